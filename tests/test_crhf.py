"""The CRHF estimator as a system: on rendered scenes against ground truth, and its failure modes."""

import itertools
import re
from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator

from diagrams.metrics import pose_errors
from diagrams.runner import RunOptions, load_scenario, run
from diagrams.scenario import scenario_names
from diagrams.stewart_run import collect_log
from diagrams.stewart_scene import StewartSceneConfig, build_stewart_scene
from systems.config import ConfigError
from systems.estimators.crhf import JUDGED_FROM_DOF, CrhfConfig, CrhfEstimator, CrhfState, RunningMean
from systems.estimators.crhf_math import NORMAL_GATE, crhf_tag_pose, residual_gate
from systems.estimators.pad_calibration import CalibrationError, CalibrationFlight, PadCalibration
from systems.estimators.track_filter import Track, TrackFilterParams
from systems.perception.apriltag import TagDetection, project_points, tag_corners_T
from systems.sensors.camera import CameraConfig
from systems.sensors.tof import sensor_positions_C
from tests.conftest import constant_offset_platform, pose

CAMERA = CameraConfig()
K = CAMERA.K
P_C_SENSORS = sensor_positions_C(0.135)


@pytest.fixture(scope="module")
def crhf():
    return CrhfEstimator(CrhfConfig(), P_C_SENSORS, 0.5, 0.05, CAMERA)


def level_frame(height=2.0):
    """Exact corners and ranges of a level tag `height` below the camera."""
    X_CT = pose([0.0, 0.0, height], [0, 0, 0])
    return project_points(K, X_CT, tag_corners_T(0.5)), np.full(4, height)


STATIC_DECKS = [(constant_offset_platform(), 0.0),
                (constant_offset_platform(x=0.04, y=-0.03, z=0.02, roll=6.0, pitch=-4.0, yaw=25.0), 10.0)]


def static_run(platform, hover_yaw_deg, pixel_noise_std, tof_noise_std_m):
    """CRHF's errors on a static rendered deck over 2 s: (settled-frame mask, xyz (m), angle (deg))."""
    config = StewartSceneConfig(platform=platform, estimators=["crhf"])
    config.hover.yaw_deg = hover_yaw_deg
    config.camera.pixel_noise_std, config.tof.noise_std_m = pixel_noise_std, tof_noise_std_m
    diagram, handles = build_stewart_scene(config)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(2.0)
    log = collect_log(handles, simulator.get_context(), config)
    valid, xyz, _, angle = pose_errors(log["X_CT"], log["estimate_crhf"])
    assert valid.all()
    return log["t"] >= 1.0, xyz, angle  # the range filter starts from one frame and settles within 1 s


@pytest.mark.slow
@pytest.mark.parametrize("platform, hover_yaw_deg", STATIC_DECKS)
def test_crhf_on_a_static_rendered_deck_is_within_1_cm_and_1_degree(platform, hover_yaw_deg):
    # The bound is 1 cm and 1 degree; CRHF does several times better, and these bounds
    # (about twice what it reaches) catch a regression. With the scenarios' noise (2 levels of pixel
    # noise, 5 mm ToF noise): every settled frame within 3 mm and 1 degree, 0.5 degree on average.
    settled, xyz, angle = static_run(platform, hover_yaw_deg, 2.0, 0.005)
    assert np.abs(xyz[settled]).max() < 0.003
    assert angle[settled].mean() < 0.5 and angle[settled].max() < 1.0
    # Exact ranges: every frame within 1 mm and 0.5 degree.
    settled, xyz, angle = static_run(platform, hover_yaw_deg, 2.0, 0.0)
    assert np.abs(xyz[settled]).max() < 0.001
    assert angle[settled].max() < 0.5


@pytest.mark.slow
def test_a_smoke_run_of_the_dynamic_deck_has_crhf_z_error_below_atda(tmp_path):
    name, scenario = load_scenario("stewart-dynamic", duration_s=10.0)
    metrics = run(name, scenario, tmp_path, RunOptions(progress=False))
    crhf, atda = metrics["estimators"]["crhf"], metrics["estimators"]["atda"]
    assert crhf["valid_fraction"] == 1.0
    assert crhf["per_frame_ms"] > 0 and atda["per_frame_ms"] > 0  # each one's own work per camera frame
    assert crhf["mae_xyz_m"][2] < atda["mae_xyz_m"][2]
    for plot in ("pose_translation.png", "pose_angles.png", "pose_trajectory.png", "errors_crhf.png"):
        assert (tmp_path / plot).stat().st_size > 10_000


def test_the_hardware_profile_tells_crhf_its_sensors_noise_at_the_hover():
    _, scenario = load_scenario("stewart-hardware")
    tof, range_m = scenario.tof, scenario.hover.height_above_deck_m
    assert scenario.crhf.range_filter.measurement_std == pytest.approx(tof.noise_std_m + tof.noise_std_per_m * range_m)
    assert scenario.crhf.range_filter.acceleration_std == CrhfConfig().range_filter.acceleration_std  # the rest kept


@pytest.mark.slow
def test_a_smoke_run_of_the_hardware_profile_shows_its_effects(tmp_path):
    # stewart-hardware's errors come from its effects (docs/results.md): ATDA's x from the principal point's
    # 2 px of calibration error at 2 m (8.7 mm), which CRHF measures itself; CRHF's z from the ToF sensors' 10 mm
    # offset less what the 27 deg cone takes off (7.9 mm over 200 s), below ATDA's 23 mm (its 10 mm on ideal sensors
    # and the 0.6 % focal error). Ideal sensors give about 1 mm.
    name, scenario = load_scenario("stewart-hardware", duration_s=6.0)
    metrics = run(name, scenario, tmp_path, RunOptions(progress=False))
    crhf, atda = metrics["estimators"]["crhf"], metrics["estimators"]["atda"]
    assert crhf["valid_fraction"] > 0.98 and crhf["flips"] == 0  # the first frame has nothing yet: one frame of latency
    assert atda["mae_xyz_m"][0] > 0.005 and crhf["mae_xyz_m"][0] < 0.5 * atda["mae_xyz_m"][0]
    assert 0.005 < crhf["mae_xyz_m"][2] < atda["mae_xyz_m"][2]


