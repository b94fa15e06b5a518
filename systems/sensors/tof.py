"""Four downward time-of-flight range sensors under the propellers (seed 000 Eq. 21-24, Fig. 20).

Each sensor is a small depth camera at the sensor, so the tilted, moving deck, its tag and anything
else in the scene are seen as they are. By default it is an ideal ray along its axis (3x3 pixels, 1
degree field of view; the reading is the centre pixel's distance), as the paper treats each reading.
With `cone_deg` set it is a real sensor's cone (a VL53L1X's is 27 degrees): the reading is the mean
path length over the cone's footprint, each pixel weighted by the power it returns (`cone_range`),
so a tilted or partly covered footprint biases it as it does on hardware. The sensors' frames S_i
have the camera's orientation (+z down along the ray) and sit in the camera plane at the positions of
Eq. (21)-(24):
    p_CS1 = [-a c, -a c, 0], p_CS2 = [-a c, a c, 0], p_CS3 = [a c, a c, 0], p_CS4 = [a c, -a c, 0]
with c = cos(AngleCam2Sensors) = cos(45 deg) and a the distance from the camera axis (see
`sensor_positions_C`).
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import ClippingRange, DepthRange, DepthRenderCamera, RenderCameraCore
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem, ValueProducer
from pydrake.systems.sensors import ImageDepth32F, RgbdSensor

from systems.config import require, require_positive
from systems.noise import sample_index, sample_rng
from systems.sensors.camera import RENDERER_NAME, camera_info

_RAY_PIXELS, _RAY_FOV_DEG = 3, 1.0
_CONE_PIXELS = 31
_NEAR_M, _FAR_M = 0.005, 20.0  # render range of the truth ray, wider than any sensor's range


@dataclass
class TofConfig:
    """ToF sensors: geometry (m, deg), range limits (m), noise (m), rate (Hz).

    Defaults: a VL53L1X-class sensor (long-distance mode 0.04-4 m). The 0.135 m arm is what seed 000's
    Table 2 implies: the pads under the sensors appear about 143 px off the image centre at 0.305 m,
    i.e. 0.095 m per axis with fx = 458.5, which is 0.135 m at 45 degrees."""

    arm_m: float = 0.135  # a in Eq. (21)-(24)
    angle_deg: float = 45.0  # AngleCam2Sensors in Eq. (21)-(24)
    min_range_m: float = 0.04
    max_range_m: float = 4.0
    noise_std_m: float = 0.0
    rate_hz: float = 20.0
    # Hardware effects (issue 13), zero by default: the cone's full width (0: an ideal ray), a range
    # noise std growing with the range, and a constant offset (a ranging calibration's residual).
    cone_deg: float = 0.0
    noise_std_per_m: float = 0.0
    bias_m: float = 0.0

    def validate(self, prefix: str = "tof") -> None:
        for name in ("arm_m", "min_range_m", "rate_hz"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.max_range_m > self.min_range_m, f"{prefix}.max_range_m must exceed {prefix}.min_range_m")
        require(self.max_range_m < _FAR_M, f"{prefix}.max_range_m must be below {_FAR_M} m")
        require(self.noise_std_m >= 0, f"{prefix}.noise_std_m must not be negative")
        require(self.noise_std_per_m >= 0, f"{prefix}.noise_std_per_m must not be negative")
        require(0 <= self.cone_deg <= 90, f"{prefix}.cone_deg must lie within 0-90 deg, got {self.cone_deg}")

    @property
    def view(self) -> tuple[int, float]:
        """(pixels per side, full field of view in deg) of each sensor's depth camera."""
        return (_CONE_PIXELS, self.cone_deg) if self.cone_deg > 0 else (_RAY_PIXELS, _RAY_FOV_DEG)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


def sensor_positions_C(arm_m: float, angle_deg: float = 45.0) -> np.ndarray:
    """The four sensor origins in the camera frame (4x3, m), Eq. (21)-(24): sensors 1..4 in the
    quadrants (-x, -y), (-x, +y), (+x, +y), (+x, -y). The paper writes a cos(angle) for both
    components; at its 45 degrees that equals a sin(angle), which keeps `arm_m` the distance from
    the axis at any angle."""
    a = np.deg2rad(angle_deg)
    signs = np.array([[-1.0, -1.0], [-1.0, 1.0], [1.0, 1.0], [1.0, -1.0]])
    return np.column_stack([signs[:, 0] * arm_m * np.cos(a), signs[:, 1] * arm_m * np.sin(a), np.zeros(4)])


def apply_range_limits(true_ranges: np.ndarray, noise: np.ndarray, min_range: float, max_range: float):
    """Sensor readings from true ranges (m): (ranges with NaN where invalid, valid flags 0/1).

    A reading is valid when the true range is finite and inside [min_range, max_range]."""
    valid = np.isfinite(true_ranges) & (true_ranges >= min_range) & (true_ranges <= max_range)
    ranges = np.where(valid, true_ranges + noise, np.nan)
    return ranges, valid.astype(float)


