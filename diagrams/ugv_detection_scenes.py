"""Rendered fisheye frames for UGV detection (seed 003 Sec. 2.2.1, Fig. 4, Table 3): the UGV over a textured
ground among distractor vehicles, seen by seed 003's fisheye from random heights and offsets, with
optional motion blur and small (high, far off-axis) targets, and the true boxes computed from the geometry.

    renderer = UgvSceneRenderer(UgvSceneConfig())
    for frame in renderer.frames(range(100, 110)):
        frame.image, frame.ugv_box, frame.distractor_boxes

The UGV is the project's ground-vehicle geometry (systems/vehicles/ground_vehicle_geometry.py: body,
wheels, the 1.0 m pad with the five ArUco markers) sized as seed 003's remote-control vehicle
(`seed003_ugv_platform`; Sec. 3.2.1 gives only the pad, 1.0 x 1.0 m), posed on the ground by its state
[x, y, heading, 0]. The ground is diagrams/stereo_hover.py's textured square (a texture seed per data
set, so held-out frames show a ground the training never saw). Distractors are plain boxes of the UGV's
size from a fixed pool (a pose per frame cannot change a colour, so every colour is registered,
`DISTRACTOR_COPIES` times), parked far beyond the far clip when unused; one colour is the UGV's own.

Frames: W z up, the UAV body B (x forward, z up), the fisheye frame C at the fisheye's mount X_BC,
the vehicle frame V (ground_vehicle.py), a distractor's frame D at the centre of its box's base.

Boxes are [x, y, w, h] px, (x, y) the top-left corner, covering [x, x + w) x [y, y + h) in pixel-index
space (pixel i spans [i, i + 1): OpenCV's Rect, the project's box, as boxes from cv2.boundingRect and
HOG windows are). A point projected to u (pixel centres at integers) lies at u + 0.5 in that space.
The true box of an object is the enclosing box of its 3-D bounding box's surface (a grid on its six
faces: a straight edge bows outwards in the fisheye, so the extremes need not be at the corners)
projected with the fisheye's model (`project_points`); points beyond the field of view count at its rim
(`projected_box`); clipped to the image; None when less than `min_box_px` of it is left.
"""

import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import FramePoseVector, GeometryFrame, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from diagrams.stereo_hover import GroundConfig, add_textured_ground
from systems.config import require
from systems.geometry import ray_to_plane
from systems.noise import sample_rng
from systems.sensors.camera import motion_blur_kernel
from systems.sensors.fisheye import FisheyeConfig, add_fisheye_camera, project_points
from systems.vehicles.ground_vehicle_geometry import GroundVehicleGeometry, PlatformConfig
from systems.vehicles.traffic import DISTRACTOR_COLOURS, DISTRACTOR_SIZE_HIGH_M, DISTRACTOR_SIZE_LOW_M, register_box

DISTRACTOR_COPIES = 2  # boxes registered per colour (a frame shows at most this many of one colour)
PARKED = RigidTransform([1.0e4, 1.0e4, -1.0e3])  # far beyond the far clip
UGV_WHEELBASE_M = 0.9
# Scene seeds: training examples, the trained threshold's validation, and the held-out frames the
# benchmark and the tests score (never seen in training, and over another ground texture).
TRAIN_SEEDS = range(100_000)
VALIDATION_SEEDS = range(500_000, 600_000)
HELD_OUT_SEEDS = range(1_000_000, 1_100_000)
TRAIN_TEXTURE_SEED = 1  # the training and validation frames' ground; held-out frames show GroundConfig's default


def seed003_ugv_platform() -> PlatformConfig:
    """Seed 003's remote-control UGV with its 1.0 x 1.0 m pad on top (Sec. 3.2.1); the body's size is
    ours (the paper shows the vehicle in Fig. 10 without dimensions): a 1.4 x 1.0 m body whose roof
    the pad covers but for 0.2 m at each end, 0.5 m tall."""
    return PlatformConfig(height_m=0.5, pad_size_m=1.0, pad_offset_m=0.45, body_length_m=1.4, body_width_m=1.0,
                          rear_overhang_m=0.25, ground_clearance_m=0.1, wheel_radius_m=0.12, wheel_width_m=0.1)


