"""Camera-ToF calibration with coloured pads (seed 000, Sec. 2.3: Eq. 11-20, Table 1).

Each ToF sensor looks straight down at a pad of its own colour. As the drone rises, every frame
gives, per sensor, the range and the pixel of the pad's centroid; the calibration maps range to the
touch point's pixel, which the CRHF estimator needs in every frame (Eq. 40-45).

Pixels follow OpenCV (u right, v down, pixel centres at integers); ranges are metres.
"""

import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import least_squares

from systems.config import ConfigError

# Pad colour under sensors 1..4 of Eq. 21-24 (quadrants (-x,-y), (-x,+y), (+x,+y), (+x,-y) in C).
# Read off Table 2's pixels: red near (113, 113), yellow (112, 400), green (400, 400), blue
# (400, 113). (The text's "sensor 1 with its blue-coloured pad" contradicts Eq. 21 with Table 2.)
PAD_COLOURS = ("red", "yellow", "green", "blue")

# Table 1: exclusive bounds (low, high) on channels 1-3 = (Y, Cb, Cr) of Eq. 11.
# Eq. 11 is BT.601 studio range (Y in 16..235, Cb and Cr in 16..240), which is MATLAB's rgb2ycbcr
# for uint8 images, the tool the paper used; so Table 1 is read in those units. Full-range YCbCr
# (OpenCV's COLOR_RGB2YCrCb, JPEG) would shift every threshold, and a saturated red pad would
# reach Cr = 255 and fail Table 1's strict "Cr < 255", whereas in studio range it is 240.
YCBCR_RANGES = {
    "yellow": ((103, 255), (0, 95), (0, 255)),
    "red": ((0, 160), (0, 255), (167, 255)),
    "green": ((0, 255), (0, 155), (0, 90)),
    "blue": ((0, 165), (139, 255), (0, 255)),
}

# Pad colours (8-bit sRGB) that lie inside exactly one Table 1 range with margin. Pure green
# (0, 255, 0) would not do: its Y = 145 and Cb = 54 also satisfy the yellow range.
PAD_RGB = {
    "red": (220, 30, 30),
    "yellow": (230, 220, 20),
    "green": (0, 140, 0),
    "blue": (20, 40, 220),
}

# Eq. 11: studio-range BT.601 from R'G'B' in [0, 1].
_YCBCR_OFFSET = np.array([16.0, 128.0, 128.0], dtype=np.float32)
_YCBCR_MATRIX = np.array(
    [[65.481, 128.553, 24.966], [-37.797, -74.203, 112.0], [112.0, -93.786, -18.214]],
    dtype=np.float32,
)

MIN_SAMPLES = 3  # distinct ranges per sensor: more than the two parameters of Eq. 18


class CalibrationError(ConfigError):
    """A pad calibration that is missing, unreadable, has too few samples or was flown with another camera
    or ToF layout than the scene's."""


FLIGHT_RTOL = 1e-6  # relative tolerance within which a scene's camera and ToF layout are the calibration flight's


@dataclass(frozen=True, eq=False)
class CalibrationFlight:
    """The camera and ToF layout a pad calibration was flown with, which its pixels hold for no other.

    camera: (6,) the renderer's (true) [fx, fy, cx, cy] in px (OpenCV convention) and the image's
    [width, height] in px; distortion: (5,) the renderer's lens, OpenCV's [k1, k2, p1, p2, k3] (`camera.distortion`);
    p_C_sensors: (S, 3) the ToF sensors' origins in C, m."""

    camera: np.ndarray
    distortion: np.ndarray
    p_C_sensors: np.ndarray

    @classmethod
    def of(cls, camera, p_C_sensors: np.ndarray) -> "CalibrationFlight":
        """From a camera configuration (fx, fy, cx, cy, width, height and distortion attributes, as `CameraConfig`'s)
        and the sensors' positions in C (S, 3; m)."""
        return cls(np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height], dtype=float),
                   np.asarray(camera.distortion, dtype=float).reshape(5),
                   np.asarray(p_C_sensors, dtype=float).reshape(-1, 3))

    def mismatch(self, scene: "CalibrationFlight") -> str | None:
        """None when `scene` has this flight's camera and ToF layout (within FLIGHT_RTOL of each array's largest
        entry) and this flight had no lens, else what differs, naming both.

        The lens is not compared with the scene's: the tag detector undistorts the corners CRHF takes with the
        estimators' lens model into the pinhole image, and CRHF takes the calibration's pad pixels as they are,
        so they must be pinhole pixels too, in every scene: a flight through a lens is refused whatever the scene's
        (the scene's lens, imperfectly modelled, is its `calibration_error`, not the calibration's)."""

        def close(a: np.ndarray, b: np.ndarray) -> bool:
            return a.shape == b.shape and np.allclose(a, b, rtol=0.0, atol=FLIGHT_RTOL * np.abs(a).max())

        differences = []
        if not close(self.camera, scene.camera):
            differences.append(f"camera [fx, fy, cx, cy, width, height] {self.camera.tolist()} px, the scene's "
                               f"{scene.camera.tolist()} px")
        if np.any(self.distortion):
            differences.append(f"a lens, distortion [k1, k2, p1, p2, k3] {self.distortion.tolist()}, where CRHF "
                               "needs none (it takes the pad pixels as the pinhole image the tag's corners are "
                               "undistorted to)")
        if not close(self.p_C_sensors, scene.p_C_sensors):
            differences.append(f"ToF sensors at (x, y, z) {np.round(self.p_C_sensors, 6).tolist()} m in C, "
                               f"the scene's {np.round(scene.p_C_sensors, 6).tolist()} m")
        return "; ".join(differences) or None


