"""The UAV's own navigation (systems/sensors/navigation.py): the Gauss-Markov errors' statistics,
the navigation state built from the truth and its errors, the system seeded and consistent, its
settings' checks, and in the gv diagram where it reaches."""

import math

import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.sensors.navigation import (
    NavigationConfig,
    NavigationSystem,
    gauss_markov_step,
    navigation_state,
    second_order_model,
)
from systems.vehicles.quadrotor import P_WB, Q_WB, V_WB, pose_from_state, quadrotor_state
from tests.conftest import wiring

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

TRUE = quadrotor_state(p_WB=[1.0, 2.0, 5.0], R_WB=RotationMatrix(RollPitchYaw(0.1, -0.05, 0.7)), v_WB=[1.0, 0.0, -0.5],
                       w_WB_B=[0.1, 0.0, 0.0], rotor_speeds=[480.0] * 4)


def test_the_gauss_markov_error_keeps_its_variance_and_correlation_time():
    rng = np.random.default_rng(0)
    period, tau, std = 0.1, 5.0, 2.0
    e, series = np.array([std * rng.standard_normal()]), []
    for _ in range(200000):
        e = gauss_markov_step(e, [std], tau, period, rng.standard_normal(1))
        series.append(e[0])
    series = np.array(series)
    assert series.std() == pytest.approx(std, rel=0.05)
    lag = 30  # 3 s
    assert np.corrcoef(series[:-lag], series[lag:])[0, 1] == pytest.approx(math.exp(-lag * period / tau), abs=0.03)


def test_the_navigation_state_is_the_truth_moved_by_its_errors():
    state = navigation_state(TRUE, [0.5, -0.2, 0.1], [0.01, -0.02, 0.05], [0.03, 0.0, -0.01])
    np.testing.assert_allclose(state[P_WB], TRUE[P_WB] + [0.5, -0.2, 0.1])
    np.testing.assert_allclose(state[V_WB], TRUE[V_WB] + [0.03, 0.0, -0.01])
    expected = pose_from_state(TRUE).rotation().multiply(RotationMatrix(RollPitchYaw(0.01, -0.02, 0.05)))
    assert pose_from_state(state).rotation().IsNearlyEqualTo(expected, 1e-12)
    np.testing.assert_array_equal(state[10:], TRUE[10:])  # body rates and rotors as they are
    np.testing.assert_allclose(navigation_state(TRUE, np.zeros(3), np.zeros(3), np.zeros(3)), TRUE, atol=1e-15)


def _simulate(seed: int, config: NavigationConfig, duration_s: float = 2.0) -> np.ndarray:
    builder = DiagramBuilder()
    truth = builder.AddSystem(ConstantVectorSource(TRUE))
    navigation = builder.AddSystem(NavigationSystem(config, seed))
    builder.Connect(truth.get_output_port(), navigation.get_input_port())
    log = LogVectorOutput(navigation.GetOutputPort("state"), builder, 0.01)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(duration_s)
    context = navigation.GetMyContextFromRoot(simulator.get_context())
    X_WB = navigation.GetOutputPort("X_WB").Eval(context)
    assert X_WB.IsNearlyEqualTo(pose_from_state(navigation.GetOutputPort("state").Eval(context)), 1e-12)
    return log.FindLog(simulator.get_context()).data().T


def test_the_system_is_seeded_its_errors_the_configured_size_and_its_velocity_error_the_positions_rate():
    config = NavigationConfig(source="gnss_ins", position_time_constant_s=0.2, attitude_time_constant_s=0.2)
    states = _simulate(3, config, 40.0)
    position, velocity = states[:, P_WB] - TRUE[P_WB], states[:, V_WB] - TRUE[V_WB]
    assert position.std() == pytest.approx(config.position_std_m, rel=0.1)  # 200 correlation times
    assert velocity.std() == pytest.approx(config.position_std_m / 0.2, rel=0.1)  # sigma / tau
    rate = np.diff(position, axis=0) / 0.01  # the logged position error's rate, against the velocity error
    assert np.corrcoef(rate.ravel(), velocity[:-1].ravel())[0, 1] > 0.95
    np.testing.assert_array_equal(states, _simulate(3, config, 40.0))
    assert not np.array_equal(states, _simulate(4, config, 40.0))


def _attitude_errors(states: np.ndarray) -> np.ndarray:
    """[roll, pitch, yaw] (rad) of R_WB_true^-1 R_WB_nav, per logged state."""
    R_BW = pose_from_state(TRUE).rotation().inverse()
    return np.array([RollPitchYaw(R_BW.multiply(pose_from_state(s).rotation())).vector() for s in states])


