"""The Monte Carlo runner (diagrams/montecarlo/) on small toy campaigns: seeds, identical summaries
whatever the executor (1 or 2 spawned workers, in-process, a Dask LocalCluster), per-run records,
failed and crashing runs, resume after an interruption, protection of an output directory holding
another campaign, an unreachable scheduler, and the `landing-sim montecarlo` command.

The run functions are module-level so that spawned worker processes can import them from here."""

import concurrent.futures as cf
import dataclasses
import functools
import json
import multiprocessing
import os
import re
import signal
import time
import types
from collections import Counter
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from unittest import mock

import matplotlib.pyplot as plt
import numpy as np
import pytest

from diagrams.cli import main
from diagrams.montecarlo import (
    CAMPAIGNS, FORMAT, CampaignDefinition, RunOutput, RunTask, campaign, campaign_settings, executors,
    parse_number_case, read_records, run_campaign, run_seed, write_summary,
)
from diagrams.montecarlo.aggregate import aggregate_fields, default_aggregate
from diagrams.montecarlo.definition import MAX_CASE_BYTES
from diagrams.montecarlo.records import RunRecord
from diagrams.montecarlo.settings import PAIRED_SEED_SCHEME
from diagrams.outputs import save_figure
from systems.config import ConfigError
from systems.noise import stream_id

SPEEDS = ("3", "6", "12")
RUNS = 4


# ---- toy run functions (picklable: module level) ------------------------------------------------

def toy_run(task: RunTask) -> RunOutput:
    """An 'estimator' whose error grows with the speed; a short error series as its arrays."""
    rng = np.random.default_rng(task.seed)
    error = rng.normal(0.0, 0.01 * float(task.case), size=50)
    metrics = {"estimators": {"toy": {"rmse_m": float(np.sqrt(np.mean(error**2))), "valid": bool(error[0] < 0),
                                      "xy_m": [float(error[0]), float(error[1])]}},
               "seed": task.seed}
    return RunOutput(metrics, {"error": error})


def nan_run(task: RunTask) -> dict:
    """Runs that miss values: run 1 a scalar (NaN) and a list's first element, every run the list's last."""
    nan = float("nan")
    return {"x": nan if task.index == 1 else float(task.index),
            "v": [nan if task.index == 1 else float(task.index), 10.0 * task.index, nan]}


def crashing_run(task: RunTask):
    if task.case == "6" and task.index == 2:
        raise ValueError("the filter diverged at t = 3.2 s")
    return toy_run(task)


def interrupting_run(out: Path, task: RunTask):
    """Stands for Ctrl-C in the middle of the campaign recorded in `out`: run 1 of case 6 raises
    KeyboardInterrupt. In a worker process it first waits until the runs before it (all of case 3,
    run 0 of case 6), which may be in flight in another worker, are recorded."""
    if task.case == "6" and task.index == 1:
        if multiprocessing.parent_process() is not None:
            wait_for_files([out / "runs" / "3" / f"{i:05d}.json" for i in range(RUNS)]
                           + [out / "runs" / "6" / "00000.json"])
        raise KeyboardInterrupt
    return toy_run(task)


def recording_interrupting_run(started: list, task: RunTask):
    """Notes each run it starts in `started` (in this process: workers=0); Ctrl-C in run 0 of case 6, the
    first of the runs submitted together."""
    started.append((task.case, task.index))
    if (task.case, task.index) == ("6", 0):
        raise KeyboardInterrupt
    return toy_run(task)


def unkeepable_run(task: RunTask) -> dict:
    """Run 1 returns metrics that JSON cannot hold (a set); the others a number."""
    return {"x": {1, 2} if task.index == 1 else float(task.index)}


def wait_for_files(paths: list[Path], limit_s: float = 120.0) -> None:
    """Returns once every path exists. Raises after `limit_s` without them, so that a run that would
    wait forever fails instead of hanging the test session."""
    deadline = time.monotonic() + limit_s
    while not all(p.exists() for p in paths):
        if time.monotonic() > deadline:
            raise RuntimeError(f"still missing after {limit_s:g} s: {[str(p) for p in paths if not p.exists()]}")
        time.sleep(0.01)


def marker_run(marker: Path, task: RunTask):
    """Fails until the file `marker` exists (a bug fixed between two invocations), then is `toy_run`."""
    if not marker.exists():
        raise ValueError("the filter diverged")
    return toy_run(task)


def dying_run(task: RunTask):
    """A run whose worker process dies (as a segfault in native code would)."""
    if task.case == "6" and task.index == 1:
        os._exit(3)
    return toy_run(task)


def sleeping_run(started: Path, seconds: float) -> None:
    """Notes that it started (the file `started`), then sleeps: a long run a worker is busy with."""
    started.touch()
    time.sleep(seconds)


def always_dying_run(task: RunTask):
    """A run whose worker process dies whatever the task."""
    os._exit(3)


def drake_run(task: RunTask) -> dict:
    """A tiny real pydrake run: x' = -x from a seeded start, simulated for 1 s."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.primitives import LinearSystem

    system = LinearSystem(A=[[-1.0]], B=np.zeros((1, 0)), C=[[1.0]], D=np.zeros((1, 0)))
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    x0 = np.random.default_rng(task.seed).normal()
    context.SetContinuousState([x0])
    simulator.AdvanceTo(1.0)
    return {"x0": float(x0), "x1": float(context.get_continuous_state_vector()[0])}


def rms_aggregate(done):
    """A campaign's own aggregation: RMS over runs of each run's RMSE, per case."""
    return {"toy": {case: {"rms_position_m": float(np.sqrt(np.mean([r.metrics["estimators"]["toy"]["rmse_m"] ** 2
                                                                  for r in records]))) if records else None,
                           "runs": len(records)}
                    for case, records in done.items()}}


def plot_errors(settings, done, out_dir):
    fig, ax = plt.subplots()
    for case, records in done.items():
        ax.plot(np.mean([r.arrays()["error"] for r in records], axis=0), label=f"{case} m/s")
    ax.legend()
    save_figure(fig, Path(out_dir) / "ensemble_error.png")


TOY = CampaignDefinition(run=toy_run, cases=SPEEDS, runs=RUNS, case_name="speed", parse_case=parse_number_case)


def toy(run=toy_run, **kwargs) -> CampaignDefinition:
    return dataclasses.replace(TOY, run=run, **kwargs)


def settings(definition=TOY, **kwargs):
    return campaign_settings(definition, "toy", **kwargs)


def snapshot(directory: Path) -> dict:
    """Every file under `directory` with its modification time and content."""
    return {str(p.relative_to(directory)): (p.stat().st_mtime_ns, p.read_bytes())
            for p in sorted(directory.rglob("*")) if p.is_file()}


def record_versions(out: Path) -> dict:
    """(inode, modification time) of every run record: a record written again (atomically, through a
    new file) gets a new inode, whatever the resolution of the file system's clock."""
    return {str(p.relative_to(out)): (p.stat().st_ino, p.stat().st_mtime_ns) for p in (out / "runs").rglob("*.json")}


# ---- seeds and settings -----------------------------------------------------------------------

def test_seeds_are_a_function_of_base_seed_case_and_index():
    # Pinned: the same in every process and release (Python's hash() of "6" would differ per process).
    assert stream_id("6") == 498629140 and run_seed(0, "6", 3) == 831844793
    seeds = {run_seed(b, c, i) for b in (0, 1) for c in SPEEDS for i in range(50)}
    assert len(seeds) == 2 * 3 * 50  # all distinct
    # Whatever the cases asked for, and in whichever order, run i of a case keeps its seed.
    one = {(t.case, t.index): t.seed for t in settings(cases=["12", "3"]).tasks()}
    two = {(t.case, t.index): t.seed for t in settings(cases=["3", "6", "12"]).tasks()}
    assert all(two[key] == seed for key, seed in one.items())


