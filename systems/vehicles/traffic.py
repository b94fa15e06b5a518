"""Other vehicles driving beside the UGV: the distractors of seed 003's tracking tests (Sec. 2.2.2, 4.4: the
tracker must keep the UGV among vehicles that look like it). Ours: their shapes, colours and motion.

Each distractor is a box on wheels' height (the detector's training distractors, diagrams/ugv_detection_scenes.py)
that drives the UGV's own path in a lane beside it: at time t it is at arc length s0 + f D(t) of the path, D(t)
the UGV's distance driven (its speed times t, or its speed schedule's integral), offset `lane` metres to the path's
left (negative: right), facing along it. s0 (ahead of the UGV's start), the speed factor f and the lane are drawn
per distractor from the scenario's seed; the first `same_colour`
wear the UGV's body colour, the rest the other colours in turn. Poses come from the time alone (no state, no
event): SceneGraph reads them when a camera renders. Frames: W z up; D at the box's footprint centre, x along
its length.
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, FramePoseVector, GeometryFrame, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.geometry import register_visual
from systems.noise import sample_rng
from systems.vehicles.ground_vehicle import GroundVehicleConfig
from systems.vehicles.ground_vehicle_geometry import BODY_RGB
from systems.vehicles.paths import Path

# Distractor colours (RGB in [0, 1]): varied hues, greys, and the UGV's own colour last.
DISTRACTOR_COLOURS = {
    "red": (0.8, 0.1, 0.1), "green": (0.15, 0.6, 0.2), "blue": (0.15, 0.25, 0.75), "yellow": (0.9, 0.8, 0.15),
    "white": (0.92, 0.92, 0.92), "dark": (0.18, 0.18, 0.2), "purple": (0.5, 0.2, 0.6), "cyan": (0.2, 0.7, 0.75),
    "ugv": BODY_RGB,
}
MAX_DISTRACTORS = 16
# A distractor box's size range [m] (length, width, height): car-like boxes about the UGV's 1.4 x 1.0 x 0.5 m,
# shared with the detector's training scenes (diagrams/ugv_detection_scenes.py).
DISTRACTOR_SIZE_LOW_M = (1.1, 0.8, 0.35)
DISTRACTOR_SIZE_HIGH_M = (1.9, 1.2, 0.7)


@dataclass
class DistractorsConfig:
    """The scenario's `distractors` section: how many, metres, m/s factors. Ours."""

    count: int = 0
    same_colour: int = 0  # how many of them wear the UGV's colour
    lane_min_m: float = 2.5  # |lateral offset| from the UGV's path, drawn uniform in [min, max], either side
    lane_max_m: float = 8.0
    ahead_max_m: float = 15.0  # s0 uniform in [0, ahead_max_m] of the path
    speed_factor_range: list[float] = field(default_factory=lambda: [0.6, 1.4])  # of the UGV's speed (schedule)
    # Box sizes [m] (length, width, height), drawn per distractor: the detector's training distractors' range.
    size_low_m: list[float] = field(default_factory=lambda: list(DISTRACTOR_SIZE_LOW_M))
    size_high_m: list[float] = field(default_factory=lambda: list(DISTRACTOR_SIZE_HIGH_M))

    def lead(self) -> tuple[float, float]:
        """(factor, ahead_m): the furthest a distractor gets along the path is ahead_m plus factor times the UGV's
        distance driven (GroundVehicleConfig.ground_length_m); (1, 0) without distractors."""
        return (max(1.0, self.speed_factor_range[1]), self.ahead_max_m) if self.count else (1.0, 0.0)

    def validate(self, prefix: str = "distractors") -> None:
        require(isinstance(self.count, int) and 0 <= self.count <= MAX_DISTRACTORS,
                f"{prefix}.count must be an integer in [0, {MAX_DISTRACTORS}], got {self.count}")
        require(isinstance(self.same_colour, int) and 0 <= self.same_colour <= self.count,
                f"{prefix}.same_colour must be an integer in [0, {prefix}.count], got {self.same_colour}")
        require_positive(self.lane_min_m, f"{prefix}.lane_min_m")
        require(self.lane_max_m >= self.lane_min_m, f"{prefix}.lane_max_m must not be under {prefix}.lane_min_m")
        require_non_negative(self.ahead_max_m, f"{prefix}.ahead_max_m")
        low_high = self.speed_factor_range
        require(len(low_high) == 2 and 0 <= low_high[0] <= low_high[1],
                f"{prefix}.speed_factor_range must be [low, high] with 0 <= low <= high, got {low_high}")
        require(len(self.size_low_m) == 3 and len(self.size_high_m) == 3
                and all(0 < a <= b for a, b in zip(self.size_low_m, self.size_high_m)),
                f"{prefix}.size_low_m/size_high_m need 3 sizes each, 0 < low <= high")

    def check_lanes(self, path: Path, path_named: str, prefix: str = "distractors") -> None:
        """ConfigError unless every lane [m] is under the tightest radius of `path` (named `path_named`), 1 / its
        largest curvature: a lane wider than a curve's radius puts a distractor past the curve's centre, where
        it drives backwards."""
        if not self.count or path.max_curvature == 0.0:
            return
        radius = 1.0 / path.max_curvature
        require(self.lane_max_m < radius,
                f"{prefix}.lane_max_m ({self.lane_max_m:g} m) must be under the tightest radius of {path_named}, "
                f"{radius:.1f} m: a wider lane puts a distractor past the curve's centre, driving backwards")


