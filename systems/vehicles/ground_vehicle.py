"""Ground vehicle of seed 002 (Sec. 2.2): kinematic bicycle of Eq. (6) with a path follower.

State g = [x, y, alpha, theta]: rear-axle position in World x-y [m], heading alpha [rad] from +x,
steering angle theta [rad] (first-order lag tau_s towards the command, limited to theta_max).
The vehicle frame V is on the ground (z = 0) under the rear axle, x forward, z up; a landing
platform's height above it belongs to the scene.

The follower steers to the named path (paths.py). About a straight path, at speed v, the lateral
error e, heading error psi and steering theta obey, per distance travelled,
e' = psi, psi' = theta / d, theta' = (theta_cmd - theta) / (v tau_s). The command

    theta_cmd = theta_ff - k1 e - k2 psi - k3 (theta - theta_ff),  theta_ff = atan(d kappa)

puts all three poles at -a per metre, a = 1 / max(preview_time_s v, min_preview_m):
k1 = a^3 d l, k2 = 3 a^2 d l, k3 = 3 a l - 1 with l = v tau_s. The curvature kappa is read
1 / (3 a) ahead, the steering's closed-loop lag distance.
"""

import math
from dataclasses import dataclass, field

import numpy as np
import pydrake.math as dmath
from pydrake.common.value import Value
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.symbolic import MakeVectorVariable
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Multiplexer, SymbolicVectorSystem
from pydrake.trajectories import PiecewisePolynomial

from systems.config import ConfigError, require, require_positive
from systems.geometry import wrap_angle
from systems.vehicles.integration import discretise, set_vehicle_state
from systems.vehicles.paths import Path, PathConfig, make_path

STATE_SIZE = 4  # [x, y, alpha, theta]
# The ground under an open path covers at least its first 400 m (Path.polyline's default; every scene before the
# run's length counted), more where the vehicle drives further in the run.
GROUND_MIN_LENGTH_M = 400.0


@dataclass
class PathFollowerConfig:
    """Not from the seeds (seed 002 does not say how its vehicle follows Eq. 13)."""

    rate_hz: float = 20.0  # steering updates; the 1 s steering lag filters the steps
    preview_time_s: float = 1.0  # tracking bandwidth a = 1 / max(preview_time_s v, min_preview_m)
    min_preview_m: float = 5.0
    search_window_m: float = 10.0  # nearest-point search around the last one

    def validate(self, prefix: str = "vehicle.follower") -> None:
        for name in ("rate_hz", "preview_time_s", "min_preview_m", "search_window_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")