def test_exact_measurements_give_the_exact_pose(crhf):
    corners, ranges = level_frame()
    _, estimate = crhf.step(CrhfState(), corners, ranges, 0.0)
    assert estimate.valid
    np.testing.assert_allclose(estimate.X_RT.translation(), [0, 0, 2.0], atol=2e-3)  # calibration residual
    assert estimate.X_RT.rotation().ToAngleAxis().angle() < np.deg2rad(0.2)


def test_a_short_detection_drop_out_is_bridged_and_a_long_one_is_not(crhf):
    corners, ranges = level_frame()
    state, estimate = crhf.step(CrhfState(), corners, ranges, 0.0)
    for k in range(1, 4):  # three frames without the tag: the corner track coasts
        state, estimate = crhf.step(state, None, ranges, 0.05 * k)
        assert estimate.valid
    state, estimate = crhf.step(state, None, ranges, 0.2)
    assert not estimate.valid


@pytest.mark.parametrize("ranges", [[2.0, np.nan, 2.0, 2.0], [20.0, 20.0, 20.0, 20.0]])
def test_an_invalid_range_or_one_outside_the_calibration_is_flagged_not_nan(crhf, ranges):
    corners, _ = level_frame()
    _, estimate = crhf.step(CrhfState(), corners, np.array(ranges), 0.0)
    assert not estimate.valid


def test_the_system_output_is_this_frames_estimate():
    system = CrhfEstimator(CrhfConfig(), P_C_SENSORS, 0.5, 0.05, CAMERA)
    context = system.CreateDefaultContext()
    context.SetTime(0.1)  # a frame time: the estimate, valid or not, is stamped with it
    corners, ranges = level_frame(1.5)
    system.GetInputPort("tag_detection").FixValue(context, TagDetection(0.1, corners))
    system.GetInputPort("ranges").FixValue(context, ranges)
    estimate = system.get_output_port().Eval(context)
    assert estimate.valid and abs(estimate.X_RT.translation()[2] - 1.5) < 2e-3 and estimate.time == 0.1
    system.GetInputPort("tag_detection").FixValue(context, TagDetection(0.1, None))
    estimate = system.get_output_port().Eval(context)
    assert not estimate.valid and estimate.time == 0.1


@pytest.mark.parametrize("fake_clock", [False, True], ids=["real-clock", "2-ms-clock"])
def test_the_system_times_each_frames_step_in_milliseconds(monkeypatch, fake_clock):
    """per_frame_ms is the mean of the frames' step times in ms (None before a frame): positive on the real clock;
    with CRHF's clock advancing 2 ms at each reading (start and end of every frame's step), exactly 2.0."""
    if fake_clock:
        clock = itertools.count(0.0, 0.002)  # s
        monkeypatch.setattr("systems.estimators.crhf.time", SimpleNamespace(perf_counter=lambda: next(clock)))
    system = CrhfEstimator(CrhfConfig(), P_C_SENSORS, 0.5, 0.05, CAMERA)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    corners, ranges = level_frame(1.5)
    system.GetInputPort("tag_detection").FixValue(context, TagDetection(0.0, corners))
    system.GetInputPort("ranges").FixValue(context, ranges)
    assert system.per_frame_ms(context) is None
    simulator.AdvanceTo(0.12)  # the frames at 0, 0.05 and 0.1 s
    assert context.get_abstract_state(0).get_value().compute_ms.weight == 3
    if fake_clock:
        assert system.per_frame_ms(context) == pytest.approx(2.0, rel=1e-9)
    else:
        assert system.per_frame_ms(context) > 0


def test_missing_calibration_and_bad_settings_are_clear_errors(tmp_path):
    with pytest.raises(CalibrationError, match="nope.npz"):
        CrhfEstimator(CrhfConfig(calibration_file=str(tmp_path / "nope.npz")), P_C_SENSORS, 0.5, 0.05, CAMERA)
    three = tmp_path / "three_pads.npz"  # a calibration of three sensors (before: a matmul error at the first frame)
    PadCalibration(PadCalibration.load(CrhfConfig().calibration_path()).sensors[:3]).save(three)
    with pytest.raises(CalibrationError, match="has 3 sensors; CRHF has 4"):
        CrhfEstimator(CrhfConfig(calibration_file=str(three)), P_C_SENSORS, 0.5, 0.05, CAMERA)
    with pytest.raises(ConfigError, match="crhf.touch_pixels"):
        load_scenario("stewart-dynamic", overrides=["crhf.touch_pixels=spline"])
    with pytest.raises(ConfigError, match="crhf.range_filter.measurement_std"):
        load_scenario("stewart-dynamic", overrides=["crhf.range_filter.measurement_std=0"])
    with pytest.raises(ConfigError, match="crhf.max_tag_residual"):
        load_scenario("deck-landing", overrides=["crhf.max_tag_residual=-0.1"])


@pytest.mark.parametrize("camera, p_C_sensors, named", [
    (replace(CAMERA, fx=550.0, fy=550.0), P_C_SENSORS, "camera [fx, fy, cx, cy, width, height] [458.5, 457.855"),
    (replace(CAMERA, width=640), P_C_SENSORS, "the scene's [458.5, 457.855, 258.7735, 252.308, 640.0, 512.0] px"),
    (CAMERA, sensor_positions_C(0.2), "ToF sensors at (x, y, z) [[-0.095459, -0.095459, 0.0]"),
    (CAMERA, sensor_positions_C(0.135, 40.0), "the scene's [[-0.103416, -0.086776, 0.0]"),
], ids=["focal-lengths", "width", "arm", "angle"])
def test_a_calibration_flown_with_another_camera_or_tof_layout_is_refused(camera, p_C_sensors, named):
    with pytest.raises(CalibrationError, match=re.escape(named)) as error:
        CrhfEstimator(CrhfConfig(), p_C_sensors, 0.5, 0.05, camera)
    assert "crhf_pad_calibration.npz was flown with" in str(error.value) and "\n" not in str(error.value)


