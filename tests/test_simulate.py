"""diagrams/simulate.py: what ends a run. Only Drake's integrator failing is a diverged flight; any other
error (a wiring mistake, a system's own exception) passes on, for the CLI to report as an internal error
and a campaign to record as a failed run."""

import contextlib
import io

import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder, EventStatus, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource, Integrator

import diagrams.simulate
from diagrams.cli import main
from diagrams.perception_sources import SOURCES, PerceptionSource, add_estimate_to_seam
from diagrams.simulate import COMPLETED, integrator_failed, simulate
from systems.estimators.estimate import PoseEstimate


class Blowup(LeafSystem):
    """x' = x^2 from x(0) = 1: x = 1 / (1 - t), infinite at t = 1 s."""

    def __init__(self):
        super().__init__()
        self.DeclareContinuousState(1)

    def DoCalcTimeDerivatives(self, context, derivatives):
        x = context.get_continuous_state_vector().GetAtIndex(0)
        derivatives.get_mutable_vector().SetAtIndex(0, x * x)


class Reader(LeafSystem):
    """Reads its required input `u` every 0.1 s; raises `broken` (an exception) from t = 0.3 s when given."""

    def __init__(self, broken: BaseException | None = None):
        super().__init__()
        self._u = self.DeclareVectorInputPort("u", 1)
        self._broken = broken
        self.DeclarePeriodicPublishEvent(0.1, 0.0, self._read)

    def _read(self, context):
        if self._broken is not None and context.get_time() > 0.25:
            raise self._broken
        self._u.Eval(context)


class FakeVideo:
    def __init__(self):
        self.ended = None

    def discard(self):
        self.ended = "discarded"

    def finish(self):
        self.ended = "finished"


class FakeVisualizer:
    """The MeshcatVisualizer calls simulate makes, in order."""

    def __init__(self):
        self.calls = []

    def StartRecording(self):
        self.calls.append("start")

    def StopRecording(self):
        self.calls.append("stop")

    def PublishRecording(self):
        self.calls.append("publish")


def _diagram(system):
    builder = DiagramBuilder()
    builder.AddSystem(system)
    return builder.Build()


def _read_one(broken: BaseException | None = None):
    """A Reader of a constant 1, raising `broken` from t = 0.3 s when given."""
    builder = DiagramBuilder()
    source, reader = builder.AddSystem(ConstantVectorSource([1.0])), builder.AddSystem(Reader(broken))
    builder.Connect(source.get_output_port(), reader.get_input_port())
    return builder.Build()


def test_the_integrator_failing_is_a_diverged_run():
    diagram = _diagram(Blowup())
    video = FakeVideo()
    run = simulate(diagram, 2.0, initialize=lambda context: context.SetContinuousState([1.0]),
                   simulator_config=SimulatorConfig(integration_scheme="runge_kutta3", use_error_control=True,
                                                    accuracy=1e-6, max_step_size=0.01), video=video)
    assert run.status.startswith("diverged: the integrator failed at t = 1.00 s (Error control wants")
    assert run.sim_time_s == pytest.approx(1.0, abs=1e-3) and video.ended == "finished"


def test_both_of_drakes_integrator_failure_messages_are_a_diverged_run():
    """Both of the messages Drake's integrator fails with (libdrake's text: the error-control floor and the
    near-zero step) count as the integrator failing; another RuntimeError, or another exception type with
    such a message, does not."""
    drake_messages = ("Error control wants to select step smaller than minimum allowed (1e-14). This is typically "
                      "an indication that some part of your system *with continuous state* is going unstable",
                      "Integrator has been directed to a near zero-length step in order to obtain convergence.")
    for message in drake_messages:
        assert integrator_failed(RuntimeError(message))
        assert not integrator_failed(ValueError(message))
    assert not integrator_failed(RuntimeError("broken"))


class Lander(LeafSystem):
    """Ends the run from t = 0.3 s, as the landing monitor does on touchdown (its event every 0.02 s)."""

    def __init__(self):
        super().__init__()
        self.DeclarePeriodicPublishEvent(0.02, 0.0, self._check)

    def _check(self, context):
        if context.get_time() >= 0.3 - 1e-9:
            return EventStatus.ReachedTermination(self, "landed: touchdown")
        return EventStatus.Succeeded()


def test_a_termination_event_stops_the_run_with_its_message():
    """A system's ReachedTermination ends the run there, well inside the 2 s asked for, with its message
    as the status (not run on to the duration)."""
    run = simulate(_diagram(Lander()), 2.0)
    assert run.status == "landed: touchdown"
    assert run.sim_time_s == pytest.approx(0.3, abs=1e-9)


