"""gv-marker-ekf: seed 002 section 4, the pose of the landing platform on a ground vehicle
estimated from five ArUco markers by the paper's EKF and by our constant-turn EKF, side by side.

    landing-sim run gv-marker-ekf --set vehicle.speed=6 [--meshcat] [--record]
    landing-sim run gv-marker-ekf --set estimation.source=detector [--video]   # the rendered camera

The scene (scenarios/gv-marker-ekf.yaml). The vehicle drives Eq. (13)'s sine path at
`vehicle.speed` (C1 = 3, C2 = 6, C3 = 12 m/s); the pad's top is 1.6 m above the ground. The UAV
starts hovering at (0, 0, 10) m (`start.height_m`), follows the vehicle and descends to 0.4 m above
the pad, where it holds: this is the gv-landing diagram (diagrams/gv_landing.py, perfect
perception) added through its public `add_gv_landing`, its supervisor's initial height IH set to
2.0 m (0.4 m above the pad) and `landing.centred_radius_m` to 1e-6 m: after TAKEOFF, CLIMB takes
it down to IH while tracking the pad, and FOLLOW then tracks and holds that altitude; APPROACH,
landing and touchdown never come. Vehicle and UAV integrate their
equations with Drake's RK5 over each 5 ms controller period (gv_landing.IntegrationConfig: its
error matches seed 002's RK4 at h = 1 ms). The UAV steers on the TRUE relative state; the filters
only watch.

Run length: `duration_s: 0` (the default) means 500 m of driving, one period of Eq. (13)'s long
wave in distance: 500 / speed seconds, 166.7 s at 3 m/s, 83.3 s at 6 and 41.7 s at 12.

Measurements, two interchangeable sources (`estimation.source`), one `MarkerStream` each. The five
markers are `platform.markers` (systems/perception/markers.py), textured on the pad.
- "synthetic", the paper's (section 4): at every T_s = 35 ms sample t_k the camera "acquires" the
  pose of each marker in the camera frame, the truth plus zero-mean Gaussian noise (0.1 m per axis,
  5 deg per axis of a rotation vector), exactly as `synthetic_marker_measurements` does, but drawn
  for the whole run at once (vectorised, `synthetic_stream`).
- "detector", the real pipeline: the downward camera (`estimation.camera`, at one frame per T_s,
  with seeded pixel noise) on the UAV renders the gv-landing scene (`build_marker_flight`) and
  `MarkerDetectorSystem` finds the markers (OpenCV ArUco) and solves each one's pose (solvePnP);
  a marker not detected at t_k is not measured. The camera's 58 deg view loses the pad while the
  UAV, starting at 10 m, catches up with the vehicle (at 6 m/s from 0.3 to 2.3 s), and sees only
  the centre marker once it holds 0.4 m above it: the filters coast and use the markers they get.
Each run's metrics carry the source's own accuracy per marker (`measurement_metrics`).

Latency: seed 002 budgets 25 ms to acquire and 10 ms to process a frame, so the measurements of
t_k reach the filters at t_{k+1} (`estimation.latency_periods: 1`); the filters fuse them at their
acquisition time (their history re-run) and their estimate at t_{k+1} is compared with the truth
at t_{k+1}. Both filters get the IDENTICAL list of MarkerMeasurement objects at every step.

Truth and noise are separate: the flight depends on the scenario, not on the measurement noise
(perfect perception steers the UAV), so with the synthetic source `fly_truth` simulates it once per
scenario settings and caches it in the process (`truth_cache_key`: the scenario without its seed and
estimation settings); each run then draws its stream from one numpy Generator seeded by the
scenario's seed and runs both filters over it. This is what makes the Monte Carlo campaign
(diagrams/gv_marker_ekf_mc.py) cheap: a worker simulates each speed once, not once per run. The
detector's stream comes from the flight itself (`fly` with the camera), once per run.

Errors are estimate minus truth over the valid estimates after `estimation.settle_s` (the first
filter steps, from an unknown velocity, are left out; so are the steps where a filter coasting
without measurements flags its estimate invalid): the pad frame P's position (the paper's S_P, at marker 0), its
heading (yaw; roll and pitch are zero for both filters and the truth), and each marker's centre.
"""

import dataclasses
import time
from dataclasses import dataclass, field

import matplotlib.colors
import matplotlib.pyplot as plt
import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Rgba
from pydrake.math import RigidTransform
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorStatus
from pydrake.systems.framework import Diagram, DiagramBuilder
from tqdm import tqdm