def test_the_committed_calibration_records_its_flight_and_a_file_without_one_is_refused(tmp_path):
    _, scenario = load_scenario("crhf-calibration")
    flight = PadCalibration.load(CrhfConfig().calibration_path()).flight
    np.testing.assert_array_equal(flight.camera, [scenario.camera.fx, scenario.camera.fy, scenario.camera.cx,
                                                  scenario.camera.cy, scenario.camera.width, scenario.camera.height])
    np.testing.assert_array_equal(flight.distortion, scenario.camera.distortion)
    assert not np.any(flight.distortion)
    np.testing.assert_array_equal(flight.p_C_sensors,
                                  sensor_positions_C(scenario.tof.arm_m, scenario.tof.angle_deg))
    unrecorded = tmp_path / "unrecorded.npz"
    PadCalibration(PadCalibration.load(CrhfConfig().calibration_path()).sensors).save(unrecorded)
    with pytest.raises(CalibrationError, match="does not record the camera and ToF layout .* re-run `landing-sim run "
                                               "crhf-calibration`"):
        CrhfEstimator(CrhfConfig(calibration_file=str(unrecorded)), P_C_SENSORS, 0.5, 0.05, CAMERA)


@pytest.mark.parametrize("name", ["stewart-hover", "stewart-hardware"])
def test_a_calibration_flown_through_a_lens_is_refused_with_a_lens_in_the_scene_or_without(name, tmp_path):
    """The corners CRHF takes are undistorted into the pinhole image and its pad pixels are used as flown, so a
    flight through a lens (stewart-hardware's) is another camera's in a scene without one and in one with it."""
    _, scenario = load_scenario(name)
    flown = replace(CAMERA, distortion=[-0.00908, -0.03128, 0.00109, -0.00198, 0.0])
    path = tmp_path / "lens.npz"
    PadCalibration(PadCalibration.load(CrhfConfig().calibration_path()).sensors,
                   CalibrationFlight.of(flown, P_C_SENSORS)).save(path)
    with pytest.raises(CalibrationError, match=re.escape(
            "was flown with a lens, distortion [k1, k2, p1, p2, k3] [-0.00908, -0.03128, 0.00109, -0.00198, 0.0], "
            "where CRHF needs none")) as error:
        CrhfEstimator(CrhfConfig(calibration_file=str(path)), P_C_SENSORS, 0.5, 0.05, scenario.camera)
    assert "(its distortion zero)" in str(error.value) and "\n" not in str(error.value)


def test_every_shipped_scenario_with_crhf_loads_the_committed_calibration():
    scenarios = [load_scenario(name)[1] for name in scenario_names()]
    with_crhf = [s for s in scenarios if hasattr(s, "crhf")]
    assert {s.diagram for s in with_crhf} == {"stewart_scene", "deck_landing"} and len(with_crhf) == 5
    for scenario in with_crhf:  # the stewart-* and deck-landing* scenarios, as their diagrams build CRHF
        CrhfEstimator(scenario.crhf, sensor_positions_C(scenario.tof.arm_m, scenario.tof.angle_deg),
                      scenario.platform.tag_size_m, scenario.camera.period_s, scenario.camera)


def test_running_mean_weights_its_samples():
    assert RunningMean().mean is None
    mean = RunningMean().add([1.0, 2.0]).add([3.0, 6.0], 3.0)
    np.testing.assert_allclose(mean.mean, [2.5, 5.0])
    assert mean.weight == 4.0


def noisy_level_frames(n, seed=7):
    """n frames of a level tag 2 m below the camera: corners with 0.3 px noise, ranges with 5 mm."""
    rng = np.random.default_rng(seed)
    corners, ranges = level_frame()
    return [(corners + 0.3 * rng.standard_normal(corners.shape), ranges + 0.005 * rng.standard_normal(4))
            for _ in range(n)]


def stepped_valid(crhf, frames) -> CrhfState:
    """The state after stepping `frames` ((corners, ranges) at 0.05 s) from a fresh one, each frame valid."""
    state = CrhfState()
    for k, (corners, ranges) in enumerate(frames):
        state, estimate = crhf.step(state, corners, ranges, 0.05 * k)
        assert estimate.valid
    return state


def test_the_state_remembers_intrinsics_and_the_corner_noise_of_valid_frames(crhf):
    state = stepped_valid(crhf, noisy_level_frames(40))
    assert state.intrinsics.weight == 40 and state.corner_variance.weight == 80  # 2 dof a frame
    np.testing.assert_allclose(state.intrinsics.mean, [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], rtol=0.01)
    assert np.sqrt(state.corner_variance.mean) == pytest.approx(0.3, rel=0.3)  # filtered: a bit below
    state, estimate = crhf.step(state, None, np.full(4, np.nan), 2.0)  # nothing valid: nothing added
    assert not estimate.valid and state.intrinsics.weight == 40 and state.corner_variance.weight == 80


def test_residuals_of_corners_that_fit_no_tag_are_not_pooled_once_the_noise_is_known(crhf):
    frames = noisy_level_frames(30)
    bad_corners = frames[0][0].copy()
    bad_corners[0] += [6.0, 0.0]  # one corner 6 px off: no rigid tag fits
    state = CrhfState()
    state, _ = crhf.step(state, bad_corners, frames[0][1], 0.0)
    assert state.corner_variance.weight == 2  # the first frames are pooled unjudged
    for k, (corners, ranges) in enumerate(frames[1:], start=1):
        state, _ = crhf.step(state, corners, ranges, 0.05 * k)
    pooled = state.corner_variance
    assert pooled.weight == 60
    before = state
    state, estimate = crhf.step(state, bad_corners, frames[-1][1], 1.5)
    assert estimate.valid and state.corner_variance == pooled  # judged now: not pooled
    # The residual left out is beyond the F(2, 60) gate of the pool (the first bad frame is in it).
    residual = crhf.estimate(state.corners, state.ranges.position, state.ranges.P[:4, :4], before).corner_residual_px2
    assert residual > residual_gate(pooled.weight) * pooled.mean


