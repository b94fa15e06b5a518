"""Campaigns over any fields of a landing scenario (a gv scenario or deck-landing; issue 10): each `--case KEY=V1,V2,...` names a field
and its values, the cases are their product, each named "key=value[,key=value]" (its directory under
runs/ too), and every run flies the scenario with its case's assignments (a landing campaign).

    landing-sim montecarlo marker-landing-wind --runs 20 --case vehicle.speed=3,6 --case wind.mean_m_s=0,5

summary.json's "cases" then holds per case, besides its run counts, the landings' figures
(diagrams/landing_campaign.landing_case_summary): success_rate (a run that raised is a failure, reason run_failed),
touchdown error and relative vertical speed (p50, p95, max, over the runs that touched down), failure reasons counted,
and aborts. A campaign seeds each of its runs: `seed` is neither a --case nor a --set.
"""

from __future__ import annotations

import itertools

import matplotlib.pyplot as plt
import numpy as np
import yaml

from diagrams.landing_campaign import build_task, landing_case_summary, run_task
from diagrams.landing_metrics import TARGET_TOUCHDOWN_ERROR_M, TARGET_TOUCHDOWN_REL_SPEED_MPS
from diagrams.montecarlo.definition import CampaignDefinition, campaign_settings
from diagrams.montecarlo.records import RunRecord
from diagrams.montecarlo.settings import GRID, CampaignSettings
from diagrams.outputs import save_figure
from diagrams.runner import load_scenario
from diagrams.scenario import parse_yaml
from systems.config import ConfigError


def _value(text: str):
    """A --case value as the scenario will read it, to compare: 3, 3.0 and 3e0 are one number (equal, as
    Python compares them); anything else, or text that is no YAML, as written."""
    try:
        value = parse_yaml(text)
    except yaml.YAMLError:
        return text
    return value if isinstance(value, int | float) and not isinstance(value, bool) else repr(value)


def parse_case_option(option: str) -> tuple[str, list[str]]:
    """`KEY=V1,V2,...` -> (key, [values as typed]); ConfigError naming the option when malformed.
    Values are scalars (a comma separates them)."""
    key, sep, values = option.partition("=")
    texts = [v.strip() for v in values.split(",")]
    if not sep or not key.strip() or not all(texts):
        raise ConfigError(f"--case expects KEY=VALUE[,VALUE...], got '{option}'")
    if key.strip() == "seed":
        raise ConfigError("--case seed: the campaign seeds each run (--seed gives its base seed)")
    if len(set(map(_value, texts))) != len(texts):
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
    """touchdowns.png: (a) each case's touchdown points in the pad frame (m) inside the pad's outline; (b) the same
    zoomed to the points (mm), where they cluster near the centre; (c) each run's touchdown error (m) and (d)
    relative vertical speed (m/s) per case against issue 4's targets, each case named with its landings and
    those within every target."""
    fig, axes = plt.subplots(2, 2, figsize=(13, 9), layout="constrained")
    (pad, zoom), (errors, speeds) = axes
    points = {case: np.array([r.metrics["landing"]["touchdown_offset_pad_xy_m"] for r in records
                              if r.metrics["landing"].get("touchdown_offset_pad_xy_m") is not None]).reshape(-1, 2)
              for case, records in done.items()}
    halves = {load_scenario(settings.scenario, overrides=[*settings.overrides, *case.split(",")])[1].pad_size_m / 2
              for case in done}  # a case may set the pad's size: each size's outline
    half = max(halves)
    reach = max([0.001, *(np.abs(xy).max() for xy in points.values() if xy.size)])  # m, the farthest point out
    for ax, scale, extent in ((pad, 1.0, half), (zoom, 1e3, min(1.2 * reach, half))):
        for case, xy in points.items():
            ax.scatter(*(scale * xy).T, s=14, label=case)
        for size in halves:
            box = scale * np.array([-size, size])
            ax.plot(box[[0, 1, 1, 0, 0]], box[[0, 0, 1, 1, 0]], "k-", lw=1)
        ax.set_xlim(-scale * extent * 1.05, scale * extent * 1.05)
        ax.set_ylim(-scale * extent * 1.05, scale * extent * 1.05)
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
    pad.set(xlabel="x in the pad frame [m]", ylabel="y in the pad frame [m]", title="(a) touchdowns on the pad")
    zoom.set(xlabel="x in the pad frame [mm]", ylabel="y in the pad frame [mm]", title="(b) the same, zoomed")
    pad.legend(fontsize=7)
    names = list(done)
    labels = []
    for case in names:
        landings = [r.metrics["landing"] for r in done[case]]
        landed, meets = sum(m["success"] for m in landings), sum(m["meets_targets"] for m in landings)
        # out of the runs asked for: a run that raised has no record here and is not a landing
        labels.append(f"{case}\nlanded {landed}/{settings.runs}, within every target {meets}/{settings.runs}")
    for ax, key, target, unit, title in (
            (errors, "touchdown_error_m", TARGET_TOUCHDOWN_ERROR_M, "m", "(c) touchdown error from the pad centre"),
            (speeds, "touchdown_rel_speed_mps", TARGET_TOUCHDOWN_REL_SPEED_MPS, "m/s",
             "(d) vertical speed relative to the pad at touchdown")):
        # One row per case, one dot per run that touched down.
        for row, case in enumerate(names):
            values = [r.metrics["landing"][key] for r in done[case] if r.metrics["landing"][key] is not None]
            ax.plot(values, np.full(len(values), row), "o", ms=5, alpha=0.7)
        ax.axvline(target, color="tab:red", ls="--", lw=1, label=f"target {target:g} {unit}")
        ax.set_yticks(range(len(names)), labels if ax is errors else [""] * len(names), fontsize=8)
        ax.set_ylim(len(names) - 0.5, -0.5)  # the first case on top, as in (a)'s legend
        ax.set(xlabel=f"[{unit}]", title=title)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    errors.set_xscale("log")
    speeds.set_xlim(left=0.0)
    save_figure(fig, out_dir / "touchdowns.png")


def grid_campaign(scenario: str) -> CampaignDefinition:
    """The landing campaign over `--case` grids of a landing scenario."""
    return CampaignDefinition(run=run_task, cases=(), runs=10, case_name="case", case_key=GRID, known_cases=(),
                              aggregate=lambda done: {}, case_summary=landing_case_summary, plot=plot_grid,
                              paired=True, build=build_task,
                              description=f"landings of {scenario} over a grid of field values")


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
