"""Seed 003's motion compensation (section 2.2.2, Eq. 7-10): the UGV's own pixel displacement between
two consecutive rectified frames, with the apparent motion of the ground (the UAV's own motion) removed.

Features are matched between the previous and the current grey frame, the UGV's box (plus a margin)
excluded from both so the vehicle's own motion does not enter the ground's model; a RANSAC homography H
(previous -> current pixels) fits the matches; the previous UGV location is mapped through H (Eq. 7,
normalised by Eq. 8-9) and the displacement is the current location minus the mapped one (Eq. 10 is
its length). Pixels are OpenCV's (centres at integers), in the rectified pinhole view; a box [x, y, w, h]
is the project's (pixel-index space, box_tracker.py), its centre in those pixels `box_centre_pixel`.

Features: ORB (FAST corners, rBRIEF descriptors, brute-force Hamming matching with Lowe's ratio test) by
default, where the paper used SIFT-GPU; `detector: sift` gives the paper's choice. ORB's keypoints sit on
its pyramid levels' pixel grids, so its homography alone was 0.4 px off at the image's corners (median;
up to 1.1 px). A step the paper does not describe fixes that: RANSAC's inliers are refined by
Lucas-Kanade on the previous frame warped by RANSAC's first H, and RANSAC runs again on them. With it
both detectors land within 0.04 px (median 0.015 px, at up to 30 deg of yaw a frame), and an ORB step
costs 6.8 ms against SIFT's 60.6 ms on one core at 512 x 512 (500 features each), most of SIFT's in its
detection (benchmarks/motion_compensation.py): hence ORB.

A frame pair whose ground gives too few matches or inliers, inliers over too small a part of the image,
or an implausible H (a fold, or a scale change past `max_scale_change`) is flagged invalid, with the
reason; nothing here raises on a bad frame. Pure functions first; `MotionCompensator` wraps them.
"""

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.config import require
from systems.perception.aruco import to_grey
from systems.perception.box_tracker import box_centre_pixel
from systems.sensors.camera import image_to_numpy
from systems.stepped import SteppedValue

DETECTORS = ("orb", "sift")
NO_BOX = np.full(4, np.nan)


@dataclass
class MotionCompensationConfig:
    """Features, matching, RANSAC (px) and the validity checks; the rate in Hz."""

    detector: str = "orb"  # "orb" or "sift" (the paper's, section 2.2.2)
    max_features: int = 500  # per frame
    # ORB only: its pyramid's levels (scale 1.2 each; 3 span 1.44x, the per-frame scale check's 1.5 nearly)
    # and FAST's corner threshold (grey levels). With 1000 features, 8 levels and threshold 20 (OpenCV's
    # defaults) the homography was no more accurate, at twice the cost (benchmarks/motion_compensation.py).
    orb_levels: int = 3
    orb_fast_threshold: int = 30
    ratio: float = 0.8  # Lowe's ratio test: best match distance < ratio x second best
    # Sub-pixel refinement of RANSAC's inliers by Lucas-Kanade in a window of this side (px; 0: none):
    # ORB's keypoints lie on its pyramid levels' pixel grids (0.5-1.3 px rms), LK's points to about 0.1 px.
    refine_window_px: int = 11
    refine_max_shift_px: float = 2.0  # a match LK moves further is dropped
    ransac_threshold_px: float = 2.0  # findHomography's reprojection threshold
    ransac_confidence: float = 0.999
    ransac_max_iters: int = 2000
    box_margin_px: float = 8.0  # excluded around the UGV's box (the tracker's box is not exact)
    min_matches: int = 20  # fewer matches after the ratio test: invalid
    min_inliers: int = 15  # fewer RANSAC inliers: invalid
    min_inlier_ratio: float = 0.3  # inliers / matches
    min_inlier_spread: float = 0.1  # the inliers' convex hull over the image area
    max_scale_change: float = 1.5  # per frame, in either direction (image area ratio within its square)
    rate_hz: float = 10.0  # the fisheye's rate (systems/sensors/fisheye.py; seed 003 runs at about 9 Hz)

    def validate(self, prefix: str = "motion_compensation") -> None:
        require(self.detector in DETECTORS, f"{prefix}.detector must be one of {DETECTORS}, got '{self.detector}'")
        require(self.max_features >= 4, f"{prefix}.max_features must be at least 4, got {self.max_features}")
        require(self.orb_levels >= 1, f"{prefix}.orb_levels must be at least 1, got {self.orb_levels}")
        require(1 <= self.orb_fast_threshold <= 254,
                f"{prefix}.orb_fast_threshold must lie in [1, 254] grey levels, got {self.orb_fast_threshold}")
        require(0 < self.ratio <= 1, f"{prefix}.ratio must lie in (0, 1], got {self.ratio}")
        require(self.refine_window_px == 0 or self.refine_window_px >= 5,
                f"{prefix}.refine_window_px must be 0 (no refinement) or at least 5, got {self.refine_window_px}")
        require(self.refine_max_shift_px > 0, f"{prefix}.refine_max_shift_px must be positive")
        require(self.ransac_threshold_px > 0, f"{prefix}.ransac_threshold_px must be positive")
        require(0 < self.ransac_confidence < 1, f"{prefix}.ransac_confidence must lie in (0, 1)")
        require(self.ransac_max_iters >= 1, f"{prefix}.ransac_max_iters must be at least 1")
        require(self.box_margin_px >= 0, f"{prefix}.box_margin_px must not be negative")
        require(self.min_matches >= 4 and self.min_inliers >= 4,
                f"{prefix}.min_matches and {prefix}.min_inliers must be at least 4 (a homography's points)")
        require(0 <= self.min_inlier_ratio <= 1, f"{prefix}.min_inlier_ratio must lie in [0, 1]")
        require(0 <= self.min_inlier_spread <= 1, f"{prefix}.min_inlier_spread must lie in [0, 1]")
        require(self.max_scale_change > 1, f"{prefix}.max_scale_change must exceed 1")
        require(self.rate_hz > 0, f"{prefix}.rate_hz must be positive, got {self.rate_hz}")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


