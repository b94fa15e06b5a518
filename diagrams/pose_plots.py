"""Plots of pose estimates against ground truth, as seed 000's Figures 24-30: translation and angles
over time, the trajectory in XZ, YZ, XY and 3-D, and each estimator's absolute errors."""

import matplotlib.pyplot as plt
import numpy as np

from diagrams.metrics import pose_errors, xyz_rpy
from diagrams.outputs import save_figure
from systems.flags import is_set

_STYLES = {"truth": dict(color="k", lw=1.2), "atda": dict(color="tab:red", lw=0.8),
           "crhf": dict(color="tab:blue", lw=0.8)}
_AXES = ["x (m)", "y (m)", "z (m)", "roll (deg)", "pitch (deg)", "yaw (deg)"]


def _style(name: str) -> dict:
    return _STYLES.get(name, dict(lw=0.8))


def plot_pose_estimates(t: np.ndarray, truth: np.ndarray, estimates: dict[str, np.ndarray], out_dir,
                        frame: str = "X_CT") -> None:
    """Writes pose_translation.png, pose_angles.png, pose_trajectory.png and errors_<name>.png.

    truth: (N, 7) [x, y, z, qw, qx, qy, qz]; estimates: name -> (N, 8) [valid, x, y, z, qw, qx, qy, qz]."""
    series = {"truth": xyz_rpy(truth)}
    series.update({name: xyz_rpy(np.where(is_set(e[:, :1]), e[:, 1:], np.nan)) for name, e in estimates.items()})
    for columns, filename, title in (((0, 1, 2), "pose_translation.png", "Translation (Fig. 24)"),
                                     ((3, 4, 5), "pose_angles.png", "Roll, pitch, yaw (Fig. 25)")):
        fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
        for ax, column in zip(axes, columns):
            scale = 1.0 if column < 3 else 180.0 / np.pi
            for name, values in series.items():
                ax.plot(t, values[:, column] * scale, label=name, **_style(name))
            ax.set_ylabel(_AXES[column])
            ax.grid(alpha=0.3)
        axes[0].set_title(f"{title}: {frame}, estimates against ground truth")
        axes[0].legend(loc="upper right")
        axes[-1].set_xlabel("time (s)")
        save_figure(fig, out_dir / filename)

    fig = plt.figure(figsize=(11, 9))
    for k, (i, j) in enumerate(((0, 2), (1, 2), (0, 1))):
        ax = fig.add_subplot(2, 2, k + 1)
        for name, values in series.items():
            ax.plot(values[:, i], values[:, j], label=name, **_style(name))
        ax.set_xlabel(_AXES[i])
        ax.set_ylabel(_AXES[j])
        ax.set_title(f"{'abc'[k]}) {_AXES[i][0].upper()}{_AXES[j][0].upper()} view")
        ax.grid(alpha=0.3)
    ax = fig.add_subplot(2, 2, 4, projection="3d")
    for name, values in series.items():
        ax.plot(values[:, 0], values[:, 1], values[:, 2], label=name, **_style(name))
    ax.set_title("d) XYZ view")
    ax.legend(loc="upper left")
    fig.suptitle(f"Trajectory of {frame} (Fig. 26)")
    save_figure(fig, out_dir / "pose_trajectory.png")

    for name, estimate in estimates.items():
        valid, xyz, rpy, _ = pose_errors(truth, estimate)
        fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        for column, label in enumerate("xyz"):
            axes[0].plot(t[valid], np.abs(xyz[:, column]), lw=0.8, label=label)
        for column, label in enumerate(("roll", "pitch", "yaw")):
            axes[1].plot(t[valid], np.abs(rpy[:, column]), lw=0.8, label=label)
        axes[0].set_ylabel("absolute error (m)")
        axes[1].set_ylabel("absolute error (deg)")
        axes[0].set_title(f"{name.upper()} absolute errors (Figs. 27-30)")
        for ax in axes:
            ax.legend(loc="upper right")
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("time (s)")
        save_figure(fig, out_dir / f"errors_{name}.png")
