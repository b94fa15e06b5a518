r"""Landing on a moving ground vehicle (issue 4): seed 002's quadrotor and bicycle models, seed 003's
two-stage PID and landing procedure, with perfect perception.

    from diagrams.gv_landing import GvLandingConfig, build_gv_landing
    diagram, handles = build_gv_landing(GvLandingConfig())
    simulator = Simulator(diagram)
    handles.initialize(simulator.get_mutable_context())   # UAV on the ground, vehicle on its path

The closed loop, all in World W (z up):

    ground vehicle (bicycle, path follower) --state, speed--> perception --> tracking PID (4 Hz)
    quadrotor --state------------------------------------------^        \--> landing supervisor (50 Hz)
    landing supervisor --command [v_WB_desired, yaw, a_WB_feed_forward]--> flight controller (200 Hz)
    flight controller --rotor speed commands--> quadrotor

**The perception seam.** `PerfectPerception` turns the true states into what the controller
needs (the layout RELATIVE_STATE: pad position relative to the UAV in W and in B, pad velocity,
height above the pad, a valid flag, pad acceleration); the vision estimators of later issues replace it with a
system that has the same output ports. "Valid" is the pad inside the downward camera's cone
(seed 003's 150 deg fisheye) and range, so a UAV that strays loses the target as a real one would.

**Speed** (no cameras here; benchmarks/landing_sweep.py measures it). Three things keep Python out
of the per-step path:
1. Both vehicles are built with `time_period` = the 5 ms controller period and integrate their
   equations over it in C++ (IntegrationConfig): with no continuous state in the diagram the simulator
   never evaluates whole-diagram derivatives, each of which would call into every Python
   LeafSystem (~4.7 us apiece, ~10 of them, several evaluations per step).
2. The flight controller is systems/control/flight_controller.py's C++ backend
   (`SymbolicFlightController`); `controller_implementation: python` selects its Python backend
   (`FlightController`, the same law), which runs as fast (~15 us a sample either way).
3. `gv_landing_run.simulate_flight` freezes the garbage collector's view of the objects from imports and the
   build (gc.freeze), which otherwise costs ~20 % of the run.
Python remains at the rates the systems declare: the supervisor (50 Hz), the perception (pulled at
50 Hz), the path follower (20 Hz), the monitor (10 Hz) and the PID (4 Hz).

**Ending a run.** There is no ground contact: `LandingMonitor` ends the simulation (an event
returning EventStatus.ReachedTermination, whose message says why) when the supervisor reports
LANDED, the UAV hits the ground or the vehicle, the state diverges or turns non-finite, or the
target stays unseen for `termination.lost_timeout_s`.
"""

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    Box, Cylinder, FramePoseVector, GeometryFrame, Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Mesh, Rgba,
    Role, SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import GetIntegrationSchemes, SimulatorConfig
from pydrake.systems.framework import Diagram, DiagramBuilder, EventStatus, LeafSystem
from pydrake.systems.primitives import (
    ConstantVectorSource, Demultiplexer, LogVectorOutput, TrajectorySource, VectorLogSink,
)
from pydrake.trajectories import PiecewisePolynomial

from models.apriltag import textured_quad_mesh
from systems.config import ConfigError, require, require_positive
from systems.control.flight_controller import (
    BACKENDS, FlightController, FlightControllerConfig, SymbolicFlightController, make_flight_controller,
)
from systems.control.landing import LandingConfig, LandingSupervisor, Mode
from systems.control.pid import TrackingPid, TrackingPidConfig
from systems.geometry import register_visual
from systems.perception.markers import MarkerLayout, pad_texture
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry
from systems.vehicles.ground_vehicle import (
    GroundVehicle, GroundVehicleConfig, PathFollowerConfig, bicycle_state_derivative,
)
from systems.vehicles.paths import PATH_NAMES, PathConfig, make_path
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, Quadrotor, QuadrotorParams, hover_state

# The perception seam's vector (PerfectPerception's `relative_state` output), all in SI units:
P_BP_W = slice(0, 3)  # pad centre minus UAV (body origin), in W [m]
P_BP_B = slice(3, 6)  # the same, in the UAV body frame B [m]
V_WP = slice(6, 9)  # velocity of the pad centre in W [m/s]
HEIGHT = 9  # UAV above the pad's top surface [m]
VALID = 10  # 1 when the pad is in view, else 0
A_WP = slice(11, 14)  # acceleration of the pad centre in W [m/s^2]
RELATIVE_STATE_SIZE = 14

# Layout of the `state` output of the ground vehicle (systems/vehicles/ground_vehicle.py).
GV_X, GV_Y, GV_HEADING, GV_STEERING = range(4)


