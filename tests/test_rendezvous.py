"""Rendezvous (issue 10): the vehicle's broadcast navigation as a coarse target
(systems/perception/rendezvous.py), the supervisor tracking it where it has no vision, and the missions
it makes possible: a vehicle that starts out of view, and the 12 m/s sine path from 10 m."""

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly
from diagrams.runner import load_scenario
from systems.control.landing import (
    LandingConfig,
    LandingStateMachine,
    Mode,
    SupervisorInputs,
    SupervisorMemory,
    supervisor_step,
)
from systems.perception.rendezvous import RendezvousConfig, SeamSelect, VehicleBroadcast
from systems.perception.seam import P_BP_W, V_WP, VALID, seam_vector
from systems.sensors.navigation import SecondOrderGaussMarkov
from systems.vehicles.quadrotor import STATE_SIZE

P0, V = np.array([5.0, -2.0, 1.6]), np.array([3.0, 1.0, 0.0])  # the pad at t = 0 [m] and its velocity [m/s]


def truth_at(t):
    """The true seam of a pad moving at constant velocity, seen from a UAV hovering at the origin."""
    return seam_vector(RigidTransform(), P0 + V * t, V, np.zeros(3), True)


def broadcast_system(seed=3, **settings):
    system = VehicleBroadcast(RendezvousConfig(source="broadcast", **settings), seed=seed)
    context = system.CreateDefaultContext()
    system.GetInputPort("quadrotor_state").FixValue(context, np.zeros(STATE_SIZE))
    system.GetInputPort("X_WB").FixValue(context, RigidTransform())
    return system, context


def send(simulator, system, t):
    """The message of time t (the truth then), sent by the periodic update at t."""
    context = simulator.get_mutable_context()
    system.GetInputPort("true_relative_state").FixValue(context, truth_at(t))
    simulator.AdvanceTo(t + 0.01)


def test_an_exact_broadcast_arrives_one_message_late_and_is_dead_reckoned():
    system, context = broadcast_system(position_std_m=0.0, latency_periods=1)
    simulator = Simulator(system, context)
    output = system.get_output_port()
    assert output.Eval(context)[VALID] == 0.0  # nothing received yet
    send(simulator, system, 0.0)
    assert output.Eval(context)[VALID] == 0.0  # the first message is still in flight
    send(simulator, system, 0.1)
    context.SetTime(0.15)  # the message of t = 0, dead-reckoned 0.15 s
    seam = output.Eval(context)
    assert seam[VALID] == 1.0
    np.testing.assert_allclose(seam[P_BP_W], truth_at(0.15)[P_BP_W], atol=1e-12)
    np.testing.assert_allclose(seam[V_WP], truth_at(0.15)[V_WP], atol=1e-12)
    context.SetTime(0.0 + 1.0 + 1e-6)  # older than max_age_s: invalid
    assert output.Eval(context)[VALID] == 0.0


def test_the_shortest_max_age_accepted_keeps_a_steady_broadcast_valid_between_messages():
    # A message arrives latency / rate old and is held a period more: the smallest max_age_s validate() accepts
    # is that, and the broadcast stays valid from its first arrival on.
    system, context = broadcast_system(position_std_m=0.0, latency_periods=1, max_age_s=(1 + 1) / 10.0)
    system.GetInputPort("true_relative_state").FixValue(context, truth_at(0.0))
    simulator = Simulator(system, context)
    valid = []
    for t in np.arange(0.105, 2.0, 0.01):
        simulator.AdvanceTo(t)
        valid.append(system.get_output_port().Eval(context)[VALID])
    assert all(v == 1.0 for v in valid)
    with pytest.raises(ValueError, match=r"rendezvous.max_age_s \(0.19 s\) must be at least"):
        RendezvousConfig(source="broadcast", latency_periods=1, max_age_s=0.19).validate()


@pytest.mark.parametrize("rate_hz, latency_periods", [(10.0, 1), (10.0, 2), (30.0, 1), (7.0, 3)])
def test_at_the_shortest_max_age_a_held_message_stays_valid_at_the_send_times_themselves(rate_hz, latency_periods):
    # At k / rate_hz, before that send's update, the held message is exactly max_age_s old: the round-off of
    # the context's time minus the message's must not turn it invalid there.
    max_age_s = (latency_periods + 1) / rate_hz
    system, context = broadcast_system(position_std_m=0.0, rate_hz=rate_hz, latency_periods=latency_periods,
                                       max_age_s=max_age_s)
    system.GetInputPort("true_relative_state").FixValue(context, truth_at(0.0))
    simulator = Simulator(system, context)
    invalid = []
    for k in range(latency_periods + 2, 200):
        simulator.AdvanceTo(k / rate_hz)
        if system.get_output_port().Eval(context)[VALID] != 1.0:
            invalid.append(k)
    assert invalid == []
    context.SetTime(context.get_time() + 1.5 / rate_hz)  # no message since: older than max_age_s, invalid
    assert system.get_output_port().Eval(context)[VALID] == 0.0


