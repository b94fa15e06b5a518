"""Where a campaign's runs are computed. Each executor gives a concurrent.futures executor, a
worker count (which sizes the window of runs in flight) and `restart`/`close`:
- `_ProcessPool`: local worker processes, started with `spawn` (forking a process that has threads,
  as pydrake's, a Dask client's or tqdm's, can deadlock the child, and a fresh interpreter per
  worker keeps runs independent; about 0.5 s per worker once per campaign); replaced when a worker dies.
- `_DaskCluster`: an existing Dask distributed cluster, through `Client(address).get_executor()`;
  its scheduler retries the runs of a worker that died, and fails one (KilledWorker) after its
  allowed failures.
- `_Inline`: every run in this process, one after the other (workers=0: for a debugger; no isolation).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
from concurrent.futures.process import BrokenProcessPool

from systems.config import ConfigError

DEFAULT_CONNECT_TIMEOUT_S = 10.0  # to reach a Dask scheduler
PING_TIMEOUT_S = 120.0  # for a first worker to take a task


class _InlineExecutor(cf.Executor):
    """Runs each task at submission, in this process (workers=0)."""

    def submit(self, fn, /, *args, **kwargs):
        future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as e:  # a KeyboardInterrupt stops the campaign here, before the next run
            future.set_exception(e)
        return future


class _Inline:
    def __init__(self):
        self.executor = _InlineExecutor()
        self.workers = 1

    def restart(self) -> None:
        pass

    def close(self, abort: bool = False) -> None:
        pass


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
        from distributed.comm.addressing import parse_host_port
        from distributed.comm.registry import get_backend

        try:  # a bad scheme or port is caught here: a Client built on one cannot even close cleanly
            scheme, location = parse_address(address)
            get_backend(scheme)
            if not location:
                raise ValueError("no host given")
            if scheme != "inproc":  # in this process (a LocalCluster without processes): no port
                _, port = parse_host_port(location)
                if not 1 <= port <= 65535:
                    raise ValueError(f"port {port} is not 1 to 65535")
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


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _check_executor(workers: int | None, scheduler: str | None) -> None:
    if scheduler is not None and workers is not None:
        raise ConfigError("give --workers or --scheduler, not both (a Dask cluster has its own workers)")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise ConfigError(f"--workers must be a whole number of at least 1 (0: in this process), got {workers}")


def _open_executor(workers: int | None, scheduler: str | None, connect_timeout_s: float | None):
    """The executor for settings `_check_executor` passed (None: the defaults)."""
    if scheduler is not None:
        return _DaskCluster(scheduler, DEFAULT_CONNECT_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s)
    workers = default_workers() if workers is None else workers
    return _Inline() if workers == 0 else _ProcessPool(workers)


def _ping(run) -> int:
    """Runs in a worker: unpickling `run` on the way checks that the worker can import it."""
    return os.getpid()


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
