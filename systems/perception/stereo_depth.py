"""Seed 003's stereo altitude (section 2.2.2): disparity by OpenCV's semi-global block matching, depth
from disparity (Eq. 11), and the mean depth of a central [M, N] window as the altitude (Eq. 12).

The MYNT SDK computed the paper's disparity in hardware; here it is `cv2.StereoSGBM` on the rectified
grey images (the paper names SGBM as the usual software choice). Only the window, its matching
margin and the disparity search range to its left are matched (`window_crop`): the altitude needs no
more, and it costs about a twentieth of the full 752 x 480 frame (6 against 117 ms, benchmarks/stereo.py).

Pure functions on numpy arrays first; `StereoAltimeter` wraps them as a LeafSystem.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer
from pydrake.systems.sensors import ImageRgba8U

from systems.config import require
from systems.perception.aruco import to_grey
from systems.sensors.camera import image_to_numpy
from systems.sensors.stereo import StereoConfig

SGBM_SCALE = 16  # cv2.StereoSGBM returns fixed-point disparities, 4 fractional bits


@dataclass
class StereoDepthConfig:
    """The matcher and the window. `num_disparities` 0 derives it from the camera: the smallest multiple
    of 16 whose search, disparities 0 to num_disparities - 1, covers f * baseline / min_altitude_m (64 px for
    the MYNT EYE down to 0.7 m)."""

    num_disparities: int = 0
    block_size: int = 5  # odd, 1..11 (OpenCV takes any odd size; 3..11 is the usual range for SGBM)
    uniqueness_ratio: int = 10  # per cent; OpenCV's docs: 5-15 is usually good enough
    speckle_window_size: int = 100  # OpenCV's docs: 50-200
    speckle_range: int = 2  # OpenCV's docs: 1 or 2 (times 16 inside)
    disp12_max_diff: int = 1  # left-right consistency check (px)
    window_rows: int = 100  # M: seed 003 section 3.2.3, "the 100 x 100 area located at the center point"
    window_cols: int = 100  # N
    crop_margin_px: int = 24  # matched context around the window (SGBM's paths and blocks)
    min_valid_fraction: float = 0.6  # below it, invalid (too close, under 0.66 m: 32-38 % of pixels matched wrongly)
    estimator: str = "mean"  # "mean": Eq. 12 as written; "median": a robust mean

    def validate(self, prefix: str = "stereo_depth", camera: StereoConfig | None = None) -> None:
        require(self.num_disparities >= 0 and self.num_disparities % 16 == 0,
                f"{prefix}.num_disparities must be 0 (derived) or a positive multiple of 16, got "
                f"{self.num_disparities}")
        require(self.block_size % 2 == 1 and 1 <= self.block_size <= 11,
                f"{prefix}.block_size must be odd and within 1..11, got {self.block_size}")
        require(0 <= self.uniqueness_ratio <= 100, f"{prefix}.uniqueness_ratio must be a percentage 0..100")
        require(self.speckle_window_size >= 0 and self.speckle_range >= 0,
                f"{prefix}.speckle_window_size and {prefix}.speckle_range must not be negative")
        require(self.window_rows > 0 and self.window_cols > 0,
                f"{prefix}.window_rows and {prefix}.window_cols must be positive, got "
                f"{self.window_rows} x {self.window_cols}")
        require(self.crop_margin_px >= 0, f"{prefix}.crop_margin_px must not be negative")
        require(0 < self.min_valid_fraction <= 1, f"{prefix}.min_valid_fraction must lie in (0, 1], got "
                                                  f"{self.min_valid_fraction}")
        require(self.estimator in ("mean", "median"),
                f"{prefix}.estimator must be 'mean' or 'median', got '{self.estimator}'")
        if camera is not None:
            require(self.window_rows <= camera.height and self.window_cols <= camera.width,
                    f"{prefix}: the {self.window_rows} x {self.window_cols} window is larger than the "
                    f"{camera.width} x {camera.height} image")
            if self.num_disparities:  # SGBM searches 0 .. num_disparities - 1
                require(self.num_disparities - 1 >= camera.max_disparity_px,
                        f"{prefix}.num_disparities ({self.num_disparities}) does not reach the disparity at "
                        f"min_altitude_m ({camera.max_disparity_px:.1f} px)")
            first = central_window((camera.height, camera.width), (camera.cx, camera.cy), self.window_rows,
                                   self.window_cols)[1].start
            require(first >= self.disparities_for(camera),
                    f"{prefix}.window_cols ({self.window_cols}) reaches column {first} of the image, inside the "
                    f"first {self.disparities_for(camera)} that SGBM leaves unmatched (num_disparities)")

    def disparities_for(self, camera: StereoConfig) -> int:
        """numDisparities: the configured one, or the smallest multiple of 16 whose search (0 to
        numDisparities - 1) covers the disparity at the camera's minimum altitude."""
        return self.num_disparities or 16 * math.ceil((camera.max_disparity_px + 1) / 16)