@pytest.mark.parametrize("kwargs, message", [
    ({"cases": ["7"]}, "unknown speed '7'"),
    ({"cases": ["fast"]}, "speed 'fast' is not a number"),
    ({"cases": ["6", "6.0"]}, "speed 6 is given twice"),
    ({"cases": []}, "no speed given"),
    ({"runs": 0}, "--runs"),
    ({"runs": True}, "--runs"),  # a bool, though Python counts it as 1
    ({"base_seed": -1}, "--seed"),
    ({"base_seed": True}, "--seed"),  # a bool, though Python counts it as 1
    ({"overrides": ["vehicle.speed"]}, "key=value"),
    ({"overrides": ["=5"]}, "key=value"),  # no key
    ({"cases": ["0"]}, "speed 0 must be a positive number"),  # at rest: no speed case
    ({"cases": ["-3"]}, "speed -3 must be a positive number"),
    ({"cases": ["inf"]}, "speed inf must be a positive number"),
    ({"cases": ["nan"]}, "speed nan must be a positive number"),
    ({"cases": ["1e999"]}, "speed 1e999 must be a positive number"),  # inf once read
])
def test_bad_settings_are_config_errors(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        settings(**kwargs)


def test_cases_are_canonical():
    assert settings(cases=["6.0", "3e0"]).cases == ("6", "3")
    assert parse_number_case("12.3456789") == "12.3456789" and parse_number_case("1234567") == "1234567"
    assert parse_number_case("3.0000001") != parse_number_case("3.0000002")  # not rounded into one


def test_a_case_names_a_directory_of_at_most_max_case_bytes(tmp_path):
    """A case is a directory's name under runs/: one of MAX_CASE_BYTES (255, a file name's longest on Linux and
    macOS) bytes is accepted, and names a directory; one byte more is refused."""
    definition = toy(known_cases=(), parse_case=str)
    longest = "a" * MAX_CASE_BYTES
    assert settings(definition, cases=[longest]).cases == (longest,)
    (tmp_path / longest).mkdir()
    with pytest.raises(ConfigError, match=f"is too long to name a directory \\({MAX_CASE_BYTES + 1} bytes"):
        settings(definition, cases=[longest + "a"])


@pytest.mark.parametrize("case", ["..", "-x"])
def test_a_case_that_does_not_start_with_a_letter_or_digit_cannot_name_a_directory(case):
    """A case's directory name starts with a letter or a digit: not '..' (the directory above runs/) nor a name
    a command would read as an option."""
    with pytest.raises(ConfigError, match=f"speed '{re.escape(case)}' cannot name a directory"):
        settings(toy(known_cases=(), parse_case=str), cases=[case])


def test_case_key_loads_the_scenario_with_case_overrides_and_seed():
    definition = toy(case_key="camera.pixel_noise_std", cases=("1", "2"), known_cases=())
    s = campaign_settings(definition, "stewart-hover", overrides=["hover.height_above_deck_m=3"])
    task = s.tasks(definition.case_key)[1]
    name, scenario = task.load_scenario()
    assert name == "stewart-hover" and scenario.camera.pixel_noise_std == 1.0
    assert scenario.hover.height_above_deck_m == 3.0 and scenario.seed == task.seed
    with pytest.raises(ConfigError, match="hover.heigth"):  # checked for every run, before any runs
        campaign_settings(definition, "stewart-hover", overrides=["hover.heigth=3"])
    with pytest.raises(ConfigError, match="sets camera.pixel_noise_std"):
        campaign_settings(definition, "stewart-hover", overrides=["camera.pixel_noise_std=3"])


# ---- executors give identical summaries --------------------------------------------------------

def test_the_aggregate_is_numpys_statistics_over_the_runs_that_have_each_figure():
    metrics = [{"a": 1.0, "ok": True, "xy": [1.0, None], "group": {"b": 2.0}, "ragged": [1.0, 2.0], "mixed": 1.0},
               {"a": 3.0, "ok": False, "xy": [2.0, 4.0], "group": {"b": float("nan")}, "ragged": [1.0], "mixed": [2.0]},
               {"a": -2.0, "ok": True, "xy": [None, None], "group": {"b": 5.0}, "ragged": [3.0, 4.0]}]
    out = aggregate_fields(metrics)
    a = np.array([1.0, 3.0, -2.0])
    assert out["a"] == pytest.approx({"n": 3, "mean": np.mean(a), "std": np.std(a), "rms": np.sqrt(np.mean(a**2)),
                                      "min": -2.0, "max": 3.0})
    assert out["ok"]["mean"] == pytest.approx(2 / 3)  # bools as 0/1: a fraction
    assert out["group.b"] == pytest.approx({"n": 2, "mean": 3.5, "std": 1.5, "rms": np.sqrt(14.5), "min": 2.0,
                                            "max": 5.0})  # the NaN left out
    # elementwise, each element over the runs where it is a number; a list with no number is no run's
    assert out["xy"]["n"] == [2, 1] and out["xy"]["mean"] == pytest.approx([1.5, 4.0])
    assert out["xy"]["rms"] == pytest.approx([np.sqrt(2.5), 4.0])
    assert "ragged" not in out  # lists of different lengths have no elementwise statistics
    assert "mixed" not in out  # nor a number in one run and a list in another (of one element or more)


@pytest.mark.parametrize("metrics, figure, expected", [
    ([{"a": float("nan"), "b": 1.0}, {"a": float("nan"), "b": 2.0}], "a", None),  # no run has a number
    ([{"v": [1.0, 2.0]}, {"v": float("nan")}], "v", {"n": [1, 1], "mean": [1.0, 2.0]}),  # a NaN for the list
    ([{"v": [1.0, 2.0]}, {"v": [None]}], "v", {"n": [1, 1], "mean": [1.0, 2.0]}),  # a list with no number
], ids=["all-nan", "nan-for-a-list", "list-of-nulls"])
def test_a_figure_a_run_misses_whole_is_none_of_that_runs(metrics, figure, expected):
    """A NaN, or a list with no number in it, is no figure: it leaves no statistics of its own, and does not
    stop the other runs' lists of that figure from being aggregated elementwise."""
    out = aggregate_fields(metrics)
    if expected is None:
        assert figure not in out and out["b"]["n"] == 2
    else:
        assert {key: out[figure][key] for key in expected} == expected


def test_runs_whose_estimators_group_holds_a_figure_are_aggregated_whole():
    """DESIGN.md's shape is an "estimators" group of estimators; a run whose group also holds a plain figure is
    not that shape, and its metrics are aggregated under "metrics" whole."""
    record = RunRecord(case="3", index=0, seed=0, status="done", metrics={"estimators": {"ekf": {"e": 1.0}, "runs": 3}},
                       error=None, wall_time_s=0.0, path=Path("00000.json"), has_arrays=False)
    out = default_aggregate({"3": [record]})
    assert list(out) == ["metrics"] and out["metrics"]["3"]["estimators.ekf.e"]["mean"] == 1.0


@pytest.fixture(scope="module")
def pool_campaigns(tmp_path_factory):
    """The toy campaign with 1 and 2 spawned worker processes and in this process."""
    base = tmp_path_factory.mktemp("pools")
    return {workers: (run_campaign(TOY, settings(), base / f"w{workers}", workers=workers, progress=False),
                      base / f"w{workers}") for workers in (1, 2, 0)}


def test_one_and_two_workers_give_identical_summaries(pool_campaigns):
    (one, _), (two, _), (inline, _) = pool_campaigns[1], pool_campaigns[2], pool_campaigns[0]
    assert one["runs"] == {"requested": 12, "done": 12, "failed": 0, "computed_now": 12}
    assert one["filters"] == two["filters"] == inline["filters"]
    assert list(one["filters"]["toy"]) == list(SPEEDS)
    stats = one["filters"]["toy"]["12"]["rmse_m"]
    assert stats["n"] == RUNS and set(stats) == {"n", "mean", "std", "rms", "min", "max"}
    assert one["filters"]["toy"]["3"]["rmse_m"]["mean"] < stats["mean"]  # the toy's trend
    assert len(one["filters"]["toy"]["3"]["xy_m"]["mean"]) == 2  # lists elementwise
    assert one["runs_per_s"] > 0 and one["wall_time_s"] > 0


def test_each_run_leaves_its_record_and_arrays(pool_campaigns):
    summary, out = pool_campaigns[2]
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["runs"] == summary["runs"] and on_disk["filters"] == summary["filters"]
    assert json.loads((out / "campaign.json").read_text())["cases"] == list(SPEEDS)
    record = json.loads((out / "runs" / "6" / "00003.json").read_text())
    assert record["status"] == "done" and record["seed"] == run_seed(0, "6", 3) == record["metrics"]["seed"]
    assert record["pid"] != os.getpid()  # computed in a worker process
    with np.load(out / "runs" / "6" / "00003.npz") as arrays:
        np.testing.assert_array_equal(arrays["error"], toy_run(RunTask("toy", "6", 3, record["seed"])).arrays["error"])
    names = [p.name for p in out.rglob("*")]
    assert not [n for n in names if "partial" in n], names


@pytest.mark.slow
def test_pydrake_runs_in_spawned_workers(tmp_path):
    definition = toy(run=drake_run)
    s = settings(definition, cases=["3", "6"], runs=2)
    two = run_campaign(definition, s, tmp_path / "pool", workers=2, progress=False)
    inline = run_campaign(definition, s, tmp_path / "inline", workers=0, progress=False)
    assert two["runs"]["done"] == 4 and two["filters"] == inline["filters"]
    record = read_records(tmp_path / "pool", s)[("6", 1)]
    assert record.metrics["x1"] == pytest.approx(record.metrics["x0"] * np.exp(-1.0), rel=1e-4)


@pytest.fixture(scope="module")
def local_cluster():
    from dask.distributed import LocalCluster

    cluster = LocalCluster(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=None)
    yield cluster
    cluster.close()


def test_dask_local_cluster_gives_the_process_pool_summary(local_cluster, pool_campaigns, tmp_path):
    summary = run_campaign(TOY, settings(), tmp_path / "dask", scheduler=local_cluster.scheduler_address,
                           progress=False)
    assert summary["runs"] == pool_campaigns[1][0]["runs"]
    assert summary["filters"] == pool_campaigns[1][0]["filters"]


def test_a_crashing_run_on_dask_is_recorded_as_failed(local_cluster, tmp_path):
    summary = run_campaign(toy(run=crashing_run), settings(), tmp_path, scheduler=local_cluster.scheduler_address,
                           progress=False)
    assert summary["runs"]["done"] == 11
    assert [f["reason"] for f in summary["failures"]] == ["ValueError: the filter diverged at t = 3.2 s"]


def test_unreachable_scheduler_fails_fast_and_writes_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9 within 1 s"):
        run_campaign(TOY, settings(), out, scheduler="tcp://127.0.0.1:9", connect_timeout_s=1.0, progress=False)
    with pytest.raises(ConfigError, match="bad Dask scheduler address 'nonsense://x'"):
        run_campaign(TOY, settings(), out, scheduler="nonsense://x", progress=False)
    assert not out.exists()


def test_workers_0_and_a_scheduler_together_are_refused_before_anything_runs(tmp_path):
    """workers=0 (in this process) is a worker count given, as much as 2 is: with a scheduler it is refused
    at once, not taken as no count and the scheduler tried."""
    with pytest.raises(ConfigError, match="give --workers or --scheduler, not both"):
        run_campaign(TOY, settings(), tmp_path / "out", workers=0, scheduler="tcp://127.0.0.1:9",
                     connect_timeout_s=1.0, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("abort, wait", [(False, True), (True, False)])
def test_closing_a_dask_cluster_waits_for_its_runs_unless_aborted(abort, wait):
    """A campaign that ends closes the Dask executor waiting for what it holds; one aborted (Ctrl-C) does not
    wait. The client is closed either way."""
    cluster = object.__new__(executors._DaskCluster)  # no scheduler: the executor and client stand in
    cluster.executor, cluster.client = mock.Mock(), mock.Mock()
    cluster.close(abort=abort)
    cluster.executor.shutdown.assert_called_once_with(wait=wait)
    cluster.client.close.assert_called_once_with()


@pytest.fixture
def fake_client(monkeypatch):
    """dask.distributed.Client replaced by a mock (no scheduler reached) whose cluster has no worker yet."""
    client = mock.Mock()
    client.nthreads.return_value = {}
    make = mock.Mock(return_value=client)
    monkeypatch.setattr("dask.distributed.Client", make)
    return make


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:1", "tcp://127.0.0.1:65535"])
def test_a_dask_cluster_with_no_worker_yet_keeps_one_run_in_flight(fake_client, address):
    """The ports 1 and 65535 (the range's ends) are addresses to try; a cluster whose workers have not joined yet
    counts as one worker, so that the campaign's window of runs in flight is not empty."""
    cluster = executors._DaskCluster(address, 1.0)
    fake_client.assert_called_once_with(address, timeout=1.0, set_as_default=False)
    assert cluster.workers == 1


@pytest.mark.parametrize("timeout_s, expected_s", [(None, executors.DEFAULT_CONNECT_TIMEOUT_S), (0.0, 0.0), (2.5, 2.5)])
def test_only_no_connect_timeout_is_the_default_one(fake_client, timeout_s, expected_s):
    executors._open_executor(None, "tcp://127.0.0.1:8786", timeout_s)
    fake_client.assert_called_once_with("tcp://127.0.0.1:8786", timeout=expected_s, set_as_default=False)


@pytest.mark.parametrize("workers, kind", [(0, executors._Inline), (1, executors._ProcessPool),
                                           (2, executors._ProcessPool)])
def test_only_workers_0_runs_in_this_process(workers, kind):
    """One worker is a worker process (isolated from this one), as two are; no process starts before a task."""
    pool = executors._open_executor(workers, None, None)
    try:
        assert type(pool) is kind and pool.workers == max(workers, 1)
    finally:
        pool.close()


def test_cores_are_those_this_process_may_use_else_all(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)  # 2 of the 8 cores
    assert executors.default_workers() == 2
    monkeypatch.delattr(os, "sched_getaffinity")  # macOS, Windows: no affinity
    assert executors.default_workers() == 8


def test_no_worker_taking_the_first_task_in_time_is_an_error_and_the_task_cancelled():
    future = mock.Mock()
    future.result.side_effect = cf.TimeoutError
    pool = types.SimpleNamespace(executor=types.SimpleNamespace(submit=lambda fn, *args: future), workers=1)
    with pytest.raises(RuntimeError, match=f"^no worker took a task within {executors.PING_TIMEOUT_S:g} s$"):
        executors._check_workers(pool, toy_run)
    future.result.assert_called_once_with(timeout=executors.PING_TIMEOUT_S)
    future.cancel.assert_called_once_with()


def test_workers_dying_as_they_start_name_the_main_guard():
    """A pool whose first task finds it broken (workers of a script without `if __name__ == '__main__':` die as
    spawn imports it) is reported as such, not as a run function the workers cannot load."""
    broken = cf.Future()
    broken.set_exception(BrokenProcessPool("a process in the pool was terminated abruptly"))
    pool = types.SimpleNamespace(executor=types.SimpleNamespace(submit=lambda fn, *args: broken), workers=1)
    with pytest.raises(RuntimeError, match=re.escape("`if __name__ == '__main__':`")):
        executors._check_workers(pool, toy_run)


@pytest.mark.parametrize("workers", [True, -1, 1.5])
def test_a_worker_count_that_is_no_whole_number_is_refused_before_anything_runs(tmp_path, workers):
    """--workers is a whole number of at least 0: True (a bool, though Python counts it as 1), a negative
    number or a fraction is a ConfigError, and nothing is written."""
    with pytest.raises(ConfigError, match=rf"--workers must be a whole number .*, got {workers}$"):
        run_campaign(TOY, settings(cases=["3"], runs=1), tmp_path / "out", workers=workers, progress=False)
    assert not (tmp_path / "out").exists()


def test_closing_the_pool_on_ctrl_c_ends_the_workers_busy_with_a_run(tmp_path):
    """Workers ignore Ctrl-C, so the pool closed on an abort terminates them rather than waiting for
    their runs: the worker busy with a 5 s run ends on a signal (a negative exit code), the run unfinished.
    (Waiting instead takes those 5 s and the worker exits with 0.)"""
    pool = executors._ProcessPool(1)
    started = tmp_path / "started"
    future = pool.executor.submit(sleeping_run, started, 5.0)
    try:
        wait_for_files([started], limit_s=60.0)
        workers = list(pool.executor._processes.values())
    finally:
        pool.close(abort=True)
    assert [worker.exitcode for worker in workers] == [-signal.SIGTERM]
    assert isinstance(future.exception(timeout=0), BrokenProcessPool)


@pytest.mark.parametrize("address, problem", [
    ("127.0.0.1", "missing port number"),  # a Client half-built on it: two tracebacks and a 20 s wait
    ("tcp://127.0.0.1:99999", "port 99999 is not 1 to 65535"),  # reported as unreachable after 10 s
    ("tcp://127.0.0.1:0", "port 0 is not 1 to 65535"),
    ("tcp://127.0.0.1:65536", "port 65536 is not 1 to 65535"),  # one past the largest port
    ("tcp://127.0.0.1:http", "invalid literal"),
    ("tcp://", "no host given"),
])
def test_a_scheduler_address_without_a_good_port_is_refused_at_once(capfd, tmp_path, address, problem):
    with pytest.raises(ConfigError, match=f"^bad Dask scheduler address '{re.escape(address)}': .*{problem}"):
        run_campaign(TOY, settings(), tmp_path / "out", scheduler=address, connect_timeout_s=1.0, progress=False)
    assert capfd.readouterr().err == "" and not (tmp_path / "out").exists()


def test_values_a_run_misses_are_left_out_of_their_element_and_summary_json_is_strict_json(tmp_path):
    # The records keep a NaN as null; each list element's figures are over the runs that have it.
    summary = run_campaign(toy(run=nan_run), settings(cases=["3"], runs=3), tmp_path, workers=0, progress=False)
    strict = json.loads((tmp_path / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    for stats in (summary["filters"]["metrics"]["3"], strict["filters"]["metrics"]["3"]):
        assert stats["x"]["n"] == 2 and stats["x"]["mean"] == 1.0  # runs 0 and 2
        assert stats["v"]["n"] == [2, 3, 0] and stats["v"]["mean"][:2] == [1.0, 10.0]
        assert stats["v"]["max"][:2] == [2.0, 20.0] and stats["v"]["min"][:2] == [0.0, 0.0]
    assert np.isnan(summary["filters"]["metrics"]["3"]["v"]["mean"][2])  # no run has it: NaN, null on disk
    assert strict["filters"]["metrics"]["3"]["v"]["mean"][2] is None
    record = json.loads((tmp_path / "runs" / "3" / "00001.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert record["metrics"] == {"x": None, "v": [None, 10.0, None]}


# ---- failures, resume, protection --------------------------------------------------------------

@pytest.mark.slow
def test_a_crashing_run_is_recorded_as_failed_and_the_campaign_goes_on(tmp_path):
    s = settings()
    summary = run_campaign(toy(run=crashing_run), s, tmp_path, workers=2, progress=False)
    assert summary["runs"]["done"] == 11 and summary["runs"]["failed"] == 1
    assert summary["cases"]["6"] == {"requested": RUNS, "done": RUNS - 1, "failed": 1}
    assert summary["failures"] == [{"case": "6", "index": 2, "seed": run_seed(0, "6", 2),
                                    "reason": "ValueError: the filter diverged at t = 3.2 s"}]
    assert summary["filters"]["toy"]["6"]["rmse_m"]["n"] == RUNS - 1
    record = json.loads((tmp_path / "runs" / "6" / "00002.json").read_text())
    assert record["status"] == "failed" and record["error"]["type"] == "ValueError"
    assert "crashing_run" in record["error"]["traceback"]
    # Re-running keeps the failure; --retry-failed runs it again (and only it).
    before = record_versions(tmp_path)
    again = run_campaign(toy(run=crashing_run), s, tmp_path, workers=0, progress=False)
    assert again["runs"]["computed_now"] == 0 and again["runs"]["failed"] == 1
    fixed = run_campaign(TOY, s, tmp_path, workers=0, progress=False, retry_failed=True)
    assert fixed["runs"] == {"requested": 12, "done": 12, "failed": 0, "computed_now": 1}
    after = record_versions(tmp_path)
    assert [k for k in before if before[k] != after[k]] == [str(Path("runs") / "6" / "00002.json")]


@pytest.mark.slow
def test_a_run_that_kills_its_worker_is_recorded_and_the_campaign_goes_on(tmp_path):
    summary = run_campaign(toy(run=dying_run), settings(), tmp_path, workers=2, progress=False)
    assert summary["runs"]["done"] == 11 and summary["runs"]["failed"] == 1
    (failure,) = summary["failures"]
    assert (failure["case"], failure["index"]) == ("6", 1) and failure["reason"].startswith("WorkerDied")


@pytest.mark.slow
def test_runs_that_all_kill_their_worker_are_recorded_and_the_campaign_ends_with_a_summary(tmp_path):
    summary = run_campaign(toy(run=always_dying_run), settings(cases=["6"]), tmp_path, workers=1, progress=False)
    assert summary["runs"] == {"requested": RUNS, "done": 0, "failed": RUNS, "computed_now": RUNS}
    assert [(f["index"], f["reason"].split(":")[0]) for f in summary["failures"]] == [
        (i, "WorkerDied") for i in range(RUNS)]
    assert (tmp_path / "summary.json").is_file()


@pytest.mark.parametrize("workers", [2, 0])
def test_interrupted_campaign_resumes_without_redoing_finished_runs(tmp_path, pool_campaigns, workers):
    s = settings()
    with pytest.raises(KeyboardInterrupt):
        run_campaign(toy(run=functools.partial(interrupting_run, tmp_path)), s, tmp_path, workers=workers,
                     progress=False)
    finished = read_records(tmp_path, s)
    assert 0 < len(finished) < 12 and ("6", 1) not in finished
    assert all(r.status == "done" for r in finished.values())
    assert not (tmp_path / "summary.json").exists()
    before = record_versions(tmp_path)
    summary = run_campaign(TOY, s, tmp_path, workers=workers, progress=False)
    assert summary["runs"]["computed_now"] == 12 - len(finished) and summary["runs"]["done"] == 12
    after = record_versions(tmp_path)
    assert all(after[k] == v for k, v in before.items())  # finished runs were not written again
    assert summary["filters"] == pool_campaigns[1][0]["filters"]


def test_ctrl_c_in_process_starts_no_other_run(tmp_path):
    started = []
    with pytest.raises(KeyboardInterrupt):
        run_campaign(toy(run=functools.partial(recording_interrupting_run, started)), settings(), tmp_path,
                     workers=0, progress=False)
    assert started[-1] == ("6", 0)


@pytest.mark.parametrize("change, named", [
    ({"runs": 5}, "runs: 4 there, 5 asked"),
    ({"base_seed": 1}, "base_seed"),
    ({"overrides": ["noise=2"]}, "overrides"),
    ({"cases": ["3", "6"]}, "cases"),
])
def test_an_output_directory_with_another_campaign_is_an_error_and_untouched(pool_campaigns, change, named):
    _, out = pool_campaigns[0]
    before = snapshot(out)
    with pytest.raises(ConfigError, match=named):
        run_campaign(TOY, settings(**change), out, workers=0, progress=False)
    assert snapshot(out) == before


def test_same_settings_in_another_case_order_resume_the_campaign(pool_campaigns):
    _, out = pool_campaigns[0]
    before = snapshot(out / "runs")
    summary = run_campaign(TOY, settings(cases=["12", "6", "3"]), out, workers=0, progress=False)
    assert summary["runs"]["computed_now"] == 0 and snapshot(out / "runs") == before


def test_a_campaign_json_without_paired_resumes_as_unpaired_and_one_of_another_format_is_refused(tmp_path):
    """A campaign.json from before `paired` existed has no such key: its runs were unpaired, and it resumes as
    paired: false (a paired campaign is another one). A campaign.json of another format is another campaign."""
    s = settings(runs=1)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    saved = json.loads((tmp_path / "campaign.json").read_text())
    (tmp_path / "campaign.json").write_text(json.dumps({key: value for key, value in saved.items() if key != "paired"}))
    before = snapshot(tmp_path / "runs")
    assert run_campaign(TOY, s, tmp_path, workers=0, progress=False)["runs"]["computed_now"] == 0
    assert snapshot(tmp_path / "runs") == before
    with pytest.raises(ConfigError, match=r"\(paired: False there, True asked\)"):
        run_campaign(TOY, dataclasses.replace(s, paired=True), tmp_path, workers=0, progress=False)
    (tmp_path / "campaign.json").write_text(json.dumps({**saved, "format": FORMAT + 1}))
    with pytest.raises(ConfigError, match=rf"\(format: {FORMAT + 1} there, {FORMAT} asked\)"):
        run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    assert snapshot(tmp_path / "runs") == before


def test_a_non_empty_directory_that_is_no_campaign_is_an_error(tmp_path):
    (tmp_path / "metrics.json").write_text("{}")
    with pytest.raises(ConfigError, match="holds no campaign.json"):
        run_campaign(TOY, settings(), tmp_path, workers=0, progress=False)
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]


@pytest.mark.parametrize("change, named", [
    (lambda saved: [], r"\(scenario: None there, toy asked; "),  # no object: none of the settings
    (lambda saved: {**saved, "scenario": "other"}, r"\(scenario: other there, toy asked\)"),
    (lambda saved: {key: value for key, value in saved.items() if key != "cases"},
     r"\(cases: None there, \[3\] asked\)"),
], ids=["no-object", "other-scenario", "no-cases"])
def test_a_campaign_json_of_other_settings_is_another_campaign_and_untouched(tmp_path, change, named):
    s = settings(cases=["3"], runs=1)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    saved = json.loads((tmp_path / "campaign.json").read_text())
    (tmp_path / "campaign.json").write_text(json.dumps(change(saved)))
    before = snapshot(tmp_path)
    with pytest.raises(ConfigError, match=named):
        run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    assert snapshot(tmp_path) == before


def test_cases_compare_as_a_set_of_text():
    """The saved cases in another order, or as numbers, are the same cases; a missing case or none is another
    campaign."""
    s = settings(cases=["3", "6"])
    saved = s.to_json()
    assert s.differences({**saved, "cases": ["6", "3"]}) == [] and s.differences({**saved, "cases": [6, 3]}) == []
    assert s.differences({**saved, "cases": ["3"]}) == ["cases: [3] there, [3, 6] asked"]
    assert s.differences({key: value for key, value in saved.items() if key != "cases"}) == [
        "cases: None there, [3, 6] asked"]


def test_overrides_are_kept_in_the_order_given_and_another_order_is_another_campaign(tmp_path):
    """A later `--set` of a key wins over an earlier one, so the order of the overrides is part of the campaign."""
    run_campaign(TOY, settings(cases=["3"], runs=1, overrides=["b=1", "a=2"]), tmp_path, workers=0, progress=False)
    assert json.loads((tmp_path / "campaign.json").read_text())["overrides"] == ["b=1", "a=2"]
    with pytest.raises(ConfigError, match=r"\(overrides: \[b=1, a=2\] there, \[a=2, b=1\] asked\)"):
        run_campaign(TOY, settings(cases=["3"], runs=1, overrides=["a=2", "b=1"]), tmp_path, workers=0,
                     progress=False)


def test_a_finished_campaign_run_again_reaches_no_executor(tmp_path):
    """With no run left to compute, the campaign opens no executor: an unreachable scheduler is not tried, and the
    summary is written again from the records."""
    s = settings(cases=["3"], runs=1)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    summary = run_campaign(TOY, s, tmp_path, scheduler="tcp://127.0.0.1:9", connect_timeout_s=1.0, progress=False)
    assert summary["runs"] == {"requested": 1, "done": 1, "failed": 0, "computed_now": 0}


def test_a_resumed_campaign_keeps_its_campaign_json(tmp_path):
    """campaign.json is written once, when the campaign starts: a resume that computes a run leaves the file as it
    was (the same inode: not written again, atomically or not)."""
    s = settings(cases=["3"], runs=2)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    (tmp_path / "runs" / "3" / "00001.json").unlink()
    saved = (tmp_path / "campaign.json").stat()
    summary = run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    assert summary["runs"]["computed_now"] == 1
    again = (tmp_path / "campaign.json").stat()
    assert (again.st_ino, again.st_mtime_ns) == (saved.st_ino, saved.st_mtime_ns)


def test_a_resumed_campaigns_progress_counts_the_failed_runs_on_record(tmp_path, capfd):
    """The progress bar of a resumed campaign starts from the failed runs it holds records of: 1 (run 2 of case 6)."""
    definition = toy(run=crashing_run)
    s = settings(definition, cases=["6"], runs=3)
    run_campaign(definition, s, tmp_path, workers=0, progress=False)
    capfd.readouterr()
    run_campaign(definition, s, tmp_path, workers=0, progress=True)
    assert set(re.findall(r"failed=(\d+)", capfd.readouterr().err)) == {"1"}


def test_a_run_function_that_cannot_be_pickled_is_refused_up_front(tmp_path):
    with pytest.raises(TypeError, match="picklable"):
        run_campaign(toy(run=lambda task: {}), settings(), tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_run_in_this_process_need_not_be_picklable_and_may_return_any_mapping(tmp_path):
    """workers=0 sends the run function nowhere, so a lambda will do; a run's metrics are any Mapping (here a
    read-only one), not only a dict."""
    s = settings(cases=["3"], runs=2)
    summary = run_campaign(toy(run=lambda task: types.MappingProxyType({"x": float(task.index)})), s, tmp_path,
                           workers=0, progress=False)
    assert summary["runs"]["done"] == 2 and summary["runs"]["failed"] == 0
    assert [r.metrics for r in read_records(tmp_path, s).values()] == [{"x": 0.0}, {"x": 1.0}]


@pytest.mark.parametrize("computed, wall_time_s, runs_per_s", [(2, 4.0, 0.5), (0, 4.0, None), (2, 0.0, None)])
def test_the_runs_per_second_are_the_runs_computed_over_the_wall_time(tmp_path, computed, wall_time_s, runs_per_s):
    """None when no run was computed now (a finished campaign run again) or no time was measured."""
    summary = write_summary(TOY, settings(cases=["3"], runs=2), tmp_path, wall_time_s=wall_time_s, computed=computed)
    assert summary["runs_per_s"] == runs_per_s


def test_a_case_summary_is_given_the_number_of_failed_runs(tmp_path):
    """case_summary gets a case's done runs and how many of its runs failed: 2 done and 1 failed of 3."""
    definition = toy(run=crashing_run, case_summary=lambda done, failed: {"ended": len(done) + failed,
                                                                         "failed_seen": failed})
    summary = run_campaign(definition, settings(definition, cases=["6"], runs=3), tmp_path, workers=0,
                           progress=False)
    assert summary["cases"]["6"] == {"requested": 3, "done": 2, "failed": 1, "ended": 3, "failed_seen": 1}


def test_a_paired_campaign_gives_run_i_one_seed_in_every_case_and_says_so(tmp_path):
    definition = toy(paired=True)
    s = settings(definition, cases=["3", "6"], runs=2)
    run_campaign(definition, s, tmp_path, workers=0, progress=False)
    records = read_records(tmp_path, s)
    assert [records[("3", i)].seed for i in range(2)] == [records[("6", i)].seed for i in range(2)]
    assert [records[("3", i)].seed for i in range(2)] == [run_seed(0, "", i) for i in range(2)]
    saved = json.loads((tmp_path / "campaign.json").read_text())
    assert saved["paired"] is True and saved["seed_scheme"] == PAIRED_SEED_SCHEME


def test_the_campaign_chooses_its_aggregation_and_plots(tmp_path):
    definition = toy(aggregate=rms_aggregate, plot=plot_errors)
    summary = run_campaign(definition, settings(definition), tmp_path, workers=0, progress=False)
    assert set(summary["filters"]) == {"toy"} and list(summary["filters"]["toy"]) == list(SPEEDS)
    assert summary["filters"]["toy"]["6"]["runs"] == RUNS
    assert (tmp_path / "ensemble_error.png").stat().st_size > 1000


# ---- the command ----------------------------------------------------------------------------

@pytest.fixture
def toy_registered(monkeypatch):
    monkeypatch.setitem(CAMPAIGNS, "toy", TOY)
    monkeypatch.setattr(executors, "DEFAULT_CONNECT_TIMEOUT_S", 1.0)


def test_command_runs_a_campaign_and_says_where_its_summary_is(capfd, tmp_path, toy_registered):
    out = tmp_path / "mc"
    code = main(["montecarlo", "toy", "--runs", "2", "--speeds", "3", "12", "--workers", "0", "--out", str(out)])
    captured = capfd.readouterr()
    assert code == 0, captured.err
    assert captured.out.count("\n") == 1 and "4 of 4 runs done, 0 failed" in captured.out
    assert str(out / "summary.json") in captured.out
    assert "4/4" in captured.err  # the progress bar
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["filters"]["toy"]) == ["3", "12"]


@pytest.mark.parametrize("args, named", [
    (["montecarlo", "no-such-scenario"], "no Monte Carlo campaign for scenario 'no-such-scenario'"),
    (["montecarlo", "deck-landing"], "flies a grid with --case"),
    (["montecarlo", "toy", "--speeds", "3", "7"], "unknown speed '7'"),
    (["montecarlo", "toy", "--runs", "0"], "--runs"),
    (["montecarlo", "toy", "--speeds", "fast"], "'fast' is not a number"),
    (["montecarlo", "toy", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"], "not allowed with"),
    (["montecarlo", "toy", "--workers", "-1"], "--workers"),
    (["montecarlo", "toy", "--scheduler", "tcp://127.0.0.1:9"], "cannot reach the Dask scheduler"),
    (["montecarlo", "toy", "--set", "novalue"], "key=value"),
    (["montecarlo", "toy", "--runs", "many"], "--runs"),
], ids=["unknown-scenario", "landing-scenario-without-case", "unknown-speed", "zero-runs", "speed-not-a-number",
        "workers-and-scheduler", "negative-workers", "unreachable-scheduler", "bad-set", "runs-not-a-number"])
def test_command_errors_give_one_line_exit_2_and_write_nothing(capfd, tmp_path, toy_registered, args, named):
    out = tmp_path / "mc"
    code = main(args + ["--out", str(out), "--quiet"])
    captured = capfd.readouterr()
    assert code == 2
    assert captured.err.count("\n") == 1 and captured.err.startswith("landing-sim: error: "), captured.err
    assert named in captured.err and captured.out == ""
    assert not out.exists()


def test_command_refuses_a_directory_with_another_campaign(capfd, pool_campaigns, toy_registered):
    _, out = pool_campaigns[0]
    before = snapshot(out)
    code = main(["montecarlo", "toy", "--runs", "7", "--workers", "0", "--out", str(out), "--quiet"])
    captured = capfd.readouterr()
    assert code == 2 and captured.err.count("\n") == 1 and "runs: 4 there, 7 asked" in captured.err
    assert snapshot(out) == before


def test_command_writes_into_results_scenario_mc_by_default(capfd, tmp_path, monkeypatch, toy_registered):
    monkeypatch.chdir(tmp_path)
    code = main(["montecarlo", "toy", "--runs", "1", "--speeds", "3", "--workers", "0", "--quiet"])
    captured = capfd.readouterr()
    assert code == 0, captured.err
    assert (tmp_path / "results" / "toy-mc" / "summary.json").is_file()
    assert "summary in results/toy-mc/summary.json" in captured.out
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["toy-mc"]


def test_command_base_seed_is_0_unless_given(capfd, tmp_path, toy_registered):
    """Without --seed the runs get the seeds of --seed 0 (run_seed of base 0); --seed 1 gives others."""
    seeds = {}
    for name, args in (("default", []), ("0", ["--seed", "0"]), ("1", ["--seed", "1"])):
        out = tmp_path / name
        code = main(["montecarlo", "toy", "--runs", "1", "--speeds", "3", "--workers", "0", "--quiet",
                     "--out", str(out), *args])
        assert code == 0, capfd.readouterr().err
        seeds[name] = json.loads((out / "runs" / "3" / "00000.json").read_text())["seed"]
    assert seeds == {"default": run_seed(0, "3", 0), "0": run_seed(0, "3", 0), "1": run_seed(1, "3", 0)}
    assert run_seed(0, "3", 0) != run_seed(1, "3", 0)


def test_command_retry_failed_runs_the_failed_runs_again(capfd, tmp_path, monkeypatch, toy_registered):
    """A failed run stays failed when the command is run again; with --retry-failed it is run again (and, the bug
    behind it fixed, done)."""
    marker = tmp_path / "fixed"
    monkeypatch.setitem(CAMPAIGNS, "toy", toy(run=functools.partial(marker_run, marker)))
    args = ["montecarlo", "toy", "--runs", "1", "--speeds", "3", "--workers", "0", "--quiet", "--out",
            str(tmp_path / "mc")]
    outputs = []
    for extra in ([], [], ["--retry-failed"]):
        code = main(args + extra)
        captured = capfd.readouterr()
        assert code == 0, captured.err
        outputs.append(captured.out)
        marker.touch()  # fixed after the first: only --retry-failed runs it again
    assert "0 of 1 runs done, 1 failed (1 run now" in outputs[0]
    assert "0 of 1 runs done, 1 failed (0 run now" in outputs[1]
    assert "1 of 1 runs done, 0 failed (1 run now" in outputs[2]


# ---- runs in groups -----------------------------------------------------------------------------

def toy_group(tasks: list[RunTask]) -> list[RunOutput]:
    """`toy_run` of runs of one case at once, its metrics marking the group's size."""
    assert len({task.case for task in tasks}) == 1
    return [RunOutput({**toy_run(task).metrics, "group": len(tasks)}, toy_run(task).arrays) for task in tasks]


def failing_group(tasks: list[RunTask]):
    raise ValueError("the group failed")


@pytest.mark.parametrize("workers", [0, 2])
def test_runs_in_groups_give_the_runs_one_by_one_a_record_each(tmp_path, workers):
    grouped = toy(run_group=toy_group, group_size=3)
    one_by_one = run_campaign(TOY, settings(), tmp_path / "one", workers=0, progress=False)
    summary = run_campaign(grouped, settings(grouped), tmp_path / "grouped", workers=workers, progress=False)
    assert summary["filters"] == one_by_one["filters"]
    records = read_records(tmp_path / "grouped", settings(grouped))
    assert len(records) == RUNS * len(SPEEDS)
    # groups of up to 3 consecutive runs of one case: 3 + 1 runs in each case (a run alone by `run`, which marks no
    # group size)
    assert Counter(r.metrics.get("group") for r in records.values()) == {3: 9, None: 3}


def test_a_failed_group_runs_one_by_one(tmp_path):
    grouped = toy(run_group=failing_group, group_size=RUNS)
    summary = run_campaign(grouped, settings(grouped), tmp_path / "grouped", workers=0, progress=False)
    one_by_one = run_campaign(TOY, settings(), tmp_path / "one", workers=0, progress=False)
    assert summary["filters"] == one_by_one["filters"]
    assert summary["runs"]["done"] == RUNS * len(SPEEDS)


class _PoolDyingBetweenRuns:
    """An in-process pool (one worker) whose executor turns out broken at the submissions numbered in
    `broken_at` (from 1), when every run it held has already finished (a worker that dies after its last
    result came in); at the submissions numbered in `given`, the future given there stands for the run."""

    workers = 1

    def __init__(self, broken_at: set[int], given: dict[int, cf.Future] | None = None):
        self.executor = self
        self.submissions, self.broken_at, self.given, self.restarts = 0, broken_at, given or {}, 0

    def submit(self, fn, /, *args, **kwargs):
        self.submissions += 1
        if self.submissions in self.broken_at:
            raise BrokenProcessPool("a process in the pool was terminated abruptly")
        if self.submissions in self.given:
            return self.given[self.submissions]
        return executors._InlineExecutor().submit(fn, *args, **kwargs)

    def restart(self) -> None:
        self.restarts += 1


def test_a_pool_found_dead_at_a_submission_is_replaced_and_every_run_is_done_once():
    pool = _PoolDyingBetweenRuns(broken_at={3})  # the window is 2: the third submission follows two finished runs
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(RUNS)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append((task, outcome)))
    assert sorted((task for task, _ in kept), key=lambda task: task.index) == tasks  # each once
    assert [outcome.status for _, outcome in kept] == ["done"] * RUNS
    assert pool.restarts == 1


def test_pool_deaths_with_runs_finishing_between_them_never_stop_the_campaign():
    """More pool deaths than MAX_POOL_DEATHS, but runs finish between every two: each death is the first in a
    row, so the pool is replaced each time and every run is done."""
    deaths = campaign.MAX_POOL_DEATHS + 2
    # the window is 2: each round's first submission finds the pool dead, the next two run
    pool = _PoolDyingBetweenRuns(broken_at={1 + 3 * k for k in range(deaths)})
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(2 * deaths)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append((task, outcome)))
    assert sorted((task for task, _ in kept), key=lambda task: task.index) == tasks  # each once
    assert {outcome.status for _, outcome in kept} == {"done"} and pool.restarts == deaths


def broken_future() -> cf.Future:
    """The future of a run whose worker process died."""
    future = cf.Future()
    future.set_exception(BrokenProcessPool("a process in the pool was terminated abruptly"))
    return future


def test_a_pool_found_dead_at_a_submission_with_a_run_in_flight_is_replaced_once_for_both():
    """The first run's worker dies, and the pool is found dead at the second submission: the second run goes back
    to the queue and the pool is replaced once, when the first run's death comes in (it is blamed, alone in the
    pool); the second run is then done in the new pool."""
    pool = _PoolDyingBetweenRuns(broken_at={2}, given={1: broken_future()})
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(2)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks],
                    lambda task, outcome: kept.append((task.index, outcome.status, (outcome.error or {}).get("type"))))
    assert kept == [(0, "failed", "WorkerDied"), (1, "done", None)] and pool.restarts == 1


class _PoolDeadAtEverySubmission:
    """A pool found dead at every submission, however often it is replaced (something outside the runs is
    wrong); fails the test after 20 replacements rather than replacing it forever."""

    workers = 1

    def __init__(self):
        self.executor, self.restarts = self, 0

    def submit(self, fn, /, *args, **kwargs):
        raise BrokenProcessPool("a process in the pool was terminated abruptly")

    def restart(self) -> None:
        self.restarts += 1
        if self.restarts >= 20:
            pytest.fail("the pool was replaced 20 times with no run finishing and the campaign goes on")


def test_a_pool_that_keeps_dying_with_no_run_finishing_stops_the_campaign():
    """MAX_POOL_DEATHS deaths in a row with no run finishing are replaced; the next one stops the campaign
    with a RuntimeError naming the deaths."""
    pool = _PoolDeadAtEverySubmission()
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(3)]
    kept = []
    with pytest.raises(RuntimeError, match=f"died {campaign.MAX_POOL_DEATHS + 1} times in a row with no run"):
        campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append(task))
    assert pool.restarts == campaign.MAX_POOL_DEATHS and kept == []


def test_runs_that_finished_before_an_interrupt_are_kept():
    """Ctrl-C while the first of two finished runs is being kept: the second, finished as well, is still
    kept before the interrupt passes on (only unfinished runs are redone on resume); none is started after."""
    pool = _PoolDyingBetweenRuns(broken_at=set())  # the window is 2: two runs in flight, both finished
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(4)]
    interrupted, kept = [], []

    def keep(task, outcome):
        if not interrupted:
            interrupted.append(task)
            raise KeyboardInterrupt
        kept.append((task, outcome.status))

    with pytest.raises(KeyboardInterrupt):
        campaign._drive(pool, toy_run, [(task,) for task in tasks], keep)
    assert pool.submissions == 2 and len(interrupted) == 1
    assert kept == [(next(task for task in tasks[:2] if task not in interrupted), "done")]


