"""CRHF, Camera and Range sensor Homogeneous Fusion (seed 000 sections 2.4-2.8), as a LeafSystem.

Per camera frame: the corner Kalman filter (Eq. 28-35) tracks the detected tag corners through
short drop-outs; the four ToF ranges give the touch points and the deck plane (Eq. 21-27); the
pad calibration (section 2.3) gives the touch points' pixels, from which the frame's focal lengths
and principal point follow (Eq. 40-45); the corners are lifted onto the plane (Eq. 46-53) and
Arun's method gives X_CT (Eq. 54-62). The mathematics is in `crhf_math`; this wraps it.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from systems.estimators.corner_filter import CornerFilterParams, CornerTrack, step_corner_track
from systems.estimators.crhf_math import crhf_tag_pose
from systems.estimators.estimate import PoseEstimate
from systems.estimators.pad_calibration import PadCalibration
from systems.perception.apriltag import TagDetection, tag_corners_T

PACKAGE_ROOT = Path(__file__).resolve().parent.parent.parent
DEFAULT_CALIBRATION = "models/crhf_pad_calibration.npz"  # written by `landing-sim run crhf-calibration`


@dataclass
class CrhfConfig:
    """calibration_file: the pad calibration (relative paths are tried from the working directory,
    then from the project root). touch_pixels: "pchip" (the paper's choice) or "hyperbola"."""

    calibration_file: str = DEFAULT_CALIBRATION
    touch_pixels: str = "pchip"
    corner_filter: CornerFilterParams = field(default_factory=CornerFilterParams)

    def calibration_path(self) -> Path:
        path = Path(self.calibration_file)
        if path.is_absolute() or path.exists():
            return path
        return PACKAGE_ROOT / path


class CrhfEstimator(LeafSystem):
    """Inputs: tag_detection (TagDetection), ranges (4, m, NaN when invalid). Output:
    X_CT_estimate (PoseEstimate), updated at `period_s`; invalid when the corner track is lost, a
    range is invalid, the touch points are degenerate or a touch pixel is outside the calibration."""

    def __init__(self, config: CrhfConfig, p_C_sensors: np.ndarray, tag_size_m: float, period_s: float):
        super().__init__()
        self._calibration = PadCalibration.load(config.calibration_path())
        self._touch_method = config.touch_pixels
        self._filter = CornerFilterParams(**{**config.corner_filter.__dict__, "dt_s": period_s})
        self._p_C_sensors = np.asarray(p_C_sensors, dtype=float)
        self._p_T_corners = tag_corners_T(tag_size_m)
        self.DeclareAbstractInputPort("tag_detection", AbstractValue.Make(TagDetection()))
        self.DeclareVectorInputPort("ranges", 4)
        self._state = self.DeclareAbstractState(AbstractValue.Make((CornerTrack(), PoseEstimate())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._update)
        self.DeclareAbstractOutputPort("X_CT_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(c.get_abstract_state(self._state).get_value()[1]))

    def estimate(self, track: CornerTrack, ranges: np.ndarray, time: float) -> PoseEstimate:
        """The CRHF pose for one frame from the corner track and the four ranges (m)."""
        if not track.valid or not np.all(np.isfinite(ranges)):
            return PoseEstimate.invalid(time)
        uv_touch = self._calibration.touch_pixels(ranges, self._touch_method)
        result = crhf_tag_pose(self._p_C_sensors, ranges, uv_touch, track.corners, self._p_T_corners)
        return PoseEstimate(time, result.X_CT, True) if result.valid else PoseEstimate.invalid(time)

    def _update(self, context, state):
        track, _ = context.get_abstract_state(self._state).get_value()
        detection = self.get_input_port(0).Eval(context)
        track = step_corner_track(track, detection.corners, self._filter)
        ranges = self.get_input_port(1).Eval(context)
        state.get_mutable_abstract_state(self._state).set_value((track, self.estimate(track, ranges, context.get_time())))