def ugv_bounds_V(platform: PlatformConfig, wheelbase_m: float = UGV_WHEELBASE_M) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners [m] of the UGV's 3-D bounding box (body, wheels, pad) in V."""
    p = platform
    x_low = min(-p.rear_overhang_m, -p.wheel_radius_m, p.pad_offset_m - p.pad_size_m / 2)
    x_high = max(p.body_length_m - p.rear_overhang_m, wheelbase_m + p.wheel_radius_m, p.pad_offset_m + p.pad_size_m / 2)
    y = max(p.body_width_m / 2 + p.wheel_width_m / 2, p.pad_size_m / 2)
    return np.array([x_low, -y, 0.0]), np.array([x_high, y, p.height_m + 0.001])


def box_surface_points(low, high, n: int = 17) -> np.ndarray:
    """Points (6 n^2, 3) on a grid over the six faces of the box [low, high] (corners and edge midpoints
    included for odd n), in the box's frame."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    s = np.linspace(0.0, 1.0, n)
    a, b = (g.ravel() for g in np.meshgrid(s, s))
    points = []
    for axis in range(3):
        others = [k for k in range(3) if k != axis]
        for side in (0.0, 1.0):
            unit = np.empty((a.size, 3))
            unit[:, axis], unit[:, others[0]], unit[:, others[1]] = side, a, b
            points.append(low + unit * (high - low))
    return np.vstack(points)


def projected_box(p_C: np.ndarray, config: FisheyeConfig, min_box_px: float = 3.0) -> np.ndarray | None:
    """The enclosing box [x, y, w, h] px (module docstring) of the points p_C (N, 3) [m] in C, None unless
    some lie within the field of view. Points in front of the lens (z_C > 0) but beyond the field of view
    count at the rim, at their azimuth (a surface crossing the rim is seen up to it); points behind it not
    at all. Clipped to the image; None if narrower than `min_box_px` either way."""
    p_C = np.asarray(p_C, float).reshape(-1, 3)
    theta = np.arctan2(np.hypot(p_C[:, 0], p_C[:, 1]), p_C[:, 2])
    inside = theta <= config.theta_max
    if not inside.any():
        return None
    uv = [project_points(p_C[inside], config)]
    beyond = ~inside & (p_C[:, 2] > 0)
    if beyond.any():
        azimuth = np.arctan2(p_C[beyond, 1], p_C[beyond, 0])
        uv.append(np.column_stack([config.cx + config.radius_px * np.cos(azimuth),
                                   config.cy + config.radius_px * np.sin(azimuth)]))
    uv = np.vstack(uv) + 0.5  # pixel-index space
    x0, y0 = np.clip(uv.min(axis=0), 0.0, [config.width, config.height])
    x1, y1 = np.clip(uv.max(axis=0), 0.0, [config.width, config.height])
    if x1 - x0 < min_box_px or y1 - y0 < min_box_px:
        return None
    return np.array([x0, y0, x1 - x0, y1 - y0])


def motion_blur(image: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    """The image smeared over `length_px` along the image direction `angle_rad` (from +x towards +y): the
    camera's exposure smear (systems/sensors/camera.py's `motion_blur_kernel`, cv2.filter2D); unchanged under
    half a pixel."""
    kernel = motion_blur_kernel(length_px * np.array([np.cos(angle_rad), np.sin(angle_rad)]))
    if kernel is None:
        return image
    return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)


@dataclass
class UgvSceneConfig:
    """How frames are drawn (heights and sizes m, angles deg, speeds m/s, exposure s). Ours: the paper's
    data set (Sec. 3.2.2, Fig. 4, 11) is real flights with large distortion, motion blur and small
    targets, which these ranges imitate."""

    height_range_m: list[float] = field(default_factory=lambda: [2.0, 10.0])  # the fisheye above the ground
    tilt_max_deg: float = 10.0  # the UAV's roll and pitch, each uniform in +-this
    max_off_axis_deg: float = 62.0  # the UGV centre's angle from the optical axis, uniform in solid angle
    small_fraction: float = 0.2  # frames with a small target: high and far off-axis
    small_height_range_m: list[float] = field(default_factory=lambda: [7.0, 10.0])
    small_off_axis_range_deg: list[float] = field(default_factory=lambda: [55.0, 68.0])
    empty_fraction: float = 0.1  # frames without the UGV (every detection is then a false positive)
    max_distractors: int = 4  # 0..max per frame, uniform
    same_colour_probability: float = 0.3  # that one distractor has the UGV's colour
    distractor_off_axis_max_deg: float = 70.0
    min_separation_m: float = 2.6  # between centres of the UGV and distractors
    blur_probability: float = 0.4  # frames with motion blur
    max_speed_mps: float = 8.0  # the image motion's ground speed, uniform in [0, max]
    exposure_s: float = 0.02
    max_blur_px: float = 15.0
    min_box_px: float = 6.0  # a true box narrower than this either way counts as not visible
    ground: GroundConfig = field(default_factory=lambda: GroundConfig(size_m=100.0, texture_seed=0))
    fisheye: FisheyeConfig = field(default_factory=FisheyeConfig)
    platform: PlatformConfig = field(default_factory=seed003_ugv_platform)
    # Distractor boxes' sizes [m]: length, width, height drawn once per pool box from this range.
    distractor_size_low_m: list[float] = field(default_factory=lambda: list(DISTRACTOR_SIZE_LOW_M))
    distractor_size_high_m: list[float] = field(default_factory=lambda: list(DISTRACTOR_SIZE_HIGH_M))

    def validate(self, prefix: str = "ugv_scenes") -> None:
        for name in ("height_range_m", "small_height_range_m", "small_off_axis_range_deg"):
            low_high = getattr(self, name)
            require(len(low_high) == 2 and 0 < low_high[0] <= low_high[1],
                    f"{prefix}.{name} must be [low, high] with 0 < low <= high, got {low_high}")
        for name in ("small_fraction", "empty_fraction", "same_colour_probability", "blur_probability"):
            require(0 <= getattr(self, name) <= 1, f"{prefix}.{name} must lie in [0, 1]")
        require(self.small_fraction + self.empty_fraction <= 1,
                f"{prefix}.small_fraction + {prefix}.empty_fraction must not exceed 1")
        half_fov = self.fisheye.fov_deg / 2
        for name in ("max_off_axis_deg", "distractor_off_axis_max_deg"):
            require(0 < getattr(self, name) < half_fov, f"{prefix}.{name} must lie in (0, {half_fov:g}) deg")
        require(self.small_off_axis_range_deg[1] < half_fov,
                f"{prefix}.small_off_axis_range_deg must stay inside the {half_fov:g} deg half field of view")
        require(0 <= self.tilt_max_deg < 45, f"{prefix}.tilt_max_deg must lie in [0, 45) deg")
        require(isinstance(self.max_distractors, int) and 0 <= self.max_distractors <= 2 * len(DISTRACTOR_COLOURS),
                f"{prefix}.max_distractors must be an integer in [0, {2 * len(DISTRACTOR_COLOURS)}]")
        for name in ("max_speed_mps", "exposure_s", "max_blur_px", "min_box_px", "min_separation_m"):
            require(getattr(self, name) >= 0, f"{prefix}.{name} must not be negative")
        require(len(self.distractor_size_low_m) == 3 and len(self.distractor_size_high_m) == 3
                and all(0 < a <= b for a, b in zip(self.distractor_size_low_m, self.distractor_size_high_m)),
                f"{prefix}.distractor_size_low_m/high_m need 3 sizes each, 0 < low <= high")
        self.ground.validate(f"{prefix}.ground")
        self.fisheye.validate(f"{prefix}.fisheye")
        self.platform.validate(f"{prefix}.platform")


def training_scene_config() -> UgvSceneConfig:
    """The held-out frames' scene config (UgvSceneConfig()) over the training ground texture."""
    return UgvSceneConfig(ground=GroundConfig(size_m=100.0, texture_seed=TRAIN_TEXTURE_SEED))


