"""The stewart-dynamic scenario's diagram simulated for 2 s: logs, detection and ground truth."""

import math
import re

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from scipy.spatial.transform import Rotation

from diagrams.stewart_run import scene_metrics
from diagrams.stewart_scene import HoverConfig, StewartSceneConfig, build_stewart_scene, hover_pose
from systems.estimators.pad_calibration import CalibrationError
from systems.platforms.stewart import StewartPlatform
from systems.sensors.tof import TofConfig

AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def deck_offset_by_hand(platform, t: float) -> np.ndarray:
    """The sinusoid offsets [x, y, z (m), roll, pitch, yaw (deg)] of the scenario at time t."""
    offset = []
    for axis in AXES:
        unit = "m" if axis in "xyz" else "deg"
        amplitudes = getattr(platform, f"{axis}_amplitude_{unit}")
        frequencies = getattr(platform, f"{axis}_frequency_hz")
        phases = getattr(platform, f"{axis}_phase_deg") or [0.0] * len(amplitudes)
        offset.append(sum(a * math.sin(2 * math.pi * f * t + math.radians(p))
                          for a, f, p in zip(amplitudes, frequencies, phases)))
    return np.array(offset)


def X_WP_by_hand(scene, t: float) -> RigidTransform:
    p = scene.config.platform
    offset = deck_offset_by_hand(p, t)
    R = Rotation.from_euler("xyz", offset[3:], degrees=True).as_matrix()
    return RigidTransform(RotationMatrix(R), [offset[0], offset[1], scene.nominal_deck_z() + offset[2]])


def pose_of(row) -> RigidTransform:
    return RigidTransform(Quaternion(row[3:] / np.linalg.norm(row[3:])), row[:3])


def test_the_scenario_is_the_moving_deck(dynamic_run):
    scene, _, _ = dynamic_run
    assert scene.config.platform.motion == "sinusoid"
    assert scene.config.duration_s == 2.0
    # Over the 2 s the deck moves by more than the 1 mm and 0.1 deg the pose checks below resolve.
    change = deck_offset_by_hand(scene.config.platform, 2.0) - deck_offset_by_hand(scene.config.platform, 0.0)
    assert np.max(np.abs(change[:3])) > 0.005 and np.max(np.abs(change[3:])) > 1.0


def test_logs_have_one_row_per_camera_frame(dynamic_run):
    scene, _, log = dynamic_run
    assert scene.config.camera.rate_hz == 20.0
    np.testing.assert_allclose(log["t"], np.arange(41) * 0.05, atol=1e-9)
    camera_rate_logs = [name for name in scene.handles.loggers if name != "imu"]
    assert {"X_CP", "ranges", "ranges_valid", "true_ranges", "tag_corners", "leg_lengths",
            "stroke_exceeded"} <= set(camera_rate_logs)
    for name in camera_rate_logs + ["true_tag_corners"]:
        assert log[name].shape[0] == 41, name
    assert log["X_CP"].shape[1] == 7 and log["tag_corners"].shape[1] == 8 and log["leg_lengths"].shape[1] == 6
    # The IMU logs at its own 200 Hz: each sample taken in the 2 s, the one due at 2 s not yet.
    np.testing.assert_allclose(log["t_imu"], np.arange(400) * 0.005, atol=1e-9)
    assert log["imu"].shape == (400, 6)


def test_the_tag_is_detected_in_every_frame_near_its_true_corners(dynamic_run):
    _, _, log = dynamic_run
    assert np.all(np.isfinite(log["tag_corners"]))
    error = np.linalg.norm((log["tag_corners"] - log["true_tag_corners"]).reshape(-1, 4, 2), axis=2)
    assert error.max() < 1.5, f"worst corner error {error.max():.2f} px"


def test_true_X_CP_is_the_deck_pose_seen_from_the_hovering_camera(dynamic_run):
    scene, _, log = dynamic_run
    X_WC = scene.X_WC()
    for t, row in zip(log["t"], log["X_CP"]):
        X_CP_expected = X_WC.inverse().multiply(X_WP_by_hand(scene, t))
        X_CP = pose_of(row)
        np.testing.assert_allclose(X_CP.translation(), X_CP_expected.translation(), atol=1e-9)
        assert X_CP.rotation().InvertAndCompose(X_CP_expected.rotation()).ToAngleAxis().angle() < 1e-9


