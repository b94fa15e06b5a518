"""Kalman filter tracking the four tag corners in the image (seed 000, Sec. 2.6, Eq. 28-35).

The paper filters the detected AprilTag corners so that short occlusions can be bridged by
prediction; it gives the textbook equations but no motion model or noise levels. Here each corner
pixel coordinate follows a constant-velocity model driven by white acceleration noise, with no
control input (B u = 0 in Eq. 28 and 30: the deck's motion is not known to the drone).

State x (16,): the corners' pixels [u0, v0, u1, v1, u2, v2, u3, v3] followed by their velocities in
the same order, in px and px/s (OpenCV pixels, centres at integers). Corner order is the detector's
(`crhf_math.tag_corners_T`).
"""

from dataclasses import dataclass

import numpy as np

N_COORDS = 8  # four corners, (u, v) each


@dataclass
class CornerFilterParams:
    """Tuning of the corner filter; the paper (Sec. 2.6) gives none of these numbers."""

    dt_s: float = 0.05  # camera period: the 50 ms simulation step of seed 000, Sec. 3
    measurement_std_px: float = 1.0  # corner detection noise, R = std^2 I
    acceleration_std_px_s2: float = 200.0  # deck swaying 5 cm at 0.5 Hz, 1.2 m below, fx ~ 460 px
    initial_velocity_std_px_s: float = 200.0  # velocity is unknown at the first detection
    max_coast_steps: int = 3  # predict-only frames bridged before the track is dropped


def constant_velocity_model(params: CornerFilterParams):
    """(F, Q, H, R) of Eq. 28-29 for the 16-state constant-velocity corner model.

    Q is the piecewise-constant white-acceleration model: per coordinate
    std^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]].
    """
    dt = params.dt_s
    eye = np.eye(N_COORDS)
    F = np.kron([[1.0, dt], [0.0, 1.0]], eye)
    Q = params.acceleration_std_px_s2**2 * np.kron(
        [[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]], eye
    )
    H = np.kron([[1.0, 0.0]], eye)
    R = params.measurement_std_px**2 * eye
    return F, Q, H, R


def kalman_predict(x, P, F, Q):
    """Prediction step, Eq. 30-31 (no control input): x- = F x+, P- = F P+ F^T + Q."""
    return F @ x, F @ P @ F.T + Q


def kalman_update(x, P, z, H, R):
    """Update step, Eq. 32-35: residual, gain, state and covariance.

    Eq. 35's (I - K H) P- is symmetrised to keep round-off from making P asymmetric.
    """
    residual = z - H @ x  # Eq. 32 (the paper's x_k is the prediction x-_k)
    S = R + H @ P @ H.T
    K = np.linalg.solve(S, H @ P).T  # Eq. 33: P- H^T S^-1, with P- and S symmetric
    x = x + K @ residual  # Eq. 34
    P = (np.eye(len(x)) - K @ H) @ P  # Eq. 35
    return x, (P + P.T) / 2


@dataclass(frozen=True)
class CornerTrack:
    """The filter's state between camera frames.

    x: (16,) state (module docstring) or None when no corners are being tracked.
    P: (16, 16) state covariance, px^2 and (px/s)^2, or None.
    coasted_steps: consecutive frames predicted without a detection.
    """

    x: np.ndarray | None = None
    P: np.ndarray | None = None
    coasted_steps: int = 0

    @property
    def valid(self) -> bool:
        """True while the corners are tracked; False before the first detection and after the
        track coasted more than `max_coast_steps` frames."""
        return self.x is not None

    @property
    def corners(self) -> np.ndarray:
        """(4, 2) filtered corner pixels (NaN when not valid)."""
        if self.x is None:
            return np.full((4, 2), np.nan)
        return self.x[:N_COORDS].reshape(4, 2)


def step_corner_track(
    track: CornerTrack, measured_corners: np.ndarray | None, params: CornerFilterParams
) -> CornerTrack:
    """Advance the track by one camera frame.

    measured_corners: (4, 2) detected corners in pixels, or None (or non-finite) when the tag was
    not detected. A detection starts a track or predicts and updates it; a missing detection
    predicts only, and after more than `params.max_coast_steps` such frames in a row the track is
    dropped (an invalid, empty track) so the next detection starts afresh.
    """
    z = None if measured_corners is None else np.asarray(measured_corners, dtype=float).reshape(-1)
    if z is not None and not np.all(np.isfinite(z)):
        z = None
    if track.x is None:
        if z is None:
            return track
        std = np.r_[
            np.full(N_COORDS, params.measurement_std_px),
            np.full(N_COORDS, params.initial_velocity_std_px_s),
        ]
        return CornerTrack(np.r_[z, np.zeros(N_COORDS)], np.diag(std**2), 0)
    F, Q, H, R = constant_velocity_model(params)
    x, P = kalman_predict(track.x, track.P, F, Q)
    if z is not None:
        return CornerTrack(*kalman_update(x, P, z, H, R), 0)
    if track.coasted_steps >= params.max_coast_steps:
        return CornerTrack()
    return CornerTrack(x, P, track.coasted_steps + 1)
