"""The marker stream and the marker filters against the truth, at the filter steps (seed 002 Sec. 4).

`SampledRun` is what a run leaves at every filter step t_k, from the diagram's loggers or from the
batch path (diagrams/marker_batch.py) alike: the UAV's and the vehicle's true states, the stream as
acquired, every filter's estimate vector (systems/estimators/marker_ekf/engine.py's EST_* layout)
and marker positions. `marker_metrics` scores it: per filter the errors of the pad P's position (the
paper's S_P, at marker 0), its attitude (the truth is level; roll and pitch only for a filter that
estimates them, its `attitude_axes`), its heading and each marker's centre, over the valid estimates
after `estimation.settle_s`; and the stream's own accuracy per marker.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform

from diagrams.metrics import estimator_metrics, level_poses
from systems.control.monitor import GV_HEADING
from systems.estimators.marker_ekf import FILTERS
from systems.estimators.marker_ekf.engine import EST_P_WP, EST_Q_WP, EST_VALID, EST_YAW
from systems.flags import is_set
from systems.geometry import wrap_angle
from systems.perception.markers import MarkerLayout
from systems.quaternion import quat_conjugate, quat_multiply, rotation_from_quaternion
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.quadrotor import P_WB, Q_WB

ATTITUDE_AXES = ("roll", "pitch", "yaw")  # the order of estimator_metrics' *_rpy_deg


@dataclass
class SampledRun:
    """A run at the filter steps t (N): `quadrotor_state` (N, 17), `vehicle_state` (N, 4),
    `measurements` (N, n, 7: [p_CM, q_CM] per layout marker as acquired, NaN where not measured),
    per filter `estimates` (N, ESTIMATE_VECTOR_SIZE) and `p_WM` (N, n, 3), its FilterStats as a dict
    in `stats` and its compute time in `compute_s` [s]."""

    t: np.ndarray
    quadrotor_state: np.ndarray
    vehicle_state: np.ndarray
    measurements: np.ndarray
    estimates: dict[str, np.ndarray]
    p_WM: dict[str, np.ndarray]
    stats: dict[str, dict]
    compute_s: dict[str, float]


@dataclass(frozen=True)
class PadTruth:
    """The truth at the samples: UAV p_WB (N, 3) and unit q_WB (N, 4, [w, x, y, z]); pad p_WP (N, 3)
    and heading yaw (N, rad, unwrapped)."""

    p_WB: np.ndarray
    q_WB: np.ndarray
    p_WP: np.ndarray
    yaw: np.ndarray


def pad_truth(quadrotor_state: np.ndarray, vehicle_state: np.ndarray, platform: PlatformConfig) -> PadTruth:
    """The truth of states sampled over a run: quadrotor (N, 17), vehicle (N, 4)."""
    heading = vehicle_state[:, GV_HEADING]
    p_WP = vehicle_state[:, :2] + platform.pad_offset_m * np.column_stack([np.cos(heading), np.sin(heading)])
    q = quadrotor_state[:, Q_WB]
    return PadTruth(quadrotor_state[:, P_WB].copy(), q / np.linalg.norm(q, axis=1, keepdims=True),
                    np.column_stack([p_WP, np.full(len(heading), platform.height_m)]), np.unwrap(heading))


def true_marker_positions(truth: PadTruth, layout: MarkerLayout) -> np.ndarray:
    """(N, n, 3) marker centres in W."""
    c, s = np.cos(truth.yaw), np.sin(truth.yaw)
    p = layout.p_PM
    return truth.p_WP[:, None, :] + np.stack([c[:, None] * p[:, 0] - s[:, None] * p[:, 1],
                                              s[:, None] * p[:, 0] + c[:, None] * p[:, 1],
                                              np.broadcast_to(p[:, 2], (len(c), len(p)))], axis=-1)


def true_marker_poses_C(truth: PadTruth, layout: MarkerLayout, X_BC: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """Every marker's true pose in the camera frame C: p_CM (N, n, 3) [m] and q_CP (N, 4, [w, x, y, z]
    of R_CP), every marker's attitude (they are aligned with P)."""
    q_BC = np.array(X_BC.rotation().ToQuaternion().wxyz())
    q_WC = quat_multiply(truth.q_WB, q_BC)
    p_WC = truth.p_WB + rotation_from_quaternion(truth.q_WB) @ X_BC.translation()
    half = truth.yaw / 2
    q_WP = np.column_stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), np.sin(half)])
    q_CP = quat_multiply(quat_conjugate(q_WC), q_WP)
    R_CW = np.swapaxes(rotation_from_quaternion(q_WC), 1, 2)
    return np.einsum("kij,kmj->kmi", R_CW, true_marker_positions(truth, layout) - p_WC[:, None, :]), q_CP