class _FutureInFlight(cf.Future):
    """A run's future: asking one still in flight for its exception would wait for the run, so that fails the test
    instead."""

    def exception(self, timeout=None):
        if not self.done():
            pytest.fail("waited for the exception of a run still in flight")
        return super().exception(timeout)


@pytest.mark.parametrize("second", ["in-flight", "worker-died"])
def test_on_ctrl_c_runs_that_did_not_finish_are_dropped_and_those_in_flight_cancelled(second):
    """Ctrl-C while the first of two runs is kept: the second, still in flight or its worker dead, is not kept,
    raises nothing in place of the interrupt, and is cancelled (it is redone on resume)."""
    future = _FutureInFlight()
    if second == "worker-died":
        future.set_exception(BrokenProcessPool("a process in the pool was terminated abruptly"))
    pool = _PoolDyingBetweenRuns(broken_at=set(), given={2: future})
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(2)]
    kept = []

    def keep(task, outcome):
        kept.append(task)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        campaign._drive(pool, toy_run, [(task,) for task in tasks], keep)
    assert kept == tasks[:1] and pool.submissions == 2
    assert future.cancelled() == (second == "in-flight") and future.done()


class _PoolOfDyingRuns:
    """An in-process pool (two workers) whose every run in `dying` takes the pool down with the runs
    submitted to it after that run; notes the runs each pool (between restarts) was given."""

    workers = 2

    def __init__(self, dying: set[int]):
        self.executor = self
        self.dying, self.pools, self.broken = dying, [[]], False

    def submit(self, fn, run, run_group, group):
        self.pools[-1] += [task.index for task in group]
        self.broken = self.broken or any(task.index in self.dying for task in group)
        if not self.broken:
            return executors._InlineExecutor().submit(fn, run, run_group, group)
        future = cf.Future()
        future.set_exception(BrokenProcessPool("a process in the pool was terminated abruptly"))
        return future

    def restart(self) -> None:
        self.pools.append([])
        self.broken = False


