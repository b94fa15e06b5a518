"""Running a gv scenario (gv-landing, marker-landing): fly until touchdown, a failure or
`duration_s`, then write metrics.json, log.npz and the plots.

    landing-sim run marker-landing [--video] [--meshcat]
    landing-sim run gv-landing --set perception.source=ct_ekf --set estimation.source=synthetic

metrics.json: `landing` and `tracking` (diagrams/landing_metrics.py), `perception` (what steered,
diagrams/perception_metrics.py), with a marker stream `measurements` (its own accuracy) and
`estimators` (every marker filter, diagrams/marker_metrics.py), and in wind `wind`
(diagrams/wind_report.py, with wind.png). Scripts use `fly(config,
duration_s)`, which returns the metrics and the flight without writing anything.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import Diagram

from diagrams.gv_landing import GvLandingHandles, build_gv_landing
from diagrams.gv_landing_config import GvLandingConfig
from diagrams.landing_metrics import gv_touchdown, landing_metrics, tracking_metrics
from diagrams.landing_plots import plot_flight, plot_perception
from diagrams.marker_metrics import SampledRun, marker_metrics
from diagrams.marker_plots import plot_run
from diagrams.outputs import write_npz
from diagrams.perception_metrics import perception_metrics
from diagrams.perception_sources import perception_source
from diagrams.scenario import RunSettings
from diagrams.simulate import Simulation, simulate
from diagrams.wind_report import plot_wind, wind_metrics
from systems.config import ConfigError, require_positive
from systems.perception.seam import HEIGHT, P_BP_W
from systems.vehicles.paths import make_path


@dataclass
class Scenario(RunSettings, GvLandingConfig):
    """A gv-landing scenario file: the diagram's configuration plus the run settings. `duration_s`
    is the time limit: a run that has not landed by then fails with "timeout"."""

    diagram: str = "gv_landing"
    duration_s: float = 120.0

    def validate(self) -> None:
        require_positive(self.duration_s, "duration_s")
        GvLandingConfig.validate(self)
        self.faults.check_within(self.duration_s)


@dataclass
class Flight:
    """A simulated flight: how it ended (`status`: the monitor's message, "completed" at the time
    limit, or "diverged: ..."), its logs at the supervisor's rate, and with a marker stream the
    sampled run."""

    status: str
    simulation: Simulation
    log: dict[str, np.ndarray]
    sampled: SampledRun | None
    handles: GvLandingHandles
    source_log: dict[str, np.ndarray] | None = None  # the perception source's own logs (and their times "t")


def collect_log(handles: GvLandingHandles, context) -> dict[str, np.ndarray]:
    """The supervisor-rate logs as arrays, one row per sample (time `t`)."""
    logs = {name: logger.FindLog(context) for name, logger in handles.loggers.items()}
    arrays = {name: log.data().T.copy() for name, log in logs.items()}
    arrays["t"] = logs["quadrotor_state"].sample_times().copy()
    arrays["mode"] = arrays["mode"][:, 0].round().astype(int)
    arrays["vehicle_speed"] = arrays["vehicle_speed"][:, 0]
    arrays["p_VP"] = handles.config.platform.p_VP
    return arrays


def collect_source_log(handles: GvLandingHandles, context) -> dict[str, np.ndarray] | None:
    """The perception source's own logs as arrays (one row per sample, times `t`), or None."""
    logs = {name: logger.FindLog(context) for name, logger in handles.perception.logs.items()}
    if not logs:
        return None
    arrays = {name: log.data().T.copy() for name, log in logs.items()}
    arrays["t"] = next(iter(logs.values())).sample_times().copy()
    return arrays


def sampled_run(handles: GvLandingHandles, context) -> SampledRun | None:
    """The run at the filter steps, from the sample loggers and the filters' final state."""
    if not handles.sample_loggers:
        return None
    logs = {name: logger.FindLog(context) for name, logger in handles.sample_loggers.items()}
    data = {name: log.data().T.copy() for name, log in logs.items()}
    n = len(handles.config.platform.markers.ids)
    filters = {name: f.GetOutputPort("filter_stats").Eval(f.GetMyContextFromRoot(context))
               for name, f in handles.filters.items()}
    compute = {name: f.GetMyContextFromRoot(context).get_abstract_state(0).get_value().compute_s
               for name, f in handles.filters.items()}
    return SampledRun(logs["measurements"].sample_times().copy(), data["quadrotor_state"], data["vehicle_state"],
                      data["measurements"].reshape(-1, n, 7), {name: data[f"{name}_estimate"] for name in filters},
                      {name: data[f"{name}_p_WM"].reshape(-1, n, 3) for name in filters},
                      {name: dataclasses.asdict(stats) for name, stats in filters.items()}, compute)