@dataclass
class VehicleConfig:
    """The ground vehicle: its path, its speed and the bicycle model of seed 002 Eq. (6)."""

    path: str = "straight"  # one of systems.vehicles.paths.PATH_NAMES
    speed: float = 0.5  # m/s, constant unless a schedule is given; seed 003 simulated 0.2-0.8 m/s
    # Scheduled speed (optional): piecewise linear through these points, held after the last one.
    speed_schedule_times_s: list[float] = field(default_factory=list)
    speed_schedule_m_s: list[float] = field(default_factory=list)
    wheelbase_m: float = 3.5  # d, seed 002 Table 1
    steering_time_constant_s: float = 1.0  # tau_s, seed 002 Table 1
    max_steering_deg: float = 20.0  # theta_max, seed 002 Table 1
    # Path sizes (seed 003 Fig. 9 gives none; see systems/vehicles/paths.py).
    path_length_m: float = 2000.0  # open paths
    path_radius_m: float = 15.0  # every arc
    path_lead_m: float = 20.0  # straight run before the turns and the S
    path_side_m: float = 60.0  # rectangle's long side
    follower: PathFollowerConfig = field(default_factory=PathFollowerConfig)

    def path_config(self) -> PathConfig:
        return PathConfig(name=self.path, length_m=self.path_length_m, radius_m=self.path_radius_m,
                          lead_m=self.path_lead_m, side_m=self.path_side_m)

    def ground_vehicle_config(self) -> GroundVehicleConfig:
        return GroundVehicleConfig(wheelbase_m=self.wheelbase_m, steering_time_constant_s=self.steering_time_constant_s,
                                   max_steering_deg=self.max_steering_deg, path=self.path_config(),
                                   follower=self.follower)

    def speed_profile(self) -> PiecewisePolynomial | None:
        """The scheduled speed as a trajectory of time, or None for the constant `speed`."""
        if not self.speed_schedule_times_s:
            return None
        times = np.asarray(self.speed_schedule_times_s, dtype=float)
        speeds = np.asarray(self.speed_schedule_m_s, dtype=float)
        if len(times) == 1:
            times, speeds = np.r_[times, times + 1.0], np.r_[speeds, speeds]
        return PiecewisePolynomial.FirstOrderHold(times, speeds.reshape(1, -1))

    def validate(self, prefix: str = "vehicle") -> None:
        require(self.path in PATH_NAMES, f"{prefix}.path '{self.path}' is not a path (known: {', '.join(PATH_NAMES)})")
        require(self.speed >= 0, f"{prefix}.speed must not be negative, got {self.speed}")
        for name in ("wheelbase_m", "steering_time_constant_s", "path_length_m", "path_radius_m", "path_lead_m",
                     "path_side_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(0 < self.max_steering_deg < 90,
                f"{prefix}.max_steering_deg must be in (0, 90), got {self.max_steering_deg}")
        times, speeds = self.speed_schedule_times_s, self.speed_schedule_m_s
        require(len(times) == len(speeds), f"{prefix}.speed_schedule_times_s and {prefix}.speed_schedule_m_s must "
                                           f"have the same length ({len(times)} and {len(speeds)})")
        require(all(b > a for a, b in zip(times, times[1:])),
                f"{prefix}.speed_schedule_times_s must increase")
        require(all(v >= 0 for v in speeds), f"{prefix}.speed_schedule_m_s must not be negative")
        gv = self.ground_vehicle_config()
        if self.path != "sine":
            require(self.path_radius_m >= gv.min_turning_radius_m(),
                    f"{prefix}.path_radius_m = {self.path_radius_m} is tighter than the vehicle can turn "
                    f"({gv.min_turning_radius_m():.1f} m at {prefix}.max_steering_deg = {self.max_steering_deg})")
        try:
            gv.validate(prefix)
            make_path(gv.path)
        except ConfigError as e:  # name our flattened fields, not GroundVehicleConfig's nested ones
            message = str(e).replace(f"{prefix}.path.name", f"{prefix}.path").replace("path.", "path_")
            raise ConfigError(message if message.startswith(prefix) else f"{prefix}.{message}") from None


