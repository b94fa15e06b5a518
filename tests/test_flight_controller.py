import time

import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.symbolic import Evaluate, MakeVectorVariable
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource, VectorLogSink
from pydrake.trajectories import PiecewisePolynomial

from systems.config import ConfigError
from systems.control.flight_controller import (
    COMMAND_SIZE, MAX_RATE_HZ, FlightController, FlightControllerConfig, FlightLaw, SymbolicFlightController,
    flight_command, make_flight_controller, rotor_speed_commands,
)
from systems.vehicles.quadrotor import (
    P_WB, ROTOR_SPEEDS, STATE_SIZE, V_WB, W_WB_B, Quadrotor, QuadrotorParams, hover_state, pose_from_state,
)

# pydrake filters numpy's "invalid value" warnings from symbolic object arrays when imported;
# pytest resets warning filters per test, so restore that one here.
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

QUAD = QuadrotorParams()
CONFIG = FlightControllerConfig()


def fly(command, state0, duration, log_period=0.01, backend="python"):
    """Closed loop Quadrotor + flight controller (held at its rate) under a constant command
    ([v_WB_desired, yaw], no feed-forward) or a command trajectory (COMMAND_SIZE rows).
    Returns (sample times, states (17 x N), wall time)."""
    builder = DiagramBuilder()
    quad = builder.AddSystem(Quadrotor(QUAD))
    controller = builder.AddSystem(make_flight_controller(QUAD, CONFIG, backend))
    source = builder.AddSystem(TrajectorySource(command) if isinstance(command, PiecewisePolynomial)
                               else ConstantVectorSource(flight_command(command[:3], command[3])))
    logger = builder.AddSystem(VectorLogSink(STATE_SIZE, log_period))
    builder.Connect(quad.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(source.get_output_port(), controller.GetInputPort("command"))
    builder.Connect(controller.GetOutputPort("rotor_speed_commands"),
                    quad.GetInputPort("rotor_speed_commands"))
    builder.Connect(quad.GetOutputPort("state"), logger.get_input_port())
    simulator = Simulator(builder.Build())
    root = simulator.get_mutable_context()
    quad.set_state(root, state0)
    controller.initialize(root)
    start = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall = time.perf_counter() - start
    log = logger.FindLog(root)
    return log.sample_times(), log.data(), wall


def yaw_of(state):
    return RollPitchYaw(pose_from_state(state).rotation()).yaw_angle()


def tilt_of(state):
    return np.arccos(np.clip(pose_from_state(state).rotation().matrix()[2, 2], -1, 1))


def test_attitude_gains_place_the_designed_poles():
    # One axis about hover: tau_a s^3 + s^2 + k_w s + k_R (per unit inertia).
    k_R, k_w = CONFIG.attitude_gains()
    tau, zeta = CONFIG.rotor_time_constant_s, CONFIG.attitude_damping
    for axis, w_n in enumerate([CONFIG.attitude_frequency_rad_s] * 2 + [CONFIG.yaw_frequency_rad_s]):
        roots = np.roots([tau, 1.0, k_w[axis], k_R[axis]])
        expected = [-(1 / tau - 2 * zeta * w_n),
                    complex(-zeta * w_n, w_n * np.sqrt(1 - zeta**2)),
                    complex(-zeta * w_n, -w_n * np.sqrt(1 - zeta**2))]
        np.testing.assert_allclose(np.sort_complex(roots), np.sort_complex(expected), rtol=1e-9)


@pytest.mark.parametrize("field, value, message", [
    ("rate_hz", 0.0, "rate_hz must be positive"),
    # Held longer than tau_a (25 ms) the rotor commands overshoot (10 Hz crashed the gv flight); 1e9 Hz hung a run.
    ("rate_hz", 30.0, r"rate_hz \(30 Hz\) must be at least 1 / flight_controller.rotor_time_constant_s \(40 Hz\)"),
    ("rate_hz", 1e9, r"rate_hz \(1e\+09 Hz\) must be at most 10000 Hz"),
    ("max_tilt_deg", 95.0, "max_tilt_deg"),
    ("max_tilt_deg", 0.0, r"max_tilt_deg must be in \(0, 90\)"),  # no tilt: no horizontal control
    ("max_tilt_deg", 90.0, r"max_tilt_deg must be in \(0, 90\)"),  # horizontal thrust: tan 90 deg, no weight held
    ("max_vertical_accel_m_s2", 10.0,
     r"^flight_controller.max_vertical_accel_m_s2 \(10 m/s\^2\) must be below quadrotor.gravity_m_s2 \(9.81 m/s\^2\)$"),
    # A full sink at a_max = g commands no thrust at all.
    ("max_vertical_accel_m_s2", 9.81, r"max_vertical_accel_m_s2 \(9.81 m/s\^2\) must be below"),
    ("attitude_frequency_rad_s", 40.0, "attitude_frequency_rad_s is too fast"),
    # 2 zeta w_n = 2 (0.8) 40 = 64 rad/s, past 1 / tau_a = 40 rad/s: yaw's real pole would be unstable too.
    ("yaw_frequency_rad_s", 40.0, "yaw_frequency_rad_s is too fast"),
    # At the bound itself, 2 (0.8) 25 = 40 rad/s = 1 / tau_a (both 40.0 in floats), the real pole is at 0: refused.
    ("attitude_frequency_rad_s", 25.0, "attitude_frequency_rad_s is too fast"),
    ("yaw_frequency_rad_s", 25.0, "yaw_frequency_rad_s is too fast"),
    ("velocity_gain_z", 0.0, "velocity_gain_z must be positive"),
])
def test_bad_config_is_rejected_by_name(field, value, message):
    with pytest.raises(ValueError, match=message):
        FlightController(QUAD, FlightControllerConfig(**{field: value}))


@pytest.mark.parametrize("rate_hz", [40.0, MAX_RATE_HZ])
def test_the_rate_limits_themselves_are_accepted(rate_hz):
    """The rate's bounds are inclusive: 1 / tau_a (40 Hz; 40 x 0.025 is 1.0 exactly in floats) and MAX_RATE_HZ."""
    FlightControllerConfig(rate_hz=rate_hz).validate(quad=QUAD)


def test_law_accepts_symbolic_expressions():
    x = MakeVectorVariable(STATE_SIZE, "x")
    c = MakeVectorVariable(COMMAND_SIZE, "c")
    symbolic = rotor_speed_commands(x, c, QUAD, CONFIG)
    state = hover_state(QUAD, [0, 0, 3], yaw=0.2)
    state[V_WB] = [0.3, -0.2, 0.1]
    state[W_WB_B] = [0.05, -0.1, 0.2]
    command = flight_command([1.0, 0.5, 0.2], 0.3, [0.4, -0.3, 0.2])
    env = dict(zip(x, state)) | dict(zip(c, command))
    np.testing.assert_allclose(Evaluate(symbolic, env).ravel(),
                               rotor_speed_commands(state, command, QUAD, CONFIG), rtol=1e-12)


def random_states_and_commands(count, seed=4):
    """Tilted, moving, spinning states with uneven rotor speeds, and commands up to the limits."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        state = hover_state(QUAD, rng.uniform(-5, 5, 3), yaw=rng.uniform(-np.pi, np.pi))
        state[3:7] = RotationMatrix(RollPitchYaw(*rng.uniform(-0.5, 0.5, 3))).ToQuaternion().wxyz() * rng.uniform(0.9, 1.1)
        state[7:13] = rng.uniform(-2, 2, 6)
        state[13:17] = rng.uniform(300, 650, 4)
        yield state, flight_command(np.r_[rng.uniform(-8, 8, 2), rng.uniform(-2, 2)], rng.uniform(-np.pi, np.pi),
                                    rng.uniform(-2, 2, 3))


@pytest.mark.parametrize("held", [False, True])
def test_the_two_backends_compute_the_same_law(held):
    python, symbolic = FlightController(QUAD, CONFIG, held=held), SymbolicFlightController(QUAD, CONFIG, held=held)
    contexts = [system.CreateDefaultContext() for system in (python, symbolic)]
    law = FlightLaw(QUAD, CONFIG)
    for state, command in random_states_and_commands(20):
        outputs = []
        for system, context in zip((python, symbolic), contexts):
            system.GetInputPort("state").FixValue(context, state)
            system.GetInputPort("command").FixValue(context, command)
            if held:  # the sample the periodic update would hold
                outputs.append(python.EvalUniquePeriodicDiscreteUpdate(context).get_vector().CopyToVector()
                               if system is python else system.GetOutputPort("law").Eval(context))
            else:
                outputs.append(system.GetOutputPort("rotor_speed_commands").Eval(context))
        np.testing.assert_allclose(outputs[0], law(state, command), rtol=1e-13)
        np.testing.assert_allclose(outputs[1], outputs[0], rtol=1e-10)


@pytest.mark.parametrize("motor_gain", [1.0, 2.0])
@pytest.mark.parametrize("backend", ["python", "symbolic"])
def test_the_held_command_starts_at_hover(backend, motor_gain):
    """Held, both backends put out the hover command, sqrt(m g / 4 k_t) / k_m per rotor, from initialize until
    their first sample, whatever the law would give at the inputs."""
    quad = QuadrotorParams(motor_gain=motor_gain)
    controller = make_flight_controller(quad, CONFIG, backend)
    context = controller.CreateDefaultContext()
    controller.initialize(context)
    state, command = next(random_states_and_commands(1))
    controller.GetInputPort("state").FixValue(context, state)
    controller.GetInputPort("command").FixValue(context, command)
    hover = np.sqrt(quad.mass_kg * quad.gravity_m_s2 / (4 * quad.thrust_coefficient)) / motor_gain
    np.testing.assert_allclose(controller.GetOutputPort("rotor_speed_commands").Eval(context), np.full(4, hover),
                               rtol=1e-12)


@pytest.mark.parametrize("backend, cls", [("symbolic", SymbolicFlightController), ("python", FlightController)])
def test_make_flight_controller_builds_the_named_backend_held_or_not(backend, cls):
    """Not held, the controller's output is the law at its inputs from the start (no initialize, no sample)."""
    controller = make_flight_controller(QUAD, CONFIG, backend, held=False)
    assert isinstance(controller, cls)
    context = controller.CreateDefaultContext()
    for state, command in random_states_and_commands(3):
        controller.GetInputPort("state").FixValue(context, state)
        controller.GetInputPort("command").FixValue(context, command)
        np.testing.assert_allclose(controller.GetOutputPort("rotor_speed_commands").Eval(context),
                                   FlightLaw(QUAD, CONFIG)(state, command), rtol=1e-10)


def test_an_unknown_backend_is_a_config_error_naming_the_known_ones():
    with pytest.raises(ConfigError, match="flight controller backend 'cpp' is not one of symbolic, python"):
        make_flight_controller(QUAD, CONFIG, "cpp")


@pytest.mark.parametrize("backend", ["python", "symbolic"])
def test_the_collective_thrust_is_the_thrust_along_the_body_z_axis(backend):
    """Pitched 30 deg (z_B = (sin 30, 0, cos 30)) and at rest, commanded a saturated forward speed and the sink
    v_z = g (cos 30 - 1) / K_v,z: the desired thrust is f_W = m (g + a_z)(tan 30, 0, 1) = m g (sin 30, 0, cos 30),
    along z_B (the desired attitude is the present one: no torque), so the collective thrust f_W . z_B is the weight
    m g, not f_W's vertical part m g cos 30. With the rotors at w_h = sqrt(m g / 4 k_t) each (the inverse mixer
    shares a collective thrust equally) they are kept there: commanded w_h / k_m."""
    F, pitch = QUAD.mass_kg * QUAD.gravity_m_s2, np.radians(30.0)
    state = hover_state(QUAD, [0, 0, 5])
    state[3:7] = RotationMatrix(RollPitchYaw(0.0, pitch, 0.0)).ToQuaternion().wxyz()
    w_h = np.sqrt(F / (4 * QUAD.thrust_coefficient))
    state[ROTOR_SPEEDS] = w_h
    command = flight_command([50.0, 0.0, QUAD.gravity_m_s2 * (np.cos(pitch) - 1) / CONFIG.velocity_gain_z])
    np.testing.assert_allclose(FlightLaw(QUAD, CONFIG).thrust(state[V_WB], command[:3], command[4:7]),
                               F * np.array([np.sin(pitch), 0.0, np.cos(pitch)]), rtol=1e-12, atol=1e-12)
    controller = make_flight_controller(QUAD, CONFIG, backend, held=False)
    context = controller.CreateDefaultContext()
    controller.GetInputPort("state").FixValue(context, state)
    controller.GetInputPort("command").FixValue(context, command)
    np.testing.assert_allclose(controller.GetOutputPort("rotor_speed_commands").Eval(context),
                               np.full(4, w_h / QUAD.motor_gain), rtol=1e-12)


def test_the_two_backends_fly_alike():
    command, state0 = [2.0, -1.0, 0.5, 0.5], hover_state(QUAD, [0, 0, 5])
    _, python, _ = fly(command, state0, duration=3.0)
    _, symbolic, _ = fly(command, state0, duration=3.0, backend="symbolic")
    assert np.abs(python[P_WB] - symbolic[P_WB]).max() < 1e-6


def test_acceleration_feed_forward_is_added_to_the_velocity_loop():
    law = FlightLaw(QUAD, CONFIG)
    v = [1.0, -0.5, 0.2]
    f_W = law.thrust(v, v, [0.8, -0.4, 0.5])  # no velocity error: the feed-forward alone
    np.testing.assert_allclose(f_W, QUAD.mass_kg * np.array([0.8, -0.4, QUAD.gravity_m_s2 + 0.5]), rtol=1e-14)


@pytest.mark.parametrize("v_z_desired", [-50.0, 0.0, 50.0])  # sinking and climbing at max_vertical_accel_m_s2
def test_a_saturated_thrust_tilts_by_max_tilt_deg_whatever_the_vertical_acceleration(v_z_desired):
    """The horizontal limit scales with the vertical thrust: a saturated horizontal command tilts the desired
    thrust f_W by exactly max_tilt_deg, also while sinking or climbing at the vertical limit, and keeps the
    vertical thrust m (g + a_z)."""
    law = FlightLaw(QUAD, CONFIG)
    f_W = np.array(law.thrust([0.0, 0.0, 0.0], [30.0, -40.0, v_z_desired], [0.0, 0.0, 0.0]))
    a_z = np.clip(CONFIG.velocity_gain_z * v_z_desired, -CONFIG.max_vertical_accel_m_s2,
                  CONFIG.max_vertical_accel_m_s2)
    assert f_W[2] == pytest.approx(QUAD.mass_kg * (QUAD.gravity_m_s2 + a_z), rel=1e-14)
    assert np.degrees(np.arctan2(np.hypot(f_W[0], f_W[1]), f_W[2])) == pytest.approx(CONFIG.max_tilt_deg, abs=1e-9)
    np.testing.assert_allclose(f_W[:2] / np.hypot(f_W[0], f_W[1]), [0.6, -0.8], rtol=1e-14)  # the command's way


def test_at_the_desired_attitude_the_torque_is_damping_plus_the_gyroscopic_term():
    """Lee et al. (2010): at R = R_des (e_R = 0) T_B = -J k_w w_B + w_B x (J w_B), computed here with numpy."""
    law = FlightLaw(QUAD, CONFIG)
    _, k_w = CONFIG.attitude_gains()
    J = QUAD.inertia_diagonal
    w_B = np.array([1.0, -2.0, 3.0])
    identity = np.eye(3).ravel().tolist()
    np.testing.assert_allclose(law.torque(identity, identity, w_B), -J * k_w * w_B + np.cross(w_B, J * w_B),
                               rtol=1e-12)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_an_attitude_error_about_each_axis_is_corrected_with_that_axis_gain(axis):
    """At rest (w_B = 0) rotated 0.2 rad about body axis `axis` from R_des = I: e_R = vee(R - R^T) / 2 is
    sin(0.2) along that axis, so T_B = -J_i k_R[i] sin(0.2) on it alone (roll, pitch and yaw each their own k_R)."""
    law = FlightLaw(QUAD, CONFIG)
    k_R, _ = CONFIG.attitude_gains()
    J = QUAD.inertia_diagonal
    R = [RotationMatrix.MakeXRotation, RotationMatrix.MakeYRotation, RotationMatrix.MakeZRotation][axis](0.2)
    identity = np.eye(3).ravel().tolist()
    expected = np.zeros(3)
    expected[axis] = -J[axis] * k_R[axis] * np.sin(0.2)
    np.testing.assert_allclose(law.torque(R.matrix().ravel().tolist(), identity, [0.0, 0.0, 0.0]), expected,
                               rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("z_desired, yaw", [
    ([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))], 0.0),  # pitched 30 deg toward the heading
    ([0.3, -0.4, np.sqrt(1 - 0.25)], 1.0),
])
def test_the_desired_rotation_of_a_tilted_thrust_is_a_rotation(z_desired, yaw):
    """y_B desired is the unit vector normal to z_desired and to the heading (cos yaw, sin yaw, 0), by numpy; with it
    R_WB_des (columns y x z, y, z) is orthonormal with det 1. Pitched 30 deg toward a heading of 0, y is (0, 1, 0),
    not z x heading's (0, cos 30, 0)."""
    law = FlightLaw(QUAD, CONFIG)
    normal = np.cross(z_desired, [np.cos(yaw), np.sin(yaw), 0.0])
    y = law.lateral_axis(z_desired, yaw)
    np.testing.assert_allclose(y, normal / np.linalg.norm(normal), rtol=1e-12, atol=1e-15)
    R = np.array(law.desired_rotation(y, z_desired)).reshape(3, 3)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R[:, 2], z_desired, rtol=1e-12)


