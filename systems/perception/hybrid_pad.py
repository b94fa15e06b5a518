"""Seed 003's hybrid estimate of the pad (Sec. 2.2-2.3): the tracked UGV box in the fisheye image, the stereo
altitude, and the UAV's own attitude -> the pad's position in World.

Per fisheye frame k (all in the project's frames, W z up; seed 003 writes NED, velocity_observer.py converts):
- the tracked box's centre (u, v), OpenCV's pixel coordinates (a box [x, y, w, h] covers [x, x + w) in
  pixel-index space, so its centre is x + w/2 - 0.5), becomes its unit ray r_C by the fisheye model
  (`pixel_rays`: cv2.fisheye's inverse of Sec. 2.1's K and D);
- r_W = R_WB R_BC r_C with the UAV's attitude from its navigation (Eq. 20-22's rotation, here Drake's);
- the camera's height above the ground h comes from the stereo altitude filter (Eq. 11-14), so the camera
  is h - z_P above the pad's horizontal plane z = z_P (the pad's top above the ground, known from the
  vehicle); the ray meets that plane at s = (h - z_P) / (-r_W,z) (the paper's Eq. 15 scales pixels to
  metres with the altitude the same way, for a ray along the axis), and
  p_WP = [x_WC, y_WC, z_P] + s r_W, with the camera's x, y from the UAV's navigation.
- The filter's altitude is the depth the stereo's left eye L sees along its optical axis (`camera_height`):
  h = d (-z_L,W . z_W) + (z_WC - z_WL), the depth put vertical with the navigation's attitude and moved from
  the eye to the fisheye (the paper's UAV flies level, where h = d; at 20 deg of tilt d reads 6 % long).

Ours, where the paper is silent:
- Over the UGV the stereo window sees the roof, not the ground: h reads up to z_P low. The ray is then
  near the axis, where the horizontal error h tan(theta) is small; off-axis the window sees the ground.
- When the stereo altitude is invalid (under its 0.7 m range, the last metre of a landing), h is carried
  on from its last valid value by the navigation's change in height, for `altitude_coast_s`.
- In the final landing (the camera within `landing_zone_m` over the pad's plane by the UAV's navigation, not
  the stereo, whose window reads spikes of 2-3 m at 0.5 m over the pad) a measurement far from a valid
  estimate's prediction is an outlier and not used (`gate_m`), and without a measurement the estimate
  coasts at the last observed velocity (Eq. 15-19's observer run on the measured positions) for
  `max_coast_s`, then turns invalid; higher, it coasts only while that observer is valid, and at most
  `approach_max_coast_s`; invalid, it forgets that coast's velocity, while the observer keeps its window (a
  target found again within `window_s` is coasted at what its sightings give across the loss: the climb's
  sightings, frames apart, build the approach's velocity that way). The paper lands
  below LH blind, as its target floods the fisheye; the supervisor here stops a landing on an invalid
  estimate. The seam's v_WP (`v_WP` output) is that observer's, else (past its window) the coasting
  estimate's velocity, else zero: never NaN.
- A fix of the pad from the stereo pair's left eye (its markers, stereo_pad.py, searched up to its
  `max_height_m`, 3 m over the pad's plane), where there is one, measures instead of the box, ungated: the box's
  centre marks the pad poorly at close range, and below `box_min_height_m` the box does not measure at all.
- Rays more oblique than `min_ray_down` do not measure in the final landing, nor more oblique than
  `approach_min_ray_down` above it; a measurement's reported std grows with the ray's obliquity.
- Invalid is PoseEstimate's valid False; `v_WP_observed` is NaN while the observer is not valid.
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.estimators.estimate import PoseEstimate
from systems.estimators.velocity_observer import ObserverState, VelocityObserverConfig, step_observer
from systems.flags import is_set
from systems.geometry import ray_to_plane
from systems.perception.box_tracker import Detection, box_centre_pixel
from systems.sensors.fisheye import FisheyeConfig, in_field_of_view, pixel_rays
from systems.stepped import SteppedValue

# [valid, p_WP (3), measured (0 no, 1 by the box, 2 by the stereo pad fix), h (1), h_source (0 none, 1 stereo,
#  2 carried), coast_s]
HYBRID_VECTOR_SIZE = 8


@dataclass
class HybridPadConfig:
    """Coasting (s) and the reported covariance (m): ours, the paper gives none."""

    # The estimate predicted without a measurement for this long, then invalid: below about 1 m over the pad
    # the UGV fills the fisheye and the detector's boxes stop matching the track (measured), which leaves
    # the last 1 m of LH's 1.5 m at 0.3 m/s to the prediction, as the paper lands blind below LH.
    max_coast_s: float = 4.0
    # A measurement further than gate_m + gate_growth_m_s * (time since the last one) from the prediction
    # of a valid estimate is an outlier (a part of the UGV, or the ground, boxed at close range), not used.
    gate_m: float = 0.5
    gate_growth_m_s: float = 0.3
    # The long coast and the gate apply only this close over the pad's plane (the camera's height by the UAV's
    # navigation; the final landing: LH is 1.5 m):
    # higher, an unmeasured frame coasts only while the observer's velocity is valid, and nothing is gated,
    # since the early, oblique measurements of the climb give velocities of 1-2 m/s off (measured: a 4 s
    # coast on them sent the UAV 5 m away, and the gate then refused the UGV's true position).
    landing_zone_m: float = 2.0
    # Above it an unmeasured frame coasts at most this long (and only while the observer is valid): under a
    # bridge the learned detector boxed the part of the UGV still in view until 0.7 s before the pad was
    # wholly hidden, and the observer-long coast after it (1.3 s) was 0.4-0.6 m off and valid (measured, seed 0);
    # 0.5 s was still valid at the hidden second's first frame with OpenCV 5.1's dnn (a frame's later last box).
    approach_max_coast_s: float = 0.4
    # Below this camera height over the pad's plane (the UAV's navigation) the fisheye's box does not measure:
    # the UGV floods the fisheye and the learned detector boxes parts of it (measured: a 58 px box 0.49 m off at
    # 0.4 m over the pad, 1.5 m/s figure-eight, passed the gate, and the velocity it gave sent the coast 2.4 m
    # off); the stereo eye's fix measures there, else the estimate coasts.
    box_min_height_m: float = 1.0
    altitude_coast_s: float = 5.0  # h carried on by the navigation's height change for this long
    position_std_m: float = 0.1  # the reported std per axis of a measured estimate
    # And its growth per second of coasting (the observed velocity's error, 0.05-0.1 m/s measured). The seam refuses
    # sqrt(trace) over perception.max_position_std_m (1 m), about 0.7 m per axis: from a measured 0.1 m, 0.1 m/s
    # reaches that 6 s into a coast, so the seam refuses none within max_coast_s (0.71 m at its 4 s: the coast
    # ends by max_coast_s); 0.2 m/s would reach it 3.1 s in.
    coast_std_growth_m_s: float = 0.1
    height_std_m: float = 0.05  # z: the pad's plane is known
    # In the landing zone only rays within 60 deg of the vertical measure (-r_W,z >= cos 60 deg): seen obliquely,
    # the box's centre is the UGV's side as much as its roof, and from a low camera the plane's intersection
    # runs metres off (measured: 2.5 m off at 80 deg from 0.4 m above the pad, in the take-off).
    min_ray_down: float = 0.5
    # Above it (the climb to IH and the follow) rays up to 78 deg measure, so that a UGV that drives off
    # while the UAV climbs stays an estimate to follow (at 1.5 m/s it is 60-70 deg off the vertical when the
    # UAV reaches IH: with 60 deg the estimate was valid in 1 frame of 150 and the UAV never followed).
    # Their reported std grows as 1 / -r_W,z (the plane's intersection moves by the height's error times
    # tan(theta)); the supervisor descends only once the UAV is over the target, where the rays are steep.
    approach_min_ray_down: float = 0.2

    def validate(self, prefix: str = "hybrid.estimator") -> None:
        for name in ("max_coast_s", "approach_max_coast_s", "box_min_height_m", "altitude_coast_s",
                     "coast_std_growth_m_s", "gate_m", "gate_growth_m_s", "landing_zone_m"):
            require_non_negative(getattr(self, name), f"{prefix}.{name}")
        require_positive(self.position_std_m, f"{prefix}.position_std_m")
        require_positive(self.height_std_m, f"{prefix}.height_std_m")
        for name in ("min_ray_down", "approach_min_ray_down"):
            value = getattr(self, name)
            require(0 < value <= 1, f"{prefix}.{name} must lie in (0, 1], got {value}")


def camera_height(depth_m: float, X_WB: RigidTransform, X_BL: RigidTransform, X_BC: RigidTransform) -> float:
    """The height [m] of the camera C (at X_BC on the body B) above the surface that the stereo's left eye L
    (at X_BL) sees at `depth_m` along its optical axis (its z), the surface taken level; NaN when L does not
    look down."""
    X_WL = X_WB.multiply(X_BL)
    down = -X_WL.rotation().matrix()[2, 2]
    if not down > 0:
        return math.nan
    return depth_m * down + X_WB.multiply(X_BC).translation()[2] - X_WL.translation()[2]


def pad_from_box(box: np.ndarray, camera_height_m: float, X_WB: RigidTransform, fisheye: FisheyeConfig,
                 z_pad: float, min_ray_down: float = 0.5) -> np.ndarray | None:
    """p_WP [m] from the tracked box (module docstring), or None (centre outside the field of view, ray
    not meeting the pad's plane, camera not above it)."""
    uv = box_centre_pixel(box)
    if not np.all(np.isfinite(uv)) or not in_field_of_view(uv, fisheye)[0]:
        return None
    X_WC = X_WB.multiply(fisheye.X_BC)
    ray_W = X_WC.rotation().multiply(pixel_rays(uv, fisheye)[0])
    return ray_to_plane(X_WC.translation(), ray_W, camera_height_m - z_pad, z_pad, min_ray_down)


@dataclass(frozen=True)
class HybridPadState:
    """After the step at `time`: the estimate, whether this frame measured it, the last measurement's
    time, the camera height used and how (0 none, 1 stereo, 2 carried), the stereo height's anchor
    (its value and the navigation's camera z then), and the observer run on the measurements."""

    time: float | None = None
    estimate: PoseEstimate = field(default_factory=lambda: PoseEstimate.invalid(0.0, "W", "P"))
    measured: bool = False
    last_measured_s: float | None = None
    last_p_WP: np.ndarray | None = None
    height_m: float = math.nan
    height_source: int = 0
    anchor: tuple | None = None  # (h, z_WC, time)
    observer: ObserverState = field(default_factory=ObserverState)
    velocity: np.ndarray | None = None  # the observer's last valid velocity (W), for coasting
    gated: int = 0  # measurements rejected by the gate so far
    ray_scale: float = 1.0  # 1 / -r_W,z of the last measured ray: its reported std is position_std_m times it
    fixed: bool = False  # this frame measured by the stereo eye's pad fix (stereo_pad.py), not the box


def hybrid_step(state: HybridPadState, time: float, box: np.ndarray, box_valid: bool, camera_height_m: float,
                altitude_valid: bool, X_WB: RigidTransform, fisheye: FisheyeConfig, z_pad: float,
                config: HybridPadConfig, observer_config: VelocityObserverConfig,
                pad_fix: np.ndarray | None = None) -> HybridPadState:
    """One frame (pure). camera_height_m: the fisheye's height above the ground from the stereo altitude
    (`camera_height`), used where `altitude_valid`. pad_fix: the stereo eye's p_WP (stereo_pad.py) or
    None/NaN; where given, it measures instead of the box, ungated."""
    p_WC = X_WB.multiply(fisheye.X_BC).translation()
    z_WC = p_WC[2]
    anchor, h, source = state.anchor, math.nan, 0
    if altitude_valid and math.isfinite(camera_height_m) and camera_height_m > 0:
        h, source, anchor = camera_height_m, 1, (camera_height_m, z_WC, time)
    elif anchor is not None and time - anchor[2] <= config.altitude_coast_s + 1e-9:
        h, source = anchor[0] + (z_WC - anchor[1]), 2
    # The navigation's height, not h: the stereo window's spikes of 2-3 m at 0.5 m over the pad (measured) must not
    # end the landing's coast, and an estimate that kept the landing's rules while valid carried them from the
    # take-off up to IH (ugv-hybrid, circle, 0.2 m/s, seed 1: the gate refused every ray for 4 s, 2.9 m off).
    landing = z_WC - z_pad <= config.landing_zone_m
    p, scale, fixed = None, 1.0, False
    if pad_fix is not None and np.all(np.isfinite(pad_fix)):
        p, fixed = np.array([pad_fix[0], pad_fix[1], z_pad]), True
    elif box_valid and source and z_WC - z_pad >= config.box_min_height_m:
        p = pad_from_box(box, h, X_WB, fisheye, z_pad,
                         config.min_ray_down if landing else config.approach_min_ray_down)
        if p is not None:  # 1 / -r_W,z of this ray: the camera's slant distance to the point over its height above
            scale = math.hypot(h - z_pad, math.dist(p[:2], p_WC[:2])) / (h - z_pad)
    last_measured, last_p, velocity, gated = state.last_measured_s, state.last_p_WP, state.velocity, state.gated

    def predicted() -> np.ndarray:
        return last_p + (time - last_measured) * np.array([*velocity[:2], 0.0])

    if (landing and p is not None and not fixed and state.estimate.valid and velocity is not None
            and last_measured is not None):
        gate = config.gate_m + config.gate_growth_m_s * (time - last_measured)
        if np.linalg.norm((p - predicted())[:2]) > gate:
            p, gated = None, gated + 1
    observer = step_observer(state.observer, time, observer_config, p_W=p, precise=fixed)
    if observer.valid:
        velocity = observer.estimate
    ray_scale = state.ray_scale  # a measurement the gate rejected leaves the last measured ray's
    if p is not None:
        last_measured, last_p, coast, ray_scale = time, p, 0.0, scale
    elif (state.estimate.valid and last_measured is not None and velocity is not None
          and time - last_measured <= config.max_coast_s + 1e-9
          and (landing or (observer.valid and time - last_measured <= config.approach_max_coast_s + 1e-9))):
        coast = time - last_measured
        p = predicted()
    else:  # invalid: the velocity seen before is no longer the target's, so no later coast may use it
        coast, velocity = math.nan, None
    if p is None:
        estimate = PoseEstimate.invalid(time, "W", "P")
    else:
        std = config.position_std_m * ray_scale + config.coast_std_growth_m_s * coast
        estimate = PoseEstimate(time, RigidTransform(p), True,
                                np.diag([1.0] * 3 + [std**2, std**2, config.height_std_m**2]), "W", "P")
    return replace(state, time=time, estimate=estimate, measured=coast == 0.0, last_measured_s=last_measured,
                   last_p_WP=last_p, height_m=h, height_source=source, anchor=anchor, observer=observer,
                   velocity=velocity, gated=gated, ray_scale=ray_scale, fixed=fixed)


def hybrid_vector(state: HybridPadState) -> np.ndarray:
    """HYBRID_VECTOR_SIZE numbers for logging; NaN position when not valid."""
    e = state.estimate
    p = e.X_RT.translation() if e.valid else np.full(3, np.nan)
    coast = 0.0 if state.measured else (state.time - state.last_measured_s if e.valid else math.nan)
    measured = (2.0 if state.fixed else 1.0) if state.measured else 0.0
    return np.array([float(e.valid), *p, measured, state.height_m, float(state.height_source), coast])


class HybridPadEstimator(LeafSystem):
    """The hybrid estimate (module docstring), stepped at the fisheye's rate (SteppedValue: a reader at a
    frame time sees that frame).

    Inputs: `target_box` (4, px: the tracker's [x, y, w, h] on the raw fisheye image), `target_valid` (1),
    optional `target_lock` (2: LockedTrackVector's [id, matched]; connected, a frame measures only when the
    locked track was matched with a detection in it: the tracker's image-space prediction knows nothing of
    the UAV's own motion, and a coasting box drifts off the UGV as the UAV moves), optional `pad_fix` (3, m:
    the stereo eye's p_WP, NaN without one, systems/perception/stereo_pad.py; connected, it measures where it
    has one),
    `altitude` (1, m: the stereo filter's depth along the left eye's axis, the eye at `X_BL` on the body;
    `camera_height` makes it the fisheye's height), `altitude_valid` (1), `X_WB` (RigidTransform: the UAV's
    navigation). Outputs: `X_WP_estimate` (PoseEstimate, frames "W"/"P"),
    `v_WP` (3, m/s, W: the seam's velocity: the observer's, else the velocity the estimate coasts with while
    valid, else zero), `v_WP_observed` (3, m/s, W: the observer's, NaN while it is not valid), `v_valid` (1:
    1.0 while the observer is valid) and `hybrid_vector` (HYBRID_VECTOR_SIZE). The observer (Eq. 15-19,
    `observer_config`, source world) is the one the estimate coasts with, run on this frame's measurement
    with the stereo eye's fixes flagged precise."""

    def __init__(self, fisheye: FisheyeConfig, X_BL: RigidTransform, z_pad: float,
                 config: HybridPadConfig | None = None, observer_config: VelocityObserverConfig | None = None):
        super().__init__()
        self._fisheye, self._X_BL, self._z_pad = fisheye, X_BL, float(z_pad)
        self._config = config or HybridPadConfig()
        self._config.validate()
        self._observer_config = observer_config or VelocityObserverConfig()
        self._box = self.DeclareVectorInputPort("target_box", 4)
        self._box_valid = self.DeclareVectorInputPort("target_valid", 1)
        self._altitude = self.DeclareVectorInputPort("altitude", 1)
        self._altitude_valid = self.DeclareVectorInputPort("altitude_valid", 1)
        self._lock = self.DeclareVectorInputPort("target_lock", 2)
        self._pad_fix = self.DeclareVectorInputPort("pad_fix", 3)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._stepped = SteppedValue(self, "hybrid_pad", HybridPadState(), fisheye.period_s, self._step,
                                     lambda s: s.time)
        tickets = {self._stepped.now.ticket()}
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self.state(c).estimate), tickets)
        self.DeclareVectorOutputPort("v_WP", 3, self._calc_velocity, tickets)
        self.DeclareVectorOutputPort("v_WP_observed", 3,
                                     lambda c, o: o.SetFromVector(self.state(c).observer.estimate), tickets)
        self.DeclareVectorOutputPort("v_valid", 1,
                                     lambda c, o: o.SetFromVector([float(self.state(c).observer.valid)]), tickets)
        self.DeclareVectorOutputPort("hybrid_vector", HYBRID_VECTOR_SIZE,
                                     lambda c, o: o.SetFromVector(hybrid_vector(self.state(c))), tickets)

    def state(self, context) -> HybridPadState:
        return self._stepped.now.Eval(context)

    def _calc_velocity(self, context, output):
        s = self.state(context)
        if s.observer.valid:
            output.SetFromVector(s.observer.estimate)
        elif s.estimate.valid and s.velocity is not None:
            output.SetFromVector(np.array([*s.velocity[:2], 0.0]))
        else:
            output.SetFromVector(np.zeros(3))

    def _step(self, context, state: HybridPadState) -> HybridPadState:
        seen = is_set(self._box_valid.Eval(context)[0])
        if self._lock.HasValue(context):  # only a box matched with this frame's detection measures
            seen = seen and is_set(self._lock.Eval(context)[1])
        fix = self._pad_fix.Eval(context) if self._pad_fix.HasValue(context) else None
        X_WB = self._X_WB.Eval(context)
        h = camera_height(float(self._altitude.Eval(context)[0]), X_WB, self._X_BL, self._fisheye.X_BC)
        return hybrid_step(state, context.get_time(), self._box.Eval(context), seen, h,
                           is_set(self._altitude_valid.Eval(context)[0]), X_WB, self._fisheye, self._z_pad,
                           self._config, self._observer_config, fix)


