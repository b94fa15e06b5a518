"""The colour-pad camera-ToF calibration flight of seed 000 (Sec. 2.3, Fig. 7-15, Tables 1-4).

Four thin discs of one radius lie on a grey floor, one under each ToF sensor, coloured as
PAD_COLOURS assigns them (sensors 1..4: red, yellow, green, blue). The drone starts level at yaw 0
with each sensor's ray through its pad's centre (Fig. 8) and climbs straight up at constant speed,
so every ray keeps hitting its pad's centre. At each camera frame the pads are segmented (Eq. 11,
Table 1), their convex-hull centroids found (Eq. 12-16) and paired with the four range readings;
`PadCalibration.from_frames` fits Eq. 18 and builds the PCHIP interpolant (Eq. 19-20).

    landing-sim run crhf-calibration --out results/cal

leaves pad_calibration.npz (the calibration and the camera, its lens included, and ToF layout flown, as
`PadCalibration.save` writes them; CRHF takes only a flight without a lens), metrics.json, log.npz and plots
like Fig. 14-15 in the output directory.

Heights are those of the camera (and the ToF sensors, which sit in the camera plane, Eq. 21-24)
above the pads' top surface: a height is the true range each sensor reads.
"""

from dataclasses import dataclass, field

import matplotlib.pyplot as plt
import numpy as np
from pydrake.geometry import Box, Cylinder, Meshcat, MeshcatVisualizer, SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from diagrams.metrics import rms_of_finite
from diagrams.outputs import save_figure, write_npz
from diagrams.scenario import RunSettings
from diagrams.stewart_scene import add_uav_sensors, add_viewers
from systems.config import require, require_positive
from systems.estimators.pad_calibration import MIN_SAMPLES, PAD_COLOURS, PAD_RGB, CalibrationFlight, PadCalibration
from systems.geometry import register_visual
from systems.perception.apriltag import project_points
from systems.perception.color_pads import PadCentroidsSystem
from systems.sensors.camera import CameraConfig, NoisyCamera, add_renderer
from systems.sensors.tof import TofConfig, TofSensors, sensor_positions_C
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry, PrescribedPose
from systems.viewers import VideoRecorder

PAD_THICKNESS_M = 0.0005  # thin discs: sheets of coloured card on the floor (a thicker disc shows its rim)
GROUND_SIZE_M = 12.0  # wider than the camera's footprint at any height the ToF sensors reach
GROUND_THICKNESS_M = 0.1
GROUND_RGBA = (0.5, 0.5, 0.5, 1.0)  # mid grey: inside none of Table 1's ranges
MIN_PAD_RADIUS_PX = 5.0  # a pad at the top of the climb must still cover ~80 pixels
PLOT_COLOURS = {"red": "tab:red", "yellow": "darkgoldenrod", "green": "tab:green", "blue": "tab:blue"}


