"""gv-marker-ekf (diagrams/gv_marker_ekf.py) and its campaign (diagrams/gv_marker_ekf_mc.py) on
short runs: the command writes its metrics, both filters see the identical measurement stream one
period late, the truth's marker geometry against Drake, the synthetic stream has the paper's
accuracy, the detector source measures the markers the camera renders in the scene and the filters
track the pad on it, Meshcat records the flight and the estimates, the campaign gives identical
summaries with 1 and 2 workers, and bad settings are one-line errors."""

import dataclasses
import json
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

import diagrams.marker_plots as marker_plots
from diagrams.cli import main
from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly_diagram
from diagrams.gv_marker_ekf import LONG_WAVE_M, Scenario
from diagrams.marker_batch import batch_run, flight_samples
from diagrams.marker_metrics import SampledRun, marker_metrics, measurement_metrics, pad_truth, true_marker_poses_C
from diagrams.montecarlo import campaign_definition, campaign_settings, run_campaign
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.marker_ekf.engine import EST_LAST_MEASUREMENT, EST_P_WP, ESTIMATE_VECTOR_SIZE
from systems.perception.seam import HEIGHT, P_BP_W
from systems.vehicles.quadrotor import P_WB, quadrotor_state
from systems.viewers import MeshcatTrail
from tests.conftest import wiring

SHORT = ["duration_s=4"]


def scenario(speed=12, seed=0, *extra):
    return load_scenario("gv-marker-ekf", None, [f"vehicle.speed={speed}", *SHORT, *extra], None, seed)[1]


def test_run_command_writes_metrics(capfd, tmp_path):
    out = tmp_path / "run"
    code = main(["run", "gv-marker-ekf", "--set", "vehicle.speed=6", "--set", "duration_s=3", "--out", str(out),
                 "--quiet"])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "gv-marker-ekf" and "landing" not in metrics
    assert metrics["perception"]["source"] == "truth" and metrics["flight"]["end"] == "completed"
    for name in ("paper_ekf", "ct_ekf"):
        m = metrics["estimators"][name]
        assert 0 < m["rms_position_m"] < 0.5 and 0 < m["rms_heading_deg"] < 10
        assert len(m["rms_marker_position_m"]) == 5 and len(m["mae_xyz_m"]) == 3
        assert {"gated", "invalid", "accepted"} <= set(m["measurements"])
    for png in ("path.png", "heading.png", "marker_errors.png", "perception.png"):
        assert (out / png).is_file()
    with np.load(out / "log.npz") as log:
        assert log["ct_ekf_estimate"].shape == (len(log["t_sample"]), ESTIMATE_VECTOR_SIZE)
        assert log["measurements"].shape == (len(log["t_sample"]), 5, 7)
        # The flight's end: the true offset in x-y only (the height above the pad is its own figure).
        last = log["true_relative_state"][-1]
    assert metrics["flight"]["final_horizontal_offset_m"] == pytest.approx(np.hypot(*last[P_BP_W][:2]), abs=1e-12)
    assert metrics["flight"]["final_height_above_pad_m"] == pytest.approx(last[HEIGHT], abs=1e-12)


def test_default_run_length_is_500_m_of_driving():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=12"])[1]
    assert s.run_length_s == pytest.approx(500 / 12)


def _heights_and_offsets(s, duration_s):
    t, quad, vehicle = flight_samples(s, duration_s)
    p_WP = np.array([s.platform.X_WP(v).translation() for v in vehicle])
    return t, quad[:, P_WB], quad[:, 2] - p_WP[:, 2], np.linalg.norm(quad[:, :2] - p_WP[:, :2], axis=1)


def test_flight_starts_at_10_m_and_holds_0_4_m_above_the_pad():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=3"])[1]
    _, p_WB, height, offset = _heights_and_offsets(s, 20.0)
    assert p_WB[0] == pytest.approx([0, 0, 10])
    assert abs(height[-1] - 0.4) < 0.05 and offset[-1] < 0.5


def test_flight_at_12_m_s_never_goes_below_the_pad_and_keeps_up():
    s = load_scenario("gv-marker-ekf", None, ["vehicle.speed=12"])[1]  # the full 500 m (42 s)
    t, _, height, offset = _heights_and_offsets(s, s.run_length_s)
    assert height.min() > 0.3 and abs(height[-1] - 0.4) < 0.05
    caught_up = t >= 20.0  # the UAV starts hovering and needs ~15 s to reach 12 m/s and catch up
    assert offset[caught_up].max() < 0.3


def test_both_filters_get_the_identical_stream_one_period_late():
    s = scenario(seed=4)
    together = batch_run(s, 4.0)
    # Each filter alone on the same seed: the same estimates as side by side.
    for name in ("paper_ekf", "ct_ekf"):
        s.estimation.filters = [name]
        alone = batch_run(s, 4.0)
        np.testing.assert_array_equal(alone.estimates[name], together.estimates[name])
        np.testing.assert_array_equal(alone.measurements, together.measurements)
        # The newest measurement in each step was acquired one period before it (none in the first).
        last = together.estimates[name][:, EST_LAST_MEASUREMENT]
        assert np.isnan(last[0])
        np.testing.assert_allclose(last[1:], together.t[:-1], atol=1e-12)


def test_the_run_is_sampled_at_the_filter_steps():
    """The sampled run (stream, truth, estimates) is logged every filter step T_s = 35 ms (1 / 28.57 Hz), not at
    the flight controller's rate."""
    s = scenario()
    assert s.estimation.ekf.period_s == pytest.approx(0.035, abs=1e-12) and s.period_s != s.estimation.ekf.period_s
    diagram, handles = build_gv_landing(s)
    flight = fly_diagram(diagram, handles, 1.0)
    assert len(flight.sampled.t) > 20
    np.testing.assert_allclose(np.diff(flight.sampled.t), 0.035, atol=1e-9)