@dataclass(frozen=True)
class Distractor:
    """One distractor's draw: colour name and RGB, size [m] (length, width, height), start arc length s0 [m],
    speed factor (its speed over the UGV's, at every moment) and lane [m, + left of the path]."""

    colour: str
    rgb: tuple
    size_m: tuple
    s0_m: float
    speed_factor: float
    lane_m: float


def draw_distractors(config: DistractorsConfig, seed: int) -> list[Distractor]:
    """The seeded draws (module docstring): one stream per distractor, so adding one keeps the others."""
    others = [name for name in DISTRACTOR_COLOURS if name != "ugv"]
    out = []
    for i in range(config.count):
        rng = sample_rng(seed, "distractors", i)
        colour = "ugv" if i < config.same_colour else others[(i - config.same_colour) % len(others)]
        size = tuple(float(v) for v in rng.uniform(config.size_low_m, config.size_high_m))
        lane = float(rng.uniform(config.lane_min_m, config.lane_max_m) * rng.choice([-1.0, 1.0]))
        out.append(Distractor(colour, DISTRACTOR_COLOURS[colour], size, float(rng.uniform(0.0, config.ahead_max_m)),
                              float(rng.uniform(*config.speed_factor_range)), lane))
    return out


def distractor_pose(path: Path, vehicle: GroundVehicleConfig, d: Distractor, time: float) -> RigidTransform:
    """X_WD at `time` [s]: on the path at s0 + the speed factor times the UGV's (`vehicle`'s) distance driven,
    `lane` to its left, facing along it."""
    s = d.s0_m + vehicle.distance_driven_m(time, d.speed_factor)
    heading = path.heading(s)
    left = np.array([-np.sin(heading), np.cos(heading)])
    return RigidTransform(RotationMatrix.MakeZRotation(heading), [*(path.position(s) + d.lane_m * left), 0.0])


def register_box(scene_graph: SceneGraph, source_id, name: str, size_m, rgb) -> object:
    """A new frame D named `name` with a box of `size_m` (length along x_D, width, height) standing on D's
    origin, coloured `rgb`, seen by Meshcat and the cameras; returns D's FrameId (pose it through the
    source's pose port)."""
    frame = scene_graph.RegisterFrame(source_id, GeometryFrame(name))
    length, width, height = size_m
    register_visual(scene_graph, source_id, frame, RigidTransform([0.0, 0.0, height / 2]),
                    Box(length, width, height), name, (*rgb, 1.0))
    return frame


class Traffic(LeafSystem):
    """Registers the distractors' boxes with SceneGraph (source `traffic`) and poses them from the context's
    time and the UGV's (`vehicle`'s) speed or schedule: output `geometry_pose` (FramePoseVector), for
    scene_graph.get_source_pose_port(source_id)."""

    def __init__(self, scene_graph: SceneGraph, path: Path, vehicle: GroundVehicleConfig,
                 distractors: list[Distractor]):
        super().__init__()
        self.source_id = scene_graph.RegisterSource("traffic")
        self._path, self._vehicle, self._distractors = path, vehicle, distractors
        self._frames = [register_box(scene_graph, self.source_id, f"distractor_{i}", d.size_m, d.rgb)
                        for i, d in enumerate(distractors)]
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc)

    def _calc(self, context, output):
        poses = output.get_mutable_value()
        poses.clear()
        for frame, d in zip(self._frames, self._distractors):
            poses.set_value(frame, distractor_pose(self._path, self._vehicle, d, context.get_time()))