def test_a_rotor_asked_for_negative_thrust_is_commanded_to_stop():
    """Level, the weight's collective thrust F with a roll torque of 2 F l1: Eq. (8) by hand gives rotors 1 and 4
    3F/4 and rotors 2 and 3 -F/4, which no rotor can push, so their w_des is 0 (not sqrt(F/4 / k_t)): the command
    (w + (tau_m / tau_a)(w_des - w)) / k_m of the module docstring."""
    law = FlightLaw(QUAD, CONFIG)
    F = QUAD.mass_kg * QUAD.gravity_m_s2
    w = np.array([400.0, 410.0, 420.0, 430.0])
    commands = law.rotor_commands([0.0, 0.0, F], np.eye(3).ravel().tolist(), [2 * F * QUAD.arm_lateral_m, 0.0, 0.0],
                                  w)
    w_des = np.array([np.sqrt(0.75 * F / QUAD.thrust_coefficient), 0.0, 0.0,
                      np.sqrt(0.75 * F / QUAD.thrust_coefficient)])
    lag_ratio = QUAD.motor_time_constant_s / CONFIG.rotor_time_constant_s
    np.testing.assert_allclose(commands, (w + lag_ratio * (w_des - w)) / QUAD.motor_gain, rtol=1e-12)


@pytest.mark.parametrize("feed_forward", [True, False])
def test_a_ramp_in_velocity_is_tracked_without_lag_with_its_acceleration_fed_forward(feed_forward):
    # v_des = a t along x for 4 s: without the feed-forward the velocity lags by a / K_v.
    a, times = 0.5, np.array([0.0, 4.0])
    commands = np.array([flight_command([a * t, 0.0, 0.0], 0.0, [a if feed_forward else 0.0, 0.0, 0.0])
                         for t in times]).T
    t, states, _ = fly(PiecewisePolynomial.FirstOrderHold(times, commands), hover_state(QUAD, [0, 0, 5]), 4.0)
    late = t >= 2.5
    lag = a * t[late] - states[V_WB.start, late]
    if feed_forward:
        assert np.abs(lag).max() < 0.01
    else:
        np.testing.assert_allclose(lag, a / CONFIG.velocity_gain_xy, rtol=0.05)


