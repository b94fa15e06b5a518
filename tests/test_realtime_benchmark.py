"""benchmarks/realtime.py on a short run (slow: it renders): the JSON it writes is the printout's figures,
consistent with each other. No assertion on how long anything takes."""

import json

import pytest

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