def test_the_pool_judges_residuals_from_exactly_judged_from_dof(crhf):
    # Ten valid frames pool 2 dof each, unjudged: exactly JUDGED_FROM_DOF. The next frame, one corner 6 px off, is
    # judged already, and its residual (beyond the F(2, 20) gate of the pool) is left out.
    frames = noisy_level_frames(10)
    state = stepped_valid(crhf, frames)
    pooled = state.corner_variance
    assert pooled.weight == JUDGED_FROM_DOF == 20
    bad_corners = frames[-1][0].copy()
    bad_corners[0] += [6.0, 0.0]
    before = state
    state, estimate = crhf.step(state, bad_corners, frames[-1][1], 0.5)
    assert estimate.valid and state.corner_variance == pooled  # lifted onto the ranges' plane, not pooled
    residual = crhf.estimate(state.corners, state.ranges.position, state.ranges.P[:4, :4], before).corner_residual_px2
    assert residual > residual_gate(pooled.weight) * pooled.mean


def test_fusion_and_averaging_switched_off_give_the_papers_pipeline_on_filtered_ranges():
    paper = CrhfEstimator(CrhfConfig(fuse_corner_normal=False, average_intrinsics=False), P_C_SENSORS, 0.5, 0.05,
                          CAMERA)
    ours = CrhfEstimator(CrhfConfig(), P_C_SENSORS, 0.5, 0.05, CAMERA)
    paper_state, ours_state = CrhfState(), CrhfState()
    for k, (corners, ranges) in enumerate(noisy_level_frames(20)):
        paper_state, paper_estimate = paper.step(paper_state, corners, ranges, 0.05 * k)
        ours_state, ours_estimate = ours.step(ours_state, corners, ranges, 0.05 * k)
    result = paper.estimate(paper_state.corners, paper_state.ranges.position, paper_state.ranges.P[:4, :4],
                            paper_state)
    assert np.isnan(result.corner_residual_px2)  # the corners' normal was never computed
    assert not ours_estimate.X_RT.IsNearlyEqualTo(paper_estimate.X_RT, 1e-6)


def test_averaged_intrinsics_are_the_mean_of_the_earlier_frames_measurements():
    """average_intrinsics: each frame's corners are lifted with the mean of the focal lengths and principal point
    that the earlier frames measured (Eq. 40-45 on their own touch points), the first frame with its own. Without
    the corners' normal (fuse_corner_normal off) a frame's pose is then crhf_tag_pose on the tracked corners and
    ranges given that mean."""
    crhf = CrhfEstimator(CrhfConfig(fuse_corner_normal=False), P_C_SENSORS, 0.5, 0.05, CAMERA)
    calibration = PadCalibration.load(CrhfConfig().calibration_path())
    state, measured = CrhfState(), []
    for k, (corners, ranges) in enumerate(noisy_level_frames(20)):
        state, estimate = crhf.step(state, corners, ranges, 0.05 * k)
        tracked = state.ranges.position
        uv_touch, uv_corners = calibration.touch_pixels(tracked, "pchip"), state.corners.position.reshape(4, 2)
        own = crhf_tag_pose(P_C_SENSORS, tracked, uv_touch, uv_corners, tag_corners_T(0.5))
        mean = np.mean(measured, axis=0) if measured else np.r_[own.focal_lengths, own.principal_point]
        expected = crhf_tag_pose(P_C_SENSORS, tracked, uv_touch, uv_corners, tag_corners_T(0.5),
                                 intrinsics=(mean[:2], mean[2:]))
        assert estimate.valid and expected.valid
        np.testing.assert_allclose(estimate.X_CT.GetAsMatrix4(), expected.X_CT.GetAsMatrix4(), rtol=0, atol=1e-9)
        measured.append(np.r_[own.focal_lengths, own.principal_point])


def test_raw_ranges_are_fused_with_the_configured_range_variance():
    """filter_ranges=False feeds the frame's raw ranges to the plane fit, their covariance the range filter's
    measurement variance times I: with the corner noise known, the fused pose is crhf_tag_pose's on the raw ranges
    with that covariance (here 1 cm, so 1e-4 m^2)."""
    std = 0.01
    config = CrhfConfig(filter_ranges=False, range_filter=TrackFilterParams(
        measurement_std=std, acceleration_std=0.05, initial_velocity_std=0.2))
    crhf = CrhfEstimator(config, P_C_SENSORS, 0.5, 0.05, CAMERA)
    rng = np.random.default_rng(4)
    X_CT = pose([0.05, -0.03, 2.0], [8.0, -5.0, 20.0])
    corners = project_points(K, X_CT, tag_corners_T(0.5)) + 0.3 * rng.standard_normal((4, 2))
    ranges = ranges_to_plane(X_CT.rotation().col(2), X_CT.translation()) + std * rng.standard_normal(4)
    noise = RunningMean().add(0.09, 20.0)  # 0.3 px, known over 20 degrees of freedom
    state, estimate = crhf.step(CrhfState(corner_variance=noise), corners, ranges, 0.0)
    expected = crhf_tag_pose(
        P_C_SENSORS, ranges, PadCalibration.load(config.calibration_path()).touch_pixels(ranges, "pchip"),
        state.corners.position.reshape(4, 2), tag_corners_T(0.5), range_covariance=std**2 * np.eye(4),
        corner_variance_px2=0.09, corner_variance_dof=20.0)
    assert estimate.valid and expected.valid and not state.ranges.valid  # no range track
    np.testing.assert_allclose(estimate.X_CT.GetAsMatrix4(), expected.X_CT.GetAsMatrix4(), rtol=0, atol=1e-12)


