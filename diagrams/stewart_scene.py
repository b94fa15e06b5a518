"""The seed 000 scene: a quadrotor hovering over a Stewart-platform deck carrying an AprilTag, with a
downward camera, four ToF range sensors and an IMU; ground truth and measurements logged at the
camera rate.

    from diagrams.stewart_scene import build_stewart_scene, StewartSceneConfig
    diagram, handles = build_stewart_scene(StewartSceneConfig())
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import Diagram, DiagramBuilder, OutputPort
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from systems.config import require
from systems.estimators.atda import AtdaEstimator
from systems.estimators.crhf import CrhfConfig, CrhfEstimator
from systems.estimators.estimate import PoseEstimateToVector
from systems.perception.apriltag import TagDetection, TagDetectorSystem
from systems.perception.latency import MeasurementLatency
from systems.platforms.stewart import StewartPlatform, StewartPlatformConfig
from systems.sensors.camera import CameraConfig, NoisyCamera, add_camera, add_renderer
from systems.sensors.ground_truth import AxisFlow, RelativePose
from systems.sensors.imu import Imu, ImuConfig
from systems.sensors.tof import TofConfig, TofSensors, make_tof_camera, sensor_positions_C
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry, PrescribedPose
from systems.viewers import VideoRecorder


@dataclass
class HoverConfig:
    """Where the drone hovers: the camera `height_above_deck_m` above the deck's nominal top surface,
    offset horizontally by `offset_xy_m`, heading `yaw_deg`, level unless `roll_deg`/`pitch_deg`."""

    height_above_deck_m: float = 2.0  # seed 000 section 4.1: tag 2 m below the camera
    offset_xy_m: list[float] = field(default_factory=lambda: [0.0, 0.0])
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0

    def validate(self, prefix: str = "hover") -> None:
        require(self.height_above_deck_m > 0.1, f"{prefix}.height_above_deck_m must exceed 0.1 m")
        require(len(self.offset_xy_m) == 2, f"{prefix}.offset_xy_m needs 2 numbers")


@dataclass
class StewartSceneConfig:
    seed: int = 0
    platform: StewartPlatformConfig = field(default_factory=StewartPlatformConfig)
    uav: AirframeConfig = field(default_factory=AirframeConfig)
    hover: HoverConfig = field(default_factory=HoverConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    tof: TofConfig = field(default_factory=TofConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    # Pose estimators of the tag in the camera, X_CT, run on the same camera stream: "atda", "crhf".
    estimators: list[str] = field(default_factory=list)
    crhf: CrhfConfig = field(default_factory=CrhfConfig)
    # Camera frames from exposure to estimate (issue 13's latency): the estimators get each frame's tag
    # detection and ranges this many frames late, so their estimates are scored against a later truth.
    estimate_latency_frames: int = 0

    def validate(self) -> None:
        for name in ("platform", "uav", "hover", "camera", "tof", "imu", "crhf"):
            getattr(self, name).validate(name)
        require(self.estimate_latency_frames >= 0, "estimate_latency_frames must not be negative")
        for name in self.estimators:
            require(name in ESTIMATORS, f"estimators: unknown estimator '{name}' (known: {', '.join(ESTIMATORS)})")
        twice = sorted({name for name in self.estimators if self.estimators.count(name) > 1})
        require(not twice, f"estimators: each may be listed once, got {', '.join(twice)} more than once")


ESTIMATORS = ("atda", "crhf")


@dataclass
class StewartSceneHandles:
    """The systems and ports of a built scene that callers use."""

    scene_graph: SceneGraph
    platform: StewartPlatform
    airframe: AirframeGeometry
    body: object  # the system whose X_WB, V_WB, A_WB outputs drive the airframe (PrescribedPose here)
    camera: object  # RgbdSensor
    noisy_camera: NoisyCamera
    tof: TofSensors
    imu: Imu
    detector: TagDetectorSystem
    truth: RelativePose
    loggers: dict[str, VectorLogSink]
    X_BC: RigidTransform
    estimators: dict[str, object]  # name -> system with an X_CT_estimate (PoseEstimate) output and per_frame_ms
    meshcat_visualizer: MeshcatVisualizer | None = None
    video: VideoRecorder | None = None

    @property
    def color_image(self):
        """The (noisy) camera image output port: evaluate it only at the camera rate."""
        return self.noisy_camera.GetOutputPort("color_image")


def hover_pose(config: StewartSceneConfig, platform: StewartPlatform) -> RigidTransform:
    """X_WB that puts the camera `height_above_deck_m` above the deck's nominal top surface."""
    h = config.hover
    p_deck = platform.geometry.X_SP0.translation()
    p_WB = p_deck + [h.offset_xy_m[0], h.offset_xy_m[1], h.height_above_deck_m - config.camera.mount_xyz_m[2]]
    return RigidTransform(RollPitchYaw(np.deg2rad([h.roll_deg, h.pitch_deg, h.yaw_deg])), p_WB)