@pytest.mark.parametrize("extra, acquired_by", [
    ((), "marker_source"), (("faults.drop_probability=0.5",), "marker_faults")])
def test_the_logged_stream_is_the_one_acquired_before_its_latency(extra, acquired_by):
    """The sampled run's `measurements` are the stream as acquired (with its faults), at its own step: the
    source's, or the faults' output, not the latency's delayed copy the filters read."""
    diagram, _ = build_gv_landing(scenario(12, 0, *extra))
    stream = diagram.GetSubsystemByName("stream_vector")
    source, _ = wiring(diagram)["stream_vector", stream.get_input_port().get_name()]
    assert source == acquired_by


def test_metrics_score_each_filters_own_attitude_estimate(monkeypatch):
    # The pad is level: a filter's roll and pitch errors are its estimate's own roll and pitch, that
    # of its pose estimate X_WP at each step (recorded here as the run steps it). paper_ekf estimates
    # all three axes, ct_ekf only the yaw: its roll and pitch are not scored.
    from systems.estimators.marker_ekf import PaperMarkerEkf

    poses = []
    record = PaperMarkerEkf.record
    monkeypatch.setattr(PaperMarkerEkf, "record", lambda f: poses.append(f.estimate().X_WP) or record(f))
    s = scenario(6, 1)
    run = batch_run(s, s.run_length_s)
    _, metrics, _ = marker_metrics(run, s.platform, s.estimation.X_BC, s.estimation.settle_s)
    scored = [X for t, X in zip(run.t, poses, strict=True) if X.valid and t >= s.estimation.settle_s]
    roll_pitch = np.degrees([RollPitchYaw(X.X_RT.rotation()).vector()[:2] for X in scored])
    paper = metrics["paper_ekf"]
    assert paper["frames_scored"] == len(scored) and paper["attitude_axes"] == ["roll", "pitch", "yaw"]
    np.testing.assert_allclose(paper["mae_rpy_deg"][:2], np.mean(np.abs(roll_pitch), axis=0), rtol=1e-6)
    np.testing.assert_allclose(paper["rmse_rpy_deg"][:2], np.sqrt(np.mean(roll_pitch**2, axis=0)), rtol=1e-6)
    assert min(paper["mae_rpy_deg"][:2]) > 0.01  # deg: the paper filter's tilt is noise, never exactly 0
    ct = metrics["ct_ekf"]
    assert ct["attitude_axes"] == ["yaw"] and ct["mae_rpy_deg"][:2] == ct["rmse_rpy_deg"][:2] == [None, None]
    assert ct["mae_rpy_deg"][2] > 0


def test_the_truths_marker_poses_in_the_camera_are_drakes():
    s = scenario()
    X_WB = [RigidTransform(RollPitchYaw(0.1, -0.05, 0.4), [1, 2, 5]),
            RigidTransform(RollPitchYaw(0, 0.2, -1), [0, 1, 3])]
    vehicle = np.array([[0.0, 0.5, 0.3, 0.0], [-1.0, 0.2, -2.0, 0.1]])
    quad = np.array([quadrotor_state(p_WB=X.translation(), R_WB=X.rotation()) for X in X_WB])
    run = SampledRun(np.array([0.0, 0.035]), quad, vehicle, np.full((2, 5, 7), np.nan), {}, {}, {}, {})
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, s.platform)
    p_CM, q_CP = true_marker_poses_C(truth, s.platform.markers, s.estimation.X_BC)
    for k in range(2):
        X_CP = X_WB[k].multiply(s.estimation.X_BC).InvertAndCompose(s.platform.X_WP(vehicle[k]))
        np.testing.assert_allclose(p_CM[k], X_CP.multiply(s.platform.markers.p_PM.T).T, atol=1e-12)
        assert abs(abs(np.dot(q_CP[k], X_CP.rotation().ToQuaternion().wxyz())) - 1) < 1e-12


def test_the_pad_heading_is_unwrapped_across_180_deg():
    """The vehicle headed 3.0 rad, then -3.0 rad (turned on by 2 pi - 6 = 0.28 rad through 180 deg): the pad's
    yaw goes on to 2 pi - 3.0 rad, not back by 6 rad."""
    s = scenario()
    vehicle = np.array([[0.0, 0.5, 3.0, 0.0], [-0.1, 0.5, -3.0, 0.0]])
    quad = np.array([quadrotor_state(p_WB=[0.0, 0.5, 5.0])] * 2)
    np.testing.assert_allclose(pad_truth(quad, vehicle, s.platform).yaw, [3.0, 2 * np.pi - 3.0], atol=1e-12)