def test_a_tag_tilted_away_from_the_plane_the_ranges_see_is_estimated_from_its_corners(crhf):
    # The ranges read a level surface through the tag's centre (as hardware cones can, averaging the deck's
    # surroundings), the corners a tag tilted 15 deg: beyond the normals' gate, with the corners' mirror
    # (tilted the other way) no closer to the ranges, the corners' normal sets the plane; the touch points
    # still lie on one plane of their own, so the frame is not flagged.
    rng = np.random.default_rng(8)
    X_CT = pose([0.0, 0.0, 2.0], [15.0, 0.0, 0.0])
    corners = project_points(K, X_CT, tag_corners_T(0.5))
    state = CrhfState()
    for k in range(20):
        state, estimate = crhf.step(state, corners + 0.3 * rng.standard_normal(corners.shape),
                                    np.full(4, 2.0) + 0.005 * rng.standard_normal(4), 0.05 * k)
        assert estimate.valid
    error = estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle()
    assert np.degrees(error) < 1.0


def corners_and_mirror(X_CT: RigidTransform):
    """A 0.5 m tag at X_CT: (its exact corners in px, the normal in C of the corners' mirror pose, IPPE's other
    solution)."""
    exact = project_points(K, X_CT, tag_corners_T(0.5))
    _, rvecs, _, _ = cv2.solvePnPGeneric(tag_corners_T(0.5), exact.reshape(-1, 1, 2), K, None,
                                         flags=cv2.SOLVEPNP_IPPE)
    return exact, min((cv2.Rodrigues(r)[0][:, 2] for r in rvecs), key=lambda n: n @ X_CT.rotation().col(2))


def tag_tilted_15_deg_and_its_mirror():
    """A 0.5 m tag 2 m ahead tilted 15 deg about x_C: (X_CT, its exact corners in px, the normal in C of the
    corners' mirror pose, tilted the other way)."""
    X_CT = pose([0.0, 0.0, 2.0], [15.0, 0.0, 0.0])
    return X_CT, *corners_and_mirror(X_CT)


