"""The deck in the World, tracked from a tag-pose estimator's frames (ours: seed 000 estimates the tag
in the camera frame by frame and says nothing of flying on it).

Each valid frame's X_CT (CRHF's or ATDA's) becomes a measurement of the deck frame P in W through
the UAV's own pose: X_WP = X_WB X_BC X_CT X_TP. Two of seed 000's constant-velocity Kalman filters
(Eq. 28-35, systems/estimators/track_filter.py) follow it, one for the deck centre p_WP [m] and one
for its attitude [n_x, n_y, yaw] [rad]: the x and y components of the deck's normal z_P in W (the
tilt: |n_xy| = sin(tilt)) and the heading left after removing that tilt,
    R_WP = R_tilt(n) Rz(yaw),   R_tilt(n) the smallest rotation taking z_W onto n.
A frame whose pose is far from the tracks' prediction (its innovation's chi-square beyond `gate_chi2`, on
the centre or on the attitude: a wrong frame from the estimator) is not used; a new track steers only once
`confirm_frames` frames in a row agree, and until then a frame outside the gate starts it afresh; frames that
confirmed tracks gate start a challenger, which replaces them after `takeover_frames` in a row. Between
frames the tracks coast; a frame without a valid (or a gated) X_CT (the tag out of view, as in the last
half metre of a landing) is a coasted step, and after `max_coast_steps` of them the estimate turns
invalid. (Updating the heave and tilt from the four ToF ranges' plane in those frames was tried: each
frame's plane tilts by 0.026 rad of noise over the sensors' 0.19 m spacing, and on a ship-like deck the
tracks' own prediction over a second was the better estimate, tests/test_deck_tracker.py.) The estimate at any time is the tracks predicted to that time, so the deck's heave rate and
tilt rate are there for a supervisor that times its touchdown (systems/control/landing_window.py).
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem, ValueProducer

from systems.config import require, require_positive
from systems.estimators.estimate import PoseEstimate
from systems.estimators.track_filter import Track, TrackFilterParams, innovation_distance, step_track
from systems.stepped import SteppedValue

DECK_MOTION_SIZE = 8  # [n_x, n_y, dn_x/dt, dn_y/dt, z (m), dz/dt (m/s), valid, coasted steps]


@dataclass
class DeckTrackerConfig:
    """The two tracks' tuning (ours; seed 000 gives no numbers). A ship-like deck moves slowly: the
    stewart-dynamic deck's accelerations are under 1 cm/s^2 and 1 deg/s^2 (0.05 allows a livelier one);
    the frames' errors are millimetres and tenths of a degree (ATDA's z, a centimetre at 2 m).
    max_coast_steps: camera frames bridged without a pose, 1.5 s at 20 Hz (the blind last half metre of a
    descent at 0.4 m/s takes about one second)."""

    position: TrackFilterParams = field(default_factory=lambda: TrackFilterParams(
        measurement_std=0.01, acceleration_std=0.05, initial_velocity_std=0.2, max_coast_steps=30))  # m
    attitude: TrackFilterParams = field(default_factory=lambda: TrackFilterParams(
        measurement_std=0.005, acceleration_std=0.05, initial_velocity_std=0.2, max_coast_steps=30))  # rad
    gate_chi2: float = 30.0  # chi-square with 3 degrees of freedom beyond which a frame is an outlier (p = 1e-6)
    # Frames in a row, each within the gate of the track the ones before it made, before a new track is valid.
    # Until then a frame outside the gate starts the track afresh from itself: a track started on one wrong
    # frame (CRHF's first frame, 9 deg off with stewart-hardware's sensors) would otherwise gate every right
    # frame after it and steer, coasting and wrong, for max_coast_steps.
    confirm_frames: int = 3
    # Frames in a row that confirmed tracks gate but that agree with each other, after which they replace the
    # tracks: the tracks had gone wrong, not the frames (on the livelier deck, tracks restarted on a re-acquired
    # tag fitted a rate to its first frames' drift, gated every frame after and coasted 25 deg off for 1.5 s).
    takeover_frames: int = 3

    def validate(self, prefix: str = "deck_tracker") -> None:
        require_positive(self.gate_chi2, f"{prefix}.gate_chi2")
        require(self.confirm_frames >= 1, f"{prefix}.confirm_frames must be at least 1")
        # A challenger takes over confirmed: one that had not been would make the estimate invalid.
        require(self.takeover_frames >= max(self.confirm_frames, 2),
                f"{prefix}.takeover_frames must be at least 2 and at least {prefix}.confirm_frames "
                f"({self.confirm_frames}), got {self.takeover_frames}")
        for name in ("position", "attitude"):
            getattr(self, name).validate(f"{prefix}.{name}")


def tilt_deg(n_xy: np.ndarray) -> np.ndarray:
    """The deck's tilt [deg] from its normal's x and y components in W, the last axis of `n_xy` (deck_motion's
    first two entries, or a prediction's): |n_xy| = sin(tilt)."""
    n_xy = np.asarray(n_xy, dtype=float)
    return np.degrees(np.arcsin(np.minimum(np.hypot(n_xy[..., 0], n_xy[..., 1]), 1.0)))


def tilt_rotation(n_xy: np.ndarray) -> RotationMatrix:
    """R_tilt: the smallest rotation taking z_W onto the unit normal whose x and y components are n_xy."""
    n_xy = np.asarray(n_xy, dtype=float)
    s = float(np.linalg.norm(n_xy))
    if s < 1e-12:
        return RotationMatrix()
    angle = math.asin(min(s, 1.0))
    axis = np.array([-n_xy[1], n_xy[0], 0.0]) / s  # z x n, normalised
    return RotationMatrix(_axis_angle(axis, angle))


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def attitude_coordinates(R_WP: RotationMatrix) -> np.ndarray:
    """[n_x, n_y, yaw] of a deck attitude (module docstring); yaw in (-pi, pi]."""
    n = R_WP.col(2)
    R_yaw = tilt_rotation(n[:2]).inverse().multiply(R_WP).matrix()
    return np.array([n[0], n[1], math.atan2(R_yaw[1, 0], R_yaw[0, 0])])


def attitude_rotation(coordinates: np.ndarray) -> RotationMatrix:
    """R_WP from [n_x, n_y, yaw] (the inverse of attitude_coordinates)."""
    return tilt_rotation(coordinates[:2]).multiply(RotationMatrix.MakeZRotation(float(coordinates[2])))


@dataclass(frozen=True)
class DeckTrack:
    """The tracks stepped at `time` [s] (None before the first frame): position (p_WP) and attitude, of the
    deck as it was at the frames' exposure (`deck_estimate`'s lag_s earlier)."""

    time: float | None = None
    position: Track = field(default_factory=Track)
    attitude: Track = field(default_factory=Track)
    frames_used: int = 0  # since the tracks started
    challenger: "DeckTrack | None" = None  # tracks started on the frames these gated in a row, if any

    @property
    def tracking(self) -> bool:
        """The tracks hold the deck, confirmed or not."""
        return self.position.valid and self.attitude.valid

    def confirmed(self, config: DeckTrackerConfig) -> bool:
        """Tracking, on at least config.confirm_frames frames: the estimate may steer."""
        return self.tracking and self.frames_used >= config.confirm_frames

    @property
    def coasted_steps(self) -> int:
        return self.position.coasted_steps


def _measurement(track: DeckTrack, X_WP: RigidTransform, config: DeckTrackerConfig, params: tuple
                 ) -> tuple[np.ndarray, np.ndarray, bool]:
    """(position, attitude coordinates, outside the gate) of a frame's X_WP next to `track`: the heading
    unwrapped next to the track's, the gate's chi-square on the centre or on the attitude."""
    position = X_WP.translation()
    attitude = attitude_coordinates(X_WP.rotation())
    if track.attitude.valid:
        yaw = track.attitude.x[2]
        attitude[2] = yaw + math.remainder(attitude[2] - yaw, 2 * math.pi)
    gated = track.tracking and max(innovation_distance(track.position, position, params[0]),
                                   innovation_distance(track.attitude, attitude, params[1])) > config.gate_chi2
    return position, attitude, gated


def _stepped(track: DeckTrack, position: np.ndarray | None, attitude: np.ndarray | None, time: float,
             params: tuple, challenger: DeckTrack | None = None) -> DeckTrack:
    """The tracks advanced one frame and updated with a measurement (None: coast), counting the frames used."""
    stepped = DeckTrack(time, step_track(track.position, position, params[0]),
                        step_track(track.attitude, attitude, params[1]),
                        track.frames_used + (position is not None), challenger)
    return stepped if stepped.tracking else replace(stepped, frames_used=0)


def step_deck_track(track: DeckTrack, X_WP_measured: RigidTransform | None, time: float,
                    config: DeckTrackerConfig, period_s: float) -> DeckTrack:
    """One camera frame arriving at `time`: the tracks advanced by period_s and updated with X_WP_measured
    (None, or one with a non-finite entry: coast), the deck at the frame's exposure. A frame outside the gate
    starts unconfirmed tracks afresh; confirmed ones do not use it, and it feeds their challenger instead."""
    params = replace(config.position, dt_s=period_s), replace(config.attitude, dt_s=period_s)
    if X_WP_measured is None or not np.all(np.isfinite(X_WP_measured.GetAsMatrix34())):
        return _stepped(track, None, None, time, params)
    position, attitude, gated = _measurement(track, X_WP_measured, config, params)
    if not gated:
        return _stepped(track, position, attitude, time, params)
    if not track.confirmed(config):
        return _stepped(DeckTrack(), position, attitude, time, params)
    # Gated by confirmed tracks: the frame starts or feeds the challenger (afresh if outside its own gate);
    # takeover_frames of them in a row that agree replace the tracks, which had gone wrong, not the frames.
    challenger = track.challenger or DeckTrack()
    c_position, c_attitude, c_gated = _measurement(challenger, X_WP_measured, config, params)
    challenger = _stepped(DeckTrack() if c_gated else challenger, c_position, c_attitude, time, params)
    if challenger.frames_used >= config.takeover_frames:
        return challenger
    return _stepped(track, None, None, time, params, challenger)


def predicted(track: Track, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(values, rates, values' variances) of a valid constant-velocity track predicted dt [s] ahead
    (without the process noise over dt: dt is the frames' lag plus under a frame, a few frames at most)."""
    n = len(track.x) // 2
    values, rates = track.x[:n] + dt * track.x[n:], track.x[n:]
    P = track.P
    variances = np.diag(P)[:n] + 2 * dt * np.diag(P[:n, n:]) + dt * dt * np.diag(P)[n:]
    return values, rates, variances


def deck_estimate(track: DeckTrack, time: float, config: DeckTrackerConfig, lag_s: float = 0.0
                  ) -> tuple[PoseEstimate, np.ndarray, np.ndarray]:
    """(PoseEstimate of X_WP, v_WP [m/s], deck_motion (DECK_MOTION_SIZE)) at `time` [s]: the tracks
    predicted from their last frame's exposure, lag_s [s] before it arrived; invalid (zeros) unless they are
    tracking, confirmed."""
    motion = np.zeros(DECK_MOTION_SIZE)
    if not track.confirmed(config):
        return PoseEstimate.invalid(time, "W", "P"), np.zeros(3), motion
    dt = time - (track.time - lag_s)
    p, v, p_var = predicted(track.position, dt)
    a, a_rate, a_var = predicted(track.attitude, dt)
    covariance = np.diag(np.r_[a_var[1], a_var[0], a_var[2], p_var])  # [roll, pitch, yaw, x, y, z]: small tilts
    estimate = PoseEstimate(time, RigidTransform(attitude_rotation(a), p), True, covariance, "W", "P")
    motion[:] = [a[0], a[1], a_rate[0], a_rate[1], p[2], v[2], 1.0, track.coasted_steps]
    return estimate, v, motion


class DeckTracker(LeafSystem):
    """Inputs `X_CT_estimate` (PoseEstimate of the tag in the camera: CRHF's or ATDA's) and `X_WB`
    (RigidTransform, the UAV's own pose: its navigation). Stepped at the camera's `period_s` (read
    the estimator only then; SteppedValue: a reader at a frame time sees that frame). Outputs at any
    time, predicted to it: `X_WP_estimate` (PoseEstimate of the deck in W), `v_WP_estimate` (3, m/s)
    and `deck_motion` (DECK_MOTION_SIZE: module docstring's tilt components and rates, heave and its
    rate, valid, coasted frames).

    latency_s [s]: the frames' age on arrival (exposure to estimate). Both inputs are then of the exposure
    (the diagram delays X_WB as the estimator's frames are delayed), and the outputs are predicted from it."""

    def __init__(self, config: DeckTrackerConfig, X_BC: RigidTransform, X_TP: RigidTransform, period_s: float,
                 latency_s: float = 0.0):
        super().__init__()
        config.validate()
        require(latency_s >= 0, f"deck tracker latency_s must not be negative, got {latency_s}")
        self._config, self._X_BC, self._X_TP, self._period = config, X_BC, X_TP, period_s
        self._estimate_in = self.DeclareAbstractInputPort("X_CT_estimate", AbstractValue.Make(PoseEstimate()))
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        now = SteppedValue(self, "deck_track", DeckTrack(), period_s, self._step, lambda track: track.time).now
        self._estimate = self.DeclareCacheEntry("estimate", ValueProducer(
            allocate=lambda: AbstractValue.Make(deck_estimate(DeckTrack(), 0.0, config)),
            calc=lambda c, v: v.set_value(deck_estimate(now.Eval(c), c.get_time(), config, latency_s))),
            {now.ticket()})
        ticket = {self._estimate.ticket()}
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._estimate.Eval(c)[0]), ticket)
        self.DeclareVectorOutputPort("v_WP_estimate", 3, lambda c, o: o.SetFromVector(self._estimate.Eval(c)[1]),
                                     ticket)
        self.DeclareVectorOutputPort("deck_motion", DECK_MOTION_SIZE,
                                     lambda c, o: o.SetFromVector(self._estimate.Eval(c)[2]), ticket)

    def _step(self, context, track: DeckTrack) -> DeckTrack:
        estimate = self._estimate_in.Eval(context)
        X_WP = None
        if estimate.valid:
            X_WP = self._X_WB.Eval(context).multiply(self._X_BC).multiply(estimate.X_CT).multiply(self._X_TP)
        return step_deck_track(track, X_WP, context.get_time(), self._config, self._period)