@dataclass
class Scenario(RunSettings):
    """The calibration flight: the drone climbs at `climb_speed_m_s` from `start_height_m` for
    `duration_s`, which may not run past `end_height_m`."""

    diagram: str = "crhf_calibration"
    duration_s: float = 24.0  # (end_height_m - start_height_m) / climb_speed_m_s
    seed: int = 0
    camera: CameraConfig = field(default_factory=CameraConfig)
    tof: TofConfig = field(default_factory=TofConfig)
    uav: AirframeConfig = field(default_factory=AirframeConfig)
    start_height_m: float = 0.3  # seed 000 Table 3: the first frame at 0.305 m
    end_height_m: float = 3.9  # inside the VL53L1X's 4 m long-distance range
    climb_speed_m_s: float = 0.15  # 7.5 mm per frame at 20 Hz
    pad_radius_m: float = 0.05  # Sec. 2.3: "the same radius color pads", one for all four

    @property
    def climb_time_s(self) -> float:
        """Time to climb from start_height_m to end_height_m (s)."""
        return (self.end_height_m - self.start_height_m) / self.climb_speed_m_s

    def validate(self) -> None:
        for name in ("camera", "tof", "uav"):
            getattr(self, name).validate(name)
        require_positive(self.duration_s, "duration_s")
        require_positive(self.climb_speed_m_s, "climb_speed_m_s")
        require_positive(self.pad_radius_m, "pad_radius_m")
        require(self.start_height_m < self.end_height_m,
                f"start_height_m ({self.start_height_m} m) must be below end_height_m ({self.end_height_m} m)")
        require(self.start_height_m >= self.tof.min_range_m,
                f"start_height_m ({self.start_height_m} m) is below tof.min_range_m ({self.tof.min_range_m} m)")
        require(self.start_height_m > self.camera.near_m,
                f"start_height_m ({self.start_height_m} m) must exceed camera.near_m ({self.camera.near_m} m)")
        require(self.end_height_m <= self.tof.max_range_m,
                f"end_height_m ({self.end_height_m} m) is beyond tof.max_range_m ({self.tof.max_range_m} m)")
        period = self.camera.period_s
        require(self.duration_s >= (MIN_SAMPLES - 1) * period,
                f"duration_s ({self.duration_s} s) must cover at least {MIN_SAMPLES} camera frames "
                f"({(MIN_SAMPLES - 1) * period:g} s)")
        require(self.duration_s <= self.climb_time_s + 1e-9,
                f"duration_s ({self.duration_s} s) runs past end_height_m: the climb from start_height_m "
                f"to end_height_m at climb_speed_m_s takes {self.climb_time_s:g} s")
        # The pads: apart from each other, whole in the image at the start, segmentable at the top.
        p_CS = sensor_positions_C(self.tof.arm_m, self.tof.angle_deg)
        gap = min(np.linalg.norm(p_CS[i, :2] - p_CS[(i + 1) % 4, :2]) for i in range(4))
        require(2 * self.pad_radius_m < gap,
                f"pad_radius_m ({self.pad_radius_m} m) makes neighbouring pads overlap (centres {gap:.3f} m apart)")
        c = self.camera
        u = c.fx * (np.abs(p_CS[:, 0]).max() + self.pad_radius_m) / self.start_height_m
        v = c.fy * (np.abs(p_CS[:, 1]).max() + self.pad_radius_m) / self.start_height_m
        require(c.cx - u >= 0 and c.cx + u <= c.width - 1 and c.cy - v >= 0 and c.cy + v <= c.height - 1,
                f"pad_radius_m ({self.pad_radius_m} m), start_height_m ({self.start_height_m} m) or the camera "
                f"(principal point {c.cx:g}, {c.cy:g} px in {c.width} x {c.height}): the pads do not fit in the image "
                f"at the start height (they reach {u:.0f} x {v:.0f} px from the principal point)")
        radius_px = min(c.fx, c.fy) * self.pad_radius_m / self.end_height_m
        require(radius_px >= MIN_PAD_RADIUS_PX,
                f"pad_radius_m ({self.pad_radius_m} m) is too small: at end_height_m a pad would be "
                f"{radius_px:.1f} px in radius, below the {MIN_PAD_RADIUS_PX:g} px segmentation needs")


@dataclass
class CalibrationSceneHandles:
    """The systems and constants of a built calibration scene that callers use."""

    scene_graph: SceneGraph
    airframe: AirframeGeometry
    body: PrescribedPose
    camera: object  # RgbdSensor
    noisy_camera: NoisyCamera
    tof: TofSensors
    pads: PadCentroidsSystem
    loggers: dict[str, VectorLogSink]
    X_BC: RigidTransform
    p_C_sensors: np.ndarray  # (4, 3) sensor origins in C (Eq. 21-24), m
    p_W_pads: np.ndarray  # (4, 3) centres of the pads' top faces in W, m
    meshcat_visualizer: MeshcatVisualizer | None = None
    video: VideoRecorder | None = None

    @property
    def color_image(self):
        """The (noisy) camera image output port: evaluate it only at the camera rate."""
        return self.noisy_camera.GetOutputPort("color_image")

    def X_WC(self, t: float) -> RigidTransform:
        """The camera's pose in W at time t."""
        return self.body.X_WB(t).multiply(self.X_BC)


def start_pose(config: Scenario) -> RigidTransform:
    """X_WB at t = 0: level, yaw 0, the camera start_height_m above the pads' top faces at the
    world origin's x, y."""
    p_WC = np.array([0.0, 0.0, PAD_THICKNESS_M + config.start_height_m])
    return RigidTransform(p_WC - np.asarray(config.camera.mount_xyz_m, dtype=float))