@dataclass
class PlatformConfig:
    """The landing platform on the vehicle's roof and the vehicle's visible body (m).

    Frame V of the vehicle is on the ground under the rear axle, x forward; the pad frame P has its
    origin at the centre of the pad's top surface, axes parallel to V's."""

    height_m: float = 1.6  # pad top above the ground, seed 002 Sec. 2.2
    pad_size_m: float = 1.0  # square pad, seed 003 Sec. 3.2.1 (1.0 x 1.0 m PVC pad)
    pad_thickness_m: float = 0.02
    pad_offset_m: float = 1.75  # pad centre ahead of the rear axle (half of seed 002's wheelbase)
    # Five ArUco markers (seed 002 Fig. 1c; seed 003's UGV carries an ArUco marker too), textured on
    # the pad; systems/perception/markers.py gives the default layout and why.
    markers: MarkerLayout = field(default_factory=MarkerLayout)
    # The visible body (not in the papers: a car the size of seed 002's 3.5 m wheelbase).
    body_length_m: float = 4.6
    body_width_m: float = 1.8
    rear_overhang_m: float = 0.55
    ground_clearance_m: float = 0.3
    wheel_radius_m: float = 0.33
    wheel_width_m: float = 0.22

    def validate(self, prefix: str = "platform") -> None:
        for name in ("height_m", "pad_size_m", "pad_thickness_m", "body_length_m", "body_width_m",
                     "ground_clearance_m", "wheel_radius_m", "wheel_width_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.rear_overhang_m >= 0, f"{prefix}.rear_overhang_m must not be negative")
        require(self.height_m - self.pad_thickness_m > self.ground_clearance_m,
                f"{prefix}.height_m ({self.height_m}) must be above {prefix}.ground_clearance_m + pad_thickness_m")
        require(self.pad_size_m <= self.body_width_m,
                f"{prefix}.pad_size_m ({self.pad_size_m}) is wider than {prefix}.body_width_m ({self.body_width_m})")
        front, rear = self.body_length_m - self.rear_overhang_m, -self.rear_overhang_m
        require(rear <= self.pad_offset_m - self.pad_size_m / 2 and self.pad_offset_m + self.pad_size_m / 2 <= front,
                f"{prefix}.pad_offset_m ({self.pad_offset_m}) puts the pad off the roof "
                f"(the body spans {rear:g} to {front:g} m along the vehicle)")
        self.markers.validate(f"{prefix}.markers", self.pad_size_m)

    @property
    def p_VP(self) -> np.ndarray:
        """Pad centre (top surface) in the vehicle frame V [m]."""
        return np.array([self.pad_offset_m, 0.0, self.height_m])


@dataclass
class PerceptionConfig:
    """Perfect perception: the true relative state whenever the pad is in view."""

    field_of_view_deg: float = 150.0  # full cone about -z of the body; seed 003's fisheye (Sec. 2.1)
    max_range_m: float = 30.0  # not in the paper

    def validate(self, prefix: str = "perception") -> None:
        require(0 < self.field_of_view_deg <= 180, f"{prefix}.field_of_view_deg must be in (0, 180]")
        require_positive(self.max_range_m, f"{prefix}.max_range_m")


@dataclass
class StartConfig:
    """Where the UAV is at t = 0, its rotors at hover speed: on the ground (height_m 0) or hovering
    height_m above it (the vehicle starts at the World origin)."""

    xy_m: list[float] = field(default_factory=lambda: [-3.0, -4.0])
    height_m: float = 0.0
    yaw_deg: float = 0.0

    def validate(self, prefix: str = "start") -> None:
        require(len(self.xy_m) == 2, f"{prefix}.xy_m needs 2 numbers")
        require(self.height_m >= 0, f"{prefix}.height_m must not be negative")


@dataclass
class TerminationConfig:
    """When `LandingMonitor` ends a run (not from the papers)."""

    rate_hz: float = 10.0  # checks per second (a run goes on up to one period past its end)
    stop_on_landed: bool = True  # false: fly on after touchdown (the supervisor keeps the vehicle's speed)
    lost_timeout_s: float = 20.0  # target unseen this long: "target_lost"
    max_speed_m_s: float = 40.0  # |v_WB| beyond this: "diverged"
    max_altitude_m: float = 60.0  # "diverged"
    max_distance_m: float = 200.0  # horizontal distance to the pad: "diverged"
    ground_tolerance_m: float = 0.02  # the UAV's centre this far below the ground: "crash"

    def validate(self, prefix: str = "termination") -> None:
        for name in ("rate_hz", "lost_timeout_s", "max_speed_m_s", "max_altitude_m", "max_distance_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.ground_tolerance_m >= 0, f"{prefix}.ground_tolerance_m must not be negative")


def _table1_airframe() -> AirframeConfig:
    """Visual airframe matching seed 002 Table 1's arms (rotors at l1 = l2 = 0.25 m)."""
    return AirframeConfig(body_size_m=0.2, body_height_m=0.08, rotor_arm_m=float(np.hypot(0.25, 0.25)),
                          propeller_radius_m=0.12)


@dataclass
class IntegrationConfig:
    """How the vehicles' continuous dynamics (seed 002 Eq. 6-8) are integrated.

    discrete (the default): each vehicle is built with `time_period` = the flight-controller period
    (systems/vehicles/integration.py) and integrates its equations over it with `scheme`, holding its input
    over the period; the rotor commands are held so anyway, so this is exact up to the integrator.
    The diagram then has no continuous state, and the simulator never evaluates derivatives of the
    whole diagram (each evaluation visits every Python LeafSystem, ~4.7 us apiece).
    discrete false: the simulator integrates the diagram with `scheme` (for comparison)."""

    discrete: bool = True
    # Drake's RK5 (Dormand-Prince), one fixed 5 ms step per controller period: its error over a period
    # matches seed 002's RK4 at 1 ms (~1e-13 m; benchmarks/landing_sweep.py). runge_kutta3 is ~15 %
    # faster, with ~1e-8 m per period.
    scheme: str = "runge_kutta5"  # a name from pydrake.systems.analysis.GetIntegrationSchemes()
    max_step_s: float = 0.005
    error_control: bool = False  # fixed steps (error control restarts from a small step every period)
    accuracy: float = 1e-6  # with error_control

    def validate(self, prefix: str = "integration") -> None:
        require(self.scheme in GetIntegrationSchemes(),
                f"{prefix}.scheme '{self.scheme}' is not one of {', '.join(GetIntegrationSchemes())}")
        require_positive(self.max_step_s, f"{prefix}.max_step_s")
        require(0 < self.accuracy < 1, f"{prefix}.accuracy must be in (0, 1)")

    def simulator_config(self) -> SimulatorConfig:
        return SimulatorConfig(integration_scheme=self.scheme, max_step_size=self.max_step_s,
                               use_error_control=self.error_control, accuracy=self.accuracy)


@dataclass
class GvLandingConfig:
    seed: int = 0  # nothing is random yet (perfect perception); kept for the metrics and later noise
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    platform: PlatformConfig = field(default_factory=PlatformConfig)
    quadrotor: QuadrotorParams = field(default_factory=QuadrotorParams)
    controller: FlightControllerConfig = field(default_factory=FlightControllerConfig)
    # The flight controller's backend (systems/control/flight_controller.py): "symbolic" (C++, the
    # default) or "python" (the same law in a LeafSystem).
    controller_implementation: str = "symbolic"
    pid: TrackingPidConfig = field(default_factory=TrackingPidConfig)
    landing: LandingConfig = field(default_factory=LandingConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    start: StartConfig = field(default_factory=StartConfig)
    termination: TerminationConfig = field(default_factory=TerminationConfig)
    integration: IntegrationConfig = field(default_factory=IntegrationConfig)
    uav: AirframeConfig = field(default_factory=_table1_airframe)  # visual only

    def validate(self) -> None:
        for name in ("vehicle", "platform", "quadrotor", "controller", "pid", "landing", "perception", "start",
                     "termination", "integration", "uav"):
            getattr(self, name).validate(name)
        require(self.controller_implementation in BACKENDS,
                f"controller_implementation '{self.controller_implementation}' is not one of {', '.join(BACKENDS)}")
        require(self.controller.max_vertical_accel_m_s2 < self.quadrotor.gravity_m_s2,
                "controller.max_vertical_accel_m_s2 must be below quadrotor.gravity_m_s2")

    @property
    def period_s(self) -> float:
        """The flight controller's sample period, over which the discrete vehicles integrate."""
        return 1.0 / self.controller.rate_hz


# ----------------------------------------------------------------------------------------------
# Systems of this diagram


def relative_state(quad_state, vehicle_state, speed: float, vehicle: VehicleConfig, platform: PlatformConfig,
                   perception: PerceptionConfig, speed_rate: float = 0.0, steering_rate: float = 0.0) -> np.ndarray:
    """The perception seam's vector (see RELATIVE_STATE_SIZE) from the true states: quadrotor
    `state` (17), vehicle `state` [x, y, heading, steering], vehicle speed (m/s), and for the pad's
    acceleration the rates of the speed (m/s^2) and of the steering angle (rad/s). Plain float
    arithmetic: it runs at every supervisor sample."""
    x, y, heading, steering = vehicle_state[:4].tolist()
    px, py, pz, qw, qx, qy, qz = quad_state[:7].tolist()
    c, s = math.cos(heading), math.sin(heading)
    r = platform.pad_offset_m  # rear axle to pad centre, along the heading
    r_x, r_y = c * r, s * r
    # Seed 002 Eq. (6): yaw rate w = v tan(steering) / d, and its rate.
    tan_steering = math.tan(steering)
    yaw_rate = speed * tan_steering / vehicle.wheelbase_m
    yaw_accel = (speed_rate * tan_steering + speed * steering_rate * (1.0 + tan_steering**2)) / vehicle.wheelbase_m
    dx, dy, dz = x + r_x - px, y + r_y - py, platform.height_m - pz  # p_BP_W
    # p_BP_B = R_WB^T p_BP_W, R_WB from the (not necessarily unit) quaternion as rotation_from_quaternion.
    n = qw * qw + qx * qx + qy * qy + qz * qz
    bx = ((qw * qw + qx * qx - qy * qy - qz * qz) * dx + 2 * (qx * qy + qw * qz) * dy + 2 * (qx * qz - qw * qy) * dz) / n
    by = (2 * (qx * qy - qw * qz) * dx + (qw * qw - qx * qx + qy * qy - qz * qz) * dy + 2 * (qy * qz + qw * qx) * dz) / n
    bz = (2 * (qx * qz + qw * qy) * dx + 2 * (qy * qz - qw * qx) * dy + (qw * qw - qx * qx - qy * qy + qz * qz) * dz) / n
    distance = math.sqrt(dx * dx + dy * dy + dz * dz)
    # In view: inside the cone about -z_B and in range (the pad centre stands for the pad).
    cos_angle = -bz / distance if distance > 0 else 1.0
    visible = distance <= perception.max_range_m and cos_angle >= math.cos(math.radians(perception.field_of_view_deg / 2))
    # The pad at r along the heading h = (c, s), n = (-s, c): v_P = v h + r w n and
    # a_P = (dv/dt - r w^2) h + (v w + r dw/dt) n.
    along, across = speed_rate - r * yaw_rate**2, speed * yaw_rate + r * yaw_accel
    values = [dx, dy, dz, bx, by, bz, speed * c - yaw_rate * r_y, speed * s + yaw_rate * r_x, 0.0, -dz, 0.0,
              along * c - across * s, along * s + across * c, 0.0]
    finite = math.isfinite(sum(values))
    values[VALID] = 1.0 if visible and finite else 0.0
    return np.array(values)


class RelativeStateTruth(LeafSystem):
    """Inputs `quadrotor_state` (17), `vehicle_state` (4), `vehicle_speed` (2: speed [m/s] and its
    rate [m/s^2]), `vehicle_steering_command` (1, rad); output `relative_state`
    (RELATIVE_STATE_SIZE), computed from the truth when pulled."""

    def __init__(self, vehicle: VehicleConfig, platform: PlatformConfig, perception: PerceptionConfig):
        super().__init__()
        self._configs = vehicle, platform, perception
        self._ground_vehicle = vehicle.ground_vehicle_config()
        self._quad = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self._vehicle = self.DeclareVectorInputPort("vehicle_state", 4)
        self._speed = self.DeclareVectorInputPort("vehicle_speed", 2)
        self._steering = self.DeclareVectorInputPort("vehicle_steering_command", 1)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _calc(self, context, output):
        vehicle_state = self._vehicle.Eval(context)
        speed, speed_rate = self._speed.Eval(context).tolist()
        steering_rate = float(bicycle_state_derivative(vehicle_state, float(self._steering.Eval(context)[0]), speed,
                                                       self._ground_vehicle)[GV_STEERING])
        output.SetFromVector(relative_state(self._quad.Eval(context), vehicle_state, speed, *self._configs,
                                            speed_rate=speed_rate, steering_rate=steering_rate))


class PerfectPerception(Diagram):
    """The perception seam, with perfect perception behind it.

    Inputs -- the truth: `quadrotor_state` (17), `vehicle_state` (4), `vehicle_speed` (2: speed
    [m/s] and its rate [m/s^2]), `vehicle_steering_command` (1, rad, for the steering rate).
    Outputs (what an estimator replacing this system must provide, in SI units, World W z up):
      `target_offset` (2): pad centre minus UAV, World x-y (the TrackingPid's error);
      `target_velocity` (2): the pad's velocity, World x-y;
      `target_acceleration` (2): the pad's acceleration, World x-y (the rate of its velocity, for
          the feed-forward; an estimator may give its velocity's rate);
      `height_above_target` (1): UAV above the pad's top surface;
      `target_valid` (1): 1 when the pad is seen;
      `p_BP_W` (3), `p_BP_B` (3): pad relative to the UAV in W and in the body frame B;
      `relative_state` (RELATIVE_STATE_SIZE): all of it in one vector (for logging).
    One Python evaluation per sample time; the split is C++."""

    def __init__(self, vehicle: VehicleConfig, platform: PlatformConfig, perception: PerceptionConfig):
        super().__init__()
        builder = DiagramBuilder()
        truth = builder.AddNamedSystem("truth", RelativeStateTruth(vehicle, platform, perception))
        # The layout of RELATIVE_STATE_SIZE, in pieces: see the names below.
        split = builder.AddNamedSystem("split", Demultiplexer([2, 1, 3, 2, 1, 1, 1, 2, 1]))
        in_w = builder.AddNamedSystem("in_world", Demultiplexer([3, RELATIVE_STATE_SIZE - 3]))
        for demux in (split, in_w):
            builder.Connect(truth.get_output_port(), demux.get_input_port())
        for name in ("quadrotor_state", "vehicle_state", "vehicle_speed", "vehicle_steering_command"):
            builder.ExportInput(truth.GetInputPort(name), name)
        for index, name in ((0, "target_offset"), (2, "p_BP_B"), (3, "target_velocity"), (5, "height_above_target"),
                            (6, "target_valid"), (7, "target_acceleration")):
            builder.ExportOutput(split.get_output_port(index), name)
        builder.ExportOutput(in_w.get_output_port(0), "p_BP_W")
        builder.ExportOutput(truth.get_output_port(), "relative_state")
        builder.BuildInto(self)
        self.set_name("perception")


class LandingMonitor(LeafSystem):
    """Ends the run: a periodic update that returns EventStatus.ReachedTermination with a message
    "<reason>: <details>", reason one of landed, crash, diverged, target_lost (gv_landing_run.FAILURE_REASONS).

    Inputs `quadrotor_state` (17), `vehicle_state` (4), `relative_state`, `mode` (1)."""

    def __init__(self, config: GvLandingConfig):
        super().__init__()
        self._config = config
        self._quad = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self._vehicle = self.DeclareVectorInputPort("vehicle_state", 4)
        self._relative = self.DeclareVectorInputPort("relative_state", RELATIVE_STATE_SIZE)
        self._mode = self.DeclareVectorInputPort("mode", 1)
        self._last_seen = self.DeclareDiscreteState([0.0, 0.0])  # [time last seen (s), seen at all (0/1)]
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.termination.rate_hz, 0.0, self._update)

    def check(self, t: float, quad, vehicle, relative, mode: int, last_seen: float, seen_ever: bool = True) -> str | None:
        """The termination message for these values, or None to go on."""
        term, platform = self._config.termination, self._config.platform
        if not (np.isfinite(quad).all() and np.isfinite(vehicle).all()):
            return f"diverged: non-finite state at t = {t:.2f} s"
        if mode == Mode.LANDED:
            return f"landed: the supervisor reported touchdown by t = {t:.2f} s" if term.stop_on_landed else None
        px, py, pz, vx, vy, vz = (float(quad[i]) for i in (0, 1, 2, 7, 8, 9))
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        if pz < -term.ground_tolerance_m:
            return f"crash: hit the ground at t = {t:.2f} s, {speed:.1f} m/s"
        c, s = math.cos(vehicle[GV_HEADING]), math.sin(vehicle[GV_HEADING])
        dx, dy = px - vehicle[GV_X], py - vehicle[GV_Y]
        along, across = c * dx + s * dy, -s * dx + c * dy  # UAV in the vehicle frame V
        if (-platform.rear_overhang_m < along < platform.body_length_m - platform.rear_overhang_m
                and abs(across) < platform.body_width_m / 2 and pz < platform.height_m - platform.pad_thickness_m):
            return f"crash: hit the ground vehicle at t = {t:.2f} s"
        if speed > term.max_speed_m_s:
            return f"diverged: speed {speed:.1f} m/s at t = {t:.2f} s"
        if pz > term.max_altitude_m:
            return f"diverged: altitude {pz:.1f} m at t = {t:.2f} s"
        distance = math.hypot(relative[0], relative[1])
        if distance > term.max_distance_m:
            return f"diverged: {distance:.0f} m from the pad at t = {t:.2f} s"
        if t - last_seen > term.lost_timeout_s:
            if not seen_ever:
                return f"target_lost: the pad was never in view in the first {t:.1f} s"
            return f"target_lost: unseen for {t - last_seen:.1f} s at t = {t:.2f} s"
        return None

    def _update(self, context, discrete_state):
        t = context.get_time()
        relative = self._relative.Eval(context)
        last_seen, seen_ever = context.get_discrete_state(self._last_seen).get_value()
        if relative[VALID] > 0.5:
            last_seen, seen_ever = t, 1.0
        discrete_state.set_value(self._last_seen, [last_seen, seen_ever])
        message = self.check(t, self._quad.Eval(context), self._vehicle.Eval(context), relative,
                             int(round(self._mode.Eval(context)[0])), last_seen, bool(seen_ever))
        return EventStatus.ReachedTermination(self, message) if message else EventStatus.Succeeded()


class GroundVehicleGeometry(LeafSystem):
    """Registers the vehicle (body, four wheels, the pad with its marker texture) with SceneGraph and
    poses it from the input `vehicle_state` (4): the body frame is V, the front wheels steer."""

    def __init__(self, vehicle: VehicleConfig, platform: PlatformConfig, scene_graph: SceneGraph):
        super().__init__()
        self._wheelbase = vehicle.wheelbase_m
        self.source_id = scene_graph.RegisterSource("ground_vehicle")
        sid, p = self.source_id, platform
        self.body_frame_id = scene_graph.RegisterFrame(sid, GeometryFrame("gv_body"))
        body = self.body_frame_id
        top = p.height_m - p.pad_thickness_m
        register_visual(scene_graph, sid, body, RigidTransform(
            [p.body_length_m / 2 - p.rear_overhang_m, 0.0, (p.ground_clearance_m + top) / 2]),
            Box(p.body_length_m, p.body_width_m, top - p.ground_clearance_m), "gv_body", (0.75, 0.3, 0.15, 1.0))
        register_visual(scene_graph, sid, body, RigidTransform([p.pad_offset_m, 0.0, p.height_m - p.pad_thickness_m / 2]),
                        Box(p.pad_size_m, p.pad_size_m, p.pad_thickness_m), "gv_pad", (0.95, 0.95, 0.95, 1.0))
        register_visual(scene_graph, sid, body, RigidTransform([p.pad_offset_m, 0.0, p.height_m + 0.001]),
                        Mesh(str(pad_texture_mesh(p)), p.pad_size_m), "gv_pad_markers", rgba=None)
        wheel = Cylinder(p.wheel_radius_m, p.wheel_width_m)
        R_wheel = RotationMatrix.MakeXRotation(np.pi / 2)  # cylinder axis (z) along the axle (y)
        y = p.body_width_m / 2  # wheels half outside the body (no coplanar faces)
        dark = (0.1, 0.1, 0.1, 1.0)
        for name, side in (("rl", 1), ("rr", -1)):
            register_visual(scene_graph, sid, body, RigidTransform(R_wheel, [0.0, side * y, p.wheel_radius_m]), wheel,
                            f"gv_wheel_{name}", dark)
        self._front = []
        for name, side in (("fl", 1), ("fr", -1)):
            frame = scene_graph.RegisterFrame(sid, GeometryFrame(f"gv_wheel_{name}"))
            register_visual(scene_graph, sid, frame, RigidTransform(R_wheel), wheel, f"gv_wheel_{name}", dark)
            self._front.append((frame, np.array([vehicle.wheelbase_m, side * y, p.wheel_radius_m])))
        self._state = self.DeclareVectorInputPort("vehicle_state", 4)
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc)

    def _calc(self, context, output):
        x, y, heading, steering = self._state.Eval(context)
        X_WV = RigidTransform(RotationMatrix.MakeZRotation(heading), [x, y, 0.0])
        poses = output.get_mutable_value()
        poses.clear()
        poses.set_value(self.body_frame_id, X_WV)
        for frame, p_VW in self._front:
            poses.set_value(frame, X_WV.multiply(RigidTransform(RotationMatrix.MakeZRotation(steering), p_VW)))


class MeshcatTrail(LeafSystem):
    """Draws the UAV's trail in Meshcat (a line through its positions, sampled at `rate_hz`)."""

    def __init__(self, meshcat: Meshcat, path: str = "gv_landing/uav_trail", rate_hz: float = 10.0):
        super().__init__()
        self._meshcat, self._path, self._points = meshcat, path, []
        self._state = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self.DeclareInitializationPublishEvent(self._reset)
        self.DeclarePeriodicPublishEvent(1.0 / rate_hz, 0.0, self._publish)

    def _reset(self, context):
        self._points = []
        self._meshcat.Delete(self._path)

    def _publish(self, context):
        p = self._state.Eval(context)[P_WB]
        if np.all(np.isfinite(p)):
            self._points.append(p.copy())
        if len(self._points) >= 2:
            self._meshcat.SetLine(self._path, np.array(self._points).T, 2.0, Rgba(0.1, 0.4, 0.9, 1.0))


# ----------------------------------------------------------------------------------------------
# Assets


def pad_texture_mesh(platform: PlatformConfig):
    """The unit textured quad (models/generated) carrying the pad's markers (`pad_texture`),
    generated on first use and named by its content."""
    image = pad_texture(platform.markers, platform.pad_size_m)
    return textured_quad_mesh(f"gv_pad_{hashlib.sha1(image.tobytes()).hexdigest()[:12]}", image)


def path_polyline(vehicle: VehicleConfig, max_length_m: float = 400.0) -> np.ndarray:
    """(N, 2) points of the vehicle's path (the first `max_length_m` of an open one)."""
    path = make_path(vehicle.path_config())
    s = path.s if path.closed else path.s[path.s <= max_length_m]
    return path.xy[np.searchsorted(path.s, s)][:: max(1, len(s) // 2000)]


def add_ground_and_path(scene_graph: SceneGraph, vehicle: VehicleConfig, meshcat: Meshcat | None) -> None:
    """A ground plane under the path (top at z = 0); the path drawn in Meshcat."""
    xy = path_polyline(vehicle)
    lo, hi = xy.min(axis=0) - 25.0, xy.max(axis=0) + 25.0
    source_id = scene_graph.RegisterSource("ground")
    register_visual(scene_graph, source_id, scene_graph.world_frame_id(),
                    RigidTransform([*(lo + hi) / 2, -0.05]), Box(*(hi - lo), 0.1), "ground", (0.8, 0.82, 0.76, 1.0))
    if meshcat is not None:
        meshcat.SetLine("gv_landing/path", np.vstack([xy.T, np.full(len(xy), 0.02)]), 3.0, Rgba(1.0, 0.85, 0.1, 1.0))
        meshcat.SetProperty("/Grid", "visible", False)  # the ground plane is the floor
        # Looking at the start of the path from behind and above the UAV's start.
        meshcat.SetCameraPose(np.array([-14.0, -18.0, 12.0]), np.array([6.0, 2.0, 2.0]))


# ----------------------------------------------------------------------------------------------
# The builder


@dataclass
class GvLandingHandles:
    """The systems and ports of a built gv-landing diagram that callers use."""

    config: GvLandingConfig
    quadrotor: Quadrotor  # discretised per controller period with integration.discrete
    vehicle: GroundVehicle  # likewise
    speed_source: object  # ConstantVectorSource or TrajectorySource of the vehicle speed and its rate (2)
    perception: PerfectPerception  # the seam
    pid: TrackingPid
    supervisor: LandingSupervisor
    controller: SymbolicFlightController | FlightController
    monitor: LandingMonitor
    scene_graph: SceneGraph
    airframe: AirframeGeometry
    vehicle_geometry: GroundVehicleGeometry
    loggers: dict[str, VectorLogSink]
    meshcat_visualizer: MeshcatVisualizer | None = None
    video: None = None  # no cameras here; runner.finish_run reads it

    def initialize(self, root_context) -> None:
        """Sets the initial conditions in a context of the built diagram: the UAV at rest at `start`
        (on the ground, or hovering) with its rotors at hover speed, the vehicle at the start of its path."""
        c = self.config
        self.quadrotor.set_state(root_context,
                                 hover_state(c.quadrotor, [*c.start.xy_m, c.start.height_m],
                                             yaw=np.radians(c.start.yaw_deg)))
        self.vehicle.set_state(root_context, self.vehicle.initial_state())
        self.controller.initialize(root_context)


LOG_NAMES = ("quadrotor_state", "vehicle_state", "relative_state", "mode", "command", "tracking_velocity",
             "vehicle_speed")


def build_gv_landing(config: GvLandingConfig, meshcat: Meshcat | None = None) -> tuple[Diagram, GvLandingHandles]:
    """Builds the gv-landing diagram; returns it with the handles of its systems. Call
    `handles.initialize(context)` on the simulator's context before simulating."""
    builder = DiagramBuilder()
    handles = add_gv_landing(builder, config, meshcat)
    diagram = builder.Build()
    diagram.set_name("gv_landing")
    return diagram, handles


def add_gv_landing(builder: DiagramBuilder, config: GvLandingConfig, meshcat: Meshcat | None = None) -> GvLandingHandles:
    """Adds the gv-landing systems to `builder` (for diagrams that add more, such as a camera on the
    airframe's body frame); returns their handles."""
    config.validate()
    discrete = config.integration.discrete
    period, integration = (config.period_s, config.integration.simulator_config()) if discrete else (None, None)
    quad = builder.AddNamedSystem("quadrotor", Quadrotor(config.quadrotor, period, integration))
    vehicle = builder.AddNamedSystem("ground_vehicle", GroundVehicle(
        config.vehicle.ground_vehicle_config(), period, integration))
    # The vehicle's speed and its rate: [v (m/s), dv/dt (m/s^2)].
    profile = config.vehicle.speed_profile()
    speed = builder.AddNamedSystem("vehicle_speed", ConstantVectorSource([config.vehicle.speed, 0.0])
                                   if profile is None else TrajectorySource(profile, 1, True))
    speed_split = builder.AddNamedSystem("vehicle_speed_split", Demultiplexer([1, 1]))
    perception = builder.AddSystem(PerfectPerception(config.vehicle, config.platform, config.perception))
    pid = builder.AddNamedSystem("tracking_pid", TrackingPid(config.pid))
    supervisor = builder.AddNamedSystem("landing_supervisor", LandingSupervisor(config.landing))
    # Not held with the discretised quadrotor: it samples and holds the law at the period itself.
    controller = builder.AddNamedSystem("flight_controller", make_flight_controller(
        config.quadrotor, config.controller, config.controller_implementation, held=not discrete))
    monitor = builder.AddNamedSystem("monitor", LandingMonitor(config))
    altitude = builder.AddNamedSystem("altitude", Demultiplexer([2, 1, STATE_SIZE - 3]))

    quad_state, vehicle_state = quad.GetOutputPort("state"), vehicle.GetOutputPort("state")
    builder.Connect(speed.get_output_port(), speed_split.get_input_port())
    builder.Connect(speed_split.get_output_port(0), vehicle.GetInputPort("speed"))
    builder.Connect(speed.get_output_port(), perception.GetInputPort("vehicle_speed"))
    builder.Connect(vehicle.GetOutputPort("steering_command"), perception.GetInputPort("vehicle_steering_command"))
    builder.Connect(quad_state, perception.GetInputPort("quadrotor_state"))
    builder.Connect(vehicle_state, perception.GetInputPort("vehicle_state"))
    builder.Connect(quad_state, altitude.get_input_port())
    for name in ("target_offset", "target_velocity", "target_valid"):
        builder.Connect(perception.GetOutputPort(name), pid.GetInputPort(name))
        builder.Connect(perception.GetOutputPort(name), supervisor.GetInputPort(name))
    builder.Connect(perception.GetOutputPort("target_acceleration"), pid.GetInputPort("target_acceleration"))
    builder.Connect(perception.GetOutputPort("height_above_target"), pid.GetInputPort("height"))
    builder.Connect(perception.GetOutputPort("height_above_target"), supervisor.GetInputPort("height_above_target"))
    builder.Connect(altitude.get_output_port(1), supervisor.GetInputPort("altitude"))
    builder.Connect(pid.GetOutputPort("velocity_command"), supervisor.GetInputPort("tracking_velocity"))
    builder.Connect(pid.GetOutputPort("acceleration_command"), supervisor.GetInputPort("tracking_acceleration"))
    builder.Connect(supervisor.GetOutputPort("command"), controller.GetInputPort("command"))
    builder.Connect(quad_state, controller.GetInputPort("state"))
    builder.Connect(controller.GetOutputPort("rotor_speed_commands"), quad.GetInputPort("rotor_speed_commands"))
    builder.Connect(quad_state, monitor.GetInputPort("quadrotor_state"))
    builder.Connect(vehicle_state, monitor.GetInputPort("vehicle_state"))
    builder.Connect(perception.GetOutputPort("relative_state"), monitor.GetInputPort("relative_state"))
    builder.Connect(supervisor.GetOutputPort("mode"), monitor.GetInputPort("mode"))

    # Logged at the supervisor's rate, so the sample before the first LANDED one holds the state
    # the supervisor saw when it declared touchdown.
    period = 1.0 / config.landing.rate_hz
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in zip(LOG_NAMES, (
        quad_state, vehicle_state, perception.GetOutputPort("relative_state"), supervisor.GetOutputPort("mode"),
        supervisor.GetOutputPort("command"), pid.GetOutputPort("velocity_command"), speed.get_output_port()))}

    # Scene geometry (pulled only by a visualizer: free when there is none).
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    add_ground_and_path(scene_graph, config.vehicle, meshcat)
    airframe = builder.AddNamedSystem("airframe", AirframeGeometry(config.uav, scene_graph))
    builder.Connect(quad.GetOutputPort("X_WB"), airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))
    vehicle_geometry = builder.AddNamedSystem("vehicle_geometry", GroundVehicleGeometry(
        config.vehicle, config.platform, scene_graph))
    builder.Connect(vehicle_state, vehicle_geometry.get_input_port())
    builder.Connect(vehicle_geometry.get_output_port(), scene_graph.get_source_pose_port(vehicle_geometry.source_id))
    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                                    MeshcatVisualizerParams(role=Role.kIllustration))
        trail = builder.AddNamedSystem("uav_trail", MeshcatTrail(meshcat))
        builder.Connect(quad_state, trail.get_input_port())

    return GvLandingHandles(config, quad, vehicle, speed, perception, pid, supervisor, controller, monitor,
                            scene_graph, airframe, vehicle_geometry, loggers, visualizer)