def view_intrinsics(pixels: int, fov_deg: float) -> tuple[float, float]:
    """(f, c) in px of a square depth camera whose centre pixel's centre is on the principal point, so
    the centre pixel looks along +z exactly."""
    return (pixels / 2) / np.tan(np.deg2rad(fov_deg) / 2), (pixels - 1) / 2


def cone_range(depth: np.ndarray, fov_deg: float) -> float:
    """The reading of a sensor whose cone fills the square depth image `depth` (z-depths, m) edge to
    edge: the mean path length over the pixels inside the cone, each weighted by the power it returns
    to a sensor that lights its cone uniformly, its solid angle (cos^3 of its angle off the axis, in
    image-plane units) over the squared path length (the surface's own reflectance and incidence are not
    modelled). Pixels that see nothing (inf) or are too close to render (0) return nothing; NaN when
    none returns."""
    pixels = depth.shape[0]
    f, c = view_intrinsics(pixels, fov_deg)
    x = (np.arange(pixels) - c) / f
    stretch = np.sqrt(1.0 + x[None, :] ** 2 + x[:, None] ** 2)  # path length per metre of z-depth
    in_cone = stretch <= 1.0 / np.cos(np.deg2rad(fov_deg) / 2)
    z = depth.astype(float)
    returns = in_cone & np.isfinite(z) & (z > 0)
    if not returns.any():
        return float("nan")
    path = z[returns] * stretch[returns]
    weight = stretch[returns] ** -3 / path**2
    return float(np.sum(weight * path) / np.sum(weight))


def make_ray_sensor(parent_frame_id, X_PS: RigidTransform, config: TofConfig | None = None) -> RgbdSensor:
    """The depth-only RgbdSensor that looks along +z of frame S (pose X_PS in the parent frame): the
    ray or the cone of `config` (an ideal ray by default)."""
    pixels, fov_deg = (config or TofConfig()).view
    f, centre = view_intrinsics(pixels, fov_deg)
    core = RenderCameraCore(RENDERER_NAME, camera_info(pixels, pixels, f, f, centre, centre),
                            ClippingRange(_NEAR_M, _FAR_M), RigidTransform())
    return RgbdSensor(parent_frame_id, X_PS, DepthRenderCamera(core, DepthRange(_NEAR_M * 1.01, _FAR_M * 0.99)))


class TofSensors(LeafSystem):
    """Turns the four ray sensors' depth images into range readings.

    Inputs depth_image_0..3 (ImageDepth32F, `make_ray_sensor`'s for the same config). Outputs, evaluated
    at the sensor rate by consumers:
      ranges: 4 readings (m) with noise (std noise_std_m + noise_std_per_m x range) and bias_m; NaN
        where invalid.
      ranges_valid: 4 flags, 1.0 for a valid reading, 0.0 when out of range or nothing is seen.
      true_ranges: 4 noise-free distances (m) along each axis, ground truth for logging.
    """

    def __init__(self, config: TofConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed = config, seed
        self._pixels, self._fov_deg = config.view
        blank = ImageDepth32F(self._pixels, self._pixels)
        for i in range(4):
            self.DeclareAbstractInputPort(f"depth_image_{i}", AbstractValue.Make(blank))
        # One reading per frame, shared by the ranges and ranges_valid outputs.
        readings = self.DeclareCacheEntry("readings", ValueProducer(
            allocate=lambda: AbstractValue.Make((np.zeros(4), np.zeros(4))),
            calc=lambda c, value: value.set_value(self.readings(c))))
        self.DeclareVectorOutputPort("ranges", 4, lambda c, o: o.SetFromVector(readings.Eval(c)[0]),
                                     {readings.ticket()})
        self.DeclareVectorOutputPort("ranges_valid", 4, lambda c, o: o.SetFromVector(readings.Eval(c)[1]),
                                     {readings.ticket()})
        self.DeclareVectorOutputPort("true_ranges", 4, lambda c, o: o.SetFromVector(self.true_ranges(c)))

    def true_ranges(self, context) -> np.ndarray:
        """Noise-free distance (m) along each sensor's axis: inf when nothing is within 20 m, 0 when
        something is closer than 5 mm (Drake's depth-image conventions)."""
        centre = self._pixels // 2
        return np.array([float(self.get_input_port(i).Eval(context).data[centre, centre, 0]) for i in range(4)])

    def measured_ranges(self, context) -> np.ndarray:
        """Noise-free readings (m): the axis distances for ideal rays, `cone_range` for cones."""
        if self._config.cone_deg == 0:
            return self.true_ranges(context)
        return np.array([cone_range(self.get_input_port(i).Eval(context).data[..., 0], self._fov_deg)
                         for i in range(4)])

    def readings(self, context):
        """(ranges with NaN where invalid, valid flags) at the context's time."""
        c = self._config
        k = sample_index(context.get_time(), c.period_s)
        measured = self.measured_ranges(context)
        std = c.noise_std_m + c.noise_std_per_m * np.where(np.isfinite(measured), measured, 0.0)
        noise = sample_rng(self._seed, "tof", k).standard_normal(4) * std + c.bias_m
        return apply_range_limits(measured, noise, c.min_range_m, c.max_range_m)