@dataclass(frozen=True)
class DistractorBox:
    """A pool box: its colour's name, RGB in [0, 1], and size [m] (length along x_D, width, height)."""

    colour: str
    rgb: tuple
    size_m: tuple


def distractor_pool(config: UgvSceneConfig) -> list[DistractorBox]:
    """The registered distractors: DISTRACTOR_COPIES per colour, sizes drawn once (a fixed stream)."""
    rng = sample_rng(0, "ugv_distractor_sizes", 0)
    low, high = np.asarray(config.distractor_size_low_m), np.asarray(config.distractor_size_high_m)
    return [DistractorBox(name, rgb, tuple(float(s) for s in rng.uniform(low, high)))
            for name, rgb in DISTRACTOR_COLOURS.items() for _ in range(DISTRACTOR_COPIES)]


@dataclass
class UgvScene:
    """One frame's draw: the UAV body's pose X_WB, the UGV's state [x, y, heading, 0] (None: absent),
    the distractors shown (pool index, X_WD), the motion blur (length px, direction rad) and whether
    the frame was drawn as a small-target one."""

    seed: int
    X_WB: RigidTransform
    ugv_state: np.ndarray | None
    distractors: list[tuple[int, RigidTransform]]
    blur_px: float
    blur_angle_rad: float
    small: bool


