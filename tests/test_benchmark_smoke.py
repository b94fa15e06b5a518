"""Smoke runs of the benchmarks whose main path no other test reaches: each main() end to end in this process at
its smallest arguments (landing_sweep: one sweep run), its figures read back from its --json/--out file or its
printout. They guard that a benchmark still runs and writes what its docstring and docs/results.md name: strict
JSON with those keys, counts equal to the arguments, figures finite and physically plausible. Not the figures'
accuracy at full size, and never how long anything takes. Slow: they render or fly."""

import json
import math
import re

import cv2
import pytest

import benchmarks.crhf_table5 as crhf_table5
import benchmarks.federated as federated
import benchmarks.fisheye as fisheye
import benchmarks.hybrid as hybrid
import benchmarks.landing_sweep as landing_sweep
import benchmarks.marker_visibility as marker_visibility
import benchmarks.motion_blur as motion_blur
import benchmarks.motion_compensation as motion_compensation
import benchmarks.stereo as stereo
import benchmarks.ugv_detection as ugv_detection
import benchmarks.vision_landing as vision_landing
from diagrams.fisheye_markers import MARKER_DIRECTIONS_DEG
from diagrams.landing_metrics import SETTLED_TOLERANCE_M, TARGET_TOUCHDOWN_ERROR_M, TARGET_TOUCHDOWN_REL_SPEED_MPS
from diagrams.runner import load_scenario
from diagrams.ugv_detection_scenes import TRAIN_TEXTURE_SEED, UgvSceneConfig
from tests.conftest import InlinePool

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def _opencv_threads():
    """The benchmarks set OpenCV's threads (one, for their timings): the other tests get theirs back."""
    threads = cv2.getNumThreads()
    yield
    cv2.setNumThreads(threads)