def test_the_attitude_error_has_the_configured_tilt_and_yaw_sizes_and_time_constant():
    """The attitude error (the truth's rotation undone from the navigation's) is a first-order Gauss-Markov
    process per axis: standard deviation [tilt, tilt, yaw] and autocorrelation e^(-|t| / tau_att), with
    tau_att its own (the position's is a minute here); 40 s is 800 correlation times."""
    tau = 0.05
    config = NavigationConfig(source="gnss_ins", tilt_std_deg=0.5, yaw_std_deg=2.0, attitude_time_constant_s=tau,
                              position_time_constant_s=60.0)
    errors = np.degrees(_attitude_errors(_simulate(3, config, 40.0)))
    np.testing.assert_allclose(errors.std(axis=0), [0.5, 0.5, 2.0], rtol=0.1)
    lag = 5  # 0.05 s of the 0.01 s log
    for axis in range(3):
        correlation = np.corrcoef(errors[:-lag, axis], errors[lag:, axis])[0, 1]
        assert correlation == pytest.approx(math.exp(-lag * 0.01 / tau), abs=0.08)


def _initial_states(config: NavigationConfig, seeds) -> np.ndarray:
    """The navigation's state at t = 0 (before any step) over the truth TRUE, one row per seed."""
    states = []
    for seed in seeds:
        navigation = NavigationSystem(config, seed)
        context = navigation.CreateDefaultContext()
        navigation.get_input_port().FixValue(context, TRUE)
        states.append(navigation.GetOutputPort("state").Eval(context))
    return np.array(states)


def test_the_errors_start_from_their_stationary_distribution():
    """At t = 0, across 150 seeds, the position and attitude errors already have their configured sizes."""
    config = NavigationConfig(source="gnss_ins", position_std_m=2.0, tilt_std_deg=0.5, yaw_std_deg=2.0)
    states = _initial_states(config, range(150))
    position, attitude = states[:, P_WB] - TRUE[P_WB], _attitude_errors(states)
    np.testing.assert_allclose(np.std(position, axis=0), [2.0] * 3, rtol=0.2)
    np.testing.assert_allclose(np.degrees(np.std(attitude, axis=0)), [0.5, 0.5, 2.0], rtol=0.2)


def test_the_initial_attitude_error_is_drawn_apart_from_the_velocity_error():
    """At t = 0, across 200 seeds, the standardised velocity error (over position_std_m / position_time_constant_s,
    its stationary size) and attitude error (over [tilt, tilt, yaw] std) are uncorrelated per axis: each has
    its own normal numbers (from the same ones they would be equal)."""
    config = NavigationConfig(source="gnss_ins")
    states = _initial_states(config, range(200))
    velocity = (states[:, V_WB] - TRUE[V_WB]) / (config.position_std_m / config.position_time_constant_s)
    attitude = _attitude_errors(states) / np.radians([config.tilt_std_deg, config.tilt_std_deg, config.yaw_std_deg])
    np.testing.assert_allclose(velocity.std(axis=0), 1.0, rtol=0.2)
    np.testing.assert_allclose(attitude.std(axis=0), 1.0, rtol=0.2)
    for axis in range(3):
        assert abs(np.corrcoef(velocity[:, axis], attitude[:, axis])[0, 1]) < 0.3


def test_each_step_draws_noise_of_its_own_not_the_initial_states():
    """The step from t = 0 adds fresh noise: across 200 seeds its innovation in the attitude error (e_1 - a e_0,
    over sigma sqrt(1 - a^2): standard normal) is uncorrelated with the standardised initial error e_0 / sigma
    (with the initial state's draw reused the two would be equal)."""
    config = NavigationConfig(source="gnss_ins", tilt_std_deg=0.5, yaw_std_deg=2.0, attitude_time_constant_s=0.05)
    period = 1.0 / config.rate_hz
    a = math.exp(-period / config.attitude_time_constant_s)
    std = np.radians([0.5, 0.5, 2.0])
    initial, innovation = [], []
    for seed in range(200):
        navigation = NavigationSystem(config, seed)
        context = navigation.CreateDefaultContext()
        navigation.get_input_port().FixValue(context, TRUE)
        e0 = context.get_discrete_state_vector().CopyToVector()[6:9]
        e1 = navigation.EvalUniquePeriodicDiscreteUpdate(context).get_vector().CopyToVector()[6:9]
        initial.append(e0 / std)
        innovation.append((e1 - a * e0) / (std * math.sqrt(1.0 - a * a)))
    initial, innovation = np.array(initial), np.array(innovation)
    np.testing.assert_allclose(innovation.std(axis=0), 1.0, rtol=0.2)
    for axis in range(3):
        assert abs(np.corrcoef(initial[:, axis], innovation[:, axis])[0, 1]) < 0.3


