"""The pad's centre from the stereo pair's left eye, for the last metres of a landing (ours: seed 003 lands
blind below LH, where its target floods the fisheye).

Below about 1 m over the pad the fisheye's detector stops boxing the UGV as one target, and a box's centre no
longer marks the pad (measured: 0.2-0.3 m off at 1.5 m/s; a 2-3 s blind coast then ends 0.13-0.45 m off). The
left eye, a rectified pinhole looking down (94 x 69 deg), has the pad's ArUco markers in view down to the
last decimetres. Per image: OpenCV's ArUco detection and one solvePnP per marker
(systems/perception/marker_detector.py) give X_LM; each marker M lies upright on the pad (R_PM = I,
systems/perception/markers.py), so it places the pad's centre at p_LP = p_LM - R_LM p_PM; the median over the
markers found is the fix, kept when it lies within `height_tolerance_m` of the pad's known plane.
p_WP = X_WB X_BL p_LP with the UAV's navigation X_WB (W z up, metres).
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.config import require, require_positive
from systems.perception.marker_detector import detect_marker_poses
from systems.perception.markers import MarkerLayout
from systems.sensors.camera import image_to_numpy
from systems.sensors.stereo import StereoConfig


@dataclass
class StereoPadConfig:
    """The left eye's pad fix (metres). Ours: the paper has no such stage."""

    enabled: bool = True  # the builder adds the finder only when enabled (diagrams/hybrid_perception.py)
    height_tolerance_m: float = 0.15  # a fix further from the pad's plane is a wrong detection, not used
    # Searched only with the eye at most this high over the pad's plane (the UAV's navigation): the estimator
    # uses every fix it gets (hybrid_pad.py), and ArUco over the whole 752 x 480 eye costs milliseconds a frame.
    max_height_m: float = 3.0
    # ArUco's adaptive threshold window (px, odd): one pass where OpenCV's default makes three (3, 13, 23 px;
    # 0 here). On rendered views from 3 m down to 0.26 m it finds the same markers, the fix within 1 mm of
    # the default's, at 0.4-0.6x the cost (docs/results.md, Table 7).
    threshold_window_px: int = 23

    def validate(self, prefix: str = "hybrid.stereo_pad") -> None:
        require_positive(self.height_tolerance_m, f"{prefix}.height_tolerance_m")
        require_positive(self.max_height_m, f"{prefix}.max_height_m")
        require(self.threshold_window_px == 0 or (self.threshold_window_px >= 3 and self.threshold_window_px % 2 == 1),
                f"{prefix}.threshold_window_px must be 0 (OpenCV's three windows) or an odd number of pixels, "
                f"at least 3, got {self.threshold_window_px}")


def pad_centre_in_eye(image: np.ndarray, K: np.ndarray, layout: MarkerLayout,
                      threshold_window_px: int | None = None) -> np.ndarray | None:
    """p_LP [m], the pad's centre in the eye's frame L (+z along the optical axis), the median over the
    layout's markers found in `image` (uint8 RGB or RGBA of an undistorted pinhole with intrinsics K), or None.
    `threshold_window_px`: ArUco's one adaptive window (None: OpenCV's three)."""
    centres = []
    for m in detect_marker_poses(image, K, layout, threshold_window_px=threshold_window_px):
        X_LM = m.X_CM
        centres.append(X_LM.translation() - X_LM.rotation().multiply(layout.p_PM[layout.index(m.marker_id)]))
    return np.median(centres, axis=0) if centres else None


class StereoPadFinder(LeafSystem):
    """Inputs `left_image` (ImageRgba8U: the left eye's stream) and `X_WB` (RigidTransform: the UAV's
    navigation); output `p_WP` (3, m: the pad's centre in W, NaN when not found or the eye higher
    than `max_height_m` over the pad's plane).
    `z_pad` [m]: the pad's top above the ground, for the plane check."""

    def __init__(self, stereo: StereoConfig, layout: MarkerLayout, z_pad: float, config: StereoPadConfig | None = None):
        super().__init__()
        self._config = config or StereoPadConfig()
        self._config.validate()
        self._K, self._X_BL, self._layout, self._z_pad = stereo.eye().K, stereo.X_BL, layout, float(z_pad)
        self._image = self.DeclareAbstractInputPort("left_image", AbstractValue.Make(ImageRgba8U()))
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self.DeclareVectorOutputPort("p_WP", 3, self._calc)

    def _calc(self, context, output):
        X_WB = self._X_WB.Eval(context)
        X_WL = X_WB.multiply(self._X_BL)
        if X_WL.translation()[2] - self._z_pad > self._config.max_height_m:
            output.SetFromVector(np.full(3, np.nan))  # the image not even fetched: no render for it
            return
        output.SetFromVector(self.find(image_to_numpy(self._image.Eval(context)), X_WB))

    def find(self, image: np.ndarray, X_WB: RigidTransform) -> np.ndarray:
        """p_WP [m] from one left-eye image, NaN when not found (module docstring)."""
        p_LP = pad_centre_in_eye(image, self._K, self._layout, self._config.threshold_window_px or None)
        if p_LP is None:
            return np.full(3, np.nan)
        p_WP = X_WB.multiply(self._X_BL).multiply(p_LP)
        return p_WP if abs(p_WP[2] - self._z_pad) <= self._config.height_tolerance_m else np.full(3, np.nan)
