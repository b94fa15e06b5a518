"""Campaigns over any fields of a landing scenario (a gv scenario or deck-landing; issue 10): each `--case KEY=V1,V2,...` names a field
and its values, the cases are their product, each named "key=value[,key=value]" (its directory under
runs/ too), and every run flies the scenario with its case's assignments (a landing campaign).

    landing-sim montecarlo marker-landing-wind --runs 20 --case vehicle.speed=3,6 --case wind.mean_m_s=0,5

summary.json's "cases" then holds per case, besides its run counts, the landings' figures
(diagrams/landing_campaign.landing_case_summary): success_rate, touchdown error and relative vertical speed (p50, p95,
max, over the runs that touched down), failure reasons counted, and aborts.
"""

from __future__ import annotations

import itertools

import matplotlib.pyplot as plt
import numpy as np

from diagrams.landing_campaign import landing_case_summary, run_task
from diagrams.montecarlo.definition import CampaignDefinition, campaign_settings
from diagrams.montecarlo.records import RunRecord
from diagrams.montecarlo.settings import GRID, CampaignSettings
from diagrams.outputs import save_figure
from diagrams.runner import load_scenario
from systems.config import ConfigError


def parse_case_option(option: str) -> tuple[str, list[str]]:
    """`KEY=V1,V2,...` -> (key, [values as typed]); ConfigError naming the option when malformed.
    Values are scalars (a comma separates them)."""
    key, sep, values = option.partition("=")
    texts = [v.strip() for v in values.split(",")]
    if not sep or not key.strip() or not all(texts):
        raise ConfigError(f"--case expects KEY=VALUE[,VALUE...], got '{option}'")
    if len(set(texts)) != len(texts):
        raise ConfigError(f"--case {key}: a value is given twice")
    return key.strip(), texts


def grid_cases(options: list[str]) -> tuple[str, ...]:
    """The product of the `--case` options as case names, "key=value[,key=value]" in option order."""
    fields = [parse_case_option(option) for option in options]
    keys = [key for key, _ in fields]
    if len(set(keys)) != len(keys):
        raise ConfigError("--case: a field is given twice (give its values in one --case, comma-separated)")
    return tuple(",".join(f"{k}={v}" for k, v in zip(keys, values))
                 for values in itertools.product(*(values for _, values in fields)))


def plot_grid(settings: CampaignSettings, done: dict[str, list[RunRecord]], out_dir) -> None:
    """touchdowns.png: each case's touchdown points in the pad frame (m) inside the pad's outline,
    and its success rate."""
    fig, (points, rates) = plt.subplots(1, 2, figsize=(12, 4.5), layout="constrained")
    for case, records in done.items():
        xy = [r.metrics["landing"]["touchdown_offset_pad_xy_m"] for r in records
              if r.metrics["landing"].get("touchdown_offset_pad_xy_m") is not None]
        if xy:
            points.scatter(*np.array(xy).T, s=14, label=case)
    half = load_scenario(settings.scenario, overrides=list(settings.overrides))[1].pad_size_m / 2
    points.plot([-half, half, half, -half, -half], [-half, -half, half, half, -half], "k-", lw=1)
    points.set_aspect("equal")
    points.set_xlabel("x in the pad frame [m]")
    points.set_ylabel("y in the pad frame [m]")
    points.legend(fontsize=7)
    points.grid(True, alpha=0.3)
    names = list(done)
    rates.barh(names, [landing_case_summary(done[c])["success_rate"] or 0.0 for c in names])
    rates.set_xlim(0, 1)
    rates.set_xlabel("success rate")
    save_figure(fig, out_dir / "touchdowns.png")


def grid_campaign(scenario: str) -> CampaignDefinition:
    """The landing campaign over `--case` grids of a landing scenario."""
    return CampaignDefinition(run=run_task, cases=(), runs=10, case_name="case", case_key=GRID, known_cases=(),
                              aggregate=lambda done: {}, case_summary=landing_case_summary, plot=plot_grid,
                              paired=True, description=f"landings of {scenario} over a grid of field values")


def grid_settings(scenario: str, options: list[str], runs: int | None, base_seed: int,
                  overrides: list[str]) -> tuple[CampaignDefinition, CampaignSettings]:
    """The definition and checked settings of a `--case` campaign (a field no scenario has, or a value
    of the wrong type, is a ConfigError naming it, before anything is written)."""
    from diagrams.landing_campaign import is_landing_scenario

    if not is_landing_scenario(load_scenario(scenario)[1]):
        raise ConfigError(f"--case campaigns fly landings: {scenario} is not a landing scenario (a gv scenario or "
                          f"deck-landing)")
    cases = grid_cases(options)
    fields = {option.partition("=")[0].strip() for option in options}
    for assignment in overrides:
        if assignment.partition("=")[0] in fields:
            raise ConfigError(f"--set {assignment.partition('=')[0]}: a --case sets it")
    definition = grid_campaign(scenario)
    return definition, campaign_settings(definition, scenario, cases, runs, base_seed, overrides)
