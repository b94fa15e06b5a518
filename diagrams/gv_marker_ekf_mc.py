"""The gv-marker-ekf Monte Carlo campaign (seed 002 section 4: 100 runs at each of 3, 6, 12 m/s).

    landing-sim montecarlo gv-marker-ekf --runs 100 --speeds 3 6 12 --workers 2 --out results/mc

A run (`run_task`) is one seeded measurement stream through the filters. Where the batch path gives
the Diagram's numbers (`batch_applies`: the paper's synthetic source and nothing seeded in the
flight, the default) it takes it (diagrams/marker_batch.py: the flight flown once per speed in each
worker); anything else flies the Diagram: with `--set estimation.source=detector` the camera,
rendering and detecting each frame (a handful of runs, not hundreds: docs/results.md has the cost),
and so faults, navigation errors, turbulence and the vehicle's broadcast. The loaded scenario is
cached per (case, overrides); only its seed changes from run to run. The campaign hands a worker
GROUP runs of one case at a time (`run_group`): on the batch path their filters are stepped together
(`batch_runs`), each run still its own record with the output `run_task` gives it (to 1e-9,
tests/test_gv_marker_ekf.py).

Each run keeps its metrics (per filter: RMS position and heading error, per-marker RMS, counts)
and, every DECIMATE-th step as float32, the true and estimated pad path, heading and marker errors.

summary.json's "filters": {filter: {speed: {"rms_position_m", "rms_heading_deg", ...}}}, where
rms_* is the RMS over every run and every scored step after settle_s (the ensemble RMS error: each
run's mean square weighted by its frames_scored), and
"ensemble_mean_*" is the paper's epsilon: the error of the ensemble-mean estimate at each step,
RMS over the steps. Plots (seed 002 Fig. 3-5, one row per speed): mc_path.png (reference, true and
ensemble-mean estimated path), mc_heading.png (true and ensemble-mean heading, and its error),
mc_marker_errors.png (the ensemble RMS position error of each marker over time, per filter).
"""

import dataclasses
import time
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from diagrams.montecarlo import CampaignDefinition, RunOutput, RunTask, parse_number_case
from diagrams.outputs import save_figure
from systems.estimators.marker_ekf.engine import EST_P_WP, EST_YAW
from systems.vehicles.paths import make_path

DECIMATE = 4  # keep every 4th step (140 ms) of the time series
SPEEDS = ("3", "6", "12")  # seed 002 Sec. 4: C1, C2, C3 [m/s]
GROUP = 20  # runs per worker task, their filters stepped together

_SCENARIOS: dict = {}


def _scenario(task: RunTask):
    key = (task.scenario, task.case, task.overrides)
    if key not in _SCENARIOS:
        _SCENARIOS[key] = task.load_scenario()[1]
    return dataclasses.replace(_SCENARIOS[key], seed=task.seed)


def build_task(task: RunTask) -> None:
    """Builds the Diagram `landing-sim run gv-marker-ekf` flies for `task`, without flying it
    (CampaignDefinition.build: the batch path checks no more than the Diagram does)."""
    from diagrams.gv_landing_run import build

    scenario = _scenario(task)
    build(scenario, scenario.run_length_s)


def sampled(scenario):
    """The run at the filter steps: by the batch path where it applies, else through the Diagram."""
    from diagrams.gv_landing_run import build, fly_diagram
    from diagrams.marker_batch import batch_applies, batch_run

    if batch_applies(scenario):
        return batch_run(scenario, scenario.run_length_s)
    diagram, handles = build(scenario, scenario.run_length_s)
    return fly_diagram(diagram, handles, scenario.run_length_s).sampled


def run_task(task: RunTask) -> RunOutput:
    """One run of the campaign (module docstring)."""
    scenario = _scenario(task)
    start = time.perf_counter()
    return _output(scenario, sampled(scenario), time.perf_counter() - start)


