"""The plots of a gv flight: seed 003 Fig. 8, 9, 14 and 15 (trajectories, altitude, velocity,
tracking error, all from the truth), and what steered against the truth over the flight with the
supervisor's modes shaded."""

import matplotlib.pyplot as plt
import numpy as np

from diagrams.landing_metrics import SETTLED_TOLERANCE_M, entered
from diagrams.metrics import quaternion_yaw
from diagrams.outputs import save_figure
from diagrams.perception_metrics import carrier_heading
from systems.control.landing import Mode
from systems.flags import is_set
from systems.perception.seam import HEIGHT, P_BP_W, V_WP, VALID
from systems.vehicles.quadrotor import P_WB, V_WB

MODE_COLOURS = {Mode.TAKEOFF: "0.85", Mode.CLIMB: "tab:cyan", Mode.FOLLOW: "tab:blue", Mode.APPROACH: "tab:green",
                Mode.LAND: "tab:orange", Mode.LANDED: "tab:red", Mode.HOLD: "tab:pink", Mode.SEARCH: "tab:purple",
                Mode.ABORT: "tab:brown", Mode.WAIT: "tab:olive"}


def _mode_lines(ax, log, touchdown: int | None) -> None:
    """Dotted lines at the APPROACH and LAND transitions and at the touchdown (its log index, or None)."""
    for mode, colour in ((Mode.APPROACH, "tab:green"), (Mode.LAND, "tab:orange")):
        i = entered(log["mode"], mode)
        if i is not None:
            ax.axvline(log["t"][i], color=colour, ls=":", lw=1)
    if touchdown is not None:
        ax.axvline(log["t"][touchdown], color="tab:red", ls=":", lw=1)


def plot_flight(log: dict[str, np.ndarray], config, out_dir, touchdown: int | None,
                path_xy: np.ndarray | None = None) -> None:
    """Seed 003 Fig. 8a/9 (trajectories_3d.png, trajectories_top.png), Fig. 14a/15a (altitude.png),
    Fig. 8c/14b/15b (velocity.png) and Fig. 8b's error (tracking_error.png); the pad on the UGV, or on the
    ground (`platform.carrier`). `touchdown`: the log index of the touchdown as the metrics score it
    (landing_metrics.gv_touchdown: the supervisor's LANDED or the gear's touch), or None."""
    t, quad = log["t"], log["quadrotor_state"]
    p_uav = quad[:, P_WB]
    p_pad = p_uav + log["true_relative_state"][:, P_BP_W]
    on_ground = config.platform.carrier == "ground"
    carrier = "pad" if on_ground else "UGV"
    pad = "pad centre" if on_ground else "UGV (pad centre)"
    title = "the pad on the ground" if on_ground else f"{config.vehicle.path}, {config.vehicle.speed_label()}"

    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*p_pad.T, "-", color="tab:orange", lw=1.5, label=pad)
    ax.plot(*p_uav.T, "-", color="tab:blue", lw=1.2, label="UAV")
    ax.scatter(*p_uav[0], color="tab:blue", marker="o", s=20)
    if touchdown is not None:
        ax.scatter(*p_uav[touchdown], color="tab:red", marker="x", s=40, label="touchdown")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"UAV and {carrier} trajectories ({title})")
    ax.legend(loc="upper left")
    save_figure(fig, out_dir / "trajectories_3d.png")

    fig, ax = plt.subplots(figsize=(8, 6.5))
    if path_xy is not None:
        span = np.ptp(np.vstack([p_uav[:, :2], p_pad[:, :2]]), axis=0).max() + 20.0
        centre = p_pad[:, :2].mean(axis=0)
        near = np.all(np.abs(path_xy - centre) < span, axis=1)
        ax.plot(*path_xy[near].T, "-", color="0.8", lw=4, label="path")
    ax.plot(*p_pad[:, :2].T, "-", color="tab:orange", lw=1.5, label=pad)
    ax.plot(*p_uav[:, :2].T, "--", color="tab:blue", lw=1.2, label="UAV")
    ax.plot(*p_uav[0, :2], "o", color="tab:blue", ms=5, label="UAV start")
    if touchdown is not None:
        ax.plot(*p_uav[touchdown, :2], "x", color="tab:red", ms=8, label="touchdown")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Top view ({title})")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save_figure(fig, out_dir / "trajectories_top.png")

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t, p_uav[:, 2], "-", color="tab:blue", label="UAV altitude")
    ax.plot(t, log["true_relative_state"][:, HEIGHT], "--", color="tab:purple", lw=1, label="UAV above the pad")
    ax.axhline(config.platform.height_m, color="tab:orange", lw=1, label="pad")
    ax.axhline(config.landing.initial_height_m, color="0.5", ls="--", lw=1, label="IH")
    ax.axhline(config.platform.height_m + config.landing.landing_height_m, color="0.3", ls="-.", lw=1,
               label="LH above the pad")
    _mode_lines(ax, log, touchdown)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("height (m)")
    ax.set_title(f"Altitude (dotted: approach, final landing, touchdown; {title})")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    save_figure(fig, out_dir / "altitude.png")

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    v_uav, v_pad, command = quad[:, V_WB], log["true_relative_state"][:, V_WP], log["command"]
    for i, (ax, label) in enumerate(zip(axes, ("x", "y", "z"))):
        ax.plot(t, v_pad[:, i], "-", color="tab:orange", lw=1.5, label=pad)
        ax.plot(t, v_uav[:, i], "-", color="tab:blue", lw=1, label="UAV")
        ax.plot(t, command[:, i], ":", color="k", lw=1, label="UAV desired")
        _mode_lines(ax, log, touchdown)
        ax.set_ylabel(f"v{label} (m/s)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(f"UAV and {carrier} velocity in World ({title})")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "velocity.png")

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    error = log["true_relative_state"][:, P_BP_W]
    seen = is_set(log["relative_state"][:, VALID])  # what steered
    for i, (ax, label) in enumerate(zip(axes, ("x", "y"))):
        ax.plot(t, error[:, i], "-", color="tab:blue", lw=1, label="pad - UAV")
        ax.plot(t[~seen], error[~seen, i], ".", color="tab:red", ms=2, label="no valid estimate")
        ax.axhspan(-SETTLED_TOLERANCE_M, SETTLED_TOLERANCE_M, color="tab:green", alpha=0.2,
                   label=f"+-{SETTLED_TOLERANCE_M:g} m")
        _mode_lines(ax, log, touchdown)
        ax.set_yscale("symlog", linthresh=SETTLED_TOLERANCE_M)  # metres and millimetres on one axis
        ax.set_ylabel(f"e{label} (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(f"Horizontal tracking error, symmetric log scale "
                      f"(linear within +-{SETTLED_TOLERANCE_M:g} m; {title})")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "tracking_error.png")


