"""Campaign definitions: what a scenario's campaign runs, the cases it knows and how its finished
runs are summarised and plotted; the registry of them by scenario name (`CAMPAIGNS`), and the
checked settings of a campaign (`campaign_settings`)."""

from __future__ import annotations

import dataclasses
import functools
import importlib
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path

from diagrams.montecarlo.aggregate import default_aggregate
from diagrams.montecarlo.records import RunOutput, RunRecord
from diagrams.montecarlo.settings import CampaignSettings, RunTask
from systems.config import ConfigError

_CASE_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+=,-]*$")  # a case names a directory under runs/
MAX_CASE_BYTES = 255  # a file name's longest on Linux and macOS


def parse_number_case(text: str) -> str:
    """A case that is a positive number (a speed in m/s): '6', '6.0' and '6e0' are all '6'."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError(f"'{text}' is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{text} must be a positive number")
    return repr(value).removesuffix(".0")  # the shortest text that reads back as the value


def _plain_case(text: str) -> str:
    return str(text)


@dataclasses.dataclass(frozen=True)
class CampaignDefinition:
    """A scenario's campaign. `run` must be picklable (a module-level function, or a
    functools.partial of one): it travels to the worker processes or Dask workers, which must be
    able to import its module."""

    run: Callable[[RunTask], dict | RunOutput]
    cases: tuple[str, ...]  # run when none are asked for; also the known cases unless `known_cases`
    runs: int = 100  # per case, when not asked for
    case_name: str = "case"  # what a case is called in messages, e.g. "speed"
    case_key: str | None = None  # the scenario field a case sets, e.g. "vehicle.speed" (RunTask.load_scenario)
    known_cases: tuple[str, ...] | None = None  # accepted cases; None: `cases`; () : any that parses
    parse_case: Callable[[str], str] = _plain_case  # a case as typed -> its canonical name (ConfigError if bad)
    aggregate: Callable[[dict[str, list[RunRecord]]], dict] = default_aggregate  # done runs by case ->
    #   summary.json's "filters": {filter name: {case: {figure: value}}}
    plot: Callable[[CampaignSettings, dict[str, list[RunRecord]], Path], None] | None = None  # draws PNGs
    #   into the output directory from the done runs by case
    description: str = ""
    paired: bool = False  # run i of every case gets the same seed (CampaignSettings.paired)
    case_summary: Callable[[list[RunRecord], int], dict] | None = None  # a case's done runs and how many
    #   of its runs failed (raised) -> figures added to its entry in summary.json's "cases"
    run_group: Callable[[list[RunTask]], list[dict | RunOutput]] | None = None  # up to `group_size` runs of
    #   one case at once, an output per run, each the one `run` gives for it (picklable, like `run`)
    group_size: int = 1  # runs per worker task when `run_group` is given; each still gets its own record
    build: Callable[[RunTask], object] | None = None  # with a `case_key`: builds a run's diagram as `run` does,
    #   without flying it; `campaign_settings` builds each case's first run, so that what only building refuses
    #   (a pad calibration flown with another camera, say) fails before anything is written


# Scenario name -> its campaign: a CampaignDefinition or "module:attribute" (imported when used, so
# the command starts without importing every scenario).
CAMPAIGNS: dict[str, CampaignDefinition | str] = {"gv-marker-ekf": "diagrams.gv_marker_ekf_mc:CAMPAIGN",
                                                  "marker-landing": "diagrams.landing_campaign:CAMPAIGN"}


def campaign_definition(name: str) -> CampaignDefinition:
    """The campaign of a scenario; ConfigError naming the known ones for any other name."""
    if name not in CAMPAIGNS:
        known = ", ".join(sorted(CAMPAIGNS)) or "none is defined yet"
        raise ConfigError(f"no Monte Carlo campaign for scenario '{name}' (campaigns: {known}); a landing scenario "
                          f"(a gv scenario or deck-landing) flies a grid with --case KEY=V1,V2,...")
    entry = CAMPAIGNS[name]
    if isinstance(entry, str):
        module, _, attribute = entry.partition(":")
        entry = getattr(importlib.import_module(module), attribute)
    return entry


def campaign_settings(definition: CampaignDefinition, scenario: str, cases: Sequence[str] | None = None,
                      runs: int | None = None, base_seed: int = 0, overrides: Sequence[str] = ()) -> CampaignSettings:
    """Checked settings: cases parsed and known, at least one run, a non-negative seed, and (with a
    `case_key`) every run's scenario loading with its case and seed, and each case's first run building
    (`CampaignDefinition.build`, when given)."""
    name = definition.case_name
    runs = definition.runs if runs is None else runs
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise ConfigError(f"--runs must be a whole number of at least 1, got {runs}")
    if isinstance(base_seed, bool) or not isinstance(base_seed, int) or base_seed < 0:
        raise ConfigError(f"--seed must be a non-negative whole number, got {base_seed}")
    given = list(definition.cases if cases is None else cases)
    if not given:
        raise ConfigError(f"no {name} given")
    known = definition.cases if definition.known_cases is None else definition.known_cases
    parsed = []
    for text in given:
        try:
            case = definition.parse_case(str(text))
        except ConfigError as e:
            raise ConfigError(f"{name} {e}") from None
        if known and case not in known:
            raise ConfigError(f"unknown {name} '{text}' for {scenario} (known: {', '.join(known)})")
        if len(case.encode()) > MAX_CASE_BYTES:
            raise ConfigError(f"{name} '{case[:40]}...' is too long to name a directory ({len(case.encode())} bytes, "
                              f"at most {MAX_CASE_BYTES})")
        if not _CASE_PATTERN.match(case):
            raise ConfigError(f"{name} '{text}' cannot name a directory (letters, digits, '.', '_', '+', '-', '=', ',')")
        if case in parsed:
            raise ConfigError(f"{name} {case} is given twice")
        parsed.append(case)
    for assignment in overrides:
        key, sep, _ = assignment.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects key=value, got '{assignment}'")
        if key == "seed":
            raise ConfigError("--set seed: the campaign seeds each run (--seed gives its base seed)")
        if definition.case_key is not None and key == definition.case_key:
            raise ConfigError(f"--set {key}: the campaign sets {key} from its {name}s")
    settings = CampaignSettings(scenario, tuple(parsed), runs, base_seed, tuple(overrides), definition.paired)
    if definition.case_key is not None:  # bad settings fail here, before anything is written
        tasks = settings.tasks(definition.case_key)
        checks = [(task, task.load_scenario) for task in tasks]  # every run: a check may depend on the seed
        if definition.build is not None:  # one build per case: a build takes up to a second or two
            checks += [(task, functools.partial(definition.build, task)) for task in tasks if task.index == 0]
        for task, check in checks:
            try:
                check()
            except ConfigError as e:
                raise ConfigError(f"{name} {task.case}, run {task.index} (seed {task.seed}): {e}") from None
    return settings
