"""The covariances seed 001's pose nodes hand the federated filter (systems/perception/rqrlp/measurements.py)
against the reprojection Jacobian taken by central differences of OpenCV's own projection."""

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from scipy.spatial.transform import Rotation

from systems.perception.rqrlp.measurements import (
    APPROACH_PIXEL_STD,
    APPROACH_REL_STD,
    NODE_VECTOR_SIZE,
    TRACK_STEP_PX,
    NodeMeasurement,
    PatternView,
    approach_covariance,
    approach_measurement,
    body_pose_covariance,
    node_vector,
    touchdown_measurement,
)
from systems.perception.rqrlp.nodes import layout_corners
from systems.perception.rqrlp.pattern import RqrlpLayout

K = np.array([[1280.0, 0.0, 948.9], [0.0, 1280.0, 543.2], [0.0, 0.0, 1.0]])  # seed 001 Table 1
X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.02, 0.0, -0.04])
POINTS_P = layout_corners(RqrlpLayout())
PIXEL_STD = 0.4


def _opencv_covariance(perturbed_X_CP, step=1e-5, pixel_std=PIXEL_STD, camera_K=K):
    """pixel_std^2 (J^T J)^-1 with J the pixels' derivative over a 6-vector, by central differences of
    cv2.projectPoints of the pattern at perturbed_X_CP(delta) through camera_K (a step of 1e-5: at 1e-6 the
    body's perturbation, through two inverses, rounds to 1.6e-5 of the covariance at 7 m with fy 1000 px)."""
    def pixels(delta):
        X_CP = perturbed_X_CP(delta)
        rvec = cv2.Rodrigues(X_CP.rotation().matrix())[0]
        return cv2.projectPoints(POINTS_P, rvec, X_CP.translation(), camera_K, None)[0].ravel()

    J = np.stack([(pixels(step * e) - pixels(-step * e)) / (2 * step) for e in np.eye(6)], axis=1)
    return pixel_std**2 * np.linalg.inv(J.T @ J)


def _exp(rotation_vector):
    return RotationMatrix(cv2.Rodrigues(np.asarray(rotation_vector, dtype=float))[0])


@pytest.mark.parametrize("fy", [1280.0, 1000.0], ids=["square_pixels", "fy_not_fx"])
@pytest.mark.parametrize("height_m", [1.5, 7.0])
def test_the_pattern_and_body_pose_covariances_are_the_reprojection_jacobians(height_m, fy):
    """Also through a camera whose pixels are not square (fy 1000 px against fx 1280): v goes with fy."""
    camera_K = K.copy()
    camera_K[1, 1] = fy
    X_PB = RigidTransform(RollPitchYaw(0.04, -0.03, 0.8), [0.3, -0.2, height_m])
    X_CP = X_BC.inverse().multiply(X_PB.inverse())
    view = PatternView(X_CP, POINTS_P, camera_K, PIXEL_STD)
    # the pattern in the camera, [dtheta, dp] in C: Exp(dtheta) R_CP, p_CP + dp
    in_camera = _opencv_covariance(lambda d: RigidTransform(_exp(d[:3]).multiply(X_CP.rotation()),
                                                            X_CP.translation() + d[3:]), camera_K=camera_K)
    np.testing.assert_allclose(view.covariance_at(X_CP), in_camera, rtol=1e-5, atol=1e-14)
    # the body in the pattern, [dtheta, dp] in P: Exp(dtheta) R_PB, p_PB + dp
    in_pattern = _opencv_covariance(lambda d: X_BC.inverse().multiply(
        RigidTransform(_exp(d[:3]).multiply(X_PB.rotation()), X_PB.translation() + d[3:]).inverse()),
        camera_K=camera_K)
    np.testing.assert_allclose(body_pose_covariance(view, X_BC), in_pattern, rtol=1e-5, atol=1e-14)


def _in_camera(X_CP):
    """The perturbation [dtheta, dp] in C of the pattern's pose: Exp(dtheta) R_CP, p_CP + dp."""
    return lambda d: RigidTransform(_exp(d[:3]).multiply(X_CP.rotation()), X_CP.translation() + d[3:])


def test_no_fit_is_trusted_beyond_min_pixel_std():
    """A view claiming 0.05 px (a touchdown chain's anchor can) is taken at MIN_PIXEL_STD, 0.3 px (the renderer's
    quantisation square-on): its covariance is OpenCV's reprojection Jacobian's at 0.3 px; above the floor, at its
    own (0.6 px)."""
    X_CP = X_BC.inverse().multiply(RigidTransform(RollPitchYaw(0.04, -0.03, 0.8), [0.3, -0.2, 3.0]).inverse())
    for claimed, used in ((0.05, 0.3), (0.6, 0.6)):
        np.testing.assert_allclose(PatternView(X_CP, POINTS_P, K, claimed).covariance_at(X_CP),
                                   _opencv_covariance(_in_camera(X_CP), pixel_std=used), rtol=1e-5, atol=1e-14)


