"""The configuration of the ground-vehicle scenarios (gv-landing, gv-marker-ekf, marker-landing):
one dataclass per YAML section, every paper number a default with its source.

Sections beyond the systems' own configs: `perception` (what steers: `source`, a name in
diagrams/perception_sources.py, and when its estimate is valid), `estimation` (the marker
measurement stream and the filters that run on it), `federated` (seed 001's camera, IMU and
federated filter, for perception.source federated), `hybrid` (seed 003's fisheye + stereo array and
what runs on it, for perception.source hybrid: diagrams/hybrid_perception.py), `wind` (systems/environment/wind.py: it acts
through the quadrotor's rotor drag), `faults` (systems/perception/marker_faults.py: in the marker
stream), `navigation` (systems/sensors/navigation.py: the UAV's own state), `rendezvous`
(systems/perception/rendezvous.py: the vehicle's broadcast navigation), `start`, `integration`.
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RigidTransform
from pydrake.systems.analysis import GetIntegrationSchemes, SimulatorConfig

from diagrams.federated_perception import FederatedPerceptionConfig
from diagrams.hybrid_perception import HybridPerceptionConfig
from diagrams.perception_sources import perception_source, require_offered
from systems.config import require, require_positive
from systems.control.flight_controller import BACKENDS, FlightControllerConfig
from systems.control.landing import LandingConfig
from systems.control.monitor import TerminationConfig, inside_carrier
from systems.control.pid import TrackingPidConfig
from systems.environment.bridge import BridgeConfig
from systems.environment.wind import WindConfig
from systems.estimators.marker_ekf import FILTERS, MarkerEkfConfig
from systems.perception.marker_faults import FaultsConfig
from systems.perception.rendezvous import RendezvousConfig
from systems.perception.seam import SeamConfig
from systems.sensors.camera import CameraConfig
from systems.sensors.navigation import NavigationConfig
from systems.vehicles.airframe import AirframeConfig
from systems.vehicles.ground_vehicle import GroundVehicleConfig, initial_state
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.paths import Path, make_path
from systems.vehicles.quadrotor import QuadrotorParams
from systems.vehicles.traffic import DistractorsConfig

MEASUREMENT_SOURCES = ("none", "synthetic", "detector")
# The schemes IntegrationConfig accepts: Drake's, but cenic, which integrates a MultibodyPlant (it finds
# none in these diagrams, and the run fails at its first step).
INTEGRATION_SCHEMES = tuple(name for name in GetIntegrationSchemes() if name != "cenic")
# How long a fixed step h an explicit scheme takes stably on y' = -y / tau: h / tau below the bound of its stability
# interval on the negative real axis, where its stability polynomial R(z) reaches |R| = 1. Explicit Euler,
# semi-explicit Euler (explicit Euler on a SymbolicVectorSystem's state, all of it misc. state z) and RK2 (Heun):
# R = 1 + z and 1 + z + z^2/2, -1 at z = -2. RK3 and Bogacki-Shampine (their 3rd-order solution, 3 stages):
# R = 1 + z + z^2/2 + z^3/6 = -1 at z = -2.5127. RK5 (Dormand-Prince's 5th-order solution): R = the Taylor
# polynomial to z^5/5! + z^6/600 = +1 at z = -3.3066. The implicit schemes are A-stable: no bound.
EXPLICIT_STABILITY_LIMITS = {"explicit_euler": 2.0, "semi_explicit_euler": 2.0, "runge_kutta2": 2.0,
                             "runge_kutta3": 2.5127, "bogacki_shampine3": 2.5127, "runge_kutta5": 3.3066}
# The schemes with no error estimate: Drake steps them fixed whatever error_control says.
FIXED_STEP_SCHEMES = ("explicit_euler", "semi_explicit_euler", "runge_kutta2")


@dataclass
class PerceptionConfig(SeamConfig):
    """What steers the UAV, and (SeamConfig) when an estimate is valid enough to steer on."""

    source: str = "truth"  # a name in diagrams.perception_sources.SOURCES: truth, ct_ekf, paper_ekf, ...
    # The truth's view (source truth, and the true relative state's flag): a cone about -z_B.
    field_of_view_deg: float = 150.0  # full angle; seed 003's fisheye (Sec. 2.1)
    max_range_m: float = 30.0  # not in the paper

    def validate(self, prefix: str = "perception") -> None:
        perception_source(self.source, f"{prefix}.source")
        SeamConfig.validate(self, prefix)
        require(0 < self.field_of_view_deg <= 180, f"{prefix}.field_of_view_deg must be in (0, 180]")
        require_positive(self.max_range_m, f"{prefix}.max_range_m")


def default_marker_camera() -> CameraConfig:
    """The project's downward camera (systems/sensors/camera.py: 512 px, 58 deg, 0.04 m under the
    body, optical axis down) at one frame per filter step T_s = 35 ms, with the pixel noise of the
    Stewart scenes (2 levels)."""
    return CameraConfig(rate_hz=1.0 / MarkerEkfConfig.period_s, pixel_noise_std=2.0)


@dataclass
class MarkerEstimationConfig:
    """The marker measurement stream and the filters on it (seed 002 Sec. 3-4).

    source "none": no stream (the truth steers). "synthetic": the paper's (Sec. 4): every marker's
    true pose in the camera plus sigma_p_m / sigma_deg noise. "detector": the camera renders the
    scene, OpenCV's ArUco detector finds the markers and solvePnP gives each one's pose.
    Every sample reaches the filters `latency_periods` filter steps after it was taken."""

    source: str = "none"  # one of MEASUREMENT_SOURCES
    filters: list[str] = field(default_factory=list)  # filters that watch (names in FILTERS)
    sigma_p_m: float = 0.1  # seed 002 Sec. 4 (synthetic source)
    sigma_deg: float = 5.0  # seed 002 Sec. 4 (synthetic source)
    latency_periods: int = 1  # seed 002 Sec. 4: 25 ms acquire + 10 ms process = one T_s late
    settle_s: float = 2.0  # the filters' errors are taken from this time on (start-up left out)
    camera: CameraConfig = field(default_factory=default_marker_camera)  # its mount for both sources
    ekf: MarkerEkfConfig = field(default_factory=MarkerEkfConfig)  # shared by every filter (T_s = 35 ms)

    def validate(self, prefix: str = "estimation") -> None:
        require(self.source in MEASUREMENT_SOURCES,
                f"{prefix}.source '{self.source}' is not one of: {', '.join(MEASUREMENT_SOURCES)}")
        require(all(f in FILTERS for f in self.filters) and len(set(self.filters)) == len(self.filters),
                f"{prefix}.filters must be different names from: {', '.join(FILTERS)}")
        require(not self.filters or self.source != "none",
                f"{prefix}.filters need a measurement stream: set {prefix}.source to synthetic or detector")
        require(self.sigma_p_m >= 0 and self.sigma_deg >= 0, f"{prefix}.sigma_p_m and sigma_deg must not be negative")
        require(self.latency_periods >= 0, f"{prefix}.latency_periods must not be negative")
        require(self.settle_s >= 0, f"{prefix}.settle_s must not be negative")
        self.camera.validate(f"{prefix}.camera")
        self.ekf.validate(f"{prefix}.ekf")
        require(abs(self.camera.period_s - self.ekf.period_s) < 1e-9,
                f"{prefix}.camera.rate_hz ({self.camera.rate_hz:g}) must be 1 / {prefix}.ekf.period_s "
                f"({1 / self.ekf.period_s:g} Hz): the camera gives one frame per filter step")

    def check_history(self, filter_names: list[str], prefix: str = "estimation") -> None:
        """The marker filters in the diagram (those that watch and the one that steers) take a sample
        latency_s late only while it lies within ekf.history_s."""
        require(not filter_names or self.latency_s <= self.ekf.history_s + 1e-9,
                f"{prefix}.ekf.history_s ({self.ekf.history_s:g} s) must be at least the stream's latency, "
                f"{prefix}.latency_periods x the filter step ({self.latency_s:g} s): every sample would arrive "
                "too late")

    @property
    def X_BC(self) -> RigidTransform:
        """The camera C in the UAV body B: optical axis down (+z_C = -z_B), +x_C = +x_B."""
        return self.camera.X_BC

    @property
    def latency_s(self) -> float:
        return self.latency_periods * self.ekf.period_s


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
class IntegrationConfig:
    """How the vehicles' continuous dynamics (seed 002 Eq. 6-8) are integrated.

    discrete (the default): each vehicle integrates its equations over each flight-controller period
    in C++ (systems/vehicles/integration.py) with `scheme`, its input held over the period (the rotor
    commands are held so anyway); the diagram then has no continuous state, so the simulator never
    evaluates whole-diagram derivatives (each visits every Python LeafSystem).
    discrete false: the simulator integrates the diagram with `scheme` (for comparison)."""

    discrete: bool = True
    # Drake's RK5, one fixed 5 ms step per controller period: its error over a period matches seed
    # 002's RK4 at 1 ms (benchmarks/landing_sweep.py measures both).
    scheme: str = "runge_kutta5"  # one of INTEGRATION_SCHEMES
    max_step_s: float = 0.005
    error_control: bool = False  # fixed steps (error control restarts from a small step every period)
    accuracy: float = 1e-6  # with error_control

    def validate(self, prefix: str = "integration") -> None:
        require(self.scheme in INTEGRATION_SCHEMES,
                f"{prefix}.scheme '{self.scheme}' is not one of {', '.join(INTEGRATION_SCHEMES)}")
        require_positive(self.max_step_s, f"{prefix}.max_step_s")
        require(0 < self.accuracy < 1, f"{prefix}.accuracy must be in (0, 1)")

    @property
    def stable_step_ratio(self) -> float:
        """The largest step over time constant, h / tau, at which `scheme` integrates y' = -y / tau stably
        (EXPLICIT_STABILITY_LIMITS): inf for an implicit scheme, or one under error control (it shortens its
        steps to its accuracy)."""
        fixed = not self.error_control or self.scheme in FIXED_STEP_SCHEMES
        return EXPLICIT_STABILITY_LIMITS.get(self.scheme, np.inf) if fixed else np.inf

    def simulator_config(self) -> SimulatorConfig:
        return SimulatorConfig(integration_scheme=self.scheme, max_step_size=self.max_step_s,
                               use_error_control=self.error_control, accuracy=self.accuracy)

    def diagram_integrator(self) -> SimulatorConfig | None:
        """What the Simulator integrates the diagram with: None when the vehicles are discrete (they step
        themselves; the Simulator only advances events), else `simulator_config`."""
        return None if self.discrete else self.simulator_config()


def table1_airframe() -> AirframeConfig:
    """Visual airframe matching seed 002 Table 1's arms (rotors at l1 = l2 = 0.25 m)."""
    return AirframeConfig(body_size_m=0.2, body_height_m=0.08, rotor_arm_m=float(np.hypot(0.25, 0.25)),
                          propeller_radius_m=0.12)


