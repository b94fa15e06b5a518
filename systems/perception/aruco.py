"""OpenCV ArUco detection shared by the AprilTag (seed 000) and the pad markers (seed 002): the
dictionary by name, one detector per dictionary with sub-pixel corner refinement, and the grey
conversion of a camera image."""

from functools import lru_cache

import cv2
import numpy as np


@lru_cache(maxsize=None)
def aruco_dictionary(name: str):
    """The predefined cv2.aruco dictionary called `name` (e.g. "DICT_4X4_50")."""
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


@lru_cache(maxsize=None)
def subpix_detector(dictionary: str, threshold_window_px: int | None = None) -> cv2.aruco.ArucoDetector:
    """A detector for the named dictionary, corners refined with CORNER_REFINE_SUBPIX
    (CORNER_REFINE_APRILTAG returned whole-pixel corners on rendered frames, and at many times the
    cost: docs/results.md). With `threshold_window_px` (odd, >= 3) the image is thresholded once, with
    that adaptive window, where OpenCV's default thresholds it three times (windows of 3, 13 and 23 px):
    the thresholding and its contours are most of the detection's cost. The corners are refined on the
    grey image either way."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    if threshold_window_px is not None:
        parameters.adaptiveThreshWinSizeMin = parameters.adaptiveThreshWinSizeMax = threshold_window_px
    return cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), parameters)


def to_grey(image: np.ndarray) -> np.ndarray:
    """A grey uint8 image from an RGB, RGBA or grey one."""
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY if image.shape[2] == 4 else cv2.COLOR_RGB2GRAY)