@dataclass
class GroundVehicleConfig:
    """The vehicle of a scenario's `vehicle` section: its path, its speed and Eq. (6)'s bicycle."""

    path: str = "straight"  # one of systems.vehicles.paths.PATH_NAMES
    speed: float = 0.5  # m/s, constant unless a schedule is given; seed 003 simulated 0.2-0.8 m/s
    # Scheduled speed (optional): piecewise linear through these points, held after the last one.
    speed_schedule_times_s: list[float] = field(default_factory=list)
    speed_schedule_m_s: list[float] = field(default_factory=list)
    wheelbase_m: float = 3.5  # d, seed 002 Table 1
    steering_time_constant_s: float = 1.0  # tau_s, seed 002 Table 1
    max_steering_deg: float = 20.0  # theta_max, seed 002 Table 1
    # Path sizes (seed 003 Fig. 9 gives none; see paths.py).
    path_length_m: float = 2000.0  # open paths
    path_radius_m: float = 15.0  # every arc
    path_lead_m: float = 20.0  # straight run before the turns and the S
    path_side_m: float = 60.0  # rectangle's long side
    follower: PathFollowerConfig = field(default_factory=PathFollowerConfig)

    def path_config(self) -> PathConfig:
        return PathConfig(name=self.path, length_m=self.path_length_m, radius_m=self.path_radius_m,
                          lead_m=self.path_lead_m, side_m=self.path_side_m)

    def ground_length_m(self, duration_s: float = 0.0, lead: tuple[float, float] = (1.0, 0.0)) -> float:
        """How much of an open path [m] the ground covers: GROUND_MIN_LENGTH_M, or where that is more, as far as
        anything on the path gets in a run of `duration_s` [s]: `lead` (factor, ahead_m) times the vehicle's
        distance driven plus ahead_m (the distractors', DistractorsConfig.lead)."""
        factor, ahead_m = lead
        return max(GROUND_MIN_LENGTH_M, factor * self.distance_driven_m(duration_s) + ahead_m)

    def ground_extent(self, duration_s: float = 0.0, margin_m: float = 25.0,
                      lead: tuple[float, float] = (1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) World x, y [m] of the path, widened by margin_m: the ground to lay under it. All of a
        closed path; of an open one, ground_length_m(duration_s, lead)."""
        xy = make_path(self.path_config()).polyline(self.ground_length_m(duration_s, lead))
        return xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m

    def speed_profile(self) -> PiecewisePolynomial | None:
        """The scheduled speed [m/s] as a trajectory of time [s], or None for the constant `speed`."""
        if not self.speed_schedule_times_s:
            return None
        times = np.asarray(self.speed_schedule_times_s, dtype=float)
        speeds = np.asarray(self.speed_schedule_m_s, dtype=float)
        if len(times) == 1:
            times, speeds = np.r_[times, times + 1.0], np.r_[speeds, speeds]
        return PiecewisePolynomial.FirstOrderHold(times, speeds.reshape(1, -1))

    def distance_driven_m(self, time_s: float, scale: float = 1.0) -> float:
        """Arc length [m] driven from t = 0 to `time_s` [s] at `scale` times the vehicle's speed (a distractor's
        factor, systems/vehicles/traffic.py): speed * scale * time_s (in that order: the distractors' poses as
        they were), or scale times the schedule's integral, linear between its points and held before the first
        and after the last, as speed_profile's TrajectorySource gives it."""
        if not self.speed_schedule_times_s:
            return self.speed * scale * time_s
        times = np.asarray(self.speed_schedule_times_s, dtype=float)
        grid = np.r_[0.0, times[(times > 0.0) & (times < time_s)], time_s]
        return scale * float(np.trapezoid(np.interp(grid, times, self.speed_schedule_m_s), grid))

    def speed_label(self) -> str:
        """The speed as a plot's title says it: "0.5 m/s", or the schedule's range, "0-2 m/s scheduled"."""
        if not self.speed_schedule_m_s:
            return f"{self.speed:g} m/s"
        return f"{min(self.speed_schedule_m_s):g}-{max(self.speed_schedule_m_s):g} m/s scheduled"

    def speed_metrics(self) -> dict:
        """metrics.json's speed of the vehicle: `speed_m_s`, or the schedule that replaces it."""
        if not self.speed_schedule_times_s:
            return {"speed_m_s": self.speed}
        return {"speed_schedule_times_s": list(self.speed_schedule_times_s),
                "speed_schedule_m_s": list(self.speed_schedule_m_s)}

    def validate(self, prefix: str = "vehicle") -> None:
        require(self.speed >= 0, f"{prefix}.speed must not be negative, got {self.speed}")
        require_positive(self.wheelbase_m, f"{prefix}.wheelbase_m")
        require_positive(self.steering_time_constant_s, f"{prefix}.steering_time_constant_s")
        require(0 < self.max_steering_deg < 90,
                f"{prefix}.max_steering_deg must be in (0, 90), got {self.max_steering_deg}")
        times, speeds = self.speed_schedule_times_s, self.speed_schedule_m_s
        require(len(times) == len(speeds), f"{prefix}.speed_schedule_times_s and {prefix}.speed_schedule_m_s must "
                                           f"have the same length ({len(times)} and {len(speeds)})")
        require(all(b > a for a, b in zip(times, times[1:])), f"{prefix}.speed_schedule_times_s must increase")
        require(all(v >= 0 for v in speeds), f"{prefix}.speed_schedule_m_s must not be negative")
        self.follower.validate(f"{prefix}.follower")
        path = make_path(self.path_config(), f"{prefix}.path")
        self._validate_search_window(path, prefix)
        curvature = path.max_curvature
        radius = self.min_turning_radius_m()
        if curvature * radius > 1.0:  # the path's tightest radius, 1 / curvature, is under the vehicle's
            arcs = "" if self.path == "sine" else f"{prefix}.path_radius_m or "  # Eq. (13) has a fixed shape
            raise ConfigError(f"{prefix}.path '{self.path}' turns on a {1.0 / curvature:.1f} m radius at its "
                              f"tightest, under the vehicle's minimum turning radius {radius:.1f} m "
                              f"({prefix}.wheelbase_m {self.wheelbase_m:g} / tan({prefix}.max_steering_deg "
                              f"{self.max_steering_deg:g})): raise {arcs}{prefix}.max_steering_deg, or shorten "
                              f"{prefix}.wheelbase_m")

    def _validate_search_window(self, path: Path, prefix: str) -> None:
        """The follower's nearest-point search (Path.nearest) looks within search_window_m [m] of its last point: it
        keeps up only if the window exceeds the distance driven per update, the top speed / rate_hz, plus the
        path's sample spacing (the last point's rounding to a sample)."""
        follower = self.follower
        speed, named = ((max(self.speed_schedule_m_s), f"{prefix}.speed_schedule_m_s's top") if self.speed_schedule_m_s
                        else (self.speed, f"{prefix}.speed"))
        needed = speed / follower.rate_hz + path.spacing
        require(follower.search_window_m > needed,
                f"{prefix}.follower.search_window_m ({follower.search_window_m:g} m) must exceed the distance driven "
                f"per follower update, {named} {speed:g} m/s / {prefix}.follower.rate_hz {follower.rate_hz:g} Hz, "
                f"plus the path's {path.spacing:.3g} m sample spacing: {needed:.3g} m")

    @property
    def max_steering_rad(self) -> float:
        return np.radians(self.max_steering_deg)

    def min_turning_radius_m(self) -> float:
        """R = d / tan(theta_max)."""
        return self.wheelbase_m / np.tan(self.max_steering_rad)


