import dataclasses

import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.examples import QuadrotorPlant
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Adder, ConstantVectorSource, Sine

from systems.config import ConfigError
from systems.vehicles.quadrotor import (
    P_WB, Q_WB, ROTOR_SPEEDS, STATE_SIZE, V_WB, W_WB_B, Quadrotor, QuadrotorParams, hover_state,
    mixer_matrix, pose_from_state, quadrotor_state, quadrotor_state_derivative,
    quaternion_rate, rotation_from_quaternion,
)

# pydrake filters numpy's "invalid value" warnings from symbolic object arrays when imported;
# pytest resets warning filters per test, so restore that one here.
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

PARAMS = QuadrotorParams()


def simulate_constant_commands(params, state0, commands, duration, time_period=None):
    """Runs the Quadrotor diagram (discretised with `time_period`) with constant rotor speed
    commands; returns the final state."""
    builder = DiagramBuilder()
    quad = builder.AddSystem(Quadrotor(params, time_period))
    source = builder.AddSystem(ConstantVectorSource(np.asarray(commands, dtype=float)))
    builder.Connect(source.get_output_port(), quad.GetInputPort("rotor_speed_commands"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.get_mutable_integrator().set_target_accuracy(1e-10)
    root = simulator.get_mutable_context()
    quad.set_state(root, state0)
    simulator.AdvanceTo(duration)
    return quad.GetOutputPort("state").Eval(quad.GetMyContextFromRoot(root))


def rotor_speeds_for(params, collective, torque_B):
    """Rotor speeds whose thrusts produce the given collective thrust (N) and body torque (N m)."""
    thrusts = np.linalg.solve(mixer_matrix(params), np.concatenate([[collective], torque_B]))
    assert np.all(thrusts > 0)
    return np.sqrt(thrusts / params.thrust_coefficient)


def test_table1_hover_speed_is_plausible():
    # 4 k_t w^2 = m g with Table 1's k_t = 1.28e-5 N s^2/rad^2 and m = 1.2 kg.
    assert PARAMS.hover_rotor_speed() == pytest.approx(479.5, abs=0.1)


# every constant but the rotor drag (0 is seed 002's no-drag model) is a mass, length, time, gain or coefficient > 0
POSITIVE_FIELDS = [f.name for f in dataclasses.fields(QuadrotorParams) if f.name != "rotor_drag_coefficient"]


@pytest.mark.parametrize("value", [0.0, -0.1])
@pytest.mark.parametrize("field", POSITIVE_FIELDS)
def test_nonpositive_fields_are_rejected_by_name(field, value):
    """Each of the 12 positive constants, set to zero or below, is a ConfigError naming it."""
    with pytest.raises(ValueError, match=f"quadrotor.{field} must be positive"):
        QuadrotorParams(**{field: value}).validate()


def test_negative_rotor_drag_is_rejected_and_zero_accepted():
    """The rotor drag opposes the air's velocity: a negative coefficient is a ConfigError; 0 (no drag) is valid."""
    with pytest.raises(ValueError, match="quadrotor.rotor_drag_coefficient must not be negative"):
        QuadrotorParams(rotor_drag_coefficient=-1e-5).validate()
    QuadrotorParams(rotor_drag_coefficient=0.0).validate()


@pytest.mark.parametrize("field", ["inertia_xx_kg_m2", "inertia_yy_kg_m2", "inertia_zz_kg_m2"])
def test_each_principal_inertia_over_the_sum_of_the_others_is_rejected(field):
    """No rigid body has one principal moment above the sum of the other two (here 0.1 > 0.015 + 0.03 at most)."""
    with pytest.raises(ValueError, match="triangle inequality"):
        QuadrotorParams(**{field: 0.1}).validate()


def test_paper_inertia_as_printed_is_rejected():
    # Table 1 prints Jx = 0.15, which no rigid body can have with Jy = 0.015, Jz = 0.03.
    with pytest.raises(ValueError, match="triangle inequality"):
        QuadrotorParams(inertia_xx_kg_m2=0.15).validate()


def test_motor_limit_below_hover_is_rejected():
    with pytest.raises(ValueError, match="max_rotor_speed_rad_s"):
        QuadrotorParams(max_rotor_speed_rad_s=400.0).validate()


@pytest.mark.parametrize("inertia", [(0.03, 0.015, 0.015), (0.015, 0.03, 0.015), (0.015, 0.015, 0.03)])
def test_a_flat_lamina_on_the_triangle_inequality_is_accepted(inertia):
    """The inequality allows equality (each moment at most the sum of the others): a flat plate in the plane normal
    to one axis has that moment equal to the sum of the other two (0.015 + 0.015 == 0.03 exactly in floats)."""
    assert inertia[0] + inertia[1] + inertia[2] == 2 * max(inertia)
    QuadrotorParams(**dict(zip(["inertia_xx_kg_m2", "inertia_yy_kg_m2", "inertia_zz_kg_m2"], inertia))).validate()


def test_a_motor_limit_exactly_at_the_hover_speed_cannot_hover():
    """Four rotors at w_max only just carry the weight, with nothing to climb or steer with: refused."""
    w_hover = np.sqrt(PARAMS.mass_kg * PARAMS.gravity_m_s2 / (4 * PARAMS.thrust_coefficient))
    with pytest.raises(ConfigError, match="max_rotor_speed_rad_s = .* cannot hover"):
        QuadrotorParams(max_rotor_speed_rad_s=float(w_hover)).validate()


def test_the_default_motor_limit_gives_the_documented_thrust_to_weight_ratio():
    """QuadrotorParams' comment: w_max = 700 rad/s gives a thrust-to-weight ratio of 2.1, 4 k_t w_max^2 / (m g)."""
    ratio = 4 * PARAMS.thrust_coefficient * PARAMS.max_rotor_speed_rad_s ** 2 / (PARAMS.mass_kg * PARAMS.gravity_m_s2)
    assert ratio == pytest.approx(2.1, abs=0.05)


@pytest.mark.parametrize("time_period", [0.0, -0.005])
def test_a_time_period_that_is_not_positive_is_a_config_error(time_period):
    """Unchecked, DiscreteTimeApproximation fails its time_period > 0 check: pydrake raises SystemExit."""
    with pytest.raises(ConfigError, match="quadrotor time_period must be positive"):
        Quadrotor(PARAMS, time_period)


def test_yaml_loaded_params_are_validated_when_built():
    params = yaml_load_typed(schema=QuadrotorParams, data="mass_kg: -2.0")
    with pytest.raises(ValueError, match="mass_kg"):
        Quadrotor(params)


def test_mixer_matches_rotor_positions():
    # Eq. (8) read as rotors at (+l2, +l1), (+l2, -l1), (-l2, -l1), (-l2, +l1): the torque of a
    # thrust f along +Bz at r = (x, y, 0) is r x [0, 0, f] = (y f, -x f, 0).
    l1, l2 = 0.2, 0.3
    params = QuadrotorParams(arm_lateral_m=l1, arm_longitudinal_m=l2)
    positions = np.array([[l2, l1], [l2, -l1], [-l2, -l1], [-l2, l1]])
    M = mixer_matrix(params)
    np.testing.assert_allclose(M[1], positions[:, 1])
    np.testing.assert_allclose(M[2], -positions[:, 0])
    np.testing.assert_allclose(M[3] * params.thrust_coefficient,
                               params.drag_torque_coefficient * np.array([1, -1, 1, -1]))


def test_quaternion_rate_matches_body_angular_velocity():
    q = RotationMatrix(RollPitchYaw(0.3, -0.2, 1.1)).ToQuaternion().wxyz()
    w_B = np.array([0.4, -0.7, 1.3])
    dt = 1e-7
    R_dot = (rotation_from_quaternion(q + dt * quaternion_rate(q, w_B))
             - rotation_from_quaternion(q)) / dt
    R = rotation_from_quaternion(q)
    w_hat = np.array([[0, -w_B[2], w_B[1]], [w_B[2], 0, -w_B[0]], [-w_B[1], w_B[0], 0]])
    np.testing.assert_allclose(R_dot, R @ w_hat, atol=1e-5)


def test_hover_equilibrium_holds_still():
    state0 = hover_state(PARAMS, p_WB=[1.0, -2.0, 10.0], yaw=0.7)
    w_hover = PARAMS.hover_rotor_speed() / PARAMS.motor_gain
    np.testing.assert_allclose(
        quadrotor_state_derivative(state0, np.full(4, w_hover), PARAMS),
        np.zeros(STATE_SIZE), atol=1e-12)
    final = simulate_constant_commands(PARAMS, state0, np.full(4, w_hover), duration=5.0)
    np.testing.assert_allclose(final, state0, atol=1e-9)


def test_yaw_torque_step_gives_expected_angular_acceleration():
    tau_z = 0.05  # N m
    rotor_speeds = rotor_speeds_for(PARAMS, PARAMS.mass_kg * PARAMS.gravity_m_s2, [0.0, 0.0, tau_z])
    state0 = quadrotor_state(p_WB=[0, 0, 5], rotor_speeds=rotor_speeds)
    commands = rotor_speeds / PARAMS.motor_gain

    derivative = quadrotor_state_derivative(state0, commands, PARAMS)
    np.testing.assert_allclose(derivative[W_WB_B], [0.0, 0.0, tau_z / PARAMS.inertia_zz_kg_m2])
    np.testing.assert_allclose(derivative[V_WB], np.zeros(3), atol=1e-12)

    duration = 0.5
    final = simulate_constant_commands(PARAMS, state0, commands, duration)
    np.testing.assert_allclose(final[W_WB_B], [0.0, 0.0, tau_z / PARAMS.inertia_zz_kg_m2 * duration],
                               rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(final[P_WB], [0, 0, 5], atol=1e-9)


def test_free_fall_with_rotors_off():
    state0 = quadrotor_state(p_WB=[0, 0, 20])
    final = simulate_constant_commands(PARAMS, state0, np.zeros(4), duration=1.0)
    g = PARAMS.gravity_m_s2
    np.testing.assert_allclose(final[P_WB], [0, 0, 20 - 0.5 * g], atol=1e-9)
    np.testing.assert_allclose(final[V_WB], [0, 0, -g], atol=1e-9)
    np.testing.assert_allclose(final[ROTOR_SPEEDS], np.zeros(4))


def test_motor_lag_and_saturation():
    state0 = hover_state(PARAMS, p_WB=[0, 0, 50])
    w0 = PARAMS.hover_rotor_speed()
    tau = PARAMS.motor_time_constant_s
    # Above the limit: each rotor relaxes towards w_max with time constant tau_m.
    final = simulate_constant_commands(PARAMS, state0, np.full(4, 1e4), duration=tau)
    expected = PARAMS.max_rotor_speed_rad_s + (w0 - PARAMS.max_rotor_speed_rad_s) * np.exp(-1.0)
    np.testing.assert_allclose(final[ROTOR_SPEEDS], np.full(4, expected), rtol=1e-7)
    # A negative command is clipped at zero speed.
    final = simulate_constant_commands(PARAMS, state0, np.full(4, -1e4), duration=tau)
    np.testing.assert_allclose(final[ROTOR_SPEEDS], np.full(4, w0 * np.exp(-1.0)), rtol=1e-7)


def test_motor_gain_scales_the_command():
    """Each rotor relaxes towards k_m times its command: with k_m = 2, a 240 rad/s command from rest reaches
    2 x 240 (1 - e^-1) rad/s after tau_m, and half the hover speed commanded holds a hover."""
    params = QuadrotorParams(motor_gain=2.0)
    tau = params.motor_time_constant_s
    final = simulate_constant_commands(params, quadrotor_state(p_WB=[0, 0, 50]), np.full(4, 240.0), duration=tau)
    np.testing.assert_allclose(final[ROTOR_SPEEDS], np.full(4, 2 * 240.0 * (1 - np.exp(-1.0))), rtol=1e-7)
    state0 = hover_state(params, p_WB=[1.0, -2.0, 10.0])
    np.testing.assert_allclose(quadrotor_state_derivative(state0, np.full(4, params.hover_rotor_speed() / 2), params),
                               np.zeros(STATE_SIZE), atol=1e-12)


def test_the_motor_limit_applies_to_the_gained_command():
    """The target speed is k_m times the command, clipped to [0, w_max]: with k_m = 2, a 400 rad/s command asks
    for 800 rad/s, held at w_max = 700, so rotors at rest accelerate at (700 - 0) / tau_m = 7000 rad/s^2 (clipping
    the command before the gain would ask for 800)."""
    params = QuadrotorParams(motor_gain=2.0)
    derivative = quadrotor_state_derivative(quadrotor_state(p_WB=[0, 0, 50]), np.full(4, 400.0), params)
    np.testing.assert_allclose(derivative[ROTOR_SPEEDS], np.full(4, 700.0 / 0.1))


class DrakeQuadrotorInputs(LeafSystem):
    """Our `state` -> QuadrotorPlant's input u: Drake's rotors 0, 1, 2, 3 are our 1, 4, 3, 2,
    and with kF = k_t, kM = k_d its u_i is our w_i^2."""

    DRAKE_ORDER = [0, 3, 2, 1]

    def __init__(self):
        super().__init__()
        state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self.DeclareVectorOutputPort("u", 4, lambda context, output: output.SetFromVector(
            state.Eval(context)[ROTOR_SPEEDS][self.DRAKE_ORDER] ** 2))


def test_matches_drake_quadrotor_plant():
    """Same airframe and rotor speeds give the same trajectory as Drake's QuadrotorPlant.

    QuadrotorPlant is a '+' airframe with roll-pitch-yaw state and no motor model. Its body
    frame D is ours yawed by +45 deg: its rotors at +x_D, +y_D, -x_D, -y_D (arm
    L = sqrt(l1^2 + l2^2), which needs l1 = l2) are our rotors 1, 4, 3, 2, and its yaw signs
    (+, -, +, -) match ours rotor by rotor. It is driven by our rotor speeds, so the comparison
    covers Eq. (8), thrust, drag torque and the rigid body; the motor lag is tested above."""
    params = PARAMS
    assert params.arm_lateral_m == params.arm_longitudinal_m
    R_BD = RotationMatrix.MakeZRotation(np.pi / 4)
    inertia_D = R_BD.inverse().matrix() @ np.diag(params.inertia_diagonal) @ R_BD.matrix()
    drake_plant = QuadrotorPlant(
        params.mass_kg, np.hypot(params.arm_lateral_m, params.arm_longitudinal_m), inertia_D,
        params.thrust_coefficient, params.drag_torque_coefficient)
    assert drake_plant.g() == params.gravity_m_s2

    builder = DiagramBuilder()
    ours = builder.AddSystem(Quadrotor(params))
    theirs = builder.AddSystem(drake_plant)
    # Rotor speed commands: hover plus distinct sinusoids, enough to roll, pitch and yaw.
    hover = builder.AddSystem(ConstantVectorSource(np.full(4, params.hover_rotor_speed())))
    wobble = builder.AddSystem(Sine(amplitudes=[2.0, -1.5, 1.75, -2.25],
                                    frequencies=[1.3, 2.1, 0.7, 1.7], phases=np.zeros(4)))
    commands = builder.AddSystem(Adder(2, 4))
    to_drake = builder.AddSystem(DrakeQuadrotorInputs())
    builder.Connect(hover.get_output_port(), commands.get_input_port(0))
    builder.Connect(wobble.get_output_port(0), commands.get_input_port(1))
    builder.Connect(commands.get_output_port(), ours.GetInputPort("rotor_speed_commands"))
    builder.Connect(ours.GetOutputPort("state"), to_drake.get_input_port())
    builder.Connect(to_drake.get_output_port(), theirs.get_input_port())
    diagram = builder.Build()

    simulator = Simulator(diagram)
    simulator.get_mutable_integrator().set_target_accuracy(1e-10)
    root = simulator.get_mutable_context()
    p0 = np.array([1.0, 2.0, 10.0])
    R_WB0 = RotationMatrix(RollPitchYaw(0.05, -0.03, 0.4))
    ours.GetMyMutableContextFromRoot(root).SetContinuousState(quadrotor_state(
        p_WB=p0, R_WB=R_WB0, rotor_speeds=np.full(4, params.hover_rotor_speed())))
    theirs.GetMyMutableContextFromRoot(root).SetContinuousState(np.concatenate(
        [p0, RollPitchYaw(R_WB0 @ R_BD).vector(), np.zeros(6)]))

    max_position_error = max_angle_error = 0.0
    for time in np.linspace(0.1, 3.0, 30):
        simulator.AdvanceTo(time)
        our_pose = ours.GetOutputPort("X_WB").Eval(ours.GetMyContextFromRoot(root))
        their_state = theirs.get_output_port().Eval(theirs.GetMyContextFromRoot(root))
        R_WB_theirs = RotationMatrix(RollPitchYaw(their_state[3:6])) @ R_BD.inverse()
        max_position_error = max(max_position_error,
                                 np.linalg.norm(our_pose.translation() - their_state[:3]))
        max_angle_error = max(max_angle_error, (our_pose.rotation().inverse() @ R_WB_theirs)
                              .ToAngleAxis().angle())
    travelled = np.linalg.norm(our_pose.translation() - p0)
    tilt = np.arccos(our_pose.rotation().matrix()[2, 2])
    print(f"\nQuadrotorPlant cross-check over 3 s ({travelled:.2f} m travelled, final tilt "
          f"{np.degrees(tilt):.1f} deg): max position error {max_position_error:.2e} m, "
          f"max attitude error {max_angle_error:.2e} rad")
    assert travelled > 0.5 and tilt > 0.05  # the trajectory is not trivial
    assert max_position_error < 1e-6
    assert max_angle_error < 1e-6


def test_pose_and_kinematics_outputs():
    quad = Quadrotor(PARAMS)
    context = quad.CreateDefaultContext()
    R_WB = RotationMatrix(RollPitchYaw(0.2, -0.1, 0.5))
    p_WB, v_WB, w_WB_B = np.array([1.0, 2.0, 5.0]), np.array([1.0, -2.0, 0.5]), [0.3, -0.2, 0.1]
    state = quadrotor_state(p_WB=p_WB, R_WB=R_WB, v_WB=v_WB, w_WB_B=w_WB_B,
                            rotor_speeds=[470.0, 490.0, 480.0, 475.0])
    context.SetContinuousState(state)
    quad.GetInputPort("rotor_speed_commands").FixValue(context, np.zeros(4))
    derivative = quadrotor_state_derivative(state, np.zeros(4), PARAMS)

    X_WB = quad.GetOutputPort("X_WB").Eval(context)
    assert X_WB.IsNearlyEqualTo(RigidTransform(R_WB, p_WB), 1e-12)
    np.testing.assert_allclose(quad.GetOutputPort("state").Eval(context), state)
    np.testing.assert_allclose(quad.GetOutputPort("V_WB").Eval(context),
                               np.concatenate([R_WB @ w_WB_B, v_WB]), atol=1e-12)
    np.testing.assert_allclose(quad.GetOutputPort("A_WB").Eval(context),
                               np.concatenate([R_WB @ derivative[W_WB_B], derivative[V_WB]]),
                               atol=1e-12)


def test_a_quaternion_off_unit_length_gives_the_pose_of_the_unit_one():
    """The module docstring: drift in |q| never reaches the physics. A state whose quaternion is 1.3 times a unit
    one has the pose of the unit one, from pose_from_state and the X_WB port alike."""
    R_WB, p_WB = RotationMatrix(RollPitchYaw(0.2, -0.1, 0.5)), [1.0, 2.0, 5.0]
    state = quadrotor_state(p_WB=p_WB, R_WB=R_WB, rotor_speeds=np.full(4, PARAMS.hover_rotor_speed()))
    state[Q_WB] *= 1.3
    expected = RigidTransform(R_WB, p_WB)
    assert pose_from_state(state).IsNearlyEqualTo(expected, 1e-12)
    quad = Quadrotor(PARAMS)
    context = quad.CreateDefaultContext()
    context.SetContinuousState(state)
    quad.GetInputPort("rotor_speed_commands").FixValue(context, np.zeros(4))
    assert quad.GetOutputPort("X_WB").Eval(context).IsNearlyEqualTo(expected, 1e-12)


def test_discretised_quadrotor_matches_the_continuous_one():
    """RK5 over each 5 ms period (the default of a Quadrotor given a time_period) against error-controlled
    integration: 2.4e-11 apart after 2 s in every component, rotor speeds included, well inside 1e-9 (RK3 per
    period is 4.8e-8 off, which a tolerance relative to the 480 rad/s rotor speeds would not see)."""
    state0 = quadrotor_state(p_WB=[0.0, 0.0, 10.0], R_WB=RotationMatrix(RollPitchYaw(0.1, -0.05, 0.3)),
                             v_WB=[1.0, 0.5, 0.0], w_WB_B=[0.2, -0.1, 0.3],
                             rotor_speeds=np.full(4, PARAMS.hover_rotor_speed()))
    commands = PARAMS.hover_rotor_speed() + np.array([3.0, -2.0, 1.0, -1.5])
    continuous = simulate_constant_commands(PARAMS, state0, commands, 2.0)
    discrete = simulate_constant_commands(PARAMS, state0, commands, 2.0, time_period=0.005)
    assert np.linalg.norm(continuous[P_WB] - state0[P_WB]) > 1.0  # it went somewhere
    np.testing.assert_allclose(discrete, continuous, rtol=0, atol=1e-9)


def test_discretised_quadrotor_outputs_the_same_kinematics():
    state = quadrotor_state(p_WB=[1.0, 2.0, 5.0], R_WB=RotationMatrix(RollPitchYaw(0.2, -0.1, 0.5)),
                            v_WB=[1.0, -2.0, 0.5], w_WB_B=[0.3, -0.2, 0.1], rotor_speeds=[470.0, 490.0, 480.0, 475.0])
    values = []
    for time_period in (None, 0.005):
        quad = Quadrotor(PARAMS, time_period)
        context = quad.CreateDefaultContext()
        quad.set_state(context, state)
        quad.GetInputPort("rotor_speed_commands").FixValue(context, np.zeros(4))
        assert context.num_continuous_states() == (STATE_SIZE if time_period is None else 0)
        values.append([quad.GetOutputPort(name).Eval(context) for name in ("state", "V_WB", "A_WB")])
        assert quad.GetOutputPort("X_WB").Eval(context).translation() == pytest.approx([1.0, 2.0, 5.0])
    for continuous, discrete in zip(*values):
        np.testing.assert_allclose(discrete, continuous, atol=1e-12)


DRAG = QuadrotorParams(rotor_drag_coefficient=8.06428e-5)  # RotorS's


def test_rotor_drag_pulls_against_the_air_relative_velocity_in_the_rotor_plane():
    R_WB = RotationMatrix(RollPitchYaw(0.3, -0.2, 0.7))
    speeds = np.array([470.0, 490.0, 480.0, 475.0])
    state = quadrotor_state(p_WB=[0.0, 0.0, 5.0], R_WB=R_WB, v_WB=[2.0, -1.0, 0.5], rotor_speeds=speeds)
    wind = np.array([-1.0, 0.5, 3.0])
    still = quadrotor_state_derivative(state, speeds, PARAMS)[V_WB]
    dragged = quadrotor_state_derivative(state, speeds, DRAG, wind)[V_WB]
    # By hand: the air-relative velocity in B, its z part dropped, times -k_rd (sum of rotor speeds) / m.
    R = R_WB.matrix()
    v_B = R.T @ (state[V_WB] - wind)
    expected = R @ (-8.06428e-5 * speeds.sum() * np.array([v_B[0], v_B[1], 0.0])) / DRAG.mass_kg
    np.testing.assert_allclose(dragged - still, expected, atol=1e-12)
    assert np.linalg.norm(expected) > 0.1  # m/s^2: large enough to mean something
    # Air along the body's z axis does not act; still air pulls on the UAV's own velocity.
    along_z = state[V_WB] - R[:, 2]
    np.testing.assert_allclose(quadrotor_state_derivative(state, speeds, DRAG, along_z)[V_WB], still, atol=1e-12)
    assert not np.allclose(quadrotor_state_derivative(state, speeds, DRAG)[V_WB], still)


@pytest.mark.parametrize("time_period", [None, 0.005])
def test_wind_blows_a_hovering_quadrotor_downwind_and_reaches_its_accelerometer(time_period):
    builder = DiagramBuilder()
    quad = builder.AddSystem(Quadrotor(DRAG, time_period, wind=True))
    commands = builder.AddSystem(ConstantVectorSource(np.full(4, DRAG.hover_rotor_speed())))
    wind = builder.AddSystem(ConstantVectorSource([0.0, 5.0, 0.0]))
    builder.Connect(commands.get_output_port(), quad.GetInputPort("rotor_speed_commands"))
    builder.Connect(wind.get_output_port(), quad.GetInputPort("wind_velocity_W"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()
    quad.set_state(root, hover_state(DRAG, [0.0, 0.0, 10.0]))
    context = quad.GetMyContextFromRoot(root)
    # At rest in a 5 m/s wind: the drag's acceleration, k_rd 4 w_hover 5 / m, toward +y.
    a_WB = quad.GetOutputPort("A_WB").Eval(context)[3:]
    expected = 8.06428e-5 * 4 * DRAG.hover_rotor_speed() * 5.0 / DRAG.mass_kg
    np.testing.assert_allclose(a_WB, [0.0, expected, 0.0], atol=1e-9)
    simulator.AdvanceTo(1.0)
    state = quad.GetOutputPort("state").Eval(context)
    assert 0.0 < state[V_WB][1] < 5.0 and abs(state[V_WB][0]) < 1e-9  # carried downwind, slower than the air