def run_group(tasks: list[RunTask]) -> list[RunOutput]:
    """Runs of one case (module docstring), the filters of all of them stepped together where the
    batch path applies (`batch_runs`), else one by one; each output the one `run_task` gives."""
    from diagrams.marker_batch import batch_applies, batch_runs

    scenario = _scenario(tasks[0])
    if not batch_applies(scenario):
        return [run_task(task) for task in tasks]
    start = time.perf_counter()
    runs = batch_runs(scenario, [task.seed for task in tasks], scenario.run_length_s)
    share = (time.perf_counter() - start) / len(tasks)
    return [_output(dataclasses.replace(scenario, seed=task.seed), run, share) for task, run in zip(tasks, runs)]


def _output(scenario, run, wall_s: float) -> RunOutput:
    """A run's metrics and decimated arrays (module docstring) from its sampled run, which took wall_s [s]."""
    from diagrams.marker_metrics import marker_metrics, pad_truth, valid_only

    start = time.perf_counter() - wall_s
    est = scenario.estimation
    measured, metrics, errors = marker_metrics(run, scenario.platform, est.X_BC, est.settle_s)
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, scenario.platform)
    keep = slice(None, None, DECIMATE)
    arrays = {"t": run.t[keep].astype(np.float32), "true_xy": truth.p_WP[keep, :2].astype(np.float32),
              "true_yaw": truth.yaw[keep].astype(np.float32)}
    for name, estimate in run.estimates.items():
        valid = errors[name].valid[keep]  # NaN where the filter flags its estimate, as its metrics leave it out
        for key, values in (("xy", estimate[keep][:, EST_P_WP][:, :2]), ("yaw", estimate[keep][:, EST_YAW]),
                            ("marker_error", errors[name].markers[keep])):
            arrays[f"{name}_{key}"] = valid_only(values, valid).astype(np.float32)
    metrics = {"speed_m_s": scenario.vehicle.speed, "seed": scenario.seed, "sim_time_s": float(run.t[-1]),
               "estimation_wall_time_s": time.perf_counter() - start, "settle_s": est.settle_s, "source": est.source,
               "measurements": measured, "estimators": metrics}
    return RunOutput(metrics, arrays)


def _filters(records) -> list[str]:
    names = []
    for r in records:
        for name in r.metrics.get("estimators", {}):
            if name not in names:
                names.append(name)
    return names


def _ensemble(records, name: str):
    """(t, true_xy, true_yaw, mean xy, mean yaw, RMS marker error over the runs) of one filter,
    each over the runs with a valid estimate at that step (NaN where none has one)."""
    data = [r.arrays() for r in records]
    t = data[0]["t"].astype(float)
    true_yaw = data[0]["true_yaw"].astype(float)
    yaw_error = np.array([d[f"{name}_yaw"] for d in data], dtype=float) - true_yaw
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)
        xy = np.nanmean([d[f"{name}_xy"] for d in data], axis=0)
        yaw = true_yaw + np.arctan2(np.nanmean(np.sin(yaw_error), axis=0), np.nanmean(np.cos(yaw_error), axis=0))
        markers = np.sqrt(np.nanmean([d[f"{name}_marker_error"].astype(float) ** 2 for d in data], axis=0))
    return t, data[0]["true_xy"].astype(float), true_yaw, xy, yaw, markers


