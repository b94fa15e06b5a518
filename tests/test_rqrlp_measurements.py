"""The covariances seed 001's pose nodes hand the federated filter (systems/perception/rqrlp/measurements.py)
against the reprojection Jacobian taken by central differences of OpenCV's own projection."""

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from systems.perception.rqrlp.measurements import PatternView, body_pose_covariance
from systems.perception.rqrlp.nodes import layout_corners
from systems.perception.rqrlp.pattern import RqrlpLayout

K = np.array([[1280.0, 0.0, 948.9], [0.0, 1280.0, 543.2], [0.0, 0.0, 1.0]])  # seed 001 Table 1
X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.02, 0.0, -0.04])
POINTS_P = layout_corners(RqrlpLayout())
PIXEL_STD = 0.4


def _opencv_covariance(perturbed_X_CP, step=1e-6):
    """pixel_std^2 (J^T J)^-1 with J the pixels' derivative over a 6-vector, by central differences of
    cv2.projectPoints of the pattern at perturbed_X_CP(delta)."""
    def pixels(delta):
        X_CP = perturbed_X_CP(delta)
        rvec = cv2.Rodrigues(X_CP.rotation().matrix())[0]
        return cv2.projectPoints(POINTS_P, rvec, X_CP.translation(), K, None)[0].ravel()

    J = np.stack([(pixels(step * e) - pixels(-step * e)) / (2 * step) for e in np.eye(6)], axis=1)
    return PIXEL_STD**2 * np.linalg.inv(J.T @ J)


def _exp(rotation_vector):
    return RotationMatrix(cv2.Rodrigues(np.asarray(rotation_vector, dtype=float))[0])


@pytest.mark.parametrize("height_m", [1.5, 7.0])
def test_the_pattern_and_body_pose_covariances_are_the_reprojection_jacobians(height_m):
    X_PB = RigidTransform(RollPitchYaw(0.04, -0.03, 0.8), [0.3, -0.2, height_m])
    X_CP = X_BC.inverse().multiply(X_PB.inverse())
    view = PatternView(X_CP, POINTS_P, K, PIXEL_STD)
    # the pattern in the camera, [dtheta, dp] in C: Exp(dtheta) R_CP, p_CP + dp
    in_camera = _opencv_covariance(lambda d: RigidTransform(_exp(d[:3]).multiply(X_CP.rotation()),
                                                            X_CP.translation() + d[3:]))
    np.testing.assert_allclose(view.covariance_at(X_CP), in_camera, rtol=1e-5, atol=1e-14)
    # the body in the pattern, [dtheta, dp] in P: Exp(dtheta) R_PB, p_PB + dp
    in_pattern = _opencv_covariance(lambda d: X_BC.inverse().multiply(
        RigidTransform(_exp(d[:3]).multiply(X_PB.rotation()), X_PB.translation() + d[3:]).inverse()))
    np.testing.assert_allclose(body_pose_covariance(view, X_BC), in_pattern, rtol=1e-5, atol=1e-14)
