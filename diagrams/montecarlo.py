"""Monte Carlo campaigns: many independent, seeded runs of one scenario over a few cases (e.g. the
vehicle speeds of seed 002 section 4), spread over local processes or a Dask distributed cluster.

    landing-sim montecarlo gv-marker-ekf --runs 100 --speeds 3 6 12 --workers 2 --out results/mc
    landing-sim montecarlo gv-marker-ekf --runs 1000 --scheduler tcp://host:8786 --out results/mc

What is run is a *campaign definition* (`CampaignDefinition`, looked up by scenario name in
`CAMPAIGNS`): a picklable run function `run(task: RunTask) -> dict | RunOutput`, the cases it knows,
and hooks that aggregate the finished runs into summary.json's "filters" section and draw plots.
What a campaign is made of is its *settings* (`CampaignSettings`: scenario, cases, runs per case,
base seed, `--set` overrides), saved in `<out>/campaign.json`.

Guarantees:
- Seeds: run i of case c gets `run_seed(base_seed, c, i)` (numpy's SeedSequence over the base seed,
  the case's CRC-32 and i), whatever the worker count, executor or completion order. Aggregation
  reads the records back in (case, index) order, so summaries are identical too.
- Nothing done is lost: the main process writes each run's record, `<out>/runs/<case>/<index>.json`
  (plus `<index>.npz` when the run returns arrays), atomically as the run finishes. A run that
  raises is recorded as failed with its exception's type and message; the campaign goes on.
- Resume: running the same command again skips every run that has a record (failed runs too,
  unless `retry_failed`). An output directory holding a campaign with other settings is an error,
  and nothing in it is touched.
- Executors: a local process pool (`spawn` start method: forking a process that has threads, as
  pydrake's, a Dask client's or tqdm's, can deadlock the child, and a fresh interpreter per worker
  keeps runs independent; it costs about 0.5 s per worker once per campaign) or, given a scheduler address, an
  existing Dask cluster through `Client(address).get_executor()`; both are driven through the same
  concurrent.futures interface, a bounded window of tasks in flight at a time. A worker process
  that dies takes down a process pool: the runs it held are retried one at a time in a new pool,
  and the one that kills a pool on its own is recorded as failed. On Dask, the scheduler retries
  runs whose worker died and reports the run as failed (KilledWorker) after its allowed failures.

`workers=0` runs everything in this process, one run after the other (for debugging a run function
with a debugger; no isolation).
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import importlib
import json
import math
import multiprocessing
import os
import pickle
import re
import signal
import socket
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
from tqdm import tqdm

from diagrams.outputs import check_writable, json_default, write_json, write_npz
from systems.config import ConfigError
from systems.noise import stream_id

FORMAT = 1  # of campaign.json and the run records
SEED_SCHEME = "numpy SeedSequence([base_seed, crc32(case), index]).generate_state(1)[0]"
DEFAULT_CONNECT_TIMEOUT_S = 10.0
_CASE_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")  # a case names a directory under runs/


# ------------------------------------------------------------------------------------------------
# What a campaign is: settings, tasks and seeds
# ------------------------------------------------------------------------------------------------

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
        if self.case_key is not None:
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

    def tasks(self, case_key: str | None = None) -> list[RunTask]:
        """Every run of the campaign, case by case, index by index."""
        return [RunTask(self.scenario, case, i, run_seed(self.base_seed, case, i), tuple(self.overrides), case_key)
                for case in self.cases for i in range(self.runs)]

    def to_json(self) -> dict:
        return {"format": FORMAT, "scenario": self.scenario, "cases": list(self.cases), "runs": self.runs,
                "base_seed": self.base_seed, "overrides": list(self.overrides), "seed_scheme": SEED_SCHEME}

    def differences(self, saved: dict) -> list[str]:
        """What differs between these settings and saved ones (cases compare as a set)."""
        mine = self.to_json()
        out = []
        for key in ("scenario", "runs", "base_seed", "overrides", "cases", "format"):
            theirs = saved.get(key)
            same = (sorted(map(str, theirs)) == sorted(mine[key]) if key == "cases" and isinstance(theirs, list)
                    else theirs == mine[key])
            if not same:
                out.append(f"{key}: {_show(theirs)} there, {_show(mine[key])} asked")
        return out


def _show(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)


# ------------------------------------------------------------------------------------------------
# What a run returns and what is kept of it
# ------------------------------------------------------------------------------------------------

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


def _execute(run: Callable, task: RunTask) -> _Outcome:
    """Runs one task in a worker; an Exception becomes a failed outcome (KeyboardInterrupt and
    SystemExit pass: they interrupt the campaign rather than fail the run)."""
    start = time.perf_counter()
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


# ------------------------------------------------------------------------------------------------
# Campaign definitions: what a scenario's campaign runs and how it is summarised
# ------------------------------------------------------------------------------------------------

def parse_number_case(text: str) -> str:
    """A case that is a positive number (a speed in m/s): '6', '6.0' and '6e0' are all '6'."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError(f"'{text}' is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{text} must be a positive number")
    return f"{value:g}"


