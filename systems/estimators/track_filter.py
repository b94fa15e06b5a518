"""Kalman filter of seed 000 (Sec. 2.6, Eq. 28-35) tracking n measured coordinates over frames.

The paper filters the detected AprilTag corners so that short occlusions can be bridged by
prediction; it gives the textbook equations but no motion model or noise levels. Here each
coordinate follows a constant-velocity model driven by white acceleration noise, with no control
input (B u = 0 in Eq. 28 and 30: the deck's motion is not known to the drone). CRHF tracks two
things with it: the four tag corners (n = 8, pixels [u0, v0, ..., u3, v3] in the detector's order)
and the four ToF ranges (n = 4, metres).

State x (2n,): the n coordinates followed by their rates, in the measurement's unit and unit/s.
"""

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from systems.config import require, require_positive


@dataclass
class TrackFilterParams:
    """Tuning of one tracking filter, in the unit of its measurements (px for corners, m for
    ranges); the paper (Sec. 2.6) gives none of these numbers. Defaults are the corner filter's."""

    dt_s: float = 0.05  # camera period: the 50 ms simulation step of seed 000, Sec. 3
    measurement_std: float = 1.0  # measurement noise, R = std^2 I (corners: px)
    acceleration_std: float = 200.0  # corners: deck swaying 5 cm at 0.5 Hz, 1.2 m below, fx ~ 460 px
    initial_velocity_std: float = 200.0  # the rate is unknown at the first measurement
    max_coast_steps: int = 3  # predict-only frames bridged before the track is dropped

    def validate(self, prefix: str) -> None:
        """A ConfigError naming the field. dt_s is not a setting here: the systems that run these filters
        step them at their camera's period, which replaces it."""
        for name in ("measurement_std", "acceleration_std", "initial_velocity_std"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.max_coast_steps >= 0, f"{prefix}.max_coast_steps must not be negative, got {self.max_coast_steps}")
        require(self.dt_s == TrackFilterParams.dt_s,
                f"{prefix}.dt_s is the camera's period (camera.rate_hz), not a setting: got {self.dt_s}")


def constant_velocity_model(params: TrackFilterParams, n: int):
    """(F, Q, H, R) of Eq. 28-29 for the 2n-state constant-velocity model of n coordinates.

    Q is the piecewise-constant white-acceleration model: per coordinate
    std^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]. Built once per setting (the tracks step every frame
    with the same one): the arrays are shared and read-only.
    """
    return _constant_velocity_model(params.dt_s, params.acceleration_std, params.measurement_std, n)


@lru_cache(maxsize=16)
def _constant_velocity_model(dt: float, acceleration_std: float, measurement_std: float, n: int):
    eye = np.eye(n)
    F = np.kron([[1.0, dt], [0.0, 1.0]], eye)
    Q = acceleration_std**2 * np.kron([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]], eye)
    H = np.kron([[1.0, 0.0]], eye)
    R = measurement_std**2 * eye
    for array in (F, Q, H, R):
        array.flags.writeable = False
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
class Track:
    """The filter's state between frames.

    x: (2n,) state (module docstring) or None when nothing is being tracked.
    P: (2n, 2n) state covariance, or None.
    coasted_steps: consecutive frames predicted without a measurement.
    """

    x: np.ndarray | None = None
    P: np.ndarray | None = None
    coasted_steps: int = 0

    @property
    def valid(self) -> bool:
        """True while tracking; False before the first measurement and after the track coasted more
        than `max_coast_steps` frames."""
        return self.x is not None

    @property
    def position(self) -> np.ndarray | None:
        """The n filtered coordinates, or None when not valid."""
        return None if self.x is None else self.x[: len(self.x) // 2]


def innovation_distance(track: Track, measurement: np.ndarray, params: TrackFilterParams) -> float:
    """The squared Mahalanobis distance of a measurement (n coordinates) from a valid track's prediction one
    step ahead, r^T S^-1 r with Eq. 32's residual r and its covariance S = R + H P- H^T: chi-square with n
    degrees of freedom when the measurement is what the track models."""
    F, Q, H, R = constant_velocity_model(params, len(track.x) // 2)
    x, P = kalman_predict(track.x, track.P, F, Q)
    residual = np.asarray(measurement, dtype=float).reshape(-1) - H @ x
    return float(residual @ np.linalg.solve(R + H @ P @ H.T, residual))


def step_track(track: Track, measurement: np.ndarray | None, params: TrackFilterParams,
               shift: np.ndarray | None = None) -> Track:
    """Advance the track by one frame.

    measurement: the n coordinates (any shape; flattened), or None (or any non-finite entry) when
    nothing was measured. A measurement starts a track or predicts and updates it; a missing one
    predicts only, and after more than `params.max_coast_steps` such frames in a row the track is
    dropped (an invalid, empty track) so the next measurement starts afresh.
    shift: Eq. 28's B u, a known change of the n coordinates over the step that is not the tracked
    thing's own motion (the ranges' change from the drone's own motion), added to the prediction; one
    with a non-finite entry is unknown and adds nothing.
    """
    z = None if measurement is None else np.asarray(measurement, dtype=float).reshape(-1)
    if z is not None and not np.all(np.isfinite(z)):
        z = None
    if track.x is None:
        if z is None:
            return track
        std = np.r_[np.full(len(z), params.measurement_std), np.full(len(z), params.initial_velocity_std)]
        return Track(np.r_[z, np.zeros(len(z))], np.diag(std**2), 0)
    F, Q, H, R = constant_velocity_model(params, len(track.x) // 2)
    x, P = kalman_predict(track.x, track.P, F, Q)
    if shift is not None and np.all(np.isfinite(shift)):  # x is the prediction's own array
        x[: len(x) // 2] += shift
    if z is not None:
        return Track(*kalman_update(x, P, z, H, R), 0)
    if track.coasted_steps >= params.max_coast_steps:
        return Track()
    return Track(x, P, track.coasted_steps + 1)
