"""Seed 003's figures for a run steered by the hybrid array (`perception.source: hybrid`), from its logs at the
fisheye's frames (diagrams/hybrid_perception.py): the pad's position and velocity against the truth, the
stereo altitude against the true depth at its window's centre, the detector's precision / recall / F1 against the UGV's
true box (its 3-D bounding box projected with the fisheye's model, diagrams/ugv_detection_scenes.py's
`projected_box`; a detection is right at IOU >= 0.5), and the tracker's identity switches.
"""

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from diagrams.hybrid_perception import GROUND_LIFT_M
from diagrams.ugv_detection_scenes import box_surface_points, projected_box, ugv_bounds_V
from systems.flags import is_set
from systems.perception.box_tracker import count_identity_switches, iou
from systems.perception.hybrid_pad import HYBRID_VECTOR_SIZE
from systems.perception.seam import P_BP_W, V_WP
from systems.vehicles.quadrotor import P_WB, Q_WB

IOU_MATCH = 0.5
CLIMBED_FRACTION = 0.95  # of IH: the climb has ended


def axis_stats(error: np.ndarray) -> dict:
    """MAE and RMSE per axis of errors (N, 3), NaN rows left out."""
    error = error[np.all(np.isfinite(error), axis=1)]
    if len(error) == 0:
        return {"samples": 0}
    return {"mae_xyz": np.abs(error).mean(axis=0).tolist(), "rmse_xyz": np.sqrt((error**2).mean(axis=0)).tolist(),
            "rmse_horizontal": float(np.sqrt((error[:, :2] ** 2).sum(axis=1).mean())), "samples": len(error)}


def climb_end_index(z_WB: np.ndarray, initial_height_m: float) -> int | None:
    """The first frame whose UAV height z_WB [m] is within CLIMBED_FRACTION of IH, None if none is."""
    climbed = np.asarray(z_WB) >= CLIMBED_FRACTION * initial_height_m
    return int(np.argmax(climbed)) if climbed.any() else None


def true_ugv_boxes(quadrotor_state: np.ndarray, vehicle_state: np.ndarray, config) -> list:
    """The UGV's true box (or None) in each frame's fisheye image."""
    fisheye = config.hybrid.fisheye
    low, high = ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)
    points_V = box_surface_points(low, high, 9)
    boxes = []
    for q, v in zip(quadrotor_state, vehicle_state):
        X_WB = RigidTransform(_quaternion(q[Q_WB]), q[P_WB])
        X_WV = RigidTransform(RollPitchYaw(0.0, 0.0, v[2]), [v[0], v[1], 0.0])
        X_CV = X_WB.multiply(fisheye.X_BC).inverse().multiply(X_WV)
        boxes.append(projected_box(X_CV.multiply(points_V.T).T, fisheye))
    return boxes


def ray_box_entry(p: np.ndarray, d: np.ndarray, low: np.ndarray, high: np.ndarray) -> float:
    """Where the ray p + s d (s >= 0) enters the axis-aligned box [low, high] (slab method): s, or inf if
    it misses."""
    parallel = d == 0  # parallel to a slab: inside it everywhere or nowhere
    if np.any(parallel & ((p < low) | (p > high))):
        return np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        s1, s2 = (low - p) / d, (high - p) / d
    near, far = np.where(parallel, -np.inf, np.minimum(s1, s2)), np.where(parallel, np.inf, np.maximum(s1, s2))
    enter, leave = near.max(), far.min()
    return float(max(enter, 0.0)) if enter <= leave and leave >= 0 else np.inf