def test_a_markers_stream_accuracy_is_over_its_measured_steps_whatever_its_quaternions_sign():
    """Markers 0 and 1 measured on the first of two steps only, their attitude the truth's (Drake's X_CP = X_CB X_BW
    X_WP), marker 0's as Drake's quaternion and 0.1 m off along the camera's x, marker 1's exact as the negated
    quaternion (the same rotation): each measured on half the steps, marker 0's RMS position error 0.1 m (over that
    step, not both), no attitude error either sign; the markers never measured have no figures."""
    s = scenario()
    X_WB = [RigidTransform(RollPitchYaw(0.1, -0.05, 0.4), [1, 2, 5]),
            RigidTransform(RollPitchYaw(0, 0.2, -1), [0, 1, 3])]
    vehicle = np.array([[0.0, 0.5, 0.3, 0.0], [-1.0, 0.2, -2.0, 0.1]])
    quad = np.array([quadrotor_state(p_WB=X.translation(), R_WB=X.rotation()) for X in X_WB])
    n = len(s.platform.markers.p_PM)
    measurements = np.full((2, n, 7), np.nan)
    X_CP = X_WB[0].multiply(s.estimation.X_BC).InvertAndCompose(s.platform.X_WP(vehicle[0]))
    w, x, y, z = X_CP.rotation().ToQuaternion().wxyz()
    p_CM = X_CP.multiply(s.platform.markers.p_PM[:2].T).T
    measurements[0, 0] = [*(p_CM[0] + [0.1, 0.0, 0.0]), x, y, z, w]  # the paper's [x, y, z, w]
    measurements[0, 1] = [*p_CM[1], -x, -y, -z, -w]
    run = SampledRun(np.array([0.0, 0.035]), quad, vehicle, measurements, {}, {}, {}, {})
    m = measurement_metrics(run, pad_truth(quad, vehicle, s.platform), s.platform.markers, s.estimation.X_BC)
    assert m["measured_fraction"] == [0.5, 0.5] + [0.0] * (n - 2)
    np.testing.assert_allclose(m["rms_position_m"][:2], [0.1, 0.0], atol=1e-9)
    np.testing.assert_allclose(m["rms_attitude_deg"][:2], 0.0, atol=1e-5)
    assert m["rms_position_m"][2:] == m["rms_attitude_deg"][2:] == [None] * (n - 2)


def test_a_filters_heading_error_wraps_and_its_largest_position_error_is_3d():
    """ct_ekf's estimate at 179 deg of a pad headed -179 deg is 2 deg off (not 358); its position off by
    (0.03, 0.04, 0.12) m on one step and (0.01, 0, 0) on the other: the largest error is 0.13 m, in 3-D; 0.07 s of
    compute over the two steps is 35 ms per frame."""
    from systems.estimators.marker_ekf.engine import EST_P_WP, EST_Q_WP, EST_VALID, EST_YAW
    s = scenario()
    vehicle = np.array([[0.0, 0.5, np.radians(-179.0), 0.0]] * 2)
    quad = np.array([quadrotor_state(p_WB=[0.0, 0.5, 5.0])] * 2)
    run = SampledRun(np.array([0.0, 0.035]), quad, vehicle, np.full((2, 5, 7), np.nan), {}, {}, {}, {})
    truth = pad_truth(quad, vehicle, s.platform)
    estimate = np.zeros((2, ESTIMATE_VECTOR_SIZE))
    estimate[:, EST_VALID], estimate[:, EST_YAW] = 1.0, np.radians(179.0)
    estimate[:, EST_P_WP] = truth.p_WP + [[0.03, 0.04, 0.12], [0.01, 0.0, 0.0]]
    estimate[:, EST_Q_WP] = RollPitchYaw(0.0, 0.0, np.radians(179.0)).ToQuaternion().wxyz()
    n = len(s.platform.markers.p_PM)
    run.estimates, run.p_WM = {"ct_ekf": estimate}, {"ct_ekf": np.zeros((2, n, 3))}
    run.stats, run.compute_s = {"ct_ekf": {}}, {"ct_ekf": 0.07}
    _, metrics, errors = marker_metrics(run, s.platform, s.estimation.X_BC, 0.0)
    np.testing.assert_allclose(np.degrees(errors["ct_ekf"].heading), -2.0)
    assert metrics["ct_ekf"]["rms_heading_deg"] == pytest.approx(2.0)
    assert metrics["ct_ekf"]["max_position_m"] == pytest.approx(0.13)
    assert metrics["ct_ekf"]["per_frame_ms"] == pytest.approx(35.0)


def test_a_filters_figures_leave_out_the_estimates_it_flags_invalid():
    """Seed 002's figures are over the valid estimates only: steps 1 and 3, flagged invalid, are 10 m, 90 deg and
    10 m per marker off, and change none of them; the valid steps 0 and 2 are off by (0.03, 0.04, 0.12) m and
    (0.05, 0, 0) m, +1 and -3 deg, and each marker j by 0.01 (j + 1) m along x and 0.02 (j + 1) m along y."""
    from diagrams.marker_metrics import true_marker_positions
    from systems.estimators.marker_ekf.engine import EST_P_WP, EST_Q_WP, EST_VALID, EST_YAW
    s = scenario()
    k = 4
    vehicle = np.array([[2.0, 0.5, np.radians(30.0), 0.0]] * k)
    quad = np.array([quadrotor_state(p_WB=[2.0, 0.5, 5.0])] * k)
    run = SampledRun(np.arange(k) * 0.035, quad, vehicle, np.full((k, 5, 7), np.nan), {}, {}, {}, {})
    truth = pad_truth(quad, vehicle, s.platform)
    yaw_error = np.radians([1.0, 90.0, -3.0, 90.0])
    estimate = np.zeros((k, ESTIMATE_VECTOR_SIZE))
    estimate[:, EST_VALID] = [1.0, 0.0, 1.0, 0.0]
    estimate[:, EST_YAW] = truth.yaw + yaw_error
    estimate[:, EST_P_WP] = truth.p_WP + [[0.03, 0.04, 0.12], [10.0, 0.0, 0.0], [0.05, 0.0, 0.0], [10.0, 0.0, 0.0]]
    estimate[:, EST_Q_WP] = [RollPitchYaw(0.0, 0.0, y).ToQuaternion().wxyz() for y in estimate[:, EST_YAW]]
    n = len(s.platform.markers.p_PM)
    scale = np.arange(1, n + 1)[:, None]
    p_WM = true_marker_positions(truth, s.platform.markers)
    p_WM[0] += scale * [0.01, 0.0, 0.0]
    p_WM[2] += scale * [0.0, 0.02, 0.0]
    p_WM[[1, 3]] += [10.0, 0.0, 0.0]
    run.estimates, run.p_WM = {"ct_ekf": estimate}, {"ct_ekf": p_WM}
    run.stats, run.compute_s = {"ct_ekf": {}}, {"ct_ekf": 0.0}
    _, metrics, _ = marker_metrics(run, s.platform, s.estimation.X_BC, 0.0)
    m = metrics["ct_ekf"]
    assert m["frames_scored"] == 2
    assert m["rms_position_m"] == pytest.approx(np.sqrt((0.13**2 + 0.05**2) / 2))
    assert m["max_position_m"] == pytest.approx(0.13)
    assert m["rms_heading_deg"] == pytest.approx(np.sqrt((1.0 + 9.0) / 2))
    np.testing.assert_allclose(m["rms_marker_position_m"], np.arange(1, n + 1) * np.sqrt((0.01**2 + 0.02**2) / 2))


