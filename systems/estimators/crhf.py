"""CRHF, Camera and Range sensor Homogeneous Fusion (seed 000 sections 2.4-2.8), as a LeafSystem.

Per camera frame: the corner Kalman filter (Eq. 28-35) tracks the detected tag corners through
short drop-outs; the four ToF ranges, filtered by the same Kalman filter (our addition: the paper
uses each frame's raw ranges, whose 5 mm noise over the sensors' 0.19 m spacing tilts the plane by
about a degree from frame to frame), give the touch points and the deck plane (Eq. 21-27); the
pad calibration (section 2.3) gives the touch points' pixels, from which the frame's focal lengths
and principal point follow (Eq. 40-45); the corners are lifted onto the plane (Eq. 46-53) and
Arun's method gives X_CT (Eq. 54-62). The mathematics is in `crhf_math`; this wraps it.
"""

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from systems.config import require, require_positive

from systems.estimators.crhf_math import crhf_tag_pose
from systems.estimators.estimate import PoseEstimate
from systems.estimators.pad_calibration import PadCalibration
from systems.estimators.track_filter import Track, TrackFilterParams, step_track
from systems.perception.apriltag import TagDetection, tag_corners_T

PACKAGE_ROOT = Path(__file__).resolve().parent.parent.parent
DEFAULT_CALIBRATION = "models/crhf_pad_calibration.npz"  # written by `landing-sim run crhf-calibration`


@dataclass
class CrhfConfig:
    """calibration_file: the pad calibration (relative paths are tried from the working directory,
    then from the project root). touch_pixels: "pchip" (the paper's choice) or "hyperbola".
    corner_filter (px) and range_filter (m): the two Kalman filters; their dt_s is the camera
    period. filter_ranges: False feeds each frame's raw ranges to the plane fit, as the paper does."""

    calibration_file: str = DEFAULT_CALIBRATION
    touch_pixels: str = "pchip"
    # Both filters were tuned on stewart-dynamic (seed 0) and a random-walk deck (seed 1), each 100-200 s
    # (replaying logged measurements); the benchmark's unseen motions use other seeds.
    corner_filter: TrackFilterParams = field(default_factory=lambda: TrackFilterParams(
        measurement_std=1.0, acceleration_std=1000.0, initial_velocity_std=200.0))  # px
    range_filter: TrackFilterParams = field(default_factory=lambda: TrackFilterParams(
        measurement_std=0.005, acceleration_std=0.05, initial_velocity_std=0.2))  # m; VL53L1X-class noise
    filter_ranges: bool = True

    def validate(self, prefix: str = "crhf") -> None:
        require(self.touch_pixels in ("pchip", "hyperbola"),
                f"{prefix}.touch_pixels must be 'pchip' or 'hyperbola', got '{self.touch_pixels}'")
        for name in ("corner_filter", "range_filter"):
            params = getattr(self, name)
            for field_name in ("measurement_std", "acceleration_std", "initial_velocity_std"):
                require_positive(getattr(params, field_name), f"{prefix}.{name}.{field_name}")

    def calibration_path(self) -> Path:
        path = Path(self.calibration_file)
        if path.is_absolute() or path.exists():
            return path
        return PACKAGE_ROOT / path


class CrhfEstimator(LeafSystem):
    """Inputs: tag_detection (TagDetection), ranges (4, m, NaN when invalid). Output:
    X_CT_estimate (PoseEstimate) for the frame at the context's time; invalid when the corner track
    is lost, a range is invalid, the touch points are degenerate or a touch pixel is outside the
    calibration.

    The filters' tracks are state, advanced by a periodic update at `period_s`; the output is the
    estimate from the previous frame's tracks and this frame's measurements, computed once per
    frame in a cache entry that the output and the update share. So the estimate logged at a frame
    is that frame's (no one-frame lag); evaluate it only at frame times."""

    def __init__(self, config: CrhfConfig, p_C_sensors: np.ndarray, tag_size_m: float, period_s: float):
        super().__init__()
        config.validate()
        self._calibration = PadCalibration.load(config.calibration_path())
        self._touch_method = config.touch_pixels
        self._corner_filter = replace(config.corner_filter, dt_s=period_s)
        self._range_filter = replace(config.range_filter, dt_s=period_s) if config.filter_ranges else None
        self._p_C_sensors = np.asarray(p_C_sensors, dtype=float)
        self._p_T_corners = tag_corners_T(tag_size_m)
        self.DeclareAbstractInputPort("tag_detection", AbstractValue.Make(TagDetection()))
        self.DeclareVectorInputPort("ranges", 4)
        self._tracks = self.DeclareAbstractState(AbstractValue.Make((Track(), Track())))
        self._frame = self.DeclareCacheEntry(
            "frame", ValueProducer(allocate=lambda: AbstractValue.Make(((Track(), Track()), PoseEstimate())),
                                   calc=self._calc_frame))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._update)
        self.DeclareAbstractOutputPort("X_CT_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._frame.Eval(c)[1]),
                                       {self._frame.ticket()})

    def step(self, tracks: tuple[Track, Track], corners: np.ndarray | None, ranges: np.ndarray, time: float):
        """One frame: ((corner track, range track), PoseEstimate) from the previous tracks, the
        detected corners (4x2 px or None) and the ranges (4, m, NaN when invalid)."""
        corner_track = step_track(tracks[0], corners, self._corner_filter)
        range_track = step_track(tracks[1], ranges, self._range_filter) if self._range_filter else Track()
        if self._range_filter is not None:
            ranges = range_track.position if range_track.valid and np.all(np.isfinite(ranges)) else None
        return (corner_track, range_track), self.estimate(corner_track, ranges, time)

    def estimate(self, corner_track: Track, ranges: np.ndarray | None, time: float) -> PoseEstimate:
        """The CRHF pose from the tracked corners and four ranges (m); invalid if either is missing."""
        if not corner_track.valid or ranges is None or not np.all(np.isfinite(ranges)):
            return PoseEstimate.invalid(time)
        uv_touch = self._calibration.touch_pixels(ranges, self._touch_method)
        result = crhf_tag_pose(self._p_C_sensors, ranges, uv_touch, corner_track.position.reshape(4, 2),
                               self._p_T_corners)
        return PoseEstimate(time, result.X_CT, True) if result.valid else PoseEstimate.invalid(time)

    def _calc_frame(self, context, value):
        tracks = context.get_abstract_state(self._tracks).get_value()
        value.set_value(self.step(tracks, self.get_input_port(0).Eval(context).corners,
                                  self.get_input_port(1).Eval(context), context.get_time()))

    def _update(self, context, state):
        state.get_mutable_abstract_state(self._tracks).set_value(self._frame.Eval(context)[0])