def add_uav_sensors(builder: DiagramBuilder, scene_graph: SceneGraph, body_frame_id, camera_config: CameraConfig,
                    tof_config: TofConfig, seed: int):
    """The downward camera (with pixel noise) and the four ToF sensors on the body frame: ideal rays cast
    on the scene's geometry, or cones sharing one depth render (`make_tof_camera`). Returns (RgbdSensor,
    NoisyCamera, TofSensors)."""
    camera, noisy_camera = add_camera(builder, scene_graph, body_frame_id, camera_config, seed)
    tof = builder.AddSystem(TofSensors(tof_config, seed, camera_config.period_s, (body_frame_id, camera_config.X_BC)))
    if tof_config.cone_deg > 0:
        depth_camera = builder.AddSystem(make_tof_camera(body_frame_id, camera_config.X_BC, tof_config))
        builder.Connect(scene_graph.get_query_output_port(), depth_camera.query_object_input_port())
        builder.Connect(depth_camera.depth_image_32F_output_port(), tof.get_input_port())
    else:
        builder.Connect(scene_graph.get_query_output_port(), tof.get_input_port())
    return camera, noisy_camera, tof


def add_axis_flow(builder: DiagramBuilder, X_BC: RigidTransform, body: tuple[OutputPort, OutputPort],
                  platform: StewartPlatform, noisy_camera: NoisyCamera) -> AxisFlow:
    """Feeds the camera's motion blur: the deck's motion across the image (`AxisFlow`) from the body's
    (X_WB, V_WB) ports and the deck's pose and spatial velocity."""
    flow = builder.AddSystem(AxisFlow(X_BC))
    for name, port in zip(("X_WB", "V_WB"), body):
        builder.Connect(port, flow.GetInputPort(name))
    builder.Connect(platform.GetOutputPort("X_WP"), flow.GetInputPort("X_WS"))
    builder.Connect(platform.GetOutputPort("V_WP"), flow.GetInputPort("V_WS"))
    builder.Connect(flow.get_output_port(), noisy_camera.GetInputPort("axis_flow"))
    return flow


def add_viewers(builder: DiagramBuilder, scene_graph: SceneGraph, meshcat: Meshcat | None, noisy_camera: NoisyCamera,
                camera_config: CameraConfig, video_path=None):
    """Meshcat (illustration geometry) when `meshcat` is given, and an MP4 of the camera stream when
    `video_path` is. Returns (MeshcatVisualizer or None, VideoRecorder or None)."""
    visualizer = video = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                                    MeshcatVisualizerParams(role=Role.kIllustration))
    if video_path is not None:
        video = builder.AddSystem(VideoRecorder(video_path, camera_config.period_s, camera_config.width,
                                                camera_config.height))
        builder.Connect(noisy_camera.get_output_port(), video.get_input_port())
    return visualizer, video


def delayed(builder: DiagramBuilder, port, period_s: float, frames: int, model_value):
    """`port`'s value acquired `frames` samples of `period_s` ago (`MeasurementLatency`); `model_value`
    (the port's type: an invalid detection, NaN ranges) before the first one is due."""
    delay = builder.AddSystem(MeasurementLatency(period_s, frames, model_value))
    builder.Connect(port, delay.get_input_port())
    return delay.get_output_port()


