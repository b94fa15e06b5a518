"""benchmarks/realtime.py on a short run (slow: it renders): the JSON it writes is the printout's figures,
consistent with each other; and on a fake scene and clock, what each figure is made of. No assertion on how long
anything takes."""

import json
from types import SimpleNamespace

import pytest

import benchmarks.realtime as realtime
from benchmarks.realtime import main


@pytest.mark.slow
def test_a_short_run_writes_consistent_figures(tmp_path, capsys):
    out = tmp_path / "realtime.json"
    assert main(["--duration", "2.05", "--out", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["frames"] == 40 and figures["simulated_s"] == pytest.approx(2.0)
    stages = figures["stages_ms"]
    assert all(stages[name] > 0 for name in ("render", "noise", "tof", "detection"))
    assert figures["render_ms"] == stages["render"]
    assert figures["per_frame_ms"] == pytest.approx(1e3 * figures["wall_s"] / figures["frames"])
    assert figures["per_frame_over_render"] == pytest.approx(figures["per_frame_ms"] / figures["render_ms"])
    assert figures["realtime_factor"] == pytest.approx(figures["simulated_s"] / figures["wall_s"])
    # "rest" is per_frame_ms less the others by construction: only its presence says anything.
    assert set(stages) == {"render", "noise", "tof", "detection", "rest"}
    # The stages timed on 4 frames after each simulated second: after 0.05-1.05 s and 1.05-2.05 s.
    assert figures["stage_frames"] == 8
    assert f"{figures['per_frame_over_render']:.2f}x the render" in capsys.readouterr().out


def test_a_mistyped_setting_is_one_line_and_exit_2(tmp_path, capsys):
    out = tmp_path / "realtime.json"
    assert main(["--set", "imu.rate_hzz=20.0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "imu.rate_hzz" in err and "imu.rate_hz" in err
    assert not out.exists()


class _Clock:
    """time.perf_counter's stand-in: it moves only when a fake stage or the fake simulator says so."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now


class _Part:
    """A fake system, port or context: `calls` names its methods; each call moves the clock by the method's
    seconds (the stage's cost) and returns the part itself."""

    def __init__(self, clock: _Clock, **calls):
        self._clock, self._calls, self.times = clock, calls, []

    def __getattr__(self, name):
        seconds = self._calls[name]

        def call(*args):
            self._clock.now += seconds
            return self
        return call

    def SetTime(self, t):  # noqa: N802 (Drake's name)
        self.times.append(t)


def _fake_scene(clock: _Clock):
    """build_stewart_scene's (diagram, handles) and a Simulator: render 1 ms, the camera's processing 2 ms, one
    ToF reading 3 ms, detection 4 ms; the simulation runs at twice real time."""
    context, render = _Part(clock), _Part(clock, Eval=1e-3)
    diagram = SimpleNamespace(CreateDefaultContext=lambda: context)
    handles = SimpleNamespace(camera=_Part(clock, GetMyContextFromRoot=0.0),
                              noisy_camera=_Part(clock, GetMyContextFromRoot=0.0), color_image=_Part(clock, Eval=2e-3),
                              tof=_Part(clock, GetMyContextFromRoot=0.0, readings=3e-3),
                              detector=SimpleNamespace(_detector=_Part(clock, detect=4e-3)))
    handles.camera.color_image_output_port = lambda: render

    class Simulator:
        advances = []

        def __init__(self, diagram):
            self.t = 0.0

        def Initialize(self):  # noqa: N802
            pass

        def AdvanceTo(self, t):  # noqa: N802
            Simulator.advances.append(t)
            clock.now += 0.5 * (t - self.t)
            self.t = t

    return diagram, handles, context, Simulator


@pytest.mark.parametrize("settings, tof_readings", [([], 1.0), (["tof.trigger=own_clock", "tof.rate_hz=30.0"], 1.5)],
                         ids=["tof-on-the-camera", "tof-own-clock-30hz"])
def test_the_figures_of_stages_timed_on_a_fake_clock(monkeypatch, tmp_path, capsys, settings, tof_readings):
    """Each stage's median is its own span (render, camera processing, ToF, detection in that order) at frame times
    rising one camera period a frame; the simulation runs to --duration 1.55 (1.5 s after the first frame: 30
    frames at 20 Hz) in 1 s steps, the last cut short; the ToF stage counts its readings per frame (30 Hz on their
    own clock: 1.5) and "rest" is the frame's wall time less every stage. A fake clock, no render."""
    clock = _Clock()
    diagram, handles, context, simulator = _fake_scene(clock)
    monkeypatch.setattr(realtime, "build_stewart_scene", lambda scenario: (diagram, handles))
    monkeypatch.setattr(realtime, "Simulator", simulator)
    monkeypatch.setattr(realtime, "image_to_numpy", lambda image: image)
    monkeypatch.setattr(realtime, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    out = tmp_path / "realtime.json"
    argv = ["--duration", "1.55", "--out", str(out)] + [a for s in settings for a in ("--set", s)]
    assert realtime.main(argv) == 0
    figures = json.loads(out.read_text())
    assert simulator.advances == pytest.approx([0.05, 1.05, 1.55])
    assert context.times == pytest.approx([0.05 * k for k in range(1, 9)])
    assert figures["simulated_s"] == pytest.approx(1.5) and figures["frames"] == 30 and figures["stage_frames"] == 8
    assert figures["wall_s"] == pytest.approx(0.75) and figures["realtime_factor"] == pytest.approx(2.0)
    assert figures["per_frame_ms"] == pytest.approx(25.0)  # 0.75 s over 30 frames
    stages = {"render": 1.0, "noise": 2.0, "tof": 3.0 * tof_readings, "detection": 4.0}
    assert figures["stages_ms"] == pytest.approx({**stages, "rest": 25.0 - sum(stages.values())})
