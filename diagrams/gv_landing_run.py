"""Running gv-landing: fly until touchdown, failure or `duration_s`, then write metrics.json (with
its "landing" and "tracking" sections), log.npz and the plots of seed 003 Fig. 8, 9, 14 and 15.

    landing-sim run gv-landing --set vehicle.path=figure-eight --set vehicle.speed=1.5 --meshcat

Scripts and benchmarks use `fly(config, duration_s)`, which returns the same metrics without
writing anything.
"""

import gc
import time
from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorStatus
from tqdm import tqdm

from diagrams.gv_landing import (
    HEIGHT, LOG_NAMES, P_BP_W, V_WP, VALID, GvLandingConfig, GvLandingHandles, build_gv_landing,
)
from diagrams.outputs import save_figure, write_npz
from diagrams.scenario import RunSettings
from systems.config import ConfigError, require_positive
from systems.control.landing import Mode
from systems.vehicles.quadrotor import P_WB, V_WB

# Issue 4's targets, for the `meets_targets` flag (never a pass/fail of the run itself).
TARGET_TOUCHDOWN_ERROR_M = 0.10
TARGET_TOUCHDOWN_REL_SPEED_MPS = 0.5
SETTLED_WINDOW_S = 2.0  # the tracking error "before the final descent" is taken over this window
SETTLED_TOLERANCE_M = 0.01  # seed 003 Fig. 8: settles to about 0.01 m in x and y
FAILURE_REASONS = ("crash", "diverged", "target_lost", "timeout", "missed_pad")


@dataclass
class Scenario(RunSettings, GvLandingConfig):
    """A gv-landing scenario file: the diagram's configuration plus the run settings. `duration_s`
    is the time limit: a run that has not landed by then fails with "timeout"."""

    diagram: str = "gv_landing"
    duration_s: float = 120.0

    def validate(self) -> None:
        require_positive(self.duration_s, "duration_s")
        GvLandingConfig.validate(self)


@dataclass
class Flight:
    """What `simulate_flight` returns."""

    status: str  # the monitor's message ("landed: ...", "crash: ...", ...), or "timeout: ..."
    sim_time_s: float
    wall_time_s: float
    log: dict[str, np.ndarray]
    context: object


