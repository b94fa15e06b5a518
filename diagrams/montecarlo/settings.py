"""What a campaign is made of: its settings (saved in campaign.json), the runs they give (`RunTask`)
and the seed of each run."""

from __future__ import annotations

import dataclasses

import numpy as np

from systems.noise import stream_id

FORMAT = 1  # of campaign.json and the run records
SEED_SCHEME = "numpy SeedSequence([base_seed, crc32(case), index]).generate_state(1)[0]"
GRID = "<grid>"  # RunTask.case_key of a campaign whose cases are "key=value[,key=value]" assignments
PAIRED_SEED_SCHEME = "numpy SeedSequence([base_seed, crc32(''), index]).generate_state(1)[0], the same for every case"


def run_seed(base_seed: int, case: str, index: int) -> int:
    """The seed of run `index` of `case`: a pure function of its arguments (a 32-bit integer)."""
    return int(np.random.SeedSequence([int(base_seed), stream_id(case), int(index)]).generate_state(1)[0])


@dataclasses.dataclass(frozen=True)
class RunTask:
    """One run, as its worker gets it. Picklable; the run function needs nothing else."""

    scenario: str
    case: str
    index: int  # 0 .. runs - 1 within its case
    seed: int  # run_seed(base_seed, case, index)
    overrides: tuple[str, ...] = ()  # `--set key=value` assignments, in the order given
    case_key: str | None = None  # the scenario field the case sets (e.g. "vehicle.speed"), if any

    def load_scenario(self):
        """(name, typed scenario) of the named scenario with this run's overrides, its case
        (`case_key=case`) and its seed, loaded as `landing-sim run` would."""
        from diagrams.runner import load_scenario

        overrides = list(self.overrides)
        if self.case_key == GRID:  # a grid campaign's case is its assignments (diagrams/montecarlo/grid.py)
            overrides += self.case.split(",")
        elif self.case_key is not None:
            overrides.append(f"{self.case_key}={self.case}")
        return load_scenario(self.scenario, None, overrides, None, self.seed)


@dataclasses.dataclass(frozen=True)
class CampaignSettings:
    """What a campaign is made of; saved in campaign.json, and compared on resume."""

    scenario: str
    cases: tuple[str, ...]
    runs: int  # per case
    base_seed: int = 0
    overrides: tuple[str, ...] = ()
    paired: bool = False  # run i of every case gets the same seed (cases compared on the same noise)

    def tasks(self, case_key: str | None = None) -> list[RunTask]:
        """Every run of the campaign, case by case, index by index."""
        return [RunTask(self.scenario, case, i, run_seed(self.base_seed, "" if self.paired else case, i),
                        tuple(self.overrides), case_key)
                for case in self.cases for i in range(self.runs)]

    def to_json(self) -> dict:
        return {"format": FORMAT, "scenario": self.scenario, "cases": list(self.cases), "runs": self.runs,
                "base_seed": self.base_seed, "overrides": list(self.overrides), "paired": self.paired,
                "seed_scheme": PAIRED_SEED_SCHEME if self.paired else SEED_SCHEME}

    def differences(self, saved: dict) -> list[str]:
        """What differs between these settings and saved ones (cases compare as a set)."""
        mine = self.to_json()
        out = []
        for key in ("scenario", "runs", "base_seed", "overrides", "cases", "paired", "format"):
            theirs = saved.get(key, False if key == "paired" else None)
            same = (sorted(map(str, theirs)) == sorted(mine[key]) if key == "cases" and isinstance(theirs, list)
                    else theirs == mine[key])
            if not same:
                out.append(f"{key}: {_show(theirs)} there, {_show(mine[key])} asked")
        return out


def _show(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)
