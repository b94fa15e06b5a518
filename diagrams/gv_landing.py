"""The ground-vehicle scenarios' diagram (gv-landing, gv-marker-ekf, marker-landing): seed 002's
quadrotor and bicycle, seed 003's two-stage PID and landing procedure, seed 002's marker filters,
and whatever `perception.source` names steering through the seam.

    diagram, handles = build_gv_landing(config)
    run = simulate(diagram, config.duration_s, initialize=handles.initialize)     # diagrams/simulate.py

All in World W (z up):

    vehicle --state--> true relative state (systems/perception/truth.py) --> monitor, logs
    camera (estimation.source detector: render, ArUco, PnP) or synthetic source [--> faults] --> latency
        --> marker filters (estimation.filters, and the steering one) --> logs
    perception source (diagrams/perception_sources.py) --seam--> tracking PID (pid.rate_hz)
        --> landing supervisor (50 Hz) --command--> flight controller (200 Hz) --> quadrotor
    wind (`wind`, unless calm: mean, Dryden turbulence, gusts) --air velocity--> quadrotor's rotor drag
    navigation (`navigation.source` gnss_ins: the truth plus its errors) --> controller, supervisor, filters
    vehicle broadcast (`rendezvous.source` broadcast: its GNSS by radio) [--> search spiral] --coarse seam--> PID where unseen

Both vehicles integrate their equations over each 5 ms controller period in C++
(`integration.discrete`), so Python runs only at the rates the systems declare.
"""

from dataclasses import dataclass, field

import numpy as np
from matplotlib.colors import to_rgba
from pydrake.geometry import Box, Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Rgba, Role, SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.framework import Diagram, DiagramBuilder, OutputPort
from pydrake.systems.primitives import (
    ConstantVectorSource,
    Demultiplexer,
    LogVectorOutput,
    TrajectorySource,
    VectorLogSink,
)
from pydrake.systems.sensors import RgbdSensor

from diagrams.flight_stack import add_flight_stack
from diagrams.gv_landing_config import GvLandingConfig
from diagrams.marker_plots import style
from diagrams.perception_sources import PerceptionInputs, SeamPorts, perception_source
from systems.config import ConfigError
from systems.control.flight_controller import FlightController, SymbolicFlightController
from systems.control.landing import LandingSupervisor
from systems.control.monitor import LandingMonitor
from systems.control.pid import TrackingPid
from systems.environment.bridge import register_bridge
from systems.environment.wind_system import WindSystem
from systems.estimators.estimate import PoseEstimateToVector
from systems.estimators.marker_ekf import FILTERS, MarkerFilterSystem
from systems.estimators.marker_ekf.engine import ESTIMATE_VECTOR_SIZE
from systems.geometry import register_visual
from systems.perception.latency import MeasurementLatency
from systems.perception.marker_detector import MarkerDetectorSystem
from systems.perception.marker_faults import MarkerFaults
from systems.perception.markers import MarkerMeasurementsToVector
from systems.perception.rendezvous import VehicleBroadcast
from systems.perception.rendezvous_search import RendezvousSearch
from systems.perception.synthetic_markers import SyntheticMarkerSource
from systems.perception.truth import PadPose, PadVelocity, RelativeStateTruth
from systems.sensors.camera import NoisyCamera, add_camera, add_renderer
from systems.sensors.ground_truth import AxisFlow
from systems.sensors.navigation import NavigationSystem
from systems.vehicles.airframe import AirframeGeometry
from systems.vehicles.ground_vehicle import GroundVehicle, GroundVehicleConfig
from systems.vehicles.ground_vehicle_geometry import GroundVehicleGeometry, PlatformConfig
from systems.vehicles.paths import make_path
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, Quadrotor, hover_state
from systems.vehicles.traffic import Traffic, draw_distractors
from systems.viewers import MeshcatArrow, MeshcatTrail, VideoRecorder

