"""What a run returns (`RunOutput`), what its worker sends back, and the record kept of it:
`<out>/runs/<case>/<index>.json` (plus `<index>.npz` when the run returns arrays), written
atomically by the main process and read back as a `RunRecord`."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
import traceback
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from diagrams.montecarlo.settings import FORMAT, CampaignSettings, RunTask
from diagrams.outputs import json_default, write_json, write_npz


@dataclasses.dataclass
class RunOutput:
    """What a run function may return instead of a plain metrics dict: JSON-able metrics plus
    arrays (time series for plots), which go to the run's NPZ file."""

    metrics: dict
    arrays: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class _Outcome:
    """What a worker sends back for one task (picklable)."""

    status: str  # "done" or "failed"
    metrics: dict
    arrays: dict
    error: dict | None
    wall_time_s: float
    host: str
    pid: int


def _execute_group(run: Callable, run_group: Callable | None, tasks: tuple[RunTask, ...]) -> list[_Outcome]:
    """Runs tasks in a worker, an outcome each: together by `run_group` (each outcome's duration its
    share of the group's), or one by one by `run` (without `run_group`, or when the group raised: a
    failure stays its own run's)."""
    if run_group is None or len(tasks) == 1:
        return [_execute(run, task) for task in tasks]
    start = time.perf_counter()
    try:
        outputs = run_group(list(tasks))
    except Exception:
        return [_execute(run, task) for task in tasks]
    share = (time.perf_counter() - start) / len(tasks)
    return [_execute(lambda _, out=out: out, task, share) for task, out in zip(tasks, outputs, strict=True)]


def _execute(run: Callable, task: RunTask, extra_s: float = 0.0) -> _Outcome:
    """Runs one task in a worker; an Exception becomes a failed outcome (KeyboardInterrupt and
    SystemExit pass: they interrupt the campaign rather than fail the run). `extra_s`: time spent on
    it before [s], added to its duration."""
    start = time.perf_counter() - extra_s
    try:
        out = run(task)
        if isinstance(out, RunOutput):
            metrics, arrays = out.metrics, out.arrays
        elif isinstance(out, Mapping):
            metrics, arrays = dict(out), {}
        else:
            raise TypeError(f"a run function returns a dict or a RunOutput, not {type(out).__name__}")
        json.dumps(metrics, default=json_default)  # fail here, as this run's failure, if it cannot be kept
        arrays = {str(k): np.asarray(v) for k, v in arrays.items()}
        status, error = "done", None
    except Exception as e:
        metrics, arrays, status = {}, {}, "failed"
        error = {"type": type(e).__name__, "message": str(e), "traceback": traceback.format_exc(limit=20)}
    return _Outcome(status, metrics, arrays, error, time.perf_counter() - start, socket.gethostname(), os.getpid())


def _failure(kind: str, message: str) -> _Outcome:
    """The outcome of a run that failed outside its run function (its worker died, say)."""
    return _Outcome("failed", {}, {}, {"type": kind, "message": message, "traceback": None}, 0.0, "", 0)


@dataclasses.dataclass
class RunRecord:
    """One run's record as read back from `<out>/runs/<case>/<index>.json`."""

    case: str
    index: int
    seed: int
    status: str  # "done" or "failed"
    metrics: dict
    error: dict | None
    wall_time_s: float
    path: Path  # the JSON file
    has_arrays: bool

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays the run returned (empty when none)."""
        if not self.has_arrays:
            return {}
        with np.load(self.path.with_suffix(".npz")) as data:
            return {k: data[k] for k in data.files}

    @property
    def reason(self) -> str | None:
        return None if self.error is None else f"{self.error['type']}: {self.error['message']}"


def _record_path(out_dir: Path, case: str, index: int) -> Path:
    return out_dir / "runs" / case / f"{index:05d}.json"


def _write_record(out_dir: Path, task: RunTask, outcome: _Outcome) -> None:
    """The NPZ first, then the JSON that says the run is finished (both atomic)."""
    path = _record_path(out_dir, task.case, task.index)
    path.parent.mkdir(parents=True, exist_ok=True)
    if outcome.arrays:
        write_npz(path.with_suffix(".npz"), **outcome.arrays)
    write_json(path, {"format": FORMAT, "scenario": task.scenario, "case": task.case, "index": task.index,
                      "seed": task.seed, "status": outcome.status, "wall_time_s": outcome.wall_time_s,
                      "host": outcome.host, "pid": outcome.pid, "has_arrays": bool(outcome.arrays),
                      "metrics": outcome.metrics, "error": outcome.error})


def _read_record(path: Path) -> RunRecord | None:
    """The record at `path`, or None when there is none or it is unreadable (then the run is redone)."""
    try:
        data = json.loads(path.read_text())
        return RunRecord(str(data["case"]), int(data["index"]), int(data["seed"]), data["status"],
                         data.get("metrics") or {}, data.get("error"), float(data.get("wall_time_s", 0.0)), path,
                         bool(data.get("has_arrays")))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def read_records(out_dir: str | Path, settings: CampaignSettings) -> dict[tuple[str, int], RunRecord]:
    """Every usable record of the campaign's runs, by (case, index); a record whose seed does not
    match the campaign's is ignored (and its run redone)."""
    out_dir = Path(out_dir)
    records = {}
    for task in settings.tasks():
        record = _read_record(_record_path(out_dir, task.case, task.index))
        if record is not None and record.seed == task.seed and record.status in ("done", "failed"):
            records[(task.case, task.index)] = record
    return records