def fly_diagram(diagram, handles: GvLandingHandles, duration_s: float, **options) -> Flight:
    """Simulates a built gv diagram (diagrams/simulate.py's options) until the monitor ends the run or
    `duration_s`."""
    simulation = simulate(diagram, duration_s, initialize=handles.initialize, video=handles.video,
                          simulator_config=handles.config.integration.diagram_integrator(),
                          visualizer=handles.meshcat_visualizer, **options)
    context = simulation.context
    return Flight(simulation.status, simulation, collect_log(handles, context), sampled_run(handles, context),
                  handles, collect_source_log(handles, context))


def estimation_metrics(flight: Flight, config: GvLandingConfig) -> dict:
    """The `measurements` and `estimators` sections (empty without a marker stream)."""
    if flight.sampled is None:
        return {}
    est = config.estimation
    measured, estimators, _ = marker_metrics(flight.sampled, config.platform, est.X_BC, est.settle_s)
    source = {"source": est.source, "period_s": est.ekf.period_s, "latency_s": est.latency_s,
              "settle_s": est.settle_s, "marker_ids": config.platform.markers.ids,
              **({"pixel_noise_std": est.camera.pixel_noise_std} if est.source == "detector" else
                 {"sigma_p_m": est.sigma_p_m, "sigma_deg": est.sigma_deg})}
    return {"measurements": {**source, **measured}, "estimators": estimators}


def flight_metrics(flight: Flight, config: GvLandingConfig, name: str = "gv-landing", landing: bool = True) -> dict:
    """metrics.json's content for a flight (docs/architecture.md's shape); `landing` false for a
    flight that is not meant to land (gv-marker-ekf's hold): no landing and tracking sections."""
    log, sim = flight.log, flight.simulation
    out = {"scenario": name, "seed": config.seed, "sim_time_s": sim.sim_time_s, "wall_time_s": sim.wall_time_s,
           "realtime_factor": sim.realtime_factor,
           "vehicle": {"path": config.vehicle.path, **config.vehicle.speed_metrics()}}
    touchdown_s = None
    if landing:
        out["landing"] = landing_metrics(log, flight.status, config)
        out["tracking"] = tracking_metrics(log)
        touchdown_s = out["landing"]["time_to_land_s"]
    else:
        last = log["true_relative_state"][-1]
        out["flight"] = {"end": flight.status, "final_height_above_pad_m": float(last[HEIGHT]),
                         "final_horizontal_offset_m": float(np.linalg.norm(last[P_BP_W][:2]))}
    steering = flight.handles.perception.filter_name
    sampled = flight.sampled
    source = perception_source(config.perception.source)
    out["perception"] = perception_metrics(
        log, config.perception.source, touchdown_s, None if steering is None else sampled.t,
        None if steering is None else sampled.estimates[steering], heading=source.estimates_heading)
    out.update(estimation_metrics(flight, config))
    if source.metrics is not None and flight.source_log is not None:
        out.setdefault("estimators", {}).update(source.metrics(flight.source_log, config, touchdown_s))
    if "wind" in log:
        out["wind"] = wind_metrics(log, config.wind)
    out["end"] = flight.status
    return out


def build(config: GvLandingConfig, duration_s: float) -> tuple[Diagram, GvLandingHandles]:
    """The diagram `fly` flies for `duration_s` [s], without Meshcat or a video, and its handles."""
    return build_gv_landing(config, duration_s=duration_s)


def fly(config: GvLandingConfig, duration_s: float, **options) -> tuple[dict, Flight]:
    """Builds, simulates and measures one flight without Meshcat or files: (metrics, flight)."""
    diagram, handles = build(config, duration_s)
    flight = fly_diagram(diagram, handles, duration_s, **options)
    return flight_metrics(flight, config), flight


def write_outputs(flight: Flight, metrics: dict, config: GvLandingConfig, out_dir) -> None:
    """log.npz and the plots of a flight."""
    arrays = dict(flight.log)
    if flight.sampled is not None:
        run = flight.sampled
        _, _, errors = marker_metrics(run, config.platform, config.estimation.X_BC, config.estimation.settle_s)
        arrays.update({"t_sample": run.t, "sample_quadrotor_state": run.quadrotor_state,
                       "sample_vehicle_state": run.vehicle_state, "measurements": run.measurements})
        for name in run.estimates:
            arrays.update({f"{name}_estimate": run.estimates[name], f"{name}_p_WM": run.p_WM[name],
                           f"{name}_marker_error": errors[name].markers})
        if run.estimates:
            plot_run(config, run, errors, out_dir)
    source = perception_source(config.perception.source)
    if flight.source_log is not None:
        arrays.update({f"{config.perception.source}_{name}": values for name, values in flight.source_log.items()})
        if source.plot is not None:
            source.plot(flight.source_log, config, out_dir)
    write_npz(out_dir / "log.npz", **arrays)
    found = gv_touchdown(flight.log, flight.status, config)
    plot_flight(flight.log, config, out_dir, None if found is None else found[0],
                make_path(config.vehicle.path_config()).polyline(max_length_m=1e9))
    plot_perception(flight.log, config.perception.source, out_dir, source.estimates_heading)
    if "wind" in flight.log:
        plot_wind(flight.log, out_dir)