def _plain_case(text: str) -> str:
    return str(text)


def _stats(values: np.ndarray) -> dict:
    """n, mean, std, rms, min and max over axis 0 (elementwise for vectors)."""
    def out(x):
        return x.tolist() if isinstance(x, np.ndarray) else float(x)

    return {"n": int(values.shape[0]), "mean": out(values.mean(axis=0)), "std": out(values.std(axis=0)),
            "rms": out(np.sqrt(np.mean(values**2, axis=0))), "min": out(values.min(axis=0)),
            "max": out(values.max(axis=0))}


def _numeric_leaves(data, prefix: str = ""):
    """(dotted name, value) of every number, bool and flat list of numbers in nested dicts."""
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            yield from _numeric_leaves(value, f"{name}.")
        elif isinstance(value, (bool, int, float)) and not (isinstance(value, float) and math.isnan(value)):
            yield name, float(value)
        elif (isinstance(value, list) and value and all(isinstance(v, (bool, int, float)) for v in value)):
            yield name, tuple(float(v) for v in value)


def aggregate_fields(metrics: Sequence[dict]) -> dict:
    """Statistics (n, mean, std, rms, min, max) of every numeric field of the given metrics dicts,
    by dotted name, over the runs that have it (lists of numbers elementwise, when all have one
    length; bools as 0/1, so their mean is a fraction)."""
    columns: dict[str, list] = {}
    for m in metrics:
        for name, value in _numeric_leaves(m):
            columns.setdefault(name, []).append(value)
    out = {}
    for name, values in columns.items():
        lengths = {len(v) if isinstance(v, tuple) else 0 for v in values}
        if len(lengths) == 1:
            out[name] = _stats(np.asarray(values, dtype=float))
    return out


def default_aggregate(done: dict[str, list[RunRecord]]) -> dict:
    """summary.json's "filters" section when a campaign gives no aggregation of its own: with
    DESIGN.md's metrics shape (an "estimators" group per run), per estimator and case the
    statistics of its numeric fields; otherwise the same under the single name "metrics"."""
    filters: dict[str, dict] = {}
    for case, records in done.items():
        groups: dict[str, list[dict]] = {}
        for r in records:
            estimators = r.metrics.get("estimators")
            if isinstance(estimators, Mapping) and all(isinstance(v, Mapping) for v in estimators.values()):
                for name, values in estimators.items():
                    groups.setdefault(name, []).append(values)
            else:
                groups.setdefault("metrics", []).append(r.metrics)
        for name, metrics in groups.items():
            filters.setdefault(name, {})[case] = aggregate_fields(metrics)
    return filters


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


# Scenario name -> its campaign: a CampaignDefinition or "module:attribute" (imported when used, so
# the command starts without importing every scenario). The gv-marker-ekf integration adds its line.
CAMPAIGNS: dict[str, CampaignDefinition | str] = {"gv-marker-ekf": "diagrams.gv_marker_ekf_mc:CAMPAIGN"}


def campaign_definition(name: str) -> CampaignDefinition:
    """The campaign of a scenario; ConfigError naming the known ones for any other name."""
    if name not in CAMPAIGNS:
        known = ", ".join(sorted(CAMPAIGNS)) or "none is defined yet"
        raise ConfigError(f"no Monte Carlo campaign for scenario '{name}' (campaigns: {known})")
    entry = CAMPAIGNS[name]
    if isinstance(entry, str):
        module, _, attribute = entry.partition(":")
        entry = getattr(importlib.import_module(module), attribute)
    return entry