def strict_json(path):
    """The file's JSON, refusing NaN and infinities (write_json writes them as null)."""
    def refuse(constant):
        raise ValueError(f"{path.name}: {constant} is not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


def finite(*values) -> bool:
    return all(isinstance(v, int | float) and math.isfinite(v) for v in values)


def test_fisheye_one_frame_prints_each_marker_s_projection_error(capsys):
    assert fisheye.main(["--frames", "1"]) is None
    out = capsys.readouterr().out
    assert "renders the median of 1 frames, remaps the best of 20" in out
    costs = [float(v) for v in re.findall(r"^  (?:render|compose|rectified).*?(\d+\.\d+)", out, re.MULTILINE)]
    assert len(costs) == 5 and all(c > 0 for c in costs)
    line = re.search(rf"projection error, {len(MARKER_DIRECTIONS_DEG)} markers: mean (\S+) px, max (\S+) px", out)
    assert line, f"no projection error line for the {len(MARKER_DIRECTIONS_DEG)} markers"
    mean, worst = map(float, line.groups())
    errors = [float(e) for e in re.findall(r"deg off-axis: (\S+) px", out)]
    assert len(errors) == len(MARKER_DIRECTIONS_DEG) == 18
    assert max(errors) == worst and sum(errors) / len(errors) == pytest.approx(mean, abs=1e-3)
    assert 0 <= mean <= worst < 0.5  # docs/results.md: mean 0.059, max 0.182 px


def test_motion_compensation_one_pair_writes_orb_s_and_sift_s_figures(tmp_path, capsys):
    out = tmp_path / "mc.json"
    assert motion_compensation.main(["--pairs", "1", "--repeats", "1", "--json", str(out)]) is None
    assert capsys.readouterr().out.startswith("1 pairs of 512 x 512 frames, yaw up to 5 deg a frame, 1 repeats")
    figures = strict_json(out)
    assert set(figures) == {"orb", "sift"}
    for name, r in figures.items():
        ms = r["ms"]
        assert set(ms) == {"detect", "match", "ransac", "homography", "step"}
        assert finite(*ms.values()) and min(ms.values()) > 0
        assert ms["step"] == pytest.approx(ms["detect"] + ms["match"] + ms["homography"])  # one pair, one repeat
        assert 0 < r["inliers_median"] <= r["features"], name
        for key in ("corner_error_px", "corner_error_unrefined_px"):
            e = r[key]
            assert e["median"] == e["max"], (name, key)  # one pair
            assert finite(e["max"]) and 0 <= e["max"] < 1.0, (name, key)  # docs/results.md: 0.038 px at worst


def test_ugv_detection_one_frame_scores_the_three_detectors(tmp_path):
    out = tmp_path / "ugv.json"
    assert ugv_detection.main(["--frames", "1", "--cache-dir", str(tmp_path / "cache"), "--json", str(out)]) == 0
    assert list((tmp_path / "cache").iterdir())  # the rendered frame cached here, not under results/
    figures = strict_json(out)
    assert (figures["frames"], figures["split"], figures["first_seed"]) == (1, "held-out", 1_000_000)
    assert figures["ground_texture_seed"] == UgvSceneConfig().ground.texture_seed != TRAIN_TEXTURE_SEED
    assert figures["min_body_px"] == 5  # the refiner's default
    assert figures["table3"] == ugv_detection.TABLE3
    assert set(figures["detectors"]) == {"learned_cnn", "learned_refined", "classical_colour_pad"}
    for name, r in figures["detectors"].items():
        assert r["frames"] == 1 and r["targets"] in (0, 1), name
        assert r["tp"] + r["fn"] == r["targets"] and 0 <= r["fp_on_distractor"] <= r["fp"], name
        for score in ("precision", "recall", "f1"):
            assert r[score] is None or 0.0 <= r[score] <= 1.0, (name, score)
        centre = r["centre_error_px"]["median"]
        assert (centre is None) == (r["tp"] == 0) and (centre is None or 0 <= centre < 50), name
        ms = r["per_frame_ms"]
        assert finite(*ms.values()) and ms["median"] > 0 and ms["std"] == 0, name  # one frame
        assert len(r["by_kind"]) == 5 and sum(k["frames"] for k in r["by_kind"].values()) <= 5, name
        scores = r["scores"]
        assert (scores["tp_median"] is None) == (r["tp"] == 0) and (scores["fp_max"] is None) == (r["fp"] == 0), name
        assert all(v is None or 0.0 <= v <= 1.0 for v in scores.values()), name


def test_ugv_detection_on_validation_frames_past_the_trainers(tmp_path):
    """`--split validation --first 300`: the frames after those the trainer chose its threshold on, on its training
    ground, scored with the colour check off."""
    out = tmp_path / "ugv.json"
    assert ugv_detection.main(["--split", "validation", "--first", "300", "--frames", "1", "--min-body-px", "0",
                               "--cache-dir", str(tmp_path / "cache"), "--json", str(out)]) == 0
    figures = strict_json(out)
    assert (figures["frames"], figures["split"], figures["first_seed"]) == (1, "validation", 500_300)
    assert figures["ground_texture_seed"] == TRAIN_TEXTURE_SEED
    assert figures["min_body_px"] == 0


def test_stereo_one_frame_and_a_two_height_sweep(tmp_path, capsys):
    out = tmp_path / "stereo.json"
    code = stereo.main(["--frames", "1", "--step", "4.3", "--json", str(out)])  # sweep heights 0.7 and 5 m
    printed = capsys.readouterr().out
    verdict = re.search(r"^Figure 16 bounds: (PASS|FAIL)$", printed, re.MULTILINE).group(1)
    assert code == (0 if verdict == "PASS" else 1)
    figures = strict_json(out)
    assert figures["pass"] == (code == 0) and figures["noise"] == 2.0
    assert set(figures["per_frame_ms"]) == {"render_left", "render_right", "noise_left", "noise_right",
                                            "sgbm_window_crop", "rest", "sgbm_full_frame"}
    assert finite(*figures["per_frame_ms"].values()) and min(figures["per_frame_ms"].values()) > 0
    assert [row["height_m"] for row in figures["table"]] == list(stereo.TABLE_HEIGHTS)
    for row in figures["table"]:
        if row["valid"]:
            assert finite(row["altitude_m"]) and row["error_m"] == pytest.approx(row["altitude_m"] - row["height_m"])
            assert abs(row["error_m"]) < 2.0, row
        else:
            assert row["altitude_m"] is None, row  # NaN written as null
        assert 0.0 <= row["valid_fraction"] <= 1.0
    sweep = figures["sweep"]
    for band in ("0.7-3 m", "3-8 m"):
        assert sweep[band]["heights"] == 1 and sweep[band]["out_of_range_m"] == [], band
        assert finite(sweep[band]["max_abs_error_m"]) and sweep[band]["max_abs_error_m"] < 2.0, band
    assert finite(sweep["rms_error_over_Z2"]) and sweep["rms_error_over_Z2"] >= 0


@pytest.mark.parametrize("scenario", ["stewart-hardware", "deck-landing-hardware"])
def test_motion_blur_a_second_s_smears(capsys, scenario):
    """Stewart: a smear per camera frame; deck-landing: flown, a smear per supervisor sample, t = 0 and 1 s with."""
    assert motion_blur.main(["--scenario", scenario, "--duration", "1"]) is None
    _, config = load_scenario(scenario)
    samples = (round(1.0 / config.camera.period_s) if scenario.startswith("stewart")
               else round(1.0 * config.landing.rate_hz) + 1)
    line = re.fullmatch(rf"{scenario} \(1 s, exposure 10 ms\): smear median (\S+) px, 95th percentile (\S+) px, "
                        rf"largest (\S+) px; (\S+)% of {samples} samples at or above half a pixel",
                        capsys.readouterr().out.strip())
    assert line, f"{samples} samples expected"
    median, p95, largest, share = map(float, line.groups())
    assert 0 <= median <= p95 <= largest < 20.0  # px: docs/results.md's largest are a few pixels
    assert 0 <= share <= 100


def test_crhf_table5_quick_half_a_second(tmp_path, capsys):
    out = tmp_path / "crhf.json"
    assert crhf_table5.main(["--quick", "--duration", "0.5", "--out", str(out)]) is None
    assert f"figures written to {out}" in capsys.readouterr().out
    figures = strict_json(out)
    assert figures["paper_mae"] == crhf_table5.PAPER
    assert set(figures["cases"]) == {"stewart-dynamic"}
    case = figures["cases"]["stewart-dynamic"]
    assert case["duration_s"] == 0.5
    assert finite(case["crhf_compute_ms"], case["realtime_factor"]) and case["crhf_compute_ms"] > 0
    for name in ("atda", "crhf"):
        m = case["estimators"][name]
        assert len(m["mae_xyz_m"]) == 3 and len(m["mae_rpy_deg"]) == 3, name
        assert all(finite(v) and 0 <= v < 0.1 for v in m["mae_xyz_m"]), name  # m; Table 5's are under 0.07
        assert all(finite(v) and 0 <= v < 10.0 for v in m["mae_rpy_deg"]), name  # deg; Table 5's under 4
        assert 0.0 <= m["valid_fraction"] <= 1.0 and m["flips"] >= 0, name


def test_hybrid_one_short_run(tmp_path, monkeypatch, capsys):
    """0.2 s of ugv-hybrid on the straight path: too short to land, so one run ended by the time limit."""
    monkeypatch.setattr(hybrid, "ProcessPoolExecutor", InlinePool)
    out = tmp_path / "hybrid.json"
    assert hybrid.main(["--paths", "straight", "--seeds", "0", "--duration", "0.2", "--json", str(out)]) is None
    assert "speed 0.5 m/s: success 0% of 1, touchdown error p95 -" in capsys.readouterr().out
    figures = strict_json(out)
    assert figures["speed"] == 0.5 and figures["success_rate"] == 0.0 and figures["touchdown_error_p95_m"] is None
    [run] = figures["runs"]
    assert (run["path"], run["speed"], run["seed"]) == ("straight", 0.5, 0)
    assert not run["success"] and run["failure"] == "timeout" and run["touchdown_error_m"] is None
    assert run["sim_time_s"] == pytest.approx(0.2)
    assert 0.0 <= run["hybrid_valid_fraction"] <= 1.0 and finite(run["wall_s"])
    assert run["identity_switches"] == 0  # 0.2 s on the ground: the UGV is not yet in view, nothing locked


def test_landing_sweep_one_run_lands_within_the_targets():
    """One run of the sweep (landing_sweep --quick is 27 s): straight at 0.5 m/s with the sweep's overrides."""
    r = landing_sweep.one_run(("straight", 0.5, list(landing_sweep.SWEEP_OVERRIDES)))
    assert (r["path"], r["speed_m_s"]) == ("straight", 0.5)
    assert r["success"] and r["meets_targets"] and r["failure"] is None
    assert 0 <= r["touchdown_error_m"] < TARGET_TOUCHDOWN_ERROR_M
    assert 0 < r["touchdown_rel_speed_mps"] < TARGET_TOUCHDOWN_REL_SPEED_MPS
    assert 0 <= r["settled_max_abs_xy_m"] <= SETTLED_TOLERANCE_M
    assert r["turn_radius_m"] is None  # a straight path
    assert 0 < r["time_to_land_s"] <= r["sim_time_s"] < load_scenario("gv-landing")[1].duration_s


def test_marker_visibility_at_its_lowest_height(tmp_path, capsys):
    """The visibility grid at 0.3 m alone (its 11 heights take 80 s; test_marker_visibility.py has 10 m): the nested
    layout sees a marker at every pose there (exit 0); the default five miss most poses, where their centre marker
    alone can be whole in view (docs/results.md: 16-36 %)."""
    out = tmp_path / "visibility.json"
    assert marker_visibility.main(["--heights", "0.3", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "PASS: a marker at every pose from 0.3 m down to 0.3 m (lowest share 100%)" in printed
    assert "reported (not met): a marker at every pose from 0.3 m down to 0.3 m" in printed
    figures = strict_json(out)
    five, nine = figures["five (marker-landing)"], figures["nested nine (marker-landing-wind)"]
    poses = {f"0.3 m, {t:g} deg" for t in marker_visibility.TILTS_DEG}
    assert set(five["any"]) == set(nine["any"]) == poses
    assert set(nine["any"].values()) == {1.0}
    assert all(0.0 < five["any"][pose] < 0.5 for pose in poses)
    assert set(five["per_marker"]) == set(nine["per_marker"]) == {"0.3 m"}
    assert set(five["per_marker"]["0.3 m"]) == {"0", "1", "2", "3", "4"}
    assert max(five["per_marker"]["0.3 m"][i] for i in "1234") == 0.0  # a 0.30 m corner marker in a 0.33 m view
    assert 0.0 < nine["per_marker"]["0.3 m"]["0"] == five["per_marker"]["0.3 m"]["0"] < 1.0  # the same centre marker


def test_federated_frame_costs_on_a_descent_s_frames(capsys):
    """Part 3 of federated.py alone (its main has no smaller run: the manoeuvres and a 20 m descent per seed, twice):
    each stage's cost per frame, on 60 frames rendered along a descent over the open-landing pattern."""
    costs = federated.frame_costs(())
    assert set(costs) == {"render", "approach", "adjustment", "touchdown", "federated_step", "fusion"}
    assert finite(*costs.values()) and min(costs.values()) > 0
    assert "## Cost per frame, 960 x 540 (median of 59 frames, ms)" in capsys.readouterr().out


def test_vision_landing_costs_alone_fly_marker_landing_and_write_each_stage(tmp_path, capsys):
    """vision_landing's part 3 alone (by default parts 1 and 2 fly 30 landings, 60 open-loop runs and the previous
    commit's campaign in a worktree): marker-landing flown once, landing by vision, then its stages timed alone; the
    JSON holds the costs, the rest by subtraction."""
    out = tmp_path / "vision_landing.json"
    assert vision_landing.main(["--runs", "0", "--open-loop-runs", "0", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"## Cost per camera frame: marker-landing, .*\(real-time factor [\d.]+; landed: ", printed)
    figures = strict_json(out)
    assert set(figures) == {"costs"}
    costs = figures["costs"]
    stages = costs["stages_ms"]
    assert set(stages) == {"render", "pixel noise", "detection", "filter paper_ekf", "filter ct_ekf"}
    assert finite(costs["per_frame_ms"], costs["rest_ms"], costs["realtime_factor"], *stages.values())
    assert min(stages.values()) > 0 and costs["per_frame_ms"] > 0 and costs["realtime_factor"] > 0
    assert costs["rest_ms"] == pytest.approx(costs["per_frame_ms"] - sum(stages.values()))
    ratio = float(re.search(r"ms = (\d+\.\d+) x the render", printed).group(1))
    assert ratio == pytest.approx(costs["per_frame_ms"] / stages["render"], abs=0.006)