def test_synthetic_measurements_have_the_papers_accuracy():
    s = scenario(6, 0, "duration_s=20")  # 572 samples of 5 markers: the RMS to about 2 %
    run = batch_run(s, s.run_length_s)
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, s.platform)
    m = measurement_metrics(run, truth, s.platform.markers, s.estimation.X_BC)
    assert m["measured_fraction"] == [1.0] * 5
    # 0.1 m on each of 3 axes, 5 deg on each of 3 axes of a rotation vector
    np.testing.assert_allclose(m["rms_position_m"], 0.1 * np.sqrt(3), rtol=0.08)
    np.testing.assert_allclose(m["rms_attitude_deg"], 5.0 * np.sqrt(3), rtol=0.08)


@pytest.fixture(scope="module")
def detector_run():
    """4 s at 3 m/s with the camera: the pad is in view, leaves it (0.3-1.2 s) and returns."""
    s = scenario(3, 0, "estimation.source=detector")
    diagram, handles = build_gv_landing(s)
    return s, fly_diagram(diagram, handles, s.run_length_s).sampled


@pytest.mark.slow
def test_detector_measures_the_markers_the_camera_renders(detector_run):
    s, run = detector_run
    layout, X_BC = s.platform.markers, s.estimation.X_BC
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, s.platform)
    m = measurement_metrics(run, truth, layout, X_BC)
    assert min(m["measured_fraction"]) > 0.5  # from 8 m up, the UAV hovering behind the vehicle
    assert max(m["rms_position_m"]) < 0.2  # m, 14-24 px markers 8 m away
    p_CM, q_CP = true_marker_poses_C(truth, layout, X_BC)
    measured, q_CM = run.measurements[..., :3], run.measurements[..., 3:]
    seen = ~np.isnan(measured[..., 0])
    # The rendered texture, the camera mount and the intrinsics agree with the layout: bearings to a
    # fraction of a pixel, ranges to a few per cent, and each marker's heading about the optical axis.
    bearing = (measured[..., :2] / measured[..., 2:] - p_CM[..., :2] / p_CM[..., 2:])[seen]
    assert np.sqrt(np.mean(np.sum(bearing**2, axis=1))) < 1.0 / s.estimation.camera.fx
    ratio = np.linalg.norm(measured[seen], axis=1) / np.linalg.norm(p_CM[seen], axis=1)
    assert abs(np.mean(ratio) - 1) < 0.03
    for k, i in zip(*np.nonzero(seen)):
        R_error = Quaternion(q_CP[k]).rotation().T @ Quaternion(np.r_[q_CM[k, i, 3], q_CM[k, i, :3]]).rotation()
        assert abs(np.degrees(np.arctan2(R_error[1, 0], R_error[0, 0]))) < 5.0
    # The pad leaves the 58 deg view while the UAV catches up: those frames measure nothing, and the
    # filters get nothing new one period later.
    blind = ~seen.any(axis=1)
    assert 10 < blind.sum() < len(run.t) / 2
    k = int(np.argmax(blind))
    assert run.estimates["ct_ekf"][k + 1, EST_LAST_MEASUREMENT] < run.t[k] - 1e-9


@pytest.mark.slow
def test_filters_track_the_pad_on_the_detector_stream(detector_run):
    s, run = detector_run
    _, metrics, _ = marker_metrics(run, s.platform, s.estimation.X_BC, s.estimation.settle_s)
    for name in ("paper_ekf", "ct_ekf"):
        m = metrics[name]
        assert m["rms_position_m"] < 0.1 and m["rms_heading_deg"] < 1.0
        assert m["frames_scored"] > 40 and m["measurements"]["invalid"] == 0


