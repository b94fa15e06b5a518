"""`FederatedFilterSystem` in a small diagram (no rendering): the same numbers as the engine's
`step` run by hand, the step of t seen at t, and the pattern put in the world through X_WB."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.federated.engine import NODES, X_PB, FederatedConfig, FederatedState, NodeStats, step
from systems.estimators.federated.local_filter import LocalState, exp_so3, log_so3
from systems.estimators.federated.system import (
    FED_LOCAL_P,
    FED_LOCAL_THETA,
    FED_LOCAL_TRACES,
    FED_P_PB,
    FED_Q_PB,
    FED_RELATIVE_STD,
    FED_STARTED,
    FED_V_PB,
    FED_VALID,
    FederatedFilterSystem,
)
from systems.perception.rqrlp.measurements import approach_measurement

G = 9.81
X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.0, 0.0, -0.04])
X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, 0.4), [1.0, 2.0, 5.0])
IMU = np.array([0.0, 0.0, G, 0.0, 0.0, 0.0])  # at rest, level
P_CP = np.array([0.1, -0.2, 4.9])
IMU_PERIOD, CAMERA_PERIOD = 0.005, 0.02


def _diagram():
    builder = DiagramBuilder()
    federated = builder.AddSystem(FederatedFilterSystem(FederatedConfig(), X_BC, IMU_PERIOD, CAMERA_PERIOD))
    builder.Connect(builder.AddSystem(ConstantVectorSource(IMU)).get_output_port(), federated.GetInputPort("imu"))
    measurement = approach_measurement(P_CP, 80.0, 0.0, 640.0)
    for node in NODES:
        value = [measurement] if node == "approach" else []
        builder.Connect(builder.AddSystem(ConstantValueSource(AbstractValue.Make(value))).get_output_port(),
                        federated.GetInputPort(node))
    builder.Connect(builder.AddSystem(ConstantValueSource(AbstractValue.Make(X_WB))).get_output_port(),
                    federated.GetInputPort("X_WB"))
    builder.Connect(builder.AddSystem(ConstantVectorSource(np.zeros(6))).get_output_port(),
                    federated.GetInputPort("V_WB"))
    return builder.Build(), federated, measurement


def test_the_system_gives_the_engines_numbers_and_puts_the_pattern_in_the_world():
    diagram, federated, measurement = _diagram()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.1)
    context = federated.GetMyContextFromRoot(simulator.get_context())
    state = FederatedState()
    for k in range(21):  # t = 0 ... 0.1 s; a frame every 4 IMU steps
        t = k * IMU_PERIOD
        frame = {"approach": measurement} if k % 4 == 0 else None
        state = step(state, t, IMU, frame, FederatedConfig(), X_BC)
    X_PB_system = federated.GetOutputPort("X_PB_estimate").Eval(context)
    np.testing.assert_allclose(X_PB_system.X_RT.GetAsMatrix34(), X_PB(state.fused).GetAsMatrix34(), atol=1e-12)
    X_WP = federated.GetOutputPort("X_WP_estimate").Eval(context)
    assert X_WP.valid and X_WP.frames == "X_WP"
    p_WP = X_WB.multiply(X_BC.multiply(P_CP))  # the measured centre, in the world
    np.testing.assert_allclose(X_WP.X_RT.translation(), p_WP, atol=2e-3)
    assert X_WP.covariance[2, 2] > np.pi**2  # no full pose yet: the pattern's heading is unknown
    np.testing.assert_allclose(federated.GetOutputPort("v_WP_estimate").Eval(context), 0.0, atol=0.05)
    vector = federated.GetOutputPort("federated_vector").Eval(context)
    assert vector[FED_VALID] == 1.0 and vector[FED_STARTED] == 1.0


def test_a_frame_is_in_the_output_at_its_own_time():
    diagram, federated, _ = _diagram()
    context = diagram.CreateDefaultContext()
    federated_context = federated.GetMyContextFromRoot(context)
    assert federated.GetOutputPort("X_WP_estimate").Eval(federated_context).valid  # t = 0's frame, no event run
    context.SetTime(0.005)  # an IMU step that is no camera frame, from the same unstepped state
    assert not federated.GetOutputPort("X_WP_estimate").Eval(federated_context).valid


def test_the_camera_period_must_be_whole_imu_periods():
    with pytest.raises(ConfigError,
                       match=r"federated\.camera\.rate_hz \(80\) must divide federated\.imu\.rate_hz \(200\)"):
        FederatedFilterSystem(FederatedConfig(), X_BC, 0.005, 0.0125)


def test_a_camera_at_the_imus_rate_is_accepted_and_one_faster_is_refused():
    """Camera and IMU at 50 Hz (a ratio of one IMU period per frame) is a valid system; a camera at 200 Hz
    over a 50 Hz IMU (a quarter of an IMU period, no whole number of steps) is not."""
    FederatedFilterSystem(FederatedConfig(), X_BC, 0.02, 0.02)
    with pytest.raises(ConfigError,
                       match=r"federated\.camera\.rate_hz \(200\) must divide federated\.imu\.rate_hz \(50\)"):
        FederatedFilterSystem(FederatedConfig(), X_BC, 0.02, 0.005)


@pytest.mark.parametrize("override, periods", [("federated.imu.rate_hz=70.0", (1 / 70, CAMERA_PERIOD)),
                                               ("federated.filter.max_coast_s=0.02", (IMU_PERIOD, CAMERA_PERIOD))])
def test_the_scenario_and_the_system_refuse_the_camera_steps_in_the_same_words(override, periods):
    """One check (require_camera_steps) for the scenario's rates and the system's periods: they had each their
    own, in other words."""
    with pytest.raises(ConfigError) as loaded:
        load_scenario("open-landing", overrides=[override])
    coast = FederatedConfig(max_coast_s=0.02) if "max_coast_s" in override else FederatedConfig()
    with pytest.raises(ConfigError) as built:
        FederatedFilterSystem(coast, X_BC, *periods)
    assert str(built.value) == str(loaded.value)


def test_before_a_full_pose_X_PB_claims_no_heading_and_the_position_it_turns():
    # The pattern turned 40 deg about its normal: the approaching node's centre cannot say so, and the
    # filters start from a gauge heading; the estimate must claim none, in its yaw and in p_PB.
    X_PB_true = RigidTransform(RollPitchYaw(0.0, 0.0, np.radians(40.0)), [0.5, -0.3, 4.9])
    p_CP = X_BC.inverse().multiply(X_PB_true.inverse()).translation()
    federated = FederatedFilterSystem(FederatedConfig(), X_BC, IMU_PERIOD, CAMERA_PERIOD)
    context = federated.CreateDefaultContext()
    federated.GetInputPort("imu").FixValue(context, IMU)
    federated.GetInputPort("approach").FixValue(context, [approach_measurement(p_CP, 80.0, 0.0, 640.0)])
    for node in ("adjustment", "touchdown"):
        federated.GetInputPort(node).FixValue(context, [])
    federated.GetInputPort("X_WB").FixValue(context, X_WB)
    federated.GetInputPort("V_WB").FixValue(context, np.zeros(6))
    estimate = federated.GetOutputPort("X_PB_estimate").Eval(context)
    assert estimate.valid
    yaw_std = np.sqrt(estimate.covariance[2, 2])
    assert yaw_std >= np.radians(90.0)
    yaw_error = log_so3(estimate.X_PB.rotation().matrix() @ X_PB_true.rotation().matrix().T)[2]
    assert abs(yaw_error) > np.radians(30.0)  # the gauge is off the truth ...
    error = estimate.X_PB.translation() - X_PB_true.translation()
    error[2] = 0.0
    assert np.linalg.norm(error) > 0.2  # ... and turns the horizontal position with it
    position_covariance = estimate.covariance[3:6, 3:6]
    assert np.sqrt(error @ position_covariance @ error) / np.linalg.norm(error) > np.linalg.norm(error)
    p = estimate.X_PB.translation()
    across = np.array([-p[1], p[0], 0.0]) / np.linalg.norm(p[:2])  # the direction a heading turns p_PB
    assert np.sqrt(across @ position_covariance @ across) >= np.radians(90.0) * np.linalg.norm(p[:2])


@pytest.mark.parametrize("max_coast_s", [0.02, 0.01])
def test_max_coast_must_exceed_the_camera_period(max_coast_s):
    # At or below the period every frame finds the filters lost and restarts them from one measurement.
    with pytest.raises(ConfigError, match=rf"max_coast_s \({max_coast_s:g} s\) must exceed the camera's period "
                                          r"\(0\.02 s\)"):
        load_scenario("open-landing", overrides=[f"federated.filter.max_coast_s={max_coast_s}"])
    with pytest.raises(ConfigError, match=rf"max_coast_s \({max_coast_s:g} s\) must exceed the camera's period "
                                          r"\(0\.02 s\)"):
        FederatedFilterSystem(FederatedConfig(max_coast_s=max_coast_s), X_BC, IMU_PERIOD, CAMERA_PERIOD)
    FederatedFilterSystem(FederatedConfig(max_coast_s=0.03), X_BC, IMU_PERIOD, CAMERA_PERIOD)
    load_scenario("open-landing", overrides=["federated.filter.max_coast_s=0.03"])


def _random_covariance(rng, n=9):
    A = rng.normal(scale=0.03, size=(n, n))
    return A @ A.T + 1e-4 * np.eye(n)


def _system_at(fused, heading_known, local_estimates, V_WB):
    """The system's context at t = 0.1 s holding a fused estimate set by hand (its step of t already taken, so
    the outputs read it as it is)."""
    t = 0.1
    federated = FederatedFilterSystem(FederatedConfig(), X_BC, IMU_PERIOD, CAMERA_PERIOD)
    context = federated.CreateDefaultContext()
    context.SetTime(t)
    state = FederatedState(time=t, fused=fused, filters=local_estimates, local_estimates=local_estimates,
                           stats=(NodeStats(1, 0, t), NodeStats(), NodeStats()), heading_known=heading_known)
    context.SetAbstractState(0, state)
    federated.GetInputPort("imu").FixValue(context, IMU)
    for node in NODES:
        federated.GetInputPort(node).FixValue(context, [])
    federated.GetInputPort("X_WB").FixValue(context, X_WB)
    federated.GetInputPort("V_WB").FixValue(context, V_WB)
    return federated, context


def _pose_jacobians(fused):
    """d[dtheta; dp] of X_PB (in P) and of X_WP = X_WB X_PB^-1 (in W) over the fused error state [dp, dv, dtheta]
    (attitude errors Exp(dtheta) R_PB), by central differences of Drake's RigidTransform; and the same of a turn
    psi of P about its own z at its origin (the heading gauge)."""
    X_PB_0 = RigidTransform(RotationMatrix(fused.R), fused.p)
    X_WP_0 = X_WB.multiply(X_PB_0.inverse())

    def error(X, X0):
        return np.r_[log_so3(X.rotation().matrix() @ X0.rotation().matrix().T), X.translation() - X0.translation()]

    def poses(dx):
        X = RigidTransform(RotationMatrix(exp_so3(dx[6:9]) @ fused.R), fused.p + dx[0:3])
        return error(X, X_PB_0), error(X_WB.multiply(X.inverse()), X_WP_0)

    def turned(psi):
        X = RigidTransform(RotationMatrix.MakeZRotation(psi).inverse(), np.zeros(3)).multiply(X_PB_0)  # X_P'B
        return error(X, X_PB_0), error(X_WB.multiply(X.inverse()), X_WP_0)

    h = 1e-6
    columns = [[(a - b) / (2 * h) for a, b in zip(poses(h * e), poses(-h * e))] for e in np.eye(9)]
    J_PB, J_WP = (np.column_stack([c[k] for c in columns]) for k in (0, 1))
    g_PB, g_WP = ((a - b) / (2 * h) for a, b in zip(turned(h), turned(-h)))
    return J_PB, J_WP, g_PB, g_WP


@pytest.mark.parametrize("heading_known", [True, False])
def test_the_pose_covariances_are_the_fused_covariance_through_the_poses_jacobians(heading_known):
    """X_PB_estimate's and X_WP_estimate's covariances ([dtheta; dp], in P and in W) against the fused covariance
    propagated through Jacobians of the poses taken by differencing Drake's RigidTransform, a tilted attitude
    and a covariance with every block filled; before a full pose (heading unknown) with pi^2 along a turn of P
    about its own z at its own origin, which is not W's z: P is tilted in W."""
    rng = np.random.default_rng(3)
    R = exp_so3([0.15, -0.1, 0.7])
    fused = LocalState(np.array([0.8, -0.5, 4.0]), np.array([0.2, -0.1, 0.05]), R, _random_covariance(rng))
    federated, context = _system_at(fused, heading_known, (fused,) * len(NODES), np.zeros(6))
    J_PB, J_WP, g_PB, g_WP = _pose_jacobians(fused)
    expected_PB, expected_WP = J_PB @ fused.P @ J_PB.T, J_WP @ fused.P @ J_WP.T
    if not heading_known:
        expected_PB = expected_PB + np.pi**2 * np.outer(g_PB, g_PB)
        expected_WP = expected_WP + np.pi**2 * np.outer(g_WP, g_WP)
    X_PB_estimate = federated.GetOutputPort("X_PB_estimate").Eval(context)
    X_WP_estimate = federated.GetOutputPort("X_WP_estimate").Eval(context)
    assert X_PB_estimate.valid and X_WP_estimate.valid
    np.testing.assert_allclose(X_PB_estimate.covariance, expected_PB, atol=1e-8)
    np.testing.assert_allclose(X_WP_estimate.covariance, expected_WP, atol=1e-8)