def test_runs_that_took_a_pool_down_run_alone_each_and_one_that_dies_alone_is_blamed():
    pool = _PoolOfDyingRuns(dying=set(range(8)))  # more deaths in a row than MAX_POOL_DEATHS
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(8)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append((task, outcome)))
    assert pool.pools == [[0, 1, 2, 3], [0], [1], [2], [3], [4, 5, 6, 7], [4], [5], [6], [7], []]
    assert [(task.index, outcome.error["type"]) for task, outcome in kept] == [(i, "WorkerDied") for i in range(8)]
    # Run 0 finished before the pool died; suspect 2 finishes, and the last suspect, 3, still runs alone.
    pool = _PoolOfDyingRuns(dying={1, 3})
    kept.clear()
    campaign._drive(pool, toy_run, [(task,) for task in tasks[:6]], lambda task, outcome: kept.append((task, outcome)))
    assert pool.pools == [[0, 1, 2, 3], [1], [2, 3], [4, 5]]
    assert sorted((task.index, outcome.status) for task, outcome in kept) == [
        (0, "done"), (1, "failed"), (2, "done"), (3, "failed"), (4, "done"), (5, "done")]


def test_runs_blamed_alone_are_progress_between_deaths_of_a_full_pool():
    """Every run takes its pool down: each full pool (the window, 4 runs) dies, then each of its runs dies alone
    and is blamed. A blamed run is progress, so the MAX_POOL_DEATHS + 1 deaths of full pools are each the first in
    a row and never stop the campaign: every run is kept as failed, after a replacement per death."""
    deaths = campaign.MAX_POOL_DEATHS + 1
    window = 2 * _PoolOfDyingRuns.workers
    pool = _PoolOfDyingRuns(dying=set(range(window * deaths)))
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(window * deaths)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append((task, outcome)))
    assert [(task.index, outcome.error["type"]) for task, outcome in kept] == [
        (i, "WorkerDied") for i in range(len(tasks))]
    assert len(pool.pools) - 1 == deaths + len(tasks)  # a replacement per full pool and per run alone