def test_the_second_order_model_is_exact():
    phi, g, stationary = second_order_model(5.0, 0.01)
    P = stationary @ stationary.T
    np.testing.assert_allclose(P, np.diag([1.0, 1.0 / 25.0]), atol=1e-12)  # var(e) = 1, var(e') = 1 / tau^2
    np.testing.assert_allclose(phi @ P @ phi.T + g @ g.T, P, atol=1e-12)  # stationary under the step
    lag = 300  # 3 s: R(t) / R(0) = (1 + t / tau) e^(-t / tau)
    assert (np.linalg.matrix_power(phi, lag) @ P)[0, 0] == pytest.approx((1 + 3.0 / 5.0) * math.exp(-3.0 / 5.0))


def test_zero_error_sizes_are_allowed_and_give_the_truth():
    """position_std_m, tilt_std_deg and yaw_std_deg may be zero (not negative): the errors are then zero times
    their draws, so the navigation is the truth, at t = 0 and after its steps."""
    config = NavigationConfig(source="gnss_ins", position_std_m=0.0, tilt_std_deg=0.0, yaw_std_deg=0.0)
    config.validate()
    state = _initial_states(config, [0])[0]
    np.testing.assert_array_equal(np.delete(state, Q_WB), np.delete(TRUE, Q_WB))  # exactly: plus zero
    np.testing.assert_allclose(state[Q_WB], TRUE[Q_WB], rtol=0, atol=1e-15)  # its round trip through R_WB
    states = _simulate(0, config, 0.1)
    np.testing.assert_allclose(states, np.tile(TRUE, (len(states), 1)), rtol=0, atol=1e-15)


def test_navigation_settings_name_their_mistakes():
    with pytest.raises(ConfigError, match=r"navigation\.source 'gps'"):
        load_scenario("gv-landing", overrides=["navigation.source=gps"])
    with pytest.raises(ConfigError, match=r"navigation\.position_std_m"):
        load_scenario("gv-landing", overrides=["navigation.position_std_m=-1"])
    with pytest.raises(ConfigError, match="navigation.source must be truth"):
        load_scenario("open-landing", overrides=["navigation.source=gnss_ins"])


def test_in_the_loop_the_controller_flies_on_the_navigation():
    # Held over the start, the UAV flies where its navigation says it is: its true position wanders
    # with the navigation's error, which the truth-navigation flight does not.
    flights = {}
    for source in ("truth", "gnss_ins"):
        _, s = load_scenario("gv-landing", overrides=[f"navigation.source={source}", "vehicle.speed=0.0"])
        flights[source] = fly(s, 3.0)[1].log["quadrotor_state"][:, P_WB]
    assert np.abs(flights["truth"][:, :2] - flights["truth"][0, :2]).max() < 1e-6
    assert np.abs(flights["gnss_ins"][:, :2] - flights["gnss_ins"][0, :2]).max() > 1e-3


def test_the_marker_filters_and_the_vehicle_broadcast_place_the_pad_with_the_navigations_pose():
    """The marker filters, the vehicle's broadcast and its search pattern, and the steering filter's seam (which
    turn what they measure into World, or World into the body frame) take the UAV's pose from its navigation, as
    the controller does, not the true pose the camera and the referee keep: at t = 0 their X_WB inputs are the
    navigation's, which is off the truth by its starting error."""
    _, s = load_scenario("gv-marker-ekf", overrides=["navigation.source=gnss_ins", "rendezvous.source=broadcast",
                                                     "rendezvous.search_spacing_m=2.0", "perception.source=ct_ekf"])
    diagram, handles = build_gv_landing(s)
    context = diagram.CreateDefaultContext()
    handles.initialize(context)

    def output(system, name):
        return system.GetOutputPort(name).Eval(system.GetMyContextFromRoot(context))

    navigation, truth = output(diagram.GetSubsystemByName("navigation"), "X_WB"), output(handles.quadrotor, "X_WB")
    assert np.linalg.norm(navigation.translation() - truth.translation()) > 1e-3
    readers = [*handles.filters.values(), *(diagram.GetSubsystemByName(name) for name in (
        "vehicle_broadcast", "rendezvous_search", "estimate_to_seam"))]
    assert len(readers) == 5
    for system in readers:
        X_WB = system.GetInputPort("X_WB").Eval(system.GetMyContextFromRoot(context))
        assert X_WB.IsExactlyEqualTo(navigation), system.get_name()


def test_the_controller_flies_on_the_navigation_and_the_referee_judges_the_truth():
    """With navigation.source gnss_ins the flight controller's state is the navigation's (truth plus its
    errors), while the landing monitor (the referee: touchdown, crash) reads the quadrotor's true state."""
    _, s = load_scenario("gv-landing", overrides=["navigation.source=gnss_ins"])
    diagram, _ = build_gv_landing(s)
    wired = wiring(diagram)
    assert wired["flight_controller", "state"] == ("navigation", "state")
    assert wired["monitor", "quadrotor_state"] == ("quadrotor", "state")