def aggregate(done: dict) -> dict:
    """summary.json's "filters" (module docstring)."""
    from diagrams.marker_metrics import pooled_rms

    out: dict = {}
    for case, records in done.items():
        if not records:
            continue
        settle = float(records[0].metrics.get("settle_s", 0.0))
        for name in _filters(records):
            ms = [r.metrics["estimators"][name] for r in records
                  if "rms_position_m" in r.metrics["estimators"].get(name, {})]
            if not ms:
                continue
            t, true_xy, true_yaw, xy, yaw, _ = _ensemble(records, name)
            window = (t >= settle) & np.all(np.isfinite(xy), axis=1)
            out.setdefault(name, {})[case] = {
                "rms_position_m": float(pooled_rms(ms, "rms_position_m")),
                "rms_heading_deg": float(pooled_rms(ms, "rms_heading_deg")),
                "rms_position_xy_m": float(pooled_rms(ms, "rms_position_xy_m")),
                "rms_marker_position_m": pooled_rms(ms, "rms_marker_position_m").tolist(),
                "ensemble_mean_position_xy_m": float(np.sqrt(np.mean(np.sum((xy - true_xy)[window] ** 2, axis=1)))),
                "ensemble_mean_heading_deg": float(np.degrees(np.sqrt(np.mean(((yaw - true_yaw)[window]) ** 2)))),
                "runs": len(ms),
                "gated": int(sum(m["measurements"]["gated"] for m in ms)),
                "invalid": int(sum(m["measurements"]["invalid"] for m in ms)),
                "resets": int(sum(m["measurements"]["resets"] for m in ms)),
                "per_frame_ms": float(np.mean([m["per_frame_ms"] for m in ms])),
                # the stream every filter saw: the share of frames in which each marker was measured
                "measured_fraction": np.mean([r.metrics["measurements"]["measured_fraction"] for r in records
                                              if "measurements" in r.metrics], axis=0).tolist(),
            }
    return out


def plot(settings, done: dict, out_dir: Path) -> None:
    """Seed 002 Fig. 3-5 over the ensemble, one row per speed."""
    from diagrams.marker_plots import plot_heading, plot_markers, plot_path
    from diagrams.runner import load_scenario

    cases = [c for c in settings.cases if done.get(c)]
    if not cases:
        return
    names = _filters(done[cases[0]])
    scenario = load_scenario(settings.scenario, None, list(settings.overrides))[1]
    reference = make_path(scenario.vehicle.path_config()).polyline(max_length_m=1e9)
    ensembles = {c: {n: _ensemble(done[c], n) for n in names} for c in cases}
    fig, axes = plt.subplots(len(cases), 1, figsize=(9, 4.5 * len(cases)), squeeze=False)
    for ax, c in zip(axes[:, 0], cases):
        e = ensembles[c]
        first = e[names[0]]
        plot_path(ax, reference, first[1], {n: e[n][3] for n in names},
                  f"{c} m/s: ensemble mean of {len(done[c])} runs (Fig. 3)", scenario.vehicle.path)
    save_figure(fig, out_dir / "mc_path.png")
    fig, axes = plt.subplots(2 * len(cases), 1, figsize=(10, 4.5 * len(cases)), squeeze=False)
    for i, c in enumerate(cases):
        e = ensembles[c]
        first = e[names[0]]
        plot_heading(axes[2 * i:2 * i + 2, 0], first[0], first[2], {n: e[n][4] for n in names},
                     f"{c} m/s: heading, ensemble mean (Fig. 4)")
    axes[-1, 0].set_xlabel("time (s)")
    save_figure(fig, out_dir / "mc_heading.png")
    fig, axes = plt.subplots(len(cases), len(names), figsize=(6 * len(names), 3.2 * len(cases)), squeeze=False,
                             sharey="row")
    for i, c in enumerate(cases):
        e = ensembles[c]
        plot_markers(axes[i, :], e[names[0]][0], {n: e[n][5] for n in names}, scenario.platform.markers.ids,
                     f"{c} m/s", ylabel="ensemble RMS error (m)")
    for ax in axes[-1, :]:
        ax.set_xlabel("time (s)")
    save_figure(fig, out_dir / "mc_marker_errors.png")


CAMPAIGN = CampaignDefinition(
    run=run_task, cases=SPEEDS, runs=100, case_name="speed", case_key="vehicle.speed",
    known_cases=SPEEDS, parse_case=parse_number_case, aggregate=aggregate, plot=plot, run_group=run_group,
    group_size=GROUP, build=build_task,
    description="seed 002 section 4: paper_ekf and ct_ekf on identical synthetic marker streams at 3, 6, 12 m/s")
