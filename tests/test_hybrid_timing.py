"""benchmarks/hybrid_timing.py's main on two rendered frames, one hovering at IH and one from 3 m (slow: it renders):
its table printed and its --json figures strict, every module of the table with a positive time and the whole
pipeline the sum; and its summary's per-flight medians on synthetic times. No assertion on how long anything takes."""

import json
from types import SimpleNamespace

import pytest

from benchmarks.hybrid_timing import PAPER_TABLE7, RECORDED, Frame, Recording, main, summarise

MODULES = ("fisheye_correction", "fisheye_composition", "stereo", "detection_learned", "detection_classical",
           "tracking_learned", "tracking_classical", "motion_compensation", "hybrid_estimate", "stereo_pad_fix",
           "velocity_observer", "estimate", "pid", "supervisor", "control")


@pytest.mark.slow
def test_two_frames_give_every_module(tmp_path, capsys):
    out = tmp_path / "figures.json"
    # One of the frames from 3 m: the stereo pad fix runs below 3 m.
    assert main(["--frames", "2", "--low-frames", "1", "--repeats", "1", "--json", str(out)]) is None
    assert capsys.readouterr().out.startswith("2 frames, 1 repeats each")
    result = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert result["frames"] == 2 and result["flights"] == {"7.5 m": 1, "3 m": 1}
    modules = result["modules"]
    for name in MODULES:
        assert modules[name]["median_ms"] > 0, name
    for name in ("fisheye_correction", "stereo", "detection_learned", "tracking_learned", "motion_compensation"):
        assert modules[name]["n"] == 2, name
    for detector in ("learned", "classical"):
        total = result["whole_pipeline"][detector]
        assert total["median_ms"] > modules[f"detection_{detector}"]["median_ms"] + modules["stereo"]["median_ms"]
        assert total["with_composition_median_ms"] > total["median_ms"] > total["without_motion_compensation_median_ms"]
    assert set(result["renders_simulator"]) == {"fisheye_faces", "stereo_eye_render", "stereo_eye_noise"}
    assert set(PAPER_TABLE7) <= {*modules, "detection", "tracking", "total"}


def test_a_recorded_step_is_told_by_its_calls_flight_not_the_frames_order():
    """30 frames hovering at IH and 10 from 3 m; the stereo pad fix called 40 times, all in the 3 m flight:
    as many calls as frames, and still all of them the 3 m flight's. The per-frame modules go by their frame."""
    record = Recording()
    record.config = SimpleNamespace(pid=SimpleNamespace(rate_hz=4.0), landing=SimpleNamespace(rate_hz=50.0))
    record.frames = ([Frame("7.5 m", 0.1 * k, None, None, [], None, None) for k in range(30)]
                     + [Frame("3 m", 0.1 * k, None, None, [], None, None) for k in range(10)])
    times = {name: [1.0] * 30 + [3.0] * 10 for name in (
        "fisheye_rectify", "fisheye_compose", "stereo_match", "detection_learned", "detection_classical",
        "tracking_learned", "tracking_classical", "motion_compensation")}
    for name in RECORDED:
        times[name] = [0.01]
        record.calls[name] = [(None, (), {}, "7.5 m")]
    times["stereo_pad_fix"] = [2.5] * 40
    record.calls["stereo_pad_fix"] = [(None, (), {}, "3 m")] * 40
    by_flight = summarise(times, record)["median_ms_by_flight"]
    assert by_flight["stereo_pad_fix"] == {"3 m": 2.5}
    assert by_flight["hybrid_estimate"] == {"7.5 m": 0.01}
    assert by_flight["fisheye_rectify"] == {"7.5 m": 1.0, "3 m": 3.0}