def test_video_needs_the_camera(capfd, tmp_path):
    out = tmp_path / "video"
    code = main(["run", "gv-marker-ekf", "--set", "duration_s=3", "--video", "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and "estimation.source=detector" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_meshcat_records_the_flight_and_shows_the_estimates():
    sizes = []
    for duration in (1.0, 3.0):
        meshcat = Meshcat()
        s = scenario(6)
        diagram, handles = build_gv_landing(s, meshcat)
        fly_diagram(diagram, handles, duration, record=True)
        sizes.append(len(meshcat.StaticHtml()))
    assert sizes[1] > sizes[0] + 10_000  # the recording holds the whole flight, not its last frame
    for name in ("paper_ekf", "ct_ekf"):
        assert meshcat.HasPath(f"gv_landing/{name}_pad_path")


def test_a_trail_leaves_out_flagged_and_non_finite_estimates():
    """MeshcatTrail draws its line only through samples with a finite position and, given valid_index, the
    valid flag set: fed only estimates the filter flags, or only NaN positions, it draws nothing."""
    meshcat = Meshcat(params=MeshcatParams(host="localhost"))
    for path, position, drawn in (("/valid", [1.0, 2.0, 3.0, 1.0], True), ("/flagged", [1.0, 2.0, 3.0, 0.0], False),
                                  ("/nan", [np.nan, 2.0, 3.0, 1.0], False)):
        trail = MeshcatTrail(meshcat, path, size=4, valid_index=3)
        simulator = Simulator(trail)
        trail.get_input_port().FixValue(simulator.get_mutable_context(), position)
        simulator.AdvanceTo(0.5)  # six samples at 10 Hz
        assert meshcat.HasPath(path) == drawn, path


def test_a_trail_needs_two_samples_and_starts_afresh_when_re_initialised():
    """One sample (at t = 0, 10 Hz) is no line: nothing is drawn. A trail run for 0.5 s and then initialised
    again (a new Simulator) forgets its samples: its first new sample alone draws nothing either."""
    meshcat = Meshcat(params=MeshcatParams(host="localhost"))
    trail = MeshcatTrail(meshcat, "/trail")
    simulator = Simulator(trail)
    trail.get_input_port().FixValue(simulator.get_mutable_context(), [1.0, 2.0, 3.0])
    simulator.AdvanceTo(0.05)
    assert not meshcat.HasPath("/trail")
    simulator.AdvanceTo(0.5)
    assert meshcat.HasPath("/trail")
    again = Simulator(trail)
    trail.get_input_port().FixValue(again.get_mutable_context(), [1.0, 2.0, 3.0])
    again.AdvanceTo(0.05)
    assert not meshcat.HasPath("/trail")


def campaign(tmp_path, workers, runs=2, speeds=("3", "12")):
    definition = campaign_definition("gv-marker-ekf")
    settings = campaign_settings(definition, "gv-marker-ekf", speeds, runs, overrides=SHORT)
    return run_campaign(definition, settings, tmp_path / f"mc{workers}", workers=workers, progress=False)


@pytest.mark.slow
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


@pytest.mark.slow
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
    (["--set", "duration_s=2", "--set", "estimation.settle_s=10"], r"estimation.settle_s (10 s) must be below"),
    (["--runs", "1", "--speeds", "12", "--set", "duration_s=1", "--set", "estimation.settle_s=0",
      "--set", "estimation.ekf.max_quaternion_norm_error=1"], "ekf.max_quaternion_norm_error must be in (0, 1)"),
])
def test_bad_campaign_settings_are_one_line(capfd, tmp_path, args, message):
    out = tmp_path / "bad"
    code = main(["montecarlo", "gv-marker-ekf", *args, "--out", str(out)])
    _, err = capfd.readouterr()
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_camera_faster_than_the_filter_is_refused_as_a_slower_one_is():
    """One frame per filter step: a camera at twice the filter's rate is refused as one at half of it is (the
    periods' difference checked both ways)."""
    period = scenario().estimation.ekf.period_s
    for rate, filter_rate in ((2 / period, 1 / period), (0.5 / period, 1 / period)):
        with pytest.raises(ConfigError, match=rf"^estimation\.camera\.rate_hz \({rate:g}\) must be 1 / "
                                              rf"estimation\.ekf\.period_s \({filter_rate:g} Hz\)"):
            scenario(12, 0, f"estimation.camera.rate_hz={rate!r}")


def test_scenario_defaults_are_the_papers_setup():
    """Without a scenario file: the UAV starts at seed 002's r_0 = (0, 0, 10) m, duration_s 0 (500 m of driving),
    and the paper's synthetic stream feeds the paper's EKF and the constant-turn EKF."""
    s = Scenario()
    assert s.start.xy_m == [0.0, 0.0] and s.start.height_m == 10.0
    assert s.duration_s == 0.0 and s.run_length_s == pytest.approx(LONG_WAVE_M / s.vehicle.speed)
    assert s.estimation.source == "synthetic" and s.estimation.filters == ["paper_ekf", "ct_ekf"]
    assert s.diagram == "gv_marker_ekf"


def test_bad_scenario_values():
    with pytest.raises(ConfigError, match="estimation.filters"):
        scenario(12, 0, "estimation.filters=[nope]")
    with pytest.raises(ConfigError, match="vehicle.speed"):
        scenario(0)
    with pytest.raises(ConfigError, match="estimation.source 'camera' is not one of: none, synthetic, detector"):
        scenario(12, 0, "estimation.source=camera")
    with pytest.raises(ConfigError, match=r"estimation.camera.rate_hz \(20\) must be 1 / estimation.ekf.period_s"):
        scenario(12, 0, "estimation.camera.rate_hz=20")
    with pytest.raises(ConfigError, match=r"estimation.ekf.history_s \(0.03 s\) must be at least the stream's "
                                          r"latency, estimation.latency_periods x the filter step \(0.035 s\)"):
        scenario(12, 0, "estimation.ekf.history_s=0.03")
    for stream in (["estimation.source=none", "estimation.filters=[]"], ["estimation.filters=[]"]):
        with pytest.raises(ConfigError, match="gv-marker-ekf needs a measurement stream"):
            scenario(12, 0, *stream)
    # The UAV starts at 10 m (the scenario file's start): the pad and the hold height must be below it (a start
    # 20 m to the side: a pad at 10 m would have the UAV start inside the vehicle's body, refused before).
    assert scenario(12, 0).start.height_m == 10.0
    for below in ("landing.initial_height_m=12", "landing.initial_height_m=10", "platform.height_m=10",
                  "platform.height_m=11"):
        with pytest.raises(ConfigError, match=r"landing.initial_height_m must be below start.height_m \(10.0 m\)"):
            scenario(12, 0, below, "start.xy_m=[0.0, 20.0]")
    with pytest.raises(ConfigError, match=r"vehicle.speed_schedule_\* is not used by gv-marker-ekf"):
        scenario(12, 0, "vehicle.speed_schedule_times_s=[0.0, 2.0]", "vehicle.speed_schedule_m_s=[12.0, 6.0]")
    # nothing would be scored: settle_s at or past the run's length (duration_s, or 500 m of driving)
    for settle, duration in ((4, 4), (42, 0)):
        with pytest.raises(ConfigError, match=rf"estimation.settle_s \({settle} s\) must be below the run's length"):
            scenario(12, 0, f"estimation.settle_s={settle}", f"duration_s={duration}")
    assert scenario(12, 0, "estimation.settle_s=3.9").estimation.settle_s == 3.9
    # the camera covered longer than the run (duration_s, or 500 m of driving): nothing would be measured
    for duration, occlusion in ((4, 5), (0, 42)):
        with pytest.raises(ConfigError, match=rf"faults: an occlusion of {occlusion} s is longer than the run"):
            scenario(12, 0, f"duration_s={duration}", f"faults.occlusions_s=[[0.0, {occlusion}.0]]")