def test_hover_holds():
    state0 = hover_state(QUAD, [1.0, 2.0, 5.0], yaw=0.3)
    _, states, _ = fly([0, 0, 0, 0.3], state0, duration=5.0)
    np.testing.assert_allclose(states[P_WB, -1], [1.0, 2.0, 5.0], atol=1e-6)
    assert yaw_of(states[:, -1]) == pytest.approx(0.3, abs=1e-6)


def test_velocity_and_yaw_step_is_tracked():
    command = [2.0, -1.0, 0.5, 0.5]
    times, states, wall = fly(command, hover_state(QUAD, [0, 0, 5]), duration=10.0)
    print(f"\nquadrotor + flight controller closed loop: {times[-1]:.0f} s simulated in "
          f"{wall:.2f} s, real-time factor {times[-1] / wall:.1f}")
    settled = times >= 3.0
    np.testing.assert_allclose(states[V_WB][:, settled].T, np.tile(command[:3], (settled.sum(), 1)),
                               atol=0.02)
    assert yaw_of(states[:, -1]) == pytest.approx(0.5, abs=1e-3)
    # Well damped: the horizontal speed overshoots its 2.24 m/s step by under 10 %.
    speed = np.linalg.norm(states[V_WB][:2], axis=0)
    assert speed.max() < 1.1 * np.hypot(2.0, -1.0)


def test_large_step_respects_tilt_limit():
    _, states, _ = fly([15.0, 0.0, 0.0, 0.0], hover_state(QUAD, [0, 0, 20]), duration=3.0)
    tilts = np.degrees([tilt_of(x) for x in states.T])
    assert 25.0 < tilts.max() < CONFIG.max_tilt_deg + 3.0
    assert abs(states[V_WB][2, -1]) < 0.3  # still holding altitude while tilted


def test_recovers_from_tilt_and_spin():
    state0 = hover_state(QUAD, [0, 0, 10])
    state0[3:7] = RotationMatrix(RollPitchYaw(0.5, -0.4, 0.0)).ToQuaternion().wxyz()
    state0[W_WB_B] = [2.0, -1.0, 1.0]
    _, states, _ = fly([0, 0, 0, 0], state0, duration=6.0)
    assert tilt_of(states[:, -1]) < 1e-3
    assert abs(yaw_of(states[:, -1])) < 1e-2
    assert np.linalg.norm(states[V_WB, -1]) < 1e-2
    assert states[2].min() > 9.0  # lost under 1 m of height on the way