def campaign_settings(definition: CampaignDefinition, scenario: str, cases: Sequence[str] | None = None,
                      runs: int | None = None, base_seed: int = 0, overrides: Sequence[str] = ()) -> CampaignSettings:
    """Checked settings: cases parsed and known, at least one run, a non-negative seed."""
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
        if not _CASE_PATTERN.match(case):
            raise ConfigError(f"{name} '{text}' cannot name a directory (letters, digits, '.', '_', '+', '-')")
        if case in parsed:
            raise ConfigError(f"{name} {case} is given twice")
        parsed.append(case)
    for assignment in overrides:
        key, sep, _ = assignment.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects key=value, got '{assignment}'")
        if definition.case_key is not None and key == definition.case_key:
            raise ConfigError(f"--set {key}: the campaign sets {key} from its {name}s")
    settings = CampaignSettings(scenario, tuple(parsed), runs, base_seed, tuple(overrides))
    if definition.case_key is not None:  # bad settings fail here, before anything is written
        for task in settings.tasks(definition.case_key)[::runs]:  # one per case
            task.load_scenario()
    return settings


# ------------------------------------------------------------------------------------------------
# Executors
# ------------------------------------------------------------------------------------------------

class _InlineExecutor(cf.Executor):
    """Runs each task at submission, in this process (workers=0)."""

    def submit(self, fn, /, *args, **kwargs):
        future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as e:
            future.set_exception(e)
        return future


