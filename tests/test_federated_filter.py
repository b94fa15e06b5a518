"""Seed 001's federated EKF (systems/estimators/federated): the local filters against analytic
motion, the fusion against a centralised Kalman filter (Carlson's equivalence), and the engine on a
synthetic flight against its truth."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from systems.config import ConfigError
from systems.estimators.federated.engine import (
    NODES,
    X_PB,
    FederatedConfig,
    FederatedState,
    NodeStats,
    is_valid,
    relative_jacobian,
    relative_std_m,
    step,
)
from systems.estimators.federated.fusion import MIN_BETA, fuse, reset
from systems.estimators.federated.local_filter import (
    LocalFilterConfig,
    LocalState,
    centre_in_body,
    exp_so3,
    initial_state,
    initial_velocity_covariance,
    log_so3,
    predict,
    update_centre_in_camera,
    update_pattern_in_camera,
    update_pose,
)
from systems.noise import van_loan_discretisation
from systems.perception.rqrlp.measurements import (
    NodeMeasurement,
    PatternView,
    adjustment_measurement,
    approach_covariance,
    body_pose_covariance,
)
from systems.perception.rqrlp.nodes import layout_corners
from systems.perception.rqrlp.pattern import RqrlpLayout

G = 9.81
X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.0, 0.0, -0.04])
K = np.array([[1280.0, 0.0, 948.9], [0.0, 1280.0, 543.2], [0.0, 0.0, 1.0]])  # the adjustment node's camera


def _state(p, P_scale=0.01):
    return LocalState(np.asarray(p, dtype=float), np.zeros(3), np.eye(3), np.eye(9) * P_scale)


def test_prediction_integrates_a_constant_acceleration_exactly():
    config = LocalFilterConfig()
    a = np.array([0.3, -0.2, 0.5])
    state = replace(_state([1.0, 2.0, 3.0]), v=np.array([0.5, 0.0, -1.0]))
    for _ in range(100):  # 1 s at 100 Hz, level, not turning: f_B = a - g
        state = predict(state, a + [0.0, 0.0, G], np.zeros(3), 0.01, config, G)
    np.testing.assert_allclose(state.p, [1.0, 2.0, 3.0] + np.array([0.5, 0.0, -1.0]) + a / 2, atol=1e-12)
    np.testing.assert_allclose(state.v, [0.5, 0.0, -1.0] + a, atol=1e-12)
    assert np.all(np.diag(state.P)[0:6] > 0.01)  # the covariance grew


def test_prediction_turns_with_the_gyroscope():
    state = predict(_state([0, 0, 0]), np.array([0.0, 0.0, G]), np.array([0.0, 0.0, 0.5]), 2.0, LocalFilterConfig(), G)
    np.testing.assert_allclose(log_so3(state.R), [0.0, 0.0, 1.0], atol=1e-12)


def test_fusion_of_equal_filters_is_their_mean_and_the_betas_are_equal():
    """Two filters as certain (P = 0.01 I): the fused position and velocity are their means (the first filter,
    the reference, moving at 1 m/s and the second still: 0.5 m/s), P halved, the shares equal."""
    a, b = replace(_state([1.0, 0.0, 2.0]), v=np.array([1.0, 0.0, 0.0])), _state([1.2, 0.4, 2.0])
    fused, betas = fuse([a, b])
    np.testing.assert_allclose(fused.p, [1.1, 0.2, 2.0], atol=1e-12)
    np.testing.assert_allclose(fused.v, [0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(fused.P, a.P / 2, atol=1e-12)
    np.testing.assert_allclose(betas, [0.5, 0.5])


def test_fusion_of_two_equally_certain_attitudes_is_their_geodesic_midpoint():
    """Two filters as sure of themselves, 60 deg apart about an axis across the first's tilt: the fused attitude
    is SciPy's Slerp halfway (the error vector's frame and the way it is applied back must agree)."""
    R1 = Rotation.from_euler("x", 40, degrees=True)
    R2 = Rotation.from_euler("z", 60, degrees=True) * R1
    states = [LocalState(np.zeros(3), np.zeros(3), R.as_matrix(), np.eye(9) * 0.01) for R in (R1, R2)]
    fused, _ = fuse(states)
    halfway = Slerp([0.0, 1.0], Rotation.concatenate([R1, R2]))(0.5)
    assert np.degrees((Rotation.from_matrix(fused.R) * halfway.inv()).magnitude()) < 1e-6


def test_the_betas_sum_to_one_with_a_floor_for_a_filter_that_knows_nothing():
    """Eq. (9)'s shares: a filter 1e9 times less certain than the other keeps its floor, MIN_BETA before the
    shares are normalised again (its process noise stays finite), and the shares still sum to 1."""
    _, betas = fuse([_state([0.0, 0.0, 1.0], 1e-3), _state([0.0, 0.0, 1.0], 1e6)])
    assert betas.sum() == pytest.approx(1.0, abs=1e-12)
    assert betas[1] == pytest.approx(MIN_BETA / (1 + MIN_BETA), rel=1e-6)


def test_the_prediction_adds_the_exact_process_noise_of_a_white_acceleration():
    """From a certain state, one step's covariance is Q: over position and velocity the Van Loan discretisation
    (systems/noise.py) of p'' = white acceleration of accel_noise_psd, cross terms included."""
    config, dt = LocalFilterConfig(), 0.01
    state = LocalState(np.zeros(3), np.zeros(3), np.eye(3), np.zeros((9, 9)))
    Q = predict(state, np.array([0.0, 0.0, G]), np.zeros(3), dt, config, G).P
    A, BBt = np.zeros((6, 6)), np.zeros((6, 6))
    A[0:3, 3:6] = np.eye(3)
    BBt[3:6, 3:6] = config.accel_noise_psd * np.eye(3)
    _, G_step = van_loan_discretisation(A * dt, BBt * dt)
    np.testing.assert_allclose(Q[0:6, 0:6], G_step @ G_step.T, rtol=1e-6, atol=1e-15)


def test_fusion_with_reset_equals_the_centralised_filter():
    """Carlson's federated filter with the information-sharing reset gives the centralised filter's
    estimate: two nodes' pose measurements on their own filters, fused, against one filter that
    takes both."""
    config = LocalFilterConfig(gate_probability=1 - 1e-12)
    rng = np.random.default_rng(3)
    A = rng.standard_normal((9, 9))
    start = LocalState(np.array([0.5, -0.3, 4.0]), np.array([0.1, 0.0, -0.5]), np.eye(3), A @ A.T * 0.01 + np.eye(9) * 0.01)
    shared = reset([start, start], start, np.array([0.3, 0.7]))
    z = [(np.array([0.6, -0.25, 3.9]), RollPitchYaw(0.01, -0.02, 0.03).ToRotationMatrix().matrix(), np.eye(6) * 0.02),
         (np.array([0.55, -0.35, 4.05]), RollPitchYaw(-0.01, 0.01, 0.02).ToRotationMatrix().matrix(), np.eye(6) * 0.05)]
    locals_ = [update_pose(s, *m, config) for s, m in zip(shared, z)]
    fused, _ = fuse(locals_)
    central = update_pose(update_pose(start, *z[0], config), *z[1], config)
    np.testing.assert_allclose(fused.p, central.p, atol=2e-3)  # to first order (the attitude's linearisation)
    np.testing.assert_allclose(np.trace(fused.P), np.trace(central.P), rtol=1e-2)
    assert np.trace(fused.P) < min(np.trace(s.P) for s in locals_)


def test_the_gate_rejects_a_ten_sigma_pose():
    state = _state([0.0, 0.0, 5.0])
    far = update_pose(state, np.array([0.0, 0.0, 6.0]), np.eye(3), np.eye(6) * 1e-4, LocalFilterConfig())
    assert far.gated == 1 and far.accepted == 0
    np.testing.assert_array_equal(far.p, state.p)


def test_the_gate_takes_the_chi_square_quantile_of_all_six_degrees_of_freedom_of_a_pose():
    """A full pose's innovation has 6 components: a position error whose NIS lies just under
    chi2.ppf(gate_probability, 6) is accepted, just over it gated (a quantile of 3 dof, 21.1 at 0.9999 against
    27.9, gated poses that pass)."""
    config = LocalFilterConfig()
    state = _state([0.0, 0.0, 5.0])
    threshold = chi2.ppf(config.gate_probability, 6)
    noise = np.eye(6) * 1e-4
    for ratio, accepted in ((0.98, 1), (1.02, 0)):
        dz = np.sqrt(ratio * threshold * (state.P[2, 2] + noise[5, 5]))  # NIS = dz^2 / S_zz
        after = update_pose(state, np.array([0.0, 0.0, 5.0 + dz]), np.eye(3), noise, config)
        assert (after.accepted, after.gated) == (accepted, 1 - accepted)


def test_a_tight_pose_brings_a_turned_filter_onto_its_attitude():
    """update_pose's attitude innovation in P, as its Jacobian and the update take it (R = Exp(dtheta) R):
    a filter yawed 90 deg, a pose turned 0.1 rad about P's x from it and measured tightly, lands on the pose's
    attitude (the innovation taken in B, R^T R_PB, turns it about P's y instead: 8 deg off)."""
    R0 = exp_so3([0.0, 0.0, np.pi / 2])
    R_measured = exp_so3([0.1, 0.0, 0.0]) @ R0
    state = LocalState(np.array([0.0, 0.0, 5.0]), np.zeros(3), R0, np.eye(9) * 0.01)
    after = update_pose(state, state.p, R_measured, np.eye(6) * 1e-10, LocalFilterConfig())
    assert after.accepted == 1
    np.testing.assert_allclose(log_so3(R_measured @ after.R.T), 0.0, atol=1e-6)


def test_a_poses_covariance_over_attitude_then_position_weighs_each_part_of_the_error_state():
    """update_pose's covariance is over [dtheta, dp] (the nodes' order), the error state's [dp, dv, dtheta]: from
    P = 0.01 I, attitude noise 1e-4 and position noise 4e-4 make independent scalar updates, the position's variance
    0.01 * 4e-4 / 0.0104 and the attitude's 0.01 * 1e-4 / 0.0101, a 0.1 m innovation in x moving p by the gain
    0.01 / 0.0104; the velocity, unmeasured and uncorrelated, keeps its 0.01."""
    state = _state([0.0, 0.0, 5.0])
    after = update_pose(state, np.array([0.1, 0.0, 5.0]), np.eye(3), np.diag([1e-4] * 3 + [4e-4] * 3),
                        LocalFilterConfig())
    assert after.accepted == 1
    expected = np.diag([0.01 * 4e-4 / 0.0104] * 3 + [0.01] * 3 + [0.01 * 1e-4 / 0.0101] * 3)
    np.testing.assert_allclose(after.P, expected, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(after.p, [0.1 * 0.01 / 0.0104, 0.0, 5.0], rtol=1e-9, atol=1e-15)


def test_a_started_filter_takes_its_velocity_covariance_from_the_horizontal_and_vertical_stds():
    """The velocity's initial covariance in P (z up): the horizontal std on x and y, the vertical on z, as the
    config names them, in initial_velocity_covariance and in a filter started from the centre."""
    config = LocalFilterConfig(initial_velocity_std_mps=0.7, initial_vertical_velocity_std_mps=0.3)
    expected = np.diag([0.7**2, 0.7**2, 0.3**2])
    np.testing.assert_allclose(initial_velocity_covariance(config), expected, rtol=1e-12)
    state = initial_state(np.array([0.4, -0.3, -15.0]), 0.01 * np.eye(3), np.array([0.0, 0.0, G]), config)
    np.testing.assert_allclose(state.P[3:6, 3:6], expected, rtol=1e-12)


def test_a_local_filter_gates_a_non_finite_measurement():
    """A NaN centre or pose into a started local filter: its NIS is NaN, which the gate rejects (gated + 1), the
    state unchanged and finite rather than NaN from the update."""
    config = LocalFilterConfig()
    state = initial_state(np.array([0.0, 0.0, -5.0]), 0.01 * np.eye(3), np.array([0.0, 0.0, G]), config)
    for after in (update_centre_in_camera(state, np.array([np.nan, 0.0, 5.0]), 0.01 * np.eye(3), np.eye(3),
                                          np.zeros(3), config),
                  update_pose(state, np.array([0.0, np.nan, -5.0]), np.eye(3), np.eye(6) * 1e-4, config)):
        assert after.gated == state.gated + 1 and after.accepted == state.accepted
        np.testing.assert_array_equal(after.p, state.p)
        np.testing.assert_array_equal(after.P, state.P)


def test_a_start_from_the_centre_alone_knows_the_relative_position_whatever_the_heading():
    config = LocalFilterConfig()
    state = initial_state(np.array([0.4, -0.3, -15.0]), 0.01 * np.eye(3), np.array([0.0, 0.0, G]), config)
    assert relative_std_m(state) == pytest.approx(0.1 * np.sqrt(3), rel=1e-9)
    # yet p_PB's horizontal position is uncertain with the attitude, over the 15 m lever arm:
    # x = -(R p_BP_B)_x moves by 15 m per radian of pitch and 0.3 m per radian of heading
    tilt, yaw = np.radians(config.initial_tilt_std_deg), np.radians(config.initial_yaw_std_deg)
    assert state.P[0, 0] == pytest.approx(0.1**2 + (15.0 * tilt) ** 2 + (0.3 * yaw) ** 2, rel=1e-9)


def test_a_start_on_a_tilted_body_levels_it_with_the_accelerometer_and_puts_the_pattern_where_it_was_seen():
    """Rolled by a = 0.2 rad, the hovering body's accelerometer reads f_B = g [0, sin a, cos a]: R_PB is the
    shortest rotation taking that direction to P's z, a turn by +a about x (axis f_B x z along +x); p_PB = -R_PB
    p_BP_B, so that the centre the state predicts in the body is the one measured (a transposed R, or a p turned
    by R_PB^T, level a body tilted the other way or move the pattern)."""
    a = 0.2
    f_B = G * np.array([0.0, np.sin(a), np.cos(a)])
    p_BP_B = np.array([0.4, -0.3, -15.0])
    state = initial_state(p_BP_B, 0.01 * np.eye(3), f_B, LocalFilterConfig())
    R_x = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    np.testing.assert_allclose(R_x, RotationMatrix.MakeXRotation(a).matrix(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(state.R, R_x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(state.R @ f_B / G, [0.0, 0.0, 1.0], rtol=0, atol=1e-12)
    # -R_x p_BP_B: x kept, y = -(cos a (-0.3) - sin a (-15)), z = -(sin a (-0.3) + cos a (-15))
    expected_p = [-0.4, 0.3 * np.cos(a) - 15.0 * np.sin(a), 0.3 * np.sin(a) + 15.0 * np.cos(a)]
    np.testing.assert_allclose(state.p, expected_p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(centre_in_body(state)[0], p_BP_B, rtol=0, atol=1e-12)


@pytest.mark.parametrize("refused, accepted", [(0.0, 1e-9), (1.0, 1 - 1e-9)])
def test_a_gate_probability_outside_the_open_unit_interval_is_refused(refused, accepted):
    """chi2.ppf(1, k) is infinite (a gate that rejects nothing) and chi2.ppf(0, k) zero (one that rejects
    everything): either end is a ConfigError naming the field, while a probability just inside is accepted."""
    assert chi2.ppf(1.0, 6) == np.inf and chi2.ppf(0.0, 6) == 0.0
    with pytest.raises(ConfigError, match=r"federated\.gate_probability must be in \(0, 1\)"):
        LocalFilterConfig(gate_probability=refused).validate()
    LocalFilterConfig(gate_probability=accepted).validate()


@pytest.mark.parametrize("name", ["accel_noise_psd", "gyro_noise_psd", "initial_velocity_std_mps",
                                  "initial_vertical_velocity_std_mps", "initial_tilt_std_deg", "initial_yaw_std_deg",
                                  "max_coast_s", "max_relative_std_m", "gravity_m_s2"])
def test_every_noise_density_std_and_bound_must_be_positive(name):
    """Each positive field of the local filters' config (LocalFilterConfig) and of the engine's (FederatedConfig)
    at 0: a ConfigError naming it, while the defaults pass."""
    FederatedConfig().validate()
    with pytest.raises(ConfigError, match=rf"federated\.{name} must be positive, got 0"):
        replace(FederatedConfig(), **{name: 0.0}).validate()


def _truth(t):
    """A descent with a sideways sway and a turn: p_PB(t) [m], v, a, R_PB(t) (yaw 0.2 t + 0.5)."""
    p = np.array([0.5 * np.sin(0.5 * t), 0.3 * t - 1.0, 8.0 - 0.5 * t])
    v = np.array([0.25 * np.cos(0.5 * t), 0.3, -0.5])
    a = np.array([-0.125 * np.sin(0.5 * t), 0.0, 0.0])
    return p, v, a, RollPitchYaw(0.0, 0.0, 0.2 * t + 0.5).ToRotationMatrix()


def _descent(duration_s, measurements, config: FederatedConfig | None = None):
    """The engine at 200 Hz on _truth's descent with an ideal IMU, and at 50 Hz the frame
    `measurements(t, p, R, X_CP)` gives (a dict of NodeMeasurement by node). Yields (t, the state before the
    step, the state after it, the true p_PB, v_PB and R_PB, whether the step read a frame)."""
    config, state = config or FederatedConfig(), FederatedState()
    for k in range(int(duration_s * 200) + 1):
        t = k / 200
        p, v, a, R = _truth(t)
        imu = np.r_[R.inverse().multiply(a + [0.0, 0.0, G]), [0.0, 0.0, 0.2]]
        frame = measurements(t, p, R, X_BC.inverse().multiply(RigidTransform(R, p).inverse())) if k % 4 == 0 else None
        before, state = state, step(state, t, imu, frame, config, X_BC)
        yield t, before, state, (p, v, R), frame is not None


def _fly(duration_s, nodes_until_s, rng, adjustment_gap_s=(0.0, 0.0)):
    """_descent with, until `nodes_until_s`, an approach centre (always) and an adjustment pose (4 mm, 5 mrad;
    from 1 s, not within adjustment_gap_s), with the noise their covariances say. Returns (final state, errors,
    valid flags, config, betas per frame)."""
    def measurements(t, p, R, X_CP):
        frame = {}
        if t <= nodes_until_s:
            covariance = approach_covariance(X_CP.translation(), 60.0, 640.0)
            frame["approach"] = NodeMeasurement(t, "approach", covariance,
                                                p_CP=rng.multivariate_normal(X_CP.translation(), covariance))
            if t >= 1.0 and not adjustment_gap_s[0] <= t < adjustment_gap_s[1]:
                noisy = RigidTransform(RollPitchYaw(*rng.normal(0, 0.005, 3)).ToRotationMatrix().multiply(R),
                                       p + rng.normal(0, 0.004, 3))
                frame["adjustment"] = NodeMeasurement(t, "adjustment", np.diag([2.5e-5] * 3 + [1.6e-5] * 3),
                                                      X_PB=noisy)
        return frame

    config = FederatedConfig()
    errors, valid, betas = [], [], []
    for t, _, state, (p, _, R), framed in _descent(duration_s, measurements, config):
        if framed:
            betas.append((t, *state.betas))
        if state.started:
            errors.append(np.r_[X_PB(state.fused).translation() - p,
                                log_so3(X_PB(state.fused).rotation().matrix() @ R.matrix().T)])
            valid.append(is_valid(state, config))
    return state, np.array(errors), np.array(valid), config, np.array(betas)


def test_the_engine_tracks_a_synthetic_flight_and_weighs_the_better_node():
    state, errors, valid, _, _ = _fly(6.0, 6.0, np.random.default_rng(1))
    late = errors[-200:]
    assert np.sqrt(np.mean(late[:, :3] ** 2)) < 0.004  # m, better than the 4 mm poses alone
    assert np.abs(late[:, 3:]).max() < 0.005  # rad: the heading found from the full poses
    assert valid.all()
    assert state.betas[NODES.index("adjustment")] > state.betas[NODES.index("approach")]
    assert state.stats[NODES.index("adjustment")].accepted > 200 and state.stats[NODES.index("touchdown")].accepted == 0


def test_with_every_node_lost_the_engine_dead_reckons_and_turns_invalid():
    state, errors, valid, config, _ = _fly(5.0, 3.0, np.random.default_rng(2))
    frames_after = np.arange(len(valid)) / 200 - 3.0  # the engine started at t = 0
    assert valid[frames_after < 0].all()
    assert not valid[frames_after > config.max_coast_s + 0.01].any()
    assert relative_std_m(state.fused) > 0.05  # grown from about 0.01 m
    assert np.isfinite(errors).all()


def test_a_node_that_loses_its_features_loses_its_weight_and_recovers_it():
    """Eq. (9): the adjustment node gone for 1 s (occluded markers) while the approaching node goes on."""
    *_, betas = _fly(6.0, 6.0, np.random.default_rng(4), adjustment_gap_s=(3.0, 4.0))
    adjustment = 1 + NODES.index("adjustment")
    at = lambda t: betas[np.argmin(np.abs(betas[:, 0] - t)), adjustment]
    assert at(3.98) < 0.1 * at(2.98)  # a tenth of its weight before, after a second without measurements
    assert at(5.0) > 0.8 * at(2.98)  # most of it back within a second of its return


def test_the_velocity_kept_across_the_heading_restart_is_turned_into_the_new_heading():
    """_truth's descent, exact centres from 0 s and exact poses from 1 s: the first pose restarts the filters in
    the pattern's heading, keeping the body's velocity, which must be turned from the old estimate's axes into
    the new ones (the centres' start had the heading 0.5 rad off here); kept unturned it is about 0.2 m/s off."""
    def exact(t, p, R, X_CP):
        frame = {"approach": NodeMeasurement(t, "approach", approach_covariance(X_CP.translation(), 60.0, 640.0),
                                             p_CP=X_CP.translation())}
        if t >= 1.0:
            frame["adjustment"] = NodeMeasurement(t, "adjustment", np.diag([2.5e-5] * 3 + [1.6e-5] * 3),
                                                  X_PB=RigidTransform(R, p))
        return frame

    t, _, state, (_, v, _), _ = next(stepped for stepped in _descent(1.2, exact)
                                     if stepped[2].heading_known and not stepped[1].heading_known)
    assert t == pytest.approx(1.0)
    assert np.linalg.norm(state.fused.v - v) < 0.1


def test_a_node_whose_gate_rejects_its_measurement_restarts_from_the_fused_estimate():
    """_truth's descent with noisy centres and poses (so each filter's own state differs from the fused one), the
    adjustment pose 1 m off at 1.6 s: its gate rejects it, and its filter restarts from the fused estimate (only a
    node that accepted its measurement keeps its own state, the approaching node's here)."""
    rng = np.random.default_rng(5)

    def noisy(t, p, R, X_CP):
        covariance = approach_covariance(X_CP.translation(), 60.0, 640.0)
        frame = {"approach": NodeMeasurement(t, "approach", covariance,
                                             p_CP=rng.multivariate_normal(X_CP.translation(), covariance))}
        if t >= 1.0:
            off = [0.0, 0.0, 1.0] if t == 1.6 else rng.normal(0, 0.004, 3)
            frame["adjustment"] = NodeMeasurement(t, "adjustment", np.diag([2.5e-5] * 3 + [1.6e-5] * 3),
                                                  X_PB=RigidTransform(R, p + off))
        return frame

    *_, (t, before, state, _, _) = _descent(1.6, noisy)
    assert t == 1.6
    approach, adjustment = NODES.index("approach"), NODES.index("adjustment")
    assert state.stats[adjustment].gated == before.stats[adjustment].gated + 1
    assert state.stats[approach].accepted == before.stats[approach].accepted + 1
    np.testing.assert_allclose(state.filters[adjustment].p, state.fused.p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(state.filters[adjustment].v, state.fused.v, rtol=0, atol=1e-12)
    assert np.linalg.norm(state.filters[approach].p - state.fused.p) > 1e-6  # kept its own


def test_a_filter_that_rejects_every_measurement_restarts_from_the_next_after_max_coast():
    """Hovering 10 m over the pattern, the filter converged; then the measurements say 2 m lower (the
    state is off, as after a divergence): gated, invalid after max_coast_s, restarted, right again."""
    config = FederatedConfig()
    state, history = FederatedState(), []
    for k in range(int(4.0 * 200) + 1):
        t = k / 200
        frame = None
        if k % 4 == 0:
            height = 10.0 if t < 2.0 else 8.0
            p_CP = X_BC.inverse().multiply(RigidTransform([0.0, 0.0, height]).inverse()).translation()
            frame = {"approach": NodeMeasurement(t, "approach", approach_covariance(p_CP, 60.0, 640.0), p_CP=p_CP)}
        state = step(state, t, np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0], frame, config, X_BC)
        history.append((t, is_valid(state, config), state.fused.p[2], state.stats[0].gated))
    t, valid, height, gated = np.array(history).T
    coasting = (t > 2.0) & (t < 1.98 + config.max_coast_s)
    assert np.abs(height[coasting] - 10.0).max() < 0.01 and valid[coasting].all()  # gated, dead-reckoned
    assert gated[coasting][-1] >= 20
    assert not valid[(t > 1.98 + config.max_coast_s) & (t < 2.0 + config.max_coast_s)].any()  # lost
    assert valid[t >= 2.0 + config.max_coast_s].all() and np.abs(height[t > 3.0] - 8.0).max() < 0.05  # restarted


@pytest.mark.parametrize("reset_states", [True, False])
def test_between_frames_the_fused_estimate_is_the_information_sum_of_the_predicted_filters(reset_states):
    """Exactly when every filter restarts from the fused state (Carlson's fusion-reset); to first order
    when the measuring filters keep their own (seed 001), whose predictions linearise about their own
    attitudes."""
    config, rng = FederatedConfig(reset_states=reset_states), np.random.default_rng(5)
    state = FederatedState()
    for k in range(13):  # frames at 0, 4, 8 and 12 (200 Hz, 50 Hz), predicted steps between
        t = k / 200
        p, _, a, R = _truth(t)
        frame = None
        if k % 4 == 0:
            X_CP = X_BC.inverse().multiply(RigidTransform(R, p).inverse())
            covariance = approach_covariance(X_CP.translation(), 60.0, 640.0)
            pose = RigidTransform(R, p + rng.normal(0, 0.004, 3))
            frame = {"approach": NodeMeasurement(t, "approach", covariance,
                                                 p_CP=rng.multivariate_normal(X_CP.translation(), covariance)),
                     "adjustment": NodeMeasurement(t, "adjustment", np.diag([2.5e-5] * 3 + [1.6e-5] * 3), X_PB=pose)}
        state = step(state, t, np.r_[R.inverse().multiply(a + [0.0, 0.0, G]), [0.0, 0.0, 0.2]], frame, config, X_BC)
        if frame is None:
            summed = np.linalg.inv(sum(np.linalg.inv(s.P) for s in state.filters))
            if reset_states:
                np.testing.assert_allclose(state.fused.P, summed, rtol=1e-6, atol=1e-12)
            else:  # the velocity-attitude terms differ with the attitudes
                assert np.linalg.norm(state.fused.P - summed) < 1e-6 * np.linalg.norm(state.fused.P)  # 5e-8
            if k < 4:
                continue  # the first frame's pose starts every filter: only the approaching node updates its own
            for name, s in zip(NODES, state.filters):
                shared = reset_states or name == "touchdown"  # the touchdown node never measured
                assert np.allclose(s.p, state.fused.p, atol=1e-12) == shared
                assert np.allclose(s.v, state.fused.v, atol=1e-12) == shared


def _hover(R: RotationMatrix, p: np.ndarray, seconds: float, side_px: float, focal_px: float, adjustment,
           config: FederatedConfig | None = None):
    """Hovering at p_PB with R_PB (level), an ideal IMU at 200 Hz; at 50 Hz the approaching node's exact
    centres (with the covariance of an outline side_px wide at focal_px) and, from 1 s, the adjustment
    node's `adjustment(t, X_CP)`; `config` the default FederatedConfig unless given. Returns (t, state) after
    each frame."""
    config, state, frames = config or FederatedConfig(), FederatedState(), []
    X_CP = X_BC.inverse().multiply(RigidTransform(R, p).inverse())
    imu = np.r_[R.inverse().multiply([0.0, 0.0, G]), 0.0, 0.0, 0.0]
    for k in range(int(seconds * 200) + 1):
        t = k / 200
        if k % 4:
            state = step(state, t, imu, None, config, X_BC)
            continue
        frame = {"approach": NodeMeasurement(t, "approach", approach_covariance(X_CP.translation(), side_px, focal_px),
                                             p_CP=X_CP.translation())}
        if t >= 1.0:
            frame["adjustment"] = adjustment(t, X_CP)
        state = step(state, t, imu, frame, config, X_BC)
        frames.append((t, state))
    return frames


def _hover_then_poses(pose_error_m: float, until_s: float, config: FederatedConfig | None = None):
    """`_hover` at p_PB (0.3, -0.2, 4) m with the heading 2 rad, the adjustment node's pose (3 mm
    claimed) with its height off by pose_error_m in the frame at 1 s and in every later one where
    `until_s` has not passed, exact after. Returns (times of frames, heading known, fused height, fused
    yaw) per frame."""
    R = RollPitchYaw(0.0, 0.0, 2.0).ToRotationMatrix()
    p = np.array([0.3, -0.2, 4.0])

    def pose(t, X_CP):
        off = pose_error_m if t < until_s or t == 1.0 else 0.0
        return NodeMeasurement(t, "adjustment", np.diag([1e-6] * 3 + [9e-6] * 3),
                               X_PB=RigidTransform(R, p + [0.0, 0.0, off]))

    return np.array([(t, state.heading_known, state.fused.p[2], RollPitchYaw(state.fused.R).yaw_angle())
                     for t, state in _hover(R, p, 2.5, 136.0, 640.0, pose, config)]).T


def test_a_first_pose_far_from_what_the_centres_measured_is_left_out_and_the_next_one_turns_the_heading():
    """The first full pose restarts every filter in the pattern's heading; one 40 mm off in height (13
    times its 3 mm) would put them all there. It is gated against the centres' estimate, turned to its
    heading (with the UAV 0.36 m off the centre, a wrong turn would gate the right pose too)."""
    t, known, height, yaw = _hover_then_poses(0.04, until_s=1.0)

    def at(when):
        return np.argmin(np.abs(t - when))

    assert not known[at(1.0)] and abs(height[at(1.0)] - 4.0) < 0.005  # left out: the centres' height
    assert known[at(1.02)] and abs(yaw[at(1.02)] - 2.0) < 1e-3  # the next, right, pose turned it
    assert np.abs(height[t >= 1.02] - 4.0).max() < 0.005


def _started_by_centres(R: np.ndarray, P: np.ndarray, v=(0.0, 0.0, 0.0)) -> FederatedState:
    """Filters the approaching node's centres started (the heading unknown), at 1 s, its last centre accepted then:
    the fused estimate p_PB (0.3, -0.2, 4) m, R_PB R, v_PB v, covariance P; each filter with N P (their fusion's P)."""
    local = LocalState(np.array([0.3, -0.2, 4.0]), np.asarray(v, dtype=float), R, len(NODES) * P,
                       q_scale=float(len(NODES)))
    return FederatedState(time=1.0, fused=replace(local, P=P, q_scale=1.0), filters=(local,) * len(NODES),
                          local_estimates=(local,) * len(NODES),
                          stats=(NodeStats(50, 0, 1.0), NodeStats(), NodeStats()))


def _first_pose(state: FederatedState, measured: RigidTransform) -> FederatedState:
    """`state` stepped, at its own time (nothing predicted), with the adjustment node's pose X_PB `measured` (1 mrad,
    3 mm claimed): the first full pose."""
    frame = {"adjustment": NodeMeasurement(state.time, "adjustment", np.diag([1e-6] * 3 + [9e-6] * 3), X_PB=measured)}
    return step(state, state.time, np.r_[state.fused.R.T @ [0.0, 0.0, G], 0.0, 0.0, 0.0], frame, FederatedConfig(),
                X_BC)


@pytest.mark.parametrize("offset, agrees", [([0.6, 0.0, 0.0], True), ([0.0, 0.6, 0.0], False)])
def test_a_first_pose_is_checked_against_the_centres_covariance_turned_to_its_heading(offset, agrees):
    """The centres' estimate, at heading 0, knows p_PB's x to 0.1 m and its y to 1 m; the first pose says the heading
    is pi/2, which turns y's 1 m onto x. A pose 0.6 m off the turned estimate along x (NIS 0.6^2 / (1 + 9e-6),
    0.36) agrees and restarts the filters on it; along y (0.36 / (0.01 + 9e-6), 36, over the gate's 27.9) it is
    left out. The covariance left unturned would swap the two."""
    assert 0.36 / (1.0 + 9e-6) < chi2.ppf(FederatedConfig().gate_probability, 6) < 0.36 / (0.01 + 9e-6)
    state = _started_by_centres(np.eye(3), np.diag([0.01, 1.0, 0.01, 0.1, 0.1, 0.04, 1e-4, 1e-4, 1e-4]))
    R_z = RotationMatrix.MakeZRotation(np.pi / 2)
    measured = RigidTransform(R_z, R_z.multiply(state.fused.p) + offset)
    after = _first_pose(state, measured)
    assert after.heading_known == agrees
    assert after.stats[NODES.index("adjustment")] == (NodeStats(1, 0, 1.0) if agrees else NodeStats(0, 1, None))
    np.testing.assert_allclose(after.fused.p, measured.translation() if agrees else state.fused.p, rtol=0, atol=1e-12)


def test_the_heading_of_a_first_pose_on_a_tilted_body_is_its_turn_about_the_vertical_of_the_pattern():
    """The centres' estimate rolled 0.3 rad at heading 0, the first pose (1 mrad) the same roll turned pi/2 about
    P's z: R_PB' R_PB^T is that turn exactly, and the estimate turned by it agrees (the pose restarts the filters).
    The turn in the body's axes, R_PB^T R_PB', is pi/2 about the tilted (0, sin 0.3, cos 0.3): the heading from its
    entries, atan2(2 cos 0.3, sin^2 0.3), is 45.7 mrad short, and the pose would be gated."""
    R = RotationMatrix.MakeXRotation(0.3)
    state = _started_by_centres(R.matrix(), np.diag([1e-4] * 3 + [0.1, 0.1, 0.04] + [1e-6] * 3))
    R_z = RotationMatrix.MakeZRotation(np.pi / 2)
    measured = RigidTransform(R_z.multiply(R), R_z.multiply(state.fused.p))
    after = _first_pose(state, measured)
    assert after.heading_known and after.stats[NODES.index("adjustment")] == NodeStats(1, 0, 1.0)
    np.testing.assert_allclose(after.fused.R, measured.rotation().matrix(), rtol=0, atol=1e-12)


def test_a_heading_restart_turns_the_velocity_and_its_covariance_into_the_new_heading():
    """The centres' estimate, at heading 0, moving 0.2 m/s along its x, knows the velocity to 0.71 m/s along x and
    0.32 m/s along y; the first pose turns the heading a quarter turn: the restart keeps the body's velocity, now
    along P's y, (0, 0.2, 0), and its covariance with x's and y's variances swapped, diag(0.1, 0.5, 0.04)."""
    state = _started_by_centres(np.eye(3), np.diag([1e-4] * 3 + [0.5, 0.1, 0.04] + [1e-6] * 3), v=[0.2, 0.0, 0.0])
    R_z = RotationMatrix.MakeZRotation(np.pi / 2)
    after = _first_pose(state, RigidTransform(R_z, R_z.multiply(state.fused.p)))
    assert after.heading_known
    np.testing.assert_allclose(after.fused.v, [0.0, 0.2, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(after.fused.P[3:6, 3:6], np.diag([0.1, 0.5, 0.04]), rtol=1e-9, atol=1e-15)


def test_a_start_from_a_full_pose_keeps_its_whole_covariance():
    """At 3.8 m the adjustment node's pose errs along the orbit about the pattern: its position and tilt errors
    correlate (+1.00), and the filters started by it carry that covariance whole (before: its diagonal, which
    understated the orbit's variance 1.8x and the worst direction's 4x); its velocity has the initial covariance."""
    X_PB_true = RigidTransform(RollPitchYaw(0.0, 0.0, 0.7), [0.3, -0.2, 3.8])
    X_CP = X_BC.inverse().multiply(X_PB_true.inverse())
    covariance = body_pose_covariance(PatternView(X_CP, layout_corners(RqrlpLayout()), K, 0.3), X_BC)
    assert abs(covariance[1, 3]) / np.sqrt(covariance[1, 1] * covariance[3, 3]) > 0.99  # theta_y with p_x
    first, config = NodeMeasurement(0.0, "adjustment", covariance, X_PB=X_PB_true), FederatedConfig()
    state = step(FederatedState(), 0.0, np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0], {"adjustment": first}, config, X_BC)
    pose, position_first = [0, 1, 2, 6, 7, 8], [3, 4, 5, 0, 1, 2]  # the error state's [dp, dtheta]; the pose's
    np.testing.assert_allclose(state.fused.P[np.ix_(pose, pose)], covariance[np.ix_(position_first, position_first)],
                               rtol=1e-9, atol=1e-15)
    # the velocity, which a pose does not measure: the initial covariance, uncorrelated with the pose
    np.testing.assert_allclose(state.fused.P[3:6, 3:6], initial_velocity_covariance(config), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(state.fused.P[3:6, pose], 0.0, rtol=0, atol=1e-15)
    for local in state.filters:  # each with N times it, so that their fusion has it
        np.testing.assert_allclose(local.P[np.ix_(pose, pose)], len(NODES) * state.fused.P[np.ix_(pose, pose)],
                                   rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("max_coast_s", [FederatedConfig().max_coast_s, 0.51])
def test_first_poses_that_go_on_disagreeing_restart_the_filters_after_max_coast(max_coast_s):
    """A pose is the only source of the heading: if every one disagrees with the centres (the centres'
    estimate may be the one that is off), the filters restart from one after max_coast_s, at the first frame
    (every 20 ms) at least max_coast_s after the first disagreeing pose: also with a max_coast_s that is no
    whole number of frames (0.51 s: at 1.52 s, while the run still goes on, its last pose 20 ms old)."""
    t, known, height, _ = _hover_then_poses(0.04, until_s=3.0, config=FederatedConfig(max_coast_s=max_coast_s))
    assert not known[(t >= 1.0) & (t < 1.0 + max_coast_s - 0.01)].any()
    restart = np.argmax(known)
    assert t[restart] == pytest.approx(1.0 + 0.02 * np.ceil(max_coast_s / 0.02 - 1e-9)) and known[restart:].all()
    assert abs(height[restart] - 4.04) < 0.005  # from the pose, which the centres then pull back


HEADED_R, HEADED_P = RollPitchYaw(0.0, 0.0, 2.0).ToRotationMatrix(), np.array([0.3, -0.2, 4.0])  # a hover's X_PB


def _headed_pose(t: float, node: str = "adjustment", offset_m=(0.0, 0.0, 0.0)) -> NodeMeasurement:
    """`node`'s pose at t [s] of the hover at HEADED_P with the heading 2 rad, moved by offset_m in P (1 mrad and 3 mm
    claimed: the covariance over [dtheta, dp])."""
    return NodeMeasurement(t, node, np.diag([1e-6] * 3 + [9e-6] * 3),
                           X_PB=RigidTransform(HEADED_R, HEADED_P + np.asarray(offset_m)))


def _lone_disagreeing_poses(when_s: tuple[float, ...], seconds: float) -> dict:
    """`_hover` at HEADED_P with the heading 2 rad for `seconds`, the adjustment node's pose 40 mm high in the frames
    at `when_s` and none in the others. Returns {t: state} after each frame."""

    def pose(t, X_CP):
        lone = any(abs(t - when) < 1e-9 for when in when_s)
        return _headed_pose(t, offset_m=(0.0, 0.0, 0.04)) if lone else None

    return dict(_hover(HEADED_R, HEADED_P, seconds, 136.0, 640.0, pose))


def test_two_lone_disagreeing_poses_far_apart_are_each_left_out():
    """A disagreeing pose at 1 s and the next pose, disagreeing too, at 3 s (none in between): each is a run of
    its own, shorter than max_coast_s, so the second is left out as the first was, not taken whole because
    the first was 2 s before."""
    frames = _lone_disagreeing_poses((1.0, 3.0), 3.1)
    after = [state for t, state in frames.items() if t >= 3.0]
    assert not any(state.heading_known for state in after)
    assert max(abs(state.fused.p[2] - 4.0) for state in after) < 0.005
    assert after[0].stats[1].gated == 2


def test_a_disagreeing_pose_max_coast_after_the_last_one_goes_on_its_run():
    """Disagreeing poses at 1 s and 1.5 s, exactly max_coast_s (0.5 s, the frames' times exact in binary) apart: a
    run ends only once more than max_coast_s has passed since its last pose, so the second goes on the first's run,
    which has then lasted max_coast_s: the filters restart from it (a run of its own would leave it out)."""
    assert FederatedConfig().max_coast_s == 0.5
    frames = _lone_disagreeing_poses((1.0, 1.5), 1.52)
    assert not frames[1.48].heading_known and frames[1.48].stats[1] == NodeStats(0, 1, None)
    assert frames[1.5].heading_known and frames[1.5].stats[1] == NodeStats(1, 1, 1.5)
    assert abs(frames[1.5].fused.p[2] - 4.04) < 0.005  # from the pose


def test_a_centre_that_restarts_lost_filters_leaves_the_heading_unknown_until_the_next_pose():
    """Hovering at heading 2 rad with exact centres and poses (the heading known), then 0.6 s of frames with nothing
    (lost: over max_coast_s), then a centre alone: it restarts the filters at heading 0 (initial_state: a centre
    cannot tell it), so the heading is unknown again, and the next exact pose turns it back to 2 rad."""
    R, p = HEADED_R, HEADED_P
    t, state = _hover(R, p, 1.5, 136.0, 640.0, lambda t, X_CP: _headed_pose(t))[-1]
    assert state.heading_known and t == 1.5
    config, imu = FederatedConfig(), np.r_[R.inverse().multiply([0.0, 0.0, G]), 0.0, 0.0, 0.0]
    for k in range(1, 31):  # frames every 20 ms with nothing, to 2.1 s
        state = step(state, (300 + 4 * k) / 200, imu, {}, config, X_BC)
    X_CP = X_BC.inverse().multiply(RigidTransform(R, p).inverse())
    centre = NodeMeasurement(2.12, "approach", approach_covariance(X_CP.translation(), 136.0, 640.0),
                             p_CP=X_CP.translation())
    restarted = step(state, 2.12, imu, {"approach": centre}, config, X_BC)
    assert restarted.stats[0].last_accepted_s == 2.12 and is_valid(restarted, config)
    assert not restarted.heading_known
    assert abs(RollPitchYaw(restarted.fused.R).yaw_angle()) < 1e-9
    turned = step(restarted, 2.14, imu, {"adjustment": _headed_pose(2.14)}, config, X_BC)
    assert turned.heading_known and abs(RollPitchYaw(turned.fused.R).yaw_angle() - 2.0) < 1e-3


def test_once_the_heading_is_known_each_pose_is_gated_by_its_own_filter_alone():
    """The check of a first pose against the centres' estimate is only for a pose that would turn the heading:
    after a second of exact adjustment poses, a frame with the adjustment pose 40 mm off in height (gated by its
    filter) and an exact touchdown pose takes the touchdown one (accepted), not leaving both out as a first
    pose's check would."""
    R, p = HEADED_R, HEADED_P
    t, before = _hover(R, p, 2.0, 136.0, 640.0, lambda t, X_CP: _headed_pose(t))[-1]
    assert before.heading_known and t == 2.0
    frame = {"adjustment": _headed_pose(2.02, offset_m=(0.0, 0.0, 0.04)), "touchdown": _headed_pose(2.02, "touchdown")}
    after = step(before, 2.02, np.r_[R.inverse().multiply([0.0, 0.0, G]), 0.0, 0.0, 0.0], frame, FederatedConfig(),
                 X_BC)
    adjustment, touchdown = NODES.index("adjustment"), NODES.index("touchdown")
    assert after.stats[adjustment] == replace(before.stats[adjustment], gated=before.stats[adjustment].gated + 1)
    assert after.stats[touchdown] == NodeStats(before.stats[touchdown].accepted + 1, before.stats[touchdown].gated,
                                               2.02)
    assert abs(after.fused.p[2] - 4.0) < 0.002


def test_a_non_finite_measurement_is_gated_and_never_starts_the_filters():
    """The first frame's centre is NaN: gated, the filters not started; the next, finite, starts them."""
    config, imu = FederatedConfig(), np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0]
    covariance = approach_covariance(np.array([0.0, 0.0, 4.0]), 136.0, 640.0)
    state = step(FederatedState(), 0.0, imu, {"approach": NodeMeasurement(0.0, "approach", covariance,
                                                                          p_CP=np.array([np.nan, 0.0, 4.0]))},
                 config, X_BC)
    assert not state.started and state.stats[0].gated == 1
    state = step(state, 0.02, imu, {"approach": NodeMeasurement(0.02, "approach", covariance,
                                                                p_CP=np.array([0.0, 0.0, 4.0]))}, config, X_BC)
    assert state.started and np.all(np.isfinite(state.fused.p)) and is_valid(state, config)


def _centre_frame(t: float, height_m: float = 10.0) -> dict:
    """A camera frame with the approaching node's exact centre, the UAV level height_m over the pattern."""
    p_CP = X_BC.inverse().multiply(RigidTransform([0.0, 0.0, height_m]).inverse()).translation()
    return {"approach": NodeMeasurement(t, "approach", approach_covariance(p_CP, 60.0, 640.0), p_CP=p_CP)}


def test_the_measurement_that_starts_the_filters_counts_as_accepted():
    """The first centre starts every filter: the approaching node's record has it accepted (one), none gated,
    at its time."""
    config, imu = FederatedConfig(), np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0]
    state = step(FederatedState(), 0.0, imu, _centre_frame(0.0), config, X_BC)
    assert state.started and state.stats == (NodeStats(1, 0, 0.0), NodeStats(), NodeStats())


def test_a_start_from_the_centre_alone_puts_the_pattern_where_the_mounted_camera_sees_it():
    """The first centre, p_CP, seen by a camera mounted off the body's axis (X_BC: turned half a turn about x,
    0.1 m forward, 0.05 m to the side): the fused centre seen from the body is X_BC p_CP = R_x(pi) p_CP + p_BC
    (with X_BC^-1 p_CP: 0.2 m in x, where the default mount on the axis hides the difference), and its covariance
    is the centre's turned into the body, R_BC C R_BC^T (initial_state's heading and tilt terms cancel in it; C
    untouched would keep the signs of its x-y and x-z terms, which R_x(pi) flips)."""
    mount = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.1, 0.05, -0.04])
    p_CP = np.array([0.3, -0.2, 10.0])
    first = NodeMeasurement(0.0, "approach", approach_covariance(p_CP, 60.0, 640.0), p_CP=p_CP)
    state = step(FederatedState(), 0.0, np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0], {"approach": first}, FederatedConfig(),
                 mount)
    expected = np.array([0.3, 0.2, -10.0]) + [0.1, 0.05, -0.04]  # R_x(pi) (x, y, z) = (x, -y, -z)
    np.testing.assert_allclose(centre_in_body(state.fused)[0], expected, atol=1e-12)
    J, R_BC = relative_jacobian(state.fused), mount.rotation().matrix()
    np.testing.assert_allclose(J @ state.fused.P @ J.T, R_BC @ first.covariance @ R_BC.T, rtol=1e-9, atol=1e-15)


def test_a_restart_after_max_coast_adds_the_initial_velocity_covariance():
    """Hovering, centres for 1 s, then frames without any for longer than max_coast_s: the next centre restarts
    the filters (lost), counted accepted. The restart keeps the body's velocity covariance, turned into the new
    attitude's axes, and adds the initial one to it (the velocity may have drifted off while lost)."""
    config, imu = FederatedConfig(), np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0]
    state = FederatedState()
    for k in range(int(1.7 * 200)):
        t = k / 200
        state = step(state, t, imu, (_centre_frame(t) if t <= 1.0 else {}) if k % 4 == 0 else None, config, X_BC)
    before = state
    assert t - before.stats[0].last_accepted_s > config.max_coast_s and not is_valid(before, config)
    after = step(before, 1.7, imu, _centre_frame(1.7), config, X_BC)
    assert after.stats[0] == NodeStats(before.stats[0].accepted + 1, 0, 1.7) and is_valid(after, config)
    R = after.fused.R @ before.fused.R.T
    np.testing.assert_allclose(after.fused.P[3:6, 3:6],
                               R @ before.fused.P[3:6, 3:6] @ R.T + initial_velocity_covariance(config),
                               rtol=1e-9, atol=1e-12)


def test_an_estimate_with_a_velocity_not_finite_is_invalid():
    """is_valid: measured just now and the relative position certain, but a NaN velocity (which the relative
    position's std does not read) is not valid."""
    config, imu = FederatedConfig(), np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0]
    state = step(FederatedState(), 0.0, imu, _centre_frame(0.0, 4.0), config, X_BC)
    assert is_valid(state, config)
    fused = replace(state.fused, v=np.array([np.nan, 0.0, 0.0]))
    assert relative_std_m(fused) < config.max_relative_std_m
    assert not is_valid(replace(state, fused=fused), config)


def test_an_estimate_whose_relative_position_is_too_uncertain_is_invalid():
    """is_valid: measured within max_coast_s and finite, but p_BP_B's std (sqrt of the trace) over
    max_relative_std_m is not valid; just under it is."""
    config, imu = FederatedConfig(), np.r_[0.0, 0.0, G, 0.0, 0.0, 0.0]
    covariance = approach_covariance(np.array([0.0, 0.0, 4.0]), 136.0, 640.0)
    state = step(FederatedState(), 0.0, imu, {"approach": NodeMeasurement(0.0, "approach", covariance,
                                                                          p_CP=np.array([0.0, 0.0, 4.0]))},
                 config, X_BC)
    assert is_valid(state, config) and relative_std_m(state.fused) < config.max_relative_std_m
    for ratio, valid in ((0.99, True), (1.01, False)):  # P scaled: the std scales with its square root
        scale = (ratio * config.max_relative_std_m / relative_std_m(state.fused)) ** 2
        inflated = replace(state, fused=replace(state.fused, P=state.fused.P * scale))
        assert relative_std_m(inflated.fused) == pytest.approx(ratio * config.max_relative_std_m)
        assert is_valid(inflated, config) == valid


def test_an_estimate_whose_relative_position_is_exactly_as_uncertain_as_allowed_is_valid():
    """is_valid's bound on p_BP_B's std is inclusive: level (R_PB = I) with the attitude certain, p_BP_B's covariance
    is p_PB's, whose trace 0.25 + 0.25 + 0.5 = 1 m^2 (exact in binary) puts the std at exactly max_relative_std_m."""
    P = np.zeros((9, 9))
    P[0:3, 0:3] = np.diag([0.25, 0.25, 0.5])
    P[3:6, 3:6] = 0.01 * np.eye(3)
    fused = LocalState(np.array([0.0, 0.0, 4.0]), np.zeros(3), np.eye(3), P)
    state = FederatedState(time=1.0, fused=fused, stats=(NodeStats(1, 0, 1.0), NodeStats(), NodeStats()))
    assert relative_std_m(fused) == 1.0
    assert is_valid(state, FederatedConfig(max_relative_std_m=1.0))


@pytest.mark.parametrize("dt", [0.005, 0.1])
def test_the_predictions_jacobian_is_its_finite_differences(dt):
    """`predict`'s covariance step without process noise, from P = I, is F F^T: against F from the nominal
    state's central differences over each error coordinate (attitude errors Exp(dtheta) R), the position's
    attitude block (-dt^2 / 2 [R f_B]x) included."""
    config = LocalFilterConfig(accel_noise_psd=0.0, gyro_noise_psd=0.0)
    R0 = RollPitchYaw(0.2, -0.1, 0.7).ToRotationMatrix().matrix()
    base = LocalState(np.array([1.0, -2.0, 3.0]), np.array([0.4, 0.1, -0.3]), R0, np.eye(9))
    f_B, w_B = np.array([0.5, -0.3, 9.6]), np.array([0.1, 0.2, -0.3])
    out = predict(base, f_B, w_B, dt, config, G)

    def nominal(x):
        state = LocalState(base.p + x[0:3], base.v + x[3:6], exp_so3(x[6:9]) @ R0, np.eye(9))
        after = predict(state, f_B, w_B, dt, config, G)
        return np.r_[after.p - out.p, after.v - out.v, log_so3(after.R @ out.R.T)]

    h = 1e-6
    F = np.column_stack([(nominal(h * e) - nominal(-h * e)) / (2 * h) for e in np.eye(9)])
    np.testing.assert_allclose(out.P, F @ F.T, atol=1e-6)


def test_the_centre_seen_from_the_body_is_what_the_camera_and_the_landing_use():
    """centre_in_body, p_BP_B = R^T (-p), and its Jacobian against central differences over the error state
    (attitude errors Exp(dtheta) R): the one behind the approaching node's model in the camera and the
    relative position's Jacobian (relative_jacobian), which had each written it out."""
    R0 = RollPitchYaw(0.2, -0.1, 0.7).ToRotationMatrix().matrix()
    base = LocalState(np.array([0.3, -0.5, 4.0]), np.zeros(3), R0, np.eye(9))
    p_BP_B, H = centre_in_body(base)
    np.testing.assert_allclose(p_BP_B, R0.T @ -base.p)

    def centre(x):
        return centre_in_body(LocalState(base.p + x[0:3], base.v + x[3:6], exp_so3(x[6:9]) @ R0, np.eye(9)))[0]

    h = 1e-6
    np.testing.assert_allclose(H, np.column_stack([(centre(h * e) - centre(-h * e)) / (2 * h) for e in np.eye(9)]),
                               atol=1e-8)
    np.testing.assert_array_equal(relative_jacobian(base), H)


def test_the_pattern_seen_from_the_camera_brings_a_filter_to_the_true_pose():
    """update_pattern_in_camera's model and Jacobian: from 20 mm and 20 mrad off, updates with an exact
    view (its covariance tiny), each from the same prior covariance (a Gauss-Newton step), take the
    filter to the true pose."""
    config = LocalFilterConfig()
    R_PB = RollPitchYaw(0.05, -0.02, 1.1).ToRotationMatrix().matrix()
    p_PB = np.array([0.3, -0.2, 3.0])
    X_CP = X_BC.inverse().multiply(RigidTransform(RotationMatrix(R_PB), p_PB).inverse())
    prior = np.diag([0.05**2] * 3 + [0.1**2] * 3 + [0.05**2] * 3)
    state = LocalState(p_PB + [0.01, -0.02, 0.015], np.zeros(3), exp_so3([0.01, -0.015, 0.02]) @ R_PB, prior)
    for _ in range(3):
        state = update_pattern_in_camera(replace(state, P=prior), X_CP.translation(), X_CP.rotation().matrix(),
                                         np.eye(6) * 1e-12, X_BC.rotation().matrix(), X_BC.translation(), config)
    assert state.accepted == 3
    np.testing.assert_allclose(state.p, p_PB, atol=1e-7)
    np.testing.assert_allclose(log_so3(state.R @ R_PB.T), 0.0, atol=1e-7)


def test_the_engine_takes_a_views_covariance_about_the_filters_own_pattern_in_the_camera():
    """A started filter, tilted and off the pattern's centre, and the adjustment node's view (seed 001's corners)
    5 mm and 5 mrad off it: the engine's update is update_pattern_in_camera with the view's covariance
    linearised about the filter's own pose of the pattern in the camera, X_CP = X_BC^-1 X_PB^-1 (not about
    the camera's pose in P, X_PB X_BC)."""
    config = FederatedConfig()
    R_PB = RollPitchYaw(0.1, -0.05, 0.7).ToRotationMatrix()
    own = LocalState(np.array([1.5, -1.0, 4.0]), np.zeros(3), R_PB.matrix(),
                     np.diag([0.05**2] * 3 + [0.1**2] * 3 + [0.02**2] * 3))
    X_CP = X_BC.inverse().multiply(RigidTransform(R_PB, own.p).inverse())
    seen = RigidTransform(RotationMatrix(exp_so3([0.005, -0.005, 0.005]) @ X_CP.rotation().matrix()),
                          X_CP.translation() + [0.005, -0.005, 0.005])
    measurement = adjustment_measurement(seen, layout_corners(RqrlpLayout()), 0.3, 0.0, X_BC, K)
    adjustment = NODES.index("adjustment")
    state = FederatedState(time=0.0, fused=own, filters=(own,) * len(NODES), heading_known=True,
                           stats=tuple(NodeStats(1, 0, 0.0) for _ in NODES))
    updated = step(state, 0.0, np.r_[R_PB.inverse().multiply([0.0, 0.0, G]), 0.0, 0.0, 0.0],
                   {"adjustment": measurement}, config, X_BC).local_estimates[adjustment]
    expected = update_pattern_in_camera(own, seen.translation(), seen.rotation().matrix(),
                                        measurement.view.covariance_at(X_CP), X_BC.rotation().matrix(),
                                        X_BC.translation(), config)
    assert updated.accepted == 1
    for name in ("p", "v", "R", "P"):
        np.testing.assert_allclose(getattr(updated, name), getattr(expected, name), rtol=1e-9, atol=1e-15)


def _hover_with_views(height_m: float, seconds: float, rng) -> np.ndarray:
    """`_hover` square-on at height_m over the pattern, the adjustment node's view of the pattern (seed
    001's 36 corners, f 1280 px, 0.3 px) with the error its covariance says, drawn about the truth. The
    fused height's error [m] per frame from 2 s."""
    points_P = layout_corners(RqrlpLayout())

    def view(t, X_CP):
        d = rng.multivariate_normal(np.zeros(6), PatternView(X_CP, points_P, K, 0.3).covariance_at(X_CP))
        seen = RigidTransform(RotationMatrix(exp_so3(d[:3]) @ X_CP.rotation().matrix()), X_CP.translation() + d[3:])
        return adjustment_measurement(seen, points_P, 0.3, t, X_BC, K)

    frames = _hover(RotationMatrix(), np.array([0.02, -0.03, height_m]), seconds, 155.0, 1280.0, view)
    return np.array([state.fused.p[2] - height_m for t, state in frames if t >= 2.0])


def test_far_off_a_pose_that_errs_along_the_orbit_about_the_pattern_leaves_the_height_unbiased():
    """At 7 m the 36 corners span 170 px and a view's tilt is known to about 30 mrad: the pose errs along
    the orbit about the pattern (tilt with a sideways shift) and hardly in its distance. Updating in the
    camera's frame with the covariance about the filter's own pose, that error is linear and the height
    unbiased; the body's pose in P, with its covariance about itself, put the fused height 5-6 mm high."""
    errors = _hover_with_views(7.0, 8.0, np.random.default_rng(1))
    assert abs(errors.mean()) < 0.001 and np.sqrt(np.mean(errors**2)) < 0.0025
