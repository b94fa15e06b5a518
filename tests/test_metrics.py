"""Estimate-against-truth metrics on analytic cases."""

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from diagrams.metrics import (
    estimator_metrics,
    level_poses,
    pose_errors,
    quaternion_yaw,
    rms_of_finite,
    rotations,
    xyz_rpy,
)
from systems.estimators.estimate import PoseEstimate, estimate_vector
from systems.sensors.ground_truth import pose_vector


def poses(n, yaw_offset_deg=0.0, dx=0.0, roll_deg=0.0):
    return [RigidTransform(RollPitchYaw(np.deg2rad([roll_deg + 0.0, 2.0, 10.0 * k + yaw_offset_deg])),
                           [0.1 * k + dx, 0.0, 2.0]) for k in range(n)]


def test_known_offsets_give_their_mae_and_rmse():
    truth = np.array([pose_vector(X) for X in poses(10)])
    estimate = np.array([estimate_vector(PoseEstimate(0.0, X, True)) for X in poses(10, yaw_offset_deg=2.0, dx=0.01)])
    m = estimator_metrics(truth, estimate)
    np.testing.assert_allclose(m["mae_xyz_m"], [0.01, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(m["mae_rpy_deg"], [0.0, 0.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(m["rmse_rpy_deg"], [0.0, 0.0, 2.0], atol=1e-9)
    assert m["valid_fraction"] == 1.0 and m["flips"] == 0


def test_uneven_errors_tell_the_rmse_from_the_mae():
    """Errors of 0.01 and 0.03 m in x (1 and 3 deg in yaw), opposite signs: MAE 0.02 m, RMSE sqrt(5e-4) m."""
    truth = np.array([pose_vector(X) for X in poses(2)])
    estimated = [poses(2, yaw_offset_deg=1.0, dx=-0.01)[0], poses(2, yaw_offset_deg=-3.0, dx=0.03)[1]]
    m = estimator_metrics(truth, np.array([estimate_vector(PoseEstimate(0.0, X, True)) for X in estimated]))
    np.testing.assert_allclose(m["mae_xyz_m"], [0.02, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(m["rmse_xyz_m"], [np.sqrt(5e-4), 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(m["mae_rpy_deg"], [0.0, 0.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(m["rmse_rpy_deg"], [0.0, 0.0, np.sqrt(5.0)], atol=1e-9)


def test_invalid_frames_are_left_out_and_counted():
    truth = np.array([pose_vector(X) for X in poses(4)])
    estimates = [PoseEstimate(0.0, X, True) for X in poses(4, dx=0.02)]
    estimates[1] = PoseEstimate.invalid(0.0)
    m = estimator_metrics(truth, np.array([estimate_vector(e) for e in estimates]))
    assert m["valid_fraction"] == 0.75
    np.testing.assert_allclose(m["mae_xyz_m"], [0.02, 0.0, 0.0], atol=1e-12)


def test_an_invalid_estimate_logs_no_pose_whatever_it_carries():
    """estimate_vector: [0, NaN x 7] for an estimate not valid, even one holding a pose; [1, x, y, z, qw, qx, qy, qz]
    (Drake's quaternion) for a valid one."""
    X = RigidTransform(RollPitchYaw(0.1, 0.2, 0.3), [1.0, 2.0, 3.0])
    invalid = estimate_vector(PoseEstimate(0.0, X, False))
    assert invalid[0] == 0.0 and invalid.shape == (8,) and np.isnan(invalid[1:]).all()
    np.testing.assert_array_equal(estimate_vector(PoseEstimate(0.0, X, True)),
                                  np.r_[1.0, 1.0, 2.0, 3.0, X.rotation().ToQuaternion().wxyz()])


def test_angle_errors_wrap_and_flips_are_counted():
    # Truth at yaw 179 deg, estimate at -179 deg: 2 deg apart, not 358.
    truth = np.array([pose_vector(RigidTransform(RollPitchYaw(0, 0, np.deg2rad(179)), [0, 0, 2]))])
    near = np.array([estimate_vector(PoseEstimate(0.0, RigidTransform(RollPitchYaw(0, 0, np.deg2rad(-179)),
                                                                         [0, 0, 2]), True))])
    np.testing.assert_allclose(estimator_metrics(truth, near)["mae_rpy_deg"], [0, 0, 2], atol=1e-9)
    flipped = np.array([estimate_vector(PoseEstimate(0.0, RigidTransform(RollPitchYaw(np.deg2rad(25), 0,
                                                                                      np.deg2rad(179)), [0, 0, 2]),
                                                     True))])
    assert estimator_metrics(truth, flipped)["flips"] == 1


def test_a_flip_is_a_rotation_error_over_10_deg():
    """Estimates turned 9.9 and 10.1 deg about a skew axis from the truth (Drake's AngleAxis): only the
    second is a pose flip (the threshold is 10 deg)."""
    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    truth = poses(2, roll_deg=5.0)
    estimate = [X.multiply(RigidTransform(RotationMatrix(AngleAxis(np.radians(deg), axis)), [0.0, 0.0, 0.0]))
                for X, deg in zip(truth, (9.9, 10.1))]
    angles = [np.degrees(t.rotation().InvertAndCompose(e.rotation()).ToAngleAxis().angle())
              for t, e in zip(truth, estimate)]
    np.testing.assert_allclose(angles, [9.9, 10.1], atol=1e-9)
    m = estimator_metrics(np.array([pose_vector(X) for X in truth]),
                          np.array([estimate_vector(PoseEstimate(0.0, X, True)) for X in estimate]))
    assert m["flips"] == 1


def test_a_window_scores_only_its_frames_and_the_valid_fraction_stays_over_all():
    truth = np.array([pose_vector(X) for X in poses(6)])
    estimates = [PoseEstimate(0.0, X, True) for X in poses(6, dx=0.05)[:3] + poses(6, dx=0.01)[3:]]
    estimates[4] = PoseEstimate.invalid(0.0)
    window = np.arange(6) >= 3  # e.g. after the filters settle
    m = estimator_metrics(truth, np.array([estimate_vector(e) for e in estimates]), window)
    np.testing.assert_allclose(m["mae_xyz_m"], [0.01, 0.0, 0.0], atol=1e-12)
    assert m["frames_scored"] == 2 and m["valid_fraction"] == 5 / 6


def test_roll_pitch_yaw_and_the_rotation_error_are_drakes():
    rng = np.random.default_rng(3)
    truth = [RigidTransform(RollPitchYaw(*rng.uniform(-1.4, 1.4, 3)), rng.normal(size=3)) for _ in range(20)]
    estimate = [X.multiply(RigidTransform(RollPitchYaw(*rng.normal(0.0, 0.3, 3)), [0.0, 0.0, 0.0])) for X in truth]
    rows = np.array([pose_vector(X) for X in truth])
    rows[:, 3:] *= 1.7  # any nonzero norm
    np.testing.assert_allclose(xyz_rpy(rows)[:, 3:], [RollPitchYaw(X.rotation()).vector() for X in truth], atol=1e-12)
    _, _, _, angle = pose_errors(rows, np.array([estimate_vector(PoseEstimate(0.0, X, True)) for X in estimate]))
    drake = [np.degrees(t.rotation().InvertAndCompose(e.rotation()).ToAngleAxis().angle())
             for t, e in zip(truth, estimate)]
    np.testing.assert_allclose(angle, drake, atol=1e-9)


def test_a_row_with_any_nan_is_all_nan_and_leaves_the_others_whole():
    """xyz_rpy: a row missing its position or its orientation (a NaN anywhere) is NaN throughout, not half a pose;
    the finite row between them is Drake's position and roll-pitch-yaw."""
    X = RigidTransform(RollPitchYaw(0.1, -0.2, 0.3), [1.0, 2.0, 3.0])
    no_position, whole, no_orientation = pose_vector(X), pose_vector(X), pose_vector(X)
    no_position[:3] = np.nan
    no_orientation[3:] = np.nan
    for rows, missing in (([no_position, whole], 0), ([whole, no_orientation], 1)):
        out = xyz_rpy(np.array(rows))
        assert np.isnan(out[missing]).all()
        np.testing.assert_allclose(out[1 - missing], [1.0, 2.0, 3.0, 0.1, -0.2, 0.3], atol=1e-12)


def test_rms_of_finite_leaves_out_nan_and_inf():
    assert rms_of_finite(np.array([0.003, -0.004, np.inf, np.nan, -np.inf])) == np.sqrt((0.003**2 + 0.004**2) / 2)
    assert rms_of_finite(np.array([np.nan, np.inf])) is None and rms_of_finite([]) is None


def test_the_shared_pose_helpers_agree_with_drake():
    """level_poses, quaternion_yaw and rotations (the one copy the perception, marker and federated metrics and
    the perception plot use) against Drake's poses and roll-pitch-yaw."""
    X = poses(6, roll_deg=5.0)
    wxyz = np.array([pose_vector(x)[3:] for x in X])
    drake_yaw = np.array([RollPitchYaw(x.rotation()).yaw_angle() for x in X])
    np.testing.assert_allclose(quaternion_yaw(wxyz), drake_yaw, atol=1e-12)
    assert np.isnan(quaternion_yaw(np.full((1, 4), np.nan))).all()  # an invalid row stays invalid
    np.testing.assert_allclose(rotations(2.0 * wxyz).as_matrix(), [x.rotation().matrix() for x in X], atol=1e-12)
    p = np.array([x.translation() for x in X])
    level = level_poses(p, drake_yaw)
    expected = [pose_vector(RigidTransform(RollPitchYaw(0.0, 0.0, yaw), xyz)) for yaw, xyz in zip(drake_yaw, p)]
    np.testing.assert_allclose(level, expected, atol=1e-12)


def test_pose_errors_are_the_estimate_minus_the_truth():
    """An estimate 0.01 m ahead in x, 0.02 m below in z and yawed 2 deg more than the truth: errors
    (+0.01, 0, -0.02) m and +2 deg in yaw (signed, not the truth minus the estimate)."""
    truth = np.array([pose_vector(X) for X in poses(3)])
    offset = np.array([0.01, 0.0, -0.02])
    estimate = np.array([estimate_vector(PoseEstimate(0.0, RigidTransform(X.rotation(), X.translation() + offset),
                                                      True)) for X in poses(3, yaw_offset_deg=2.0)])
    _, xyz, rpy, _ = pose_errors(truth, estimate)
    np.testing.assert_allclose(xyz, np.tile([0.01, 0.0, -0.02], (3, 1)), atol=1e-12)
    np.testing.assert_allclose(rpy, np.tile([0.0, 0.0, 2.0], (3, 1)), atol=1e-9)


def test_a_run_without_estimates_has_no_valid_fraction():
    """No frame at all: a valid fraction of 0 (none was valid), nothing scored."""
    m = estimator_metrics(np.zeros((0, 7)), np.zeros((0, 8)))
    assert m["valid_fraction"] == 0.0 and m["frames_scored"] == 0 and "mae_xyz_m" not in m