def ranges_to_plane(n: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The four sensors' ranges (along C's z) to the plane with unit normal n through `point` (C, m)."""
    return (n @ point - P_C_SENSORS @ n) / n[2]


def test_ranges_tilted_the_mirrors_way_do_not_take_over_from_the_corners_the_previous_frames_followed(crhf):
    # The livelier deck with stewart-hardware's cones (seed 53917133): the corners see the tag tilted 15 deg and
    # the ranges a flatter plane; their mirror (tilted the other way) agrees with neither, so the corners' normal is
    # taken. Then the ranges tilt towards the mirror's plane and agree with it: the corners are ambiguous, and the
    # previous frame's deck, the corners', keeps the pose on them (on the ranges' plane it is 30 deg off).
    rng = np.random.default_rng(5)
    X_CT, exact, n = tag_tilted_15_deg_and_its_mirror()
    assert n[1] > 0.2  # the mirror's normal: tilted the other way
    mirror_ranges = ranges_to_plane(n, X_CT.translation())
    state, errors = CrhfState(), []
    for k in range(40):
        ranges = np.full(4, 2.0) if k < 20 else mirror_ranges
        state, estimate = crhf.step(state, exact + 0.3 * rng.standard_normal(exact.shape),
                                    ranges + 0.005 * rng.standard_normal(4), 0.05 * k)
        assert estimate.valid
        errors.append(estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle())
    # One frame's corners at 0.3 px give the normal to 0.2-1.7 deg here, before and after the ranges tilt.
    assert np.degrees(max(errors[20:])) < 3.0


@pytest.mark.parametrize("gap_frames, valid_after", [(1, True), (20, True), (21, False)])
def test_the_last_valid_frames_deck_breaks_the_tie_across_a_short_gap(crhf, gap_frames, valid_after):
    # As above, the ranges then tilted the mirror's way (ambiguous corners, the previous frame's deck decides), until
    # a sensor drops out (a NaN range) for one frame, for 20 (exactly deck_normal_memory_s' 1 s, though twenty 0.05 s
    # steps sum to 1.0000000000000002 s), or for 21 (1.05 s, over it). After one or 20, the last valid frame's deck
    # still decides and every later frame is valid and right; after 21 nothing does, and the ambiguous frames are
    # flagged (they would have been, forgetting the deck at the first invalid frame).
    rng = np.random.default_rng(5)
    X_CT, exact, n = tag_tilted_15_deg_and_its_mirror()
    mirror_ranges = ranges_to_plane(n, X_CT.translation())
    state, valid, errors = CrhfState(), [], []
    for k in range(60 + gap_frames):
        ranges = (np.full(4, 2.0) if k < 20 else mirror_ranges) + 0.005 * rng.standard_normal(4)
        if 40 <= k < 40 + gap_frames:
            ranges[1] = np.nan
        state, estimate = crhf.step(state, exact + 0.3 * rng.standard_normal(exact.shape), ranges, 0.05 * k)
        valid.append(estimate.valid)
        if estimate.valid:
            errors.append(estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle())
    after = valid[40 + gap_frames:]
    assert all(valid[:40]) and not any(valid[40:40 + gap_frames])
    assert all(after) if valid_after else not any(after)
    assert np.degrees(max(errors)) < 3.0


def test_a_valid_frame_between_two_gaps_renews_the_decks_memory(crhf):
    """Ambiguous corners (ranges tilted the mirror's way) with two sensor drop-outs of 12 frames each (0.6 s, under
    deck_normal_memory_s' 1 s) and 10 valid frames between them: each valid frame's deck starts the memory's age
    again, so after the second gap, 1.1 s of gaps in all, the last valid frame's deck still decides."""
    rng = np.random.default_rng(5)
    X_CT, exact, n = tag_tilted_15_deg_and_its_mirror()
    mirror_ranges = ranges_to_plane(n, X_CT.translation())
    gaps = [*range(30, 42), *range(52, 64)]
    state, valid, errors = CrhfState(), [], []
    for k in range(80):
        ranges = (np.full(4, 2.0) if k < 20 else mirror_ranges) + 0.005 * rng.standard_normal(4)
        if k in gaps:
            ranges[1] = np.nan
        state, estimate = crhf.step(state, exact + 0.3 * rng.standard_normal(exact.shape), ranges, 0.05 * k)
        valid.append(estimate.valid)
        if estimate.valid:
            errors.append(estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle())
    assert [k for k in range(80) if not valid[k]] == gaps
    assert np.degrees(max(errors)) < 3.0


@pytest.mark.parametrize("seed", [1, 2, 5])
def test_the_previous_frames_deck_breaks_the_tie_as_seen_after_the_cameras_own_turn(crhf, seed):
    # A tag tilted 6 deg about x; the ranges read a level surface through its centre, then (from frame 12) the plane
    # of the corners' mirror pose, 12 deg from the tag's: the corners are ambiguous, and the previous frame's deck
    # decides. From frame 21 the camera rolls at -2 rad/s, 5.7 deg a frame, half the two planes' angle. Turned into
    # this frame by the camera's rate (V_WC_C), the previous frame's deck stays the nearer to the tag's plane; as
    # that frame saw it, it was nearer the mirror's in some frames, and the pose 12-14 deg off there (these seeds).
    rng = np.random.default_rng(seed)
    X_WT, w = pose([0.0, 0.0, 2.0], [6.0, 0.0, 0.0]), -2.0
    state, errors = CrhfState(), []
    for k in range(26):
        X_WC = RigidTransform(RotationMatrix.MakeXRotation(w * max(0.05 * (k - 20), 0.0)), np.zeros(3))
        X_CT = X_WC.inverse().multiply(X_WT)
        exact, n = corners_and_mirror(X_CT)
        ranges = ranges_to_plane(n, X_CT.translation()) if k >= 12 else np.full(4, X_CT.translation()[2])
        V_WC_C = np.r_[w if k > 20 else 0.0, np.zeros(5)]
        state, estimate = crhf.step(state, exact + 0.3 * rng.standard_normal(exact.shape),
                                    ranges + 0.005 * rng.standard_normal(4), 0.05 * k, V_WC_C)
        assert estimate.valid
        errors.append(estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle())
    assert np.degrees(max(errors[21:])) < 3.0


def test_corners_and_ranges_that_agree_on_the_mirrors_plane_from_the_first_frame_are_flagged_until_one_tells(crhf):
    # The ranges see the corners' mirror plane from the first frame: with no previous frame nothing says whether the
    # corners took the wrong one of their two poses or the ranges see a plane tilted the mirror's way, so the frames
    # are flagged (lifted onto the ranges' plane they were 30 deg off) while the range track goes on. When the ranges
    # read the tag's plane, the corners are no longer ambiguous and the pose is right from that frame on (the range
    # track followed the ranges through the flagged frames).
    rng = np.random.default_rng(7)
    X_CT, exact, n = tag_tilted_15_deg_and_its_mirror()
    mirror_ranges = ranges_to_plane(n, X_CT.translation())
    tag_ranges = ranges_to_plane(X_CT.rotation().matrix()[:, 2], X_CT.translation())
    state, valid, errors = CrhfState(), [], []
    for k in range(30):
        ranges = mirror_ranges if k < 5 else tag_ranges
        state, estimate = crhf.step(state, exact + 0.3 * rng.standard_normal(exact.shape),
                                    ranges + 0.005 * rng.standard_normal(4), 0.05 * k)
        valid.append(estimate.valid)
        if estimate.valid:
            errors.append(estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle())
        else:  # flagged: the range track still took the frame's ranges, neither dropped nor coasted
            assert state.ranges.valid and state.ranges.coasted_steps == 0
    assert not any(valid[:5]) and all(valid[5:]) and np.degrees(max(errors)) < 3.0


def test_the_first_frame_weighs_its_corners_by_their_own_residual(crhf):
    # No residual is pooled before the first frame: its own stands for the corner noise, so its corners' normal
    # is fused (or, as here, beyond the gate, decides) from the first frame. The ranges read a level surface
    # through the tag's centre, as stewart-hardware's cones can, the corners a tag tilted 15 deg; the corners'
    # mirror (tilted the other way) is no closer to the ranges. Lifted onto the ranges' plane alone, as before,
    # the pose was 15 deg off; one frame's corners at 0.3 px give the normal to 0.2-2.4 deg (40 draws).
    rng = np.random.default_rng(3)
    X_CT = pose([0.0, 0.0, 2.0], [15.0, 0.0, 0.0])
    corners = project_points(K, X_CT, tag_corners_T(0.5)) + 0.3 * rng.standard_normal((4, 2))
    state, estimate = crhf.step(CrhfState(), corners, np.full(4, 2.0), 0.0)
    assert estimate.valid and state.corner_variance.weight == 2
    error = estimate.X_RT.rotation().inverse().multiply(X_CT.rotation()).ToAngleAxis().angle()
    assert np.degrees(error) < 3.0


def test_the_first_frames_corner_noise_is_its_residual_over_its_two_degrees_of_freedom(crhf):
    """With nothing pooled, a frame's corner noise is its own PnP residual over its 2 degrees of freedom, the
    variance the state then pools: the first frame's pose is the one the same frame gives once that variance
    is pooled."""
    rng = np.random.default_rng(3)
    X_CT = pose([0.0, 0.0, 2.0], [3.0, 0.0, 0.0])
    corners = project_points(K, X_CT, tag_corners_T(0.5)) + 0.3 * rng.standard_normal((4, 2))
    ranges = np.full(4, 2.0)
    state, first = crhf.step(CrhfState(), corners, ranges, 0.0)
    assert first.valid and state.corner_variance.weight == 2
    _, pooled = crhf.step(CrhfState(corner_variance=state.corner_variance), corners, ranges, 0.0)
    assert first.X_RT.rotation().inverse().multiply(pooled.X_RT.rotation()).ToAngleAxis().angle() < 1e-12
    np.testing.assert_allclose(first.X_RT.translation(), pooled.X_RT.translation(), atol=1e-12)


def one_corner_off_frame(crhf, tilt_deg):
    """A tag 2 m ahead tilted tilt_deg about x_C with one corner 1 px off, over level ranges: (corners, ranges, the
    state after its first frame, the corners' PnP residual (px^2) in that frame from a fresh state)."""
    corners = project_points(K, pose([0.0, 0.0, 2.0], [tilt_deg, 0.0, 0.0]), tag_corners_T(0.5))
    corners[0] += [1.0, 0.0]
    ranges = np.full(4, 2.0)
    state, _ = crhf.step(CrhfState(), corners, ranges, 0.0)
    residual = crhf.estimate(state.corners, state.ranges.position, state.ranges.P[:4, :4],
                             CrhfState()).corner_residual_px2
    return corners, ranges, state, residual


def test_the_corners_are_judged_by_the_pools_own_degrees_of_freedom(crhf):
    # A corner noise pooled over 2 dof of r / 30: the F(2, 2) gate (1998) accepts a residual r 30 times it, the
    # exact-variance one (13.8) would not. The corners are fused: the normal leaves the ranges' level plane.
    corners, ranges, state, residual = one_corner_off_frame(crhf, 3.0)
    assert NORMAL_GATE < 30.0 < residual_gate(2.0)
    pooled = CrhfState(corner_variance=RunningMean().add(residual / 30.0, 2.0))
    result = crhf.estimate(state.corners, state.ranges.position, state.ranges.P[:4, :4], pooled)
    assert result.valid and result.corner_residual_px2 == pytest.approx(residual)
    assert np.degrees(np.arccos(min(1.0, result.plane.normal @ [0.0, 0.0, 1.0]))) > 0.5


def test_a_residual_within_the_pools_f_gate_but_beyond_the_chi_square_one_is_pooled(crhf):
    # A pool of 20 dof (judged) at r / 16: r is within its F(2, 20) gate (19.9) though beyond the exact-variance
    # one (13.8), so the frame adds r / 2 over 2 dof: weight 22, mean (20 r / 16 + 2 r / 2) / 22.
    corners, ranges, _, residual = one_corner_off_frame(crhf, 0.0)
    assert NORMAL_GATE < 16.0 < residual_gate(JUDGED_FROM_DOF)
    pooled = CrhfState(corner_variance=RunningMean().add(residual / 16.0, JUDGED_FROM_DOF))
    state, estimate = crhf.step(pooled, corners, ranges, 0.0)
    assert estimate.valid
    assert state.corner_variance.weight == JUDGED_FROM_DOF + 2.0
    assert state.corner_variance.mean == pytest.approx((20.0 * residual / 16.0 + residual) / 22.0, rel=1e-12)


def test_ranges_off_one_plane_drop_the_range_track_even_when_the_frame_is_flagged_already(crhf):
    # The first frame, ranges on the mirror's plane: the corners are ambiguous with no previous deck, so the frame
    # is flagged invalid. A twist of 3 cm keeps the fitted normal but puts the touch points 0.03 cos 15 = 0.029 m
    # off it, beyond max_plane_residual_m (0.02): the ranges are not the deck, and no range track is started.
    X_CT, exact, n = tag_tilted_15_deg_and_its_mirror()
    ranges = ranges_to_plane(n, X_CT.translation()) + 0.03 * np.array([1.0, -1.0, 1.0, -1.0])
    state, estimate = crhf.step(CrhfState(), exact, ranges, 0.0)
    assert not estimate.valid and not state.ranges.valid


def test_raw_ranges_with_a_nan_give_no_estimate():
    raw = CrhfEstimator(CrhfConfig(filter_ranges=False), P_C_SENSORS, 0.5, 0.05, CAMERA)
    corners, ranges = level_frame()
    state, _ = raw.step(CrhfState(), corners, ranges, 0.0)
    assert raw.estimate(state.corners, np.array([2.0, np.nan, 2.0, 2.0]), 1e-4 * np.eye(4), state) is None


@pytest.mark.parametrize("next_range, accepted", [(2.0 - 0.05 * 2.5, True), (2.0, False)])
def test_the_range_gate_is_centred_on_the_tracks_prediction_one_frame_ahead(crhf, next_range, accepted):
    """A range track at 2 m closing at 2.5 m/s predicts 1.875 m one 0.05 s frame on: ranges there are 0.125 m
    from its position but on its prediction, and pass the 0.1 m gate; ranges still at 2 m are 0.125 m off the
    prediction, gated (the track coasts and the frame is flagged)."""
    rate = -2.5
    state = CrhfState(ranges=Track(np.r_[np.full(4, 2.0), np.full(4, rate)], np.eye(8) * 1e-6))
    corners = project_points(K, pose([0.0, 0.0, next_range], [0, 0, 0]), tag_corners_T(0.5))
    state, estimate = crhf.step(state, corners, np.full(4, next_range), 0.05)
    assert estimate.valid == accepted and state.ranges.coasted_steps == (0 if accepted else 1)
    if accepted:
        assert estimate.X_CT.translation()[2] == pytest.approx(next_range, abs=1e-3)


def test_a_sensor_past_the_decks_edge_is_gated_and_does_not_pull_the_range_track(crhf):
    corners, ranges = level_frame()
    state = CrhfState()
    for k in range(10):
        state, estimate = crhf.step(state, corners, ranges, 0.05 * k)
    assert estimate.valid
    past_edge = ranges.copy()
    past_edge[2] += 0.7  # its ray falls past the deck onto the base
    state, estimate = crhf.step(state, corners, past_edge, 0.5)
    assert not estimate.valid  # flagged
    np.testing.assert_allclose(state.ranges.position, ranges, atol=1e-3)  # the track coasted, unpulled
    state, estimate = crhf.step(state, corners, ranges, 0.55)
    assert estimate.valid and estimate.X_CT.translation()[2] == pytest.approx(2.0, abs=1e-3)


def test_four_touch_points_off_one_plane_are_flagged_from_the_first_frame_and_start_no_range_track(crhf):
    corners, ranges = level_frame()
    off_plane = ranges.copy()
    off_plane[0] += 0.3  # on the first frame there is no track to gate against
    state, estimate = crhf.step(CrhfState(), corners, off_plane, 0.0)
    assert not estimate.valid and not state.ranges.valid
    state, estimate = crhf.step(state, corners, ranges, 0.05)  # a track of the first readings would gate these
    assert estimate.valid and estimate.X_CT.translation()[2] == pytest.approx(2.0, abs=1e-3)


@pytest.mark.parametrize("past_edge", [[0.0, 0.0, 0.6, 0.6], [0.6, 0.6, 0.6, 0.6]], ids=["two", "four"])
def test_sensors_past_the_decks_edge_on_the_first_frame_are_flagged_and_start_no_range_track(crhf, past_edge):
    # Before any range track exists nothing gates the first readings. Two sensors on the ground 0.6 m below
    # the deck fit a plane tilted about 70 deg, four fit a level one 0.6 m too deep: either fits its four touch
    # points exactly, but the corners lifted onto it are not the tag (stretched, or 1.3 times too large).
    corners, ranges = level_frame()
    state = CrhfState()
    for k in range(3):
        state, estimate = crhf.step(state, corners, ranges + past_edge, 0.05 * k)
        assert not estimate.valid
        assert not state.ranges.valid  # the wrong surface starts no track
    state, estimate = crhf.step(state, corners, ranges, 0.15)  # back on the deck: valid at once
    assert estimate.valid and estimate.X_CT.translation()[2] == pytest.approx(2.0, abs=1e-3)


def test_sensors_past_the_decks_edge_once_the_corner_noise_is_known_are_flagged(crhf):
    # Once the corner noise is known the corners' normal is fused; two sensors on the ground 0.6 m below the deck
    # (a new range track, the old one dropped) are beyond the normals' gate, and the corners' normal is taken
    # through the touch points' centroid, 0.3 m too deep: a tag 1.15 times too large passes the tag's check, but
    # two touch points lie 0.3 m from the plane the corners fix, farther than the range gate.
    frames = noisy_level_frames(12)
    state = stepped_valid(crhf, frames)
    corners, ranges = frames[-1]
    state = replace(state, ranges=Track())  # as after a failed check
    state, estimate = crhf.step(state, corners, ranges + [0.0, 0.0, 0.6, 0.6], 0.6)
    assert not estimate.valid and not state.ranges.valid


def test_the_drones_own_motion_keeps_the_range_track_on_the_deck(crhf):
    # The camera descends at 0.4 m/s towards a level tag: told its velocity (Eq. 28's B u), CRHF's z
    # follows within millimetres; not told, its slow range track lags by centimetres.
    def descend(told: bool) -> float:
        state, worst = CrhfState(), 0.0
        for k in range(60):
            height = 2.0 - (0.0 if k < 20 else 0.4 * 0.05 * (k - 20))
            corners, ranges = level_frame(height)
            V_WC_C = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.4 if k > 20 else 0.0]) if told else None
            state, estimate = crhf.step(state, corners, ranges, 0.05 * k, V_WC_C)
            if k > 20:
                worst = max(worst, abs(estimate.X_CT.translation()[2] - height))
        return worst

    assert descend(True) < 0.005
    assert descend(False) > 0.02


