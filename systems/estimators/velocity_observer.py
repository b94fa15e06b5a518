"""Seed 003's velocity observer (Sec. 2.2.3, Eq. 15-19) and its frame transforms (Sec. 2.3, Eq. 20-22).

The paper scales the UGV's motion-compensated pixel displacement between two frames to metres with the
altitude (Eq. 15), divides by the frame time (Eq. 16), takes its direction (Eq. 17), and averages speed and
direction over the recent frames with Gaussian weights peaked at the current frame (Eq. 18-19); the result,
in the body frame, is rotated into the world (Eq. 22, the rotation of Eq. 20-21).

**Frames.** Everything here is in the project's frames: World W z up, body B x forward and z up, camera C
+z along the optical axis, +x right and +y down in the image (docs/architecture.md). Seed 003 writes its
world in NED (north, east, down) and its body x forward, y right, z down (FRD, Fig. 6). This module is the
one place that converts: for that boundary only, W is read as ENU (x east, y north, z up), so
v_NED = R_NW v_W with R_NW below, and v_B = R_B_FRD v_FRD. `paper_rotation_matrix` is Eq. 21 as printed;
as printed it is the transpose of the rotation of a Hamilton unit quaternion q = (q0, q1, q2, q3) (q0
the scalar), i.e. the world -> body matrix of the attitude q (tested against Drake), so for Eq. 22
(V_w = R V_b, body -> world) `rotation_ned_frd` uses its transpose. Nothing else in the project speaks NED.

Ours, where the paper is silent or where we differ (each named where it is done):
- The instant velocities are taken in W, each rotated with the attitude at its own frame, and averaged
  in W: a UAV that yaws during the window does not smear the average (the paper averages in the body
  frame and rotates the result once).
- Eq. 18-19's weights are normalised to sum 1 (the paper's pdf values sum to about 1 only when sigma
  spans many frames), so a constant velocity is read without a scale error.
- `combine = "vector"` (the default) averages the velocity vectors; `"speed_heading"` averages speed and
  direction separately as Eq. 18-19 print them. The two agree for a target moving straight; at low
  speed, noise makes every instant speed positive, and the separate average reads a standing target as
  moving (tests/test_velocity_observer.py measures it).
- `fit = "linear"` fits a line through the instant velocities by weighted least squares (Eq. 18-19's
  weights) and takes its value now, where Eq. 18-19's weighted mean (`fit = "mean"`, the default) is the
  velocity of about sigma sqrt(2/pi) = 0.4 s ago. On a turn that lag points the velocity off the target's:
  on a 15 m turn at 1.5 m/s the UAV followed 0.10 m off the pad in the landing zone on an exact stereo fix
  and touched down 0.14 m off. The line is exact for a constant acceleration (but for the newest
  difference's half frame) and noisier: 3.9 against 1.5 m/s per axis per metre of white position noise at
  10 Hz, 12 against 5 cm/s on the fisheye box's 3 cm. So it is taken only where every instant velocity in
  the window joins two sightings flagged `precise` (step_observer's argument, the system's optional input;
  unflagged: precise) and there are at least `linear_min_samples` of them, else the mean. Where no new
  sighting comes (the last second of a landing, under the stereo eye's last fix) the line is carried on: a
  constant acceleration. The hybrid loop flags the stereo eye's marker fixes (millimetres);
  over ugv-hybrid's eight paths with every sighting flagged, the estimate from the climb's end was within
  0.01 m on 0 of 16 runs at 1.5 m/s (8 with the mean) and one run at 0.5 m/s ended 0.058 m off
  (docs/results.md).
- Eq. 17 is atan((x_j - x_i)/(y_j - y_i)), an angle from the image's y axis that loses the quadrant;
  here the heading is atan2(v_y, v_x) in W (from +x_W, counter-clockwise about +z_W).
- A target seen again after more than `max_gap_s` restarts the differences (the step is no instant
  velocity). The estimate is valid with at least `min_samples` instant velocities in the window; an
  invalid estimate is NaN, never a number that looks valid.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.flags import is_set
from systems.geometry import ray_to_plane
from systems.stepped import SteppedValue

SOURCES = ("world", "pixel", "displacement")
COMBINES = ("vector", "speed_heading")
FITS = ("linear", "mean")

# The NED boundary (module docstring): W read as ENU. v_NED = R_NW @ v_W; v_B = R_B_FRD @ v_FRD.
R_NW = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
R_B_FRD = np.diag([1.0, -1.0, -1.0])


@dataclass
class VelocityObserverConfig:
    """The observer's settings: seconds, Hz. The paper gives no sigma and no window: ours."""

    rate_hz: float = 10.0  # seed 003 runs at about 9 Hz (Table 7); the fisheye's 10 Hz
    sigma_s: float = 0.5  # Eq. 18-19's sigma, in seconds of age: a mean lag of sigma sqrt(2/pi) = 0.4 s
    window_s: float = 1.5  # Eq. 18-19's m..n: instant velocities up to 3 sigma old
    min_samples: int = 3  # instant velocities in the window for a valid estimate
    max_gap_s: float = 0.5  # a longer gap between two sightings gives no instant velocity
    combine: str = "vector"  # "vector" (ours) or "speed_heading" (Eq. 18-19 as printed)
    fit: str = "mean"  # "mean" (Eq. 18-19) or "linear" (ours: the weighted line's value now; "vector" only)
    # The line only through at least this many precise instant velocities: the line through three stereo fixes met
    # in the climb, carried 0.3 s past them, read 0.28 m/s of a UGV at 0.2 m/s, and the estimate coasted 5 m off
    # (measured, circle path at 0.2 m/s, seed 1).
    linear_min_samples: int = 8
    source: str = "world"  # input: "world" (p_WT), "pixel" (the target's pixel) or "displacement" (Eq. 10's)

    def validate(self, prefix: str = "velocity_observer") -> None:
        for name in ("rate_hz", "sigma_s", "window_s", "max_gap_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(isinstance(self.min_samples, int) and self.min_samples >= 1,
                f"{prefix}.min_samples must be an integer of at least 1, got {self.min_samples}")
        require(self.combine in COMBINES, f"{prefix}.combine must be one of {COMBINES}, got '{self.combine}'")
        require(self.fit in FITS, f"{prefix}.fit must be one of {FITS}, got '{self.fit}'")
        require(isinstance(self.linear_min_samples, int) and self.linear_min_samples >= 2,
                f"{prefix}.linear_min_samples must be an integer of at least 2, got {self.linear_min_samples}")
        require(self.fit == "mean" or self.combine == "vector",
                f"{prefix}.fit '{self.fit}' needs combine 'vector' (speed_heading averages as Eq. 18-19 print it)")
        require(self.source in SOURCES, f"{prefix}.source must be one of {SOURCES}, got '{self.source}'")
        require(self.window_s >= 1.0 / self.rate_hz,
                f"{prefix}.window_s must hold at least one period (1 / rate_hz = {1.0 / self.rate_hz:g} s), "
                f"got {self.window_s}")
        for name in ("min_samples", "linear_min_samples") if self.fit == "linear" else ("min_samples",):
            require(getattr(self, name) <= self.window_capacity,
                    f"{prefix}.{name} ({getattr(self, name)}) is more than the window holds: {self.window_capacity} "
                    f"instant velocities ({prefix}.window_s x rate_hz + 1); the estimate would never be "
                    f"{'valid' if name == 'min_samples' else 'linear'}")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def window_capacity(self) -> int:
        """The most instant velocities the window holds, one a period [s] from age 0 to window_s (with the window's
        1e-9 s tolerance, as weighted_velocity and step_observer keep them)."""
        return math.floor((self.window_s + 1e-9) * self.rate_hz) + 1