def _figures(metrics: dict, prefix: str = "") -> dict:
    """The metrics' figures by path, without the timings (which depend on the machine)."""
    out = {}
    for key, value in metrics.items():
        if key in ("estimation_wall_time_s", "per_frame_ms"):
            continue
        out.update(_figures(value, f"{prefix}{key}/") if isinstance(value, dict) else {f"{prefix}{key}": value})
    return out


def _assert_same_figures(metrics: dict, expected: dict) -> None:
    """Every figure of `expected` in `metrics` to 1e-9 (None, an axis a filter does not estimate, where
    expected has it); names equal."""
    figures, expected = _figures(metrics), _figures(expected)
    assert set(figures) == set(expected)
    for key, value in expected.items():
        if isinstance(value, str) or key.endswith("attitude_axes"):
            assert figures[key] == value, key
        else:
            np.testing.assert_allclose(np.array(figures[key], dtype=float), np.array(value, dtype=float), rtol=0,
                                       atol=1e-9, err_msg=key)


def test_a_group_of_runs_gives_each_runs_own_output():
    from diagrams.gv_marker_ekf_mc import CAMPAIGN, run_group, run_task

    s = campaign_settings(CAMPAIGN, "gv-marker-ekf", cases=["12"], runs=3, overrides=["duration_s=4"])
    tasks = s.tasks(CAMPAIGN.case_key)
    for task, grouped in zip(tasks, run_group(tasks), strict=True):
        alone = run_task(task)
        assert set(grouped.arrays) == set(alone.arrays)
        for key in alone.arrays:
            np.testing.assert_allclose(grouped.arrays[key], alone.arrays[key], rtol=1e-6, atol=1e-6)
        assert grouped.metrics["seed"] == task.seed
        _assert_same_figures(grouped.metrics, alone.metrics)


@pytest.mark.parametrize("override", ["navigation.source=gnss_ins", "faults.drop_probability=0.5"])
def test_a_campaign_run_the_batch_path_cannot_replay_is_the_diagrams(override):
    # the filters read the navigation's X_WB, or the stream has faults: each run flies the Diagram
    from diagrams.gv_marker_ekf_mc import CAMPAIGN, run_group

    s = campaign_settings(CAMPAIGN, "gv-marker-ekf", cases=["12"], runs=2,
                          overrides=["duration_s=2.5", "estimation.settle_s=1", override])
    tasks = s.tasks(CAMPAIGN.case_key)
    for task, output in zip(tasks, run_group(tasks), strict=True):
        config = task.load_scenario()[1]
        run = fly_diagram(*build_gv_landing(config), config.run_length_s).sampled
        _, expected, _ = marker_metrics(run, config.platform, config.estimation.X_BC, config.estimation.settle_s)
        assert output.metrics["seed"] == task.seed
        _assert_same_figures(output.metrics["estimators"], expected)


