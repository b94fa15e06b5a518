"""Landing campaigns: seeded closed-loop landings of a gv scenario (or deck-landing), one case per perception source,
the same seeds for every source (the same pixel noise, the same stream), side by side.

    landing-sim montecarlo marker-landing --runs 10 --cases ct_ekf paper_ekf truth --workers 2

A run flies the scenario (diagrams/gv_landing_run.fly) and keeps its `landing`, `perception`,
`measurements` and `estimators` sections. summary.json's "filters" has per source: how many runs
landed on the pad and met the touchdown targets, the touchdown error's median, 95th percentile and
maximum (over the runs that touched down), the largest relative vertical speed, the steering
estimate's RMS position error (RMS over the runs) and the time flown on the prediction before
touchdown.
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


def _percentiles(values: list[float], median: str = "median") -> dict | None:
    """{median, "p95", "max"} of the values (None for none); `median` names the first key."""
    if not values:
        return None
    v = np.asarray(values, dtype=float)
    return {median: float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}


def aggregate(done: dict) -> dict:
    """summary.json's "filters": per source (case) the landing figures (module docstring)."""
    out = {}
    for case, records in done.items():
        landings = [r.metrics["landing"] for r in records]
        touched = [m for m in landings if m["touchdown_error_m"] is not None]
        steering = [r.metrics["perception"].get("rms_position_m") for r in records]
        coasts = [r.metrics["perception"].get("coast_before_touchdown_s") for r in records]
        out[case] = {
            "runs": len(records),
            "landed": sum(m["success"] for m in landings),
            "meets_targets": sum(m["meets_targets"] for m in landings),
            "failures": sorted({m["failure_reason"] for m in landings if m["failure_reason"]}),
            "touchdown_error_m": _percentiles([m["touchdown_error_m"] for m in touched]),
            "touchdown_rel_speed_mps": _percentiles([m["touchdown_rel_speed_mps"] for m in touched]),
            "steering_rms_position_m": (float(np.sqrt(np.mean(np.square([s for s in steering if s is not None]))))
                                        if any(s is not None for s in steering) else None),
            "coast_before_touchdown_s": _percentiles([c for c in coasts if c is not None]),
            "time_to_land_s": _percentiles([m["time_to_land_s"] for m in touched]),
        }
    return {"landing": out}


def landing_case_summary(records: list, failed: int = 0) -> dict:
    """One case's landing figures in a `--case` campaign (diagrams/montecarlo/grid.py), from its
    finished runs (RunRecord) and the number of its runs that raised (`failed`, each a failure, reason
    "run_failed"): success rate, touchdown error and relative vertical speed (p50, p95,
    max over the runs that touched down), failure reasons counted, aborts, how many met the targets, and on a
    deck its tilt at touchdown and the time waited for a landing window."""
    landings = [r.metrics["landing"] for r in records]
    touched = [m for m in landings if m["touchdown_error_m"] is not None]
    reasons = Counter(m["failure_reason"] for m in landings if m["failure_reason"])
    if failed:
        reasons["run_failed"] = failed
    ended = len(landings) + failed
    return {"success_rate": sum(m["success"] for m in landings) / ended if ended else None,
            "touchdown_error_m": _percentiles([m["touchdown_error_m"] for m in touched], "p50"),
            "touchdown_rel_speed_mps": _percentiles([m["touchdown_rel_speed_mps"] for m in touched], "p50"),
            "failure_reasons": dict(reasons),
            "aborts": sum(m["aborts"] for m in landings),
            "meets_targets": sum(m["meets_targets"] for m in landings),
            # On a moving deck: its tilt at touchdown and the waits for a landing window.
            **({"deck_tilt_at_touchdown_deg": _percentiles([m["deck_tilt_at_touchdown_deg"] for m in touched], "p50"),
                "wait_s": _percentiles([m["wait_s"] for m in landings], "p50")}
               if any("deck_tilt_at_touchdown_deg" in m for m in touched) else {})}


CAMPAIGN = CampaignDefinition(
    run=run_task, cases=SOURCES, runs=10, case_name="source", case_key="perception.source", known_cases=(),
    aggregate=aggregate, paired=True, build=build_task,
    description="closed-loop landings, one case per perception source, the same seeds for every source")
