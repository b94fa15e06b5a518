"""Four downward time-of-flight range sensors under the propellers (seed 000 Eq. 21-24, Fig. 20).

By default each sensor is an ideal ray along its axis, as the paper treats each reading, cast on the
scene's geometry (`ray_cast.cast_rays`: what has a proximity role, less the geometry on the frame the
sensors are mounted on). With `cone_deg` set it is a real sensor's cone (a VL53L1X's is 27 degrees)
sampled by a 31x31 pixel grid:
the reading is the mean path length over the cone's footprint, each pixel weighted by the power it
returns, calibrated to read a flat target square to its axis at its distance (`cone_range`), so a tilted
or partly covered footprint biases it as it does on hardware. The
sensors' frames S_i have the camera's orientation (+z down along the ray) and sit in the camera plane
at the positions of Eq. (21)-(24):
    p_CS1 = [-a c, -a c, 0], p_CS2 = [-a c, a c, 0], p_CS3 = [a c, a c, 0], p_CS4 = [a c, -a c, 0]
with c = cos(AngleCam2Sensors) = cos(45 deg) and a the distance from the camera axis (see
`sensor_positions_C`).

The four cones share one depth render (`make_tof_camera`): a narrow depth camera K, oriented like C,
TOF_CAMERA_BACK_M (45 m) behind the camera plane on the camera axis, X_CK = [I, (0, 0, -45 m)], whose
near clipping plane is the sensors' own (5 mm in front of the camera plane), so the drone's own geometry
is clipped as it was for a camera at each sensor. Its lines of sight are within 0.2 degrees of the
sensors' axes (a near-orthographic view of the deck), and each ray of each sensor is followed to the
surface K sees along it (`ray_depths`): exact where K sees what the sensor's ray hits (a plane, up to
the pixel of K where it ends; not a surface hidden from K by an edge the sensor looks past).
"""

from dataclasses import dataclass
from functools import cache

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import ClippingRange, DepthRange, DepthRenderCamera, QueryObject, RenderCameraCore, Role
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem, ValueProducer
from pydrake.systems.sensors import ImageDepth32F, RgbdSensor
from scipy.ndimage import map_coordinates

from systems.config import require, require_positive
from systems.noise import sample_index, sample_rng
from systems.sensors.camera import DEPTH_INSET, RENDERER_NAME, camera_info
from systems.sensors.ray_cast import cast_rays