def make_matcher(num_disparities: int, config: StereoDepthConfig) -> cv2.StereoSGBM:
    """cv2.StereoSGBM on grey images, with P1 = 8 cn B^2 and P2 = 32 cn B^2 (cn = 1 channel, B the
    block size), the smoothness penalties OpenCV's documentation recommends."""
    b = config.block_size
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=b,
                                 P1=8 * b * b, P2=32 * b * b, disp12MaxDiff=config.disp12_max_diff,
                                 uniquenessRatio=config.uniqueness_ratio,
                                 speckleWindowSize=config.speckle_window_size, speckleRange=config.speckle_range,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)


def disparity(left_gray: np.ndarray, right_gray: np.ndarray, matcher: cv2.StereoSGBM) -> np.ndarray:
    """The left image's disparity (px, float32) by SGBM; NaN where there is no valid match."""
    raw = matcher.compute(left_gray, right_gray)
    d = raw.astype(np.float32) / SGBM_SCALE
    d[raw <= 0] = np.nan  # SGBM marks invalid pixels with (minDisparity - 1) * 16; 0 is infinitely far
    return d


def depth_from_disparity(d: np.ndarray, focal_length_px: float, baseline_m: float) -> np.ndarray:
    """Seed 003 Eq. 11: Z(i, j) = f_stereo * T_x / d(i, j) (m), NaN where d is NaN or not positive."""
    d = np.asarray(d, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d > 0, focal_length_px * baseline_m / d, np.nan)


def central_window(shape: tuple[int, int], centre_xy: tuple[float, float], rows: int, cols: int) -> tuple[slice, slice]:
    """Row and column slices of the rows x cols window centred on `centre_xy` (px, OpenCV), clipped
    to the image."""
    height, width = shape[:2]
    r0 = min(max(round(centre_xy[1] - rows / 2 + 0.5), 0), height - rows)
    c0 = min(max(round(centre_xy[0] - cols / 2 + 0.5), 0), width - cols)
    return slice(r0, r0 + rows), slice(c0, c0 + cols)


def window_crop(shape: tuple[int, int], window: tuple[slice, slice], num_disparities: int,
                margin: int) -> tuple[slice, slice]:
    """The region of both images to match for the window: the window plus `margin` around it and the
    disparity search range to its left (SGBM leaves the first numDisparities columns of what it is
    given unmatched), clipped to the image. Cropping both images alike keeps every disparity."""
    height, width = shape[:2]
    rows, cols = window
    return (slice(max(rows.start - margin, 0), min(rows.stop + margin, height)),
            slice(max(cols.start - margin - num_disparities, 0), min(cols.stop + margin, width)))


def window_altitude(depth: np.ndarray, min_valid_fraction: float, estimator: str = "mean",
                    max_altitude_m: float = math.inf) -> tuple[float, bool, float]:
    """Seed 003 Eq. 12: the mean depth (m) over the window's valid pixels (`estimator` "median": their
    median). Returns (altitude m, valid, fraction of valid pixels); the altitude is NaN and valid False
    when fewer than `min_valid_fraction` of the window's pixels have a depth, or when it exceeds
    `max_altitude_m` (beyond the camera's range)."""
    finite = depth[np.isfinite(depth)]
    fraction = finite.size / depth.size if depth.size else 0.0
    if fraction < min_valid_fraction or finite.size == 0:
        return math.nan, False, fraction
    value = float(np.median(finite)) if estimator == "median" else float(finite.mean())
    if value > max_altitude_m:
        return math.nan, False, fraction
    return value, True, fraction


@dataclass
class StereoAltitude:
    """One frame's result: altitude (m, NaN when invalid), valid flag, fraction of valid pixels in the
    window, and the window's disparity (px, NaN where unmatched)."""

    altitude_m: float
    valid: bool
    valid_fraction: float
    window_disparity: np.ndarray