def test_a_run_shorter_than_a_progress_chunk_stops_at_its_duration():
    """A 0.3 s run (less than one 0.5 s progress chunk) stops at 0.3 s: the integral of a constant 1 is
    then 0.3, not the 0.5 of a whole chunk."""
    builder = DiagramBuilder()
    source, integrator = builder.AddSystem(ConstantVectorSource([1.0])), builder.AddSystem(Integrator(1))
    builder.Connect(source.get_output_port(), integrator.get_input_port())
    diagram = builder.Build()
    run = simulate(diagram, 0.3)
    assert run.status == COMPLETED and run.sim_time_s == pytest.approx(0.3, abs=1e-12)
    state = diagram.GetSubsystemContext(integrator, run.context).get_continuous_state_vector().CopyToVector()
    assert state[0] == pytest.approx(0.3, abs=1e-9)


def test_an_unconnected_input_raises_not_diverges():
    video = FakeVideo()
    with pytest.raises(RuntimeError, match="is not connected"):
        simulate(_diagram(Reader()), 1.0, video=video)
    assert video.ended == "discarded"


def test_a_systems_own_runtime_error_raises_not_diverges():
    with pytest.raises(RuntimeError, match="broken"):
        simulate(_read_one(RuntimeError("broken")), 1.0)
    assert simulate(_diagram(Blowup()), 0.5, initialize=lambda c: c.SetContinuousState([1.0])).status == COMPLETED


def test_ctrl_c_discards_the_video_and_passes_on():
    """KeyboardInterrupt is no Exception: the video is discarded all the same, and the interrupt reaches the
    caller (the CLI exits 130)."""
    video = FakeVideo()
    with pytest.raises(KeyboardInterrupt):
        simulate(_read_one(KeyboardInterrupt()), 1.0, video=video)
    assert video.ended == "discarded"


@pytest.mark.parametrize("record, broken, calls", [
    (False, None, []),
    (True, None, ["start", "stop", "publish"]),
    (True, RuntimeError("broken"), ["start", "stop"]),
    (True, KeyboardInterrupt(), ["start", "stop"]),
], ids=["not-recording", "recorded", "error", "ctrl-c"])
def test_meshcat_records_only_when_asked_and_stops_unpublished_on_an_error(record, broken, calls):
    """The visualizer records the run only with `record`, and publishes it at the end; a run that raises stops its
    recording unpublished (a caller that goes on, in a notebook, keeps no recorder running)."""
    visualizer = FakeVisualizer()
    with pytest.raises(type(broken)) if broken is not None else contextlib.nullcontext():
        simulate(_read_one(broken), 0.5, visualizer=visualizer, record=record)
    assert visualizer.calls == calls


@pytest.mark.parametrize("realtime, rate", [(True, 1.0), (False, 0.0)], ids=["realtime", "as-fast-as-it-can"])
def test_realtime_paces_the_simulator_at_1_and_otherwise_not_at_all(monkeypatch, realtime, rate):
    """`realtime` (--meshcat) sets the Simulator's target real-time rate to 1; without it the rate stays Drake's
    default 0, no pacing (read back from the Simulator simulate made, not timed)."""
    made = []

    class KeptSimulator(Simulator):
        def __init__(self, diagram):
            super().__init__(diagram)
            made.append(self)

    monkeypatch.setattr(diagrams.simulate, "Simulator", KeptSimulator)
    run = simulate(_read_one(), 0.05, realtime=realtime)
    assert run.status == COMPLETED
    (simulator,) = made
    assert simulator.get_target_realtime_rate() == rate


class Unwired(LeafSystem):
    """A pad estimator whose X_WB input its source forgets to connect."""

    def __init__(self):
        super().__init__()
        self._X_WB = self.DeclareVectorInputPort("X_WB", 1)
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()), self._calc)

    def _calc(self, context, output):
        self._X_WB.Eval(context)  # raises: not connected


def _add_unwired(builder, inputs):
    estimator = builder.AddNamedSystem("unwired", Unwired())
    return add_estimate_to_seam(builder, inputs, estimator.GetOutputPort("X_WP_estimate"))


def test_a_wiring_bug_in_a_users_source_is_an_internal_error_with_nothing_written(monkeypatch, tmp_path):
    monkeypatch.setitem(SOURCES, "unwired", PerceptionSource(_add_unwired))
    out = tmp_path / "run"
    stderr = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(stderr):
        code = main(["run", "marker-landing", "--duration", "0.2", "--quiet", "--out", str(out),
                     "--set", "perception.source=unwired", "--set", "estimation.source=synthetic"])
    assert code == 1 and "internal error: RuntimeError" in stderr.getvalue() and "not connected" in stderr.getvalue()
    assert not (out / "metrics.json").exists()