_CONE_PIXELS = 31
_NEAR_M, _FAR_M = 0.005, 20.0  # the sensors' render range (from the camera plane), wider than any sensor's range
# the depth camera's range, DEPTH_INSET inside the render range: nearer reads 0 (too close), farther inf (nothing seen)
_MIN_DEPTH_M, _MAX_DEPTH_M = _NEAR_M * (1 + DEPTH_INSET), _FAR_M * (1 - DEPTH_INSET)
# The shared depth camera K's distance behind the camera plane; with the 19.8 m of range it stays under
# the 65.5 m an RgbdSensor's 16-bit depth output can hold (Drake warns otherwise).
TOF_CAMERA_BACK_M = 45.0
# K's pixels per side: a cone's 31 x 31 rays need about their own 3 cm spacing at 2 m, over the cones out
# to 2 x max_range_m.
_K_CONE_PIXELS = 128
# `ray_depths`' fixed point: at most this many steps, each shrinking the error by about the ray's slope in
# K's view times the surface's (a cone's edge ray, 0.24, over a 12 deg deck: 0.05, 5 steps from 2 m to
# 0.2 um); a ray stops when its inverse depth q moves less than _Q_TOLERANCE (1/m), i.e. its depth less
# than _Q_TOLERANCE (TOF_CAMERA_BACK_M + s)^2, 0.2 um at 2 m.
_MAX_ITERATIONS, _Q_TOLERANCE = 8, 1e-10
_JUMP = 1e-3  # an edge in K's inverse depth between neighbouring pixels (relative; 5 cm at 2 m)
TRIGGERS = ("camera", "own_clock")
MIN_AXIS_OFFSET_M = 1e-3  # a sensor's least x and y offset in C: CRHF's focal lengths divide by them (Eq. 40-45)


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
    # Timing: "camera" (default) ranges at the instant of the camera frame that reads it (triggered with
    # the camera, at its rate; rate_hz is then unused); "own_clock" ranges at rate_hz from time_offset_s (s)
    # on, free-running, and a frame reads the last reading completed before it.
    trigger: str = "camera"
    time_offset_s: float = 0.0

    def validate(self, prefix: str = "tof") -> None:
        for name in ("arm_m", "min_range_m", "rate_hz"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.max_range_m > self.min_range_m, f"{prefix}.max_range_m must exceed {prefix}.min_range_m")
        require(self.max_range_m < _FAR_M, f"{prefix}.max_range_m must be below {_FAR_M} m")
        require(self.noise_std_m >= 0, f"{prefix}.noise_std_m must not be negative")
        require(self.noise_std_per_m >= 0, f"{prefix}.noise_std_per_m must not be negative")
        require(self.trigger in TRIGGERS,
                f"{prefix}.trigger must be one of {', '.join(TRIGGERS)}, got {self.trigger!r}")
        require(self.trigger == "own_clock" or self.time_offset_s == 0,
                f"{prefix}.time_offset_s applies to {prefix}.trigger: own_clock only")
        require(0 <= self.time_offset_s < self.period_s,
                f"{prefix}.time_offset_s must lie within 0 and the sensors' period ({self.period_s:g} s), "
                f"got {self.time_offset_s}")
        require(0 <= self.cone_deg <= 90, f"{prefix}.cone_deg must lie within 0-90 deg, got {self.cone_deg}")
        require(0 < self.angle_deg < 90, f"{prefix}.angle_deg must lie strictly within 0-90 deg (on the camera's "
                                         f"axes the sensors leave Eq. 40-45's focal lengths undefined), got {self.angle_deg}")
        offsets_m = np.abs(sensor_positions_C(self.arm_m, self.angle_deg)[0, :2])
        for axis, offset_m in zip("xy", offsets_m):
            require(offset_m >= MIN_AXIS_OFFSET_M,
                    f"{prefix}.arm_m and {prefix}.angle_deg give the sensors |{axis}| = {offset_m * 1e3:.3g} mm in C, "
                    f"under the {MIN_AXIS_OFFSET_M * 1e3:g} mm CRHF needs (Eq. 40-45 divide by each sensor's x and y)")

    @property
    def view(self) -> tuple[int, float]:
        """(pixels per side, full field of view in deg) of each sensor's own pixel grid: one pixel on
        the axis for an ideal ray, 31 x 31 filling the cone edge to edge for a cone."""
        return (_CONE_PIXELS, self.cone_deg) if self.cone_deg > 0 else (1, 0.0)

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


def apply_range_limits(noise_free: np.ndarray, noise: np.ndarray, min_range: float, max_range: float):
    """Sensor readings from their noise-free ranges (m: an ideal ray's true range, a cone's `cone_range`):
    (ranges with NaN where invalid, valid flags 0/1).

    A reading is valid when its noise-free range is finite and inside [min_range, max_range] (for a cone, the
    range its return gives, not its centre ray's), and the reading (with its noise and bias) is a distance:
    positive."""
    valid = np.isfinite(noise_free) & (noise_free >= min_range) & (noise_free <= max_range)
    valid &= np.where(valid, noise_free + noise, np.nan) > 0
    ranges = np.where(valid, noise_free + noise, np.nan)
    return ranges, valid.astype(float)


def view_intrinsics(pixels: int, fov_deg: float) -> tuple[float, float]:
    """(f, c) in px of a square depth camera whose centre pixel's centre is on the principal point, so
    the centre pixel looks along +z exactly."""
    return (pixels / 2) / np.tan(np.deg2rad(fov_deg) / 2), (pixels - 1) / 2


