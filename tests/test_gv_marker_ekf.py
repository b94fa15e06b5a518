"""gv-marker-ekf (diagrams/gv_marker_ekf.py) and its campaign (diagrams/gv_marker_ekf_mc.py) on
short runs: the command writes its metrics, both filters see the identical measurement stream, the
vectorised stream matches `synthetic_marker_measurements`, the detector source measures the markers
the camera renders in the scene and the filters track the pad on it, Meshcat records the flight,
the campaign gives identical summaries with 1 and 2 workers, and bad settings are one-line errors."""

import json

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Meshcat
from pydrake.math import RigidTransform, RollPitchYaw

from diagrams.cli import main
from diagrams.gv_marker_ekf import (
    Truth, arrivals, estimate_run, fly, fly_truth, measurement_metrics, quat_multiply, show_estimates, synthetic_stream,
    true_marker_poses_C,
)
from diagrams.montecarlo import campaign_definition, campaign_settings, run_campaign
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.perception.markers import synthetic_marker_measurements

SHORT = ["duration_s=4"]


def scenario(speed=12, seed=0, *extra):
    return load_scenario("gv-marker-ekf", None, [f"vehicle.speed={speed}", *SHORT, *extra], None, seed)[1]


def test_run_command_writes_metrics(capfd, tmp_path):
    out = tmp_path / "run"
    code = main(["run", "gv-marker-ekf", "--set", "vehicle.speed=6", "--set", "duration_s=3", "--out", str(out),
                 "--quiet"])
    assert code in (0, None)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "gv-marker-ekf"
    for name in ("paper_ekf", "ct_ekf"):
        m = metrics["estimators"][name]
        assert 0 < m["rms_position_m"] < 0.5 and 0 < m["rms_heading_deg"] < 10
        assert len(m["rms_marker_position_m"]) == 5
        assert {"gated", "invalid", "accepted"} <= set(m["measurements"])
    for png in ("path.png", "heading.png", "marker_errors.png"):
        assert (out / png).is_file()
    with np.load(out / "log.npz") as log:
        assert log["ct_ekf_p_WP"].shape == log["p_WP"].shape


def test_default_run_length_is_500_m_of_driving():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=12"])[1]
    assert s.run_length_s == pytest.approx(500 / 12)


def test_flight_starts_at_10_m_and_holds_0_4_m_above_the_pad():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=3", "duration_s=20"])[1]
    truth = fly_truth(s)
    assert truth.p_WB[0] == pytest.approx([0, 0, 10])
    height = truth.p_WB[:, 2] - truth.p_WP[:, 2]
    assert abs(height[-1] - 0.4) < 0.05
    assert np.linalg.norm(truth.p_WB[-1, :2] - truth.p_WP[-1, :2]) < 0.5


def test_flight_at_12_m_s_never_goes_below_the_pad_and_keeps_up():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=12"])[1]  # the full 500 m (42 s)
    truth = fly_truth(s, cache=False)
    height = truth.p_WB[:, 2] - truth.p_WP[:, 2]
    offset = np.linalg.norm(truth.p_WB[:, :2] - truth.p_WP[:, :2], axis=1)
    assert height.min() > 0.3 and abs(height[-1] - 0.4) < 0.05
    caught_up = truth.t >= 20.0  # the UAV starts hovering and needs ~15 s to reach 12 m/s and catch up
    assert offset[caught_up].max() < 0.3


def test_both_filters_get_the_identical_stream():
    s = scenario()
    truth = fly_truth(s)
    log = []
    est = estimate_run(s, truth, inputs_log=log)
    assert len(log) == len(truth.t) and log[0] == [] and len(log[1]) == 5  # one period late
    # Run each filter alone on the same seed: the same estimates as side by side.
    for name in ("paper_ekf", "ct_ekf"):
        s.estimation.filters = [name]
        alone = estimate_run(s, truth)
        np.testing.assert_array_equal(alone.traces[name].p_WP, est.traces[name].p_WP)
    again = estimate_run(scenario(), truth)
    np.testing.assert_array_equal(again.stream.p_CM, est.stream.p_CM)


