"""Running deck-landing: fly until touchdown, a failure or `duration_s`, then write metrics.json, log.npz
and the plots.

    landing-sim run deck-landing [--set perception.source=atda] [--video] [--meshcat]

metrics.json: `landing` (diagrams/landing_metrics.pad_landing on the deck, with the deck's tilt and heave
rate at touchdown), `perception` (what steered, diagrams/perception_metrics.py) and `estimators` (ATDA
and CRHF against the true X_CT over the camera frames, as in the Stewart scenes). Scripts use
`fly(config, duration_s)`, which returns the metrics and the flight without writing anything.
"""

from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np
from pydrake.systems.framework import Diagram

from diagrams.deck_landing import DeckLandingHandles, build_deck_landing
from diagrams.deck_landing_config import ESTIMATORS, DeckLandingConfig
from diagrams.landing_metrics import pad_arguments, pad_landing, touchdown
from diagrams.landing_plots import plot_perception, shade_modes
from diagrams.metrics import estimator_metrics
from diagrams.outputs import save_figure, write_npz
from diagrams.perception_metrics import perception_metrics
from diagrams.scenario import RunSettings
from diagrams.simulate import Simulation, simulate
from diagrams.stewart_run import pose_from_vector
from systems.config import require_positive
from systems.control.monitor import GV_HEADING
from systems.estimators.deck_tracker import tilt_deg
from systems.flags import is_set
from systems.perception.seam import HEIGHT, VALID
from systems.sensors.ground_truth import pose_vector

TARGET_TILT_DEG = 3.0  # issue 13: the deck's tilt at touchdown


@dataclass
class Scenario(RunSettings, DeckLandingConfig):
    """A deck-landing scenario file: the diagram's configuration plus the run settings. `duration_s` is the
    time limit: a run that has not landed by then fails with "timeout"."""

    diagram: str = "deck_landing"
    duration_s: float = 120.0

    def validate(self) -> None:
        require_positive(self.duration_s, "duration_s")
        DeckLandingConfig.validate(self)
        self.check_motion(self.duration_s)


@dataclass
class DeckFlight:
    """A simulated flight: how it ended, its supervisor-rate `log` (time `t`) and camera-rate `frames`
    (time `t`, with the true `X_CT` and each estimator's `estimate_<name>`)."""

    status: str
    simulation: Simulation
    log: dict[str, np.ndarray]
    frames: dict[str, np.ndarray]
    handles: DeckLandingHandles


def _arrays(loggers: dict, context) -> dict[str, np.ndarray]:
    logs = {name: logger.FindLog(context) for name, logger in loggers.items()}
    arrays = {name: log.data().T.copy() for name, log in logs.items()}
    arrays["t"] = next(iter(logs.values())).sample_times().copy()
    return arrays


def fly_diagram(diagram, handles: DeckLandingHandles, duration_s: float, **options) -> DeckFlight:
    """Simulates a built deck-landing diagram (diagrams/simulate.py's options) until the monitor ends the
    run or `duration_s`."""
    simulation = simulate(diagram, duration_s, initialize=handles.initialize, video=handles.video,
                          visualizer=handles.meshcat_visualizer, **options)
    log = _arrays(handles.loggers, simulation.context)
    log["mode"] = log["mode"][:, 0].round().astype(int)
    frames = _arrays(handles.frame_loggers, simulation.context)
    X_PT = handles.platform.X_PT
    frames["X_CT"] = np.array([pose_vector(pose_from_vector(v).multiply(X_PT)) for v in frames["X_CP"]])
    return DeckFlight(simulation.status, simulation, log, frames, handles)


def _deck_pad(log: dict[str, np.ndarray], config: DeckLandingConfig) -> dict:
    """landing_metrics.touchdown's pad arguments for a deck flight: the deck, headed as the carrier."""
    return pad_arguments(log["carrier_state"][:, GV_HEADING], config.platform.deck_size_m,
                         config.platform.deck_thickness_m, config.landing)