def add_stewart_scene(builder: DiagramBuilder, config: StewartSceneConfig, meshcat: Meshcat | None = None,
                      video_path=None) -> StewartSceneHandles:
    """Adds the scene's systems to `builder` and returns their handles."""
    config.validate()
    scene_graph = builder.AddSystem(SceneGraph())
    add_renderer(scene_graph)

    platform = builder.AddSystem(StewartPlatform(config.platform, scene_graph, config.seed))
    builder.Connect(platform.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(platform.source_id))

    airframe = builder.AddSystem(AirframeGeometry(config.uav, scene_graph))
    body = builder.AddSystem(PrescribedPose(hover_pose(config, platform)))
    builder.Connect(body.GetOutputPort("X_WB"), airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))

    X_BC = config.camera.X_BC
    camera, noisy_camera, tof = add_uav_sensors(builder, scene_graph, airframe.body_frame_id, config.camera,
                                                config.tof, config.seed)

    if config.camera.exposure_s > 0:
        add_axis_flow(builder, X_BC, (body.GetOutputPort("X_WB"), body.GetOutputPort("V_WB")), platform, noisy_camera)

    imu = builder.AddSystem(Imu(config.imu, config.seed))
    for name in ("X_WB", "V_WB", "A_WB"):
        builder.Connect(body.GetOutputPort(name), imu.GetInputPort(name))

    detector = builder.AddSystem(TagDetectorSystem(config.platform.tag_id, config.camera.width, config.camera.height,
                                                   (config.camera.K_estimated, config.camera.D_estimated)))
    builder.Connect(noisy_camera.get_output_port(), detector.get_input_port())

    truth = builder.AddSystem(RelativePose(X_BC))
    builder.Connect(body.GetOutputPort("X_WB"), truth.GetInputPort("X_WB"))
    builder.Connect(platform.GetOutputPort("X_WP"), truth.GetInputPort("X_WP"))

    period = config.camera.period_s
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in {
        "X_CP": truth.GetOutputPort("X_CP_vector"),
        "ranges": tof.GetOutputPort("ranges"),
        "ranges_valid": tof.GetOutputPort("ranges_valid"),
        "true_ranges": tof.GetOutputPort("true_ranges"),
        "tag_corners": detector.GetOutputPort("tag_corners"),
        "leg_lengths": platform.GetOutputPort("leg_lengths"),
        "stroke_exceeded": platform.GetOutputPort("stroke_exceeded"),
    }.items()}
    loggers["imu"] = LogVectorOutput(imu.get_output_port(), builder, config.imu.period_s)

    detection, ranges = detector.GetOutputPort("tag_detection"), tof.GetOutputPort("ranges")
    if config.estimate_latency_frames:
        frames = config.estimate_latency_frames
        detection = delayed(builder, detection, period, frames, TagDetection())
        ranges = delayed(builder, ranges, period, frames, np.full(4, np.nan))
    estimators = {}
    for name in config.estimators:
        if name == "atda":
            estimator = builder.AddSystem(AtdaEstimator(config.camera.K_estimated, config.platform.tag_size_m,
                                                        config.camera.period_s))
        else:
            estimator = builder.AddSystem(CrhfEstimator(
                config.crhf, sensor_positions_C(config.tof.arm_m, config.tof.angle_deg), config.platform.tag_size_m,
                config.camera.period_s, config.camera))
            builder.Connect(ranges, estimator.GetInputPort("ranges"))
        estimators[name] = estimator
        builder.Connect(detection, estimator.GetInputPort("tag_detection"))
        to_vector = builder.AddSystem(PoseEstimateToVector())
        builder.Connect(estimator.GetOutputPort("X_CT_estimate"), to_vector.get_input_port())
        loggers[f"estimate_{name}"] = LogVectorOutput(to_vector.get_output_port(), builder, period)

    visualizer, video = add_viewers(builder, scene_graph, meshcat, noisy_camera, config.camera, video_path)
    return StewartSceneHandles(scene_graph, platform, airframe, body, camera, noisy_camera, tof, imu, detector,
                               truth, loggers, X_BC, estimators, visualizer, video)


def build_stewart_scene(config: StewartSceneConfig, meshcat: Meshcat | None = None,
                        video_path=None) -> tuple[Diagram, StewartSceneHandles]:
    """Builds the scene as a Diagram; returns it with the handles of its systems."""
    builder = DiagramBuilder()
    handles = add_stewart_scene(builder, config, meshcat, video_path)
    diagram = builder.Build()
    diagram.set_name("stewart_scene")
    return diagram, handles
