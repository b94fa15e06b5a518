"""Seed 001's figures for a run with the federated filter: each vision node's own measurement, each
local filter and the fused estimate against the truth (seed 001 Sec. 5, Fig. 8-10), and the fused
height against the local filters' where two nodes overlap (Sec. 5.3, `overlap_metrics`).

Everything is the UAV body B in the pattern frame P (the paper's pose), at the camera's frames:
`FederatedLog` holds the logs of diagrams/federated_perception.py and the true X_PB. The
approaching node measures only the pattern's centre in the camera, p_CP: it is scored there.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform
from scipy.spatial.transform import Rotation

from diagrams.marker_metrics import pad_truth
from diagrams.metrics import estimator_metrics, rotations
from systems.estimators.federated.engine import NODES
from systems.estimators.federated.system import (
    FED_LOCAL_P,
    FED_LOCAL_THETA,
    FED_P_PB,
    FED_Q_PB,
    FED_STARTED,
    FED_VALID,
)
from systems.flags import is_set
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.quadrotor import P_WB, Q_WB


@dataclass
class FederatedLog:
    """At the camera's frames t (N,): `federated` (N, FEDERATED_VECTOR_SIZE), `nodes` (name ->
    (N, NODE_VECTOR_SIZE)) and the truth X_PB (N, 7: [x, y, z, qw, qx, qy, qz])."""

    t: np.ndarray
    federated: np.ndarray
    nodes: dict[str, np.ndarray]
    X_PB: np.ndarray


def _wxyz(rotation: Rotation) -> np.ndarray:
    xyzw = rotation.as_quat()
    return np.column_stack([xyzw[:, 3], xyzw[:, :3]])


def true_X_PB(quadrotor_state: np.ndarray, vehicle_state: np.ndarray, platform: PlatformConfig) -> np.ndarray:
    """(N, 7) the UAV body in the pad frame from sampled states (quadrotor (N, 17), vehicle (N, 4))."""
    truth = pad_truth(quadrotor_state, vehicle_state, platform)
    R_WP = Rotation.from_rotvec(np.outer(truth.yaw, [0.0, 0.0, 1.0]))
    R_WB = rotations(quadrotor_state[:, Q_WB])
    p_PB = R_WP.inv().apply(quadrotor_state[:, P_WB] - truth.p_WP)
    return np.column_stack([p_PB, _wxyz(R_WP.inv() * R_WB)])


def federated_log(log: dict, platform: PlatformConfig) -> FederatedLog:
    """From the federated source's logs as arrays (diagrams/perception_sources.py: "t", "federated",
    one per node, "quadrotor_state", "vehicle_state")."""
    return FederatedLog(log["t"], log["federated"], {name: log[name] for name in NODES},
                        true_X_PB(log["quadrotor_state"], log["vehicle_state"], platform))


def _pose_rows(valid: np.ndarray, p: np.ndarray, wxyz: np.ndarray) -> np.ndarray:
    """(N, 8) estimator_metrics rows [valid, x, y, z, qw, qx, qy, qz]."""
    return np.column_stack([valid.astype(float), p, wxyz])


def _paper_figures(truth: np.ndarray, rows: np.ndarray, window: np.ndarray) -> dict:
    """Seed 001's figures over the scored frames: 3-D position RMSE, orientation RMSE (the rotation
    angle's) and the height's (z of p_PB)."""
    scored = window & is_set(rows[:, 0])
    if not scored.any():
        return {}
    error = rows[scored, 1:4] - truth[scored, :3]
    angle = (rotations(truth[scored, 3:]).inv() * rotations(rows[scored, 4:])).magnitude()
    return {"rmse_position_m": float(np.sqrt(np.mean(np.sum(error**2, axis=1)))),
            "rmse_orientation_rad": float(np.sqrt(np.mean(angle**2))),
            "rmse_height_m": float(np.sqrt(np.mean(error[:, 2] ** 2)))}


def _band(heights: np.ndarray, present: np.ndarray) -> list[float] | None:
    """[lowest, highest] true height [m] of the frames where a node measured."""
    return [float(heights[present].min()), float(heights[present].max())] if present.any() else None


def true_p_CP(log: FederatedLog, X_BC: RigidTransform) -> np.ndarray:
    """(N, 3) the pattern's centre in the camera C [m], what the approaching node measures."""
    X_CB = X_BC.inverse()
    p_BP = rotations(log.X_PB[:, 3:]).inv().apply(-log.X_PB[:, :3])
    return p_BP @ X_CB.rotation().matrix().T + X_CB.translation()


def _fraction(frames: np.ndarray, window: np.ndarray) -> float:
    """The share of `window`'s frames (bool, (N,)) in `frames` (bool, (N,)); 0 for an empty window."""
    return float(np.mean(frames[window])) if window.any() else 0.0


def _estimator_figures(truth: np.ndarray, rows: np.ndarray, scored: np.ndarray, window: np.ndarray) -> dict:
    """estimator_metrics and the paper's figures of `rows` (_pose_rows) over the `scored` frames, with
    `valid_fraction` over `window`'s (estimator_metrics' counts every logged frame, after touchdown too)."""
    figures = {**estimator_metrics(truth, rows, scored), **_paper_figures(truth, rows, scored)}
    figures["valid_fraction"] = _fraction(is_set(rows[:, 0]), window)
    return figures


