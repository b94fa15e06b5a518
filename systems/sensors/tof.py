"""Four downward time-of-flight range sensors under the propellers (seed 000 Eq. 21-24, Fig. 20).

Each sensor is modelled as an ideal ray along its axis: a tiny depth camera (3x3 pixels, 1 degree
field of view) at the sensor, whose centre pixel is the distance along the axis to whatever the
renderer sees there, so the tilted, moving deck, its tag and anything else in the scene are seen
as they are. (A real VL53L1X averages over a 27 degree cone; the paper treats each reading as a
point on the ray, and so do we.) The sensors' frames S_i have the camera's orientation (+z down
along the ray) and sit in the camera plane at the positions of Eq. (21)-(24):
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

_PIXELS = 3
_FOV_RAD = np.deg2rad(1.0)
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

    def validate(self, prefix: str = "tof") -> None:
        for name in ("arm_m", "min_range_m", "rate_hz"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.max_range_m > self.min_range_m, f"{prefix}.max_range_m must exceed {prefix}.min_range_m")
        require(self.max_range_m < _FAR_M, f"{prefix}.max_range_m must be below {_FAR_M} m")
        require(self.noise_std_m >= 0, f"{prefix}.noise_std_m must not be negative")

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


def make_ray_sensor(parent_frame_id, X_PS: RigidTransform) -> RgbdSensor:
    """The depth-only RgbdSensor that looks along +z of frame S (pose X_PS in the parent frame)."""
    # The centre pixel's centre on the principal point, so the centre pixel looks along +z exactly.
    f = (_PIXELS / 2) / np.tan(_FOV_RAD / 2)
    centre = (_PIXELS - 1) / 2
    core = RenderCameraCore(RENDERER_NAME, camera_info(_PIXELS, _PIXELS, f, f, centre, centre),
                            ClippingRange(_NEAR_M, _FAR_M), RigidTransform())
    return RgbdSensor(parent_frame_id, X_PS, DepthRenderCamera(core, DepthRange(_NEAR_M * 1.01, _FAR_M * 0.99)))


class TofSensors(LeafSystem):
    """Turns the four ray sensors' depth images into range readings.

    Inputs depth_image_0..3 (ImageDepth32F). Outputs, evaluated at the sensor rate by consumers:
      ranges: 4 readings (m) with noise; NaN where invalid.
      ranges_valid: 4 flags, 1.0 for a valid reading, 0.0 when out of range or nothing is seen.
      true_ranges: 4 noise-free distances (m) along each axis, ground truth for logging.
    """

    def __init__(self, config: TofConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed = config, seed
        blank = ImageDepth32F(_PIXELS, _PIXELS)
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
        return np.array([float(self.get_input_port(i).Eval(context).data[_PIXELS // 2, _PIXELS // 2, 0])
                         for i in range(4)])

    def readings(self, context):
        """(ranges with NaN where invalid, valid flags) at the context's time."""
        c = self._config
        k = sample_index(context.get_time(), c.period_s)
        noise = sample_rng(self._seed, "tof", k).standard_normal(4) * c.noise_std_m
        return apply_range_limits(self.true_ranges(context), noise, c.min_range_m, c.max_range_m)