def test_the_window_opens_again_once_every_suspect_has_run_alone(monkeypatch):
    """Run 1 takes the pool of runs 0-3 down: 1, 2 and 3 then run alone one after the other (1 is blamed), and once
    3 has finished, runs 4 and 5 are in flight together again."""
    in_flight = []
    wait = cf.wait
    monkeypatch.setattr(campaign.cf, "wait", lambda fs, **kwargs: in_flight.append(len(fs)) or wait(fs, **kwargs))
    pool = _PoolOfDyingRuns(dying={1})
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(6)]
    kept = []
    campaign._drive(pool, toy_run, [(task,) for task in tasks], lambda task, outcome: kept.append(task.index))
    assert in_flight == [4, 1, 1, 1, 2] and sorted(kept) == list(range(6))


def test_the_groups_a_dead_pool_held_run_again_a_run_each():
    """Run 1 takes down the pool holding the groups (0, 1) and (2, 3): each of the four runs then runs alone (by
    `run`), so that run 1 alone is blamed and 0, 2 and 3 are done."""
    pool = _PoolOfDyingRuns(dying={1})
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(4)]
    kept = []
    campaign._drive(pool, toy_run, [tuple(tasks[:2]), tuple(tasks[2:])],
                    lambda task, outcome: kept.append((task.index, outcome.status, outcome.metrics.get("group"))),
                    run_group=toy_group)
    assert sorted(kept) == [(0, "done", None), (1, "failed", None), (2, "done", None), (3, "done", None)]