def test_the_patterns_velocity_is_the_bodys_less_the_bodys_relative_to_the_pattern():
    """v_WP_estimate: p_WB = p_WP + R_WP p_PB with the pattern not turning, so v_WP = v_WB - R_WP v_PB, for a
    body moving relative to the pattern (v_PB not zero) and in the world."""
    rng = np.random.default_rng(4)
    fused = LocalState(np.array([0.8, -0.5, 4.0]), np.array([0.6, -0.4, 0.2]), exp_so3([0.1, -0.05, 0.9]),
                       _random_covariance(rng))
    V_WB = np.array([0.0, 0.0, 0.1, 1.5, -0.7, 0.3])  # [w; v] in W
    federated, context = _system_at(fused, True, (fused,) * len(NODES), V_WB)
    R_WP = X_WB.multiply(RigidTransform(RotationMatrix(fused.R), fused.p).inverse()).rotation().matrix()
    np.testing.assert_allclose(federated.GetOutputPort("v_WP_estimate").Eval(context), V_WB[3:] - R_WP @ fused.v,
                               atol=1e-12)


def test_the_vector_logs_the_trace_of_each_local_filters_position_covariance():
    """federated_vector's FED_LOCAL_TRACES: the trace of each local filter's position block (m^2), as its
    layout says, not of its whole covariance."""
    rng = np.random.default_rng(5)
    locals_ = tuple(LocalState(np.array([0.0, 0.0, 4.0]), np.zeros(3), np.eye(3), _random_covariance(rng))
                    for _ in NODES)
    federated, context = _system_at(locals_[0], True, locals_, np.zeros(6))
    vector = federated.GetOutputPort("federated_vector").Eval(context)
    np.testing.assert_allclose(vector[FED_LOCAL_TRACES], [np.trace(s.P[0:3, 0:3]) for s in locals_], rtol=1e-12)


