"""Stewart platform: the moving landing deck of seed 000 (section 3, Figures 19 and 21).

The deck frame P sits at the centre of the deck's top surface (z up); the base frame S is the
world frame W (the base stands on the ground at the origin). The deck moves about its nominal
pose X_SP0 by a 6-DOF motion: translations (x, y, z in S's axes, m) and roll, pitch, yaw about the
deck centre (rad). Legs connect base joints b_i (in S) to deck joints q_i (in P):
    L_i = | p_SP + R_SP q_i - b_i |                      (inverse kinematics)
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, FramePoseVector, GeometryFrame, Mesh, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import LeafSystem
from scipy.interpolate import PchipInterpolator
from scipy.optimize import minimize_scalar

from models.apriltag import tag_mesh_path, tag_plate_scale
from systems.config import require, require_positive
from systems.estimators.deck_tracker import DECK_MOTION_SIZE
from systems.geometry import frame_between, register_collision, register_visual
from systems.noise import sample_rng
from systems.perception.apriltag import tag_corners_T

AXES = ("x", "y", "z", "roll", "pitch", "yaw")
MOTION_MODES = ("static", "sinusoid", "random_walk")
TAG_ABOVE_DECK_M = 0.0005  # the tag plate floats this far above the deck surface (no z-fighting)
LEG_PART_FRACTION = 0.6  # a leg's cylinder and rod, each as a fraction of the longest leg, where the stroke allows
RATE_STEP_S = 1e-3  # central-difference step of the deck's velocity and acceleration


def _axis_unit(axis: str) -> str:
    return "m" if axis in ("x", "y", "z") else "deg"


@dataclass
class StewartPlatformConfig:
    """Geometry, tag and motion of the Stewart platform. Lengths in m, angles in deg."""

    # Joint circles: six base joints (in S, at z = base_joint_height_m) and six deck joints (in P,
    # on the deck's underside). Leg i joins base joint i to deck joint i.
    base_radius_m: float = 0.5
    platform_radius_m: float = 0.35
    base_joint_angles_deg: list[float] = field(default_factory=lambda: [-15.0, 15.0, 105.0, 135.0, 225.0, 255.0])
    platform_joint_angles_deg: list[float] = field(default_factory=lambda: [-45.0, 45.0, 75.0, 165.0, 195.0, 285.0])
    base_joint_height_m: float = 0.05
    nominal_height_m: float = 0.6  # vertical distance between the joint planes at the nominal pose
    leg_min_m: float = 0.50  # actuator stroke
    leg_max_m: float = 0.85
    deck_size_m: float = 1.0
    deck_thickness_m: float = 0.04
    # AprilTag 36h11 on the deck: tag_size_m is the edge of the black square (AprilTag convention).
    # 0.5 m fills about 115 px of the 512x512 image at 2 m with the Eq. (10) intrinsics.
    tag_id: int = 0
    tag_size_m: float = 0.5
    # Motion about the nominal pose. Per axis, a sum of sinusoids A_j sin(2 pi f_j t + phi_j);
    # in random_walk mode each axis is a seeded, mean-reverting random walk bounded by sum(A_j).
    motion: str = "static"
    x_amplitude_m: list[float] = field(default_factory=list)
    x_frequency_hz: list[float] = field(default_factory=list)
    x_phase_deg: list[float] = field(default_factory=list)
    y_amplitude_m: list[float] = field(default_factory=list)
    y_frequency_hz: list[float] = field(default_factory=list)
    y_phase_deg: list[float] = field(default_factory=list)
    z_amplitude_m: list[float] = field(default_factory=list)
    z_frequency_hz: list[float] = field(default_factory=list)
    z_phase_deg: list[float] = field(default_factory=list)
    roll_amplitude_deg: list[float] = field(default_factory=list)
    roll_frequency_hz: list[float] = field(default_factory=list)
    roll_phase_deg: list[float] = field(default_factory=list)
    pitch_amplitude_deg: list[float] = field(default_factory=list)
    pitch_frequency_hz: list[float] = field(default_factory=list)
    pitch_phase_deg: list[float] = field(default_factory=list)
    yaw_amplitude_deg: list[float] = field(default_factory=list)
    yaw_frequency_hz: list[float] = field(default_factory=list)
    yaw_phase_deg: list[float] = field(default_factory=list)
    random_walk_time_constant_s: float = 4.0  # correlation time of the random walk
    random_walk_knot_interval_s: float = 0.25
    time_offset_s: float = 0.0  # the motion's own time at t = 0: a run that finds the deck mid-motion

    def validate(self, prefix: str = "platform") -> None:
        for name in ("base_radius_m", "platform_radius_m", "base_joint_height_m", "nominal_height_m", "leg_min_m",
                     "deck_size_m", "deck_thickness_m", "tag_size_m", "random_walk_time_constant_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        # The deck's rates are central differences over RATE_STEP_S: knots closer than that are not resolved
        # (and the stroke check, sampling a tenth of an interval, would take billions of samples).
        require(self.random_walk_knot_interval_s >= RATE_STEP_S,
                f"{prefix}.random_walk_knot_interval_s must be at least {RATE_STEP_S:g} s (the step of the deck's "
                f"rates), got {self.random_walk_knot_interval_s}")
        require(len(self.base_joint_angles_deg) == 6, f"{prefix}.base_joint_angles_deg needs 6 angles")
        require(len(self.platform_joint_angles_deg) == 6, f"{prefix}.platform_joint_angles_deg needs 6 angles")
        require(self.leg_max_m > self.leg_min_m, f"{prefix}.leg_max_m must exceed {prefix}.leg_min_m")
        require(self.motion in MOTION_MODES, f"{prefix}.motion must be one of {', '.join(MOTION_MODES)}, "
                f"got '{self.motion}'")
        joints = self.platform_radius_m * np.abs([np.cos(np.radians(self.platform_joint_angles_deg)),
                                                  np.sin(np.radians(self.platform_joint_angles_deg))])
        require(np.all(joints <= self.deck_size_m / 2 + 1e-9),
                f"{prefix}.platform_radius_m ({self.platform_radius_m:g} m) puts deck joints off the "
                f"{self.deck_size_m:g} m deck (at {prefix}.platform_joint_angles_deg)")
        require(self.time_offset_s >= 0, f"{prefix}.time_offset_s must not be negative")
        require(0 <= self.tag_id < 587, f"{prefix}.tag_id must be in [0, 586] for tag36h11")
        require(tag_plate_scale(self.tag_size_m) <= self.deck_size_m,
                f"{prefix}.tag_size_m = {self.tag_size_m} m does not fit on the deck: the tag with its white "
                f"border is {tag_plate_scale(self.tag_size_m):.3f} m wide but {prefix}.deck_size_m is "
                f"{self.deck_size_m} m")
        for axis in AXES if self.motion == "static" else ():  # the deck stands still: a motion given is a mistake
            for name in (f"{axis}_amplitude_{_axis_unit(axis)}", f"{axis}_frequency_hz", f"{axis}_phase_deg"):
                value = getattr(self, name)
                require(not (np.any(value) if "amplitude" in name else value), f"{prefix}.{name} is {value} but "
                        f"{prefix}.motion is 'static' (the deck stands still): empty it or choose another motion")
        for axis in AXES if self.motion == "sinusoid" else ():  # a random walk takes only the bounds (amplitudes)
            unit = _axis_unit(axis)
            lengths = {len(getattr(self, f"{axis}_{part}")) for part in (f"amplitude_{unit}", "frequency_hz")}
            require(len(lengths) == 1, f"{prefix}.{axis}_amplitude_{unit} and {prefix}.{axis}_frequency_hz "
                    "must have the same length (one entry per sinusoid)")
            n_phase = len(getattr(self, f"{axis}_phase_deg"))
            require(n_phase in (0, *lengths), f"{prefix}.{axis}_phase_deg must be empty or have one entry "
                    "per sinusoid")
            require(all(f >= 0 for f in getattr(self, f"{axis}_frequency_hz")),
                    f"{prefix}.{axis}_frequency_hz must not be negative")


@dataclass(frozen=True)
class StewartGeometry:
    """Joint positions: b_S (6x3) base joints in S, q_P (6x3) deck joints in P; nominal deck pose."""

    b_S: np.ndarray
    q_P: np.ndarray
    X_SP0: RigidTransform
    leg_min_m: float
    leg_max_m: float

    @staticmethod
    def from_config(config: StewartPlatformConfig) -> "StewartGeometry":
        def circle(radius, angles_deg, z):
            a = np.deg2rad(angles_deg)
            return np.column_stack([radius * np.cos(a), radius * np.sin(a), np.full(6, z)])

        b_S = circle(config.base_radius_m, config.base_joint_angles_deg, config.base_joint_height_m)
        q_P = circle(config.platform_radius_m, config.platform_joint_angles_deg, -config.deck_thickness_m)
        deck_top_z = config.base_joint_height_m + config.nominal_height_m + config.deck_thickness_m
        return StewartGeometry(b_S, q_P, RigidTransform([0.0, 0.0, deck_top_z]), config.leg_min_m, config.leg_max_m)


def leg_lengths(X_SP: RigidTransform, geometry: StewartGeometry) -> np.ndarray:
    """Inverse kinematics: the six leg lengths (m) for the deck pose X_SP."""
    q_S = X_SP.multiply(geometry.q_P.T).T
    return np.linalg.norm(q_S - geometry.b_S, axis=1)


def within_stroke(lengths: np.ndarray, geometry: StewartGeometry) -> bool:
    return bool(np.all((lengths >= geometry.leg_min_m) & (lengths <= geometry.leg_max_m)))


class StewartMotion:
    """The deck's offset from its nominal pose as a function of time: [x, y, z (m), roll, pitch, yaw (rad)]."""

    def __init__(self, config: StewartPlatformConfig, seed: int = 0):
        self._mode = config.motion
        self._amplitude, self._omega, self._phase = [], [], []
        for axis in AXES:
            unit = _axis_unit(axis)
            scale = 1.0 if unit == "m" else np.pi / 180.0
            amplitude = np.asarray(getattr(config, f"{axis}_amplitude_{unit}"), dtype=float) * scale
            phase = np.deg2rad(getattr(config, f"{axis}_phase_deg")) if getattr(config, f"{axis}_phase_deg") \
                else np.zeros_like(amplitude)
            self._amplitude.append(amplitude)
            self._omega.append(2 * np.pi * np.asarray(getattr(config, f"{axis}_frequency_hz"), dtype=float))
            self._phase.append(np.asarray(phase, dtype=float))
        self._bound = np.array([np.sum(np.abs(a)) for a in self._amplitude])
        self._seed = seed
        self._tau = config.random_walk_time_constant_s
        self._h = config.random_walk_knot_interval_s
        self._offset_s = config.time_offset_s
        self._knots = np.zeros((1, 6))  # random-walk state at t = 0, 1 h, 2 h, ...
        self._interpolant = None

    def __call__(self, t: float) -> np.ndarray:
        t = t + self._offset_s
        if self._mode == "static":
            return np.zeros(6)
        if self._mode == "sinusoid":
            return np.array([np.sum(a * np.sin(w * t + p))
                             for a, w, p in zip(self._amplitude, self._omega, self._phase)])
        return self._random_walk(t)

    def _random_walk(self, t: float) -> np.ndarray:
        # An Ornstein-Uhlenbeck walk with unit stationary variance, sampled at knots, extended in
        # chunks drawn in order from the seed, interpolated shape-preservingly, and squashed into
        # +-bound by tanh so the deck never leaves its configured envelope.
        while self._interpolant is None or t > (len(self._knots) - 2) * self._h:
            chunk = len(self._knots) // 256
            rng = sample_rng(self._seed, "stewart_random_walk", chunk)
            decay = np.exp(-self._h / self._tau)
            steps = rng.standard_normal((256, 6)) * np.sqrt(1 - decay**2)
            new = np.empty((256, 6))
            state = self._knots[-1]
            for i in range(256):
                state = decay * state + steps[i]
                new[i] = state
            self._knots = np.vstack([self._knots, new])
            self._interpolant = PchipInterpolator(self._h * np.arange(len(self._knots)), self._knots)
        return self._bound * np.tanh(0.5 * self._interpolant(t))

    def X_SP(self, t: float, geometry: StewartGeometry) -> RigidTransform:
        """The deck pose in the base frame at time t (s)."""
        offset = self(t)
        return RigidTransform(RollPitchYaw(offset[3:]), geometry.X_SP0.translation() + offset[:3])

    def translation_rates(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(velocity [m/s], acceleration [m/s^2]) of the deck centre at time t (s), by central differences
        over RATE_STEP_S (the motions are smooth: sinusoids, or PCHIP through the walk's knots)."""
        h = RATE_STEP_S
        before, now, after = (self(t + d)[:3] for d in (-h, 0.0, h))
        return (after - before) / (2 * h), (after - 2 * now + before) / h**2

    def angular_velocity(self, t: float) -> np.ndarray:
        """w_SP [rad/s, in S]: the deck's angular velocity at time t (s), from the rotation across a central
        difference of RATE_STEP_S (R(t + h) R(t - h)^T = exp([w] 2h))."""
        h = RATE_STEP_S
        before, after = (RotationMatrix(RollPitchYaw(self(t + d)[3:])) for d in (-h, h))
        turn = after.multiply(before.inverse()).ToAngleAxis()
        return turn.axis() * turn.angle() / (2 * h)


MAX_STROKE_SAMPLES = 1e6  # the stroke check's samples at most (0.05 s apart: 14 hours of motion)


def stroke_step_s(config: StewartPlatformConfig) -> float:
    """A sampling step [s] that resolves the motion: 40 samples a period of its fastest sinusoid (a sampled
    peak then falls short of the true one by under 0.4 % of its amplitude), 10 a random-walk knot, at most
    0.05 s."""
    step = 0.05
    fastest = max((f for axis in AXES for f in getattr(config, f"{axis}_frequency_hz")), default=0.0)
    if fastest > 0:
        step = min(step, 1.0 / (40.0 * fastest))
    if config.motion == "random_walk":
        step = min(step, config.random_walk_knot_interval_s / 10.0)
    return step


def stroke_violation(config: StewartPlatformConfig, duration_s: float, seed: int = 0) -> str | None:
    """Where the configured motion takes a leg outside [leg_min_m, leg_max_m] within duration_s: "t = ... s,
    leg i L m" for the first such time, or None when it stays within the stroke. Sampled every
    `stroke_step_s`; each leg's sampled extremes near a limit are refined between their neighbours
    (SciPy's bounded scalar search), so a peak between two samples is not missed. ConfigError where that
    takes over MAX_STROKE_SAMPLES samples."""
    geometry, motion = StewartGeometry.from_config(config), StewartMotion(config, seed)
    step = stroke_step_s(config)
    require(duration_s / step <= MAX_STROKE_SAMPLES,
            f"platform: the deck's motion cannot be checked against the legs' stroke over {duration_s:g} s: at "
            f"{step:.3g} s a sample (its fastest sinusoid or random-walk knot) that is over {MAX_STROKE_SAMPLES:g} "
            f"samples; shorten the run or slow the motion")
    times = np.append(np.arange(0.0, duration_s, step), duration_s)  # the run's end, not past it
    legs = np.array([leg_lengths(motion.X_SP(float(t), geometry), geometry) for t in times])
    found = []  # (t, leg, length) outside the stroke
    for t, lengths in zip(times, legs):
        if not within_stroke(lengths, geometry):
            i = int(np.argmax(np.maximum(lengths - geometry.leg_max_m, geometry.leg_min_m - lengths)))
            found.append((float(t), i, float(lengths[i])))
            break
    margin = 0.01 * max(float(np.ptp(legs)), 1e-3)  # m: sampled extremes this near a limit are refined
    for i in range(6):
        for sign, limit in ((1.0, geometry.leg_max_m), (-1.0, geometry.leg_min_m)):
            y = np.r_[-np.inf, sign * legs[:, i], -np.inf]  # a peak in the first or last interval too
            peaks = np.flatnonzero((y[1:-1] >= y[:-2]) & (y[1:-1] >= y[2:]))
            for k in peaks[y[peaks + 1] > sign * limit - margin]:
                best = minimize_scalar(lambda t: -sign * leg_lengths(motion.X_SP(float(t), geometry), geometry)[i],
                                       bounds=(times[max(k - 1, 0)], times[min(k + 1, len(times) - 1)]),
                                       method="bounded", options={"xatol": 1e-6})
                if -best.fun > sign * limit:
                    found.append((float(best.x), i, -sign * best.fun))
                    break
    if not found:
        return None
    t, i, length = min(found)
    return f"t = {t:.2f} s, leg {i + 1} {length:.3f} m"


def require_within_stroke(config: StewartPlatformConfig, duration_s: float, seed: int = 0) -> None:
    """ConfigError (one line naming where) when the configured motion leaves the legs' stroke within
    duration_s: a platform cannot follow it."""
    violation = stroke_violation(config, duration_s, seed)
    require(violation is None, f"platform: the motion leaves the legs' stroke "
                               f"[{config.leg_min_m:g}, {config.leg_max_m:g}] m ({violation})")


class StewartPlatform(LeafSystem):
    """The Stewart platform as a kinematic source, with its geometry registered in SceneGraph.

    Output ports:
      X_WP: deck pose in world (RigidTransform); the deck's top surface centre, z up.
      leg_lengths: the six leg lengths (m) from inverse kinematics.
      stroke_exceeded: [1.0] when any leg is outside [leg_min_m, leg_max_m], else [0.0].
      pad_motion: [p_WP (3, m), v_WP (3, m/s), a_WP (3, m/s^2)] of the deck centre in W.
      V_WP: the deck's spatial velocity [w_WP (rad/s); v_WP (m/s)], both in W.
      carrier_state: [x, y, yaw (rad), 0], the deck centre and heading in the ground vehicle's state layout,
        for what reads a carrier that way (systems/control/monitor.py).
      deck_motion: the true deck in the layout of systems/estimators/deck_tracker.py's estimate (tilt
        components of the normal and their rates, heave and its rate, valid).
      geometry_pose: FramePoseVector for SceneGraph (connect to its source pose port).
    """

    def __init__(self, config: StewartPlatformConfig, scene_graph: SceneGraph, seed: int = 0):
        super().__init__()
        config.validate()
        self.config = config
        self.geometry = StewartGeometry.from_config(config)
        self.motion = StewartMotion(config, seed)
        self.source_id = scene_graph.RegisterSource("stewart_platform")
        self._register_geometry(scene_graph)

        # X_WP is computed once per time (output ports are cached); the other outputs read it.
        self._X_WP_port = self.DeclareAbstractOutputPort("X_WP", lambda: AbstractValue.Make(RigidTransform()),
                                                         self._calc_X_WP)
        self._leg_lengths_port = self.DeclareVectorOutputPort("leg_lengths", 6, self._calc_leg_lengths)
        self.DeclareVectorOutputPort("stroke_exceeded", 1, self._calc_stroke_exceeded)
        self.DeclareVectorOutputPort("pad_motion", 9, self._calc_pad_motion)
        self.DeclareVectorOutputPort("V_WP", 6, lambda context, output: output.SetFromVector(
            self.V_WP(context.get_time())))
        self.DeclareVectorOutputPort("carrier_state", 4, self._calc_carrier_state)
        self.DeclareVectorOutputPort("deck_motion", DECK_MOTION_SIZE, self._calc_deck_motion)
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()),
                                       self._calc_geometry_pose)

    @property
    def X_PT(self) -> RigidTransform:
        """Pose of the tag frame T in the deck frame P. T is the paper's camera-facing convention
        (seed 000 section 4.1): origin at the tag centre, x right and y down in the upright tag's
        image, z into the deck; a level deck under a level camera gives X_CT = [I, (0, 0, h)]."""
        return RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.0, 0.0, TAG_ABOVE_DECK_M])

    def tag_corners_T(self) -> np.ndarray:
        """The tag's four black-square corners in T (4x3, m), in ArUco's corner order."""
        return tag_corners_T(self.config.tag_size_m)

    def _register_geometry(self, scene_graph: SceneGraph) -> None:
        c, world = self.config, scene_graph.world_frame_id()
        grey, steel, deck_grey = (0.35, 0.35, 0.38, 1.0), (0.75, 0.75, 0.78, 1.0), (0.55, 0.58, 0.62, 1.0)
        register_visual(scene_graph, self.source_id, world,
                        RigidTransform([0, 0, c.base_joint_height_m / 2]),
                        Cylinder(c.base_radius_m * 1.15, c.base_joint_height_m), "stewart_base", grey,
                        collidable=True)
        self._deck_frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame("stewart_deck"))
        register_visual(scene_graph, self.source_id, self._deck_frame,
                        RigidTransform([0, 0, -c.deck_thickness_m / 2]),
                        Box(c.deck_size_m, c.deck_size_m, c.deck_thickness_m), "stewart_deck", deck_grey,
                        collidable=True)
        plate = tag_plate_scale(c.tag_size_m)
        register_visual(scene_graph, self.source_id, self._deck_frame, RigidTransform(self.X_PT.translation()),
                        Mesh(str(tag_mesh_path(c.tag_id)), plate), "apriltag", rgba=None)
        # The plate's face for distance queries (the ToF rays): a box from the deck's surface up to it.
        register_collision(scene_graph, self.source_id, self._deck_frame, RigidTransform([0, 0, TAG_ABOVE_DECK_M / 2]),
                           Box(plate, plate, TAG_ABOVE_DECK_M), "apriltag_plate")
        # Each leg is a telescoping actuator: a cylinder from the base joint towards the deck joint
        # and a thinner rod from the deck joint towards the base joint, which reaches the cylinder at the
        # longest leg. The cylinder is no longer than the shortest leg (an actuator closes no shorter than its
        # body), so it never stands up through the deck: the deck joints at +-45 deg lie under the tag's corners.
        cylinder = min(LEG_PART_FRACTION * c.leg_max_m, c.leg_min_m)
        rod = max(LEG_PART_FRACTION * c.leg_max_m, c.leg_max_m - cylinder)
        self._leg_frames = []
        for i in range(6):
            lower = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"leg{i}_cylinder"))
            upper = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"leg{i}_rod"))
            register_visual(scene_graph, self.source_id, lower, RigidTransform([0, 0, cylinder / 2]),
                            Cylinder(0.025, cylinder), f"leg{i}_cylinder", grey, collidable=True)
            register_visual(scene_graph, self.source_id, upper, RigidTransform([0, 0, rod / 2]),
                            Cylinder(0.014, rod), f"leg{i}_rod", steel, collidable=True)
            self._leg_frames.append((lower, upper))

    def X_WP(self, t: float) -> RigidTransform:
        return self.motion.X_SP(t, self.geometry)

    def V_WP(self, t: float) -> np.ndarray:
        """The deck's spatial velocity [w_WP (rad/s); v_WP (m/s)], both in W, at time t (s)."""
        return np.concatenate([self.motion.angular_velocity(t), self.motion.translation_rates(t)[0]])

    def _calc_X_WP(self, context, output):
        output.set_value(self.X_WP(context.get_time()))

    def _calc_leg_lengths(self, context, output):
        output.SetFromVector(leg_lengths(self._X_WP_port.Eval(context), self.geometry))

    def _calc_stroke_exceeded(self, context, output):
        lengths = self._leg_lengths_port.Eval(context)
        output.SetFromVector([0.0 if within_stroke(lengths, self.geometry) else 1.0])

    def _calc_pad_motion(self, context, output):
        v_WP, a_WP = self.motion.translation_rates(context.get_time())
        output.SetFromVector(np.concatenate([self._X_WP_port.Eval(context).translation(), v_WP, a_WP]))

    def _calc_carrier_state(self, context, output):
        X_WP = self._X_WP_port.Eval(context)
        x_WP = X_WP.rotation().col(0)
        output.SetFromVector([*X_WP.translation()[:2], np.arctan2(x_WP[1], x_WP[0]), 0.0])

    def _calc_deck_motion(self, context, output):
        t, h = context.get_time(), RATE_STEP_S
        n_before, n_after = (self.X_WP(t + d).rotation().col(2)[:2] for d in (-h, h))
        n = self._X_WP_port.Eval(context).rotation().col(2)[:2]
        v_WP, _ = self.motion.translation_rates(t)
        z = self._X_WP_port.Eval(context).translation()[2]
        output.SetFromVector([*n, *((n_after - n_before) / (2 * h)), z, v_WP[2], 1.0, 0.0])

    def _calc_geometry_pose(self, context, output):
        X_WP = self._X_WP_port.Eval(context)
        poses = output.get_mutable_value()
        poses.clear()
        poses.set_value(self._deck_frame, X_WP)
        q_W = X_WP.multiply(self.geometry.q_P.T).T
        for (lower, upper), b_W, q in zip(self._leg_frames, self.geometry.b_S, q_W):
            poses.set_value(lower, frame_between(b_W, q))
            poses.set_value(upper, frame_between(q, b_W))