def test_turning_and_moving_sideways_over_a_tilted_deck_keeps_the_range_track_on_it(crhf):
    # After 1 s at rest the camera descends at 0.4 m/s, slides sideways at 0.2 m/s and turns at 0.1 rad/s about
    # x_C, over a deck tilted 16 deg. Told its whole spatial velocity, the range track's prediction follows the
    # ranges over the tilted plane (`range_shift`); told the motion along its axis alone (a level deck's shift),
    # the slow track lags by millimetres; told nothing, by centimetres.
    X_WT = RigidTransform(RollPitchYaw(0.0, np.radians(16.0), 0.0), [0.0, 0.0, 2.0])
    w_C, v_W = np.array([0.1, 0.0, 0.0]), np.array([0.2, 0.0, 0.4])

    def worst_depth_error(told) -> float:
        state, worst = CrhfState(), 0.0
        for k in range(50):
            moving = max(0.05 * k - 1.0, 0.0)
            X_WC = RigidTransform(RotationMatrix.MakeXRotation(w_C[0] * moving), v_W * moving)
            X_CT = X_WC.inverse().multiply(X_WT)
            n_C = X_CT.rotation().col(2)
            ranges = (n_C @ X_CT.translation() - P_C_SENSORS @ n_C) / n_C[2]
            V_WC_C = np.r_[w_C, X_WC.rotation().inverse().multiply(v_W)] if moving > 0.0 else np.zeros(6)
            state, estimate = crhf.step(state, project_points(K, X_CT, tag_corners_T(0.5)), ranges, 0.05 * k,
                                        told(V_WC_C))
            assert estimate.valid
            worst = max(worst, abs(estimate.X_CT.translation()[2] - X_CT.translation()[2]))
        return worst

    assert worst_depth_error(lambda V: V) < 0.001
    assert worst_depth_error(lambda V: np.r_[0.0, 0.0, 0.0, 0.0, 0.0, V[5]]) > 0.003
    assert worst_depth_error(lambda V: None) > 0.02


def test_a_focal_length_error_scales_atdas_depth_and_leaves_crhfs():
    # The estimators are given fx, fy 2 % long: ATDA's pinhole depth grows by 2 % (4 cm at 2 m) against
    # the same frames with the exact K; CRHF measures its own intrinsics from the ranges and the pad
    # calibration (seed 000 Eq. 40-45) and does not move.
    def depths(error_pct):
        config = StewartSceneConfig(platform=constant_offset_platform(), estimators=["atda", "crhf"])
        config.camera.calibration_error.fx_pct = config.camera.calibration_error.fy_pct = error_pct
        diagram, handles = build_stewart_scene(config)
        simulator = Simulator(diagram)
        simulator.AdvanceTo(1.0)
        log = collect_log(handles, simulator.get_context(), config)
        return log["X_CT"][:, 2], log["estimate_atda"][:, 3], log["estimate_crhf"][:, 3]

    true_z, atda_exact, crhf_exact = depths(0.0)
    _, atda_z, crhf_z = depths(2.0)
    np.testing.assert_allclose(atda_z / atda_exact, 1.02, atol=0.002)
    np.testing.assert_array_equal(crhf_z, crhf_exact)
    assert np.max(np.abs(crhf_z - true_z)) < 0.005