def bicycle_state_derivative(state, steering_command, speed, config: GroundVehicleConfig):
    """Seed 002 Eq. (6), with the command limited to +-theta_max. Works on floats and
    pydrake.symbolic Expressions."""
    _, _, alpha, theta = state
    limit = config.max_steering_rad
    command = dmath.min(dmath.max(steering_command, -limit), limit)
    return np.array([
        speed * dmath.cos(alpha),
        speed * dmath.sin(alpha),
        speed * dmath.tan(theta) / config.wheelbase_m,
        (command - theta) / config.steering_time_constant_s,
    ])


def make_bicycle_dynamics(config: GroundVehicleConfig) -> SymbolicVectorSystem:
    """Eq. (6) as a SymbolicVectorSystem: input [steering command (rad), speed v (m/s)], state and
    output [x, y, alpha, theta] (no direct feedthrough of the speed)."""
    g = MakeVectorVariable(STATE_SIZE, "g")
    u = MakeVectorVariable(2, "u")
    return SymbolicVectorSystem(state=g, input=u, dynamics=bicycle_state_derivative(g, u[0], u[1], config),
                                output=g)


def steering_command(state, speed: float, path: Path, s: float, config: GroundVehicleConfig) -> float:
    """The follower law of the module docstring for the path point at arc length s [m]. Plain
    float arithmetic: it runs at every follower update."""
    x, y, alpha, theta = (float(v) for v in state[:4])
    px, py, path_heading, _ = path.sample(s)
    lateral_error = -math.sin(path_heading) * (x - px) + math.cos(path_heading) * (y - py)
    heading_error = wrap_angle(alpha - path_heading)

    follower = config.follower
    a = 1.0 / max(follower.preview_time_s * abs(speed), follower.min_preview_m)
    lag = abs(speed) * config.steering_time_constant_s
    d = config.wheelbase_m
    k1, k2, k3 = a**3 * d * lag, 3 * a**2 * d * lag, 3 * a * lag - 1
    feed_forward = math.atan(d * path.sample(s + 1.0 / (3 * a))[3])
    return feed_forward - k1 * lateral_error - k2 * heading_error - k3 * (theta - feed_forward)


def initial_state(path: Path, config: GroundVehicleConfig) -> np.ndarray:
    """[x, y, alpha, theta] at the start of the path, wheels set to its curvature."""
    theta = np.arctan(config.wheelbase_m * path.curvature(0.0))
    return np.array([*path.position(0.0), path.heading(0.0), theta])


