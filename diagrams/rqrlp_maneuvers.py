"""Seed 001's first experiment (Sec. 5.1) as a diagram: the UAV flies scripted manoeuvres (forward,
backward, left, right, up, down, 360 deg spins) over the RQRLP lying on the ground, while the
vision nodes and the federated filter estimate its pose (diagrams/federated_perception.py).

    diagram, handles = build_rqrlp_maneuvers(config)

    manoeuvres (velocity and yaw-rate commands) --> flight controller (200 Hz) --> quadrotor
    quadrotor --X_WB--> camera (seed 001 Table 1) --> approaching, adjustment, touchdown nodes
    quadrotor --X_WB, V_WB, A_WB--> IMU --> federated filter <-- nodes

The airframe is seed 002's quadrotor with the project's flight controller (the paper flew a
hexarotor by hand). The pattern lies on the ground at the origin of World W; nothing steers on the
estimate here: it is scored against the truth.
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, SceneGraph
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, MatrixGain, TrajectorySource
from pydrake.systems.sensors import RgbdSensor
from pydrake.trajectories import PiecewisePolynomial

from diagrams.federated_perception import FederatedPerceptionConfig, FederatedPorts, add_federated_perception
from diagrams.gv_landing import add_ground, add_pad_axis_flow
from diagrams.gv_landing_config import IntegrationConfig, StartConfig, table1_airframe
from diagrams.stewart_scene import add_viewers
from systems.config import require
from systems.control.flight_controller import BACKENDS, COMMAND_SIZE, FlightControllerConfig, make_flight_controller
from systems.sensors.camera import add_camera, add_renderer
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry
from systems.vehicles.ground_vehicle import GroundVehicleConfig
from systems.vehicles.ground_vehicle_geometry import GroundVehicleGeometry, PlatformConfig
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, Quadrotor, QuadrotorParams, hover_state
from systems.viewers import MeshcatTrail, VideoRecorder

RAMP_S = 0.5  # a manoeuvre's velocity command is reached over this time [s]


def _pattern_on_the_ground() -> PlatformConfig:
    """Seed 001's 0.85 m RQRLP on a 1.2 m white pad lying on the ground, its centre at W's origin."""
    return PlatformConfig(carrier="ground", height_m=0.02, pattern="rqrlp", pad_size_m=1.2, pad_offset_m=0.0)


def _paper_manoeuvres() -> list[list[float]]:
    """[duration (s), vx, vy, vz (m/s, World), yaw rate (deg/s)]: hover; forward and back; left and
    right; up and down; two 360 deg spins (Sec. 5.1's "forward, backward, left, right, up and down,
    and several 360 deg spins"), within the view of the pattern from 2.5 m."""
    out = [[3.0, 0, 0, 0, 0]]
    for axis in range(3):
        move = np.zeros(3)
        move[axis] = 0.2
        out += [[2.0, *move, 0], [1.0, 0, 0, 0, 0], [4.0, *-move, 0], [1.0, 0, 0, 0, 0], [2.0, *move, 0],
                [1.0, 0, 0, 0, 0]]
    out += [[8.0, 0, 0, 0, 45.0], [8.0, 0, 0, 0, -45.0], [2.0, 0, 0, 0, 0]]
    return [[float(v) for v in row] for row in out]


@dataclass
class ManeuversConfig:
    seed: int = 0  # of every noise source (IMU, pixels)
    platform: PlatformConfig = field(default_factory=_pattern_on_the_ground)
    quadrotor: QuadrotorParams = field(default_factory=QuadrotorParams)
    controller: FlightControllerConfig = field(default_factory=FlightControllerConfig)
    controller_implementation: str = "symbolic"
    federated: FederatedPerceptionConfig = field(default_factory=FederatedPerceptionConfig)
    start: StartConfig = field(default_factory=lambda: StartConfig(xy_m=[0.0, 0.0], height_m=2.5))
    manoeuvres: list[list[float]] = field(default_factory=_paper_manoeuvres)
    integration: IntegrationConfig = field(default_factory=IntegrationConfig)
    uav: AirframeConfig = field(default_factory=table1_airframe)  # visual only

    def validate(self) -> None:
        for name in ("platform", "quadrotor", "federated", "start", "integration", "uav"):
            getattr(self, name).validate(name)
        self.controller.validate("controller", self.quadrotor)
        require(self.platform.pattern == "rqrlp", "platform.pattern must be rqrlp: the nodes look for seed 001's")
        require(self.controller_implementation in BACKENDS,
                f"controller_implementation '{self.controller_implementation}' is not one of {', '.join(BACKENDS)}")
        require(len(self.manoeuvres) > 0, "manoeuvres needs rows [duration_s > 0, vx, vy, vz, yaw_rate_deg_s]")
        for i, row in enumerate(self.manoeuvres):
            require(len(row) == 5 and np.all(np.isfinite(row)) and row[0] > 0,
                    f"manoeuvres[{i}] is {list(row)}: a row is 5 finite numbers [duration_s > 0, vx, vy, vz "
                    f"(m/s, World), yaw_rate_deg_s]")
        require(self.start.height_m > self.platform.height_m, "start.height_m must be above the pattern")

    @property
    def manoeuvres_s(self) -> float:
        return float(sum(row[0] for row in self.manoeuvres))

    def command_trajectory(self) -> PiecewisePolynomial:
        """[v_WB desired (3, m/s, World), yaw desired (rad)] over time, first-order hold: each
        manoeuvre's velocity reached RAMP_S after it starts, its yaw rate at once (the yaw from
        start.yaw_deg). Its derivative is the feed-forward acceleration."""
        times, values = [0.0], [[0.0, 0.0, 0.0, np.radians(self.start.yaw_deg)]]
        t, yaw = 0.0, np.radians(self.start.yaw_deg)
        for duration, vx, vy, vz, rate_deg_s in self.manoeuvres:
            rate = np.radians(rate_deg_s)
            ramp = min(RAMP_S, duration / 2)
            times += [t + ramp, t + duration]
            values += [[vx, vy, vz, yaw + rate * ramp], [vx, vy, vz, yaw + rate * duration]]
            t, yaw = t + duration, yaw + rate * duration
        return PiecewisePolynomial.FirstOrderHold(times, np.asarray(values).T)


@dataclass
class ManeuversHandles:
    config: ManeuversConfig
    quadrotor: Quadrotor
    perception: FederatedPorts
    camera: RgbdSensor  # the renderer's camera; perception's color_image is its distorted, noisy stream
    truth_logs: dict
    meshcat_visualizer: MeshcatVisualizer | None = None
    video: VideoRecorder | None = None

    def initialize(self, root_context) -> None:
        c = self.config
        self.quadrotor.set_state(root_context, hover_state(c.quadrotor, [*c.start.xy_m, c.start.height_m],
                                                          yaw=np.radians(c.start.yaw_deg)))


def build_rqrlp_maneuvers(config: ManeuversConfig, meshcat: Meshcat | None = None,
                          video_path=None) -> tuple[Diagram, ManeuversHandles]:
    """The diagram and its handles; simulate with `initialize=handles.initialize`."""
    config.validate()
    builder = DiagramBuilder()
    discrete = config.integration.discrete
    period, integration = ((1.0 / config.controller.rate_hz, config.integration.simulator_config()) if discrete
                           else (None, None))
    quad = builder.AddNamedSystem("quadrotor", Quadrotor(config.quadrotor, period, integration))
    controller = builder.AddNamedSystem("flight_controller", make_flight_controller(
        config.quadrotor, config.controller, config.controller_implementation, held=not discrete))
    commands = builder.AddNamedSystem("manoeuvres", TrajectorySource(config.command_trajectory(), 1, True))
    # [v (3), yaw, dv/dt (3), dyaw/dt] -> the command [v_WB desired, yaw, a_WB feed-forward].
    select = builder.AddNamedSystem("command", MatrixGain(np.eye(COMMAND_SIZE, 8)))
    builder.Connect(commands.get_output_port(), select.get_input_port())
    builder.Connect(select.get_output_port(), controller.GetInputPort("command"))
    quad_state, X_WB = quad.GetOutputPort("state"), quad.GetOutputPort("X_WB")
    builder.Connect(quad_state, controller.GetInputPort("state"))
    builder.Connect(controller.GetOutputPort("rotor_speed_commands"), quad.GetInputPort("rotor_speed_commands"))

    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    add_ground(scene_graph, np.array([-15.0, -15.0]), np.array([15.0, 15.0]))
    airframe = builder.AddNamedSystem("airframe", AirframeGeometry(config.uav, scene_graph))
    builder.Connect(X_WB, airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))
    pattern = builder.AddNamedSystem("pattern", GroundVehicleGeometry(1.0, config.platform, scene_graph))
    vehicle_state = builder.AddNamedSystem("pattern_pose", ConstantVectorSource(np.zeros(4))).get_output_port()
    builder.Connect(vehicle_state, pattern.get_input_port())
    builder.Connect(pattern.get_output_port(), scene_graph.get_source_pose_port(pattern.source_id))

    camera_config = config.federated.camera
    add_renderer(scene_graph)
    camera, noisy_camera = add_camera(builder, scene_graph, airframe.body_frame_id, camera_config, config.seed)
    if camera_config.exposure_s > 0:  # the pattern is still: its plane crosses the image as the UAV moves
        still = builder.AddNamedSystem("pattern_speed", ConstantVectorSource(np.zeros(2))).get_output_port()
        add_pad_axis_flow(builder, camera_config.X_BC, (X_WB, quad.GetOutputPort("V_WB")), (vehicle_state, still),
                          GroundVehicleConfig(), config.platform, noisy_camera)
    perception = add_federated_perception(builder, config.federated, config.platform.rqrlp, config.seed,
                                          noisy_camera.get_output_port(), X_WB, quad.GetOutputPort("V_WB"),
                                          quad.GetOutputPort("A_WB"))
    truth_logs = {name: LogVectorOutput(port, builder, camera_config.period_s)
                  for name, port in (("quadrotor_state", quad_state), ("vehicle_state", vehicle_state))}
    visualizer, video = add_viewers(builder, scene_graph, meshcat, noisy_camera, camera_config, video_path)
    if meshcat is not None:
        trail = builder.AddNamedSystem("uav_trail", MeshcatTrail(meshcat, "rqrlp/uav_trail", STATE_SIZE, P_WB))
        builder.Connect(quad_state, trail.get_input_port())
        meshcat.SetCameraPose(np.array([-4.0, -5.0, 4.0]), np.array([0.0, 0.0, 1.0]))
    diagram = builder.Build()
    diagram.set_name("rqrlp_maneuvers")
    return diagram, ManeuversHandles(config, quad, perception, camera, truth_logs, visualizer, video)