@dataclass
class FlightConfig:
    """The sections of every landing scenario's flight (diagrams/flight_stack.py's): the quadrotor, its
    flight controller, seed 003's PID and landing procedure, the start, the referee and the integration."""

    quadrotor: QuadrotorParams = field(default_factory=QuadrotorParams)
    controller: FlightControllerConfig = field(default_factory=FlightControllerConfig)
    # The flight controller's backend (systems/control/flight_controller.py): "symbolic" (C++, the
    # default) or "python" (the same law in a LeafSystem).
    controller_implementation: str = "symbolic"
    pid: TrackingPidConfig = field(default_factory=TrackingPidConfig)
    landing: LandingConfig = field(default_factory=LandingConfig)
    start: StartConfig = field(default_factory=StartConfig)
    termination: TerminationConfig = field(default_factory=TerminationConfig)
    integration: IntegrationConfig = field(default_factory=IntegrationConfig)
    uav: AirframeConfig = field(default_factory=table1_airframe)  # visual only

    def validate(self) -> None:
        for name in ("quadrotor", "pid", "landing", "start", "termination", "integration", "uav"):
            getattr(self, name).validate(name)
        self.controller.validate("controller", self.quadrotor)
        require(self.controller_implementation in BACKENDS,
                f"controller_implementation '{self.controller_implementation}' is not one of {', '.join(BACKENDS)}")
        # The loops nest (diagrams/flight_stack.py): the supervisor reads the PID's command at landing.rate_hz (also
        # the log's rate), the flight controller the supervisor's at controller.rate_hz; a slower reader skips samples.
        require(self.controller.rate_hz >= self.landing.rate_hz >= self.pid.rate_hz,
                f"the loops must nest, controller.rate_hz >= landing.rate_hz >= pid.rate_hz: they are "
                f"{self.controller.rate_hz:g}, {self.landing.rate_hz:g} and {self.pid.rate_hz:g} Hz")
        # The monitor ends a run above termination.max_altitude_m as diverged: at t = 0, or on the climb to IH.
        max_altitude = self.termination.max_altitude_m
        require(self.start.height_m <= max_altitude,
                f"start.height_m ({self.start.height_m:g} m) is above termination.max_altitude_m ({max_altitude:g} m): "
                "the run would end at t = 0")
        require(self.landing.initial_height_m < max_altitude,
                f"landing.initial_height_m (IH, {self.landing.initial_height_m:g} m above the ground) must be below "
                f"termination.max_altitude_m ({max_altitude:g} m): the climb to IH would end the run")
        require(self.landing.motors_stop_at_landed or self.termination.stop_on_landed,
                "landing.touchdown_by contact descends until the gear touches, and termination.stop_on_landed "
                "is false: the run would fly on through the pad")

    @property
    def period_s(self) -> float:
        """The flight controller's sample period, over which the discrete vehicles integrate."""
        return 1.0 / self.controller.rate_hz