from diagrams.gv_landing import GvLandingConfig, GvLandingHandles, StartConfig, add_gv_landing, path_polyline
from diagrams.metrics import axis_errors
from diagrams.outputs import save_figure, write_npz
from diagrams.scenario import RunSettings
from systems.config import ConfigError, require, require_positive
from systems.estimators.marker_ekf import FILTERS, MarkerEkfConfig
from systems.perception.markers import MarkerDetectorSystem, MarkerLayout, MarkerMeasurement
from systems.sensors.camera import CameraConfig, add_camera, add_renderer
from systems.sensors.video import VideoRecorder
from systems.geometry import wrap_angle
from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE

LONG_WAVE_M = 500.0  # seed 002 Eq. (13): the long wave's period in x


SOURCES = ("synthetic", "detector")


def default_marker_camera() -> CameraConfig:
    """The project's downward camera (systems/sensors/camera.py: 512 px, 58 deg, 0.04 m under the
    body, optical axis down) at one frame per filter step T_s = 35 ms, with the pixel noise of the
    Stewart scenes (2 levels)."""
    return CameraConfig(rate_hz=1.0 / MarkerEkfConfig.period_s, pixel_noise_std=2.0)


@dataclass
class MarkerEstimationConfig:
    """The measurement source and the filters (seed 002 Sec. 3-4).

    source "synthetic": the paper's measurements (Sec. 4), truth plus sigma_p_m / sigma_deg noise.
    source "detector": the camera renders the scene, OpenCV's ArUco detector finds the markers
    and solvePnP gives each one's pose; a marker not detected is not measured."""

    filters: list[str] = field(default_factory=lambda: ["paper_ekf", "ct_ekf"])  # names in FILTERS
    source: str = "synthetic"  # one of SOURCES
    sigma_p_m: float = 0.1  # seed 002 Sec. 4 (synthetic source)
    sigma_deg: float = 5.0  # seed 002 Sec. 4 (synthetic source)
    latency_periods: int = 1  # seed 002 Sec. 4: 25 ms acquire + 10 ms process = one T_s late
    settle_s: float = 2.0  # errors are taken from this time on (filter start-up left out)
    camera: CameraConfig = field(default_factory=default_marker_camera)  # its mount for both sources
    ekf: MarkerEkfConfig = field(default_factory=MarkerEkfConfig)  # shared by both filters (T_s = 35 ms)

    def validate(self, prefix: str = "estimation") -> None:
        require(len(self.filters) >= 1 and all(f in FILTERS for f in self.filters)
                and len(set(self.filters)) == len(self.filters),
                f"{prefix}.filters must be different names from: {', '.join(FILTERS)}")
        require(self.source in SOURCES, f"{prefix}.source '{self.source}' is not one of: {', '.join(SOURCES)}")
        require(self.sigma_p_m >= 0 and self.sigma_deg >= 0, f"{prefix}.sigma_p_m and sigma_deg must not be negative")
        require(self.latency_periods >= 0, f"{prefix}.latency_periods must not be negative")
        require(self.settle_s >= 0, f"{prefix}.settle_s must not be negative")
        self.camera.validate(f"{prefix}.camera")
        self.ekf.validate(f"{prefix}.ekf")
        require(abs(self.camera.period_s - self.ekf.period_s) < 1e-9,
                f"{prefix}.camera.rate_hz ({self.camera.rate_hz:g}) must be 1 / {prefix}.ekf.period_s "
                f"({1 / self.ekf.period_s:g} Hz): the camera gives one frame per filter step")

    @property
    def X_BC(self) -> RigidTransform:
        """The camera C in the UAV body B: optical axis down (+z_C = -z_B), +x_C = +x_B."""
        return self.camera.X_BC


@dataclass
class Scenario(RunSettings, GvLandingConfig):
    """A gv-marker-ekf scenario file: the gv-landing flight plus the estimation settings.
    duration_s 0: 500 m of driving (LONG_WAVE_M / vehicle.speed)."""

    diagram: str = "gv_marker_ekf"
    start: StartConfig = field(default_factory=lambda: StartConfig(xy_m=[0.0, 0.0], height_m=10.0))  # seed 002 r_0
    duration_s: float = 0.0
    estimation: MarkerEstimationConfig = field(default_factory=MarkerEstimationConfig)

    def validate(self) -> None:
        require(self.duration_s >= 0, "duration_s must not be negative (0: 500 m of driving)")
        require_positive(self.vehicle.speed, "vehicle.speed")
        require(not self.vehicle.speed_schedule_times_s, "vehicle.speed_schedule_* is not used by gv-marker-ekf")
        GvLandingConfig.validate(self)
        self.estimation.validate()
        require(self.platform.height_m < self.start.height_m and self.landing.initial_height_m < self.start.height_m,
                f"platform.height_m and landing.initial_height_m must be below start.height_m ({self.start.height_m} m)")

    @property
    def run_length_s(self) -> float:
        return self.duration_s if self.duration_s > 0 else LONG_WAVE_M / self.vehicle.speed

    @property
    def sample_times(self) -> np.ndarray:
        """The filter steps t_k = k T_s up to the run length."""
        ts = self.estimation.ekf.period_s
        return np.arange(int(np.floor(self.run_length_s / ts + 1e-9)) + 1) * ts


