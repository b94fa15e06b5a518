"""federated.png: seed 001 Fig. 8-10 for a run with the federated filter: (a) the three vision
nodes' heights against the truth, (b) their and the fused estimate's absolute height errors, (c)
the traces of the local filters' position covariances, (d) the beta weights of Eq. (9), (e) the
local filters' and the fused height against the truth, with Overlap 1 shaded (the approaching and
adjustment nodes both measure: where seed 001 Sec. 5.3 compares them). Heights are z of p_PB (the UAV
above the pattern, m); the approaching node's is its depth along the camera's axis, and its error is
against the true depth."""

import matplotlib.pyplot as plt
import numpy as np
from pydrake.math import RigidTransform

from diagrams.federated_metrics import OVERLAPS, FederatedLog, measured_by_all, true_p_CP
from diagrams.outputs import save_figure
from systems.estimators.federated.engine import NODES
from systems.estimators.federated.system import FED_BETAS, FED_LOCAL_P, FED_LOCAL_TRACES, FED_P_PB, FED_VALID
from systems.flags import is_set

COLOURS = {"approach": "tab:blue", "adjustment": "tab:green", "touchdown": "tab:orange", "federated": "tab:red"}


def shade_frames(ax, t: np.ndarray, frames: np.ndarray, label: str) -> None:
    """The stretches of time where `frames` (bool, per t) holds, as grey bands behind the axis."""
    edges = np.flatnonzero(np.diff(frames.astype(int))) + 1
    for start, end in zip(np.r_[0, edges], np.r_[edges, len(t)]):
        if frames[start]:
            ax.axvspan(t[start], t[end - 1], color="0.85", lw=0, zorder=0, label=label)
            label = None


def plot_federated(log: FederatedLog, X_BC: RigidTransform, out_dir) -> None:
    """federated.png in out_dir for a run whose camera is at X_BC in the body."""
    t, true_height, fed = log.t, log.X_PB[:, 2], log.federated
    true_depth = true_p_CP(log, X_BC)[:, 2]  # the approaching node's
    fused = np.where(is_set(fed[:, FED_VALID:FED_VALID + 1]), fed[:, FED_P_PB], np.nan)[:, 2]
    fig, axes = plt.subplots(5, 1, figsize=(10, 13), sharex=True)
    axes[0].plot(t, true_height, "-", color="k", lw=1.2, label="true")
    for name in NODES:
        rows = log.nodes[name]
        height = np.where(is_set(rows[:, 0]), rows[:, 3], np.nan)
        axes[0].plot(t, height, ".", color=COLOURS[name], ms=2, label=name)
        truth = true_depth if name == "approach" else true_height
        axes[1].semilogy(t, np.maximum(np.abs(height - truth), 1e-4), ".", color=COLOURS[name], ms=2, label=name)
    axes[1].semilogy(t, np.maximum(np.abs(fused - true_height), 1e-4), "-", color=COLOURS["federated"], lw=1,
                     label="federated")
    for i, name in enumerate(NODES):
        axes[2].semilogy(t, fed[:, FED_LOCAL_TRACES][:, i], "-", color=COLOURS[name], lw=1, label=f"LF {name}")
        axes[3].plot(t, fed[:, FED_BETAS][:, i], "-", color=COLOURS[name], lw=1, label=f"beta {name}")
        axes[4].plot(t, fed[:, FED_LOCAL_P][:, 3 * i + 2], "-", color=COLOURS[name], lw=0.8, label=f"LF {name}")
    for ax in (axes[1], axes[4]):
        shade_frames(ax, t, measured_by_all(log, OVERLAPS["overlap_1"]), "Overlap 1")
    axes[4].plot(t, true_height, "-", color="k", lw=1.2, label="true")
    axes[4].plot(t, fused, "--", color=COLOURS["federated"], lw=1.2, label="federated (valid)")
    labels = ("(a) node heights (m)", "(b) |height error| (m)", "(c) trace P_i, position (m^2)",
              "(d) beta_i (Eq. 9)", "(e) height (m)")
    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7, ncol=4)
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title("Seed 001 Fig. 8-10: the vision nodes, the local filters and the federated estimate")
    save_figure(fig, out_dir / "federated.png")