@dataclass
class GvLandingConfig(FlightConfig):
    seed: int = 0  # of every noise source (measurements, pixels)
    vehicle: GroundVehicleConfig = field(default_factory=GroundVehicleConfig)
    platform: PlatformConfig = field(default_factory=PlatformConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    estimation: MarkerEstimationConfig = field(default_factory=MarkerEstimationConfig)
    federated: FederatedPerceptionConfig = field(default_factory=FederatedPerceptionConfig)
    hybrid: HybridPerceptionConfig = field(default_factory=HybridPerceptionConfig)  # perception.source hybrid
    wind: WindConfig = field(default_factory=WindConfig)  # calm by default
    faults: FaultsConfig = field(default_factory=FaultsConfig)  # in the marker stream; none by default
    navigation: NavigationConfig = field(default_factory=NavigationConfig)  # the UAV's own; the truth by default
    rendezvous: RendezvousConfig = field(default_factory=RendezvousConfig)  # the vehicle's broadcast; none by default
    distractors: DistractorsConfig = field(default_factory=DistractorsConfig)  # other vehicles; none by default
    bridge: BridgeConfig = field(default_factory=BridgeConfig)  # an occluder over the path; none by default

    def validate(self) -> None:
        FlightConfig.validate(self)
        for name in ("vehicle", "platform", "perception", "estimation", "federated", "hybrid", "wind", "faults",
                     "navigation", "rendezvous", "distractors", "bridge"):
            getattr(self, name).validate(name)
        self.estimation.check_history(self.filter_names)
        self._validate_steering_lag()
        path = make_path(self.vehicle.path_config(), "vehicle.path")
        self.distractors.check_lanes(path, f"vehicle.path '{self.vehicle.path}'")
        self._validate_start(path)
        if self.bridge.enabled:
            self._validate_bridge()
        if self.platform.carrier == "ground":
            self._validate_vehicle_at_rest()
        require(self.navigation.source == "truth" or self.perception.source != "federated",
                "perception.source federated drives its IMU from the UAV's pose: navigation.source must be truth")
        require(not self.faults.active or self.estimation.source != "none",
                "faults act on the marker stream, and estimation.source is none: set it to synthetic or detector")
        self.faults.check_period(self.estimation.ekf.period_s)
        require(self.wind.is_calm or self.quadrotor.rotor_drag_coefficient > 0,
                "wind acts on the quadrotor through its rotor drag, and quadrotor.rotor_drag_coefficient is 0 "
                "(seed 002's model): set it (RotorS's is 8.06428e-5)")
        source, stream = perception_source(self.perception.source), self.estimation.source
        require_offered(self.perception.source, "perception.source",
                        "estimation.source is none: set estimation.source to synthetic or detector"
                        if stream == "none" else None,
                        f"estimation.source is {stream}: set estimation.source to detector"
                        if source.camera is None and stream != "detector" else None)
        require(source.camera is None or stream != "detector",
                f"perception.source '{self.perception.source}' brings its own camera: estimation.source detector "
                f"would add a second one")
        if self.perception.source == "federated":
            require(self.platform.pattern == "rqrlp",
                    "perception.source federated looks for seed 001's pattern: set platform.pattern to rqrlp")
        if self.perception.source == "hybrid":
            require(self.platform.carrier == "vehicle",
                    "perception.source hybrid detects the UGV: platform.carrier must be vehicle")
        require(stream == "none" or self.platform.pattern == "markers",
                f"estimation.source {stream} measures the ArUco markers, and platform.pattern is "
                f"{self.platform.pattern}")

    def _validate_steering_lag(self) -> None:
        """The vehicle's steering lag, theta' = (command - theta) / tau_s, linear in theta with its command held over
        a step, is integrated stably only for steps h < stable_step_ratio tau_s; the steps end at every controller
        period, the vehicles discrete or not, so h is max_step_s or that period where it is shorter."""
        integration, tau = self.integration, self.vehicle.steering_time_constant_s
        step = min(integration.max_step_s, self.period_s)
        shortest = step / integration.stable_step_ratio
        require(tau > shortest,
                f"vehicle.steering_time_constant_s ({tau:g} s) must exceed {shortest:.3g} s: integration.scheme "
                f"{integration.scheme}'s fixed {step:g} s steps (integration.max_step_s, at most the controller "
                f"period) are unstable on a lag under step / {integration.stable_step_ratio:g}; lengthen the lag or "
                f"shorten integration.max_step_s")

    def _validate_start(self, path: Path) -> None:
        """The UAV starts outside the vehicle's body and within termination.max_distance_m of the pad, where the
        vehicle starts (the monitor's tests: else the run ends at t = 0)."""
        vehicle = initial_state(path, self.vehicle)
        start = self.start
        require(not inside_carrier(self.platform, [*start.xy_m, start.height_m], vehicle),
                f"start.xy_m {list(start.xy_m)} at start.height_m ({start.height_m:g} m) is inside the ground "
                "vehicle's body (platform's body_length_m, body_width_m, rear_overhang_m, height_m) where it starts")
        distance = float(np.hypot(*(self.platform.X_WP(vehicle).translation()[0:2] - np.asarray(start.xy_m))))
        require(distance <= self.termination.max_distance_m,
                f"start.xy_m {list(start.xy_m)} is {distance:.1f} m from the pad, beyond "
                f"termination.max_distance_m ({self.termination.max_distance_m:g} m)")

    def _validate_vehicle_at_rest(self) -> None:
        """platform.carrier ground: the pad lies on the ground where the vehicle starts, so the vehicle stays there."""
        vehicle = self.vehicle
        if vehicle.speed_schedule_times_s:  # the schedule replaces vehicle.speed
            moving = max(vehicle.speed_schedule_m_s) > 0
            what = f"vehicle.speed_schedule_m_s reaches {max(vehicle.speed_schedule_m_s):g} m/s"
        else:
            moving, what = vehicle.speed > 0, f"vehicle.speed is {vehicle.speed:g} m/s"
        require(not moving, f"platform.carrier ground lays the pad alone on the ground with the vehicle at rest, and "
                            f"{what}: set platform.carrier vehicle to carry the pad, or stop the vehicle")

    def _validate_bridge(self) -> None:
        """The vehicle fits under the bridge and between its piers, and an open path reaches it."""
        bridge, platform = self.bridge, self.platform
        require(bridge.clearance_m > platform.height_m,
                f"bridge.clearance_m ({bridge.clearance_m:g} m) must exceed the vehicle's height "
                f"(platform.height_m, {platform.height_m:g} m): it drives under the bridge")
        require(bridge.gap_m > platform.body_width_m,
                f"the bridge's piers leave {bridge.gap_m:g} m (bridge.width_m - 2 bridge.pier_m) for the vehicle, "
                f"narrower than its body (platform.body_width_m, {platform.body_width_m:g} m)")
        path = make_path(self.vehicle.path_config(), "vehicle.path")
        require(path.closed or bridge.at_m <= path.length,
                f"bridge.at_m ({bridge.at_m:g} m) is beyond the end of the vehicle's {self.vehicle.path} path "
                f"({path.length:g} m)")

    def camera(self):
        """The scene's camera (CameraConfig), or None: estimation.source detector's, or the one the
        perception source brings."""
        own = perception_source(self.perception.source).camera
        if own is not None:
            return own(self)
        return self.estimation.camera if self.estimation.source == "detector" else None

    @property
    def has_video(self) -> bool:
        """Whether --video has a stream to record: the scene's camera, or the perception source's own."""
        return self.camera() is not None or perception_source(self.perception.source).records_video

    @property
    def pad_size_m(self) -> float:
        """The side of the square landed on: the pad's."""
        return self.platform.pad_size_m

    @property
    def filter_names(self) -> list[str]:
        """The marker filters in the diagram: those that watch and the one that steers."""
        names = list(self.estimation.filters)
        if self.perception.source in FILTERS and self.perception.source not in names:
            names.append(self.perception.source)
        return names