def test_the_platform_and_hover_pose_agree_with_the_hand_computed_poses(dynamic_run):
    scene, context, _ = dynamic_run
    handles = scene.handles
    t = context.get_time()
    assert t == pytest.approx(2.0)
    X_WP = scene.eval(handles.platform, "X_WP", context)
    np.testing.assert_allclose(X_WP.GetAsMatrix4(), X_WP_by_hand(scene, t).GetAsMatrix4(), atol=1e-12)
    np.testing.assert_allclose(hover_pose(scene.config, handles.platform).GetAsMatrix4(), scene.X_WB().GetAsMatrix4(),
                               atol=1e-12)
    np.testing.assert_allclose(handles.X_BC.GetAsMatrix4(), scene.X_WB().inverse().multiply(scene.X_WC()).GetAsMatrix4(),
                               atol=1e-12)


def test_legs_and_stroke_logs_follow_the_deck(dynamic_run):
    scene, _, log = dynamic_run
    p = scene.config.platform
    assert np.all(log["stroke_exceeded"] == 0.0)
    assert np.all((log["leg_lengths"] > p.leg_min_m) & (log["leg_lengths"] < p.leg_max_m))
    assert np.ptp(log["leg_lengths"], axis=0).min() > 1e-4  # every leg moves


def test_tof_readings_are_valid_and_scatter_about_the_truth(dynamic_run):
    scene, _, log = dynamic_run
    std = scene.config.tof.noise_std_m
    assert std > 0
    np.testing.assert_array_equal(log["ranges_valid"], 1.0)
    error = log["ranges"] - log["true_ranges"]
    assert np.all(np.abs(error) < 5 * std)
    assert 0.6 * std < np.std(error) < 1.4 * std
    # The camera is about 2 m above the deck.
    assert np.all(np.abs(log["true_ranges"] - 2.0) < 0.3)


def test_a_tof_error_is_the_reading_less_the_truth_and_nan_where_invalid():
    """Readings 5 cm long, 3 cm short, flagged invalid (far off) and exact: errors +0.05, -0.03, NaN and 0 m
    (signed: measured less true)."""
    from diagrams.stewart_run import range_errors
    log = {"ranges": np.array([[2.05, 1.97, 9.0, 2.0]]), "true_ranges": np.full((1, 4), 2.0),
           "ranges_valid": np.array([[1.0, 1.0, 0.0, 1.0]])}
    np.testing.assert_allclose(range_errors(log), [[0.05, -0.03, np.nan, 0.0]], atol=1e-12)


def test_the_tof_plot_shows_each_sensors_error_beside_its_range(dynamic_run, tmp_path, monkeypatch):
    from diagrams import stewart_run

    scene, _, log = dynamic_run
    figures = []
    monkeypatch.setattr(stewart_run, "save_figure", lambda fig, path: figures.append((path.name, fig)))
    stewart_run.plot_scene(log, scene.config, tmp_path)
    ranges, errors = np.array(dict(figures)["tof_ranges.png"].axes).reshape(4, 2).T
    for i in range(4):
        valid = log["ranges_valid"][:, i] > 0.5  # invalid readings left out, as the plot's title says
        error_mm = 1e3 * np.where(valid, log["ranges"][:, i] - log["true_ranges"][:, i], np.nan)
        np.testing.assert_allclose(errors[i].get_lines()[0].get_ydata(), error_mm)
        # At 2 m the 4 m maximum range is not drawn: it would squash the readings into a line.
        assert [line.get_label() for line in ranges[i].get_lines()] == ["true", "measured"]