def rgb_to_ycbcr(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 (Y, Cb, Cr) in studio range, Eq. 11, from an 8-bit RGB or RGBA image.

    Written from Eq. 11 rather than cv2.cvtColor, whose YCrCb is full range and ordered Y, Cr, Cb.
    """
    rgb = np.asarray(image)[..., :3].astype(np.float32) / 255.0
    return _YCBCR_OFFSET + rgb @ _YCBCR_MATRIX.T


def segment_colour(ycbcr: np.ndarray, colour: str) -> np.ndarray:
    """(H, W) uint8 mask, 1 where every channel lies strictly inside its Table 1 range."""
    mask = np.ones(ycbcr.shape[:2], dtype=bool)
    for channel, (low, high) in enumerate(YCBCR_RANGES[colour]):
        mask &= (ycbcr[..., channel] > low) & (ycbcr[..., channel] < high)
    return mask.astype(np.uint8)


def fill_largest_blob(mask: np.ndarray, min_area_px: int) -> np.ndarray | None:
    """The convex hull (Eq. 12-15) of the largest 8-connected blob of a 0/1 mask, filled.

    Returns an (H, W) uint8 0/1 mask, or None when no blob has at least min_area_px pixels.
    Filling the hull closes holes (specular highlights, the tag's shadow) in the pad. fillConvexPoly
    rasterises the hull's edges a little generously and unevenly: on drawn discs of radius 5-30 px
    this moves the centroid by up to 0.15 px.
    """
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count < 2:
        return None
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[largest, cv2.CC_STAT_AREA] < min_area_px:
        return None
    hull = cv2.convexHull(cv2.findNonZero((labels == largest).astype(np.uint8)))
    filled = np.zeros_like(mask)
    cv2.fillConvexPoly(filled, hull, 1)
    return filled


def blob_centroid(mask: np.ndarray) -> np.ndarray:
    """(u, v) pixel centroid of a non-empty 0/1 mask: the mean pixel coordinate of Eq. 16."""
    m = cv2.moments(mask, binaryImage=True)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def pad_centroids(
    image: np.ndarray, colours: tuple[str, ...] = PAD_COLOURS, min_area_px: int = 20
) -> np.ndarray:
    """(len(colours), 2) pad centroids (u, v) in pixels from an 8-bit RGB(A) image; NaN rows
    for pads not found (Sec. 2.3: Eq. 11 -> Table 1 -> convex hull -> Eq. 16)."""
    ycbcr = rgb_to_ycbcr(image)
    centroids = np.full((len(colours), 2), np.nan)
    for i, colour in enumerate(colours):
        blob = fill_largest_blob(segment_colour(ycbcr, colour), min_area_px)
        if blob is not None:
            centroids[i] = blob_centroid(blob)
    return centroids


class Hyperbola(NamedTuple):
    """pixel = a / range + c (Eq. 18); a in px*m, c in px."""

    a: float
    c: float

    def __call__(self, ranges):
        return self.a / np.asarray(ranges, dtype=float) + self.c


def fit_hyperbola(ranges: np.ndarray, pixels: np.ndarray, f_scale_px: float = 0.5) -> Hyperbola:
    """Robust fit of Eq. 18 to (range m, pixel) pairs.

    The paper fits by Least Absolute Residuals. The model is linear in (a, c) given 1/range, so an
    ordinary least-squares line starts SciPy's least_squares with the soft-L1 loss: quadratic for
    residuals below f_scale_px (sub-pixel centroid noise) and absolute above it, so outliers such
    as a mis-segmented frame pull on the fit as they would in LAR, while the loss stays smooth for
    the trust-region solver (LAR's |r| is not differentiable at zero).
    """
    x = 1.0 / np.asarray(ranges, dtype=float)
    y = np.asarray(pixels, dtype=float)
    start = np.polyfit(x, y, 1)
    fit = least_squares(lambda p: p[0] * x + p[1] - y, start, loss="soft_l1", f_scale=f_scale_px)
    return Hyperbola(float(fit.x[0]), float(fit.x[1]))


@dataclass(eq=False)
class SensorCalibration:
    """Range-to-pixel calibration of one sensor's touch point.

    colour: the sensor's pad colour. ranges: (N,) metres, strictly increasing. pixels: (N, 2)
    centroids (u, v). Construction drops non-finite samples, sorts by range and averages the pixels
    of repeated ranges; it raises CalibrationError below MIN_SAMPLES distinct positive ranges.
    Derived: fit_u, fit_v (Eq. 18) and interpolant, the shape-preserving PCHIP of Eq. 19-20
    (SciPy's PchipInterpolator: weighted harmonic-mean slopes, one-sided end slopes), NaN
    outside the calibrated ranges.
    """

    colour: str
    ranges: np.ndarray
    pixels: np.ndarray
    fit_u: Hyperbola = field(init=False)
    fit_v: Hyperbola = field(init=False)
    interpolant: PchipInterpolator = field(init=False, repr=False)

    def __post_init__(self):
        ranges = np.asarray(self.ranges, dtype=float).reshape(-1)
        pixels = np.asarray(self.pixels, dtype=float).reshape(-1, 2)
        keep = np.isfinite(ranges) & np.all(np.isfinite(pixels), axis=1) & (ranges > 0)
        self.ranges, inverse, counts = np.unique(
            ranges[keep], return_inverse=True, return_counts=True
        )
        self.pixels = np.zeros((len(self.ranges), 2))
        np.add.at(self.pixels, inverse, pixels[keep])
        self.pixels /= counts[:, None]
        if len(self.ranges) < MIN_SAMPLES:
            raise CalibrationError(
                f"{self.colour} pad: usable samples at {len(self.ranges)} distinct ranges, "
                f"at least {MIN_SAMPLES} are needed"
            )
        self.fit_u = fit_hyperbola(self.ranges, self.pixels[:, 0])
        self.fit_v = fit_hyperbola(self.ranges, self.pixels[:, 1])
        self.interpolant = PchipInterpolator(self.ranges, self.pixels, axis=0, extrapolate=False)


@dataclass(eq=False)
class PadCalibration:
    """Per-sensor range-to-pixel calibrations, in sensor order 1..4 of Eq. 21-24, and the camera and ToF
    layout they were flown with (None when unrecorded: a file written before flights were recorded)."""

    sensors: tuple[SensorCalibration, ...]
    flight: CalibrationFlight | None = None

    @classmethod
    def from_frames(
        cls, ranges: np.ndarray, pixels: np.ndarray, colours: tuple[str, ...] = PAD_COLOURS,
        flight: CalibrationFlight | None = None,
    ) -> "PadCalibration":
        """From per-frame samples: ranges (F, S) metres and pad centroids (F, S, 2) pixels, NaN
        where a sensor or pad gave nothing; S = len(colours); flight: the camera and ToF layout flown."""
        ranges = np.asarray(ranges, dtype=float)
        pixels = np.asarray(pixels, dtype=float)
        return cls(
            tuple(SensorCalibration(c, ranges[:, i], pixels[:, i]) for i, c in enumerate(colours)), flight
        )

    def touch_pixels(self, ranges: np.ndarray, method: str = "pchip") -> np.ndarray:
        """(S, 2) touch-point pixels (u, v) for one reading of each sensor's range, metres.

        method "pchip" is the paper's choice (Sec. 2.3) and gives NaN outside the calibrated
        ranges; "hyperbola" evaluates the Eq. 18 fits, which extrapolate.
        """
        if method == "pchip":
            return np.array([s.interpolant(r) for s, r in zip(self.sensors, ranges)])
        if method == "hyperbola":
            return np.array([[s.fit_u(r), s.fit_v(r)] for s, r in zip(self.sensors, ranges)])
        raise ValueError(f"unknown touch-pixel method {method!r}; use 'pchip' or 'hyperbola'")

    def implied_intrinsics(self, p_C_sensors: np.ndarray) -> np.ndarray:
        """(S, 4) [fx, fy, cx, cy] in pixels implied by each sensor's Eq. 18 fits.

        A pad under a sensor at (X, Y) in the camera's z = 0 plane (Eq. 21-24) is seen at
        u = fx X / range + cx, so a_u = fx X and c_u = cx (likewise v with Y and fy).
        p_C_sensors: (S, 3) sensor positions in C, metres.
        """
        p = np.asarray(p_C_sensors, dtype=float)
        return np.array(
            [
                [s.fit_u.a / x, s.fit_v.a / y, s.fit_u.c, s.fit_v.c]
                for s, (x, y) in zip(self.sensors, p[:, :2])
            ]
        )

    def save(self, path: str | os.PathLike) -> None:
        """Write the samples (the fits are rebuilt on load) and the flight, when known (arrays `flight_camera`,
        `flight_distortion` and `flight_p_C_sensors`), to an .npz file, atomically."""
        path = Path(path)
        arrays = {"colours": np.array([s.colour for s in self.sensors])}
        for i, s in enumerate(self.sensors):
            arrays[f"ranges_{i}"] = s.ranges
            arrays[f"pixels_{i}"] = s.pixels
        if self.flight is not None:
            arrays["flight_camera"] = self.flight.camera
            arrays["flight_distortion"] = self.flight.distortion
            arrays["flight_p_C_sensors"] = self.flight.p_C_sensors
        temporary = path.with_name(path.name + ".tmp")
        with open(temporary, "wb") as f:
            np.savez(f, **arrays)
        os.replace(temporary, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "PadCalibration":
        """Read a file written by `save` (flight None when the file records none); a CalibrationError names the
        file and the problem."""
        path = Path(path)
        if not path.is_file():
            raise CalibrationError(f"pad calibration file {path} does not exist")
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError, zipfile.BadZipFile) as error:
            raise CalibrationError(f"pad calibration file {path} is unreadable: {error}") from None
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise CalibrationError(f"pad calibration file {path} is not an .npz archive")
        try:  # the members are read here: an object array, or a damaged member, fails now
            with data:
                arrays = dict(data)
        except (OSError, ValueError, zipfile.BadZipFile) as error:
            raise CalibrationError(f"pad calibration file {path} is unreadable: {error}") from None
        if "colours" not in arrays:
            raise CalibrationError(f"pad calibration file {path} lacks the array 'colours'")
        colours = [str(c) for c in arrays["colours"]]
        wanted = [f"{kind}_{i}" for i in range(len(colours)) for kind in ("ranges", "pixels")]
        missing = [key for key in wanted if key not in arrays]
        if missing:
            raise CalibrationError(f"pad calibration file {path} lacks the arrays {missing}")
        shapes = {"flight_camera": (6,), "flight_distortion": (5,), "flight_p_C_sensors": (len(colours), 3)}
        flight_recorded = any(key in arrays for key in shapes)  # all three, or (a file from before flights) none
        if flight_recorded:
            if any(key not in arrays or arrays[key].shape != shape for key, shape in shapes.items()):
                raise CalibrationError(f"pad calibration file {path}: the flight needs flight_camera (6,), "
                                       f"flight_distortion (5,) and flight_p_C_sensors ({len(colours)}, 3); "
                                       "re-run `landing-sim run crhf-calibration` to write them")
        try:
            flight = CalibrationFlight(*(arrays[key].astype(float) for key in shapes)) if flight_recorded else None
            return cls(
                tuple(
                    SensorCalibration(c, arrays[f"ranges_{i}"], arrays[f"pixels_{i}"])
                    for i, c in enumerate(colours)
                ),
                flight,
            )
        except ValueError as error:  # CalibrationError, or arrays of the wrong shape or of no numbers
            raise CalibrationError(f"pad calibration file {path}: {error}") from None
