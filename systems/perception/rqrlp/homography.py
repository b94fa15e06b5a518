"""Pose from a plane's homography, seed 001 Sec. 3.2: Eq. (1) H = K [r1 r2 t] maps the pattern plane
(X, Y) to pixels; Eq. (2) recovers r1, r2 and t with the scale lambda = 1 / |K^-1 h1|, r3 = r1 x r2,
and the rotation made orthonormal by SVD. Pixels are undistorted (OpenCV's K, integer centres)."""

import cv2
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix


def pose_from_homography(H: np.ndarray, K: np.ndarray) -> RigidTransform:
    """X_CP, the pattern frame P in the camera C, from H (pattern (X, Y, 1) in m -> pixels), Eq. (2).
    The sign is chosen so the pattern lies in front of the camera (t_z > 0)."""
    B = np.linalg.solve(K, H)  # lambda^-1 [r1 r2 t]
    scale = 2.0 / (np.linalg.norm(B[:, 0]) + np.linalg.norm(B[:, 1]))  # Eq. (2)'s lambda, both columns alike
    if B[2, 2] < 0:
        scale = -scale
    r1, r2, t = scale * B[:, 0], scale * B[:, 1], scale * B[:, 2]
    U, _, Vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))  # the nearest rotation
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return RigidTransform(RotationMatrix(R), t)


def homography_from_pose(X_CP: RigidTransform, K: np.ndarray) -> np.ndarray:
    """Eq. (1): H = K [r1 r2 t], scaled so H[2, 2] = 1."""
    R, t = X_CP.rotation().matrix(), X_CP.translation()
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2]


def plane_pose(points_P: np.ndarray, pixels: np.ndarray, K: np.ndarray,
               ransac_px: float = 2.0) -> tuple[RigidTransform, np.ndarray] | None:
    """X_CP from (N >= 4) points (X, Y) of the plane [m] and their undistorted pixels: the homography
    by cv2.findHomography with RANSAC, then Eq. (2). (pose, inlier mask), or None."""
    if len(points_P) < 4:
        return None
    H, inliers = cv2.findHomography(np.asarray(points_P, dtype=np.float64)[:, :2], np.asarray(pixels, np.float64),
                                    cv2.RANSAC, ransac_px)
    if H is None or not np.all(np.isfinite(H)) or inliers.sum() < 4:
        return None
    return pose_from_homography(H, K), inliers.ravel().astype(bool)