def test_imu_reads_gravity_while_hovering(dynamic_run):
    scene, _, log = dynamic_run
    c = scene.config.imu
    f_std, w_std = c.accel_sample_std_m_s2, c.gyro_sample_std_rad_s
    # Every row is a sample (before: the first was the Imu's initial placeholder, [0, 0, g, 0, 0, 0] without noise).
    error = log["imu"] - [0.0, 0.0, 9.80665, 0.0, 0.0, 0.0]
    assert np.all(np.abs(error[:, :3]) < 6 * f_std) and np.all(np.abs(error[:, 3:]) < 6 * w_std)
    assert np.all(error[:, 3:] != 0.0)
    # The row stamped t_imu[k] is the sample taken at t_imu[k] (before: the sample of t_imu[k - 1]).
    context = scene.context()
    imu_context = scene.handles.imu.GetMyContextFromRoot(context)
    for k in (0, 1, 200, 399):
        context.SetTime(log["t_imu"][k])
        sample = scene.handles.imu.EvalUniquePeriodicDiscreteUpdate(imu_context).get_vector().CopyToVector()
        np.testing.assert_array_equal(log["imu"][k], sample)


def test_the_same_seed_reproduces_the_run_bit_for_bit(dynamic_run):
    from pydrake.systems.analysis import Simulator

    from diagrams.stewart_run import collect_log

    scene, _, log = dynamic_run
    diagram, handles = build_stewart_scene(scene.config)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.5)
    again = collect_log(handles, simulator.get_context(), scene.config)
    n = len(again["t"])
    assert n == 11
    for name in ("ranges", "tag_corners", "X_CP"):
        np.testing.assert_array_equal(again[name], log[name][:n], err_msg=name)
    np.testing.assert_array_equal(again["imu"], log["imu"][:len(again["imu"])])


def test_a_scene_builds_from_the_defaults():
    diagram, handles = build_stewart_scene(StewartSceneConfig())
    assert diagram.get_name() == "stewart_scene"
    assert set(handles.loggers) >= {"X_CP", "ranges", "ranges_valid", "true_ranges", "tag_corners", "imu"}


def test_with_an_exposure_the_image_is_smeared_by_the_deck_s_motion_across_the_axis():
    import copy

    import cv2

    from diagrams.runner import load_scenario
    from systems.sensors.camera import motion_blur_flow

    _, config = load_scenario("stewart-dynamic")
    config = copy.deepcopy(config)
    config.camera.exposure_s = 0.01
    config.hover.offset_xy_m = [0.3, -0.2]  # the axis off the deck's centre: its tilt moves the point too
    diagram, handles = build_stewart_scene(config)
    context = diagram.CreateDefaultContext()
    K, dt = config.camera.K, 1e-4

    def X_CP(t):
        context.SetTime(t)
        return handles.truth.GetOutputPort("X_CP").Eval(handles.truth.GetMyContextFromRoot(context))

    for t in (1.3, 4.6, 9.2):
        X = X_CP(t)
        n_C, p_C = X.rotation().col(2), X.translation()
        p_P = X.inverse().multiply([0.0, 0.0, (n_C @ p_C) / n_C[2]])  # the deck's point on the axis at t
        uv = [cv2.projectPoints(X_CP(t + d).multiply(p_P).reshape(1, 3), np.zeros(3), np.zeros(3), K, None)[0].ravel()
              for d in (-dt, dt)]
        context.SetTime(t)
        flow = handles.noisy_camera.GetInputPort("axis_flow").Eval(handles.noisy_camera.GetMyContextFromRoot(context))
        expected = (uv[1] - uv[0]) / (2 * dt)  # px/s
        assert np.linalg.norm(expected) > 0.5
        np.testing.assert_allclose(motion_blur_flow(K, flow, 1.0), expected, rtol=1e-3, atol=1e-5)


def test_the_estimates_arrive_the_latency_s_frames_late(dynamic_run):
    import copy

    from pydrake.systems.analysis import Simulator

    from diagrams.stewart_run import collect_log

    scene, _, log = dynamic_run
    config = copy.deepcopy(scene.config)
    config.estimate_latency_frames = 2
    diagram, handles = build_stewart_scene(config)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.5)
    late = collect_log(handles, simulator.get_context(), config)
    for name in ("estimate_atda", "estimate_crhf"):
        np.testing.assert_array_equal(late[name][:2, 0], 0.0, err_msg=name)  # nothing due yet: invalid
        np.testing.assert_array_equal(late[name][2:], log[name][:len(late["t"]) - 2], err_msg=name)
    np.testing.assert_array_equal(late["X_CP"], log["X_CP"][:len(late["t"])])  # the truth is not late