# Logged at the supervisor's rate (the sample before the first LANDED holds what the supervisor saw
# at touchdown): the states, the seam (what steers), the truth's seam, the supervisor and the PID;
# and `wind` (the air's velocity in W) where it blows.
LOG_NAMES = ("quadrotor_state", "vehicle_state", "relative_state", "true_relative_state", "mode", "command",
             "tracking_velocity", "vehicle_speed")


@dataclass
class Measurements:
    """The camera and the marker stream of `estimation.source` (what is None is not there): `acquired`
    (with the `faults` in it) and `delayed` (after the latency) MarkerMeasurement lists; with the camera (config.camera()), the
    `camera` (RgbdSensor), its noisy `color_image` port, the `video` recorder, and with
    estimation.source detector the `detector`."""

    acquired: OutputPort | None = None
    delayed: OutputPort | None = None
    camera: RgbdSensor | None = None
    color_image: OutputPort | None = None
    detector: MarkerDetectorSystem | None = None
    video: VideoRecorder | None = None


@dataclass
class GvLandingHandles:
    """The systems and ports of a built gv diagram that callers use. `loggers` sample at the
    supervisor's rate (LOG_NAMES, and `steering_estimate` when an estimator steers); with a marker
    stream, `sample_loggers` sample every filter step: `measurements` (the stream as acquired, as
    markers.measurements_vector), `quadrotor_state`, `vehicle_state`, and per filter in `filters`
    `<name>_estimate` (its estimate_vector) and `<name>_p_WM`."""

    config: GvLandingConfig
    quadrotor: Quadrotor  # discretised per controller period with integration.discrete
    wind: WindSystem | None  # None in calm air
    vehicle: GroundVehicle  # likewise
    truth: RelativeStateTruth
    perception: SeamPorts  # what steers
    pid: TrackingPid
    supervisor: LandingSupervisor
    controller: SymbolicFlightController | FlightController
    monitor: LandingMonitor
    scene_graph: SceneGraph
    airframe: AirframeGeometry
    vehicle_geometry: GroundVehicleGeometry
    loggers: dict[str, VectorLogSink]
    measurements: Measurements = field(default_factory=Measurements)
    filters: dict[str, MarkerFilterSystem] = field(default_factory=dict)
    sample_loggers: dict[str, VectorLogSink] = field(default_factory=dict)
    meshcat_visualizer: MeshcatVisualizer | None = None

    @property
    def video(self) -> VideoRecorder | None:
        return self.measurements.video or self.perception.video

    def initialize(self, root_context) -> None:
        """Sets the initial conditions in a context of the built diagram: the UAV at rest at `start`
        (on the ground, or hovering) with its rotors at hover speed, the vehicle at the start of its path."""
        c = self.config
        self.quadrotor.set_state(root_context,
                                 hover_state(c.quadrotor, [*c.start.xy_m, c.start.height_m],
                                             yaw=np.radians(c.start.yaw_deg)))
        self.vehicle.set_state(root_context, self.vehicle.initial_state())
        self.controller.initialize(root_context)


def add_ground(scene_graph: SceneGraph, lo: np.ndarray, hi: np.ndarray) -> None:
    """A ground plane from World x-y `lo` to `hi` [m], its top at z = 0."""
    source_id = scene_graph.RegisterSource("ground")
    register_visual(scene_graph, source_id, scene_graph.world_frame_id(),
                    RigidTransform([*(lo + hi) / 2, -0.05]), Box(*(hi - lo), 0.1), "ground", (0.8, 0.82, 0.76, 1.0))


