"""AprilTag 36h11 detection with OpenCV's ArUco module (cv2.aruco.DICT_APRILTAG_36h11)."""

from dataclasses import dataclass

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.aruco import subpix_detector, to_grey
from systems.sensors.camera import image_to_numpy, undistort_pixels


def tag_corners_T(tag_size_m: float) -> np.ndarray:
    """The black square's four corners (4x3, m) in the tag frame T, in ArUco's corner order:
    top-left, top-right, bottom-right, bottom-left of the tag as printed.

    T is the paper's camera-facing convention (seed 000 section 4.1): origin at the tag centre, x right
    and y down in the upright tag's image, z into the tag, so a tag seen head-on and upright by the
    camera C has R_CT = I. (OpenCV's marker frame for solvePnP has y up and z out of the tag: it is
    T rotated by pi about x.)"""
    s = tag_size_m / 2
    return np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])


@dataclass(frozen=True)
class TagDetection:
    """The tag's four corners in pixels (4x2, OpenCV convention), in ArUco order: top-left,
    top-right, bottom-right, bottom-left of the tag as printed; None when not detected. Where the
    detector was given a lens model, the corners are in that model's ideal (undistorted) pinhole image."""

    time: float = 0.0
    corners: np.ndarray | None = None

    @property
    def detected(self) -> bool:
        return self.corners is not None


class AprilTagDetector:
    """Finds one tag36h11 by id, corners refined with CORNER_REFINE_SUBPIX (`aruco.subpix_detector`).

    The image is thresholded once, with a `threshold_window_px` adaptive window, where OpenCV's default
    thresholds it three times (windows of 3, 13 and 23 px): on seed 000's frames from 0.55 to 7.5 m it
    finds the tag in the same frames, with corners within 0.02 px of the full search's (both are refined
    on the grey image), at a third to a fifth of the cost (docs/results.md)."""

    def __init__(self, tag_id: int, threshold_window_px: int = 23):
        self.tag_id = tag_id
        self._detector = subpix_detector("DICT_APRILTAG_36h11", threshold_window_px)

    def detect(self, rgb: np.ndarray) -> np.ndarray | None:
        """Corners (4x2 px) of the tag in an RGB, RGBA or grey uint8 image, or None."""
        corners, ids, _ = self._detector.detectMarkers(to_grey(rgb))
        if ids is None:
            return None
        matches = np.flatnonzero(ids.ravel() == self.tag_id)
        return corners[matches[0]].reshape(4, 2).astype(float) if len(matches) == 1 else None


class TagDetectorSystem(LeafSystem):
    """Detects the tag in `color_image` (ImageRgba8U) whenever a consumer evaluates its outputs.

    Outputs: tag_detection (TagDetection), tag_corners (8: u0, v0, ..., u3, v3 in px, NaN when not
    detected) and tag_detected ([1.0] or [0.0]). With `lens` = (K, D), the lens model the estimators
    are given, the corners are undistorted to the pinhole image of K (cv2.undistortPoints), so every
    estimator downstream sees a pinhole camera, as imperfectly as the model fits the lens."""

    def __init__(self, tag_id: int, width: int, height: int, lens: tuple[np.ndarray, np.ndarray] | None = None):
        super().__init__()
        self._detector = AprilTagDetector(tag_id)
        self._lens = lens if lens is not None and np.any(lens[1]) else None
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        detection = self.DeclareAbstractOutputPort("tag_detection", lambda: AbstractValue.Make(TagDetection()),
                                                   self._calc_detection)
        self.DeclareVectorOutputPort("tag_corners", 8, lambda c, o: o.SetFromVector(self._corners(c, detection)))
        self.DeclareVectorOutputPort(
            "tag_detected", 1,
            lambda c, o: o.SetFromVector([float(detection.Eval(c).detected)]))

    def _calc_detection(self, context, output):
        corners = self._detector.detect(image_to_numpy(self.get_input_port().Eval(context)))
        if corners is not None and self._lens is not None:
            corners = undistort_pixels(corners, *self._lens)
        output.set_value(TagDetection(context.get_time(), corners))

    @staticmethod
    def _corners(context, detection_port) -> np.ndarray:
        detection = detection_port.Eval(context)
        return detection.corners.ravel() if detection.detected else np.full(8, np.nan)


def project_points(K: np.ndarray, X_CT, points_T: np.ndarray) -> np.ndarray:
    """Pixels (Nx2, OpenCV convention) of points given in frame T, seen by an undistorted pinhole
    camera C with intrinsics K; projected by cv2.projectPoints."""
    X = X_CT.GetAsMatrix4()
    rvec, _ = cv2.Rodrigues(X[:3, :3])
    pixels, _ = cv2.projectPoints(np.asarray(points_T, dtype=float), rvec, X[:3, 3], K, None)
    return pixels.reshape(-1, 2)