def _tof_noise(seed: int) -> np.ndarray:
    """The ToF readings less the true ranges over the first four camera frames of a default scene with range
    noise, built with `seed` (the UAV hovering 2 m over the deck: every reading valid)."""
    config = StewartSceneConfig(seed=seed)
    config.tof.noise_std_m = 0.005  # stewart-dynamic's (none by default)
    diagram, handles = build_stewart_scene(config)
    context = diagram.CreateDefaultContext()
    tof_context = handles.tof.GetMyContextFromRoot(context)
    noise = []
    for k in range(4):
        context.SetTime(k * config.camera.period_s)
        ranges, true = (handles.tof.GetOutputPort(name).Eval(tof_context) for name in ("ranges", "true_ranges"))
        noise.append(ranges - true)
    return np.array(noise)


def test_the_tof_noise_is_drawn_from_the_scene_s_seed():
    """The scene's seed reaches the ToF sensors: one seed gives the same range noise twice, another seed other
    noise (a Monte Carlo run's ranges are not every run's)."""
    first = _tof_noise(0)
    assert np.all(np.isfinite(first)) and np.all(first != 0.0)
    np.testing.assert_array_equal(_tof_noise(0), first)
    assert np.all(_tof_noise(1) != first)


def test_the_true_tag_corners_are_the_tag_seen_through_the_renderer_s_intrinsics():
    """collect_log's true_tag_corners are the tag's corners at the true X_CT projected with the camera the
    renderer has (K, which the log keeps), not with the estimators' miscalibrated K_estimated: checked
    against cv2.projectPoints."""
    import dataclasses
    from types import SimpleNamespace

    import cv2
    from pydrake.systems.primitives import VectorLog

    from diagrams.stewart_run import collect_log
    from systems.sensors.ground_truth import pose_vector

    config = StewartSceneConfig()
    config.camera.calibration_error.fx_pct, config.camera.calibration_error.cx_px = 3.0, 4.0
    _, handles = build_stewart_scene(config)
    X_CP = [RigidTransform(RotationMatrix(Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()), p)
            for rpy, p in (((180.0, 0.0, 10.0), [0.05, -0.02, 2.0]), ((174.0, 3.0, -20.0), [-0.1, 0.08, 1.8]))]
    poses, imu = VectorLog(7), VectorLog(6)
    for k, X in enumerate(X_CP):
        poses.AddData(k * config.camera.period_s, pose_vector(X))
        imu.AddData(k * config.camera.period_s, np.zeros(6))
    loggers = {name: SimpleNamespace(FindLog=lambda context, log=log: log) for name, log in (("X_CP", poses),
                                                                                          ("imu", imu))}
    log = collect_log(dataclasses.replace(handles, loggers=loggers), None, config)
    corners_T = handles.platform.tag_corners_T()
    np.testing.assert_array_equal(log["K"], config.camera.K)
    for X, corners in zip(X_CP, log["true_tag_corners"]):
        X_CT = X.multiply(handles.platform.X_PT)
        rvec = Rotation.from_matrix(X_CT.rotation().matrix()).as_rotvec()
        expected, _ = cv2.projectPoints(corners_T, rvec, X_CT.translation(), config.camera.K, None)
        np.testing.assert_allclose(corners, expected.ravel(), atol=1e-6)


def test_the_stroke_exceeded_fraction_is_the_fraction_of_frames():
    """scene_metrics' stroke_exceeded_fraction: the share of frames with a leg out of its stroke (1 of 4 here)."""
    from diagrams.stewart_run import scene_metrics

    n = 4
    log = {"tag_corners": np.zeros((n, 8)), "true_tag_corners": np.zeros((n, 8)), "ranges": np.full((n, 4), 2.0),
           "true_ranges": np.full((n, 4), 2.0), "ranges_valid": np.ones((n, 4)),
           "stroke_exceeded": np.array([[0.0], [1.0], [0.0], [0.0]]), "leg_lengths": np.full((n, 6), 0.5)}
    assert scene_metrics(log)["platform"]["stroke_exceeded_fraction"] == 0.25