def simulate_flight(diagram, handles: GvLandingHandles, duration_s: float, realtime: bool = False,
                    progress: bool = False, record: bool = False) -> Flight:
    """Simulates until the monitor ends the run or `duration_s`. An integrator failure (a state that
    blew up between two checks) ends it as "diverged"."""
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    handles.initialize(context)
    integration = handles.config.integration
    if not integration.discrete:
        ApplySimulatorConfig(integration.simulator_config(), simulator)
    if realtime:
        simulator.set_target_realtime_rate(1.0)
    visualizer = handles.meshcat_visualizer
    if visualizer is not None and record:
        visualizer.StartRecording()
    status = f"timeout: no touchdown within {duration_s:g} s"
    # Objects from imports and the build go to the permanent generation, so the garbage collector's
    # passes during the run do not walk them (~20 % of the run time otherwise).
    gc.freeze()
    start = time.perf_counter()
    try:
        simulator.Initialize()
        chunk = 0.5
        with tqdm(total=duration_s, unit="sim s", disable=not progress, leave=False,
                  bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim s [{elapsed}]") as bar:
            while context.get_time() < duration_s - 1e-9:
                result = simulator.AdvanceTo(min(duration_s, context.get_time() + chunk))
                bar.update(context.get_time() - bar.n)
                if result.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                    status = result.message()
                    break
    except RuntimeError as e:
        status = f"diverged: the integrator failed at t = {context.get_time():.2f} s ({str(e).splitlines()[0]})"
    finally:
        wall = time.perf_counter() - start
        gc.unfreeze()
    if visualizer is not None and record:
        visualizer.StopRecording()
        visualizer.PublishRecording()
    return Flight(status, context.get_time(), wall, collect_log(handles, context), context)


def collect_log(handles: GvLandingHandles, context) -> dict[str, np.ndarray]:
    """The logs as arrays, one row per supervisor sample (time `t`)."""
    logs = {name: handles.loggers[name].FindLog(context) for name in LOG_NAMES}
    arrays = {name: log.data().T.copy() for name, log in logs.items()}
    arrays["t"] = logs["quadrotor_state"].sample_times().copy()
    arrays["mode"] = arrays["mode"][:, 0].round().astype(int)
    arrays["vehicle_speed"] = arrays["vehicle_speed"][:, 0]
    arrays["p_VP"] = handles.config.platform.p_VP
    return arrays


def _first(mask) -> int | None:
    index = np.flatnonzero(mask)
    return int(index[0]) if index.size else None


def landing_metrics(log: dict[str, np.ndarray], status: str, config: GvLandingConfig) -> dict:
    """The "landing" section: touchdown figures from the supervisor's touchdown sample (the one
    before the first logged LANDED), success (touched down on the pad) and the failure reason."""
    kind = status.split(":", 1)[0]
    out = {"success": False, "touchdown_error_m": None, "touchdown_rel_speed_mps": None, "time_to_land_s": None,
           "failure_reason": None, "failure_detail": None}
    landed = _first(log["mode"] == Mode.LANDED)
    if kind == "landed" or landed is not None:
        # The monitor may end the run at the very update where the supervisor declares LANDED
        # (unrestricted updates come first), before a LANDED sample is logged: then the last sample.
        k = max(landed - 1, 0) if landed is not None else len(log["t"]) - 1
        relative, quad = log["relative_state"][k], log["quadrotor_state"][k]
        heading = log["vehicle_state"][k, 2]
        offset_W = -relative[P_BP_W][:2]  # UAV minus pad centre
        c, s = np.cos(heading), np.sin(heading)
        offset_P = np.array([c * offset_W[0] + s * offset_W[1], -s * offset_W[0] + c * offset_W[1]])
        on_pad = bool(np.all(np.abs(offset_P) <= config.platform.pad_size_m / 2))
        out.update({
            "success": on_pad,
            "touchdown_error_m": float(np.linalg.norm(offset_W)),
            "touchdown_rel_speed_mps": float(abs(quad[V_WB][2] - relative[V_WP][2])),
            "time_to_land_s": float(log["t"][k]),
            "touchdown_offset_pad_xy_m": offset_P.tolist(),  # UAV centre in the pad frame
            "touchdown_rel_speed_horizontal_mps": float(np.linalg.norm(quad[V_WB][:2] - relative[V_WP][:2])),
            "touchdown_height_m": float(relative[HEIGHT]),
            "vehicle_speed_at_touchdown_m_s": float(log["vehicle_speed"][k]),
            # The vehicle's turn radius (bicycle: d / tan(steering)) at touchdown; null on a straight
            # (steering under 1 mrad: a radius over 3.5 km).
            "vehicle_turn_radius_at_touchdown_m": (
                float(abs(config.vehicle.wheelbase_m / np.tan(steering)))
                if abs(steering := log["vehicle_state"][k, 3]) > 1e-3 else None),
        })
        if not on_pad:
            out["failure_reason"], out["failure_detail"] = "missed_pad", (
                f"touched down {np.linalg.norm(offset_W):.2f} m from the pad centre, off the "
                f"{config.platform.pad_size_m:g} m pad")
    else:
        out["failure_reason"] = kind if kind in FAILURE_REASONS else "diverged"
        out["failure_detail"] = status
    out["meets_targets"] = bool(out["success"] and out["touchdown_error_m"] < TARGET_TOUCHDOWN_ERROR_M
                                and out["touchdown_rel_speed_mps"] < TARGET_TOUCHDOWN_REL_SPEED_MPS)
    out["mode_entry_times_s"] = {mode.name.lower(): float(log["t"][i]) for mode in Mode
                                 if (i := _first(log["mode"] == mode)) is not None}
    if out["time_to_land_s"] is not None:
        out["mode_entry_times_s"]["landed"] = out["time_to_land_s"]
    return out


def tracking_metrics(log: dict[str, np.ndarray]) -> dict:
    """The horizontal tracking error (pad centre minus UAV, World x and y) before the final descent:
    RMSE and largest error over APPROACH (descending while tracking; the acquisition in FOLLOW is
    left out), the error at the start of LAND and its largest value over the SETTLED_WINDOW_S
    before, and the time from the first FOLLOW after which it stays within SETTLED_TOLERANCE_M."""
    t, mode = log["t"], log["mode"]
    error = log["relative_state"][:, P_BP_W][:, :2]
    land = _first(mode == Mode.LAND)
    end = land if land is not None else len(t)
    before = np.arange(len(t)) < end
    out = {}
    approach = (mode == Mode.APPROACH) & before
    if approach.any():
        e = error[approach]
        out.update({"approach_rmse_xy_m": np.sqrt(np.mean(e**2, axis=0)).tolist(),
                    "approach_max_abs_xy_m": np.abs(e).max(axis=0).tolist()})
    start = _first(mode == Mode.FOLLOW)
    if start is not None and start < end:
        outside = np.flatnonzero(np.any(np.abs(error[start:end]) > SETTLED_TOLERANCE_M, axis=1))
        settled_at = start + (outside[-1] + 1 if outside.size else 0)
        out["settled_within_m"] = SETTLED_TOLERANCE_M
        out["settling_time_s"] = float(t[settled_at] - t[start]) if settled_at < end else None
    if land is not None:
        window = (t >= t[land] - SETTLED_WINDOW_S) & before
        out["at_final_descent_xy_m"] = error[land].tolist()
        out["before_final_descent_max_abs_xy_m"] = np.abs(error[window]).max(axis=0).tolist()
        out["before_final_descent_window_s"] = SETTLED_WINDOW_S
    return out


def flight_metrics(flight: Flight, config: GvLandingConfig, name: str = "gv-landing") -> dict:
    """metrics.json's content for a flight (DESIGN.md's shape)."""
    log = flight.log
    seen = log["relative_state"][:, VALID] > 0.5
    return {
        "scenario": name, "seed": config.seed, "sim_time_s": flight.sim_time_s, "wall_time_s": flight.wall_time_s,
        "realtime_factor": flight.sim_time_s / flight.wall_time_s if flight.wall_time_s > 0 else None,
        "vehicle": {"path": config.vehicle.path, "speed_m_s": config.vehicle.speed},
        "landing": landing_metrics(log, flight.status, config),
        "tracking": tracking_metrics(log),
        "perception": {"kind": "perfect", "valid_fraction": float(np.mean(seen)) if len(seen) else 0.0},
        "end": flight.status,
    }


def fly(config: GvLandingConfig, duration_s: float, **kwargs) -> tuple[dict, Flight]:
    """Builds, simulates and measures one landing without Meshcat or files: (metrics, flight)."""
    diagram, handles = build_gv_landing(config)
    flight = simulate_flight(diagram, handles, duration_s, **kwargs)
    return flight_metrics(flight, config), flight


# ----------------------------------------------------------------------------------------------
# Plots


def _mode_lines(ax, log):
    """Dotted lines at the FOLLOW/APPROACH/LAND/LANDED transitions."""
    for mode, colour in ((Mode.APPROACH, "tab:green"), (Mode.LAND, "tab:orange"), (Mode.LANDED, "tab:red")):
        i = _first(log["mode"] == mode)
        if i is not None:
            ax.axvline(log["t"][i], color=colour, ls=":", lw=1)


def plot_flight(log: dict[str, np.ndarray], config: GvLandingConfig, out_dir, path_xy: np.ndarray | None = None) -> None:
    """Seed 003 Fig. 8a/9 (trajectories_3d.png, trajectories_top.png), Fig. 14a/15a (altitude.png),
    Fig. 8c/14b/15b (velocity.png) and Fig. 8b's error (tracking_error.png)."""
    t, quad = log["t"], log["quadrotor_state"]
    p_uav = quad[:, P_WB]
    p_pad = p_uav + log["relative_state"][:, P_BP_W]
    landed = _first(log["mode"] == Mode.LANDED)
    title = f"{config.vehicle.path}, {config.vehicle.speed:g} m/s"

    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*p_pad.T, "-", color="tab:orange", lw=1.5, label="UGV (pad centre)")
    ax.plot(*p_uav.T, "-", color="tab:blue", lw=1.2, label="UAV")
    ax.scatter(*p_uav[0], color="tab:blue", marker="o", s=20)
    if landed is not None:
        ax.scatter(*p_uav[landed - 1], color="tab:red", marker="x", s=40, label="touchdown")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"UAV and UGV trajectories ({title})")
    ax.legend(loc="upper left")
    save_figure(fig, out_dir / "trajectories_3d.png")

    fig, ax = plt.subplots(figsize=(8, 6.5))
    if path_xy is not None:
        span = np.ptp(np.vstack([p_uav[:, :2], p_pad[:, :2]]), axis=0).max() + 20.0
        centre = p_pad[:, :2].mean(axis=0)
        near = np.all(np.abs(path_xy - centre) < span, axis=1)
        ax.plot(*path_xy[near].T, "-", color="0.8", lw=4, label="path")
    ax.plot(*p_pad[:, :2].T, "-", color="tab:orange", lw=1.5, label="UGV (pad centre)")
    ax.plot(*p_uav[:, :2].T, "--", color="tab:blue", lw=1.2, label="UAV")
    ax.plot(*p_uav[0, :2], "o", color="tab:blue", ms=5, label="UAV start")
    if landed is not None:
        ax.plot(*p_uav[landed - 1, :2], "x", color="tab:red", ms=8, label="touchdown")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Top view ({title})")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save_figure(fig, out_dir / "trajectories_top.png")

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t, p_uav[:, 2], "-", color="tab:blue", label="UAV altitude")
    ax.plot(t, log["relative_state"][:, HEIGHT], "--", color="tab:purple", lw=1, label="UAV above the pad")
    ax.axhline(config.platform.height_m, color="tab:orange", lw=1, label="pad")
    ax.axhline(config.landing.initial_height_m, color="0.5", ls="--", lw=1, label="IH")
    ax.axhline(config.platform.height_m + config.landing.landing_height_m, color="0.3", ls="-.", lw=1,
               label="LH above the pad")
    _mode_lines(ax, log)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("height (m)")
    ax.set_title(f"Altitude (dotted: approach, final landing, touchdown; {title})")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    save_figure(fig, out_dir / "altitude.png")

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    v_uav, v_pad, command = quad[:, V_WB], log["relative_state"][:, V_WP], log["command"]
    for i, (ax, label) in enumerate(zip(axes, ("x", "y", "z"))):
        ax.plot(t, v_pad[:, i], "-", color="tab:orange", lw=1.5, label="UGV (pad)")
        ax.plot(t, v_uav[:, i], "-", color="tab:blue", lw=1, label="UAV")
        ax.plot(t, command[:, i], ":", color="k", lw=1, label="UAV desired")
        _mode_lines(ax, log)
        ax.set_ylabel(f"v{label} (m/s)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(f"UAV and UGV velocity in World ({title})")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "velocity.png")

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    error = log["relative_state"][:, P_BP_W]
    seen = log["relative_state"][:, VALID] > 0.5
    for i, (ax, label) in enumerate(zip(axes, ("x", "y"))):
        ax.plot(t, error[:, i], "-", color="tab:blue", lw=1, label="pad - UAV")
        ax.plot(t[~seen], error[~seen, i], ".", color="tab:red", ms=2, label="pad not in view")
        ax.axhspan(-SETTLED_TOLERANCE_M, SETTLED_TOLERANCE_M, color="tab:green", alpha=0.2, label="+-0.01 m")
        _mode_lines(ax, log)
        ax.set_yscale("symlog", linthresh=SETTLED_TOLERANCE_M)  # metres and millimetres on one axis
        ax.set_ylabel(f"e{label} (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title(f"Horizontal tracking error, symmetric log scale (linear within +-0.01 m; {title})")
    axes[-1].set_xlabel("time (s)")
    save_figure(fig, out_dir / "tracking_error.png")


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.gv_landing import path_polyline
    from diagrams.runner import finish_run

    if ctx.options.video:
        raise ConfigError("--video records a camera stream, and gv-landing has none (perfect perception)")
    diagram, handles = build_gv_landing(scenario, ctx.meshcat)
    flight = simulate_flight(diagram, handles, scenario.duration_s, realtime=ctx.options.meshcat,
                             progress=ctx.options.progress, record=ctx.options.record)
    metrics = flight_metrics(flight, scenario, ctx.name)
    write_npz(ctx.out_dir / "log.npz", **flight.log)
    plot_flight(flight.log, scenario, ctx.out_dir, path_polyline(scenario.vehicle, max_length_m=1e9))
    landing = metrics["landing"]
    if landing["success"]:
        print(f"{ctx.name}: landed {landing['touchdown_error_m']:.3f} m from the pad centre at "
              f"{landing['touchdown_rel_speed_mps']:.2f} m/s after {landing['time_to_land_s']:.1f} s")
    else:
        print(f"{ctx.name}: no landing ({landing['failure_reason']}: {landing['failure_detail']})")
    return finish_run(handles, ctx, metrics)
