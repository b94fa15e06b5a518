"""Running a campaign: checking its output directory, driving its runs through an executor while
each finished run's record is written, and summary.json from the records once all have one."""

from __future__ import annotations

import concurrent.futures as cf
import json
import pickle
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from tqdm import tqdm

from diagrams.montecarlo.definition import CampaignDefinition
from diagrams.montecarlo.executors import _check_executor, _check_workers, _Inline, _open_executor
from diagrams.montecarlo.records import RunRecord, _execute_group, _failure, _Outcome, _write_record, read_records
from diagrams.montecarlo.settings import CampaignSettings, RunTask
from diagrams.outputs import check_writable, write_json
from systems.config import ConfigError

MAX_POOL_DEATHS = 5  # in a row, with no run finishing or blamed between them: something else is wrong


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
    definition's plots) once all have one; returns the summary. `workers`: local processes (None: one
    per core, 0: in this process); `scheduler`: a Dask scheduler's address instead, reached within
    `connect_timeout_s` (None: DEFAULT_CONNECT_TIMEOUT_S).

    Raises ConfigError for bad settings, an output directory holding another campaign, or an
    unreachable scheduler, before anything is written; KeyboardInterrupt passes through after the
    runs that finished are written and the workers are ended."""
    start = time.perf_counter()
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

            _drive(pool, definition.run, _groups(todo, definition), keep, definition.run_group)
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


def _groups(tasks: Sequence[RunTask], definition: CampaignDefinition) -> list[tuple[RunTask, ...]]:
    """The tasks in groups of consecutive runs of one case, up to the definition's group_size (one
    each without `run_group`)."""
    size = definition.group_size if definition.run_group is not None else 1
    groups: list[tuple[RunTask, ...]] = []
    for task in tasks:
        if groups and len(groups[-1]) < size and groups[-1][-1].case == task.case:
            groups[-1] += (task,)
        else:
            groups.append((task,))
    return groups


def _drive(pool, run: Callable, groups: Sequence[tuple[RunTask, ...]], keep: Callable[[RunTask, _Outcome], None],
           run_group: Callable | None = None) -> None:
    """Submits the groups of tasks through `pool` (`_execute_group`), a window at a time, and hands each
    outcome to `keep` as it arrives. When a process pool dies, it is replaced and the runs it held
    become suspects, run one at a time; a run that takes down a pool while alone in it is kept as failed."""
    queue = deque(groups)
    suspects: deque[tuple[RunTask, ...]] = deque()
    in_flight: dict[cf.Future, tuple[RunTask, ...]] = {}
    isolating: set[cf.Future] = set()  # the suspect in flight, alone in its pool
    window = 2 * pool.workers
    deaths_without_progress = 0

    def refill() -> bool:
        """Fills the window (one run while a suspect waits or runs); False when the pool turned out dead
        at a submission (the group goes back)."""
        while (queue or suspects) and len(in_flight) < (1 if suspects or isolating else window):
            source = suspects or queue
            group = source.popleft()
            try:
                future = pool.executor.submit(_execute_group, run, run_group, group)
            except BrokenProcessPool:  # a worker died after its last result came in
                source.appendleft(group)
                return False
            in_flight[future] = group
            if source is suspects:
                isolating.add(future)
        return True

    def pool_died(held: list[tuple[RunTask, ...]]) -> None:
        nonlocal deaths_without_progress
        isolating.clear()
        if len(held) == 1:  # alone in the pool: blamed and kept, which is progress
            keep(held[0][0], _failure("WorkerDied", "the worker process running this run died (a crash in "
                                                 "native code, or killed for lack of memory)"))
            deaths_without_progress = 0
        else:
            deaths_without_progress += 1
            if deaths_without_progress > MAX_POOL_DEATHS:
                raise RuntimeError(f"the worker processes died {deaths_without_progress} times in a row with no "
                                   f"run finishing or blamed; stopping (finished runs are kept)")
            suspects.extend(held)
        pool.restart()

    try:
        while True:
            if not refill() and not in_flight:  # it died holding no run: nothing to blame
                pool_died([])
                continue
            if not in_flight:
                break
            done, _ = cf.wait(in_flight, return_when=cf.FIRST_COMPLETED)
            broken = False
            for future in done:
                group = in_flight[future]
                try:
                    outcomes = future.result()
                except BrokenProcessPool:
                    broken = True
                    continue
                except cf.CancelledError:  # not the run's doing (a Dask scheduler that went away): stop
                    raise RuntimeError(f"the executor cancelled run {group[0].index} of "
                                       f"{group[0].case}; stopping (finished runs are kept)") from None
                except Exception as e:  # the executor's own verdict on these runs (e.g. Dask's KilledWorker)
                    outcomes = [_failure(type(e).__name__, str(e))] * len(group)
                del in_flight[future]
                isolating.discard(future)
                for task, outcome in zip(group, outcomes, strict=True):
                    keep(task, outcome)
                deaths_without_progress = 0
            if broken:
                held = [(task,) for group in in_flight.values() for task in group]  # every run the dead pool held
                in_flight.clear()
                pool_died(held)
    except BaseException:
        # Interrupted: keep what finished, drop the rest (it is redone on resume).
        for future, group in in_flight.items():
            if future.done() and not future.cancelled() and future.exception() is None:
                for task, outcome in zip(group, future.result(), strict=True):
                    keep(task, outcome)
            future.cancel()
        raise


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
        if definition.case_summary is not None:
            cases[case].update(definition.case_summary(done[case], len(bad)))
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