def test_before_any_measurement_every_output_says_there_is_nothing_yet():
    """No node has measured (the pattern never seen): both poses invalid, stamped with the time, in their frames, the
    pattern's velocity zeros (never NaN), the vector's valid and started flags 0 and the rest NaN."""
    federated = FederatedFilterSystem(FederatedConfig(), X_BC, IMU_PERIOD, CAMERA_PERIOD)
    context = federated.CreateDefaultContext()
    context.SetTime(0.1)
    federated.GetInputPort("imu").FixValue(context, IMU)
    for node in NODES:
        federated.GetInputPort(node).FixValue(context, [])
    federated.GetInputPort("X_WB").FixValue(context, X_WB)
    federated.GetInputPort("V_WB").FixValue(context, np.r_[0.0, 0.0, 0.0, 1.0, 2.0, 3.0])
    for port, frames in (("X_PB_estimate", ("P", "B")), ("X_WP_estimate", ("W", "P"))):
        estimate = federated.GetOutputPort(port).Eval(context)
        assert not estimate.valid and (estimate.reference, estimate.target) == frames and estimate.time == 0.1
    np.testing.assert_array_equal(federated.GetOutputPort("v_WP_estimate").Eval(context), np.zeros(3))
    vector = federated.GetOutputPort("federated_vector").Eval(context)
    assert vector[FED_VALID] == 0.0 and vector[FED_STARTED] == 0.0
    assert np.isnan(np.delete(vector, [FED_VALID, FED_STARTED])).all()