@pytest.mark.parametrize("tilt, axis", [("roll_deg", "x"), ("pitch_deg", "y")])
def test_the_hover_pose_is_offset_over_the_deck_and_tilted_about_its_own_axis(tilt, axis):
    """hover_pose puts the body offset_xy_m from the deck's nominal centre and height_above_deck_m less the
    camera's mount height over its top; roll about W's x, pitch about its y."""
    config = StewartSceneConfig(hover=HoverConfig(offset_xy_m=[0.3, -0.2], **{tilt: 10.0}))
    platform = StewartPlatform(config.platform, SceneGraph(), config.seed)
    X_WB = hover_pose(config, platform)
    expected = platform.geometry.X_SP0.translation() + [0.3, -0.2, 2.0 - config.camera.mount_xyz_m[2]]
    np.testing.assert_allclose(X_WB.translation(), expected, atol=1e-12)
    np.testing.assert_allclose(X_WB.rotation().matrix(), Rotation.from_euler(axis, 10.0, degrees=True).as_matrix(),
                               atol=1e-12)


def test_with_a_cone_the_tof_sensors_read_the_deck_through_their_depth_render():
    """A 27 deg cone (a VL53L1X's) wires the ToF sensors to their depth camera: the scene builds and, hovering 2 m
    over the level deck, each sensor reads a valid range near its true one."""
    diagram, handles = build_stewart_scene(StewartSceneConfig(tof=TofConfig(cone_deg=27.0)))
    context = diagram.CreateDefaultContext()
    tof_context = handles.tof.GetMyContextFromRoot(context)
    ranges, valid, true = (handles.tof.GetOutputPort(name).Eval(tof_context)
                           for name in ("ranges", "ranges_valid", "true_ranges"))
    np.testing.assert_array_equal(valid, 1.0)
    np.testing.assert_allclose(ranges, true, atol=0.02)
    assert np.all((true > 1.9) & (true < 2.1))


def test_crhf_refuses_a_scene_whose_tof_sensors_sit_at_another_angle_than_its_calibration():
    """The committed pad calibration was flown with the sensors at 45 deg on a 0.135 m arm: at 40 deg the first
    sits at -0.135 (cos 40, sin 40) = (-0.103416, -0.086776) m in C, and CRHF is refused naming it."""
    config = StewartSceneConfig(estimators=["crhf"], tof=TofConfig(angle_deg=40.0))
    with pytest.raises(CalibrationError, match=re.escape("the scene's [[-0.103416, -0.086776, 0.0]")):
        build_stewart_scene(config)


def test_scene_metrics_score_the_frames_with_all_four_corners_and_each_sensors_valid_share():
    """Frame 0: corners (1, 1) and (3, 4) px off, two exact; frame 1 misses a corner (not a detection). Sensor 0
    valid in both frames, the others in the first only."""
    nan = np.nan
    corners = np.array([[1.0, 1.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0], [nan, nan, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    log = {"tag_corners": corners,
           "true_tag_corners": np.zeros((2, 8)), "ranges": np.zeros((2, 4)), "true_ranges": np.zeros((2, 4)),
           "ranges_valid": np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 0.0, 0.0, 0.0]]),
           "stroke_exceeded": np.zeros((2, 1)), "leg_lengths": np.ones((2, 6))}
    metrics = scene_metrics(log)
    perception = metrics["perception"]
    assert perception["tag_detected_fraction"] == 0.5
    assert perception["corner_error_px_mean"] == pytest.approx((math.sqrt(2.0) + 5.0 + 0.0 + 0.0) / 4)
    assert perception["corner_error_px_max"] == pytest.approx(5.0)
    assert metrics["sensors"]["tof_valid_fraction"] == [1.0, 0.5, 0.5, 0.5]