def pad_centres_W(config: Scenario) -> np.ndarray:
    """(4, 3) centres of the pads' top faces: straight below each ToF sensor at the start pose."""
    X_WC0 = start_pose(config).multiply(config.camera.X_BC)
    p_W = np.array([X_WC0.multiply(p) for p in sensor_positions_C(config.tof.arm_m, config.tof.angle_deg)])
    p_W[:, 2] = PAD_THICKNESS_M
    return p_W


def add_floor_and_pads(scene_graph: SceneGraph, config: Scenario) -> np.ndarray:
    """Registers the grey floor (top at z = 0) and the four pads, seen by the camera and the ToF rays;
    returns the pads' top centres."""
    source_id = scene_graph.RegisterSource("calibration_floor")
    world = scene_graph.world_frame_id()
    register_visual(scene_graph, source_id, world, RigidTransform([0.0, 0.0, -GROUND_THICKNESS_M / 2]),
                    Box(GROUND_SIZE_M, GROUND_SIZE_M, GROUND_THICKNESS_M), "floor", GROUND_RGBA, collidable=True)
    p_W_pads = pad_centres_W(config)
    for colour, p in zip(PAD_COLOURS, p_W_pads):
        rgba = (*(np.asarray(PAD_RGB[colour]) / 255.0), 1.0)
        register_visual(scene_graph, source_id, world, RigidTransform(p - [0.0, 0.0, PAD_THICKNESS_M / 2]),
                        Cylinder(config.pad_radius_m, PAD_THICKNESS_M), f"pad_{colour}", rgba, collidable=True)
    return p_W_pads


def add_calibration_scene(builder: DiagramBuilder, config: Scenario, meshcat: Meshcat | None = None,
                          video_path=None) -> CalibrationSceneHandles:
    """Adds the calibration scene's systems to `builder` and returns their handles."""
    config.validate()
    scene_graph = builder.AddSystem(SceneGraph())
    add_renderer(scene_graph)
    p_W_pads = add_floor_and_pads(scene_graph, config)

    airframe = builder.AddSystem(AirframeGeometry(config.uav, scene_graph))
    body = builder.AddSystem(PrescribedPose(start_pose(config), (0.0, 0.0, config.climb_speed_m_s)))
    builder.Connect(body.GetOutputPort("X_WB"), airframe.get_input_port())
    builder.Connect(airframe.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(airframe.source_id))
    camera, noisy_camera, tof = add_uav_sensors(builder, scene_graph, airframe.body_frame_id, config.camera,
                                                config.tof, config.seed)
    pads = builder.AddSystem(PadCentroidsSystem(config.camera.width, config.camera.height))
    builder.Connect(noisy_camera.get_output_port(), pads.get_input_port())

    period = config.camera.period_s
    loggers = {name: LogVectorOutput(port, builder, period) for name, port in {
        "pad_pixels": pads.GetOutputPort("pad_pixels"),
        "ranges": tof.GetOutputPort("ranges"),
        "true_ranges": tof.GetOutputPort("true_ranges"),
    }.items()}

    visualizer, video = add_viewers(builder, scene_graph, meshcat, noisy_camera, config.camera, video_path)
    p_C_sensors = sensor_positions_C(config.tof.arm_m, config.tof.angle_deg)
    return CalibrationSceneHandles(scene_graph, airframe, body, camera, noisy_camera, tof, pads, loggers,
                                   config.camera.X_BC, p_C_sensors, p_W_pads, visualizer, video)


def build_calibration_scene(config: Scenario, meshcat: Meshcat | None = None,
                            video_path=None) -> tuple[Diagram, CalibrationSceneHandles]:
    """Builds the calibration scene as a Diagram; returns it with the handles of its systems."""
    builder = DiagramBuilder()
    handles = add_calibration_scene(builder, config, meshcat, video_path)
    diagram = builder.Build()
    diagram.set_name("crhf_calibration")
    return diagram, handles