# ----------------------------------------------------------------------------------------------
# Truth: the flight, once per scenario settings


@dataclass(frozen=True)
class Truth:
    """The flight sampled at the filter steps t (N): UAV p_WB (N, 3) and quaternion q_WB (N, 4,
    Drake's w, x, y, z), pad p_WP (N, 3) (P at the pad top's centre, marker 0) and its heading
    yaw (N); the vehicle's state (N, 4); the supervisor's status line at the end."""

    t: np.ndarray
    p_WB: np.ndarray
    q_WB: np.ndarray
    p_WP: np.ndarray
    yaw: np.ndarray
    vehicle_state: np.ndarray
    status: str
    wall_time_s: float


def truth_cache_key(scenario: Scenario) -> str:
    """What the flight depends on: the scenario without its seed, description and estimation
    settings (the filter period stays: it sets the samples)."""
    data = dataclasses.asdict(scenario)
    for key in ("seed", "description", "estimation"):
        data.pop(key, None)
    return repr((data, scenario.estimation.ekf.period_s, scenario.run_length_s))


_TRUTH_CACHE: dict[str, Truth] = {}
_TRUTH_CACHE_SIZE = 4


@dataclass
class MarkerFlightHandles:
    """The gv-landing systems, plus with the camera the marker detector on its images and a video
    recorder of them."""

    gv: GvLandingHandles
    detector: MarkerDetectorSystem | None = None
    video: VideoRecorder | None = None

    @property
    def meshcat_visualizer(self):
        return self.gv.meshcat_visualizer


def build_marker_flight(scenario: Scenario, meshcat=None, camera: bool = False,
                        video_path=None) -> tuple[Diagram, MarkerFlightHandles]:
    """The gv-landing flight; with `camera`, the downward camera (estimation.camera, pixel noise
    seeded by scenario.seed) on the airframe's body frame renders the scene (ground, vehicle, the
    pad with platform.markers) and `MarkerDetectorSystem` reads its images; `video_path` records them."""
    builder = DiagramBuilder()
    handles = MarkerFlightHandles(add_gv_landing(builder, scenario, meshcat))
    if camera:
        config, gv = scenario.estimation.camera, handles.gv
        add_renderer(gv.scene_graph)
        _, noisy_camera = add_camera(builder, gv.scene_graph, gv.airframe.body_frame_id, config, scenario.seed)
        handles.detector = builder.AddNamedSystem("marker_detector", MarkerDetectorSystem(
            config.K, scenario.platform.markers, config.width, config.height))
        builder.Connect(noisy_camera.get_output_port(), handles.detector.get_input_port())
        if video_path is not None:
            handles.video = builder.AddSystem(VideoRecorder(video_path, config.period_s, config.width, config.height))
            builder.Connect(noisy_camera.get_output_port(), handles.video.get_input_port())
    diagram = builder.Build()
    diagram.set_name("gv_marker_ekf")
    return diagram, handles


