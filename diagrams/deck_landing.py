"""deck-landing's diagram: seed 002's quadrotor, flown by our flight controller and seed 003's PID and
supervisor, lands on seed 000's moving Stewart deck steered by CRHF's (or ATDA's) estimate.

    diagram, handles = build_deck_landing(config)
    run = simulate(diagram, duration_s, initialize=handles.initialize)     # diagrams/simulate.py

All in World W (z up), the deck's base at the origin:

    Stewart deck --pad motion--> true relative state (systems/perception/truth.py) --> monitor, logs
    camera (render, pixel noise) --> AprilTag detector --(estimate_latency_frames late)--> ATDA, CRHF (with the
        four ToF ranges) --X_CT--> deck tracker (systems/estimators/deck_tracker.py: X_WP through the UAV's pose
        at the frame's exposure, predicted to now, coasting) --> seam
    deck motion (the tracker's, or the truth's) + seam height --> landing window --> supervisor
        (with `window.prediction: autoregressive`, through the deck predictor: systems/estimators/deck_predictor.py)
    seam --> tracking PID --> landing supervisor --> flight controller --> quadrotor   (diagrams/flight_stack.py)

Both estimators run on the same stream whatever steers (`perception.source`), and are scored against
the truth's X_CT at the camera rate as in the Stewart scenes.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, SceneGraph
from pydrake.systems.framework import Diagram, DiagramBuilder, OutputPort
from pydrake.systems.primitives import Demultiplexer, LogVectorOutput, VectorLogSink

from diagrams.deck_landing_config import DeckLandingConfig
from diagrams.flight_stack import FlightStack, add_flight_stack
from diagrams.perception_sources import PerceptionInputs, perception_source
from diagrams.stewart_scene import add_axis_flow, add_uav_sensors, add_viewers, delayed
from systems.config import ConfigError
from systems.control.landing_window import LandingWindow
from systems.estimators.atda import AtdaEstimator
from systems.estimators.crhf import CrhfEstimator
from systems.estimators.deck_predictor import DeckPredictor
from systems.estimators.estimate import PoseEstimateToVector
from systems.perception.apriltag import TagDetection, TagDetectorSystem
from systems.perception.truth import PadMotionTruth
from systems.platforms.stewart import StewartPlatform
from systems.sensors.camera import add_renderer
from systems.sensors.ground_truth import CameraVelocity, RelativePose
from systems.sensors.tof import TofSensors, sensor_positions_C
from systems.vehicles.airframe import AirframeGeometry
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, V_WB, Quadrotor, hover_state
from systems.viewers import MeshcatTrail, VideoRecorder

# Logged at the supervisor's rate: the UAV, the deck (as the monitor's carrier, and its true motion), what
# steered and the truth's seam, the supervisor, and the landing window with the deck motion it was given.
SUPERVISOR_LOGS = ("quadrotor_state", "carrier_state", "true_deck_motion", "relative_state", "true_relative_state",
                   "mode", "command", "landing_window", "deck_motion")


@dataclass
class DeckLandingHandles:
    """The systems and ports of a built deck-landing diagram. `loggers` sample at the supervisor's rate
    (SUPERVISOR_LOGS); `frame_loggers` at the camera's: `X_CP` (the truth), `ranges`, `tag_corners` and
    per estimator `estimate_<name>` (PoseEstimate vectors of X_CT)."""

    config: DeckLandingConfig
    quadrotor: Quadrotor
    platform: StewartPlatform
    stack: FlightStack
    estimators: dict[str, object]  # "atda", "crhf" -> systems with an X_CT_estimate output
    tof: TofSensors
    scene_graph: SceneGraph
    loggers: dict[str, VectorLogSink]
    frame_loggers: dict[str, VectorLogSink]
    meshcat_visualizer: MeshcatVisualizer | None = None
    video: VideoRecorder | None = None

    def initialize(self, root_context) -> None:
        """The UAV hovering at `start` (World x-y, height above the ground), rotors at hover speed."""
        c = self.config
        self.quadrotor.set_state(root_context, hover_state(c.quadrotor, [*c.start.xy_m, c.start.height_m],
                                                           yaw=np.radians(c.start.yaw_deg)))
        self.stack.controller.initialize(root_context)


def _add_estimators(builder: DiagramBuilder, config: DeckLandingConfig, color_image: OutputPort,
                    tof: TofSensors, camera_velocity: CameraVelocity) -> tuple[TagDetectorSystem, dict]:
    """The tag detector, ATDA and CRHF on the camera stream, `estimate_latency_frames` late; CRHF's range
    track told the camera's own spatial velocity at the frame's exposure (from the UAV's state, here the truth)."""
    detector = builder.AddNamedSystem("tag_detector", TagDetectorSystem(
        config.platform.tag_id, config.camera.width, config.camera.height,
        (config.camera.K_estimated, config.camera.D_estimated)))
    builder.Connect(color_image, detector.get_input_port())
    detection, ranges, V_WC_C = (detector.GetOutputPort("tag_detection"), tof.GetOutputPort("ranges"),
                                 camera_velocity.GetOutputPort("V_WC_C"))
    if frames := config.estimate_latency_frames:
        period = config.camera.period_s
        detection = delayed(builder, detection, period, frames, TagDetection())
        ranges = delayed(builder, ranges, period, frames, np.full(4, np.nan))
        V_WC_C = delayed(builder, V_WC_C, period, frames, np.zeros(6))
    atda = builder.AddNamedSystem("atda", AtdaEstimator(config.camera.K_estimated, config.platform.tag_size_m,
                                                        config.camera.period_s))
    crhf = builder.AddNamedSystem("crhf", CrhfEstimator(
        config.crhf, sensor_positions_C(config.tof.arm_m, config.tof.angle_deg), config.platform.tag_size_m,
        config.camera.period_s, config.camera))
    builder.Connect(ranges, crhf.GetInputPort("ranges"))
    builder.Connect(V_WC_C, crhf.GetInputPort("V_WC_C"))
    for estimator in (atda, crhf):
        builder.Connect(detection, estimator.GetInputPort("tag_detection"))
    return detector, {"atda": atda, "crhf": crhf}


def add_deck_landing(builder: DiagramBuilder, config: DeckLandingConfig, meshcat: Meshcat | None = None,
                     video_path=None) -> DeckLandingHandles:
    """Adds the deck-landing systems to `builder`; returns their handles."""
    config.validate()
    quad = builder.AddNamedSystem("quadrotor", Quadrotor(config.quadrotor, config.period_s,
                                                         config.integration.simulator_config()))
    quad_state, X_WB = quad.GetOutputPort("state"), quad.GetOutputPort("X_WB")
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    add_renderer(scene_graph)
    platform = builder.AddNamedSystem("stewart_platform", StewartPlatform(config.deck(), scene_graph, config.seed))
    builder.Connect(platform.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(platform.source_id))
    airframe = builder.AddNamedSystem("airframe", AirframeGeometry(config.uav, scene_graph))
    builder.Connect(X_WB, airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))
    _, noisy_camera, tof = add_uav_sensors(builder, scene_graph, airframe.body_frame_id, config.camera, config.tof,
                                           config.seed)
    camera_velocity = builder.AddNamedSystem("camera_velocity", CameraVelocity(config.X_BC))
    builder.Connect(quad.GetOutputPort("X_WB"), camera_velocity.GetInputPort("X_WB"))
    builder.Connect(quad.GetOutputPort("V_WB"), camera_velocity.GetInputPort("V_WB"))
    if config.camera.exposure_s > 0:
        add_axis_flow(builder, config.X_BC, (X_WB, quad.GetOutputPort("V_WB")), platform, noisy_camera)
    color_image = noisy_camera.get_output_port()
    detector, estimators = _add_estimators(builder, config, color_image, tof, camera_velocity)

    truth = builder.AddNamedSystem("true_relative_state", PadMotionTruth(config.perception.field_of_view_deg,
                                                                        config.perception.max_range_m))
    builder.Connect(X_WB, truth.GetInputPort("X_WB"))
    builder.Connect(platform.GetOutputPort("pad_motion"), truth.GetInputPort("pad_motion"))

    # What steers: diagrams/perception_sources.py's (the truth, or ATDA's or CRHF's estimate through the deck tracker).
    tag_estimates = {name: estimator.GetOutputPort("X_CT_estimate") for name, estimator in estimators.items()}
    perception = perception_source(config.perception.source, scene="deck").add(builder, PerceptionInputs(
        config, X_WB, quad.GetOutputPort("V_WB"), quad.GetOutputPort("A_WB"), quad_state,
        platform.GetOutputPort("carrier_state"), truth.get_output_port(), None, color_image, {}, scene_graph,
        airframe.body_frame_id, tag_estimates=tag_estimates, X_TP=platform.X_PT.inverse(),
        true_deck_motion=platform.GetOutputPort("deck_motion")))
    relative_state, deck_motion = perception.relative_state, perception.deck_motion
    if deck_motion is None:  # the landing window must not read the truth for a source that is not the truth
        raise ConfigError(f"perception.source '{config.perception.source}' gives no deck_motion (SeamPorts."
                          "deck_motion), which deck-landing's landing window reads")

    stack = add_flight_stack(builder, config, quad, quad_state, relative_state, platform.GetOutputPort("carrier_state"),
                             truth.get_output_port(), config.carrier())
    window = builder.AddNamedSystem("landing_window", LandingWindow(
        config.window, config.landing.touchdown_height_m, config.landing.landing_speed_m_s,
        1.0 / config.controller.velocity_gain_z))
    vertical = builder.AddNamedSystem("vertical_velocity", Demultiplexer([V_WB.start + 2, 1, STATE_SIZE - V_WB.stop]))
    builder.Connect(quad_state, vertical.get_input_port())
    builder.Connect(vertical.get_output_port(1), window.GetInputPort("vertical_velocity"))
    builder.Connect(deck_motion, window.GetInputPort("deck_motion"))
    if config.window.prediction == "autoregressive":  # else the window predicts at constant rate itself
        predictor = builder.AddNamedSystem("deck_predictor", DeckPredictor(config.window.predictor,
                                                                           config.camera.period_s))
        builder.Connect(deck_motion, predictor.get_input_port())
        builder.Connect(predictor.get_output_port(), window.GetInputPort("deck_prediction"))
    builder.Connect(stack.seam.GetOutputPort("height_above_target"), window.GetInputPort("height_above_target"))
    builder.Connect(window.get_output_port(), stack.supervisor.GetInputPort("landing_window"))

    period = 1.0 / config.landing.rate_hz
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in zip(SUPERVISOR_LOGS, (
        quad_state, platform.GetOutputPort("carrier_state"), platform.GetOutputPort("deck_motion"), relative_state,
        truth.get_output_port(), stack.supervisor.GetOutputPort("mode"), stack.supervisor.GetOutputPort("command"),
        window.get_output_port(), deck_motion))}
    if perception.X_WP_estimate is not None:
        to_vector = builder.AddNamedSystem("steering_estimate_vector", PoseEstimateToVector())
        builder.Connect(perception.X_WP_estimate, to_vector.get_input_port())
        loggers["steering_estimate"] = LogVectorOutput(to_vector.get_output_port(), builder, period)
    camera_truth = builder.AddNamedSystem("camera_truth", RelativePose(config.X_BC))
    builder.Connect(X_WB, camera_truth.GetInputPort("X_WB"))
    builder.Connect(platform.GetOutputPort("X_WP"), camera_truth.GetInputPort("X_WP"))
    frame_ports = {"X_CP": camera_truth.GetOutputPort("X_CP_vector"), "ranges": tof.GetOutputPort("ranges"),
                   "tag_corners": detector.GetOutputPort("tag_corners")}
    for name, estimator in estimators.items():
        to_vector = builder.AddNamedSystem(f"{name}_vector", PoseEstimateToVector())
        builder.Connect(estimator.GetOutputPort("X_CT_estimate"), to_vector.get_input_port())
        frame_ports[f"estimate_{name}"] = to_vector.get_output_port()
    frame_loggers = {name: LogVectorOutput(port, builder, config.camera.period_s) for name, port in frame_ports.items()}

    visualizer, video = add_viewers(builder, scene_graph, meshcat, noisy_camera, config.camera, video_path)
    if meshcat is not None:
        trail = builder.AddNamedSystem("uav_trail", MeshcatTrail(meshcat, "deck_landing/uav_trail", STATE_SIZE, P_WB))
        builder.Connect(quad_state, trail.get_input_port())
        meshcat.SetCameraPose(np.array([-3.0, -4.0, 3.5]), np.array([0.0, 0.0, 1.0]))
    return DeckLandingHandles(config, quad, platform, stack, estimators, tof, scene_graph, loggers,
                              frame_loggers, visualizer, video)


def build_deck_landing(config: DeckLandingConfig, meshcat: Meshcat | None = None,
                       video_path=None) -> tuple[Diagram, DeckLandingHandles]:
    """Builds the diagram; returns it with the handles of its systems. Simulate it with
    `initialize=handles.initialize` (diagrams/simulate.py). `video_path`: record the camera."""
    builder = DiagramBuilder()
    handles = add_deck_landing(builder, config, meshcat, video_path)
    diagram = builder.Build()
    diagram.set_name("deck_landing")
    return diagram, handles