def test_a_groups_wall_time_is_shared_equally_among_its_runs(monkeypatch):
    """batch_runs stepping a group of two runs' filters for 10 s (on a stand-in clock that only it advances):
    each run's estimation_wall_time_s is 10 s / 2."""
    import diagrams.gv_marker_ekf_mc as mc
    import diagrams.marker_batch as marker_batch
    from diagrams.gv_marker_ekf_mc import CAMPAIGN, run_group

    clock = [100.0]
    monkeypatch.setattr(mc, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    batch_runs = marker_batch.batch_runs

    def ten_seconds(*args):
        clock[0] += 10.0
        return batch_runs(*args)

    monkeypatch.setattr(marker_batch, "batch_runs", ten_seconds)
    s = campaign_settings(CAMPAIGN, "gv-marker-ekf", cases=["12"], runs=2, overrides=SHORT)
    outputs = run_group(s.tasks(CAMPAIGN.case_key))
    assert [o.metrics["estimation_wall_time_s"] for o in outputs] == [5.0, 5.0]


def test_a_runs_output_keeps_every_decimate_th_step_from_the_first_and_ends_at_its_last():
    from diagrams.gv_marker_ekf_mc import DECIMATE, _output, sampled

    s = scenario(12, 3)
    run = sampled(s)
    output = _output(s, run, 0.0)
    np.testing.assert_array_equal(output.arrays["t"], run.t[::DECIMATE].astype(np.float32))
    assert output.arrays["t"][0] == run.t[0] and len(output.arrays["t"]) == (len(run.t) + DECIMATE - 1) // DECIMATE
    assert output.metrics["sim_time_s"] == run.t[-1] == pytest.approx(4.0, abs=0.2)  # duration_s 4


def test_campaign_rms_is_over_every_scored_step_of_every_run():
    from diagrams.gv_marker_ekf_mc import _output, aggregate, sampled

    # two runs scoring very different numbers of steps: from 0.5 s and from 3.5 s of 4 s
    records, steps = [], {}
    for seed, settle in ((1, 0.5), (2, 3.5)):
        s = scenario(12, seed, f"estimation.settle_s={settle}")
        run = sampled(s)
        output = _output(s, run, 0.0)
        records.append(SimpleNamespace(metrics=output.metrics, arrays=lambda output=output: output.arrays))
        for name, e in marker_metrics(run, s.platform, s.estimation.X_BC, settle)[2].items():
            scored = e.valid & (run.t >= settle)
            steps.setdefault(name, []).append((e.position[scored], e.heading[scored], e.markers[scored]))
    summary = aggregate({"12": records})
    for name, runs in steps.items():
        position, heading, markers = (np.concatenate(part) for part in zip(*runs))
        figures = summary[name]["12"]
        assert figures["runs"] == 2 and len(runs[0][0]) > 5 * len(runs[1][0])
        assert figures["rms_position_m"] == pytest.approx(np.sqrt(np.mean(np.sum(position**2, axis=1))), rel=1e-9)
        assert figures["rms_position_xy_m"] == pytest.approx(np.sqrt(np.mean(np.sum(position[:, :2] ** 2, axis=1))),
                                                             rel=1e-9)
        assert figures["rms_heading_deg"] == pytest.approx(np.degrees(np.sqrt(np.mean(heading**2))), rel=1e-9)
        np.testing.assert_allclose(figures["rms_marker_position_m"], np.sqrt(np.mean(markers**2, axis=0)), rtol=1e-9)


def _ensemble_record(t, true_xy, true_yaw, xy, yaw, marker_error, measurements, per_frame_ms=1.0,
                     measured_fraction=(1.0,) * 5):
    """A campaign record of one filter "f" holding the given decimated arrays (as `_output` keeps them: NaN
    where the filter flags its estimate), measurement counts, time per frame and measured fraction per marker."""
    arrays = dict(t=t, true_xy=true_xy, true_yaw=true_yaw, f_xy=xy, f_yaw=yaw, f_marker_error=marker_error)
    arrays = {k: np.asarray(v, dtype=np.float32) for k, v in arrays.items()}
    m = {"rms_position_m": 1.0, "rms_heading_deg": 1.0, "rms_position_xy_m": 1.0, "rms_marker_position_m": [1.0] * 5,
         "frames_scored": len(t), "per_frame_ms": per_frame_ms, "measurements": measurements}
    return SimpleNamespace(metrics={"settle_s": 1.0, "estimators": {"f": m},
                                    "measurements": {"measured_fraction": list(measured_fraction)}},
                           arrays=lambda: arrays)


def test_ensemble_mean_figures_are_the_error_of_the_mean_estimate_after_settling():
    """summary.json's ensemble_mean_* (the paper's epsilon) on two hand-made runs: the error of the runs' mean
    estimate at each step from settle_s on, its heading a circular mean across +-pi, each step over the runs
    with a valid estimate; the plots' marker error is the RMS over the runs; the counts are summed per kind."""
    from diagrams.gv_marker_ekf_mc import _ensemble, aggregate

    t = np.arange(0.0, 3.0, 0.5)  # settle_s 1.0: steps 2 to 5 are scored
    n = len(t)
    true_xy = np.c_[2.0 * t, np.ones(n)]
    true_yaw = np.angle(np.exp(1j * (2.8 + 0.15 * np.arange(n))))  # turning left through +-pi at the scored steps
    settling = t < 1.0
    offsets, heading_errors, marker_errors = ((0.2, 0.3), (0.4, 0.5)), (0.1, 0.3), (3.0, 4.0)
    counts = ({"gated": 5, "invalid": 3, "resets": 1}, {"gated": 7, "invalid": 0, "resets": 0})
    records = []
    for (dx, dy), dyaw, dm, counted in zip(offsets, heading_errors, marker_errors, counts):
        error = np.tile([dx, dy], (n, 1))
        error[settling] *= 10.0  # large while the filters settle: left out
        xy = true_xy + error
        yaw = np.angle(np.exp(1j * (true_yaw + dyaw)))  # wrapped to (-pi, pi] as the filters give it
        records.append([t, true_xy, true_yaw, xy, yaw, np.full((n, 5), dm), counted])
    for part in (3, 4, 5):  # the first run flags its estimate at the last step
        records[0][part] = np.array(records[0][part], dtype=float)
        records[0][part][-1] = np.nan
    frame_ms, fractions = (2.0, 6.0), ((0.2, 0.4, 0.6, 0.8, 1.0), (0.4, 0.4, 0.0, 1.0, 0.5))
    records = [_ensemble_record(*r, ms, f) for r, ms, f in zip(records, frame_ms, fractions)]
    summary = aggregate({"6": records, "12": []})  # a case with no run ended has no figures
    assert list(summary) == ["f"] and list(summary["f"]) == ["6"]
    out = summary["f"]["6"]
    assert out["per_frame_ms"] == pytest.approx(4.0)  # the mean over the runs of 2 and 6 ms
    assert out["measured_fraction"] == pytest.approx([0.3, 0.4, 0.3, 0.9, 0.75])  # per marker, over the runs
    # Scored steps 2-4: mean offset (0.3, 0.4), 0.5 m, and mean heading error 0.2 rad (the circular mean of
    # 0.1 and 0.3); step 5, the second run alone: (0.4, 0.5) and 0.3 rad.
    assert out["ensemble_mean_position_xy_m"] == pytest.approx(np.sqrt((3 * 0.5**2 + 0.4**2 + 0.5**2) / 4), rel=1e-6)
    assert out["ensemble_mean_heading_deg"] == pytest.approx(np.degrees(np.sqrt((3 * 0.2**2 + 0.3**2) / 4)),
                                                             rel=1e-5)
    assert (out["runs"], out["gated"], out["invalid"], out["resets"]) == (2, 12, 3, 1)
    markers = _ensemble(records, "f")[5]
    np.testing.assert_allclose(markers[:-1], np.sqrt((3.0**2 + 4.0**2) / 2), rtol=1e-6)  # RMS of 3 and 4: 3.54
    np.testing.assert_allclose(markers[-1], 4.0, rtol=1e-6)


@pytest.mark.parametrize("path, label", [("sine", "reference (Eq. 13)"), ("circle", "reference (circle)")])
def test_the_path_plot_names_the_vehicles_reference_path(path, label):
    reference = np.c_[np.arange(30.0), np.zeros(30)]
    true_xy = np.c_[np.arange(5.0), 5.0 + np.arange(5.0)]  # reaching x = 4 m (and y = 9 m)
    fig, ax = plt.subplots()
    marker_plots.plot_path(ax, reference, true_xy, {}, "title", path)
    assert ax.get_legend().get_texts()[0].get_text() == label
    # The reference is drawn up to 10 m past the farthest x the pad reached (x, not y).
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), np.arange(15.0))
    plt.close(fig)