def test_the_touchdown_chain_adds_its_random_walk_per_chained_frame():
    """After 100 chained frames the touchdown pose's pixel noise is sqrt(anchor^2 + 100 TRACK_STEP_PX^2), and its
    covariance OpenCV's reprojection Jacobian's at that noise."""
    X_CP = X_BC.inverse().multiply(RigidTransform(RollPitchYaw(0.02, 0.01, -0.5), [0.1, 0.2, 1.2]).inverse())
    measurement = touchdown_measurement(X_CP, POINTS_P, 0.5, 100, 0.0, X_BC, K)
    expected = np.sqrt(0.5**2 + 100 * TRACK_STEP_PX**2)
    assert measurement.view.pixel_std == pytest.approx(expected)
    np.testing.assert_allclose(measurement.view.covariance_at(X_CP),
                               _opencv_covariance(_in_camera(X_CP), pixel_std=expected), rtol=1e-5, atol=1e-14)


def test_a_view_with_a_nan_pixel_noise_is_not_finite():
    """A pose node's view whose pixel noise is NaN (a fit of NaN residuals) has measured nothing: its covariance is
    NaN, and the measurement says it is not finite."""
    X_CP = RigidTransform([0.0, 0.0, 2.0])
    view = PatternView(X_CP, POINTS_P, K, float("nan"))
    assert np.isnan(view.covariance_at(X_CP)).any()
    assert not NodeMeasurement(0.0, "adjustment", None, X_PB=X_CP.inverse(), view=view).finite
    view = PatternView(X_CP, POINTS_P, K, 0.4)
    assert NodeMeasurement(0.0, "adjustment", None, X_PB=X_CP.inverse(), view=view).finite


def test_the_approach_covariance_is_that_of_z_u_v_sampled():
    """p_CP = z [u, v, 1] with u, v at APPROACH_PIXEL_STD / focal and z at its relative std
    sqrt((APPROACH_PIXEL_STD / side)^2 + APPROACH_REL_STD^2), independent: 200 000 samples of them give the
    covariance approach_covariance reports off the axis, where x and y share z's error (to 2 % of each pair's
    std product)."""
    p_CP, side_px, focal_px = np.array([1.5, -0.9, 6.0]), 40.0, 500.0
    rng = np.random.default_rng(7)
    n = 200_000
    u = p_CP[0] / p_CP[2] + APPROACH_PIXEL_STD / focal_px * rng.standard_normal(n)
    v = p_CP[1] / p_CP[2] + APPROACH_PIXEL_STD / focal_px * rng.standard_normal(n)
    z = p_CP[2] * (1 + np.hypot(APPROACH_PIXEL_STD / side_px, APPROACH_REL_STD) * rng.standard_normal(n))
    sampled = np.cov(np.stack([z * u, z * v, z]))
    covariance = approach_covariance(p_CP, side_px, focal_px)
    scale = np.sqrt(np.outer(np.diag(sampled), np.diag(sampled)))
    assert np.all(np.abs(covariance - sampled) <= 0.02 * scale)


def test_the_approach_depth_is_never_trusted_beyond_its_relative_std():
    """However many pixels the outline spans, its depth's std is at least APPROACH_REL_STD of the depth."""
    covariance = approach_covariance(np.array([0.0, 0.0, 5.0]), 1e6, 640.0)
    assert np.sqrt(covariance[2, 2]) == pytest.approx(5.0 * APPROACH_REL_STD, rel=1e-6)


def test_the_node_vector_logs_presence_position_quaternion_and_quality():
    """[present, x, y, z, qw, qx, qy, qz, quality]: a pose node's X_PB's translation and rotation (SciPy's
    quaternion of the same roll, pitch, yaw, scalar first, up to its sign); the approaching node's p_CP with a
    NaN quaternion; no measurement: present 0 and NaN for the rest."""
    rpy = [0.1, 0.2, 0.3]
    pose = node_vector(NodeMeasurement(1.0, "adjustment", np.eye(6), X_PB=RigidTransform(RollPitchYaw(rpy), [1, 2, 3]),
                                       quality=0.5))
    assert pose.shape == (NODE_VECTOR_SIZE,) and pose[0] == 1.0 and pose[8] == 0.5
    np.testing.assert_allclose(pose[1:4], [1.0, 2.0, 3.0], rtol=0, atol=1e-12)
    x, y, z, w = Rotation.from_euler("xyz", rpy).as_quat()  # extrinsic x, y, z: Drake's R = Rz(yaw) Ry(pitch) Rx(roll)
    quaternion = np.array([w, x, y, z]) * np.sign(pose[4] * w)
    np.testing.assert_allclose(pose[4:8], quaternion, rtol=0, atol=1e-12)
    rough = node_vector(approach_measurement(np.array([0.4, -0.2, 6.0]), 40.0, 1.0, 640.0))
    assert rough[0] == 1.0 and rough[8] == 40.0 and np.isnan(rough[4:8]).all()
    np.testing.assert_array_equal(rough[1:4], [0.4, -0.2, 6.0])
    absent = node_vector(None)
    assert absent.shape == (NODE_VECTOR_SIZE,) and absent[0] == 0.0 and np.isnan(absent[1:]).all()