def measurement_metrics(run: SampledRun, truth: PadTruth, layout: MarkerLayout, X_BC: RigidTransform) -> dict:
    """The stream's own accuracy, per marker: the share of samples with a measurement, and the RMS
    position error [m] and RMS attitude error [deg] of those measurements (None for a marker never
    measured)."""
    p_true, q_CP = true_marker_poses_C(truth, layout, X_BC)
    p_CM, q_CM = run.measurements[..., :3], run.measurements[..., 3:]
    measured = ~np.isnan(p_CM[..., 0])
    position = np.linalg.norm(p_CM - p_true, axis=-1)
    q_CM = np.concatenate([q_CM[..., 3:], q_CM[..., :3]], axis=-1)  # the paper's [x, y, z, w] to [w, x, y, z]
    q_CM = q_CM / np.linalg.norm(q_CM, axis=-1, keepdims=True)
    cos_half = np.abs(np.einsum("kmi,ki->km", q_CM, q_CP))
    attitude = np.degrees(2 * np.arccos(np.clip(cos_half, 0.0, 1.0)))

    def rms(errors: np.ndarray) -> list:
        return [float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else None for e, m in zip(errors.T, measured.T)]

    return {"measured_fraction": measured.mean(axis=0).tolist(), "rms_position_m": rms(position),
            "rms_attitude_deg": rms(attitude)}


@dataclass
class FilterErrors:
    """One filter's estimate minus truth per step (NaN where it has not started) and its validity."""

    position: np.ndarray  # (N, 3) pad P [m]
    heading: np.ndarray  # (N,) [rad]
    markers: np.ndarray  # (N, n) norm of each marker's position error [m]
    valid: np.ndarray  # (N,) bool


def pooled_rms(filter_metrics: list[dict], key: str) -> np.ndarray:
    """The RMS `key` (a scalar or per-marker figure of `filter_metrics`) over every scored step of several
    runs: each run's mean square weighted by its `frames_scored`."""
    return np.sqrt(np.average(np.square([m[key] for m in filter_metrics]), axis=0,
                              weights=[m["frames_scored"] for m in filter_metrics]))


def valid_only(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """values (N, ...) with NaN in the rows where valid (N,) is False: what the metrics leave out."""
    return np.where(valid.reshape(-1, *[1] * (values.ndim - 1)), values, np.nan)


def filter_errors(run: SampledRun, truth: PadTruth, name: str, layout: MarkerLayout) -> FilterErrors:
    estimate = run.estimates[name]
    return FilterErrors(estimate[:, EST_P_WP] - truth.p_WP, wrap_angle(estimate[:, EST_YAW] - truth.yaw),
                        np.linalg.norm(run.p_WM[name] - true_marker_positions(truth, layout), axis=-1),
                        is_set(estimate[:, EST_VALID]))


def filter_metrics(run: SampledRun, truth: PadTruth, name: str, errors: FilterErrors, settle_s: float) -> dict:
    """One filter's figures: estimator_metrics' (docs/architecture.md) of its pose estimate X_WP,
    with `attitude_axes` naming the axes it estimates (the others' *_rpy_deg entries None), plus seed
    002's: RMS error of P's position (3-D and horizontal), heading and every marker, over its valid
    estimates from settle_s on (a filter coasting without measurements flags its estimate invalid once
    the pad's position std passes MarkerEkfConfig.max_valid_position_std_m); its counts and cost per step."""
    window = run.t >= settle_s
    estimate = run.estimates[name]
    estimate_rows = np.column_stack([errors.valid, estimate[:, EST_P_WP], estimate[:, EST_Q_WP]])
    out = estimator_metrics(level_poses(truth.p_WP, truth.yaw), estimate_rows, window)
    axes = FILTERS[name].attitude_axes
    for key in ("mae_rpy_deg", "rmse_rpy_deg"):
        if key in out:
            out[key] = [value if axis in axes else None for axis, value in zip(ATTITUDE_AXES, out[key])]
    out["attitude_axes"] = list(axes)
    out.update({"per_frame_ms": 1e3 * run.compute_s[name] / max(len(run.t), 1), "measurements": run.stats[name]})
    scored = window & errors.valid & np.isfinite(errors.heading)
    if scored.any():
        e, h, m = errors.position[scored], errors.heading[scored], errors.markers[scored]
        out.update({
            "rms_position_m": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
            "rms_position_xy_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
            "rms_heading_deg": float(np.degrees(np.sqrt(np.mean(h**2)))),
            "rms_marker_position_m": np.sqrt(np.mean(m**2, axis=0)).tolist(),
            "max_position_m": float(np.max(np.linalg.norm(e, axis=1))),
        })
    return out


def marker_metrics(run: SampledRun, platform: PlatformConfig, X_BC: RigidTransform,
                   settle_s: float) -> tuple[dict, dict, dict[str, FilterErrors]]:
    """(the stream's accuracy, per filter its figures, per filter its errors) of a sampled run."""
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, platform)
    errors = {name: filter_errors(run, truth, name, platform.markers) for name in run.estimates}
    metrics = {name: filter_metrics(run, truth, name, e, settle_s) for name, e in errors.items()}
    return measurement_metrics(run, truth, platform.markers, X_BC), metrics, errors
