"""The pinhole projection of points in a camera frame C (x right, y down, z along the optical axis; m)
to pixels by intrinsics K (3x3, px), and its Jacobian, for the filters that take points' pixels."""

import numpy as np


def project(p_C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of the points p_C (N, 3)."""
    x, y, z = np.asarray(p_C, dtype=float).T
    return np.c_[K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]]


def projection_jacobian(p_C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2, 3) d(pixel)/d(p_C) of each point."""
    x, y, z = np.asarray(p_C, dtype=float).T
    J = np.zeros((len(z), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = K[0, 0] / z, -K[0, 0] * x / z**2
    J[:, 1, 1], J[:, 1, 2] = K[1, 1] / z, -K[1, 1] * y / z**2
    return J