def node_metrics(log: FederatedLog, X_BC: RigidTransform, window: np.ndarray) -> dict:
    """Each node's own measurement: the pose nodes' X_PB as estimators; the approaching node's p_CP
    (MAE/RMSE per axis in C); each one's share of frames and its altitude band."""
    heights = log.X_PB[:, 2]
    out = {}
    for name in NODES:
        rows = log.nodes[name]
        present = is_set(rows[:, 0])
        figures = {"present_fraction": _fraction(present, window),
                   "altitude_band_m": _band(heights, present & window)}
        if name == "approach":
            p_CP = true_p_CP(log, X_BC)
            error = rows[present & window, 1:4] - p_CP[present & window]
            if len(error):
                figures.update({"frame": "C", "mae_xyz_m": np.mean(np.abs(error), axis=0).tolist(),
                                "rmse_xyz_m": np.sqrt(np.mean(error**2, axis=0)).tolist(),
                                "rmse_position_m": float(np.sqrt(np.mean(np.sum(error**2, axis=1))))})
        else:
            pose = _pose_rows(present, np.nan_to_num(rows[:, 1:4]), np.where(present[:, None], rows[:, 4:8], 1.0))
            figures.update(_estimator_figures(log.X_PB, pose, window, window))
        out[name] = figures
    return out


def filter_metrics(log: FederatedLog, window: np.ndarray) -> dict:
    """The local filters (after their own updates, `local_<node>`) and the fused estimate
    (`federated`): MAE/RMSE per axis, valid fraction (over `window`), and the paper's figures. The local
    filters are scored on the frames where the fused estimate is valid, as the overlaps are, so that each
    of their figures compares with the fused one's (a coasting stretch counts against neither)."""
    fed = log.federated
    started = is_set(fed[:, FED_STARTED])
    valid = is_set(fed[:, FED_VALID])
    out = {}
    for i, name in enumerate(NODES):
        p = fed[:, FED_LOCAL_P][:, 3 * i:3 * i + 3]
        theta = fed[:, FED_LOCAL_THETA][:, 3 * i:3 * i + 3]
        has = started & np.isfinite(p).all(axis=1)
        wxyz = np.ones((len(p), 4))
        if has.any():
            wxyz[has] = _wxyz(Rotation.from_rotvec(theta[has]))
        rows = _pose_rows(has, np.nan_to_num(p), wxyz)
        out[f"local_{name}"] = _estimator_figures(log.X_PB, rows, window & valid, window)
    rows = _pose_rows(valid, np.nan_to_num(fed[:, FED_P_PB]), np.where(started[:, None], fed[:, FED_Q_PB], 1.0))
    out["federated"] = _estimator_figures(log.X_PB, rows, window, window)
    return out


OVERLAPS = {"overlap_1": ("approach", "adjustment"), "overlap_2": ("adjustment", "touchdown")}


def measured_by_all(log: FederatedLog, nodes) -> np.ndarray:
    """(N,) bool: the frames where every one of `nodes` measured."""
    return np.logical_and.reduce([is_set(log.nodes[n][:, 0]) for n in nodes])


def overlap_metrics(log: FederatedLog, window: np.ndarray) -> dict:
    """Seed 001 Sec. 5.3's comparison: where two neighbouring nodes both measure (Overlap 1, the
    approaching and adjustment nodes; Overlap 2, adjustment and touchdown), the height RMSE of every
    local filter (after its own update, Fig. 10d's LF curves: the paper's two, the overlap's nodes', and
    the third, which measures there too in ours: the touchdown node chains from the adjustment node's
    every pose) and of the fused estimate (GB) on the same frames, with the frames' count and true
    altitude band [m]. The paper's figures are Overlap 1's: LF1 0.065, LF2 0.0835, GB 0.037 m."""
    fed, heights = log.federated, log.X_PB[:, 2]
    out = {}
    for name, nodes in OVERLAPS.items():
        both = window & is_set(fed[:, FED_VALID]) & measured_by_all(log, nodes)
        figures = {"nodes": list(nodes), "frames": int(both.sum()), "altitude_band_m": _band(heights, both)}
        if both.any():
            z = {f"local_{n}": fed[both, FED_LOCAL_P][:, 3 * i + 2] for i, n in enumerate(NODES)}
            z["federated"] = fed[both, FED_P_PB][:, 2]
            figures["rmse_height_m"] = {k: float(np.sqrt(np.mean((v - heights[both]) ** 2))) for k, v in z.items()}
        out[name] = figures
    return out


def federated_metrics(log: FederatedLog, X_BC: RigidTransform, end_s: float | None = None) -> dict:
    """The `estimators` section: the nodes, the local filters and the fused estimate over the
    frames up to `end_s` (touchdown; None: all)."""
    window = np.ones(len(log.t), bool) if end_s is None else log.t <= end_s
    out = {**node_metrics(log, X_BC, window), **filter_metrics(log, window)}
    out["federated"]["overlaps"] = overlap_metrics(log, window)
    return out
