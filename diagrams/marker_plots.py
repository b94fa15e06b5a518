"""Seed 002 Fig. 3-5 of a run or a campaign: the pad's path, its heading and each marker's position
error, per marker filter, against the truth."""

import matplotlib.pyplot as plt
import numpy as np

from diagrams.marker_metrics import FilterErrors, SampledRun, pad_truth, valid_only
from diagrams.outputs import save_figure
from systems.estimators.marker_ekf.engine import EST_P_WP, EST_YAW
from systems.geometry import wrap_angle
from systems.vehicles.paths import make_path

FILTER_STYLE = {"paper_ekf": ("tab:red", "paper EKF"), "ct_ekf": ("tab:green", "constant-turn EKF")}


def style(name: str) -> tuple[str, str]:
    return FILTER_STYLE.get(name, ("tab:purple", name))


def plot_path(ax, reference_xy, true_xy, estimates: dict[str, np.ndarray], title: str, path_name: str) -> None:
    """Fig. 3: reference path (`vehicle.path`'s name; "sine" is seed 002's Eq. 13), true pad path, estimated
    pad path per filter."""
    near = reference_xy[:, 0] <= np.nanmax(true_xy[:, 0]) + 10.0
    reference = "Eq. 13" if path_name == "sine" else path_name
    ax.plot(*reference_xy[near].T, "-", color="0.75", lw=4, label=f"reference ({reference})")
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


def plot_run(config, run: SampledRun, errors: dict[str, FilterErrors], out_dir) -> None:
    """path.png, heading.png and marker_errors.png of one run (config: the gv scenario), each filter's
    estimates where it flags them valid (`errors`' valid), as its metrics score them."""
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, config.platform)
    title = config.vehicle.speed_label()
    reference = make_path(config.vehicle.path_config()).polyline(max_length_m=1e9)
    estimates = {n: valid_only(e, errors[n].valid) for n, e in run.estimates.items()}
    fig, ax = plt.subplots(figsize=(9, 6))
    plot_path(ax, reference, truth.p_WP[:, :2], {n: e[:, EST_P_WP][:, :2] for n, e in estimates.items()},
              f"Pad path ({title}, Fig. 3)", config.vehicle.path)
    save_figure(fig, out_dir / "path.png")
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    plot_heading(axes, run.t, truth.yaw, {n: e[:, EST_YAW] for n, e in estimates.items()},
                 f"Heading ({title}, Fig. 4)")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "heading.png")
    fig, axes = plt.subplots(len(errors), 1, figsize=(10, 3 * len(errors)), sharex=True, squeeze=False)
    plot_markers(axes[:, 0], run.t, {n: valid_only(e.markers, e.valid) for n, e in errors.items()},
                 config.platform.markers.ids, f"Marker position error ({title}, Fig. 5)")
    axes[-1, 0].set_xlabel("time (s)")
    save_figure(fig, out_dir / "marker_errors.png")
