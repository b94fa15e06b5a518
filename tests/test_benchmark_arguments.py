"""The benchmarks' bad arguments: exit 2 with one line naming the argument, before any work (nothing
on stdout). A count below 1 or a negative noise is argparse's error (its usage, then the line); a scenario
or camera the project's checks refuse is that check's line alone."""

import pytest

import benchmarks.crhf_table5 as crhf_table5
import benchmarks.fisheye as fisheye
import benchmarks.hybrid as hybrid
import benchmarks.hybrid_timing as hybrid_timing
import benchmarks.landing_campaign as landing_campaign
import benchmarks.landing_sweep as landing_sweep
import benchmarks.marker_ekf_mc as marker_ekf_mc
import benchmarks.marker_visibility as marker_visibility
import benchmarks.motion_blur as motion_blur
import benchmarks.motion_compensation as motion_compensation
import benchmarks.realtime as realtime
import benchmarks.stereo as stereo
import benchmarks.ugv_detection as ugv_detection
import benchmarks.vision_landing as vision_landing


@pytest.mark.parametrize("main, argv, line", [
    (motion_compensation.main, ["--pairs", "0"], "error: --pairs must be at least 1, got 0"),
    (motion_compensation.main, ["--pairs", "1", "--repeats", "0"], "error: --repeats must be at least 1, got 0"),
    (stereo.main, ["--frames", "0", "--step", "0"], "error: --frames must be at least 1, got 0"),
    (stereo.main, ["--noise", "-1", "--step", "0", "--frames", "1"],
     "error: --noise must be a finite number, not negative, got -1"),
    (stereo.main, ["--noise", "nan", "--step", "0", "--frames", "1"],
     "error: --noise must be a finite number, not negative, got nan"),
    (stereo.main, ["--noise", "inf", "--step", "0", "--frames", "1"],
     "error: --noise must be a finite number, not negative, got inf"),
    (stereo.main, ["--step", "-0.1", "--frames", "1"],
     "error: --step must be a finite number, positive or 0 (no sweep), got -0.1"),
    (stereo.main, ["--step", "nan", "--frames", "1"],
     "error: --step must be a finite number, positive or 0 (no sweep), got nan"),
    (fisheye.main, ["--frames", "0"], "error: --frames must be at least 1, got 0"),
    (motion_compensation.main, ["--max-yaw-deg", "nan"], "error: --max-yaw-deg must lie in [0, 180], got nan"),
    (motion_compensation.main, ["--max-yaw-deg", "-400"], "error: --max-yaw-deg must lie in [0, 180], got -400"),
    (ugv_detection.main, ["--frames", "-5"],
     "error: --frames must lie in 1..100000 (the held-out seeds from --first 0), got -5"),
    (ugv_detection.main, ["--frames", "0"],
     "error: --frames must lie in 1..100000 (the held-out seeds from --first 0), got 0"),
    (ugv_detection.main, ["--frames", "200000"],
     "error: --frames must lie in 1..100000 (the held-out seeds from --first 0), got 200000"),
    (ugv_detection.main, ["--split", "validation", "--first", "99990", "--frames", "11"],
     "error: --frames must lie in 1..10 (the validation seeds from --first 99990), got 11"),
    (ugv_detection.main, ["--first", "-1"], "error: --first must lie in 0..99999 (the held-out seeds), got -1"),
    (ugv_detection.main, ["--first", "100000"], "error: --first must lie in 0..99999 (the held-out seeds), got 100000"),
    (ugv_detection.main, ["--min-body-px", "-1"], "error: --min-body-px must be 0 or more, got -1"),
    # The figures' file is checked before the work, not written into a missing folder after it.
    (stereo.main, ["--json", "/no-such-folder/x.json", "--frames", "1"],
     "error: argument --json: no folder /no-such-folder to write x.json in"),
    (motion_compensation.main, ["--json", "/no-such-folder/x.json"],
     "error: argument --json: no folder /no-such-folder to write x.json in"),
    (ugv_detection.main, ["--json", "/no-such-folder/x.json"],
     "error: argument --json: no folder /no-such-folder to write x.json in"),
    (realtime.main, ["--out", "/no-such-folder/x.json"],
     "error: argument --out: no folder /no-such-folder to write x.json in"),
    # stewart-dynamic's camera at 20 Hz: 0.05 s before the timing, then at least one timed frame.
    (realtime.main, ["--duration", "0.04"],
     "error: --duration must be at least 0.1 s (one 20 Hz camera frame before the timing, one timed), got 0.04"),
    (realtime.main, ["--duration", "0.09"],
     "error: --duration must be at least 0.1 s (one 20 Hz camera frame before the timing, one timed), got 0.09"),
    (stereo.main, ["--json", "/"], "error: argument --json: / is a folder, not a file"),
    (crhf_table5.main, ["--quick", "--out", "/no-such-folder/x.json"],
     "error: argument --out: no folder /no-such-folder to write x.json in"),
    # Refused before the group campaigns, not by the throughput measurement after them.
    (landing_campaign.main, ["--throughput-runs", "-3"], "error: --throughput-runs must not be negative, got -3"),
    (landing_campaign.main, ["--scaling-runs", "-1"], "error: --scaling-runs must not be negative, got -1"),
    (landing_campaign.main, ["--workers", "-1"], "error: --workers must not be negative, got -1"),
    (landing_campaign.main, ["--runs", "-1"], "error: --runs must not be negative, got -1"),
    (landing_campaign.main, ["--rendered-runs", "-2"], "error: --rendered-runs must not be negative, got -2"),
    (hybrid_timing.main, ["--frames", "0"], "error: --frames must be at least 1, got 0"),
    (hybrid_timing.main, ["--frames", "1", "--repeats", "0"], "error: --repeats must be at least 1, got 0"),
    # Not 45 frames recorded for --frames 40, nor a --low-frames above --frames cut to it unsaid.
    (hybrid_timing.main, ["--frames", "40", "--low-frames", "-5"],
     "error: --low-frames must lie in 0..40 (of the --frames), got -5"),
    (hybrid_timing.main, ["--frames", "4", "--low-frames", "5"],
     "error: --low-frames must lie in 0..4 (of the --frames), got 5"),
    (hybrid.main, ["--jobs", "0"], "error: --jobs must be at least 1, got 0"),
    # Before the closed-loop campaign (a negative count skipped its part unsaid).
    (vision_landing.main, ["--runs", "-1"], "error: --runs must not be negative, got -1"),
    (vision_landing.main, ["--open-loop-runs", "-2"], "error: --open-loop-runs must not be negative, got -2"),
    (vision_landing.main, ["--workers", "-1"], "error: --workers must not be negative, got -1"),
    (landing_sweep.main, ["--jobs", "0", "--quick"], "error: --jobs must be at least 1, got 0"),
    # Before the campaign (and its temporary folder), not a traceback from it or from the scaling after it.
    (marker_ekf_mc.main, ["--runs", "0"], "error: --runs must be at least 1, got 0"),
    (marker_ekf_mc.main, ["--workers", "-1"], "error: --workers must not be negative, got -1"),
    (marker_ekf_mc.main, ["--scaling-runs", "-1"], "error: --scaling-runs must not be negative, got -1"),
    (marker_ekf_mc.main, ["--detector-runs", "-2"], "error: --detector-runs must not be negative, got -2"),
    # Before the first render, not a rig asked for a camera under the pad.
    (marker_visibility.main, ["--heights", "0.3", "0"], "error: --heights must be finite and positive [m], got 0"),
    (marker_visibility.main, ["--heights", "-1"], "error: --heights must be finite and positive [m], got -1"),
    (marker_visibility.main, ["--heights", "nan"], "error: --heights must be finite and positive [m], got nan"),
])
def test_a_count_below_1_or_a_negative_noise_is_argparse_s_error(capsys, main, argv, line):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    assert captured.err.startswith("usage:") and captured.err.splitlines()[-1].endswith(line)