def deck_touchdown(flight: DeckFlight, config: DeckLandingConfig) -> tuple[int, str] | None:
    """(log index, "supervisor" or "contact") of the touchdown on the deck (landing_metrics.touchdown, as
    `deck_landing_metrics` scores it), or None."""
    return touchdown(flight.log, status=flight.status, **_deck_pad(flight.log, config))


def deck_landing_metrics(flight: DeckFlight, config: DeckLandingConfig) -> dict:
    """The `landing` section on the deck, with its tilt and heave rate at touchdown and whether the issue's
    targets are met (`meets_targets`: on the deck within 0.10 m, under 0.5 m/s, tilt under 3 deg)."""
    log = flight.log
    out, k = pad_landing(log, flight.status, gravity_m_s2=config.quadrotor.gravity_m_s2, **_deck_pad(log, config))
    if k is not None:
        out["deck_tilt_at_touchdown_deg"] = float(tilt_deg(log["true_deck_motion"][k, :2]))
        out["deck_heave_rate_at_touchdown_m_s"] = float(log["true_deck_motion"][k, 5])
        out["meets_targets"] = bool(out["meets_targets"] and out["deck_tilt_at_touchdown_deg"] < TARGET_TILT_DEG)
    return out


def flight_metrics(flight: DeckFlight, config: DeckLandingConfig, name: str = "deck-landing") -> dict:
    """metrics.json's content for a flight (docs/architecture.md's shape)."""
    sim, frames = flight.simulation, flight.frames
    out = {"scenario": name, "seed": config.seed, "sim_time_s": sim.sim_time_s, "wall_time_s": sim.wall_time_s,
           "realtime_factor": sim.realtime_factor, "deck": {"motion": config.platform.motion,
                                                          "time_offset_s": config.deck().time_offset_s}}
    out["landing"] = deck_landing_metrics(flight, config)
    out["perception"] = perception_metrics(flight.log, config.perception.source, out["landing"]["time_to_land_s"])
    out["estimators"] = {name: estimator_metrics(frames["X_CT"], frames[f"estimate_{name}"]) for name in ESTIMATORS}
    out["end"] = flight.status
    return out


def build(config: DeckLandingConfig, duration_s: float) -> tuple[Diagram, DeckLandingHandles]:
    """The diagram `fly` flies, without Meshcat or a video, and its handles; the same for any `duration_s` [s]
    (which gv_landing_run.build takes too, so that a landing campaign builds either scenario alike)."""
    return build_deck_landing(config)


def fly(config: DeckLandingConfig, duration_s: float, **options) -> tuple[dict, DeckFlight]:
    """Builds, simulates and measures one flight without Meshcat or files: (metrics, flight)."""
    diagram, handles = build(config, duration_s)
    flight = fly_diagram(diagram, handles, duration_s, **options)
    return flight_metrics(flight, config), flight