def _ray_to_height(p_WC: np.ndarray, ray_W: np.ndarray, z: float) -> np.ndarray | None:
    """Where the ray from p_WC along ray_W meets the plane at height z (W, m), or None if it does not."""
    return ray_to_plane(p_WC, ray_W, p_WC[2] - z, z, min_ray_down=1e-6)


def _direction_C(theta: float, phi: float) -> np.ndarray:
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def sample_scene(seed: int, config: UgvSceneConfig, pool: list[DistractorBox]) -> UgvScene:
    """The frame drawn for `seed` (a pure function of it: sample_rng(seed, "ugv_detection_scene", 0))."""
    rng = sample_rng(seed, "ugv_detection_scene", 0)
    kind = rng.uniform()
    small = kind < config.small_fraction
    empty = config.small_fraction <= kind < config.small_fraction + config.empty_fraction
    heights = config.small_height_range_m if small else config.height_range_m
    height = rng.uniform(*heights)
    tilt = np.radians(config.tilt_max_deg)
    reach = 0.3 * config.ground.size_m  # the UAV anywhere over the middle of the ground: fresh texture per frame
    X_WB = RigidTransform(RollPitchYaw(rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-np.pi, np.pi)),
                          [rng.uniform(-reach, reach), rng.uniform(-reach, reach), height])
    X_WC = X_WB.multiply(config.fisheye.X_BC)
    p_WC, R_WC = X_WC.translation(), X_WC.rotation().matrix()
    centre_height = config.platform.height_m / 2
    if small:
        theta = np.radians(rng.uniform(*config.small_off_axis_range_deg))
    else:  # uniform in solid angle up to the limit
        theta = np.arccos(1 - rng.uniform() * (1 - np.cos(np.radians(config.max_off_axis_deg))))
    p_Wcentre = _ray_to_height(p_WC, R_WC @ _direction_C(theta, rng.uniform(-np.pi, np.pi)), centre_height)
    heading = rng.uniform(-np.pi, np.pi)
    ugv_state = None
    occupied = []
    if not empty and p_Wcentre is not None:
        low, high = ugv_bounds_V(config.platform)
        centre_V = (low[:2] + high[:2]) / 2
        R = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]])
        xy = p_Wcentre[:2] - R @ centre_V
        ugv_state = np.array([xy[0], xy[1], heading, 0.0])
        occupied.append(p_Wcentre[:2])
    distractors = []
    count = int(rng.integers(0, config.max_distractors + 1))
    same_colour = rng.uniform() < config.same_colour_probability
    colours = [name for name in DISTRACTOR_COLOURS if name != "ugv"]
    chosen = list(rng.choice(colours, size=count, replace=True)) if count else []
    if same_colour and count:
        chosen[0] = "ugv"
    used = set()
    cos_max = np.cos(np.radians(config.distractor_off_axis_max_deg))
    for name in chosen:
        slots = [i for i, box in enumerate(pool) if box.colour == name and i not in used]
        if not slots:
            continue
        for _ in range(30):  # rejection sampling of a free spot in view
            theta_d = np.arccos(1 - rng.uniform() * (1 - cos_max))
            spot = _ray_to_height(p_WC, R_WC @ _direction_C(theta_d, rng.uniform(-np.pi, np.pi)), 0.0)
            if spot is not None and all(np.linalg.norm(spot[:2] - o) >= config.min_separation_m for o in occupied):
                index = slots[0]
                used.add(index)
                occupied.append(spot[:2])
                distractors.append((index, RigidTransform(RotationMatrix.MakeZRotation(rng.uniform(-np.pi, np.pi)),
                                                          [spot[0], spot[1], 0.0])))
                break
    blur_px, blur_angle = 0.0, 0.0
    if rng.uniform() < config.blur_probability:
        # The ground's image speed at the nadir scale, f / height px per m.
        blur_px = min(rng.uniform(0.0, config.max_speed_mps) * config.exposure_s * config.fisheye.f / height,
                      config.max_blur_px)
        blur_angle = rng.uniform(-np.pi, np.pi)
    return UgvScene(seed, X_WB, ugv_state, distractors, float(blur_px), float(blur_angle), bool(small))