def fly(scenario: Scenario, meshcat=None, camera: bool = False, realtime: bool = False, progress: bool = False,
        record: bool = False, video_path=None) -> tuple[Truth, "MarkerStream | None", MarkerFlightHandles]:
    """Simulates the flight and samples it at the filter steps: (truth, the camera's detections at
    the same steps when `camera`, else None, the handles). `record` records it in Meshcat."""
    diagram, handles = build_marker_flight(scenario, meshcat, camera, video_path)
    gv = handles.gv
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    gv.initialize(context)  # the UAV hovering at start.height_m: seed 002 Sec. 4's r_0 = (0, 0, 10) m
    if not scenario.integration.discrete:
        ApplySimulatorConfig(scenario.integration.simulator_config(), simulator)
    if realtime:
        simulator.set_target_realtime_rate(1.0)
    quad_port, vehicle_port = gv.quadrotor.GetOutputPort("state"), gv.vehicle.GetOutputPort("state")
    quad_ctx, vehicle_ctx = gv.quadrotor.GetMyContextFromRoot(context), gv.vehicle.GetMyContextFromRoot(context)
    times = scenario.sample_times
    layout = scenario.platform.markers
    quad_states, vehicle_states = np.empty((len(times), STATE_SIZE)), np.empty((len(times), 4))
    p_CM, q_CM = np.full((len(times), len(layout.ids), 3), np.nan), np.full((len(times), len(layout.ids), 4), np.nan)
    detector_ctx = handles.detector.GetMyContextFromRoot(context) if camera else None
    status = (f"held {scenario.landing.initial_height_m - scenario.platform.height_m:.2g} m above the pad "
              f"for the run ({times[-1]:.1f} s)")
    if handles.meshcat_visualizer is not None and record:
        handles.meshcat_visualizer.StartRecording()
    start = time.perf_counter()
    try:
        simulator.Initialize()
        for k, t in enumerate(tqdm(times, disable=not progress, leave=False, unit="step")):
            if t > 0:
                result = simulator.AdvanceTo(t)
                if result.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                    raise RuntimeError(f"the flight ended at t = {context.get_time():.2f} s: {result.message()}")
            quad_states[k] = quad_port.Eval(quad_ctx)
            vehicle_states[k] = vehicle_port.Eval(vehicle_ctx)[:4]
            if camera:
                for m in handles.detector.get_output_port().Eval(detector_ctx):
                    i = layout.index(m.marker_id)
                    p_CM[k, i], q_CM[k, i] = m.p_CM, m.q_CM
    except BaseException:
        if handles.video is not None:
            handles.video.discard()
        raise
    wall = time.perf_counter() - start
    if handles.meshcat_visualizer is not None and record:
        handles.meshcat_visualizer.StopRecording()
        handles.meshcat_visualizer.PublishRecording()
    heading = vehicle_states[:, 2]
    offset = scenario.platform.pad_offset_m
    p_WP = np.column_stack([vehicle_states[:, 0] + offset * np.cos(heading),
                            vehicle_states[:, 1] + offset * np.sin(heading),
                            np.full(len(times), scenario.platform.height_m)])
    q = quad_states[:, Q_WB]
    truth = Truth(times, quad_states[:, P_WB].copy(), q / np.linalg.norm(q, axis=1, keepdims=True), p_WP,
                  np.unwrap(heading), vehicle_states, status, wall)
    return truth, (MarkerStream(times, p_CM, q_CM) if camera else None), handles


def fly_truth(scenario: Scenario, cache: bool = True) -> Truth:
    """The flight's truth without a camera, from this process's cache when it has flown these
    settings (`truth_cache_key`) before."""
    key = truth_cache_key(scenario)
    if cache and key in _TRUTH_CACHE:
        return _TRUTH_CACHE[key]
    truth = fly(scenario)[0]
    if cache:
        if len(_TRUTH_CACHE) >= _TRUTH_CACHE_SIZE:
            _TRUTH_CACHE.pop(next(iter(_TRUTH_CACHE)))
        _TRUTH_CACHE[key] = truth
    return truth