def true_pad_pixels(handles: CalibrationSceneHandles, K: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(F, 4, 2) projections through K of the pads' top centres at the given times."""
    return np.array([project_points(K, handles.X_WC(float(t)).inverse(), handles.p_W_pads) for t in times])


def collect_log(handles: CalibrationSceneHandles, context, config: Scenario) -> dict[str, np.ndarray]:
    """The run's logs as arrays, one row per camera frame."""
    log = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    arrays = {name: entry.data().T.copy() for name, entry in log.items()}
    arrays["t"] = log["pad_pixels"].sample_times().copy()
    arrays["true_pad_pixels"] = true_pad_pixels(handles, config.camera.K, arrays["t"]).reshape(-1, 8)
    arrays["K"] = config.camera.K
    arrays["p_C_sensors"] = handles.p_C_sensors
    arrays["p_W_pads"] = handles.p_W_pads
    return arrays


def leave_one_out_residuals(ranges: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N-2, 2) PCHIP interpolation residuals: each interior sample against the PCHIP through all
    the others (what the interpolant would be off by between samples)."""
    from scipy.interpolate import PchipInterpolator

    out = np.empty((len(ranges) - 2, 2))
    for k in range(1, len(ranges) - 1):
        keep = np.arange(len(ranges)) != k
        out[k - 1] = PchipInterpolator(ranges[keep], pixels[keep], axis=0)(ranges[k]) - pixels[k]
    return out


def calibration_metrics(calibration: PadCalibration, log: dict[str, np.ndarray], config: Scenario,
                        p_C_sensors: np.ndarray) -> dict:
    """The "calibration" section of metrics.json."""
    c = config.camera
    true = {"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy}
    implied = calibration.implied_intrinsics(p_C_sensors)
    pads = {}
    for i, (sensor, row) in enumerate(zip(calibration.sensors, implied)):
        X, Y = p_C_sensors[i, :2]
        dense = np.linspace(sensor.ranges[0], sensor.ranges[-1], 2000)
        truth = np.column_stack([c.fx * X / dense + c.cx, c.fy * Y / dense + c.cy])
        fit = np.column_stack([sensor.fit_u(sensor.ranges), sensor.fit_v(sensor.ranges)])
        hyperbola = np.column_stack([sensor.fit_u(dense), sensor.fit_v(dense)])
        loo = leave_one_out_residuals(sensor.ranges, sensor.pixels)
        found = np.all(np.isfinite(log["pad_pixels"].reshape(-1, 4, 2)[:, i]), axis=1)
        pads[sensor.colour] = {
            "sensor": i + 1,
            "samples": int(len(sensor.ranges)),
            "detected_fraction": float(np.mean(found)),
            "range_m": [float(sensor.ranges[0]), float(sensor.ranges[-1])],
            "hyperbola": {  # Eq. 18: pixel = a / range + c, a in px m, c in px
                "u": {"a": sensor.fit_u.a, "c": sensor.fit_u.c,
                      "fit_rmse_px": rms_of_finite(fit[:, 0] - sensor.pixels[:, 0])},
                "v": {"a": sensor.fit_v.a, "c": sensor.fit_v.c,
                      "fit_rmse_px": rms_of_finite(fit[:, 1] - sensor.pixels[:, 1])},
            },
            "implied_intrinsics": dict(zip(("fx", "fy", "cx", "cy"), row.tolist())),
            "implied_error_percent": {k: 100.0 * (v - true[k]) / true[k] for k, v in zip(true, row)},
            # Against the true projection over the calibrated ranges (per axis u, v, px):
            "hyperbola_vs_truth_rmse_px": [rms_of_finite(hyperbola[:, j] - truth[:, j]) for j in range(2)],
            "pchip_vs_truth_rmse_px": [rms_of_finite(sensor.interpolant(dense)[:, j] - truth[:, j]) for j in range(2)],
            "pchip_vs_truth_max_px": [float(np.nanmax(np.abs(sensor.interpolant(dense)[:, j] - truth[:, j])))
                                      for j in range(2)],
            # PCHIP interpolation residual: each sample against the PCHIP through the others.
            "pchip_leave_one_out_rmse_px": [rms_of_finite(loo[:, j]) for j in range(2)],
        }
    mean = implied.mean(axis=0)
    return {
        "pads": pads,
        "true_intrinsics": true,
        "implied_intrinsics_mean": dict(zip(true, mean.tolist())),
        "implied_error_percent_mean": {k: 100.0 * (v - true[k]) / true[k] for k, v in zip(true, mean)},
        "implied_error_px_mean": {k: float(v - true[k]) for k, v in zip(true, mean)},
    }


def plot_calibration(calibration: PadCalibration, config: Scenario, p_C_sensors: np.ndarray, out_dir) -> None:
    """Fig. 14-15 of the paper: pixel u (calibration_u.png) and v (calibration_v.png) against the
    range per pad, with the samples, the Eq. 18 hyperbola and the PCHIP curve; and the residuals
    against the true projection (calibration_residuals.png)."""
    c = config.camera
    for axis, name in ((0, "u"), (1, "v")):
        fig, axes = plt.subplots(2, 2, figsize=(11, 8), sharex=True)
        for i, (sensor, ax) in enumerate(zip(calibration.sensors, axes.ravel())):
            fit = sensor.fit_u if axis == 0 else sensor.fit_v
            dense = np.linspace(sensor.ranges[0], sensor.ranges[-1], 1000)
            colour = PLOT_COLOURS.get(sensor.colour, "k")
            ax.plot(sensor.ranges, sensor.pixels[:, axis], ".", ms=3, color="0.5", label="samples")
            ax.plot(dense, sensor.interpolant(dense)[:, axis], "-", lw=1, color=colour, label="PCHIP")
            ax.plot(dense, fit(dense), "k--", lw=1, label=f"a/r + c: a = {fit.a:.2f}, c = {fit.c:.2f}")
            ax.set_title(f"sensor {i + 1}, {sensor.colour} pad")
            ax.set_ylabel(f"{name} (px)")
            ax.grid(alpha=0.3)
            ax.legend(loc="best", fontsize=8)
        for ax in axes[-1]:
            ax.set_xlabel("ToF range (m)")
        fig.suptitle(f"Pad centroid {name} against range (true c{name} = {c.cx if axis == 0 else c.cy:g} px)")
        save_figure(fig, out_dir / f"calibration_{name}.png")

    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for i, sensor in enumerate(calibration.sensors):
        X, Y = p_C_sensors[i, :2]
        truth = np.column_stack([c.fx * X / sensor.ranges + c.cx, c.fy * Y / sensor.ranges + c.cy])
        fit = np.column_stack([sensor.fit_u(sensor.ranges), sensor.fit_v(sensor.ranges)])
        colour = PLOT_COLOURS.get(sensor.colour, "k")
        for axis, ax in enumerate(axes):
            ax.plot(sensor.ranges, sensor.pixels[:, axis] - truth[:, axis], ".", ms=2, color=colour,
                    label=f"{sensor.colour}: samples (= PCHIP at its nodes)")
            ax.plot(sensor.ranges, fit[:, axis] - truth[:, axis], "-", lw=1, color=colour)
    for axis, ax in enumerate(axes):
        ax.set_ylabel(f"{'uv'[axis]} - true projection (px)")
        ax.grid(alpha=0.3)
    axes[0].set_title("Calibration against the true projection at the measured range (lines: Eq. 18 fits)")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("ToF range (m)")
    save_figure(fig, out_dir / "calibration_residuals.png")


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.runner import finish_run, simulate_scene

    video_path = ctx.out_dir / "camera.mp4" if ctx.options.video else None
    diagram, handles = build_calibration_scene(scenario, ctx.meshcat, video_path)
    metrics, context = simulate_scene(diagram, handles, scenario, ctx)
    log = collect_log(handles, context, scenario)
    calibration = PadCalibration.from_frames(log["ranges"], log["pad_pixels"].reshape(-1, 4, 2), PAD_COLOURS,
                                             CalibrationFlight.of(scenario.camera, handles.p_C_sensors))
    valid = np.isfinite(log["ranges"])
    metrics.update({
        "frames": int(len(log["t"])),
        "height_m": [scenario.start_height_m,
                     scenario.start_height_m + scenario.climb_speed_m_s * float(log["t"][-1])],
        "sensors": {
            "tof_valid_fraction": np.mean(valid, axis=0).tolist(),
            "tof_error_m_rmse": [rms_of_finite(e) for e in (log["ranges"] - log["true_ranges"]).T],
        },
        "perception": {
            "pad_centroid_error_px_rmse": [
                rms_of_finite(np.linalg.norm((log["pad_pixels"] - log["true_pad_pixels"]).reshape(-1, 4, 2)[:, i],
                                             axis=1))
                for i in range(4)],
        },
        "calibration": calibration_metrics(calibration, log, scenario, handles.p_C_sensors),
    })
    calibration.save(ctx.out_dir / "pad_calibration.npz")  # atomic: written to a temporary name, renamed
    write_npz(ctx.out_dir / "log.npz", **log)
    plot_calibration(calibration, scenario, handles.p_C_sensors, ctx.out_dir)
    return finish_run(ctx, metrics)

