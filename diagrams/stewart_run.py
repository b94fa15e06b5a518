"""Running the Stewart scene: simulate it and write metrics.json, log.npz and plots."""

from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform

from diagrams.metrics import estimator_metrics, rms_of_finite
from diagrams.outputs import save_figure, write_npz
from diagrams.pose_plots import plot_pose_estimates
from diagrams.scenario import RunSettings
from diagrams.stewart_scene import StewartSceneConfig, build_stewart_scene
from systems.config import require_positive
from systems.flags import is_set
from systems.perception.apriltag import project_points
from systems.platforms.stewart import require_within_stroke
from systems.sensors.ground_truth import pose_vector


@dataclass
class Scenario(RunSettings, StewartSceneConfig):
    """A Stewart-scene scenario file: the scene's configuration plus the run settings."""

    def validate(self) -> None:
        require_positive(self.duration_s, "duration_s")
        StewartSceneConfig.validate(self)
        require_within_stroke(self.platform, self.duration_s, self.seed)


def pose_from_vector(v: np.ndarray) -> RigidTransform:
    """Inverse of `pose_vector`: [x, y, z, qw, qx, qy, qz] -> RigidTransform."""
    return RigidTransform(Quaternion(v[3:] / np.linalg.norm(v[3:])), v[:3])


def collect_log(handles, context, config: StewartSceneConfig) -> dict[str, np.ndarray]:
    """The run's logs as arrays, one row per camera frame (IMU: per IMU sample, `t_imu` the time it was taken)."""
    log = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    arrays = {name: entry.data().T.copy() for name, entry in log.items()}
    arrays["t"] = log["X_CP"].sample_times().copy()
    # The IMU's logger reads its held output every IMU period, before that instant's sample is taken: the row
    # logged at t_k is the sample of t_(k-1), the first the Imu's initial placeholder. Each sample at its own time.
    arrays["imu"] = arrays["imu"][1:]
    arrays["t_imu"] = log["imu"].sample_times()[:-1].copy()
    X_CT = [pose_from_vector(v).multiply(handles.platform.X_PT) for v in arrays["X_CP"]]
    arrays["X_CT"] = np.array([pose_vector(X) for X in X_CT])
    arrays["true_tag_corners"] = np.array(
        [project_points(config.camera.K, X, handles.platform.tag_corners_T()).ravel() for X in X_CT])
    arrays["K"] = config.camera.K
    arrays["X_BC"] = handles.X_BC.GetAsMatrix4()
    arrays["X_PT"] = handles.platform.X_PT.GetAsMatrix4()
    return arrays


def range_errors(log: dict[str, np.ndarray]) -> np.ndarray:
    """(N, 4) each ToF reading less the true range [m], NaN where the reading is flagged invalid."""
    return np.where(is_set(log["ranges_valid"]), log["ranges"] - log["true_ranges"], np.nan)


def scene_metrics(log: dict[str, np.ndarray]) -> dict:
    """Perception, sensor and platform figures of a run (no estimators in the bare scene)."""
    detected = np.all(np.isfinite(log["tag_corners"]), axis=1)
    corner_error = np.linalg.norm((log["tag_corners"] - log["true_tag_corners"]).reshape(-1, 4, 2), axis=2)
    valid = is_set(log["ranges_valid"])
    return {
        "perception": {
            "tag_detected_fraction": float(np.mean(detected)),
            "corner_error_px_mean": float(np.mean(corner_error[detected])) if detected.any() else None,
            "corner_error_px_max": float(np.max(corner_error[detected])) if detected.any() else None,
        },
        "sensors": {
            "tof_valid_fraction": np.mean(valid, axis=0).tolist(),
            "tof_error_m_rmse": [rms_of_finite(e) for e in range_errors(log).T],
        },
        "platform": {
            "stroke_exceeded_fraction": float(np.mean(log["stroke_exceeded"])),
            "leg_length_min_m": float(log["leg_lengths"].min()),
            "leg_length_max_m": float(log["leg_lengths"].max()),
        },
    }


def plot_scene(log: dict[str, np.ndarray], config: StewartSceneConfig, out_dir) -> None:
    """tof_ranges.png (each sensor's range, m, true and measured, and its error, mm), stewart_legs.png and
    tag_corners.png."""
    t = log["t"]
    fig, axes = plt.subplots(4, 2, figsize=(13, 8), sharex=True)
    true = log["true_ranges"][np.isfinite(log["true_ranges"])]  # inf before a sensor's first reading
    near_max = true.size > 0 and true.max() > 0.75 * config.tof.max_range_m
    errors_mm = 1e3 * range_errors(log)
    for i, (ranges, errors) in enumerate(axes):
        ranges.plot(t, log["true_ranges"][:, i], "k-", lw=1, label="true")
        ranges.plot(t, log["ranges"][:, i], ".", ms=2, label="measured")
        if near_max:
            ranges.axhline(config.tof.max_range_m, color="r", ls=":", lw=1, label="max range")
        ranges.set_ylabel(f"ToF {i + 1} (m)")
        errors.plot(t, errors_mm[:, i], ".", ms=2, color="tab:red")
        errors.axhline(0.0, color="k", lw=0.8)
        rms = rms_of_finite(errors_mm[:, i])
        errors.set_ylabel("error (mm)" if rms is None else f"error (mm), rms {rms:.1f}")
        for ax in (ranges, errors):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right")
    axes[0, 1].set_title("measured - true (invalid readings left out)")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    save_figure(fig, out_dir / "tof_ranges.png")

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t, log["leg_lengths"], lw=1)
    for limit in (config.platform.leg_min_m, config.platform.leg_max_m):
        ax.axhline(limit, color="r", ls="--", lw=1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("leg length (m)")
    ax.set_title("Stewart platform legs (dashed: stroke limits)")
    ax.grid(alpha=0.3)
    save_figure(fig, out_dir / "stewart_legs.png")

    fig, ax = plt.subplots(figsize=(10, 3.5))
    error = np.linalg.norm((log["tag_corners"] - log["true_tag_corners"]).reshape(-1, 4, 2), axis=2)
    ax.plot(t, error, ".", ms=2, label=[f"corner {k + 1}" for k in range(4)])
    ax.legend(loc="upper right", fontsize=8, ncol=4, markerscale=4)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("corner error (px)")
    ax.set_title("Detected tag corners against the projection of the true corners")
    ax.grid(alpha=0.3)
    save_figure(fig, out_dir / "tag_corners.png")


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.runner import finish_run, simulate_scene

    video_path = ctx.out_dir / "camera.mp4" if ctx.options.video else None
    diagram, handles = build_stewart_scene(scenario, ctx.meshcat, video_path)
    metrics, context = simulate_scene(diagram, handles, scenario, ctx)
    log = collect_log(handles, context, scenario)
    metrics.update(scene_metrics(log))
    if scenario.estimators:
        metrics["estimators"] = {name: {**estimator_metrics(log["X_CT"], log[f"estimate_{name}"]),
                                        "per_frame_ms": system.per_frame_ms(system.GetMyContextFromRoot(context))}
                                 for name, system in handles.estimators.items()}
    write_npz(ctx.out_dir / "log.npz", **log)
    plot_scene(log, scenario, ctx.out_dir)
    plot_pose_estimates(log["t"], log["X_CT"], {name: log[f"estimate_{name}"] for name in scenario.estimators},
                        ctx.out_dir)
    return finish_run(ctx, metrics)
