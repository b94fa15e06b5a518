"""metrics.json's `perception` section: how well what steered the UAV knew where the pad was.

Scored at the supervisor's samples against the truth: the pad position the seam implied (UAV
position plus the seam's offset) and, where the source estimates one, its heading; over the
samples where the seam was valid. Also how long the UAV flew without a valid estimate, and, for a
marker filter, how long before touchdown it last fused a measurement (the blind end of the descent).
"""

import numpy as np

from diagrams.metrics import estimator_metrics, level_poses, quaternion_yaw
from systems.control.monitor import GV_HEADING
from systems.estimators.marker_ekf.engine import EST_LAST_MEASUREMENT
from systems.flags import is_set
from systems.perception.seam import P_BP_W, VALID
from systems.vehicles.quadrotor import P_WB


def longest_span_s(t: np.ndarray, mask: np.ndarray) -> float:
    """The longest time [s] that `mask` (a boolean per sample time `t`) holds: a run of True lasts from its
    first sample to the sample after it, or to t[-1], the log's end, when it runs to the end."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return float((t[np.minimum(ends, len(t) - 1)] - t[starts]).max()) if starts.size else 0.0


def carrier_heading(log: dict[str, np.ndarray]) -> np.ndarray:
    """The pad carrier's heading per sample [rad]: the ground vehicle's, or the deck's (`carrier_state`, the
    same layout)."""
    return log["carrier_state" if "carrier_state" in log else "vehicle_state"][:, GV_HEADING]


def perception_metrics(log: dict[str, np.ndarray], source: str, touchdown_s: float | None = None,
                       filter_t: np.ndarray | None = None, filter_estimate: np.ndarray | None = None,
                       heading: bool = True) -> dict:
    """The section for a flight's `log` (diagrams/gv_landing_run.collect_log); `filter_t` and
    `filter_estimate` are the steering marker filter's samples and estimate vectors, if one steered.
    `heading`: whether the source estimates the pad's heading; if not (a position alone, as the hybrid
    source's), or where no estimate steered (the truth: no `steering_estimate` in the log, as perception.png
    has it), only positions are scored: no heading, rotation or flip figures."""
    t, seam, truth = log["t"], log["relative_state"], log["true_relative_state"]
    valid = is_set(seam[:, VALID])
    p_WB = log["quadrotor_state"][:, P_WB]
    true_yaw = carrier_heading(log)
    heading = heading and "steering_estimate" in log
    if heading:  # [valid, x, y, z, qw, qx, qy, qz]; NaN where invalid
        yaw = quaternion_yaw(log["steering_estimate"][:, 4:])
    else:  # the true heading, its figures left out below
        yaw = true_yaw
    estimate = np.column_stack([valid, level_poses(p_WB + seam[:, P_BP_W], yaw)])
    out = {"source": source,
           **estimator_metrics(level_poses(p_WB + truth[:, P_BP_W], true_yaw), estimate)}
    if not heading:
        for key in ("mae_rpy_deg", "rmse_rpy_deg", "flips"):
            out.pop(key, None)
    for key in ("mae_rpy_deg", "rmse_rpy_deg"):  # the heading alone is scored: roll and pitch are not figures
        if key in out:
            out[key] = [None, None, out[key][2]]
    out["longest_invalid_s"] = longest_span_s(t, ~valid)
    out["first_valid_s"] = float(t[valid][0]) if valid.any() else None
    if valid.any():
        error = (seam[:, P_BP_W] - truth[:, P_BP_W])[valid]
        heading_error = np.angle(np.exp(1j * (yaw - true_yaw)))[valid]
        out["rms_position_m"] = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
        if heading:
            out["rms_heading_deg"] = float(np.degrees(np.sqrt(np.mean(heading_error**2))))
    if touchdown_s is not None and filter_estimate is not None:
        before = filter_t <= touchdown_s + 1e-9
        last = filter_estimate[before, EST_LAST_MEASUREMENT][-1] if before.any() else np.nan
        out["coast_before_touchdown_s"] = float(touchdown_s - last) if np.isfinite(last) else None
    return out
