"""benchmarks/hybrid_timing.py on two rendered frames, one hovering at IH and one from 3 m (slow: it renders):
every module of the table has a positive time and the whole pipeline is the sum. No assertion on how long
anything takes."""

import json

import pytest

from benchmarks.hybrid_timing import PAPER_TABLE7, run

MODULES = ("fisheye_correction", "fisheye_composition", "stereo", "detection_learned", "detection_classical",
           "tracking_learned", "tracking_classical", "motion_compensation", "hybrid_estimate", "stereo_pad_fix",
           "velocity_observer", "estimate", "pid", "supervisor", "control")


@pytest.mark.slow
def test_two_frames_give_every_module():
    result = run(frames=2, low_frames=1, repeats=1)  # one frame from 3 m: the stereo pad fix runs below 3 m
    json.dumps(result)  # --json writes it
    assert result["frames"] == 2
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