class PathFollower(LeafSystem):
    """Inputs `state` (4) and `speed` (1, m/s); output `steering_command` (rad), updated at
    `follower.rate_hz`. Keeps the arc length of the last nearest path point as its state."""

    def __init__(self, path: Path, config: GroundVehicleConfig):
        super().__init__()
        self._path, self._config = path, config
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._speed = self.DeclareVectorInputPort("speed", 1)
        self._progress = self.DeclareDiscreteState(1)
        self._command = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.follower.rate_hz, 0.0, self._update)
        self.DeclareStateOutputPort("steering_command", self._command)
        self.DeclareStateOutputPort("path_progress", self._progress)

    def _update(self, context, discrete_state):
        state = self._state.Eval(context).tolist()
        s_hint = context.get_discrete_state(self._progress).GetAtIndex(0)
        s = self._path.nearest(state, s_hint, self._config.follower.search_window_m)
        command = steering_command(state, self._speed.Eval(context)[0], self._path, s, self._config)
        discrete_state.set_value(self._progress, [s])
        discrete_state.set_value(self._command, [command])


def ground_pose(state) -> RigidTransform:
    """X_WV from [x, y, alpha, theta]: on the ground at (x, y), yawed by alpha."""
    return RigidTransform(RotationMatrix.MakeZRotation(state[2]), [state[0], state[1], 0.0])


class StateToGroundPose(LeafSystem):
    """Input `state` (4) -> abstract output `X_WV`: at (x, y, 0), yawed by alpha."""

    def __init__(self):
        super().__init__()
        state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self.DeclareAbstractOutputPort(
            "X_WV", lambda: Value(RigidTransform()),
            lambda context, output: output.set_value(ground_pose(state.Eval(context))))


class GroundVehicle(Diagram):
    """Bicycle model following its configured path.

    Input `speed` (1, m/s). Outputs `state` (4: x, y, alpha, theta), `X_WV` (abstract RigidTransform), `steering_command` (1, rad, the follower's) and
    `path_progress` (1, arc length [m] of the nearest path point).

    `time_period` None: the state is the continuous state of the subsystem `dynamics`.
    `time_period` T: Eq. (6) is integrated over each period T in C++ with `integration`
    (systems/vehicles/integration.py), its inputs held over the period, so a steering command
    reaches the bicycle up to T later. Either way, start it on the path with
    `vehicle.set_state(root_context, vehicle.initial_state())`.
    """

    def __init__(self, config: GroundVehicleConfig, time_period: float | None = None,
                 integration: SimulatorConfig | None = None):
        super().__init__()
        config.validate()
        self.config = config
        self.path = make_path(config.path_config())
        builder = DiagramBuilder()
        bicycle = make_bicycle_dynamics(config)
        if time_period is not None:
            bicycle = discretise(bicycle, time_period, integration, "ground vehicle")
        self.dynamics = dynamics = builder.AddNamedSystem("dynamics", bicycle)
        inputs = builder.AddNamedSystem("inputs", Multiplexer([1, 1]))
        follower = builder.AddNamedSystem("follower", PathFollower(self.path, config))
        pose = builder.AddNamedSystem("pose", StateToGroundPose())
        builder.Connect(follower.GetOutputPort("steering_command"), inputs.get_input_port(0))
        builder.Connect(inputs.get_output_port(), dynamics.get_input_port())
        builder.Connect(dynamics.get_output_port(), follower.GetInputPort("state"))
        builder.Connect(dynamics.get_output_port(), pose.get_input_port())
        builder.ExportInput(inputs.get_input_port(1), "speed")
        builder.ConnectInput("speed", follower.GetInputPort("speed"))
        builder.ExportOutput(dynamics.get_output_port(), "state")
        builder.ExportOutput(pose.get_output_port(), "X_WV")
        builder.ExportOutput(follower.GetOutputPort("steering_command"), "steering_command")
        builder.ExportOutput(follower.GetOutputPort("path_progress"), "path_progress")
        builder.BuildInto(self)
        self.set_name("ground_vehicle")

    def initial_state(self) -> np.ndarray:
        """The state at the start of the configured path (see initial_state())."""
        return initial_state(self.path, self.config)

    def set_state(self, root_context, x) -> None:
        """Sets the state [x, y, alpha, theta] in a context of a diagram that contains this system."""
        set_vehicle_state(self, root_context, x)