def true_window_depth(quadrotor_state: np.ndarray, vehicle_state: np.ndarray, config) -> np.ndarray:
    """Per frame the true depth (m) at the stereo window's centre: along the left eye's optical axis (the
    window is centred on the principal point, Eq. 12) to the UGV's bounding box where the axis meets it, else
    to the textured ground; NaN where neither lies ahead."""
    X_BL = config.hybrid.stereo.X_BL
    low, high = ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)
    depth = np.full(len(quadrotor_state), np.nan)
    for k, (q, v) in enumerate(zip(quadrotor_state, vehicle_state)):
        X_WL = RigidTransform(_quaternion(q[Q_WB]), q[P_WB]).multiply(X_BL)
        p_WL, axis_W = X_WL.translation(), X_WL.rotation().col(2)
        ground = (GROUND_LIFT_M - p_WL[2]) / axis_W[2] if axis_W[2] < 0 else np.inf
        X_VW = RigidTransform(RollPitchYaw(0.0, 0.0, v[2]), [v[0], v[1], 0.0]).inverse()
        ugv = ray_box_entry(X_VW.multiply(p_WL), X_VW.rotation().multiply(axis_W), low, high)
        nearest = min(ground, ugv)
        depth[k] = nearest if 0 <= nearest < np.inf else np.nan  # NaN: nothing ahead (the eye under the ground)
    return depth


def _quaternion(wxyz):
    from pydrake.common.eigen_geometry import Quaternion

    q = np.asarray(wxyz, float)
    return Quaternion(q / np.linalg.norm(q))