# ----------------------------------------------------------------------------------------------
# Frame transforms: Eq. 15 (pixels -> metres), Eq. 20-22 (body -> world), the NED boundary


def pixel_displacement_to_camera(d_px: np.ndarray, altitude: float, K: np.ndarray) -> np.ndarray:
    """Eq. 15, s_ugv = f_pd Z / f, per image axis: a displacement [du, dv] px in a rectified (pinhole) image
    with intrinsics K, of a point at depth Z = `altitude` [m] under a camera looking straight down, as
    [du Z / fx, dv Z / fy, 0] m in the camera frame C."""
    d = np.asarray(d_px, dtype=float)
    return np.array([d[0] * altitude / K[0, 0], d[1] * altitude / K[1, 1], 0.0])


def camera_to_world(v_C: np.ndarray, R_WB, R_BC) -> np.ndarray:
    """Eq. 22, V_w = R V_b, on a free vector (a velocity or displacement: no translation, Eq. 20's T drops
    out) given in C: v_W = R_WB R_BC v_C. R_WB, R_BC: RotationMatrix or 3x3 arrays."""
    R_WB, R_BC = (R.matrix() if isinstance(R, RotationMatrix) else np.asarray(R, dtype=float) for R in (R_WB, R_BC))
    return R_WB @ (R_BC @ np.asarray(v_C, dtype=float))