def test_the_gnss_error_starts_from_its_stationary_spread():
    errors = []
    for seed in range(400):
        system = VehicleBroadcast(RendezvousConfig(source="broadcast"), seed=seed)
        errors.append(system.CreateDefaultContext().get_discrete_state(0).get_value().reshape(3, 2)[:, 0])
    std = np.std(np.array(errors) * RendezvousConfig().position_std_m)
    assert std == pytest.approx(2.0, rel=0.1)


def gnss_error(context):
    """The broadcast's GNSS error state: 3 axes x [e, e'], in units of position_std_m."""
    return context.get_discrete_state(0).get_value().reshape(3, 2).copy()


def test_the_broadcast_carries_the_gnss_position_error_and_its_rate_as_the_velocity_error():
    """Each message is the truth plus std x the error state at its send: e on the position, e' (its rate) on the
    velocity (module docstring); read at 10 ms old, dead-reckoned on the message's velocity."""
    std = 2.0
    system, context = broadcast_system(position_std_m=std, latency_periods=0)
    simulator = Simulator(system, context)
    for t in (0.0, 0.1, 0.2):
        error = gnss_error(context)
        send(simulator, system, t)
        seam = system.get_output_port().Eval(context)
        velocity_error = seam[V_WP] - V
        assert np.linalg.norm(velocity_error) > 1e-3  # a GNSS error of about 2 cm/s
        np.testing.assert_allclose(velocity_error, std * error[:, 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(seam[P_BP_W] - truth_at(t)[P_BP_W] - (V + velocity_error) * 0.01,
                                   std * error[:, 0], rtol=0, atol=1e-12)


def driving_noise(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """The 6 standard normal numbers (3 axes x [e, e']) that stepped the GNSS error from `before` to `after` (3 x 2
    each, as gnss_error gives them), recovered through the default config's second-order Gauss-Markov model
    (systems/sensors/navigation.py)."""
    config = RendezvousConfig()
    model = SecondOrderGaussMarkov(config.position_time_constant_s, 1.0 / config.rate_hz)
    g = np.column_stack([model.step(np.zeros(6), np.eye(6)[i])[:2] for i in range(2)])  # one axis's noise gain
    return np.linalg.solve(g, (after - model.step(before, np.zeros(6)).reshape(3, 2)).T).T.ravel()


def test_the_gnss_error_is_driven_by_fresh_white_noise_at_every_send():
    """The noise that steps the GNSS error at each send, recovered from its successive states through the
    second-order Gauss-Markov model (systems/sensors/navigation.py), is white and of unit spread over 120 sends,
    not one draw repeated."""
    system, context = broadcast_system()
    simulator = Simulator(system, context)
    system.GetInputPort("true_relative_state").FixValue(context, truth_at(0.0))
    errors, rate_hz = [gnss_error(context)], RendezvousConfig().rate_hz
    for k in range(120):
        simulator.AdvanceTo(k / rate_hz + 0.01)
        errors.append(gnss_error(context))
    noise = np.array([driving_noise(before, after) for before, after in zip(errors, errors[1:])])
    np.testing.assert_allclose(noise.std(axis=0), 1.0, rtol=0.25)
    assert np.all(np.abs(noise.mean(axis=0)) < 0.4)
    lag_one = np.mean(noise[1:] * noise[:-1]) / np.mean(noise**2)
    assert abs(lag_one) < 0.15


def test_the_first_send_steps_the_gnss_error_with_a_draw_of_its_own_not_the_initial_ones():
    """Over 100 seeds, the noise that drives the first send's step (at t = 0) is uncorrelated with the initial
    error, each of its 6 numbers with each of the error's 6 (|r| < 0.5, 5 standard errors of a correlation over 100):
    a fresh draw, not the one the stationary initial error was made from (which would make them one function of
    the other)."""
    initial, first = [], []
    for seed in range(100):
        system, context = broadcast_system(seed=seed)
        system.GetInputPort("true_relative_state").FixValue(context, truth_at(0.0))
        initial.append(gnss_error(context))
        Simulator(system, context).AdvanceTo(0.01)
        first.append(driving_noise(initial[-1], gnss_error(context)))
    correlation = np.corrcoef(np.reshape(initial, (100, 6)).T, np.array(first).T)[:6, 6:]
    assert np.abs(correlation).max() < 0.5


def test_seam_select_prefers_vision_and_flags_which():
    select = SeamSelect()
    context = select.CreateDefaultContext()
    vision, coarse = truth_at(0.0), truth_at(1.0)
    vision_lost = vision.copy()
    vision_lost[VALID] = 0.0
    for seen, expected in ((vision, vision), (vision_lost, coarse)):
        select.GetInputPort("vision").FixValue(context, seen)
        select.GetInputPort("rendezvous").FixValue(context, coarse)
        np.testing.assert_array_equal(select.GetOutputPort("relative_state").Eval(context), expected)
        assert select.GetOutputPort("vision_valid").Eval(context)[0] == seen[VALID]
        assert select.GetOutputPort("rendezvous_valid").Eval(context)[0] == 1.0


@pytest.mark.parametrize("source", ["none", "broadcast"])
def test_the_pid_is_told_which_seam_steers_it(source):
    # With a broadcast, the seam select's choice is the PID's source: a handover restarts it
    # (systems/control/pid.py); without one there is a single source and the port stays free.
    _, config = load_scenario("gv-landing", overrides=[f"rendezvous.source={source}"])
    diagram, handles = build_gv_landing(config)
    root = diagram.CreateDefaultContext()
    handles.initialize(root)  # HasValue evaluates the source: from a state, not the default context's zeros
    context = handles.pid.GetMyContextFromRoot(root)
    assert handles.pid.GetInputPort("source").HasValue(context) == (source == "broadcast")


def test_the_supervisor_tracks_the_rendezvous_target_unseen_and_never_descends_on_it():
    config = LandingConfig()
    machine = LandingStateMachine(config)
    tracking = np.array([11.0, 3.0])

    def step(t, altitude, seen=False, rendezvous=True):
        return machine.step(SupervisorInputs(t, altitude, altitude, seen, np.array([20.0, 5.0]), np.array([12.0, 0.0]),
                                             tracking, np.array([0.5, 0.0]), rendezvous_valid=rendezvous))

    command = step(0.0, 10.0)  # off the ground already, above IH
    assert machine.mode == Mode.CLIMB and command[2] == 0.0  # unseen: no descent to IH
    np.testing.assert_allclose(command[:2], tracking)  # but flying to the vehicle meanwhile
    np.testing.assert_allclose(command[4:6], [0.5, 0.0])
    command = step(0.02, 10.0, rendezvous=False)
    assert machine.mode == Mode.CLIMB and not command[:2].any()  # without it, it stands still

    machine = LandingStateMachine(config)
    step(0.0, config.initial_height_m)
    command = step(0.02, config.initial_height_m)  # at IH, unseen: SEARCH, following the broadcast
    assert machine.mode == Mode.SEARCH and command[2] == 0.0
    np.testing.assert_allclose(command[:2], tracking)
    np.testing.assert_allclose(command[4:6], [0.5, 0.0])  # with the PID's feed-forward, as in CLIMB
    command = step(0.04, config.initial_height_m, rendezvous=False)
    assert machine.mode == Mode.SEARCH and not command[:2].any() and not command[4:].any()
    step(0.06, config.initial_height_m, seen=True)
    assert machine.mode == Mode.FOLLOW  # the camera has it: the vision takes over


def test_the_rendezvous_target_steers_but_is_not_remembered_as_the_vision_target():
    """Only the vision estimate is kept for coasting and for the low-abort rule: tracking the rendezvous target
    (vision invalid, its velocity NaN) keeps the last vision velocity, which the coast uses once the rendezvous
    is lost too; and a FOLLOW last seen 5 m above the target that loses it while the rendezvous (whose height
    input reads 1 m, below LH) is valid holds, rather than aborting as if the last valid estimate were low."""
    config = LandingConfig()
    memory = SupervisorMemory(mode=Mode.HOLD, mode_since_s=0.0, altitude_hold_m=5.0,
                              last_target_velocity_m_s=(0.6, -0.2), last_height_m=5.0)

    def step(memory, t, rendezvous):
        return supervisor_step(memory, SupervisorInputs(t, 5.0, 5.0, False, target_velocity_m_s=np.full(2, np.nan),
                                                        tracking_velocity_m_s=np.array([0.9, -0.3]),
                                                        rendezvous_valid=rendezvous), config)

    memory, command = step(memory, 0.1, True)
    assert memory.mode == Mode.HOLD and memory.last_target_velocity_m_s == (0.6, -0.2)
    np.testing.assert_array_equal(command[:2], [0.9, -0.3])  # the PID on the rendezvous target
    memory, command = step(memory, 0.12, False)
    assert memory.mode == Mode.HOLD
    np.testing.assert_array_equal(command[:2], [0.6, -0.2])  # coasting on the last vision velocity

    memory, _ = supervisor_step(SupervisorMemory(mode=Mode.FOLLOW, altitude_hold_m=5.0, last_height_m=5.0),
                                SupervisorInputs(0.0, 5.0, 1.0, False, rendezvous_valid=True), config)
    assert memory.mode == Mode.HOLD and memory.last_height_m == 5.0


@pytest.mark.parametrize("source, lands", [("none", False), ("broadcast", True)])
def test_a_vehicle_out_of_view_is_reached_only_with_the_broadcast(source, lands):
    _, config = load_scenario("gv-landing", overrides=["vehicle.speed=3", "start.xy_m=[-40, -40]",
                                                       f"rendezvous.source={source}"])
    metrics, _ = fly(config, 60.0)
    landing = metrics["landing"]
    assert landing["success"] == lands
    if lands:
        assert landing["touchdown_error_m"] < 0.05
    else:
        assert landing["failure_reason"] == "target_lost"


@pytest.mark.parametrize("source, lands", [("none", False), ("broadcast", True)])
def test_the_12_m_s_sine_path_from_10_m_lands_on_the_truth_with_the_broadcast(source, lands):
    # Issue 10's example: it ends "diverged: 201 m from the pad" (the UAV loses the vehicle while it
    # comes down towards IH and stands still, never descending unseen); the broadcast brings it along.
    _, config = load_scenario("gv-landing", overrides=[
        "vehicle.path=sine", "vehicle.speed=12", "start.height_m=10", "start.xy_m=[0, 0]",
        f"rendezvous.source={source}"])
    landing = fly(config, 60.0)[0]["landing"]
    assert landing["success"] == lands
    if lands:
        assert landing["touchdown_error_m"] < 0.1 and landing["touchdown_rel_speed_mps"] < 0.5
    else:
        assert landing["failure_reason"] == "diverged"


def test_the_search_is_told_of_vision_by_the_perception_seam_not_the_truth():
    """The rendezvous search sweeps while the camera has no pad: its `vision` input is the seam the perception
    steers on. At t = 0 in marker-landing-wind the pad is in view (the truth's seam is valid) but the marker
    filter has fused nothing yet (the perception's is not): the search must see the latter."""
    _, config = load_scenario("marker-landing-wind", overrides=["rendezvous.source=broadcast"])
    diagram, handles = build_gv_landing(config)
    context = diagram.CreateDefaultContext()
    handles.initialize(context)

    def value(port):
        return port.Eval(port.get_system().GetMyContextFromRoot(context))

    search = diagram.GetSubsystemByName("rendezvous_search")
    vision, seam = value(search.GetInputPort("vision")), value(handles.perception.relative_state)
    assert value(handles.truth.get_output_port())[VALID] == 1.0 and seam[VALID] == 0.0
    np.testing.assert_array_equal(vision, seam)


def test_the_supervisor_and_the_monitor_are_told_of_vision_not_of_the_broadcast():
    """The supervisor descends only on the camera's seam and the monitor's target_lost waits for it: both take
    the seam select's vision flag, not the selected seam's, which the broadcast keeps valid. 40 m from a still
    vehicle, out of view, after 1 s the seam that steers is valid (the broadcast's) while their target_valid
    inputs are 0 (wired to the seam's flag, the supervisor would follow and descend on the broadcast alone)."""
    _, config = load_scenario("gv-landing", overrides=["rendezvous.source=broadcast", "start.xy_m=[-40, -40]",
                                                       "vehicle.speed=0"])
    diagram, handles = build_gv_landing(config)
    root = diagram.CreateDefaultContext()
    handles.initialize(root)
    Simulator(diagram, root).AdvanceTo(1.0)

    def value(port):
        return port.Eval(port.get_system().GetMyContextFromRoot(root))[0]

    assert value(diagram.GetSubsystemByName("seam").GetOutputPort("target_valid")) == 1.0
    assert value(handles.supervisor.GetInputPort("target_valid")) == 0.0
    assert value(handles.monitor.GetInputPort("target_valid")) == 0.0