class StereoAltitudeEstimator:
    """The matcher and the window for one camera: `estimate(left, right)` on images (grey, RGB or RGBA)."""

    def __init__(self, camera: StereoConfig, config: StereoDepthConfig | None = None, crop: bool = True):
        self.camera, self.config = camera, config or StereoDepthConfig()
        camera.validate()
        self.config.validate(camera=camera)
        self.num_disparities = self.config.disparities_for(camera)
        # the nearest depth (m) whose disparity the search reaches (Eq. 11 at its largest, numDisparities - 1)
        self.nearest_m = camera.focal_length_px * camera.baseline_m / (self.num_disparities - 1)
        self.matcher = make_matcher(self.num_disparities, self.config)
        shape = (camera.height, camera.width)
        self.window = central_window(shape, (camera.cx, camera.cy), self.config.window_rows, self.config.window_cols)
        full = (slice(0, camera.height), slice(0, camera.width))
        self.crop = window_crop(shape, self.window, self.num_disparities, self.config.crop_margin_px) if crop else full

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """The disparity (px, NaN invalid) of the matched region `self.crop` of the left image."""
        rows, cols = self.crop
        return disparity(to_grey(np.ascontiguousarray(left[rows, cols])),
                         to_grey(np.ascontiguousarray(right[rows, cols])), self.matcher)

    def window_of(self, region_disparity: np.ndarray) -> np.ndarray:
        """The window's part of a disparity of the region `self.crop`."""
        rows, cols = self.window
        r, c = rows.start - self.crop[0].start, cols.start - self.crop[1].start
        return region_disparity[r:r + self.config.window_rows, c:c + self.config.window_cols]

    def altitude(self, window_disparity: np.ndarray) -> StereoAltitude:
        depth = depth_from_disparity(window_disparity, self.camera.focal_length_px, self.camera.baseline_m)
        value, valid, fraction = window_altitude(depth, self.config.min_valid_fraction, self.config.estimator,
                                                 self.camera.max_altitude_m)
        return StereoAltitude(value, valid, fraction, window_disparity)

    def estimate(self, left: np.ndarray, right: np.ndarray) -> StereoAltitude:
        return self.altitude(self.window_of(self.disparity(left, right)))


class StereoAltimeter(LeafSystem):
    """The altitude under the stereo pair (seed 003 Eq. 11-12) from the rectified left and right images.

    Inputs `left_image`, `right_image` (ImageRgba8U). Outputs `altitude` (1, m: the raw window depth,
    NaN when invalid) and `altitude_valid` (1: 1.0 or 0.0; 0.0 when fewer than min_valid_fraction of
    the window's pixels match or the altitude is beyond the camera's `max_altitude_m`). Both outputs
    come from one cache entry computed (and the images rendered) only when evaluated: consumers read it
    at the camera rate, as NoisyCamera's output.
    """

    def __init__(self, camera: StereoConfig, config: StereoDepthConfig | None = None):
        super().__init__()
        self.estimator = StereoAltitudeEstimator(camera, config)
        blank = ImageRgba8U(camera.width, camera.height)
        self._left = self.DeclareAbstractInputPort("left_image", AbstractValue.Make(blank))
        self._right = self.DeclareAbstractInputPort("right_image", AbstractValue.Make(blank))
        self._result = self.DeclareCacheEntry("stereo_altitude", ValueProducer(
            allocate=lambda: AbstractValue.Make((math.nan, False)), calc=self._calc_result),
            {self.all_input_ports_ticket()})
        self.DeclareVectorOutputPort("altitude", 1, self._calc_altitude, {self._result.ticket()})
        self.DeclareVectorOutputPort("altitude_valid", 1, self._calc_valid, {self._result.ticket()})

    def _calc_result(self, context, value):
        result = self.estimator.estimate(image_to_numpy(self._left.Eval(context)),
                                         image_to_numpy(self._right.Eval(context)))
        value.set_value((result.altitude_m, result.valid))

    def _calc_altitude(self, context, output):
        output.SetAtIndex(0, self._result.Eval(context)[0])

    def _calc_valid(self, context, output):
        output.SetAtIndex(0, 1.0 if self._result.Eval(context)[1] else 0.0)
