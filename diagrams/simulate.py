"""One way to simulate any scenario's diagram: progress bar, real-time pacing, Meshcat recording,
the camera video, and what ends a run early.

    run = simulate(diagram, duration_s, initialize=handles.initialize, realtime=options.meshcat)
    run.status   # "completed", a termination event's message ("landed: ..."), or "diverged: ..."

A system's event that returns EventStatus.ReachedTermination ends the run with its message; Drake's
integrator failing (INTEGRATOR_FAILURES: error control below the minimum step, or no convergence at
a near-zero step) ends it as "diverged". Any other exception (a wiring error, a system's own error)
or Ctrl-C discards the partial video and passes on (the CLI reports an internal error; a campaign
records a failed run). The garbage collector's view of the objects from imports and the build is
frozen for the run (gc.freeze): its passes would otherwise walk them all, a large share of a Python-heavy run.
"""

import gc
import time
from collections.abc import Callable
from dataclasses import dataclass

from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig, SimulatorStatus
from tqdm import tqdm

COMPLETED = "completed"
CHUNK_S = 0.5  # simulated time between progress-bar updates (and Ctrl-C checks)
# How Drake's messages begin when its integrator fails (systems/analysis/integrator_base.{h,cc}).
INTEGRATOR_FAILURES = ("Error control wants to select step smaller than minimum allowed",
                       "Integrator has been directed to a near zero-length step")


@dataclass
class Simulation:
    """What `simulate` returns: why it stopped, the simulated and wall times [s], the final context, and
    the calling thread's CPU time over the same span as the wall time [s] (time.thread_time)."""

    status: str
    sim_time_s: float
    wall_time_s: float
    context: object
    thread_cpu_time_s: float

    @property
    def realtime_factor(self) -> float | None:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else None


def integrator_failed(error: BaseException) -> bool:
    """Whether `error` is Drake's integrator failing (the dynamics going unstable), not a bug."""
    return isinstance(error, RuntimeError) and str(error).startswith(INTEGRATOR_FAILURES)


def simulate(diagram, duration_s: float, *, initialize: Callable | None = None,
             simulator_config: SimulatorConfig | None = None, realtime: bool = False, progress: bool = False,
             visualizer=None, record: bool = False, video=None) -> Simulation:
    """Simulates `diagram` for `duration_s` [s] or until a termination event. `initialize(context)`
    sets the initial conditions; `visualizer` (a MeshcatVisualizer) records when `record` (published at the end,
    stopped unpublished on an error); `video` (a VideoRecorder in the diagram) is finished on success and discarded
    otherwise."""
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    if initialize is not None:
        initialize(context)
    if simulator_config is not None:
        ApplySimulatorConfig(simulator_config, simulator)
    if realtime:
        simulator.set_target_realtime_rate(1.0)
    recording = visualizer is not None and record
    if recording:
        visualizer.StartRecording()
    status = COMPLETED
    gc.freeze()
    start, cpu_start = time.perf_counter(), time.thread_time()
    try:
        simulator.Initialize()
        with tqdm(total=duration_s, unit="sim s", disable=not progress, leave=False,
                  bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim s [{elapsed}<{remaining}]") as bar:
            while context.get_time() < duration_s - 1e-9:
                result = simulator.AdvanceTo(min(duration_s, context.get_time() + CHUNK_S))
                bar.update(context.get_time() - bar.n)
                if result.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                    status = result.message()
                    break
    except BaseException as e:
        if not integrator_failed(e):
            if recording:
                visualizer.StopRecording()  # a caller that goes on (Ctrl-C in a notebook) keeps no recorder running
            if video is not None:
                video.discard()
            raise
        status = f"diverged: the integrator failed at t = {context.get_time():.2f} s ({str(e).splitlines()[0]})"
    finally:
        wall, cpu = time.perf_counter() - start, time.thread_time() - cpu_start
        gc.unfreeze()
    if recording:
        visualizer.StopRecording()
        visualizer.PublishRecording()
    if video is not None:
        video.finish()
    return Simulation(status, context.get_time(), wall, context, cpu)