def pixel_to_ground_W(uv: np.ndarray, altitude: float, K: np.ndarray, X_WC: RigidTransform) -> np.ndarray | None:
    """p_W [m] of the point seen at pixel `uv` (rectified image, intrinsics K) on the horizontal plane
    `altitude` [m] below the camera: the pixel's ray K^-1 [u, v, 1] rotated into W and scaled to reach the
    plane, plus the camera's position (Eq. 20, with its translation). For a camera looking straight down
    the offset from the point under the camera is Eq. 15's, [(u - cx) Z / fx, (v - cy) Z / fy] in C.
    None when the ray does not go down to the plane (`ray_to_plane`, any ray pointing down)."""
    ray_C = np.linalg.solve(np.asarray(K, dtype=float), np.array([uv[0], uv[1], 1.0]))
    p_WC = X_WC.translation()
    return ray_to_plane(p_WC, X_WC.rotation().multiply(ray_C), altitude, p_WC[2] - altitude, min_ray_down=1e-9)


def paper_rotation_matrix(q: Sequence[float]) -> np.ndarray:
    """Eq. 21 as printed, for q = (q0, q1, q2, q3), q0 the scalar part, unit norm. It equals the transpose
    of the Hamilton rotation of q (module docstring)."""
    q0, q1, q2, q3 = (float(v) for v in q)
    return np.array([
        [1 - 2 * q2**2 - 2 * q3**2, 2 * (q1 * q2 + q0 * q3), 2 * (q1 * q3 - q0 * q2)],
        [2 * (q1 * q2 - q0 * q3), 1 - 2 * q1**2 - 2 * q3**2, 2 * (q2 * q3 + q0 * q1)],
        [2 * (q1 * q3 + q0 * q2), 2 * (q2 * q3 - q0 * q1), 1 - 2 * q1**2 - 2 * q2**2]])


def rotation_ned_frd(q: Sequence[float]) -> np.ndarray:
    """R of Eq. 22 (body FRD -> world NED) for the attitude quaternion q = (q0, q1, q2, q3) of the FRD body
    in NED (Hamilton, scalar first: the convention of PX4 and ROS): Eq. 21's matrix transposed."""
    return paper_rotation_matrix(q).T


def ned_to_world(v_NED: np.ndarray) -> np.ndarray:
    """A vector in the paper's NED world as components in W (read as ENU at this boundary)."""
    return R_NW.T @ np.asarray(v_NED, dtype=float)


def world_to_ned(v_W: np.ndarray) -> np.ndarray:
    """A vector in W (read as ENU) as components in the paper's NED world."""
    return R_NW @ np.asarray(v_W, dtype=float)