def shade_modes(ax, log) -> None:
    """The supervisor's modes as coloured bands behind a time axis."""
    t, mode = log["t"], log["mode"]
    changes = np.flatnonzero(np.diff(mode)) + 1
    for start, end in zip(np.r_[0, changes], np.r_[changes, len(t) - 1]):
        ax.axvspan(t[start], t[end], color=MODE_COLOURS[Mode(int(mode[start]))], alpha=0.15, lw=0)


ERROR_FLOOR_M = 1e-4  # perception.png's position error is drawn from here up (a log scale)


def plot_perception(log: dict[str, np.ndarray], source: str, out_dir, heading: bool = True) -> None:
    """perception.png: the pad's position in W (x, y, z, m), the seam's estimate and the truth, and, where the
    source estimates one (`heading`) and an estimate steered (`steering_estimate`), its heading error as the
    steering estimate had them against the truth; the samples without a valid estimate ticked on the last panel (at zero
    heading error, or at the position error's floor), the supervisor's modes shaded."""
    t, quad = log["t"], log["quadrotor_state"]
    valid = is_set(log["relative_state"][:, VALID])
    estimate = quad[:, P_WB] + np.where(valid[:, None], log["relative_state"][:, P_BP_W], np.nan)
    truth = quad[:, P_WB] + log["true_relative_state"][:, P_BP_W]
    heading = heading and "steering_estimate" in log  # not for a source whose estimate is a position alone
    fig, axes = plt.subplots(5 if heading else 4, 1, figsize=(10, 11 if heading else 9), sharex=True)
    for i, (ax, label) in enumerate(zip(axes[:3], ("pad x (m)", "pad y (m)", "pad z (m)"))):
        ax.plot(t, truth[:, i], "-", color="k", lw=1.2, label="true")
        ax.plot(t, estimate[:, i], "--", color="tab:red", lw=1, label=f"{source} (valid)")
        ax.set_ylabel(label)
    error = np.linalg.norm(estimate - truth, axis=1)
    axes[3].semilogy(t, np.maximum(error, ERROR_FLOOR_M), "-", color="tab:red", lw=1)
    axes[3].set_ylabel("position error (m)")
    if heading:
        yaw = quaternion_yaw(log["steering_estimate"][:, 4:])
        axes[4].plot(t, np.degrees(np.angle(np.exp(1j * (yaw - carrier_heading(log))))), "-",
                     color="tab:red", lw=1)
        axes[4].set_ylabel("heading error (deg)")
    last = axes[-1]
    last.plot(t[~valid], np.full(np.count_nonzero(~valid), 0.0 if heading else ERROR_FLOOR_M), "|", color="0.3",
              ms=6, label="no valid estimate")
    last.set_xlabel("time (s)")
    for ax in axes:
        shade_modes(ax, log)
        ax.grid(alpha=0.3)
    handles = [plt.Rectangle((0, 0), 1, 1, color=c, alpha=0.3) for c in MODE_COLOURS.values()]
    axes[0].legend(loc="best", fontsize=8)
    last.legend(handles + last.get_legend_handles_labels()[0],
                [m.name.lower() for m in MODE_COLOURS] + ["no valid estimate"], loc="best", fontsize=7, ncol=5)
    axes[0].set_title(f"What steered ({source}) against the truth; the supervisor's modes shaded")
    save_figure(fig, out_dir / "perception.png")
