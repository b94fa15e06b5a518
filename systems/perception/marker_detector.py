"""The markers' real measurement source: the rendered image, OpenCV's ArUco detection and one
cv2.solvePnP per marker (SOLVEPNP_SQPNP: IPPE_SQUARE before OpenCV 5.1 fails on fronto-parallel
squares, see systems/estimators/atda.py); markers not detected are simply absent."""

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RotationMatrix
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.aruco import subpix_detector, to_grey
from systems.perception.markers import MarkerLayout, MarkerMeasurement, marker_corners_M
from systems.quaternion import drake_to_paper
from systems.sensors.camera import image_to_numpy


def detect_marker_poses(rgb: np.ndarray, K: np.ndarray, layout: MarkerLayout, time: float = 0.0,
                        threshold_window_px: int | None = None, D: np.ndarray | None = None) -> list[MarkerMeasurement]:
    """X_CM of every layout marker found in an RGB, RGBA (or grey) uint8 image from a pinhole camera with
    intrinsics K (OpenCV convention) and OpenCV's distortion coefficients D (None: undistorted), stamped
    `time` [s]. Markers not found, found twice, or whose PnP fails are absent. `threshold_window_px`: one
    adaptive threshold window (px) instead of OpenCV's three (`aruco.subpix_detector`)."""
    corners, ids, _ = subpix_detector(layout.dictionary, threshold_window_px).detectMarkers(to_grey(rgb))
    if ids is None:
        return []
    ids = ids.ravel()
    measurements = []
    for marker_id, marker_corners in zip(ids, corners):
        index = layout.index(int(marker_id))
        if index is None or np.count_nonzero(ids == marker_id) > 1:
            continue
        ok, rvec, tvec = cv2.solvePnP(marker_corners_M(layout.sizes_m[index]), marker_corners.reshape(4, 1, 2),
                                      np.asarray(K, dtype=float), D, flags=cv2.SOLVEPNP_SQPNP)
        if ok and np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec)):
            R_CM = RotationMatrix(cv2.Rodrigues(rvec)[0])
            measurements.append(MarkerMeasurement(time, int(marker_id), tvec.ravel(), drake_to_paper(R_CM)))
    return measurements


class MarkerDetectorSystem(LeafSystem):
    """Input `color_image` (ImageRgba8U); output `marker_measurements` (list of MarkerMeasurement,
    stamped with the context's time) from `detect_marker_poses` with the lens model K, D (the
    estimators' own, which may differ from the renderer's). Computed when evaluated: evaluate it at the
    camera rate."""

    def __init__(self, K: np.ndarray, layout: MarkerLayout, width: int, height: int, D: np.ndarray | None = None):
        super().__init__()
        layout.validate()
        self._K, self._layout = np.asarray(K, dtype=float), layout
        self._D = None if D is None or not np.any(D) else np.asarray(D, dtype=float)
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclareAbstractOutputPort("marker_measurements", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        image = image_to_numpy(self.get_input_port().Eval(context))
        output.set_value(detect_marker_poses(image, self._K, self._layout, context.get_time(), D=self._D))