def test_vectorised_stream_matches_the_synthetic_source_geometry():
    s = scenario()
    layout, X_BC = s.platform.markers, s.estimation.X_BC
    t = np.array([0.0, 0.035])
    X_WB = [RigidTransform(RollPitchYaw(0.1, -0.05, 0.4), [1, 2, 5]), RigidTransform(RollPitchYaw(0, 0.2, -1), [0, 1, 3])]
    yaw = np.array([0.3, -2.0])
    p_WP = np.array([[1.5, 2.2, 1.6], [0.2, 0.9, 1.6]])
    q_WB = np.array([X.rotation().ToQuaternion().wxyz() for X in X_WB])
    truth = Truth(t, np.array([X.translation() for X in X_WB]), q_WB, p_WP, yaw, np.zeros((2, 4)), "", 0.0)
    stream = synthetic_stream(truth, layout, X_BC, np.random.default_rng(0), 0.0, 0.0)
    for k in range(2):
        X_WP = RigidTransform(RollPitchYaw(0, 0, yaw[k]), p_WP[k])
        ref = synthetic_marker_measurements(X_WB[k].multiply(X_BC).InvertAndCompose(X_WP), layout,
                                            np.random.default_rng(0), 0.0, 0.0)
        for i, m in enumerate(ref):
            np.testing.assert_allclose(stream.p_CM[k, i], m.p_CM, atol=1e-12)
            q = stream.q_CM[k, i]
            assert abs(abs(q @ m.q_CM) - 1) < 1e-12
    a = np.array([0.5, 0.5, 0.5, 0.5])
    np.testing.assert_allclose(quat_multiply(a, a), (Quaternion(a).multiply(Quaternion(a))).wxyz())


def test_synthetic_measurements_have_the_papers_accuracy():
    s = scenario(6)
    est = estimate_run(s, fly_truth(s))
    m = est.measurements
    assert m["measured_fraction"] == [1.0] * 5
    # 0.1 m on each of 3 axes, 5 deg on each of 3 axes of a rotation vector
    np.testing.assert_allclose(m["rms_position_m"], 0.1 * np.sqrt(3), rtol=0.08)
    np.testing.assert_allclose(m["rms_attitude_deg"], 5.0 * np.sqrt(3), rtol=0.08)


@pytest.fixture(scope="module")
def detector_run():
    """4 s at 3 m/s with the camera: the pad is in view, leaves it (0.3-1.2 s) and returns."""
    s = scenario(3, 0, "estimation.source=detector")
    truth, stream, _ = fly(s, camera=True)
    return s, truth, stream


def test_detector_measures_the_markers_the_camera_renders(detector_run):
    s, truth, stream = detector_run
    layout = s.platform.markers
    m = measurement_metrics(truth, stream, layout, s.estimation.X_BC)
    assert min(m["measured_fraction"]) > 0.5  # from 8 m up, the UAV hovering behind the vehicle
    assert max(m["rms_position_m"]) < 0.2  # m, 14-24 px markers 8 m away
    p_CM, q_CP = true_marker_poses_C(truth, layout, s.estimation.X_BC)
    seen = ~np.isnan(stream.p_CM[..., 0])
    # The rendered texture, the camera mount and the intrinsics agree with the layout: bearings to a
    # fraction of a pixel, ranges to a few per cent, and each marker's heading about the optical axis.
    bearing = (stream.p_CM[..., :2] / stream.p_CM[..., 2:] - p_CM[..., :2] / p_CM[..., 2:])[seen]
    assert np.sqrt(np.mean(np.sum(bearing**2, axis=1))) < 1.0 / s.estimation.camera.fx
    ratio = np.linalg.norm(stream.p_CM[seen], axis=1) / np.linalg.norm(p_CM[seen], axis=1)
    assert abs(np.mean(ratio) - 1) < 0.03
    for k, i in zip(*np.nonzero(seen)):
        R_error = (Quaternion(q_CP[k]).rotation().T
                   @ Quaternion(np.r_[stream.q_CM[k, i, 3], stream.q_CM[k, i, :3]]).rotation())
        assert abs(np.degrees(np.arctan2(R_error[1, 0], R_error[0, 0]))) < 5.0
    # The pad leaves the 58 deg view while the UAV catches up: those frames measure nothing.
    blind = ~seen.any(axis=1)
    assert 10 < blind.sum() < len(truth.t) / 2
    k = int(np.argmax(blind))
    assert arrivals(stream, layout, k + s.estimation.latency_periods, s.estimation.latency_periods) == []


def test_filters_track_the_pad_on_the_detector_stream(detector_run):
    s, truth, stream = detector_run
    est = estimate_run(s, truth, stream)
    for name in ("paper_ekf", "ct_ekf"):
        m = est.metrics[name]
        assert m["rms_position_m"] < 0.1 and m["rms_heading_deg"] < 1.0
        assert m["steps"] > 40 and m["measurements"]["invalid"] == 0
    np.testing.assert_array_equal(est.stream.p_CM, stream.p_CM)


