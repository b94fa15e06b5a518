"""The downward camera of seed 000: a 512x512 RgbdSensor rigidly on the airframe, plus lens
distortion (seed 001's camera has some) and pixel noise.

Pixel convention: intrinsics here are OpenCV's (pixel centres at integer coordinates), which is
what every vision function in the project uses. Drake's renderer puts pixel centres at
half-integers, so `camera_info` shifts the principal point by half a pixel when it builds Drake's
CameraInfo; rendered images then obey the OpenCV K exactly.
"""

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.sensors import CameraInfo, ImageRgba8U, RgbdSensor
from scipy.stats import norm

from systems.config import require, require_positive
from systems.noise import sample_index, sample_rng
from systems.stepped import in_intervals

RENDERER_NAME = "vtk"


@dataclass
class CalibrationErrorConfig:
    """How far the intrinsics the estimators are given (a calibration's result) are from the lens the
    renderer has (issue 13): focal lengths in per cent, principal point in pixels. Zero by default (the
    estimators know the renderer's K exactly). A chessboard calibration of a small camera typically
    leaves a few tenths of a per cent in the focal length and a few pixels in the principal point (the
    standard deviations OpenCV's calibrateCamera reports); seed 000 puts ATDA's 6.9 cm of z error
    (Table 5) down to imperfect calibration: about 3.4 % of focal length at 2 m. `k1`, `k2`: the
    radial distortion the estimators assume minus the lens's (`camera.distortion`)."""

    fx_pct: float = 0.0
    fy_pct: float = 0.0
    cx_px: float = 0.0
    cy_px: float = 0.0
    k1: float = 0.0
    k2: float = 0.0

    def validate(self, prefix: str = "camera.calibration_error") -> None:
        for name in ("fx_pct", "fy_pct"):
            require(abs(getattr(self, name)) < 50, f"{prefix}.{name} must be within +-50 %")
        for name in ("k1", "k2"):
            require(abs(getattr(self, name)) < 1, f"{prefix}.{name} must be within +-1")
        # (CameraConfig.validate keeps the principal point the estimators assume inside the image, and their
        # lens model from folding it.)