class KilledWorker(Exception):
    """Stands for Dask's verdict on a task whose workers kept dying."""


class _PoolKillingEveryTask:
    """An in-process pool whose every task comes back failed with the executor's own verdict (KilledWorker)."""

    workers = 1

    def __init__(self):
        self.executor = self

    def submit(self, fn, /, *args, **kwargs):
        future = cf.Future()
        future.set_exception(KilledWorker("attempted to run the task 3 times and all failed"))
        return future

    def restart(self) -> None:
        pass


def test_an_executors_verdict_on_a_group_fails_each_of_its_runs():
    tasks = [RunTask("toy", "3", i, run_seed(0, "3", i)) for i in range(4)]
    kept = []
    campaign._drive(_PoolKillingEveryTask(), toy_run, [tuple(tasks[:2]), tuple(tasks[2:])],
                    lambda task, outcome: kept.append((task, outcome)), run_group=toy_group)
    assert sorted((task for task, _ in kept), key=lambda task: task.index) == tasks  # each once
    assert {(outcome.status, outcome.error["type"]) for _, outcome in kept} == {("failed", "KilledWorker")}


# ---- records ------------------------------------------------------------------------------------

def test_a_record_of_another_seed_or_unfinished_is_redone_on_resume(tmp_path):
    """A run's record that holds another seed than the campaign's for it, or a status other than done or
    failed, is not the campaign's, and one that is no JSON (cut short: "{") cannot be read: read_records leaves
    each out and a resumed campaign runs it again."""
    s = settings(cases=["3"], runs=4)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    for index, change in ((1, {"seed": run_seed(0, "3", 1) + 1}), (2, {"status": "running"})):
        path = tmp_path / "runs" / "3" / f"{index:05d}.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), **change}))
    (tmp_path / "runs" / "3" / "00003.json").write_text("{")
    assert sorted(read_records(tmp_path, s)) == [("3", 0)]
    summary = run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    assert summary["runs"]["computed_now"] == 3 and summary["runs"]["done"] == 4
    records = read_records(tmp_path, s)
    assert [records[("3", i)].seed for i in range(4)] == [run_seed(0, "3", i) for i in range(4)]