def test_video_needs_the_camera(capfd, tmp_path):
    out = tmp_path / "video"
    code = main(["run", "gv-marker-ekf", "--set", "duration_s=1", "--video", "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and "estimation.source=detector" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_meshcat_records_the_flight_and_shows_the_estimates():
    sizes = []
    for duration in ("1", "3"):
        meshcat = Meshcat()
        s = scenario(6, 0, f"duration_s={duration}")
        truth, _, handles = fly(s, meshcat, record=True)
        sizes.append(len(meshcat.StaticHtml()))
    assert sizes[1] > sizes[0] + 10_000  # the recording holds the whole flight, not its last frame
    show_estimates(meshcat, estimate_run(s, truth))
    for name in ("paper_ekf", "ct_ekf"):
        assert meshcat.HasPath(f"gv_marker_ekf/{name}_pad_path")


def campaign(tmp_path, workers, runs=2, speeds=("3", "12")):
    definition = campaign_definition("gv-marker-ekf")
    settings = campaign_settings(definition, "gv-marker-ekf", speeds, runs, overrides=SHORT)
    return run_campaign(definition, settings, tmp_path / f"mc{workers}", workers=workers, progress=False)


def test_campaign_identical_with_1_and_2_workers(tmp_path):
    one, two = campaign(tmp_path, 1), campaign(tmp_path, 2)
    assert one["runs"]["done"] == 4 and one["runs"]["failed"] == 0
    def figures(summary):  # every figure but the timing (per_frame_ms)
        return json.dumps({f: {c: {k: v for k, v in d.items() if k != "per_frame_ms"} for c, d in cases.items()}
                           for f, cases in summary["filters"].items()}, sort_keys=True)

    assert figures(one) == figures(two)
    assert set(one["filters"]) == {"paper_ekf", "ct_ekf"}
    assert {"rms_position_m", "rms_heading_deg"} <= set(one["filters"]["ct_ekf"]["12"])
    for png in ("mc_path.png", "mc_heading.png", "mc_marker_errors.png"):
        assert (tmp_path / "mc1" / png).is_file()


def test_detector_campaign_leaves_out_what_the_filters_flag(tmp_path):
    # At 12 m/s the pad leaves the camera's view 0.2 s in and the filters coast until they flag
    # their estimates invalid: the figures are over the valid ones (from t = 0 here).
    definition = campaign_definition("gv-marker-ekf")
    settings = campaign_settings(definition, "gv-marker-ekf", ["12"], 1,
                                 overrides=[*SHORT, "estimation.source=detector", "estimation.settle_s=0"])
    summary = run_campaign(definition, settings, tmp_path / "detector", workers=0, progress=False)
    assert summary["runs"]["done"] == 1
    record = json.loads((tmp_path / "detector" / "runs" / "12" / "00000.json").read_text())
    ct = record["metrics"]["estimators"]["ct_ekf"]
    assert 0 < ct["valid_fraction"] < 0.5 and record["metrics"]["measurements"]["measured_fraction"][0] < 0.2
    for name in ("paper_ekf", "ct_ekf"):
        c = summary["filters"][name]["12"]
        assert np.isfinite(c["ensemble_mean_position_xy_m"]) and c["ensemble_mean_position_xy_m"] < 1.0


@pytest.mark.parametrize("args, message", [
    (["--speeds", "5"], "unknown speed '5'"),
    (["--runs", "0"], "--runs must be"),
    (["--speeds", "fast"], "not a number"),
])
def test_bad_campaign_settings_are_one_line(capfd, tmp_path, args, message):
    out = tmp_path / "bad"
    code = main(["montecarlo", "gv-marker-ekf", *args, "--out", str(out)])
    _, err = capfd.readouterr()
    assert code != 0 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_scenario_values():
    with pytest.raises(ConfigError, match="estimation.filters"):
        scenario(12, 0, "estimation.filters=[nope]")
    with pytest.raises(ConfigError, match="vehicle.speed"):
        scenario(0)
    with pytest.raises(ConfigError, match="estimation.source 'camera' is not one of: synthetic, detector"):
        scenario(12, 0, "estimation.source=camera")
    with pytest.raises(ConfigError, match=r"estimation.camera.rate_hz \(20\) must be 1 / estimation.ekf.period_s"):
        scenario(12, 0, "estimation.camera.rate_hz=20")
