"""gv-marker-ekf (diagrams/gv_marker_ekf.py) and its campaign (diagrams/gv_marker_ekf_mc.py) on
short runs: the command writes its metrics, both filters see the identical measurement stream, the
vectorised stream matches `synthetic_marker_measurements`, the campaign gives identical summaries
with 1 and 2 workers, and bad settings are one-line errors."""

import json

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw

from diagrams.cli import main
from diagrams.gv_marker_ekf import (
    Truth, arrivals, estimate_run, fly_truth, quat_multiply, run_filters, synthetic_stream,
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
    layout, X_BC = s.estimation.markers, s.estimation.X_BC
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