def summary_lines(name: str, metrics: dict) -> list[str]:
    """What a run prints: the landing, what steered, and the filters."""
    lines = []
    landing = metrics.get("landing")
    if landing is not None and landing["success"]:
        lines.append(f"landed {landing['touchdown_error_m']:.3f} m from the pad centre at "
                     f"{landing['touchdown_rel_speed_mps']:.2f} m/s after {landing['time_to_land_s']:.1f} s")
    elif landing is not None:
        lines.append(f"no landing ({landing['failure_reason']}: {landing['failure_detail']})")
    perception = metrics["perception"]
    if perception["source"] != "truth" and "rms_position_m" in perception:
        coast = perception.get("coast_before_touchdown_s")
        heading = f"heading {perception['rms_heading_deg']:.2f} deg, " if "rms_heading_deg" in perception else ""
        lines.append(f"steered by {perception['source']}: RMS position {perception['rms_position_m']:.3f} m over the "
                     f"flight, {heading}valid {perception['valid_fraction']:.0%}, longest "
                     f"without a valid estimate {perception['longest_invalid_s']:.2f} s"
                     + (f", last measurement {coast:.2f} s before touchdown" if coast is not None else ""))
    after_climb = metrics.get("estimators", {}).get("hybrid", {}).get("position_m_after_climb", {})
    if after_climb.get("samples"):
        lines.append("hybrid from the climb's end on: MAE x / y / z "
                     + " / ".join(f"{v:.4f}" for v in after_climb["mae_xyz"]) + " m")
    settle = metrics.get("measurements", {}).get("settle_s", 0.0)
    for filter_name, m in metrics.get("estimators", {}).items():
        if "rms_position_m" in m:
            lines.append(f"{filter_name} from {settle:g} s on: RMS position {m['rms_position_m']:.3f} m, heading "
                         f"{m['rms_heading_deg']:.2f} deg ({m['measurements']['gated']} gated, "
                         f"{m['measurements']['invalid']} invalid)")
    for estimator, m in metrics.get("estimators", {}).items():
        if "rmse_orientation_rad" in m and not estimator.startswith(("approach", "adjustment", "touchdown")):
            lines.append(f"{estimator}: RMSE position {m['rmse_position_m']:.4f} m, orientation "
                         f"{m['rmse_orientation_rad']:.4f} rad, height {m['rmse_height_m']:.4f} m, valid "
                         f"{m['valid_fraction']:.1%}")
        overlap = m.get("overlaps", {}).get("overlap_1", {})
        if "rmse_height_m" in overlap:  # seed 001 Sec. 5.3's comparison
            rmse, (low, high) = overlap["rmse_height_m"], overlap["altitude_band_m"]
            lines.append(f"{estimator} in Overlap 1 ({low:.2f}-{high:.2f} m, {overlap['frames']} frames): height RMSE "
                         f"{rmse['federated']:.4f} m, local filters {rmse['local_approach']:.4f} / "
                         f"{rmse['local_adjustment']:.4f} / {rmse['local_touchdown']:.4f} m "
                         "(paper 0.037; 0.065 / 0.0835)")
    return [f"{name}: {line}" for line in lines]


def run_flight(scenario: GvLandingConfig, ctx, duration_s: float, landing: bool = True) -> dict:
    """Builds, flies and writes a gv scenario for the landing-sim command."""
    from diagrams.runner import finish_run

    if ctx.options.video and not scenario.has_video:
        raise ConfigError(f"--video records the camera, and {ctx.name} has none "
                          f"(--set estimation.source=detector renders it)")
    video_path = ctx.out_dir / "camera.mp4" if ctx.options.video else None
    diagram, handles = build_gv_landing(scenario, ctx.meshcat, video_path, duration_s)
    flight = fly_diagram(diagram, handles, duration_s, realtime=ctx.options.meshcat, progress=ctx.options.progress,
                         record=ctx.options.record)
    metrics = flight_metrics(flight, scenario, ctx.name, landing)
    write_outputs(flight, metrics, scenario, ctx.out_dir)
    for line in summary_lines(ctx.name, metrics):
        print(line)
    return finish_run(ctx, metrics)


def run(scenario: Scenario, ctx) -> dict:
    return run_flight(scenario, ctx, scenario.duration_s)