def add_ground_and_path(scene_graph: SceneGraph, vehicle: GroundVehicleConfig, meshcat: Meshcat | None,
                        duration_s: float = 0.0,
                        lead: tuple[float, float] = (1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A ground plane under the path, as far as the vehicle (and what drives ahead of it, `lead`) gets in
    `duration_s` [s] (GroundVehicleConfig.ground_extent); the path drawn in Meshcat as far. Returns the ground's
    (lower, upper) World x, y [m]."""
    ground_xy = vehicle.ground_extent(duration_s, lead=lead)
    add_ground(scene_graph, *ground_xy)
    if meshcat is not None:
        xy = make_path(vehicle.path_config()).polyline(vehicle.ground_length_m(duration_s, lead))
        meshcat.SetLine("gv_landing/path", np.vstack([xy.T, np.full(len(xy), 0.02)]), 3.0, Rgba(1.0, 0.85, 0.1, 1.0))
        meshcat.SetProperty("/Grid", "visible", False)  # the ground plane is the floor
        # Looking at the start of the path from behind and above the UAV's start.
        meshcat.SetCameraPose(np.array([-14.0, -18.0, 12.0]), np.array([6.0, 2.0, 2.0]))
    return ground_xy


def build_gv_landing(config: GvLandingConfig, meshcat: Meshcat | None = None,
                     video_path=None, duration_s: float = 0.0) -> tuple[Diagram, GvLandingHandles]:
    """Builds the diagram; returns it with the handles of its systems. Simulate it with
    `initialize=handles.initialize` (diagrams/simulate.py). `video_path`: record the camera. `duration_s`: the
    run's length [s], which the ground covers (add_ground_and_path; 0: the first 400 m of an open path)."""
    builder = DiagramBuilder()
    handles = add_gv_landing(builder, config, meshcat, video_path, duration_s)
    diagram = builder.Build()
    diagram.set_name("gv_landing")
    return diagram, handles


def add_pad_axis_flow(builder: DiagramBuilder, X_BC: RigidTransform, body: tuple[OutputPort, OutputPort],
                      vehicle: tuple[OutputPort, OutputPort], vehicle_config: GroundVehicleConfig,
                      platform: PlatformConfig, noisy_camera: NoisyCamera) -> AxisFlow:
    """Feeds the camera's motion blur: the pad's plane crossing the image (`AxisFlow`), from the body's
    (X_WB, V_WB) ports and the vehicle's (state, speed) ports that carry the pad."""
    flow = builder.AddNamedSystem("axis_flow", AxisFlow(X_BC))
    pad_pose = builder.AddNamedSystem("blur_pad_pose", PadPose(platform))
    pad_velocity = builder.AddNamedSystem("blur_pad_velocity", PadVelocity(vehicle_config, platform))
    builder.Connect(vehicle[0], pad_pose.get_input_port())
    builder.Connect(vehicle[0], pad_velocity.GetInputPort("vehicle_state"))
    builder.Connect(vehicle[1], pad_velocity.GetInputPort("vehicle_speed"))
    for name, port in (("X_WB", body[0]), ("V_WB", body[1]), ("X_WS", pad_pose.get_output_port()),
                       ("V_WS", pad_velocity.get_output_port())):
        builder.Connect(port, flow.GetInputPort(name))
    builder.Connect(flow.get_output_port(), noisy_camera.GetInputPort("axis_flow"))
    return flow


def _add_measurements(builder: DiagramBuilder, config: GvLandingConfig, scene_graph: SceneGraph, body_frame_id,
                      body: tuple[OutputPort, OutputPort], vehicle: tuple[OutputPort, OutputPort],
                      video_path) -> Measurements:
    """The camera (with its motion blur fed when it has an exposure) and the marker stream. `body`: the
    UAV's true (X_WB, V_WB) ports; `vehicle`: the vehicle's (state, speed) ports."""
    est = config.estimation
    out = Measurements()
    X_WB, vehicle_state = body[0], vehicle[0]
    camera_config = config.camera()
    if camera_config is not None:
        add_renderer(scene_graph)
        out.camera, noisy_camera = add_camera(builder, scene_graph, body_frame_id, camera_config, config.seed)
        if camera_config.exposure_s > 0:
            add_pad_axis_flow(builder, camera_config.X_BC, body, vehicle, config.vehicle, config.platform,
                              noisy_camera)
        out.color_image = noisy_camera.get_output_port()
        if video_path is not None:
            out.video = builder.AddNamedSystem("video", VideoRecorder(video_path, camera_config.period_s,
                                                                      camera_config.width, camera_config.height))
            builder.Connect(out.color_image, out.video.get_input_port())
    if est.source == "none":
        return out
    if est.source == "synthetic":
        pad = builder.AddNamedSystem("pad_pose", PadPose(config.platform))
        source = builder.AddNamedSystem("marker_source", SyntheticMarkerSource(
            config.platform.markers, est.X_BC, est.ekf.period_s, config.seed, est.sigma_p_m, est.sigma_deg))
        builder.Connect(vehicle_state, pad.get_input_port())
        builder.Connect(X_WB, source.GetInputPort("X_WB"))
        builder.Connect(pad.get_output_port(), source.GetInputPort("X_WP"))
        out.acquired = source.get_output_port()
    else:
        out.detector = builder.AddNamedSystem("marker_detector", MarkerDetectorSystem(
            camera_config.K_estimated, config.platform.markers, camera_config.width, camera_config.height,
            camera_config.D_estimated))
        builder.Connect(out.color_image, out.detector.get_input_port())
        out.acquired = out.detector.get_output_port()
    if config.faults.active:  # what the camera or the source delivers, with the faults in it
        faults = builder.AddNamedSystem("marker_faults", MarkerFaults(config.faults, est.ekf.period_s, config.seed))
        builder.Connect(out.acquired, faults.get_input_port())
        out.acquired = faults.get_output_port()
    latency = builder.AddNamedSystem("measurement_latency", MeasurementLatency(est.ekf.period_s, est.latency_periods))
    builder.Connect(out.acquired, latency.get_input_port())
    out.delayed = latency.get_output_port()
    return out


def add_gv_landing(builder: DiagramBuilder, config: GvLandingConfig, meshcat: Meshcat | None = None,
                   video_path=None, duration_s: float = 0.0) -> GvLandingHandles:
    """Adds the gv systems to `builder`; returns their handles (`duration_s`: build_gv_landing's)."""
    config.validate()
    if video_path is not None and not config.has_video:
        raise ConfigError("a video records the camera, and this scene has none (estimation.source detector, "
                          "perception.source federated or hybrid render one)")
    discrete = config.integration.discrete
    period, integration = (config.period_s, config.integration.simulator_config()) if discrete else (None, None)
    wind = None if config.wind.is_calm else builder.AddNamedSystem("wind", WindSystem(config.wind, config.seed))
    quad = builder.AddNamedSystem("quadrotor", Quadrotor(config.quadrotor, period, integration, wind=wind is not None))
    vehicle = builder.AddNamedSystem("ground_vehicle", GroundVehicle(config.vehicle, period, integration))
    # The vehicle's speed and its rate: [v (m/s), dv/dt (m/s^2)].
    profile = config.vehicle.speed_profile()
    speed = builder.AddNamedSystem("vehicle_speed", ConstantVectorSource([config.vehicle.speed, 0.0])
                                   if profile is None else TrajectorySource(profile, 1, True))
    speed_split = builder.AddNamedSystem("vehicle_speed_split", Demultiplexer([1, 1]))
    builder.Connect(speed.get_output_port(), speed_split.get_input_port())
    builder.Connect(speed_split.get_output_port(0), vehicle.GetInputPort("speed"))
    quad_state, vehicle_state, X_WB = (quad.GetOutputPort("state"), vehicle.GetOutputPort("state"),
                                       quad.GetOutputPort("X_WB"))
    if wind is not None:
        builder.Connect(quad_state, wind.get_input_port())
        builder.Connect(wind.get_output_port(), quad.GetInputPort("wind_velocity_W"))
    # What the UAV believes of itself (the controller, the supervisor, the estimators placing the pad
    # in W): the truth, or its navigation's; the referee, the camera and the metrics keep the truth.
    nav_state, nav_X_WB = quad_state, X_WB
    if config.navigation.source != "truth":
        navigation = builder.AddNamedSystem("navigation", NavigationSystem(config.navigation, config.seed))
        builder.Connect(quad_state, navigation.get_input_port())
        nav_state, nav_X_WB = navigation.GetOutputPort("state"), navigation.GetOutputPort("X_WB")

    truth = builder.AddNamedSystem("true_relative_state", RelativeStateTruth(
        config.vehicle, config.platform, config.perception.field_of_view_deg, config.perception.max_range_m))
    builder.Connect(X_WB, truth.GetInputPort("X_WB"))
    builder.Connect(vehicle_state, truth.GetInputPort("vehicle_state"))
    builder.Connect(speed.get_output_port(), truth.GetInputPort("vehicle_speed"))
    builder.Connect(vehicle.GetOutputPort("steering_command"), truth.GetInputPort("vehicle_steering_command"))

    # Scene geometry: drawn by Meshcat, rendered by the camera (free when neither is there).
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    ground_xy = add_ground_and_path(scene_graph, config.vehicle, meshcat, duration_s, config.distractors.lead())
    airframe = builder.AddNamedSystem("airframe", AirframeGeometry(config.uav, scene_graph))
    builder.Connect(X_WB, airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))
    vehicle_geometry = builder.AddNamedSystem("vehicle_geometry", GroundVehicleGeometry(
        config.vehicle.wheelbase_m, config.platform, scene_graph))
    builder.Connect(vehicle_state, vehicle_geometry.get_input_port())
    builder.Connect(vehicle_geometry.get_output_port(), scene_graph.get_source_pose_port(vehicle_geometry.source_id))
    if config.bridge.enabled:
        register_bridge(scene_graph, vehicle.path, config.bridge)
    if config.distractors.count:
        traffic = builder.AddNamedSystem("traffic", Traffic(
            scene_graph, vehicle.path, config.vehicle, draw_distractors(config.distractors, config.seed)))
        builder.Connect(traffic.get_output_port(), scene_graph.get_source_pose_port(traffic.source_id))

    measurements = _add_measurements(builder, config, scene_graph, airframe.body_frame_id,
                                     (X_WB, quad.GetOutputPort("V_WB")), (vehicle_state, speed.get_output_port()),
                                     video_path)
    filters = {}
    for name in config.filter_names:
        est = config.estimation
        filters[name] = builder.AddNamedSystem(name, MarkerFilterSystem(
            FILTERS[name](config.platform.markers, est.X_BC, est.ekf)))
        builder.Connect(measurements.delayed, filters[name].GetInputPort("marker_measurements"))
        builder.Connect(nav_X_WB, filters[name].GetInputPort("X_WB"))

    perception = perception_source(config.perception.source).add(
        builder, PerceptionInputs(config, nav_X_WB, quad.GetOutputPort("V_WB"), quad.GetOutputPort("A_WB"), quad_state,
                                  vehicle_state, truth.get_output_port(), measurements.delayed,
                                  measurements.color_image, filters, scene_graph, airframe.body_frame_id,
                                  video_path if measurements.video is None else None, ground_xy))
    rendezvous = None
    if config.rendezvous.source == "broadcast":  # the vehicle's navigation by radio: a coarse target
        broadcast = builder.AddNamedSystem("vehicle_broadcast", VehicleBroadcast(config.rendezvous, config.seed))
        builder.Connect(truth.get_output_port(), broadcast.GetInputPort("true_relative_state"))
        builder.Connect(quad_state, broadcast.GetInputPort("quadrotor_state"))
        builder.Connect(nav_X_WB, broadcast.GetInputPort("X_WB"))
        rendezvous = broadcast.get_output_port()
        r = config.rendezvous
        if r.search_spacing_m > 0:  # swept about the broadcast while vision is lost
            search = builder.AddNamedSystem("rendezvous_search", RendezvousSearch(
                r.search_spacing_m, r.search_radius_m, r.search_speed_m_s, r.search_after_s))
            builder.Connect(rendezvous, search.GetInputPort("rendezvous"))
            builder.Connect(perception.relative_state, search.GetInputPort("vision"))
            builder.Connect(nav_X_WB, search.GetInputPort("X_WB"))
            rendezvous = search.get_output_port()
    stack = add_flight_stack(builder, config, quad, nav_state, perception.relative_state, vehicle_state,
                             truth.get_output_port(), config.platform, rendezvous)
    pid, supervisor = stack.pid, stack.supervisor

    period = 1.0 / config.landing.rate_hz
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in zip(LOG_NAMES, (
        quad_state, vehicle_state, perception.relative_state, truth.get_output_port(),
        supervisor.GetOutputPort("mode"), supervisor.GetOutputPort("command"), pid.GetOutputPort("velocity_command"),
        speed.get_output_port()))}
    if wind is not None:
        loggers["wind"] = LogVectorOutput(wind.get_output_port(), builder, period)
    if perception.X_WP_estimate is not None:
        to_vector = builder.AddNamedSystem("steering_estimate_vector", PoseEstimateToVector())
        builder.Connect(perception.X_WP_estimate, to_vector.get_input_port())
        loggers["steering_estimate"] = LogVectorOutput(to_vector.get_output_port(), builder, period)
    sample_loggers = {}
    if measurements.acquired is not None:  # the stream as acquired, the truth and every filter's estimate
        stream = builder.AddNamedSystem("stream_vector", MarkerMeasurementsToVector(config.platform.markers))
        builder.Connect(measurements.acquired, stream.get_input_port())
        ports = {"measurements": stream.get_output_port(), "quadrotor_state": quad_state,
                 "vehicle_state": vehicle_state}
        for name, f in filters.items():
            ports[f"{name}_estimate"] = f.GetOutputPort("estimate_vector")
            ports[f"{name}_p_WM"] = f.GetOutputPort("p_WM_estimate")
        sample_loggers = {name: LogVectorOutput(port, builder, config.estimation.ekf.period_s)
                          for name, port in ports.items()}

    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                                    MeshcatVisualizerParams(role=Role.kIllustration))
        trail = builder.AddNamedSystem("uav_trail", MeshcatTrail(meshcat, "gv_landing/uav_trail", STATE_SIZE, P_WB))
        builder.Connect(quad_state, trail.get_input_port())
        if wind is not None:  # the air's velocity at the UAV, 0.4 m per m/s
            arrow = builder.AddNamedSystem("wind_arrow", MeshcatArrow(meshcat, "gv_landing/wind", STATE_SIZE, P_WB))
            builder.Connect(quad_state, arrow.GetInputPort("position"))
            builder.Connect(wind.get_output_port(), arrow.GetInputPort("vector"))
        # Each estimator's pad path (valid estimates) beside it.
        estimates = {name: (f.GetOutputPort("estimate_vector"), ESTIMATE_VECTOR_SIZE) for name, f in filters.items()}
        if perception.X_WP_estimate is not None and perception.filter_name is None:
            estimates[config.perception.source] = (to_vector.get_output_port(), 8)
        for name, (port, size) in estimates.items():
            trail = builder.AddNamedSystem(f"{name}_trail", MeshcatTrail(
                meshcat, f"gv_landing/{name}_pad_path", size, slice(1, 4), to_rgba(style(name)[0]), valid_index=0))
            builder.Connect(port, trail.get_input_port())

    return GvLandingHandles(config, quad, wind, vehicle, truth, perception, pid, supervisor, stack.controller,
                            stack.monitor, scene_graph, airframe, vehicle_geometry, loggers, measurements, filters,
                            sample_loggers, visualizer)