def ugv_box(scene: UgvScene, config: UgvSceneConfig) -> np.ndarray | None:
    """The UGV's true box [x, y, w, h] px in the frame (module docstring), None when absent or unseen."""
    if scene.ugv_state is None:
        return None
    return _object_box(scene, _X_WV(scene), *ugv_bounds_V(config.platform), config)


def _X_WV(scene: UgvScene) -> RigidTransform:
    """The UGV's pose in W from its state [x, y, heading, _] (on the ground)."""
    x, y, heading, _ = scene.ugv_state
    return RigidTransform(RotationMatrix.MakeZRotation(heading), [x, y, 0.0])


def pad_centre_pixel(scene: UgvScene, config: UgvSceneConfig) -> np.ndarray | None:
    """The pad's centre (on the roof, pad_offset_m ahead of V) in the frame [u, v] px, the point the hybrid
    estimate takes a box's centre for; None when the UGV is absent or the point beyond the field of view."""
    if scene.ugv_state is None:
        return None
    X_CV = scene.X_WB.multiply(config.fisheye.X_BC).inverse().multiply(_X_WV(scene))
    p_C = X_CV.multiply(np.array([config.platform.pad_offset_m, 0.0, config.platform.height_m]))
    if np.arctan2(np.hypot(p_C[0], p_C[1]), p_C[2]) > config.fisheye.theta_max:
        return None
    return project_points(p_C.reshape(1, 3), config.fisheye)[0]


def distractor_boxes(scene: UgvScene, config: UgvSceneConfig, pool: list[DistractorBox]) -> list[np.ndarray]:
    """The shown distractors' true boxes (those seen)."""
    boxes = []
    for index, X_WD in scene.distractors:
        size = np.asarray(pool[index].size_m)
        box = _object_box(scene, X_WD, np.array([-size[0] / 2, -size[1] / 2, 0.0]),
                          np.array([size[0] / 2, size[1] / 2, size[2]]), config)
        if box is not None:
            boxes.append(box)
    return boxes


