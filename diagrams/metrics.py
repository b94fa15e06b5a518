"""Estimate-against-truth figures, the same for every estimator (DESIGN.md's metrics.json shape)."""

import numpy as np
from scipy.spatial.transform import Rotation

from systems.flags import is_set

FLIP_THRESHOLD_DEG = 10.0  # a frame whose rotation error exceeds this counts as a pose flip


def rotations(wxyz: np.ndarray) -> Rotation:
    """SciPy rotations of (M, 4) quaternions [w, x, y, z] of any nonzero norm."""
    return Rotation.from_quat(wxyz[:, [1, 2, 3, 0]])  # SciPy is scalar-last, and normalises


def quaternion_yaw(wxyz: np.ndarray) -> np.ndarray:
    """The yaw [rad] (about z, Drake's RollPitchYaw's) of (M, 4) unit quaternions [w, x, y, z]; NaN rows NaN."""
    w, x, y, z = wxyz.T
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y**2 + z**2))


def level_poses(p: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 7) rows [x, y, z, qw, qx, qy, qz] of level poses at p (N, 3) [m] yawed by yaw (N) [rad]."""
    zero = np.zeros_like(yaw)
    return np.column_stack([p, np.cos(yaw / 2), zero, zero, np.sin(yaw / 2)])


def xyz_rpy(poses: np.ndarray) -> np.ndarray:
    """(N, 6) [x, y, z (m), roll, pitch, yaw (rad)] from (N, 7) [x, y, z, qw, qx, qy, qz] rows
    (roll, pitch, yaw as Drake's RollPitchYaw: R = Rz(yaw) Ry(pitch) Rx(roll)); NaN rows stay NaN."""
    out = np.full((len(poses), 6), np.nan)
    finite = np.all(np.isfinite(poses), axis=1)
    if finite.any():
        out[finite] = np.column_stack([poses[finite, :3], rotations(poses[finite, 3:]).as_euler("xyz")])
    return out


def pose_errors(truth: np.ndarray, estimate: np.ndarray):
    """Per-frame errors of valid estimates.

    truth: (N, 7) rows [x, y, z, qw, qx, qy, qz]; estimate: (N, 8) rows [valid, x, y, z, qw, qx, qy, qz].
    Returns (valid mask (N,), xyz error (M, 3) in m, rpy error (M, 3) in deg, rotation error angle
    (M,) in deg) for the M valid frames; errors are estimate minus truth, angle differences wrapped
    to [-180, 180).
    """
    valid = is_set(estimate[:, 0])
    difference = xyz_rpy(estimate[valid, 1:]) - xyz_rpy(truth[valid])
    rpy = (np.rad2deg(difference[:, 3:]) + 180.0) % 360.0 - 180.0
    angle = ((rotations(truth[valid, 3:]).inv() * rotations(estimate[valid, 4:])).magnitude()
             if valid.any() else np.zeros(0))
    return valid, difference[:, :3], rpy, np.rad2deg(angle)


def rms_of_finite(values) -> float | None:
    """The root mean square of the finite values (NaN and inf left out), in their unit; None when there are none."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else None


def axis_errors(xyz: np.ndarray, rpy_deg: np.ndarray) -> dict:
    """MAE and RMSE per axis of errors xyz (M, 3) in m and rpy_deg (M, 3) in deg: the estimator
    figures of docs/architecture.md."""
    return {
        "mae_xyz_m": np.mean(np.abs(xyz), axis=0).tolist(),
        "mae_rpy_deg": np.mean(np.abs(rpy_deg), axis=0).tolist(),
        "rmse_xyz_m": np.sqrt(np.mean(xyz**2, axis=0)).tolist(),
        "rmse_rpy_deg": np.sqrt(np.mean(rpy_deg**2, axis=0)).tolist(),
    }


def estimator_metrics(truth: np.ndarray, estimate: np.ndarray, window: np.ndarray | None = None) -> dict:
    """One estimator's figures over a run: MAE and RMSE per axis and the pose-flip count over its
    valid estimates (within `window`, a boolean mask of the frames to score, when given), and the
    share of all frames with a valid estimate. Rows as `pose_errors`."""
    scored = estimate.copy()
    if window is not None:
        scored[~window, 0] = 0.0
    valid, xyz, rpy, angle = pose_errors(truth, scored)
    out = {"valid_fraction": float(np.mean(is_set(estimate[:, 0]))) if len(estimate) else 0.0,
           "flips": int(np.sum(angle > FLIP_THRESHOLD_DEG)), "frames_scored": int(valid.sum())}
    if valid.any():
        out.update(axis_errors(xyz, rpy))
    return out