def detection_scores(detections: np.ndarray, truth: list) -> dict:
    """Precision, recall and F1 of every detection against the true boxes, from the logged detections (N, 1 +
    5 K: DetectionsToTracker's count, then the best K by score, [valid, x, y, w, h] each): per frame the
    best-scoring box within IOU_MATCH of the true one is its true positive (seed 003 Table 3's rule,
    `match_truth`), every other detection a false positive, counted or logged."""
    tp = fp = fn = 0
    for row, true_box in zip(detections, truth):
        boxes = [row[5 * k + 2:5 * k + 6] for k in range((len(row) - 1) // 5) if is_set(row[5 * k + 1])]
        hit = int(true_box is not None and any(iou(box, true_box) >= IOU_MATCH for box in boxes))
        tp, fp, fn = tp + hit, fp + int(row[0]) - hit, fn + int(true_box is not None and not hit)
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else None  # the harmonic mean of the two; 0 without a match
    return {"precision": precision, "recall": recall, "f1": f1, "true_positives": tp, "false_positives": fp,
            "false_negatives": fn, "iou_match": IOU_MATCH, "frames_with_ugv_in_view": int(sum(b is not None for b in truth))}


def identity_switches(lock: np.ndarray) -> dict:
    """Changes of the locked track's id between frames with a lock (LockedTrackVector's log (N, 2), id -1
    without one; one UGV: every change is a switch), box_tracker's `count_identity_switches`."""
    ids = [int(i) if i >= 0 else None for i in lock[:, 0]]
    locked = [i for i in ids if i is not None]
    switches = count_identity_switches(ids, [None] * len(ids)).total
    return {"identity_switches": switches, "frames_locked": len(locked), "tracks_locked": len(set(locked))}


def hybrid_metrics(log: dict, config, end_s: float | None) -> dict:
    """metrics.json's `estimators.hybrid` (and its detector's and altitude's figures) from the source's logs."""
    t = log["t"]
    keep = t <= end_s + 1e-9 if end_s is not None else np.ones(len(t), bool)
    hybrid = log["hybrid"][keep].reshape(-1, HYBRID_VECTOR_SIZE)
    truth = log["true_relative_state"][keep]
    quad, vehicle = log["quadrotor_state"][keep], log["vehicle_state"][keep]
    p_WP_true = quad[:, P_WB] + truth[:, P_BP_W]
    valid = is_set(hybrid[:, 0])
    p_error = np.where(valid[:, None], hybrid[:, 1:4] - p_WP_true, np.nan)
    v_valid = is_set(log["v_valid"][keep][:, 0])
    v_error = np.where(v_valid[:, None], log["v_WP"][keep] - truth[:, V_WP], np.nan)
    boxes = true_ugv_boxes(quad, vehicle, config)
    in_view = np.array([b is not None for b in boxes], bool)
    out = {"frames": len(t[keep]), "valid_fraction": float(valid.mean()) if len(valid) else 0.0,
           "measured_fraction": float(is_set(hybrid[:, 4]).mean()) if len(valid) else 0.0,
           "stereo_pad_fraction": float((hybrid[:, 4] > 1.5).mean()) if len(valid) else 0.0,
           "valid_fraction_in_view": float(valid[in_view].mean()) if in_view.any() else None,
           "velocity_valid_fraction": float(v_valid.mean()) if len(valid) else 0.0,
           "position_m": axis_stats(p_error), "velocity_mps": axis_stats(v_error)}
    # Seed 003 section 3.1.2's error "after settling": from the climb's end on.
    start = climb_end_index(quad[:, P_WB][:, 2], config.landing.initial_height_m)
    if start is not None:
        out["position_m_after_climb"] = axis_stats(p_error[start:])
    position = out["position_m"]
    if position["samples"]:
        out.update({"mae_xyz_m": position["mae_xyz"], "rmse_xyz_m": position["rmse_xyz"]})
    # The stereo altimeter (raw) and its filter against the true depth at the window's centre.
    depth_true = true_window_depth(quad, vehicle, config)
    stereo = {}
    for name, value, ok in (("raw", "stereo_altitude", "stereo_valid"), ("filtered", "altitude", "altitude_valid")):
        good = is_set(log[ok][keep][:, 0])
        e = log[value][keep][good, 0] - depth_true[good]
        e = e[np.isfinite(e)]
        stereo[name] = {"valid_fraction": float(good.mean()) if len(good) else 0.0,
                        **({"mae_m": float(np.abs(e).mean()), "rmse_m": float(np.sqrt((e**2).mean())),
                            "bias_m": float(e.mean())} if len(e) else {})}
    stereo["note"] = ("against the true depth at the window's centre: along the left eye's axis to the UGV's "
                      "bounding box, else to the ground")
    detector = {"type": config.hybrid.detector, **detection_scores(log["detections"][keep], boxes),
                **identity_switches(log["lock"][keep])}
    return {"hybrid": out, "hybrid_stereo_altitude": stereo, "hybrid_detector": detector}


def plot_hybrid(log: dict, config, out_dir) -> None:
    """hybrid.png: the pad's x, y from the hybrid estimate against the truth, its error, the stereo altitude
    against the true depth at its window's centre, and the tracker's lock."""
    import matplotlib.pyplot as plt

    from diagrams.outputs import save_figure

    t, hybrid, truth, quad = log["t"], log["hybrid"], log["true_relative_state"], log["quadrotor_state"]
    p_true = quad[:, P_WB] + truth[:, P_BP_W]
    valid = is_set(hybrid[:, 0])
    p = np.where(valid[:, None], hybrid[:, 1:4], np.nan)
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    for k, (axis, colour) in enumerate((("x", "tab:blue"), ("y", "tab:orange"))):
        axes[0].plot(t, p_true[:, k], "-", color=colour, lw=1.2, label=f"true {axis}")
        axes[0].plot(t, p[:, k], ".", color=colour, ms=2, label=f"hybrid {axis}")
    axes[1].plot(t, np.linalg.norm(p[:, :2] - p_true[:, :2], axis=1), ".", ms=2, color="tab:red")
    axes[2].plot(t, true_window_depth(quad, log["vehicle_state"], config), "-", color="k", lw=1,
                 label="depth at the window's centre (truth)")
    axes[2].plot(t, np.where(is_set(log["stereo_valid"][:, 0]), log["stereo_altitude"][:, 0], np.nan), ".", ms=2,
                 label="stereo (raw)")
    axes[2].plot(t, np.where(is_set(log["altitude_valid"][:, 0]), log["altitude"][:, 0], np.nan), "-", lw=1,
                 label="stereo filter")
    axes[3].plot(t, log["lock"][:, 0], ".", ms=2, label="locked track id")
    axes[3].plot(t, hybrid[:, 4], "-", lw=0.8, label="measured")
    axes[3].plot(t, valid.astype(float), "--", lw=0.8, label="valid")
    for ax, label in zip(axes, ("pad x, y in W (m)", "horizontal error (m)", "stereo depth (m)", "tracker")):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # a run that never saw the UGV draws nothing in some panels
            ax.legend(loc="best", fontsize=7, ncol=3)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title("Seed 003: the hybrid array's pad estimate")
    save_figure(fig, out_dir / "hybrid.png")