def _object_box(scene: UgvScene, X_WO: RigidTransform, low, high, config: UgvSceneConfig) -> np.ndarray | None:
    X_CO = scene.X_WB.multiply(config.fisheye.X_BC).inverse().multiply(X_WO)
    p_C = (X_CO.rotation().matrix() @ box_surface_points(low, high).T).T + X_CO.translation()
    return projected_box(p_C, config.fisheye, config.min_box_px)


class ScenePoser(LeafSystem):
    """Registers the UAV body frame B (no geometry: the fisheye's faces ride on it) and the distractor
    pool's boxes, and poses them from the abstract input `poses` (list: X_WB, then one X_WD per pool box)."""

    def __init__(self, scene_graph: SceneGraph, pool: list[DistractorBox]):
        super().__init__()
        self.source_id = scene_graph.RegisterSource("ugv_detection_scene")
        self.body_frame_id = scene_graph.RegisterFrame(self.source_id, GeometryFrame("ugv_scene_uav"))
        self._frames = [self.body_frame_id] + [register_box(scene_graph, self.source_id, f"distractor_{i}", box.size_m,
                                                            box.rgb) for i, box in enumerate(pool)]
        self._poses = self.DeclareAbstractInputPort(
            "poses", AbstractValue.Make([RigidTransform()] + [PARKED] * len(pool)))
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc)

    def _calc(self, context, output):
        poses = output.get_mutable_value()
        poses.clear()
        for frame, X in zip(self._frames, self._poses.Eval(context)):
            poses.set_value(frame, X)


@dataclass
class UgvFrame:
    """A rendered frame: RGB (H, W, 3) uint8, the UGV's true box or None, the distractors' boxes."""

    image: np.ndarray
    ugv_box: np.ndarray | None
    distractor_boxes: list[np.ndarray]
    scene: UgvScene


class UgvSceneRenderer:
    """The scene built once (ground, UGV, distractor pool, fisheye on B); `render(scene)` poses it and
    returns the fisheye image with the scene's motion blur."""

    def __init__(self, config: UgvSceneConfig | None = None):
        self.config = config = config or UgvSceneConfig()
        config.validate()
        self.pool = distractor_pool(config)
        builder = DiagramBuilder()
        scene_graph = builder.AddSystem(SceneGraph())
        add_textured_ground(scene_graph, config.ground)
        self.ugv = builder.AddSystem(GroundVehicleGeometry(UGV_WHEELBASE_M, config.platform, scene_graph))
        builder.Connect(self.ugv.get_output_port(), scene_graph.get_source_pose_port(self.ugv.source_id))
        self.poser = builder.AddSystem(ScenePoser(scene_graph, self.pool))
        builder.Connect(self.poser.get_output_port(), scene_graph.get_source_pose_port(self.poser.source_id))
        self.rig = add_fisheye_camera(builder, scene_graph, self.poser.body_frame_id, config.fisheye)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()

    def sample(self, seed: int) -> UgvScene:
        return sample_scene(seed, self.config, self.pool)

    def render(self, scene: UgvScene) -> np.ndarray:
        """The fisheye RGB image (H, W, 3) uint8 of the scene, motion-blurred as drawn."""
        poses = [scene.X_WB] + [PARKED] * len(self.pool)
        for index, X_WD in scene.distractors:
            poses[index + 1] = X_WD
        self.poser.get_input_port().FixValue(self.poser.GetMyContextFromRoot(self.context), poses)
        state = scene.ugv_state if scene.ugv_state is not None else np.array([PARKED.translation()[0], 0.0, 0.0, 0.0])
        self.ugv.get_input_port().FixValue(self.ugv.GetMyContextFromRoot(self.context), state)
        image = self.rig.color_image.Eval(self.rig.camera.GetMyContextFromRoot(self.context)).data[..., :3].copy()
        return motion_blur(image, scene.blur_px, scene.blur_angle_rad)

    def frame(self, seed: int) -> UgvFrame:
        scene = self.sample(seed)
        return UgvFrame(self.render(scene), ugv_box(scene, self.config),
                        distractor_boxes(scene, self.config, self.pool), scene)

    def frames(self, seeds: Iterable[int]) -> Iterator[UgvFrame]:
        """Yields each seed's frame (image, true UGV box or None, distractor boxes)."""
        for seed in seeds:
            yield self.frame(seed)