# ----------------------------------------------------------------------------------------------
# Measurements: the paper's synthetic source vectorised over the run, or the camera's detections


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions [w, x, y, z] (Drake's order): R(a b) = R(a) R(b)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of unit quaternions (..., 4) [w, x, y, z]."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


@dataclass(frozen=True)
class MarkerStream:
    """Measurements of the markers at every sample: p_CM (N, n, 3) [m] and q_CM (N, n, 4) (the
    paper's scalar-last q^{M/C}), acquired at t (N); NaN where a marker was not measured (not
    detected)."""

    t: np.ndarray
    p_CM: np.ndarray
    q_CM: np.ndarray


def true_marker_positions(truth: Truth, layout: MarkerLayout) -> np.ndarray:
    """(N, n, 3) marker centres in W."""
    c, s = np.cos(truth.yaw), np.sin(truth.yaw)
    p = layout.p_PM
    return truth.p_WP[:, None, :] + np.stack([c[:, None] * p[:, 0] - s[:, None] * p[:, 1],
                                              s[:, None] * p[:, 0] + c[:, None] * p[:, 1],
                                              np.broadcast_to(p[:, 2], (len(c), len(p)))], axis=-1)


def true_marker_poses_C(truth: Truth, layout: MarkerLayout, X_BC: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """Every marker's true pose in the camera frame C at every sample: p_CM (N, n, 3) [m] and q_CP
    (N, 4), Drake's [w, x, y, z] of R_CP, every marker's attitude (they are aligned with P)."""
    N = len(truth.t)
    q_BC = np.array(X_BC.rotation().ToQuaternion().wxyz())
    R_WB = quat_to_matrix(truth.q_WB)
    q_WC = quat_multiply(truth.q_WB, q_BC)
    p_WC = truth.p_WB + R_WB @ X_BC.translation()
    half = truth.yaw / 2
    q_WP = np.column_stack([np.cos(half), np.zeros(N), np.zeros(N), np.sin(half)])
    q_CP = quat_multiply(q_WC * np.array([1, -1, -1, -1]), q_WP)
    p_WM = true_marker_positions(truth, layout)
    R_CW = np.swapaxes(quat_to_matrix(q_WC), 1, 2)
    return np.einsum("kij,kmj->kmi", R_CW, p_WM - p_WC[:, None, :]), q_CP


def synthetic_stream(truth: Truth, layout: MarkerLayout, X_BC: RigidTransform, rng: np.random.Generator,
                     sigma_p: float = 0.1, sigma_deg: float = 5.0) -> MarkerStream:
    """Seed 002 Sec. 4 for the whole run: every marker's true pose in C plus noise, as
    `synthetic_marker_measurements` (sigma_p on each axis of p_CM; R_CM = R_CP Exp(dtheta), dtheta
    ~ N(0, sigma_deg^2 I3)), in two draws from `rng`: positions (N, n, 3), then angles (N, n, 3)."""
    N, n = len(truth.t), len(layout.ids)
    p_CM, q_CP = true_marker_poses_C(truth, layout, X_BC)
    p_CM = p_CM + rng.normal(0.0, sigma_p, (N, n, 3))
    dtheta = rng.normal(0.0, np.radians(sigma_deg), (N, n, 3))
    angle = np.linalg.norm(dtheta, axis=-1, keepdims=True)
    dq = np.concatenate([np.cos(angle / 2), np.sinc(angle / (2 * np.pi)) * dtheta / 2], axis=-1)  # [w, x, y, z]
    q = quat_multiply(np.broadcast_to(q_CP[:, None, :], dq.shape), dq)
    return MarkerStream(truth.t, p_CM, np.concatenate([q[..., 1:], q[..., :1]], axis=-1))


def arrivals(stream: MarkerStream, layout: MarkerLayout, k: int, latency_periods: int) -> list[MarkerMeasurement]:
    """The measurements that reach the filters at step k: those acquired at step k - latency, of
    the markers measured then."""
    j = k - latency_periods
    if j < 0:
        return []
    period = float(stream.t[1] - stream.t[0]) if len(stream.t) > 1 else 0.0
    latency = latency_periods * period
    measured = ~np.isnan(stream.p_CM[j, :, 0])
    return [MarkerMeasurement(float(stream.t[j]), marker_id, stream.p_CM[j, i], stream.q_CM[j, i], latency)
            for i, marker_id in enumerate(layout.ids) if measured[i]]


def measurement_metrics(truth: Truth, stream: MarkerStream, layout: MarkerLayout, X_BC: RigidTransform) -> dict:
    """The source's own accuracy, per marker: the share of samples with a measurement, and the RMS
    position error [m] and RMS attitude error [deg] of those measurements against the truth (None
    for a marker never measured)."""
    p_true, q_CP = true_marker_poses_C(truth, layout, X_BC)
    measured = ~np.isnan(stream.p_CM[..., 0])
    position = np.linalg.norm(stream.p_CM - p_true, axis=-1)
    q_CM = np.concatenate([stream.q_CM[..., 3:], stream.q_CM[..., :3]], axis=-1)  # to [w, x, y, z]
    q_CM = q_CM / np.linalg.norm(q_CM, axis=-1, keepdims=True)
    cos_half = np.abs(np.einsum("kmi,ki->km", q_CM, q_CP))
    attitude = np.degrees(2 * np.arccos(np.clip(cos_half, 0.0, 1.0)))

    def rms(errors: np.ndarray) -> list:
        return [float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else None for e, m in zip(errors.T, measured.T)]

    return {"measured_fraction": measured.mean(axis=0).tolist(), "rms_position_m": rms(position),
            "rms_attitude_deg": rms(attitude)}


# ----------------------------------------------------------------------------------------------
# Filters over a stream


@dataclass
class FilterTrace:
    """One filter's estimates at every step (NaN before it starts): p_WP (N, 3), yaw (N),
    p_WM (N, n, 3), valid (N); its counts and its cost per step."""

    p_WP: np.ndarray
    yaw: np.ndarray
    p_WM: np.ndarray
    valid: np.ndarray
    stats: dict
    per_step_ms: float


def run_filters(truth: Truth, stream: MarkerStream, estimation: MarkerEstimationConfig, layout: MarkerLayout,
                inputs_log: list | None = None) -> dict[str, FilterTrace]:
    """Runs every filter of `estimation.filters` over the same stream of `layout`'s markers: at
    each step the same list of measurements (appended to `inputs_log` when given, for tests) and
    the UAV's true pose."""
    filters = {name: FILTERS[name](layout, estimation.X_BC, estimation.ekf) for name in estimation.filters}
    N, n = len(truth.t), len(layout.ids)
    traces = {name: FilterTrace(np.full((N, 3), np.nan), np.full(N, np.nan), np.full((N, n, 3), np.nan),
                                np.zeros(N, bool), {}, 0.0) for name in filters}
    cost = dict.fromkeys(filters, 0.0)
    first = next(iter(filters.values()))
    for k in range(N):
        t = float(truth.t[k])
        X_WB = RigidTransform(Quaternion(truth.q_WB[k]), truth.p_WB[k])
        start = time.perf_counter()
        camera = first.camera_at(X_WB)  # every filter has the camera at estimation.X_BC
        camera_cost = time.perf_counter() - start  # counted in each filter's cost: each needs it
        measurements = arrivals(stream, layout, k, estimation.latency_periods)
        if inputs_log is not None:
            inputs_log.append(measurements)
        for name, f in filters.items():
            start = time.perf_counter() - camera_cost
            f.step(t, X_WB, measurements, camera)
            cost[name] += time.perf_counter() - start
            values = f.estimate_values(t)  # estimate(t)'s figures without its Drake objects
            if values is not None:
                trace = traces[name]
                trace.p_WP[k], trace.yaw[k], trace.p_WM[k], trace.valid[k] = values
    for name, f in filters.items():
        traces[name].stats = dataclasses.asdict(f.stats)
        traces[name].per_step_ms = 1e3 * cost[name] / max(N, 1)
    return traces


@dataclass
class Errors:
    """Estimate minus truth per step (NaN where the filter has not started)."""

    position: np.ndarray  # (N, 3) pad P
    heading: np.ndarray  # (N,) rad
    markers: np.ndarray  # (N, n) norm of each marker's position error


def filter_errors(truth: Truth, trace: FilterTrace, p_WM_true: np.ndarray) -> Errors:
    return Errors(trace.p_WP - truth.p_WP, wrap_angle(trace.yaw - truth.yaw),
                  np.linalg.norm(trace.p_WM - p_WM_true, axis=-1))


def error_metrics(truth: Truth, trace: FilterTrace, errors: Errors, settle_s: float) -> dict:
    """One filter's figures (DESIGN.md's estimator shape plus the seed 002 ones) over its valid
    estimates from settle_s on (a filter coasting without measurements flags its estimate invalid
    once the pad's position std passes MarkerEkfConfig.max_valid_position_std_m); valid_fraction
    is the share of all steps with a valid estimate."""
    window = (truth.t >= settle_s) & trace.valid & np.isfinite(errors.heading)
    e, h, m = errors.position[window], errors.heading[window], errors.markers[window]
    if not window.any():
        return {"valid_fraction": float(np.mean(trace.valid)), "steps": 0, "measurements": trace.stats}
    rpy = np.column_stack([np.zeros_like(h), np.zeros_like(h), np.degrees(h)])
    return {
        "rms_position_m": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
        "rms_position_xy_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
        "rms_heading_deg": float(np.degrees(np.sqrt(np.mean(h**2)))),
        "rms_marker_position_m": np.sqrt(np.mean(m**2, axis=0)).tolist(),
        **axis_errors(e, rpy),
        "max_position_m": float(np.max(np.linalg.norm(e, axis=1))),
        "valid_fraction": float(np.mean(trace.valid)),
        "steps": int(window.sum()),
        "per_frame_ms": trace.per_step_ms,
        "measurements": trace.stats,  # accepted, gated, invalid, too_late, resets
    }


@dataclass
class Estimation:
    """One run's estimation: the stream and its own accuracy (`measurement_metrics`), every
    filter's trace, errors and metrics."""

    truth: Truth
    stream: MarkerStream
    measurements: dict
    traces: dict[str, FilterTrace]
    errors: dict[str, Errors]
    metrics: dict[str, dict]
    wall_time_s: float


def estimate_run(scenario: Scenario, truth: Truth | None = None, stream: MarkerStream | None = None,
                 inputs_log: list | None = None) -> Estimation:
    """One run of both filters. Without `truth`, the flight: with the synthetic source from the
    cache (`fly_truth`), with the detector flown with its camera (its detections are the stream).
    Without `stream`, the synthetic one drawn from default_rng(scenario.seed)."""
    est, layout = scenario.estimation, scenario.platform.markers
    if truth is None and est.source == "detector":
        truth, stream, _ = fly(scenario, camera=True)
    truth = fly_truth(scenario) if truth is None else truth
    start = time.perf_counter()
    if stream is None:
        require(est.source == "synthetic", "the detector's stream comes from a flight with the camera (fly)")
        stream = synthetic_stream(truth, layout, est.X_BC, np.random.default_rng(scenario.seed), est.sigma_p_m,
                                  est.sigma_deg)
    traces = run_filters(truth, stream, est, layout, inputs_log)
    p_WM_true = true_marker_positions(truth, layout)
    errors = {name: filter_errors(truth, trace, p_WM_true) for name, trace in traces.items()}
    metrics = {name: error_metrics(truth, traces[name], errors[name], est.settle_s) for name in traces}
    return Estimation(truth, stream, measurement_metrics(truth, stream, layout, est.X_BC), traces, errors, metrics,
                      time.perf_counter() - start)


# ----------------------------------------------------------------------------------------------
# Plots (seed 002 Fig. 3-5)

FILTER_STYLE = {"paper_ekf": ("tab:red", "paper EKF"), "ct_ekf": ("tab:green", "constant-turn EKF")}


def style(name: str) -> tuple[str, str]:
    return FILTER_STYLE.get(name, ("tab:purple", name))


def plot_path(ax, reference_xy, true_xy, estimates: dict[str, np.ndarray], title: str) -> None:
    """Fig. 3: reference path, true pad path, estimated pad path per filter."""
    near = reference_xy[:, 0] <= np.nanmax(true_xy[:, 0]) + 10.0
    ax.plot(*reference_xy[near].T, "-", color="0.75", lw=4, label="reference (Eq. 13)")
    ax.plot(*true_xy.T, "-", color="k", lw=1.2, label="true (pad P)")
    for name, xy in estimates.items():
        colour, label = style(name)
        ax.plot(*xy.T, "--", color=colour, lw=1, label=f"estimated, {label}")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)


def plot_heading(axes, t, yaw_true, yaws: dict[str, np.ndarray], title: str) -> None:
    """Fig. 4: true and estimated heading, and the error."""
    axes[0].plot(t, np.degrees(wrap_angle(yaw_true)), "-", color="k", lw=1.2, label="true")
    for name, yaw in yaws.items():
        colour, label = style(name)
        axes[0].plot(t, np.degrees(wrap_angle(yaw)), "--", color=colour, lw=1, label=label)
        axes[1].plot(t, np.degrees(wrap_angle(yaw - yaw_true)), "-", color=colour, lw=0.8, label=label)
    axes[0].set_ylabel("heading (deg)")
    axes[1].set_ylabel("error (deg)")
    axes[0].set_title(title)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=7)