class DetectionsToTracker(LeafSystem):
    """The UGV detector's (box, score) pairs as the tracker's `Detection`s (input `detections`, output
    `detections`), and for logs a vector `detection_vector` (1 + 5 max_logged): the frame's number of
    detections, then the best max_logged by score, [valid, x, y, w, h] each (the CNN gives at most 10)."""

    def __init__(self, max_logged: int = 10):
        super().__init__()
        self._n = max_logged
        self._input = self.DeclareAbstractInputPort("detections", AbstractValue.Make([]))
        self.DeclareAbstractOutputPort("detections", lambda: AbstractValue.Make([]), self._calc)
        self.DeclareVectorOutputPort("detection_vector", 1 + 5 * max_logged, self._calc_vector)

    def _calc(self, context, output):
        output.set_value([Detection(np.asarray(box, float), float(score)) for box, score in self._input.Eval(context)])

    def _calc_vector(self, context, output):
        detections = sorted(self._input.Eval(context), key=lambda d: -d[1])
        v = np.zeros(1 + 5 * self._n)
        v[0] = len(detections)
        for k, (box, _score) in enumerate(detections[:self._n]):
            v[1 + 5 * k:6 + 5 * k] = [1.0, *box]
        output.SetFromVector(v)


class LockedTrackVector(LeafSystem):
    """For logs: inputs `tracks` (the tracker's list of BoxTrack) and `target_box` (4); output `lock` (2:
    [the locked track's id, or -1; 1.0 when it was matched with a detection this frame]). The locked track
    is the one whose box is the target's."""

    def __init__(self):
        super().__init__()
        self._tracks = self.DeclareAbstractInputPort("tracks", AbstractValue.Make([]))
        self._box = self.DeclareVectorInputPort("target_box", 4)
        self.DeclareVectorOutputPort("lock", 2, self._calc)

    def _calc(self, context, output):
        box = self._box.Eval(context)
        out = [-1.0, 0.0]
        if np.all(np.isfinite(box)):
            for track in self._tracks.Eval(context):
                if np.allclose(track.box, box, atol=1e-6):
                    out = [float(track.id), float(track.detection is not None)]
                    break
        output.SetFromVector(out)