def paper_velocity_to_world(v_FRD: np.ndarray, q: Sequence[float]) -> np.ndarray:
    """Eq. 22 end to end as the paper states it: a velocity in the paper's body frame (FRD) with the
    attitude quaternion q of that body in NED, as components in our World W."""
    return ned_to_world(rotation_ned_frd(q) @ np.asarray(v_FRD, dtype=float))


# ----------------------------------------------------------------------------------------------
# Eq. 16-19: instant velocities and their Gaussian-weighted average


def instant_velocity(p_previous: np.ndarray, p: np.ndarray, dt: float) -> np.ndarray:
    """Eq. 16 as a vector, v = s / dt [m/s], from two positions (or from a displacement s = p - p_previous
    already in metres, Eq. 15) dt [s] apart."""
    return (np.asarray(p, dtype=float) - np.asarray(p_previous, dtype=float)) / dt


def speed_and_heading(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 16-17 on (..., 3) velocities in W: horizontal speed [m/s] and heading atan2(v_y, v_x) [rad] (ours
    for Eq. 17's atan((x_j - x_i)/(y_j - y_i)), module docstring)."""
    v = np.asarray(v, dtype=float)
    return np.hypot(v[..., 0], v[..., 1]), np.arctan2(v[..., 1], v[..., 0])


def gaussian_weights(ages: np.ndarray, sigma: float) -> np.ndarray:
    """Eq. 18-19's w(x) = exp(-x^2 / 2 sigma^2) / (sigma sqrt(2 pi)) at x = each sample's age [s] (its
    peak at the current frame, age 0), normalised to sum 1 (ours, module docstring). Computed relative to
    the youngest sample's, which the normalisation cancels, so that samples many sigma old do not underflow
    to 0 / 0."""
    x = np.asarray(ages, dtype=float) / sigma
    w = np.exp(-0.5 * (x**2 - np.min(x**2)))
    return w / w.sum()


def weighted_velocity(times: np.ndarray, velocities: np.ndarray, now: float, config: VelocityObserverConfig,
                      precise: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """Eq. 18-19: (v_W [m/s] (3,), valid) at `now` [s] from the instant velocities (n, 3) stamped `times` [s]
    (the end of each sample's interval). Only those at most `window_s` old count; invalid (NaN) with
    fewer than `min_samples` of them. `precise` (n,) bool: which samples the linear fit may use (None: all);
    it is taken only when every sample counted is precise (module docstring)."""
    times, velocities = np.asarray(times, dtype=float), np.reshape(np.asarray(velocities, dtype=float), (-1, 3))
    ages = now - times
    keep = (ages >= -1e-9) & (ages <= config.window_s + 1e-9)
    if np.count_nonzero(keep) < config.min_samples:
        return np.full(3, np.nan), False
    w, v = gaussian_weights(ages[keep], config.sigma_s), velocities[keep]
    if config.combine == "vector":
        linear = (config.fit == "linear" and np.count_nonzero(keep) >= config.linear_min_samples
                  and (precise is None or bool(np.all(np.asarray(precise, bool)[keep]))))
        return (linear_fit_now(ages[keep], v, w) if linear else w @ v), True
    speed, heading = speed_and_heading(v)
    newest = heading[np.argmin(ages[keep])]
    heading = newest + np.remainder(heading - newest + np.pi, 2 * np.pi) - np.pi  # unwrapped next to the newest
    v_ugv, o_ugv = w @ speed, w @ heading  # Eq. 18, Eq. 19
    return np.array([v_ugv * math.cos(o_ugv), v_ugv * math.sin(o_ugv), w @ v[:, 2]]), True


def linear_fit_now(ages: np.ndarray, velocities: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The weighted least-squares line v(age) = v_now - a age through the instant velocities (n, 3) [m/s] of
    `ages` [s] with weights `w` (summing to 1), at age 0: v_now [m/s] (3,). The weighted mean when the ages do
    not spread (one sample, or all of one age)."""
    mean_age, mean_v = w @ ages, w @ velocities
    spread = w @ (ages - mean_age) ** 2
    if spread < 1e-9:
        return mean_v
    slope = (w * (ages - mean_age)) @ (velocities - mean_v) / spread  # dv/d(age) = -a
    return mean_v - slope * mean_age


@dataclass(frozen=True)
class ObserverState:
    """The observer after its step at `time` [s] (None before the first): the last sighting (time [s],
    p_W [m]; None when none; whether it was precise), the instant velocities in the window (times [s], v_W
    [m/s], whether each joins two precise sightings) and the estimate then (v_W [m/s], NaN when not valid)."""

    time: float | None = None
    last_time: float | None = None
    last_position: np.ndarray | None = None
    times: tuple[float, ...] = ()
    velocities: tuple[np.ndarray, ...] = ()
    last_precise: bool = True
    precise: tuple[bool, ...] = ()
    estimate: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    valid: bool = False


def step_observer(state: ObserverState, time: float, config: VelocityObserverConfig,
                  p_W: np.ndarray | None = None, v_W: np.ndarray | None = None, precise: bool = True) -> ObserverState:
    """One step at `time` [s] with this frame's target position p_W [m] (sources world and pixel), or with an
    instant velocity v_W [m/s] already made (source displacement: Eq. 15-16 on the compensated
    displacement), or neither (not seen). `precise`: this frame's sighting may feed the linear fit (module
    docstring). Pure: `state` is not changed."""
    times, velocities, flags = list(state.times), list(state.velocities), list(state.precise)
    last_time, last_position, last_precise = state.last_time, state.last_position, state.last_precise
    if p_W is not None and np.all(np.isfinite(p_W)):
        p_W = np.asarray(p_W, dtype=float)
        if last_time is not None and 0 < time - last_time <= config.max_gap_s + 1e-9:
            times.append(time)
            velocities.append(instant_velocity(last_position, p_W, time - last_time))  # Eq. 16
            flags.append(precise and last_precise)
        last_time, last_position, last_precise = time, p_W, precise
    elif v_W is not None and np.all(np.isfinite(v_W)):
        times.append(time)
        velocities.append(np.asarray(v_W, dtype=float))
        flags.append(precise)
    keep = [k for k, t in enumerate(times) if time - t <= config.window_s + 1e-9]
    times, velocities, flags = (tuple(x[k] for k in keep) for x in (times, velocities, flags))
    estimate, valid = weighted_velocity(np.array(times), np.array(velocities).reshape(-1, 3), time, config,
                                        np.array(flags, bool))
    return ObserverState(time, last_time, last_position, times, velocities, last_precise, flags, estimate, valid)


def observe_velocities(times: Sequence[float], positions: np.ndarray,
                       config: VelocityObserverConfig) -> tuple[np.ndarray, np.ndarray]:
    """The observer run over a position history (batch form, for scripts and tests): (n, 3) estimates
    [m/s] and (n,) valid flags, one per sample time [s]; a non-finite position is a frame without the target."""
    state, estimates, valid = ObserverState(), [], []
    for t, p in zip(times, np.reshape(positions, (-1, 3))):
        state = step_observer(state, float(t), config, p_W=p)
        estimates.append(state.estimate)
        valid.append(state.valid)
    return np.array(estimates), np.array(valid)


# ----------------------------------------------------------------------------------------------
# The LeafSystem


class VelocityObserverSystem(LeafSystem):
    """Seed 003's velocity observer, stepped at `config.rate_hz` from t = 0 (SteppedValue: a reader at a
    step time sees that step). Inputs by `config.source`:

    - "world": `p_WT` (3, m: the target in W; NaN when not seen) and optional `precise` (1: 1.0 when this
      frame's p_WT may feed the linear fit; unconnected: every one may).
    - "pixel": `target_pixel` (2, px: the target's centre in the rectified image of intrinsics K, OpenCV's
      pixel coordinates (centres at integers: a box's centre x + w/2 less half a pixel); NaN when not seen), `altitude` (1, m: the camera's height above the target's plane; not positive or NaN:
      unknown), optional `altitude_valid` (1; unconnected: valid) and `X_WB` (RigidTransform, the UAV's own
      pose). Each frame's pixel becomes p_W by `pixel_to_ground_W` through X_WC = X_WB X_BC: the UAV's
      navigation, not the image, removes its own motion.
    - "displacement": `target_displacement` (2, px: the target's motion-compensated displacement over the
      last period, Eq. 10's vector, motion_compensation.py's `ugv_displacement`; NaN when not known),
      `altitude`, optional `altitude_valid` and `X_WB`: Eq. 15, then Eq. 22 with this frame's attitude, over
      the period (Eq. 16): the paper's own path.

    Outputs: `v_WT` (3, m/s, W: the estimate; NaN when not valid) and `valid` (1: 1.0 or 0.0).
    """

    def __init__(self, config: VelocityObserverConfig | None = None, K: np.ndarray | None = None,
                 X_BC: RigidTransform | None = None):
        super().__init__()
        self._config = config or VelocityObserverConfig()
        self._config.validate()
        source = self._config.source
        if source == "world":
            self._p_WT = self.DeclareVectorInputPort("p_WT", 3)
            self._precise = self.DeclareVectorInputPort("precise", 1)
        else:
            require(K is not None and np.shape(K) == (3, 3),
                    f"velocity_observer.source '{source}' needs the camera's 3x3 intrinsics K")
            require(X_BC is not None, f"velocity_observer.source '{source}' needs the camera's pose X_BC")
            self._K, self._X_BC = np.asarray(K, dtype=float), X_BC
            name = "target_pixel" if source == "pixel" else "target_displacement"
            self._target = self.DeclareVectorInputPort(name, 2)
            self._altitude = self.DeclareVectorInputPort("altitude", 1)
            self._altitude_valid = self.DeclareVectorInputPort("altitude_valid", 1)
            self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._stepped = SteppedValue(self, "velocity_observer", ObserverState(), self._config.period_s, self._step,
                                     lambda state: state.time)
        tickets = {self._stepped.now.ticket()}
        self.DeclareVectorOutputPort("v_WT", 3, lambda c, o: o.SetFromVector(self.state(c).estimate), tickets)
        self.DeclareVectorOutputPort("valid", 1, lambda c, o: o.SetFromVector([float(self.state(c).valid)]), tickets)

    def state(self, context) -> ObserverState:
        """The observer's state at the context's time (including the step of a frame at that time)."""
        return self._stepped.now.Eval(context)

    def _altitude_now(self, context) -> float | None:
        if self._altitude_valid.HasValue(context) and not is_set(self._altitude_valid.Eval(context)[0]):
            return None
        h = float(self._altitude.Eval(context)[0])
        return h if math.isfinite(h) and h > 0 else None

    def _step(self, context, state: ObserverState) -> ObserverState:
        t, source = context.get_time(), self._config.source
        if source == "world":
            precise = not self._precise.HasValue(context) or is_set(self._precise.Eval(context)[0])
            return step_observer(state, t, self._config, p_W=self._p_WT.Eval(context), precise=precise)
        target, h = self._target.Eval(context), self._altitude_now(context)
        if h is None or not np.all(np.isfinite(target)):
            return step_observer(state, t, self._config)
        X_WB = self._X_WB.Eval(context)
        if source == "pixel":
            return step_observer(state, t, self._config,
                                 p_W=pixel_to_ground_W(target, h, self._K, X_WB.multiply(self._X_BC)))
        d_W = camera_to_world(pixel_displacement_to_camera(target, h, self._K), X_WB.rotation(),
                              self._X_BC.rotation())  # Eq. 15, Eq. 22
        return step_observer(state, t, self._config, v_W=d_W / self._config.period_s)  # Eq. 16