def test_the_heading_plot_wraps_the_truth_the_estimates_and_their_errors_to_plus_minus_180_deg():
    """The truth at 4 rad, one estimate 0.1 rad past it unwrapped (4.1 rad) and one wrapped (4.1 - 2 pi): each drawn
    in [-180, 180) deg, and both errors 0.1 rad (5.73 deg), not 0.1 - 2 pi."""
    fig, axes = plt.subplots(2, 1)
    wrapped = 4.1 - 2 * np.pi
    marker_plots.plot_heading(axes, np.array([0.0, 1.0]), np.array([0.0, 4.0]),
                              {"paper_ekf": np.array([0.1, 4.1]), "ct_ekf": np.array([0.1, wrapped])}, "title")
    truth, *estimates = axes[0].lines
    np.testing.assert_allclose(truth.get_ydata(), np.degrees([0.0, 4.0 - 2 * np.pi]))
    assert len(estimates) == len(axes[1].lines) == 2
    for estimate, error in zip(estimates, axes[1].lines):
        np.testing.assert_allclose(estimate.get_ydata(), np.degrees([0.1, wrapped]))
        np.testing.assert_allclose(error.get_ydata(), np.degrees([0.1, 0.1]))
    plt.close(fig)


def test_run_plots_leave_out_the_estimates_the_filters_flag(monkeypatch, tmp_path):
    # the camera covered from 1 to 3 s: the filters coast and flag their estimates once the pad's
    # position std passes 0.3 m
    s = scenario(6, 1, "faults.occlusions_s=[[1.0, 3.0]]", "estimation.ekf.max_valid_position_std_m=0.3")
    run = fly_diagram(*build_gv_landing(s), s.run_length_s).sampled
    _, _, errors = marker_metrics(run, s.platform, s.estimation.X_BC, s.estimation.settle_s)
    figures = {}
    monkeypatch.setattr(marker_plots, "save_figure", lambda fig, path: figures.__setitem__(path.name, fig))
    marker_plots.plot_run(s, run, errors, tmp_path)
    for i, (name, e) in enumerate(errors.items()):
        flagged = ~e.valid & ~np.isnan(run.estimates[name][:, 1])  # started, and flagged
        assert flagged.sum() > 10 and e.valid.sum() > 10
        path = next(line for line in figures["path.png"].axes[0].lines
                    if marker_plots.style(name)[1] in line.get_label())
        drawn = {"path": np.asarray(path.get_ydata(), dtype=float),
                 "heading": np.asarray(figures["heading.png"].axes[0].lines[1 + i].get_ydata(), dtype=float),
                 "marker 0": np.asarray(figures["marker_errors.png"].axes[i].lines[0].get_ydata(), dtype=float)}
        for what, y in drawn.items():
            assert np.all(np.isnan(y[flagged])) and np.all(np.isfinite(y[e.valid])), (name, what)
        # The path drawn is the estimate's x and y (not y and z).
        np.testing.assert_allclose(path.get_xydata()[e.valid], run.estimates[name][e.valid][:, EST_P_WP][:, :2])
        # On the valid rows each line is the error it names: the heading error in degrees, marker j's own error.
        error = figures["heading.png"].axes[1].lines[i].get_ydata()
        np.testing.assert_allclose(error[e.valid], np.degrees(e.heading[e.valid]), atol=1e-9)
        for j, line in enumerate(figures["marker_errors.png"].axes[i].lines):
            np.testing.assert_allclose(line.get_ydata()[e.valid], e.markers[e.valid, j])
        assert len(figures["marker_errors.png"].axes[i].lines) == e.markers.shape[1]
    # The truth drawn is the pad's (from the vehicle's state): its path in x, y and its heading.
    truth = pad_truth(run.quadrotor_state, run.vehicle_state, s.platform)
    true_path = next(line for line in figures["path.png"].axes[0].lines if line.get_label() == "true (pad P)")
    np.testing.assert_allclose(true_path.get_xydata(), truth.p_WP[:, :2])
    heading = figures["heading.png"].axes[0].lines[0]
    assert heading.get_label() == "true"
    np.testing.assert_allclose(heading.get_ydata(), np.degrees(np.angle(np.exp(1j * truth.yaw))), atol=1e-9)
    # The titles give the speed the vehicle drove: under a schedule its range (before: vehicle.speed, 6 m/s).
    scheduled = dataclasses.replace(s, vehicle=dataclasses.replace(s.vehicle, speed_schedule_times_s=[0.0, 5.0],
                                                                   speed_schedule_m_s=[0.0, 12.0]))
    marker_plots.plot_run(scheduled, run, errors, tmp_path)
    for name in ("path.png", "heading.png", "marker_errors.png"):
        title = figures[name].axes[0].get_title()
        assert "0-12 m/s scheduled" in title and "6 m/s" not in title, (name, title)