@pytest.mark.parametrize("main, argv, line", [
    (motion_blur.main, ["--scenario", "nope"], "unknown scenario 'nope' (known: "),
    (motion_blur.main, ["--duration", "0"], "duration_s must be positive, got 0.0"),
    (fisheye.main, ["--side-axis-deg", "200"], "fisheye.side_axis_deg must lie in [30, 90] deg, got 200.0"),
    # Every case's scenario is loaded before the first run (11 minutes of them without --quick).
    (crhf_table5.main, ["--duration", "-1"], "duration_s must be positive, got -1.0"),
    (realtime.main, ["--scenario", "gv-landing", "--duration", "1"], "gv-landing: not a Stewart scene"),
    # Every run's scenario before the process pool starts, not a traceback from inside it.
    (hybrid.main, ["--paths", "straight", "--seeds", "0", "--set", "bogus=1"], "unknown key 'bogus'"),
    (hybrid.main, ["--seeds", "0", "-1"], "seed must not be negative"),
    (hybrid.main, ["--duration", "-1"], "duration_s must be positive, got -1.0"),
    (landing_sweep.main, ["--quick", "--set", "bogus=1"], "unknown key 'bogus'"),
])
def test_a_scenario_or_camera_the_checks_refuse_is_their_line(capsys, main, argv, line):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    assert len(captured.err.splitlines()) == 1 and captured.err.startswith(line)