@cache
def view_geometry(pixels: int, fov_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sensor's own pixel grid (`TofConfig.view`): (x, the normalised image coordinate of each pixel
    column, the same for rows; stretch, the path length per metre of z-depth of each pixel,
    sqrt(1 + x^2 + y^2); in_cone, the pixels inside the cone). One pixel on the axis when fov_deg is 0."""
    if fov_deg == 0:
        return np.zeros(1), np.ones((1, 1)), np.ones((1, 1), bool)
    f, c = view_intrinsics(pixels, fov_deg)
    x = (np.arange(pixels) - c) / f
    stretch = np.sqrt(1.0 + x[None, :] ** 2 + x[:, None] ** 2)
    return x, stretch, stretch <= 1.0 / np.cos(np.deg2rad(fov_deg) / 2)


def cone_range(depth: np.ndarray, fov_deg: float) -> float:
    """The reading of a sensor whose cone fills the square depth image `depth` (z-depths, m) edge to
    edge: the mean path length over the pixels inside the cone, each weighted by the power it returns
    to a sensor that lights its cone uniformly, its solid angle (cos^3 of its angle off the axis, in
    image-plane units) over the squared path length (the surface's own reflectance and incidence are not
    modelled), over the same mean on a flat target square to the axis (`flat_target_path_factor`): a
    sensor's ranging is calibrated on such a target, which it reads to its datasheet's accuracy. Pixels
    that see nothing (inf) or are too close to render (0) return nothing; NaN when none returns."""
    _, stretch, in_cone = view_geometry(depth.shape[0], fov_deg)
    z = depth.astype(float)
    returns = in_cone & np.isfinite(z) & (z > 0)
    if not returns.any():
        return float("nan")
    path = z[returns] * stretch[returns]
    weight = stretch[returns] ** -3 / path**2
    return float(np.sum(weight * path) / np.sum(weight)) / flat_target_path_factor(depth.shape[0], fov_deg)


@cache
def flat_target_path_factor(pixels: int, fov_deg: float) -> float:
    """The power-weighted mean path over a flat target square to the cone's axis, per metre of its distance
    (1.0138 for the VL53L1X's 27 deg, 1.0043 for a 15 deg ROI): over the cone's pixels a path h s returns
    s^-3 / (h s)^2 of power (s, the pixel's `stretch`), so the mean is h sum(s^-4) / sum(s^-5)."""
    _, stretch, in_cone = view_geometry(pixels, fov_deg)
    return float(np.sum(stretch[in_cone] ** -4) / np.sum(stretch[in_cone] ** -5))


def tof_camera_view(config: TofConfig) -> tuple[int, float, float]:
    """(pixels per side, f, c in px, OpenCV convention) of the cones' shared depth camera K: square,
    centred on the camera axis, wide enough for every cone's rays from the camera plane out to
    2 x max_range_m, with two pixels of margin."""
    require(config.cone_deg > 0, "the shared depth camera is the cones' (tof.cone_deg > 0); ideal rays are cast")
    x, _, _ = view_geometry(*config.view)
    reach = min(_FAR_M, 2 * config.max_range_m)
    offset = np.max(np.abs(sensor_positions_C(config.arm_m, config.angle_deg)[:, :2]))
    # |x_K| = |p_S + s x| / (TOF_CAMERA_BACK_M + s) along a ray is largest at one end of s in [0, reach].
    tan_half = max(offset / TOF_CAMERA_BACK_M, (offset + reach * np.max(np.abs(x))) / (TOF_CAMERA_BACK_M + reach))
    f = (_K_CONE_PIXELS / 2 - 2) / tan_half
    return _K_CONE_PIXELS, f, (_K_CONE_PIXELS - 1) / 2


def make_tof_camera(parent_frame_id, X_PC: RigidTransform, config: TofConfig) -> RgbdSensor:
    """The depth-only RgbdSensor of the cones' shared depth camera K (`tof_camera_view`) for the sensors
    of `config` around the camera at X_PC in the parent frame: at X_PK = X_PC [I, (0, 0,
    -TOF_CAMERA_BACK_M)], its clipping and depth ranges the sensors' own from the camera plane."""
    pixels, f, c = tof_camera_view(config)
    core = RenderCameraCore(RENDERER_NAME, camera_info(pixels, pixels, f, f, c, c),
                            ClippingRange(TOF_CAMERA_BACK_M + _NEAR_M, TOF_CAMERA_BACK_M + _FAR_M), RigidTransform())
    X_PK = X_PC.multiply(RigidTransform([0.0, 0.0, -TOF_CAMERA_BACK_M]))
    return RgbdSensor(parent_frame_id, X_PK, DepthRenderCamera(core, DepthRange(TOF_CAMERA_BACK_M + _MIN_DEPTH_M,
                                                                                  TOF_CAMERA_BACK_M + _MAX_DEPTH_M)))


def ray_depths(depth_K: np.ndarray, f: float, c: float, p_CS: np.ndarray, x_S: np.ndarray, y_S: np.ndarray):
    """z-depths (m, from the camera plane) at which rays from sensor origins p_CS (n x 3, in the camera
    plane) along directions [x_S, y_S, 1] (n, in C) meet the surface the depth image `depth_K` (z-depths
    of camera K, `make_tof_camera`'s with intrinsics f, c) sees; 0 where it is nearer than 5.05 mm,
    inf where nothing is within 19.8 m or the ray leaves K's image.

    A point at depth s on a ray, p_CS + s [x_S, y_S, 1], is seen by K at normalised image coordinates
    p_CS q + [x_S, y_S] (1 - TOF_CAMERA_BACK_M q), q = 1 / (TOF_CAMERA_BACK_M + s); the ray meets the
    surface where K's inverse depth W there equals q, found by the fixed point q <- W(q) from the camera
    plane on (it converges by the ray's slope in K's view times the surface's, ~0.002 on a cone's axis,
    and from the near side, so a ray that clears an edge goes on to what lies beyond it). W is
    interpolated bilinearly, exact on a plane (inverse depth is affine in the image coordinates there),
    except between pixels that straddle a jump in depth (an edge: over _JUMP of the inverse depth,
    ~5 cm), where the nearest pixel's is taken, so an edge is placed to half a pixel of K rather than
    blurred into depths that nothing has."""
    D = depth_K.astype(float)
    q_near, q_far = 1.0 / (TOF_CAMERA_BACK_M + _NEAR_M), 1.0 / (TOF_CAMERA_BACK_M + _FAR_M)
    with np.errstate(divide="ignore"):
        W = np.where(D == 0, q_near, 1.0 / D)  # 0 where nothing is seen (inf)
    corners = np.stack([W[:-1, :-1], W[1:, :-1], W[:-1, 1:], W[1:, 1:]])
    jump = np.ptp(corners, axis=0) > _JUMP * corners.max(axis=0)  # per 2x2 cell, at its top-left pixel
    last = W.shape[0] - 2
    q = np.full(len(x_S), q_near)
    moving = np.arange(len(x_S))  # the rays whose q still moves
    for _ in range(_MAX_ITERATIONS):
        q_ray = np.clip(q[moving], q_far, q_near)  # the rays end at the far clipping plane (nothing seen: q = 0)
        u = c + f * (p_CS[moving, 0] * q_ray + x_S[moving] * (1 - TOF_CAMERA_BACK_M * q_ray))
        v = c + f * (p_CS[moving, 1] * q_ray + y_S[moving] * (1 - TOF_CAMERA_BACK_M * q_ray))
        q_new = map_coordinates(W, [v, u], order=1, mode="constant", cval=0.0)
        at_jump = jump[np.clip(v.astype(int), 0, last), np.clip(u.astype(int), 0, last)]
        if at_jump.any():
            q_new[at_jump] = map_coordinates(W, [v[at_jump], u[at_jump]], order=0, mode="constant", cval=0.0)
        still = np.abs(q_new - q[moving]) >= _Q_TOLERANCE
        q[moving] = q_new
        moving = moving[still]
        if not moving.size:
            break
    with np.errstate(divide="ignore"):
        s = 1.0 / q - TOF_CAMERA_BACK_M
    return np.where(s < _MIN_DEPTH_M, 0.0, np.where(s > _MAX_DEPTH_M, np.inf, s))


class TofSensors(LeafSystem):
    """The four sensors' range readings, ideal rays cast on the scene or cones read from their depth render.

    Input, ideal rays: geometry_query (SceneGraph's QueryObject), the sensors at `mount` = (the frame F
    they ride on, X_FC the camera frame's pose in it); cones: depth_image (ImageDepth32F, `make_tof_camera`'s
    for the same config). Outputs:
      ranges: 4 readings (m) with noise (std noise_std_m + noise_std_per_m x range) and bias_m; NaN
        where invalid.
      ranges_valid: 4 flags, 1.0 for a valid reading, 0.0 when out of range or nothing is seen.
      true_ranges: 4 noise-free distances (m) along each axis, ground truth for logging.
    With `trigger: camera` they are the readings at the time a consumer evaluates them (the camera's frames);
    with `own_clock` a periodic update takes them at time_offset_s + k / rate_hz and holds them (NaN, 0, inf
    before the first), so a frame at the same instant as a reading still sees the one before it.
    """

    def __init__(self, config: TofConfig, seed: int = 0, frame_period_s: float | None = None,
                 mount: tuple | None = None):
        """`frame_period_s`: the camera's, which triggers the readings (`trigger: camera`); default rate_hz's.
        `mount` (FrameId, RigidTransform X_FC): where ideal rays are cast from; unused by cones."""
        super().__init__()
        config.validate()
        require(config.cone_deg > 0 or mount is not None, "ideal ToF rays need the frame they are mounted on")
        self._config, self._seed, self._mount = config, seed, mount
        # Readings are numbered (for their noise) by the clock that takes them.
        by_camera = config.trigger == "camera" and frame_period_s is not None
        self._reading_period = frame_period_s if by_camera else config.period_s
        self._pixels, self._fov_deg = config.view
        # Every ray of every sensor: origins p_CS and directions [x, y, 1] (in C) of the pixels inside each
        # sensor's cone (its axis alone for an ideal ray), sensor by sensor.
        x, _, in_cone = view_geometry(self._pixels, self._fov_deg)
        self._rows, self._cols = np.nonzero(in_cone)
        n = len(self._rows)
        self._p_CS = np.repeat(sensor_positions_C(config.arm_m, config.angle_deg), n, axis=0)
        self._x_S, self._y_S = np.tile(x[self._cols], 4), np.tile(x[self._rows], 4)
        if config.cone_deg > 0:
            k_pixels, self._f, self._c = tof_camera_view(config)
            self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F(k_pixels, k_pixels)))
        else:
            self.DeclareAbstractInputPort("geometry_query", AbstractValue.Make(QueryObject()))
        names = ("ranges", "ranges_valid", "true_ranges")
        if config.trigger == "own_clock":
            held = self.DeclareDiscreteState(np.concatenate([np.full(4, np.nan), np.zeros(4), np.full(4, np.inf)]))
            self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, config.time_offset_s, lambda c, state: (
                state.get_mutable_vector().SetFromVector(np.concatenate(self.readings(c)))))
            for i, name in enumerate(names):
                self.DeclareVectorOutputPort(name, 4, lambda c, o, i=i: o.SetFromVector(
                    c.get_discrete_state(held).value()[4 * i:4 * i + 4]), {self.xd_ticket()})
            return
        # One set of readings per frame, shared by the three outputs.
        readings = self.DeclareCacheEntry("readings", ValueProducer(
            allocate=lambda: AbstractValue.Make((np.zeros(4), np.zeros(4), np.zeros(4))),
            calc=lambda c, value: value.set_value(self.readings(c))))
        for i, name in enumerate(names):
            self.DeclareVectorOutputPort(name, 4, lambda c, o, i=i: o.SetFromVector(readings.Eval(c)[i]),
                                         {readings.ticket()})

    def sensor_depths(self, context) -> np.ndarray:
        """The z-depths (m) each sensor's own pixel grid sees (4 x pixels x pixels; inf outside the
        cone)."""
        if self._config.cone_deg > 0:
            depth = ray_depths(self.get_input_port().Eval(context).data[..., 0], self._f, self._c, self._p_CS,
                               self._x_S, self._y_S)
        else:
            depth = self._cast_rays(self.get_input_port().Eval(context))
        images = np.full((4, self._pixels, self._pixels), np.inf)
        images[:, self._rows, self._cols] = depth.reshape(4, -1)
        return images

    def _cast_rays(self, query_object) -> np.ndarray:
        """The four axes' distances (m) to the scene's surfaces: along each sensor's axis (the camera's +z)
        from its origin in the camera plane, ignoring the geometry of the mount frame (the UAV's own)."""
        frame_id, X_FC = self._mount
        X_WC = query_object.GetPoseInWorld(frame_id).multiply(X_FC)
        own = frozenset(query_object.inspector().GetGeometries(frame_id, Role.kProximity))
        d_W = np.tile(X_WC.rotation().matrix()[:, 2], (4, 1))
        return cast_rays(query_object, X_WC.multiply(self._p_CS.T).T, d_W, _FAR_M, own)

    def readings(self, context):
        """(ranges with NaN where invalid, valid flags, true ranges) at the context's time. True ranges:
        the noise-free distance (m) along each sensor's axis, inf when nothing is within 20 m (19.8 m for
        cones), 0 from inside a geometry (for cones, something closer than 5.05 mm: Drake's depth-image
        conventions); the noise-free readings are these for ideal rays, `cone_range` for cones."""
        c = self._config
        depths = self.sensor_depths(context)
        centre = self._pixels // 2
        true_ranges = depths[:, centre, centre]
        measured = true_ranges if c.cone_deg == 0 else np.array([cone_range(d, self._fov_deg) for d in depths])
        k = sample_index(context.get_time() - c.time_offset_s, self._reading_period)
        std = c.noise_std_m + c.noise_std_per_m * np.where(np.isfinite(measured), measured, 0.0)
        noise = sample_rng(self._seed, "tof", k).standard_normal(4) * std + c.bias_m
        return (*apply_range_limits(measured, noise, c.min_range_m, c.max_range_m), true_ranges)