@pytest.mark.parametrize("P_scale, valid", [(0.01, True), (1.0, False)])
def test_a_started_estimate_too_uncertain_is_invalid_in_every_output(P_scale, valid):
    """Started, a node measured at t (the coast limit is not the reason), P = P_scale I: p_BP_B = -R^T p's
    covariance is P_scale (I + R^T [p]x [p]x^T R), whose trace is P_scale (3 + 2 |p|^2), so its std is
    0.61 m (within FederatedConfig's 1 m: valid) or 6.07 m (over it: invalid). X_PB_estimate, X_WP_estimate and
    the vector's FED_VALID all say so, the vector's FED_STARTED 1 either way."""
    p = np.array([0.8, -0.5, 4.0])
    fused = LocalState(p, np.zeros(3), exp_so3([0.15, -0.1, 0.7]), P_scale * np.eye(9))
    expected_std = np.sqrt(P_scale * (3.0 + 2.0 * p @ p))
    assert (expected_std <= FederatedConfig().max_relative_std_m) == valid
    federated, context = _system_at(fused, True, (fused,) * len(NODES), np.zeros(6))
    assert federated.GetOutputPort("X_PB_estimate").Eval(context).valid == valid
    assert federated.GetOutputPort("X_WP_estimate").Eval(context).valid == valid
    vector = federated.GetOutputPort("federated_vector").Eval(context)
    assert vector[FED_RELATIVE_STD] == pytest.approx(expected_std, rel=1e-12)
    assert vector[FED_VALID] == float(valid) and vector[FED_STARTED] == 1.0