def test_a_record_that_is_no_object_of_a_run_is_redone_on_resume(tmp_path):
    """A record that is a JSON object without a run's fields ("{}") or no object ("[]") cannot be read: read_records
    leaves it out, and a resumed campaign runs it again."""
    s = settings(cases=["3"], runs=3)
    run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    (tmp_path / "runs" / "3" / "00001.json").write_text("{}")
    (tmp_path / "runs" / "3" / "00002.json").write_text("[]")
    assert sorted(read_records(tmp_path, s)) == [("3", 0)]
    summary = run_campaign(TOY, s, tmp_path, workers=0, progress=False)
    assert summary["runs"]["computed_now"] == 2 and summary["runs"]["done"] == 3


@pytest.mark.parametrize("error, reason", [
    (None, None),
    ({"type": "WorkerDied", "message": "the worker died", "traceback": None}, "WorkerDied: the worker died"),
])
def test_a_records_reason_is_its_errors_type_and_message(error, reason):
    record = RunRecord(case="3", index=0, seed=0, status="done" if error is None else "failed", metrics={},
                       error=error, wall_time_s=0.0, path=Path("00000.json"), has_arrays=False)
    assert record.reason == reason


def test_a_run_returning_a_dict_has_no_arrays(tmp_path):
    run_campaign(toy(run=nan_run), settings(cases=["3"], runs=2), tmp_path, workers=0, progress=False)
    for record in read_records(tmp_path, settings(cases=["3"], runs=2)).values():
        assert not record.has_arrays and record.arrays() == {}
    assert not list(tmp_path.rglob("*.npz"))


def test_a_run_whose_metrics_json_cannot_hold_is_recorded_failed_and_the_campaign_goes_on(tmp_path):
    s = settings(cases=["3"], runs=3)
    summary = run_campaign(toy(run=unkeepable_run), s, tmp_path, workers=0, progress=False)
    assert summary["runs"]["done"] == 2 and summary["runs"]["failed"] == 1
    record = read_records(tmp_path, s)[("3", 1)]
    assert record.status == "failed" and record.error["type"] == "TypeError" and record.metrics == {}


def test_a_groups_time_is_shared_by_its_runs(monkeypatch):
    """A group of 3 runs taking 3 s (a clock that moves only while the group runs): 1 s for each run."""
    from diagrams.montecarlo import records

    class Clock:
        now = 100.0

        @staticmethod
        def perf_counter():
            return Clock.now

    def group(tasks):
        Clock.now += 3.0
        return [{"index": task.index} for task in tasks]

    monkeypatch.setattr(records, "time", Clock)
    outcomes = records._execute_group(toy_run, group, tuple(settings(cases=["3"], runs=3).tasks()))
    assert [o.status for o in outcomes] == ["done"] * 3
    assert [o.wall_time_s for o in outcomes] == [1.0, 1.0, 1.0]