def test_a_folder_no_campaign_wrote_is_not_removed_for_one(capsys, tmp_path):
    """marker_ekf_mc.py starts its timed campaign afresh in --out, but never by removing a user's folder."""
    (tmp_path / "thesis.txt").write_text("mine")
    with pytest.raises(SystemExit) as exit_info:
        marker_ekf_mc.main(["--out", str(tmp_path)])
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    assert captured.err.splitlines()[-1].endswith(f"--out {tmp_path} holds no campaign.json: not a campaign's folder, "
                                                  "left as it is")
    assert (tmp_path / "thesis.txt").read_text() == "mine"


def test_crhf_table5_s_default_figures_file_is_checked_before_the_work(capsys, tmp_path, monkeypatch):
    """Without --out the figures go to results/crhf_table5.json, the folder made if missing: a path it cannot make
    is refused before the 11 minutes of runs."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").write_text("not a folder")
    with pytest.raises(SystemExit) as exit_info:
        crhf_table5.main(["--quick"])
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    assert captured.err.splitlines()[-1].endswith(f"error: --out (default results/crhf_table5.json): output path "
                                                  f"{tmp_path}/results exists and is not a directory")


def test_landing_campaign_s_out_that_is_a_file_is_one_line_before_the_work(capsys, tmp_path):
    """--out names a file: the campaigns' folder cannot be made there, said in one line, exit 2, before any run."""
    (tmp_path / "afile").write_text("mine")
    assert landing_campaign.main(["--out", str(tmp_path / "afile")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1
    assert captured.err.startswith(f"landing_campaign: output path {tmp_path / 'afile'} exists and is not a directory")
    assert (tmp_path / "afile").read_text() == "mine"


@pytest.mark.parametrize("met", [(True, True), (True, False)])
def test_landing_campaign_exits_1_on_any_failed_target(capsys, monkeypatch, tmp_path, met):
    """The benchmark's exit code is 0 when every target's check passes and 1 when one fails, as the other
    benchmarks' (the campaigns themselves replaced by a summary and two checks)."""
    monkeypatch.setattr(landing_campaign, "campaign", lambda *args, **kwargs: {"wall_time_s": 1.0, "cases": {}})
    monkeypatch.setattr(landing_campaign, "print_table", lambda *args: None)
    monkeypatch.setattr(landing_campaign, "checks_for",
                        lambda group, stream, summary: [(f"{group} {k}", ok, "x") for k, ok in enumerate(met)])
    code = landing_campaign.main(["--only", "wind", "--runs", "1", "--rendered-runs", "0", "--throughput-runs", "0",
                                  "--scaling-runs", "0", "--out", str(tmp_path / "c")])
    printed = capsys.readouterr().out
    assert code == (0 if all(met) else 1)
    assert printed.count("FAIL") == met.count(False) and printed.count("PASS") == met.count(True)


@pytest.mark.parametrize("nested_everywhere", [True, False])
def test_marker_visibility_exits_1_when_the_nested_layout_misses_a_pose(capsys, monkeypatch, nested_everywhere):
    """The target is the nested layout's: exit 1 when it misses a pose, 0 when it sees a marker at every one, the
    default five (seen nowhere here) reported either way (the rig replaced by detections made up per layout)."""
    def visibility(scenario, heights_m):
        seen_here = scenario == "marker-landing-wind" and nested_everywhere
        seen = {(h, t): [{5} if seen_here or k else set() for k in range(len(marker_visibility.OFFSETS_M))]
                for h in heights_m for t in marker_visibility.TILTS_DEG}
        if scenario == "marker-landing":
            seen = {key: [set()] * len(ids) for key, ids in seen.items()}
        return {"ids": [0, 5], "sizes_m": [0.2, 0.06], "seen": seen}
    monkeypatch.setattr(marker_visibility, "visibility", visibility)
    code = marker_visibility.main(["--heights", "2", "0.5"])
    printed = capsys.readouterr().out
    assert code == (0 if nested_everywhere else 1)
    assert "reported (not met): a marker at every pose from 2 m down to 0.5 m (lowest share 0%)" in printed
    verdict = "PASS" if nested_everywhere else "FAIL"
    share = "100%" if nested_everywhere else "96%"  # one offset of 25 without a marker
    assert f"{verdict}: a marker at every pose from 2 m down to 0.5 m (lowest share {share})" in printed