@dataclass
class Features:
    """One frame's keypoints (N x 2, px) and descriptors (N rows; None when N = 0)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    descriptors: np.ndarray | None = None


@dataclass
class GroundMotion:
    """The ground's homography between two frames: H (3 x 3, previous -> current px; NaN when invalid),
    matches after the ratio test, RANSAC inliers, their ratio and spread, valid, and why not ("")."""

    H: np.ndarray
    matches: int
    inliers: int
    inlier_ratio: float
    inlier_spread: float
    valid: bool
    reason: str = ""


@dataclass
class MotionCompensation:
    """One frame pair: the ground's motion and the UGV's compensated displacement (2, px per frame:
    current location minus the previous one mapped through H, Eq. 10's vector; NaN when not known)."""

    ground: GroundMotion
    displacement_px: np.ndarray

    @property
    def valid(self) -> bool:
        """The displacement is known: the ground's H is valid and both frames have a UGV box."""
        return self.ground.valid and bool(np.all(np.isfinite(self.displacement_px)))


def make_detector(config: MotionCompensationConfig) -> cv2.Feature2D:
    """cv2's ORB (with the config's levels and FAST threshold) or SIFT, with `max_features`."""
    if config.detector == "sift":
        return cv2.SIFT_create(nfeatures=config.max_features)
    return cv2.ORB_create(nfeatures=config.max_features, nlevels=config.orb_levels,
                          fastThreshold=config.orb_fast_threshold)


def make_matcher(config: MotionCompensationConfig) -> cv2.DescriptorMatcher:
    """Brute force: Hamming distance for ORB's binary descriptors, L2 for SIFT's."""
    return cv2.BFMatcher(cv2.NORM_HAMMING if config.detector == "orb" else cv2.NORM_L2)


def has_box(box) -> bool:
    """A box [x, y, w, h] (px) is given: finite, with positive width and height."""
    return box is not None and bool(np.all(np.isfinite(box))) and box[2] > 0 and box[3] > 0


def feature_mask(shape: tuple[int, ...], box=None, margin_px: float = 0.0) -> np.ndarray | None:
    """The detector's mask (uint8, 255 where features may lie): everything but the box grown by
    `margin_px`; None (no mask) without a box."""
    if not has_box(box):
        return None
    height, width = shape[:2]
    x0, x1 = (min(max(v, 0), width) for v in (math.floor(box[0] - margin_px), math.ceil(box[0] + box[2] + margin_px)))
    y0, y1 = (min(max(v, 0), height) for v in (math.floor(box[1] - margin_px), math.ceil(box[1] + box[3] + margin_px)))
    mask = np.full((height, width), 255, np.uint8)
    mask[y0:y1, x0:x1] = 0
    return mask


def detect_features(grey: np.ndarray, detector: cv2.Feature2D, box=None, margin_px: float = 0.0) -> Features:
    """Keypoints and descriptors of a grey frame outside the UGV's box (plus `margin_px`)."""
    keypoints, descriptors = detector.detectAndCompute(grey, feature_mask(grey.shape, box, margin_px))
    if descriptors is None or not keypoints:
        return Features()
    return Features(np.array([k.pt for k in keypoints], np.float32).reshape(-1, 2), descriptors)


def match_features(previous: Features, current: Features, matcher: cv2.DescriptorMatcher,
                   ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Matched points (previous, current; M x 2 px each) that pass the ratio test: a match is kept
    when its distance is under `ratio` times the second best's."""
    if previous.descriptors is None or current.descriptors is None or len(current.points) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    pairs = matcher.knnMatch(previous.descriptors, current.descriptors, k=2)
    kept = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    src = np.array([previous.points[m.queryIdx] for m in kept], np.float32).reshape(-1, 2)
    dst = np.array([current.points[m.trainIdx] for m in kept], np.float32).reshape(-1, 2)
    return src, dst


def map_point(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Seed 003 Eq. 7-9: p (px, or N x 2) mapped through H, [x', y', w'] = H [u, v, 1], then
    (x, y) = (x' / w', y' / w')."""
    p = np.asarray(p, dtype=float)
    q = np.c_[p.reshape(-1, 2), np.ones(p.size // 2)] @ np.asarray(H, dtype=float).T
    return (q[:, :2] / q[:, 2:]).reshape(p.shape)


def compensated_displacement(H: np.ndarray, p_previous: np.ndarray, p_current: np.ndarray) -> np.ndarray:
    """Seed 003 Eq. 10 as a vector (px per frame): p_current - H(p_previous); its norm is Eq. 10's
    f_pd, the UGV's own pixel displacement with the ground's apparent motion removed."""
    return np.asarray(p_current, dtype=float) - map_point(H, p_previous)


def plane_homography(K: np.ndarray, R_10: np.ndarray, p_10: np.ndarray, n_0: np.ndarray, d_0: float) -> np.ndarray:
    """The homography (previous -> current px) a plane induces between two views with intrinsics K:
    H = K (R_10 - p_10 n_0^T / d_0) K^-1, with the plane n_0 . x + d_0 = 0 in the previous camera frame
    C0 (n_0 unit, d_0 m), and x_1 = R_10 x_0 + p_10 taking C0's points to the current camera frame C1.
    For a ground below a camera at height h, n_0 is the ground's upward normal in C0 and d_0 = h."""
    K = np.asarray(K, dtype=float)
    H = K @ (np.asarray(R_10, float) - np.outer(p_10, n_0) / d_0) @ np.linalg.inv(K)
    return H / H[2, 2]


def homography_plausible(H: np.ndarray, shape: tuple[int, ...], max_scale_change: float) -> str:
    """"" when H maps the image's corners to a convex quadrilateral of the same orientation whose area
    is within max_scale_change^2 of the image's either way; else why not."""
    height, width = shape[:2]
    corners = np.array([[0, 0], [width, 0], [width, height], [0, height]], float)
    q = map_point(H, corners)
    if not np.all(np.isfinite(q)):
        return "homography maps the image to infinity"
    edges = np.roll(q, -1, axis=0) - q
    turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if not np.all(turns > 0):
        return "homography folds or mirrors the image"
    area = 0.5 * float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - q[:, 1] * np.roll(q[:, 0], -1)))
    ratio = area / (width * height)
    if not 1 / max_scale_change**2 <= ratio <= max_scale_change**2:
        return f"homography scales the image area by {ratio:.2f}"
    return ""


def ransac_homography(src: np.ndarray, dst: np.ndarray, config: MotionCompensationConfig,
                      refit: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """cv2.findHomography with RANSAC on matched points (previous -> current px): (H or None, inlier
    mask). With `refit`, H is then fitted by least squares to all the inliers (OpenCV 5's RANSAC result
    was the less accurate: 0.70 against 0.39 px at the image's corners on unrefined ORB matches)."""
    H, mask = cv2.findHomography(src, dst, cv2.RANSAC, config.ransac_threshold_px,
                                 maxIters=config.ransac_max_iters, confidence=config.ransac_confidence)
    if H is None or mask is None or not np.all(np.isfinite(H)):
        return None, np.zeros(len(src), bool)
    inlier = mask.ravel().astype(bool)
    if refit and inlier.sum() >= 4:
        fitted, _ = cv2.findHomography(src[inlier], dst[inlier], 0)
        H = fitted if fitted is not None and np.all(np.isfinite(fitted)) else H
    return H / H[2, 2], inlier


def refine_matches(previous_grey: np.ndarray, grey: np.ndarray, H: np.ndarray, src: np.ndarray, dst: np.ndarray,
                   window_px: int, max_shift_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Matches refined to sub-pixel: the previous frame is warped by the first estimate H into the current
    frame's geometry (so rotation and scale are gone), and Lucas-Kanade (cv2's, one level, from the
    descriptor match) finds where each previous point, at H(src) in the warped frame, lies in `grey`.
    Returns the matches LK keeps (moved by at most max_shift_px): (src, refined dst)."""
    height, width = grey.shape[:2]
    warped = cv2.warpPerspective(previous_grey, H, (width, height), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_REPLICATE)
    start = map_point(H, src).astype(np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    refined, status, _ = cv2.calcOpticalFlowPyrLK(warped, grey, start, dst.reshape(-1, 1, 2).copy(),
                                                  winSize=(window_px, window_px), maxLevel=0, criteria=criteria,
                                                  flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    refined = refined.reshape(-1, 2)
    kept = (status.ravel() == 1) & (np.linalg.norm(refined - dst, axis=1) <= max_shift_px)
    return src[kept], refined[kept].astype(np.float32)


def ground_homography(src: np.ndarray, dst: np.ndarray, shape: tuple[int, ...], config: MotionCompensationConfig,
                      previous_grey: np.ndarray | None = None, grey: np.ndarray | None = None) -> GroundMotion:
    """The ground's homography (previous -> current px) from matched points and its validity: RANSAC,
    then (given the frames and `refine_window_px`) the inliers refined by `refine_matches` and RANSAC
    again on them, H fitted by least squares to the final inliers each time."""
    matches, nan = len(src), np.full((3, 3), np.nan)
    if matches < config.min_matches:
        return GroundMotion(nan, matches, 0, 0.0, 0.0, False, f"{matches} matches (< {config.min_matches})")
    H, inlier = ransac_homography(src, dst, config)
    if H is None:
        return GroundMotion(nan, matches, 0, 0.0, 0.0, False, "RANSAC found no homography")
    src, dst = src[inlier], dst[inlier]
    if previous_grey is not None and grey is not None and config.refine_window_px and len(src) >= config.min_inliers:
        src, dst = refine_matches(previous_grey, grey, H, src, dst, config.refine_window_px, config.refine_max_shift_px)
        if len(src) < 4:
            return GroundMotion(nan, matches, 0, 0.0, 0.0, False,
                                f"{len(src)} matches left after refinement (a homography needs 4)")
        H, inlier = ransac_homography(src, dst, config)
        if H is None:
            return GroundMotion(nan, matches, 0, 0.0, 0.0, False, "RANSAC found no homography in the refined matches")
        src, dst = src[inlier], dst[inlier]
    inliers = len(src)
    ratio = inliers / matches
    spread = 0.0
    if inliers >= 3:
        spread = cv2.contourArea(cv2.convexHull(dst.reshape(-1, 1, 2))) / (shape[0] * shape[1])
    if inliers < config.min_inliers:
        reason = f"{inliers} inliers (< {config.min_inliers})"
    elif ratio < config.min_inlier_ratio:
        reason = f"inlier ratio {ratio:.2f} (< {config.min_inlier_ratio})"
    elif spread < config.min_inlier_spread:
        reason = f"inliers cover {spread:.1%} of the image (< {config.min_inlier_spread:.0%})"
    else:
        reason = homography_plausible(H, shape, config.max_scale_change)
    return GroundMotion(nan if reason else H, matches, inliers, ratio, spread, not reason, reason)


@dataclass
class Frame:
    """One frame as the compensator keeps it: the grey image, its features (the box excluded) and the
    UGV's box [x, y, w, h] (px; NaN when none)."""

    grey: np.ndarray
    features: Features
    box: np.ndarray


def make_frame(grey: np.ndarray, box, detector: cv2.Feature2D, config: MotionCompensationConfig) -> Frame:
    """A grey frame's features outside the UGV's box grown by `box_margin_px`."""
    box = NO_BOX.copy() if box is None else np.asarray(box, dtype=float)
    return Frame(grey, detect_features(grey, detector, box, config.box_margin_px), box)


def compensate_frames(previous: Frame, current: Frame, config: MotionCompensationConfig,
                      matcher: cv2.DescriptorMatcher) -> MotionCompensation:
    """Seed 003 section 2.2.2 between two frames: matches (ratio test, then refined), the ground's
    homography, and the UGV's compensated displacement (NaN unless both frames have a box)."""
    src, dst = match_features(previous.features, current.features, matcher, config.ratio)
    ground = ground_homography(src, dst, current.grey.shape, config, previous.grey, current.grey)
    displacement = np.full(2, np.nan)
    if ground.valid and has_box(previous.box) and has_box(current.box):
        displacement = compensated_displacement(ground.H, box_centre_pixel(previous.box),
                                                box_centre_pixel(current.box))
    return MotionCompensation(ground, displacement)


def compensate(previous_grey: np.ndarray, grey: np.ndarray, previous_box=None, box=None,
               config: MotionCompensationConfig | None = None) -> MotionCompensation:
    """The whole of section 2.2.2 on two grey frames and the UGV's boxes [x, y, w, h] (px, None or NaN
    when none): features outside the boxes, the ground's homography, the compensated displacement."""
    config = config or MotionCompensationConfig()
    detector = make_detector(config)
    return compensate_frames(make_frame(previous_grey, previous_box, detector, config),
                             make_frame(grey, box, detector, config), config, make_matcher(config))


@dataclass
class CompensatorStep:
    """The compensator after a frame: its time (None before the first), the frame (kept for the next
    one) and the result (None on the first frame)."""

    time: float | None = None
    frame: Frame | None = None
    result: MotionCompensation | None = None


class MotionCompensator(LeafSystem):
    """Seed 003's motion compensation (section 2.2.2), stepped at `config.rate_hz`.

    Inputs `rectified_image` (ImageRgba8U, the rectified pinhole view) and `ugv_box` (4: [x, y, w, h]
    px, (x, y) the top-left corner; NaN when there is no UGV). Outputs `ugv_displacement` (2: px per
    frame, the UGV's own displacement since the previous step, NaN when not known), `valid` (1: 1.0
    when the displacement is known, else 0.0) and `homography` (9: the ground's H, previous -> current
    px, row-major, NaN when invalid). The state keeps the previous frame (grey image, features detected
    once with its box excluded, box), so each step detects in one frame; outputs at a step time already
    include that step (systems/stepped.py).
    """

    def __init__(self, width: int, height: int, config: MotionCompensationConfig | None = None):
        super().__init__()
        self._config = config or MotionCompensationConfig()
        self._config.validate()
        self._detector, self._matcher = make_detector(self._config), make_matcher(self._config)
        self._image = self.DeclareAbstractInputPort("rectified_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self._box = self.DeclareVectorInputPort("ugv_box", BasicVector(NO_BOX))
        self._now = SteppedValue(self, "motion_compensation", CompensatorStep(), self._config.period_s,
                                 self._step, lambda s: s.time).now
        prerequisites = {self._now.ticket()}
        self.DeclareVectorOutputPort("ugv_displacement", 2, self._calc_displacement, prerequisites)
        self.DeclareVectorOutputPort("valid", 1, self._calc_valid, prerequisites)
        self.DeclareVectorOutputPort("homography", 9, self._calc_homography, prerequisites)

    def _step(self, context, previous: CompensatorStep) -> CompensatorStep:
        grey = to_grey(image_to_numpy(self._image.Eval(context)))  # a new array (cvtColor), kept in the state
        frame = make_frame(grey, self._box.Eval(context), self._detector, self._config)
        result = None if previous.frame is None else compensate_frames(previous.frame, frame, self._config,
                                                                       self._matcher)
        return CompensatorStep(context.get_time(), frame, result)

    def _result(self, context) -> MotionCompensation | None:
        return self._now.Eval(context).result

    def _calc_displacement(self, context, output):
        result = self._result(context)
        output.SetFromVector(np.full(2, np.nan) if result is None else result.displacement_px)

    def _calc_valid(self, context, output):
        result = self._result(context)
        output.SetFromVector([1.0 if result is not None and result.valid else 0.0])

    def _calc_homography(self, context, output):
        result = self._result(context)
        output.SetFromVector(np.full(9, np.nan) if result is None else result.ground.H.ravel())