@dataclass
class CameraConfig:
    """Downward camera: intrinsics in pixels (OpenCV convention), rate in Hz, noise in 8-bit levels."""

    width: int = 512
    height: int = 512
    # Seed 000 Eq. (10), from MATLAB's calibrator, which counts the first pixel's centre as 1: in OpenCV's
    # convention the paper's lens has its principal point 1 px less on each axis. The simulated lens keeps Eq.
    # (10)'s numbers (docs/results.md's figures were measured with them) and the estimators are handed the same
    # K, so only where the optical axis meets the image differs from the paper's camera, by a pixel.
    fx: float = 458.5
    fy: float = 457.855
    cx: float = 258.7735
    cy: float = 252.308
    rate_hz: float = 20.0  # seed 000 section 3: 50 ms simulation step
    pixel_noise_std: float = 0.0  # std of additive Gaussian noise per channel, 8-bit levels
    # A sensor's own noise (issue 13), 0 for none: the electrons a pixel holds at level 255 (shot
    # noise grows with the square root of the signal) and the read noise in electrons.
    full_well_e: float = 0.0
    read_noise_e: float = 0.0
    # The sensor's analog gain over the exposure's signal: at gain g a level holds 1/g of the electrons
    # it holds at unity (a shorter exposure amplified back to the same brightness), so shot noise grows
    # by sqrt(g) and read noise by g. Needs full_well_e.
    analog_gain: float = 1.0
    near_m: float = 0.05
    far_m: float = 50.0
    # Camera frame C in the body frame B: below the body, optical axis down (+z_C = -z_B),
    # +x_C = +x_B (forward), so +y_C = -y_B.
    mount_xyz_m: list[float] = field(default_factory=lambda: [0.0, 0.0, -0.04])
    # Lens distortion applied to the rendered (pinhole) image: OpenCV's [k1, k2, p1, p2, k3].
    distortion: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])
    # Motion blur (issue 13): the exposure time [s]; 0: none. The smear is how far the scene at the
    # principal point moves across the image over the exposure, by the camera's rotation and its motion
    # relative to the deck (`AxisFlow`, `motion_blur_kernel`): one kernel for the whole image.
    exposure_s: float = 0.0
    # Faults: [start, end] intervals [s] in which the lens is covered (black frames).
    blackouts_s: list[list[float]] = field(default_factory=list)
    # The estimators' intrinsics (K_estimated) against the renderer's (K).
    calibration_error: CalibrationErrorConfig = field(default_factory=CalibrationErrorConfig)

    def validate(self, prefix: str = "camera") -> None:
        require(self.width > 0 and self.height > 0, f"{prefix}.width and {prefix}.height must be positive")
        for name in ("fx", "fy", "rate_hz", "near_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_render_limits(self, prefix)
        require(self.pixel_noise_std >= 0, f"{prefix}.pixel_noise_std must not be negative")
        require(self.full_well_e >= 0, f"{prefix}.full_well_e must not be negative")
        require(self.read_noise_e >= 0, f"{prefix}.read_noise_e must not be negative")
        require(0 <= self.exposure_s < self.period_s,
                f"{prefix}.exposure_s must lie within 0 and the frame period ({self.period_s:g} s), got {self.exposure_s}")
        require(self.read_noise_e == 0 or self.full_well_e > 0,
                f"{prefix}.read_noise_e needs {prefix}.full_well_e (the electrons at level 255) to convert it")
        require(self.analog_gain >= 1, f"{prefix}.analog_gain must be at least 1 (unity), got {self.analog_gain}")
        require(self.analog_gain == 1 or self.full_well_e > 0,
                f"{prefix}.analog_gain needs {prefix}.full_well_e (the electrons at level 255 at unity gain)")
        require(len(self.mount_xyz_m) == 3, f"{prefix}.mount_xyz_m needs 3 numbers")
        require(len(self.distortion) == 5, f"{prefix}.distortion needs 5 numbers [k1, k2, p1, p2, k3]")
        self.calibration_error.validate(f"{prefix}.calibration_error")
        e = self.calibration_error
        require(-0.5 < self.cx + e.cx_px < self.width - 0.5 and -0.5 < self.cy + e.cy_px < self.height - 0.5,
                f"{prefix}.calibration_error.cx_px and cy_px must keep the estimators' principal point inside the "
                f"image, got ({self.cx + e.cx_px:g}, {self.cy + e.cy_px:g})")
        for interval in self.blackouts_s:
            require(len(interval) == 2 and 0 <= interval[0] < interval[1],
                    f"{prefix}.blackouts_s needs [start, end] pairs with 0 <= start < end, got {interval}")
        K_e = self.K_estimated  # the estimators' lens model is D_estimated with their own intrinsics
        estimated = replace(self, fx=K_e[0, 0], fy=K_e[1, 1], cx=K_e[0, 2], cy=K_e[1, 2])
        for name, camera, D in (("distortion", self, self.D),
                                ("calibration_error (the estimators' lens model)", estimated, self.D_estimated)):
            if not np.any(D):
                continue
            folds = distortion_folds(camera, D)
            require(not folds, f"{prefix}.{name} folds the image (its radial map turns back at {folds:.0%} "
                               f"of the half-diagonal)")
            off, (u, v) = distortion_round_trip_px(camera, D)
            require(off <= MAX_ROUND_TRIP_PX, f"{prefix}.{name} cannot be inverted to {MAX_ROUND_TRIP_PX} px at "
                                              f"pixel ({u:g}, {v:g}): it maps back {off:.2g} px from itself")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (OpenCV convention)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_estimated(self) -> np.ndarray:
        """The intrinsic matrix the estimators are given: K with `calibration_error` (K itself by default)."""
        e = self.calibration_error
        return np.array([[self.fx * (1 + e.fx_pct / 100), 0.0, self.cx + e.cx_px],
                         [0.0, self.fy * (1 + e.fy_pct / 100), self.cy + e.cy_px], [0.0, 0.0, 1.0]])

    @property
    def D_estimated(self) -> np.ndarray:
        """The distortion coefficients the estimators are given: D with `calibration_error`'s k1, k2."""
        e = self.calibration_error
        return self.D + [e.k1, e.k2, 0.0, 0.0, 0.0]

    @property
    def X_BC(self) -> RigidTransform:
        """Pose of the camera frame C in the body frame B."""
        return RigidTransform(RotationMatrix.MakeXRotation(np.pi), self.mount_xyz_m)

    @property
    def D(self) -> np.ndarray:
        """The distortion coefficients as OpenCV takes them."""
        return np.asarray(self.distortion, dtype=float)


MAX_ROUND_TRIP_PX = 0.05  # a lens model that maps a pixel back farther than this from itself is refused
DEPTH_INSET = 0.01  # a depth camera's range lies this fraction inside its clipping range at each end (Drake's rule)


def require_render_limits(config, prefix: str) -> None:
    """What Drake's render camera takes, checked on a camera config's `width`, `height`, `cx`, `cy` (OpenCV's
    pixel centres at whole numbers: the image spans -0.5 to width - 0.5 px) and `near_m`, `far_m`, so that a
    setting it refuses is one line naming the key, not Drake's error at build time."""
    for name, size, bound in (("cx", config.width, "width"), ("cy", config.height, "height")):
        value = getattr(config, name)
        require(-0.5 < value < size - 0.5, f"{prefix}.{name} must lie inside the image (-0.5 < {name} < {bound} - 0.5, "
                                           f"pixel centres at whole numbers), got {value:g}")
    require(config.far_m * (1 - DEPTH_INSET) > config.near_m * (1 + DEPTH_INSET),
            f"{prefix}.far_m must exceed {prefix}.near_m by over 2 % (the depth range lies {DEPTH_INSET:.0%} inside "
            f"both), got {config.near_m:g} and {config.far_m:g}")


def depth_range(near_m: float, far_m: float) -> DepthRange:
    """The depth camera's range for the clipping range [near_m, far_m] [m]: DEPTH_INSET inside it at each end."""
    return DepthRange(near_m * (1 + DEPTH_INSET), far_m * (1 - DEPTH_INSET))


def distortion_folds(config: CameraConfig, D=None) -> float:
    """0 when the radial distortion r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) grows monotonically until it
    reaches the image's corners (normalised coordinates; the pinhole radius r a corner pixel samples lies
    beyond the corner's own radius under barrel distortion), else the fraction of the half-diagonal where
    the distorted image turns back (or, never reaching the corner within four times its radius, how far
    it gets). D: OpenCV's [k1, k2, p1, p2, k3] (default the lens's, config.distortion)."""
    k1, k2, _, _, k3 = config.distortion if D is None else D
    corner = max(np.hypot(u / config.fx, v / config.fy) for u in (config.cx, config.width - config.cx)
                 for v in (config.cy, config.height - config.cy))
    r = np.linspace(0.0, 4.0 * corner, 1600)
    r_d = r * (1 + k1 * r**2 + k2 * r**4 + k3 * r**6)
    slope = 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6
    reached = np.flatnonzero(r_d >= corner)
    end = reached[0] if reached.size else len(r) - 1
    bad = np.flatnonzero(slope[: end + 1] <= 0)
    if bad.size:
        return float(r_d[bad[0]] / corner)
    return 0.0 if reached.size else float(r_d.max() / corner)


def distortion_maps(config: CameraConfig) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's maps for the distorted image: where each of its pixels (OpenCV's integer centres)
    lies in the undistorted pinhole render with the same K (px; under barrel distortion the rim's lie
    outside it: `render_margin_px`)."""
    u, v = np.meshgrid(np.arange(config.width, dtype=np.float32), np.arange(config.height, dtype=np.float32))
    maps = undistort_pixels(np.stack([u.ravel(), v.ravel()], axis=1), config.K, config.D).reshape(
        config.height, config.width, 2)
    return maps[..., 0].astype(np.float32), maps[..., 1].astype(np.float32)


# cv2.undistortPoints' fixed-point iteration until the pixel it re-projects is within 1e-9 px of the one given:
# a strong barrel lens that does not fold (k1 -0.6, k2 0.2) needs about 500 iterations at the corners (40 left
# them 3 px off), a mild one (stewart-hardware's) under 20.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-9)


def undistort_pixels(pixels: np.ndarray, K: np.ndarray, D: np.ndarray | None) -> np.ndarray:
    """(N, 2) the pinhole camera K's pixels that the distorted image's pixels (N, 2; OpenCV's integer centres)
    look at, through the lens model D (OpenCV's [k1, k2, p1, p2, k3]; None or zeros: the pixels as given)."""
    points = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if D is None or not np.any(D):
        return points.reshape(-1, 2)
    return cv2.undistortPoints(points, K, D, None, None, K, _UNDISTORT_CRITERIA).reshape(-1, 2)


def _pixel_grid(config: CameraConfig, stride: int) -> np.ndarray:
    """(N, 2) pixels every `stride` along each axis, the last row and column included."""
    u = np.unique(np.r_[np.arange(0, config.width, stride), config.width - 1])
    v = np.unique(np.r_[np.arange(0, config.height, stride), config.height - 1])
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)


def distortion_round_trip_px(config: CameraConfig, D=None, stride: int = 8) -> tuple[float, np.ndarray]:
    """(the largest distance [px], the pixel (u, v) [px] where it is) between a pixel (every `stride`-th, the
    border's included) and its place in the pinhole render (`distortion_maps`' sample) distorted again by
    OpenCV's projectPoints: about 0 for a lens model D (default config.D) that undistortion inverts, hundreds
    of px where the model folds the image."""
    D = config.D if D is None else np.asarray(D, float)
    pixels = _pixel_grid(config, stride)
    rays = cv2.undistortPoints(undistort_pixels(pixels, config.K, D).reshape(-1, 1, 2), config.K, None)
    back, _ = cv2.projectPoints(cv2.convertPointsToHomogeneous(rays), np.zeros(3), np.zeros(3), config.K, D)
    off = np.linalg.norm(back.reshape(-1, 2) - pixels, axis=1)
    off = np.where(np.isfinite(off), off, math.inf)
    worst = int(np.argmax(off))
    return float(off[worst]), pixels[worst]


def render_margin_px(config: CameraConfig) -> int:
    """The pinhole render's extra pixels on every side [px] so that every pixel of the distorted image samples
    the scene (under barrel distortion the rim looks beyond the same-K pinhole image): 0 without distortion.
    From the border's pixels: a lens that does not fold maps the image's inside within them."""
    if not any(config.distortion):
        return 0
    w, h = config.width, config.height
    border = np.concatenate([[(u, v) for u in range(w) for v in (0, h - 1)],
                             [(u, v) for v in range(h) for u in (0, w - 1)]])
    x, y = undistort_pixels(border, config.K, config.D).T
    beyond = max(-x.min(), x.max() - (w - 1), -y.min(), y.max() - (h - 1))
    return math.ceil(max(float(beyond), 0.0)) + 1  # and the bilinear sample's neighbour


def camera_info(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> CameraInfo:
    """Drake's CameraInfo for OpenCV-convention intrinsics (adds the half-pixel offset)."""
    return CameraInfo(width, height, fx, fy, cx + 0.5, cy + 0.5)


def make_camera(config: CameraConfig, parent_frame_id, X_PC: RigidTransform) -> RgbdSensor:
    """An RgbdSensor at pose X_PC in the SceneGraph frame `parent_frame_id` (e.g. the body frame): the pinhole
    render with K, `render_margin_px` wider on every side (the principal point moved with it) when the lens
    distorts."""
    m = render_margin_px(config)
    core = RenderCameraCore(RENDERER_NAME, camera_info(config.width + 2 * m, config.height + 2 * m, config.fx,
                                                       config.fy, config.cx + m, config.cy + m),
                            ClippingRange(config.near_m, config.far_m), RigidTransform())
    return RgbdSensor(parent_frame_id, X_PC, ColorRenderCamera(core, False),
                      DepthRenderCamera(core, depth_range(config.near_m, config.far_m)))


def add_renderer(scene_graph: SceneGraph) -> None:
    """The VTK renderer every camera here uses (headless through EGL)."""
    scene_graph.AddRenderer(RENDERER_NAME, MakeRenderEngineVtk(RenderEngineVtkParams(
        default_clear_color=[0.85, 0.88, 0.9])))


def add_camera(builder: DiagramBuilder, scene_graph: SceneGraph, body_frame_id, config: CameraConfig,
               seed: int) -> tuple[RgbdSensor, "NoisyCamera"]:
    """The camera at config.X_BC on the SceneGraph frame `body_frame_id`, its images with seeded
    pixel noise: (RgbdSensor, NoisyCamera whose output is the camera stream). The scene graph needs
    `add_renderer`."""
    camera = builder.AddSystem(make_camera(config, body_frame_id, config.X_BC))
    builder.Connect(scene_graph.get_query_output_port(), camera.query_object_input_port())
    noisy_camera = builder.AddSystem(NoisyCamera(config, seed))
    builder.Connect(camera.color_image_output_port(), noisy_camera.GetInputPort("rendered_image"))
    return camera, noisy_camera


def image_to_numpy(image) -> np.ndarray:
    """A read-only numpy view (rows, cols, channels) of a Drake image, without copying."""
    return image.data


# The standard normal at 256 equiprobable quantiles, scaled to unit variance (tails cut at 2.9 sigma):
# a random byte through cv2.LUT draws one Gaussian sample, the cheapest way found to noise 512x512x3
# values per frame (docs/results.md). Alpha's column is zero, so alpha is never touched.
_Z = norm.ppf((np.arange(256) + 0.5) / 256)
_Z_RGB = np.zeros((1, 256, 4), np.float32)
_Z_RGB[0, :, :3] = (_Z / _Z.std())[:, None]


def noise_std_by_level(config: CameraConfig) -> np.ndarray:
    """The noise std (8-bit levels) of a pixel at each of the 256 levels: the flat `pixel_noise_std`
    plus, when `full_well_e` is set, photon shot noise (Poisson: variance = the electrons collected, a
    level v holding v / 255 of the full well over the analog gain) and read noise, each converted at
    analog_gain x 255 / full_well_e levels per electron; the three add in variance."""
    variance = np.full(256, config.pixel_noise_std**2)
    if config.full_well_e > 0:
        gain = config.analog_gain * 255.0 / config.full_well_e  # levels per electron
        variance += np.arange(256) * gain + (config.read_noise_e * gain) ** 2
    return np.sqrt(variance)


def motion_blur_flow(K: np.ndarray, axis_flow: np.ndarray, exposure_s: float) -> np.ndarray:
    """How far (px, [du, dv]) the scene at the principal point moves in the image over the exposure, for the
    rate at which it crosses the image (`axis_flow`, rad/s along C's x and y; ground_truth.axis_flow):
    (fx rate_x, fy rate_y) exposure_s. A camera turning at w_C over a still scene gives (-fx w_y, fy w_x)."""
    return np.array([K[0, 0] * axis_flow[0], K[1, 1] * axis_flow[1]]) * exposure_s


def motion_blur_kernel(flow_px: np.ndarray) -> np.ndarray | None:
    """The image of a point smeared uniformly along `flow_px` (a line of that length, centred, sub-pixel
    positions shared bilinearly; sums to 1), or None when the smear is under half a pixel."""
    length = float(np.hypot(*flow_px))
    if length < 0.5:
        return None
    size = 2 * int(np.ceil(length / 2)) + 3
    t = np.linspace(-0.5, 0.5, 8 * int(np.ceil(length)) + 1)
    u, v = size // 2 + t * flow_px[0], size // 2 + t * flow_px[1]
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    kernel = np.zeros((size, size))
    for du, dv, share in ((0, 0, (1 - a) * (1 - b)), (1, 0, a * (1 - b)), (0, 1, (1 - a) * b), (1, 1, a * b)):
        np.add.at(kernel, (v0 + dv, u0 + du), share)
    return (kernel / kernel.sum()).astype(np.float32)


def add_pixel_noise(rgba: np.ndarray, std, rng: np.random.Generator) -> np.ndarray:
    """RGBA uint8 image plus zero-mean Gaussian noise on R, G, B (rounded and saturated to 0-255); alpha
    untouched. `std` (8-bit levels) is one number, or 256 numbers: the std at each pixel level."""
    words = -(-rgba.size // 8)
    draws = rng.bit_generator.random_raw(words).view(np.uint8)[:rgba.size].reshape(rgba.shape)
    if np.ndim(std) == 0:
        return cv2.add(rgba, cv2.LUT(draws, _Z_RGB * np.float32(std)), dtype=cv2.CV_8U)
    level_std = np.zeros((1, 256, 4), np.float32)
    level_std[0, :, :3] = np.asarray(std, np.float32)[:, None]
    noise = cv2.multiply(cv2.LUT(draws, _Z_RGB), cv2.LUT(rgba, level_std))
    return cv2.add(rgba, noise, dtype=cv2.CV_8U)


class NoisyCamera(LeafSystem):
    """The lens and the sensor: the rendered pinhole image distorted by `config.distortion`
    (cv2.remap), smeared over `config.exposure_s` by the scene's motion across the image (input
    `axis_flow`, rad/s along C's x and y, from `AxisFlow`; declared only with an exposure; unconnected: no
    smear) and given seeded pixel noise
    (`noise_std_by_level`); black within `config.blackouts_s`.

    Input `rendered_image` (the pinhole render, `render_margin_px` wider on every side) and output
    `color_image` (width x height) are ImageRgba8U. The output is a pure function
    of the time's frame index, so it is computed (and the scene rendered) only when a consumer
    evaluates it; consumers evaluate it at the camera rate, in their periodic events.
    """

    def __init__(self, config: CameraConfig, seed: int = 0):
        super().__init__()
        self._std = noise_std_by_level(config) if config.full_well_e > 0 else config.pixel_noise_std
        self._period, self._seed = config.period_s, seed
        m = render_margin_px(config)
        self._maps = tuple(map_ + m for map_ in distortion_maps(config)) if any(config.distortion) else None
        self._blackouts = [tuple(interval) for interval in config.blackouts_s]
        self._K, self._exposure = config.K, config.exposure_s
        blank = ImageRgba8U(config.width, config.height)
        self._rendered = self.DeclareAbstractInputPort(
            "rendered_image", AbstractValue.Make(ImageRgba8U(config.width + 2 * m, config.height + 2 * m)))
        self._axis_flow = self.DeclareVectorInputPort("axis_flow", 2) if config.exposure_s > 0 else None
        self.DeclareAbstractOutputPort("color_image", lambda: AbstractValue.Make(blank), self._calc_image)

    def _calc_image(self, context, output):
        t = context.get_time()
        if in_intervals(t, self._blackouts):
            output.get_mutable_value().mutable_data[:] = 0
            output.get_mutable_value().mutable_data[..., 3] = 255
            return
        rendered = self._rendered.Eval(context)
        noisy = np.any(self._std)
        blur = None
        if self._axis_flow is not None and self._axis_flow.HasValue(context):
            blur = motion_blur_kernel(motion_blur_flow(self._K, self._axis_flow.Eval(context), self._exposure))
        if not noisy and self._maps is None and blur is None:
            output.set_value(rendered)
            return
        image = image_to_numpy(rendered)
        if self._maps is not None:
            image = cv2.remap(image, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if blur is not None:
            image = cv2.filter2D(image, -1, blur, borderType=cv2.BORDER_REPLICATE)
        if noisy:
            k = sample_index(context.get_time(), self._period)
            image = add_pixel_noise(image, self._std, sample_rng(self._seed, "camera_pixels", k))
        output.get_mutable_value().mutable_data[:] = image
