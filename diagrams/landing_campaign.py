"""Landing campaigns: seeded closed-loop landings of a gv scenario (or deck-landing), one case per perception source,
the same seeds for every source (the same pixel noise, the same stream), side by side.

    landing-sim montecarlo marker-landing --runs 10 --cases ct_ekf paper_ekf truth --workers 2

A run flies the scenario (diagrams/gv_landing_run.fly) and keeps its `landing`, `perception`,
`measurements` and `estimators` sections. summary.json's "cases" has per source, besides its run counts, the
landing figures a `--case` campaign gives per case (`landing_case_summary`: success rate, a run that raised
counting as a failure; touchdown error and relative vertical speed; failure reasons counted; aborts; how many met
the targets) and the source's own (`source_summary`): the steering estimate's RMS position error, the time flown
on the prediction before touchdown and the time to land.
"""

from collections import Counter

import numpy as np

from diagrams.montecarlo import CampaignDefinition, RunTask

SOURCES = ("ct_ekf", "paper_ekf", "truth")


LANDING_DIAGRAMS = ("gv_landing", "deck_landing")  # their run modules' `fly(config, duration_s)` lands


def is_landing_scenario(scenario) -> bool:
    """A scenario whose diagram flies a landing: a gv scenario that lands (not gv-marker-ekf, which
    hovers over the vehicle) or deck-landing."""
    return scenario.diagram in LANDING_DIAGRAMS


def _run_module(diagram: str):
    """The run module of a landing diagram (LANDING_DIAGRAMS): its `build` and `fly`."""
    import importlib

    from diagrams.runner import DIAGRAM_MODULES

    return importlib.import_module(DIAGRAM_MODULES[diagram])


def build_task(task: RunTask) -> None:
    """Builds the diagram `run_task` flies for `task`, without flying it (CampaignDefinition.build)."""
    _, scenario = task.load_scenario()
    _run_module(scenario.diagram).build(scenario, scenario.duration_s)


def run_task(task: RunTask) -> dict:
    """One landing of the campaign, by the scenario's own diagram."""
    _, scenario = task.load_scenario()
    metrics, _ = _run_module(scenario.diagram).fly(scenario, scenario.duration_s)
    keep = ("sim_time_s", "wall_time_s", "realtime_factor", "landing", "perception", "measurements", "estimators")
    return {"seed": task.seed, **{key: metrics[key] for key in keep if key in metrics}}


def _percentiles(values: list[float]) -> dict | None:
    """{"p50", "p95", "max"} of the values (None for none)."""
    if not values:
        return None
    v = np.asarray(values, dtype=float)
    return {"p50": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}


def landing_case_summary(records: list, failed: int = 0) -> dict:
    """One case's landing figures in summary.json's "cases" (a `--case` campaign's, diagrams/montecarlo/grid.py,
    and, with `source_summary`'s, the `--cases` campaign's per source), from its finished runs (RunRecord) and
    the number of its runs that raised (`failed`, each a failure, reason "run_failed"): the runs that ended
    (finished or raised), how many of them landed and the success rate, touchdown error (m) and relative vertical
    speed (m/s; p50, p95, max over the runs that touched down), failure reasons counted, aborts, how many met the
    targets, and on a deck its tilt at touchdown (deg) and the time waited for a landing window (s)."""
    landings = [r.metrics["landing"] for r in records]
    touched = [m for m in landings if m["touchdown_error_m"] is not None]
    reasons = Counter(m["failure_reason"] for m in landings if m["failure_reason"])
    if failed:
        reasons["run_failed"] = failed
    ended, landed = len(landings) + failed, sum(bool(m["success"]) for m in landings)
    return {"ended": ended, "landed": landed, "success_rate": landed / ended if ended else None,
            "touchdown_error_m": _percentiles([m["touchdown_error_m"] for m in touched]),
            "touchdown_rel_speed_mps": _percentiles([m["touchdown_rel_speed_mps"] for m in touched]),
            "failure_reasons": dict(reasons),
            "aborts": sum(m["aborts"] for m in landings),
            "meets_targets": sum(m["meets_targets"] for m in landings),
            # On a moving deck: its tilt at touchdown and the waits for a landing window.
            **({"deck_tilt_at_touchdown_deg": _percentiles([m["deck_tilt_at_touchdown_deg"] for m in touched]),
                "wait_s": _percentiles([m["wait_s"] for m in landings])}
               if any("deck_tilt_at_touchdown_deg" in m for m in touched) else {})}


def source_summary(records: list, failed: int = 0) -> dict:
    """One source's figures in the `--cases` campaign: `landing_case_summary`'s, then the steering estimate's RMS
    position error (m, RMS over the runs that report one), the time flown on the prediction before touchdown and
    the time to land (s; p50, p95, max over the runs that have them)."""
    perception = [r.metrics["perception"] for r in records]
    steering = [p["rms_position_m"] for p in perception if p.get("rms_position_m") is not None]
    coasts = [p["coast_before_touchdown_s"] for p in perception if p.get("coast_before_touchdown_s") is not None]
    touched = [r.metrics["landing"] for r in records if r.metrics["landing"]["touchdown_error_m"] is not None]
    return {**landing_case_summary(records, failed),
            "steering_rms_position_m": float(np.sqrt(np.mean(np.square(steering)))) if steering else None,
            "coast_before_touchdown_s": _percentiles(coasts),
            "time_to_land_s": _percentiles([m["time_to_land_s"] for m in touched])}


CAMPAIGN = CampaignDefinition(
    run=run_task, cases=SOURCES, runs=10, case_name="source", case_key="perception.source", known_cases=(),
    aggregate=lambda done: {}, case_summary=source_summary, paired=True, build=build_task,
    description="closed-loop landings, one case per perception source, the same seeds for every source")