def default_cache_dir() -> Path:
    """results/ugv_detection_cache at the repository's root (git ignores results/)."""
    return Path(__file__).resolve().parents[1] / "results" / "ugv_detection_cache"


@dataclass
class UgvDataset:
    """Rendered frames as arrays: images (N, H, W, 3) uint8, ugv_boxes (N, 4) px (NaN: no UGV seen),
    distractor_boxes (list of (k, 4) arrays), and per frame the seed, blur length px, small flag."""

    images: np.ndarray
    ugv_boxes: np.ndarray
    distractor_boxes: list[np.ndarray]
    seeds: np.ndarray
    blur_px: np.ndarray
    small: np.ndarray

    def __len__(self) -> int:
        return len(self.images)

    def ugv_box(self, i: int) -> np.ndarray | None:
        return None if np.isnan(self.ugv_boxes[i, 0]) else self.ugv_boxes[i]


def _cache_key(config: UgvSceneConfig, seeds: list[int]) -> str:
    text = json.dumps({"config": asdict(config), "seeds": seeds, "version": 3}, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def load_or_render_dataset(seeds: Iterable[int], config: UgvSceneConfig | None = None,
                           cache_dir: Path | None = None, renderer: UgvSceneRenderer | None = None,
                           progress=None) -> UgvDataset:
    """The frames of `seeds`, read from `cache_dir` (default `default_cache_dir()`) when rendered before
    with the same config, else rendered and written there (an .npz named by a hash of config and seeds,
    written to a temporary name and renamed)."""
    config = config or (renderer.config if renderer else UgvSceneConfig())
    seeds = [int(s) for s in seeds]
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = cache_dir / f"ugv_frames_{_cache_key(config, seeds)}.npz"
    if path.exists():
        with np.load(path) as data:
            counts = data["distractor_counts"]
            flat = data["distractor_boxes"]
            splits = np.split(flat, np.cumsum(counts)[:-1]) if len(counts) else []
            return UgvDataset(data["images"], data["ugv_boxes"], [s.reshape(-1, 4) for s in splits], data["seeds"],
                              data["blur_px"], data["small"])
    renderer = renderer or UgvSceneRenderer(config)
    images, boxes, others, blur, small = [], [], [], [], []
    for frame in renderer.frames(progress(seeds) if progress else seeds):
        images.append(frame.image)
        boxes.append(frame.ugv_box if frame.ugv_box is not None else np.full(4, np.nan))
        others.append(np.asarray(frame.distractor_boxes, float).reshape(-1, 4))
        blur.append(frame.scene.blur_px)
        small.append(frame.scene.small)
    dataset = UgvDataset(np.asarray(images), np.asarray(boxes), others, np.asarray(seeds), np.asarray(blur),
                         np.asarray(small))
    cache_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=cache_dir, prefix=path.name + ".", suffix=".npz")
    os.close(fd)
    np.savez_compressed(tmp, images=dataset.images, ugv_boxes=dataset.ugv_boxes,
                        distractor_boxes=np.vstack(others) if others else np.zeros((0, 4)),
                        distractor_counts=np.array([len(o) for o in others], int), seeds=dataset.seeds,
                        blur_px=dataset.blur_px, small=dataset.small)
    os.replace(tmp, path)
    return dataset