def plot_markers(axes, t, marker_errors: dict[str, np.ndarray], ids, title: str, ylabel="error (m)") -> None:
    """Fig. 5: each marker's position error over time, one axis per filter."""
    for ax, (name, err) in zip(axes, marker_errors.items()):
        for i, marker_id in enumerate(ids):
            ax.plot(t, err[:, i], lw=0.8, label=f"marker {marker_id}")
        ax.set_title(f"{title}: {style(name)[1]}", fontsize=9)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=7, ncol=5)


def plot_run(scenario: Scenario, est: Estimation, out_dir) -> None:
    truth = est.truth
    title = f"{scenario.vehicle.speed:g} m/s"
    reference = path_polyline(scenario.vehicle, max_length_m=1e9)
    fig, ax = plt.subplots(figsize=(9, 6))
    plot_path(ax, reference, truth.p_WP[:, :2], {n: tr.p_WP[:, :2] for n, tr in est.traces.items()},
              f"Pad path ({title}, Fig. 3)")
    save_figure(fig, out_dir / "path.png")
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    plot_heading(axes, truth.t, truth.yaw, {n: tr.yaw for n, tr in est.traces.items()}, f"Heading ({title}, Fig. 4)")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "heading.png")
    fig, axes = plt.subplots(len(est.traces), 1, figsize=(10, 3 * len(est.traces)), sharex=True, squeeze=False)
    plot_markers(axes[:, 0], truth.t, {n: e.markers for n, e in est.errors.items()}, scenario.platform.markers.ids,
                 f"Marker position error ({title}, Fig. 5)")
    axes[-1, 0].set_xlabel("time (s)")
    save_figure(fig, out_dir / "marker_errors.png")