def test_the_vector_logs_the_fused_estimate_and_each_local_filters_pose_in_its_slots():
    """federated_vector's layout with three distinct local filters and a fused estimate unlike any: p_PB and v_PB
    (m, m/s, in P), q_PB (wxyz: [cos(|theta|/2), sin(|theta|/2) theta/|theta|] of its rotation vector theta),
    each filter's p_PB and its R_PB as the rotation vector it was made from (|theta| < pi, so the log returns it)
    in NODES' order, what diagrams/federated_metrics.py scores the filters from."""
    rng = np.random.default_rng(6)
    positions = [[0.7, -0.4, 4.1], [0.9, -0.6, 3.9], [-0.2, 0.3, 5.0]]
    thetas = [[0.0, 0.2, -0.3], [-0.1, 0.0, 1.2], [0.5, -0.4, 0.1]]
    locals_ = tuple(LocalState(np.array(p), np.array([0.1, 0.0, -0.2]), exp_so3(theta), _random_covariance(rng))
                    for p, theta in zip(positions, thetas))
    theta = np.array([0.15, -0.1, 0.7])
    fused = LocalState(np.array([0.8, -0.5, 4.0]), np.array([0.2, -0.1, 0.05]), exp_so3(theta),
                       _random_covariance(rng))
    federated, context = _system_at(fused, True, locals_, np.zeros(6))
    vector = federated.GetOutputPort("federated_vector").Eval(context)
    np.testing.assert_allclose(vector[FED_P_PB], [0.8, -0.5, 4.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(vector[FED_V_PB], [0.2, -0.1, 0.05], rtol=0, atol=1e-12)
    angle = np.linalg.norm(theta)
    np.testing.assert_allclose(vector[FED_Q_PB], np.r_[np.cos(angle / 2), np.sin(angle / 2) * theta / angle],
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(vector[FED_LOCAL_P], np.concatenate(positions), rtol=0, atol=1e-12)
    np.testing.assert_allclose(vector[FED_LOCAL_THETA], np.concatenate(thetas), rtol=0, atol=1e-12)