def plot_deck_landing(flight: DeckFlight, config: DeckLandingConfig, out_dir) -> None:
    """deck_landing.png: the UAV's height above the deck (true, and as steered where the estimate was valid),
    the deck's tilt (true and as tracked) with the landing window's flags, and the horizontal offset, the
    supervisor's modes shaded; the title gives the touchdown as the metrics score it (`deck_touchdown`: the
    supervisor's LANDED or the gear's touch)."""
    log = flight.log
    t = log["t"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    axes[0].plot(t, log["true_relative_state"][:, HEIGHT], "k-", lw=1.2, label="true")
    steered = np.where(is_set(log["relative_state"][:, VALID]), log["relative_state"][:, HEIGHT], np.nan)
    axes[0].plot(t, steered, "--", color="tab:red", lw=1, label=f"{config.perception.source} (valid)")
    axes[0].axhline(config.landing.landing_height_m, color="0.5", ls=":", lw=1, label="LH")
    axes[0].set_ylabel("UAV above the deck (m)")
    axes[1].plot(t, tilt_deg(log["true_deck_motion"][:, :2]), "k-", lw=1.2, label="true tilt")
    tracked = np.where(is_set(log["deck_motion"][:, 6]), tilt_deg(log["deck_motion"][:, :2]), np.nan)
    axes[1].plot(t, tracked, "--", color="tab:red", lw=1, label="tracked")
    axes[1].axhline(config.window.max_tilt_deg, color="tab:green", ls=":", lw=1, label="commit within")
    axes[1].axhline(config.window.abort_tilt_deg, color="tab:brown", ls=":", lw=1, label="abort beyond")
    axes[1].fill_between(t, 0, np.where(is_set(log["landing_window"][:, 0]), axes[1].get_ylim()[1], 0),
                         color="tab:green", alpha=0.1, step="post", label="window open")
    axes[1].set_ylabel("deck tilt (deg)")
    offset = np.linalg.norm(log["true_relative_state"][:, :2], axis=1)
    axes[2].plot(t, offset, "k-", lw=1.2)
    axes[2].set_ylabel("horizontal offset (m)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        shade_modes(ax, log)
        ax.grid(alpha=0.3)
        if ax is not axes[2]:
            ax.legend(loc="upper right", fontsize=8)
    found = deck_touchdown(flight, config)
    axes[0].set_title(f"deck-landing steered by {config.perception.source}"
                      + (f", touchdown ({found[1]}) at {t[found[0]]:.1f} s" if found is not None else ""))
    save_figure(fig, out_dir / "deck_landing.png")


def write_outputs(flight: DeckFlight, config: DeckLandingConfig, out_dir) -> None:
    """log.npz and the plots of a flight."""
    frames = {f"frame_{name}": values for name, values in flight.frames.items()}
    X_BC = config.X_BC.GetAsMatrix4()
    write_npz(out_dir / "log.npz", **flight.log, **frames, X_BC=X_BC,
              X_PT=flight.handles.platform.X_PT.GetAsMatrix4(), K=config.camera.K)
    plot_deck_landing(flight, config, out_dir)
    plot_perception(flight.log, config.perception.source, out_dir)


def summary_lines(name: str, metrics: dict) -> list[str]:
    """What a run prints: the landing and the estimators (one that never had a valid estimate says so)."""
    landing = metrics["landing"]
    if landing["success"]:
        lines = [(f"landed {landing['touchdown_error_m']:.3f} m from the tag centre at "
                  f"{landing['touchdown_rel_speed_mps']:.2f} m/s, deck tilt {landing['deck_tilt_at_touchdown_deg']:.1f} "
                  f"deg, after {landing['time_to_land_s']:.1f} s ({landing['waits']} waits, {landing['wait_s']:.1f} s, "
                  f"{landing['aborts']} aborts)")]
    else:
        lines = [f"no landing ({landing['failure_reason']}: {landing['failure_detail']})"]
    for estimator, m in metrics["estimators"].items():
        if "mae_xyz_m" not in m:  # estimator_metrics scores valid frames only
            lines.append(f"{estimator}: never valid (valid {m['valid_fraction']:.0%})")
            continue
        lines.append(f"{estimator}: MAE xyz {np.round(m['mae_xyz_m'], 4).tolist()} m, rpy "
                     f"{np.round(m['mae_rpy_deg'], 2).tolist()} deg, valid {m['valid_fraction']:.0%}")
    return [f"{name}: {line}" for line in lines]


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.runner import finish_run

    video_path = ctx.out_dir / "camera.mp4" if ctx.options.video else None
    diagram, handles = build_deck_landing(scenario, ctx.meshcat, video_path)
    flight = fly_diagram(diagram, handles, scenario.duration_s, realtime=ctx.options.meshcat,
                         progress=ctx.options.progress, record=ctx.options.record)
    metrics = flight_metrics(flight, scenario, ctx.name)
    write_outputs(flight, scenario, ctx.out_dir)
    for line in summary_lines(ctx.name, metrics):
        print(line)
    return finish_run(ctx, metrics)