# ----------------------------------------------------------------------------------------------
# landing-sim run


def show_estimates(meshcat, est: Estimation) -> None:
    """Each filter's estimated pad path as a line in Meshcat, beside the live scene's UAV trail."""
    for name, trace in est.traces.items():
        p = trace.p_WP[trace.valid]
        if len(p) >= 2:
            colour = matplotlib.colors.to_rgba(style(name)[0])
            meshcat.SetLine(f"gv_marker_ekf/{name}_pad_path", p.T, 2.0, Rgba(*colour))


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.runner import finish_run

    camera = scenario.estimation.source == "detector"
    if ctx.options.video and not camera:
        raise ConfigError("--video records the camera, which only the detector source has "
                          "(--set estimation.source=detector)")
    start = time.perf_counter()
    truth, stream, handles = fly(scenario, ctx.meshcat, camera, realtime=ctx.options.meshcat,
                                 progress=ctx.options.progress, record=ctx.options.record,
                                 video_path=ctx.out_dir / "camera.mp4" if ctx.options.video else None)
    est = estimate_run(scenario, truth, stream)
    if ctx.meshcat is not None:
        show_estimates(ctx.meshcat, est)
    wall = time.perf_counter() - start
    sim_time = float(truth.t[-1])
    source = scenario.estimation
    measurements = {"source": source.source, "period_s": source.ekf.period_s,
                    "latency_s": source.latency_periods * source.ekf.period_s, "settle_s": source.settle_s,
                    **({"pixel_noise_std": source.camera.pixel_noise_std} if camera else
                       {"sigma_p_m": source.sigma_p_m, "sigma_deg": source.sigma_deg}),
                    "marker_ids": scenario.platform.markers.ids, **est.measurements}
    metrics = {
        "scenario": ctx.name, "seed": scenario.seed, "sim_time_s": sim_time, "wall_time_s": wall,
        "realtime_factor": sim_time / wall if wall > 0 else None,
        "vehicle": {"path": scenario.vehicle.path, "speed_m_s": scenario.vehicle.speed,
                    "run_length_s": scenario.run_length_s, "distance_m": scenario.vehicle.speed * sim_time},
        "flight": {"wall_time_s": truth.wall_time_s, "end": truth.status,
                   "final_height_above_pad_m": float(truth.p_WB[-1, 2] - truth.p_WP[-1, 2]),
                   "final_horizontal_offset_m": float(np.linalg.norm(truth.p_WB[-1, :2] - truth.p_WP[-1, :2]))},
        "measurements": measurements,
        "estimators": est.metrics,
    }
    arrays = {"t": truth.t, "p_WB": truth.p_WB, "q_WB": truth.q_WB, "p_WP": truth.p_WP, "yaw": truth.yaw,
              "vehicle_state": truth.vehicle_state, "p_CM": est.stream.p_CM, "q_CM": est.stream.q_CM}
    for name, trace in est.traces.items():
        arrays.update({f"{name}_p_WP": trace.p_WP, f"{name}_yaw": trace.yaw, f"{name}_p_WM": trace.p_WM,
                       f"{name}_valid": trace.valid, f"{name}_marker_error": est.errors[name].markers})
    write_npz(ctx.out_dir / "log.npz", **arrays)
    plot_run(scenario, est, ctx.out_dir)
    seen = ", ".join(f"{i}: {f:.0%}"
                     for i, f in zip(scenario.platform.markers.ids, est.measurements["measured_fraction"]))
    print(f"{ctx.name}: {source.source} measurements, markers measured in {seen} of the frames")
    for name, m in est.metrics.items():
        if "rms_position_m" in m:
            print(f"{ctx.name}: {name}: RMS position {m['rms_position_m']:.3f} m, heading "
                  f"{m['rms_heading_deg']:.2f} deg ({m['measurements']['gated']} gated, "
                  f"{m['measurements']['invalid']} invalid)")
    return finish_run(handles, ctx, metrics)


__all__ = ["Scenario", "MarkerEstimationConfig", "fly", "fly_truth", "synthetic_stream", "run_filters", "estimate_run",
           "ConfigError"]