def _ignore_sigint() -> None:
    """Worker processes leave Ctrl-C to the campaign, which ends them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _ProcessPool:
    """A spawn-context process pool that can be replaced when a worker dies."""

    def __init__(self, workers: int):
        self.workers = workers
        self.executor = self._new()

    def _new(self):
        return cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=_ignore_sigint)

    def restart(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)
        self.executor = self._new()

    def close(self, abort: bool = False) -> None:
        if abort:  # Ctrl-C: the workers ignore it, so end them (running runs are redone on resume)
            terminate = getattr(self.executor, "terminate_workers", None)  # Python 3.14
            if terminate is not None:
                terminate()
            else:
                for process in list((getattr(self.executor, "_processes", None) or {}).values()):
                    process.terminate()
        self.executor.shutdown(wait=True, cancel_futures=True)


class _DaskCluster:
    """An existing Dask distributed cluster, through its concurrent.futures executor."""

    def __init__(self, address: str, connect_timeout_s: float):
        try:
            from dask.distributed import Client
        except ImportError:
            raise ConfigError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
        from distributed.comm import parse_address
        from distributed.comm.registry import get_backend

        try:  # a bad scheme is caught here: a Client built on one cannot even close cleanly
            scheme, location = parse_address(address)
            get_backend(scheme)
            if not location:
                raise ValueError("no host given")
        except ValueError as e:
            raise ConfigError(f"bad Dask scheduler address '{address}': {e} (e.g. tcp://host:8786)") from None
        try:
            self.client = Client(address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as e:
            detail = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ConfigError(f"cannot reach the Dask scheduler at {address} within {connect_timeout_s:g} s "
                              f"({detail})") from None
        self.executor = self.client.get_executor(pure=False)
        self.workers = max(1, sum(self.client.nthreads().values()))

    def restart(self) -> None:  # the scheduler replaces dead workers itself
        pass

    def close(self, abort: bool = False) -> None:
        try:
            self.executor.shutdown(wait=not abort)
        finally:
            self.client.close()


class _Inline:
    def __init__(self):
        self.executor = _InlineExecutor()
        self.workers = 1

    def restart(self) -> None:
        pass

    def close(self, abort: bool = False) -> None:
        pass


def _ping(run) -> int:
    """Runs in a worker: unpickling `run` on the way checks that the worker can import it."""
    return os.getpid()


PING_TIMEOUT_S = 120.0


def _check_workers(pool, run) -> None:
    """Fails with a clear message when a worker cannot start or cannot import the run function,
    rather than recording every run as failed."""
    if isinstance(pool, _Inline):
        return
    future = pool.executor.submit(_ping, run)
    try:
        future.result(timeout=PING_TIMEOUT_S)
    except cf.TimeoutError:
        future.cancel()
        raise RuntimeError(f"no worker took a task within {PING_TIMEOUT_S:g} s") from None
    except BrokenProcessPool:
        raise RuntimeError("the worker processes die as they start (a script that runs a campaign needs "
                           "`if __name__ == '__main__':` around it, as multiprocessing's spawn requires)") from None
    except Exception as e:
        raise RuntimeError(f"a worker cannot load the run function {getattr(run, '__qualname__', run)!r} "
                           f"({type(e).__name__}: {e}); its module must be importable there") from None


def _check_executor(workers: int | None, scheduler: str | None) -> None:
    if scheduler is not None and workers is not None:
        raise ConfigError("give --workers or --scheduler, not both (a Dask cluster has its own workers)")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise ConfigError(f"--workers must be a whole number of at least 1 (0: in this process), got {workers}")


def _open_executor(workers: int | None, scheduler: str | None, connect_timeout_s: float):
    """The executor for settings `_check_executor` passed."""
    if scheduler is not None:
        return _DaskCluster(scheduler, connect_timeout_s)
    workers = default_workers() if workers is None else workers
    return _Inline() if workers == 0 else _ProcessPool(workers)


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# ------------------------------------------------------------------------------------------------
# Running a campaign
# ------------------------------------------------------------------------------------------------

def _check_out_dir(out_dir: Path, settings: CampaignSettings) -> None:
    """Raises ConfigError unless `out_dir` is new, empty, or holds this very campaign (a resume)."""
    check_writable(out_dir)
    if not out_dir.exists() or not any(out_dir.iterdir()):
        return
    saved_path = out_dir / "campaign.json"
    if not saved_path.is_file():
        raise ConfigError(f"output directory {out_dir} is not empty and holds no campaign.json; "
                          f"give a new or empty directory")
    try:
        saved = json.loads(saved_path.read_text())
    except (OSError, ValueError) as e:
        raise ConfigError(f"cannot read {saved_path}: {e}") from None
    differences = settings.differences(saved if isinstance(saved, dict) else {})
    if differences:
        raise ConfigError(f"{out_dir} holds a campaign with other settings ({'; '.join(differences)}); "
                          f"give another --out or the same settings to resume it")


def _check_picklable(run) -> None:
    try:
        pickle.dumps(run)
    except Exception as e:
        raise TypeError(f"the campaign's run function {run!r} cannot go to worker processes: it must be "
                        f"picklable (a module-level function): {e}") from None


def run_campaign(definition: CampaignDefinition, settings: CampaignSettings, out_dir: str | Path, *,
                 workers: int | None = None, scheduler: str | None = None, progress: bool = True,
                 retry_failed: bool = False, connect_timeout_s: float | None = None) -> dict:
    """Runs every run of `settings` that `out_dir` holds no record of; writes summary.json (and the
    definition's plots) once all have one; returns the summary.

    Raises ConfigError for bad settings, an output directory holding another campaign, or an
    unreachable scheduler, before anything is written; KeyboardInterrupt passes through after the
    runs that finished are written and the workers are ended."""
    start = time.perf_counter()
    connect_timeout_s = DEFAULT_CONNECT_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s
    out_dir = Path(out_dir)
    _check_executor(workers, scheduler)
    _check_out_dir(out_dir, settings)
    tasks = settings.tasks(definition.case_key)
    records = read_records(out_dir, settings) if out_dir.is_dir() else {}
    finished = {key for key, r in records.items() if r.status == "done" or not retry_failed}
    todo = [t for t in tasks if (t.case, t.index) not in finished]
    failed = sum(1 for key in finished if records[key].status == "failed")
    if todo and scheduler is None and workers != 0:
        _check_picklable(definition.run)
    # Fails fast (an unreachable scheduler, workers that cannot start), before anything is written.
    pool = _open_executor(workers, scheduler, connect_timeout_s) if todo else _Inline()
    aborted = True
    try:
        if todo:
            _check_workers(pool, definition.run)
        out_dir.mkdir(parents=True, exist_ok=True)
        if not (out_dir / "campaign.json").exists():
            write_json(out_dir / "campaign.json", settings.to_json())
        with tqdm(total=len(tasks), initial=len(tasks) - len(todo), unit="run", disable=not progress,
                  desc=settings.scenario, dynamic_ncols=True) as bar:
            bar.set_postfix(failed=failed)

            def keep(task: RunTask, outcome: _Outcome) -> None:
                nonlocal failed
                _write_record(out_dir, task, outcome)
                if outcome.status == "failed":
                    failed += 1
                    bar.set_postfix(failed=failed)
                bar.update(1)

            _drive(pool, definition.run, todo, keep)
        wall = time.perf_counter() - start
        aborted = False
    except KeyboardInterrupt:
        done = len(read_records(out_dir, settings))
        print(f"montecarlo: interrupted with {done} of {settings.runs * len(settings.cases)} runs recorded in "
              f"{out_dir}; run the same command again to resume", file=sys.stderr)
        raise
    finally:
        pool.close(abort=aborted)
    return write_summary(definition, settings, out_dir, wall, computed=len(todo))


MAX_POOL_DEATHS = 5  # in a row, with no run finishing between them: something else is wrong


def _drive(pool, run: Callable, tasks: Sequence[RunTask], keep: Callable[[RunTask, _Outcome], None]) -> None:
    """Submits the tasks through `pool`, a window at a time, and hands each outcome to `keep` as it
    arrives. When a process pool dies, it is replaced and the runs it held become suspects, run one
    at a time; a run that takes down a pool while alone in it is kept as failed."""
    queue = deque(tasks)
    suspects: deque[RunTask] = deque()
    in_flight: dict[cf.Future, RunTask] = {}
    window = 2 * pool.workers
    deaths_without_progress = 0

    def refill() -> None:
        while (queue or suspects) and len(in_flight) < (1 if suspects else window):
            task = (suspects or queue).popleft()
            in_flight[pool.executor.submit(_execute, run, task)] = task

    try:
        refill()
        while in_flight:
            done, _ = cf.wait(in_flight, return_when=cf.FIRST_COMPLETED)
            broken = False
            for future in done:
                try:
                    outcome = future.result()
                except BrokenProcessPool:
                    broken = True
                    continue
                except cf.CancelledError:  # not the run's doing (a Dask scheduler that went away): stop
                    raise RuntimeError(f"the executor cancelled run {in_flight[future].index} of "
                                       f"{in_flight[future].case}; stopping (finished runs are kept)") from None
                except Exception as e:  # the executor's own verdict on this run (e.g. Dask's KilledWorker)
                    outcome = _failure(type(e).__name__, str(e))
                keep(in_flight.pop(future), outcome)
                deaths_without_progress = 0
            if broken:
                deaths_without_progress += 1
                if deaths_without_progress > MAX_POOL_DEATHS:
                    raise RuntimeError(f"the worker processes died {deaths_without_progress} times in a row with no "
                                       f"run finishing; stopping (finished runs are kept)")
                held = list(in_flight.values())  # every run the dead pool held
                in_flight.clear()
                if len(held) == 1:
                    keep(held[0], _failure("WorkerDied", "the worker process running this run died (a crash in "
                                                         "native code, or killed for lack of memory)"))
                else:
                    suspects.extend(held)
                pool.restart()
            refill()
    except BaseException:
        # Interrupted: keep what finished, drop the rest (it is redone on resume).
        for future, task in in_flight.items():
            if future.done() and not future.cancelled() and future.exception() is None:
                keep(task, future.result())
            future.cancel()
        raise


def _failure(kind: str, message: str) -> _Outcome:
    return _Outcome("failed", {}, {}, {"type": kind, "message": message, "traceback": None}, 0.0, "", 0)


def write_summary(definition: CampaignDefinition, settings: CampaignSettings, out_dir: str | Path,
                  wall_time_s: float, computed: int) -> dict:
    """summary.json from every record of the campaign (read back in case and index order, so it
    does not depend on how or in which order the runs were computed), then the plots."""
    out_dir = Path(out_dir)
    records = read_records(out_dir, settings)
    done: dict[str, list[RunRecord]] = {case: [] for case in settings.cases}
    cases = {}
    failures = []
    for case in settings.cases:
        mine = [records[(case, i)] for i in range(settings.runs) if (case, i) in records]
        done[case] = [r for r in mine if r.status == "done"]
        bad = [r for r in mine if r.status == "failed"]
        cases[case] = {"requested": settings.runs, "done": len(done[case]), "failed": len(bad)}
        failures += [{"case": r.case, "index": r.index, "seed": r.seed, "reason": r.reason} for r in bad]
    requested = settings.runs * len(settings.cases)
    summary = {
        "scenario": settings.scenario,
        "runs": {"requested": requested, "done": sum(c["done"] for c in cases.values()),
                 "failed": len(failures), "computed_now": computed},
        "wall_time_s": wall_time_s,
        "runs_per_s": computed / wall_time_s if computed and wall_time_s > 0 else None,
        "filters": definition.aggregate(done),
        "cases": cases,
        "failures": failures,
        "campaign": settings.to_json(),
    }
    write_json(out_dir / "summary.json", summary)
    if definition.plot is not None:
        definition.plot(settings, done, out_dir)
    return summary
