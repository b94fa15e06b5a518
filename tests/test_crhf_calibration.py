"""The colour-pad calibration flight (seed 000 Sec. 2.3): pad segmentation on rendered frames, the
PadCentroidsSystem, a short calibration run, scenario validation and the command line."""

import dataclasses
import json
import subprocess
from operator import attrgetter
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.sensors import ImageRgba8U

from diagrams.crhf_calibration import (
    PAD_THICKNESS_M,
    build_calibration_scene,
    calibration_metrics,
    leave_one_out_residuals,
    true_pad_pixels,
)
from diagrams.runner import RunOptions, load_scenario, run
from systems.config import ConfigError
from systems.estimators.pad_calibration import PAD_COLOURS, PAD_RGB, PadCalibration, rgb_to_ycbcr, segment_colour
from systems.perception.color_pads import PadCentroidsSystem
from systems.sensors.tof import sensor_positions_C
from systems.vehicles.airframe import PrescribedPose
from tests.conftest import landing_sim_command

ROOT = Path(__file__).resolve().parent.parent
EQ10 = np.array([458.5, 457.855, 258.7735, 252.308])  # fx, fy, cx, cy: seed 000 Eq. 10


@pytest.fixture(scope="module")
def scene():
    """The named scenario's scene (pixel noise 2 levels, ToF noise 5 mm) and a context."""
    _, scenario = load_scenario("crhf-calibration")
    diagram, handles = build_calibration_scene(scenario)
    return scenario, diagram, handles, diagram.CreateDefaultContext()


def rendered(scene, t):
    """(RGBA image, pad_pixels (4, 2)) at time t."""
    _, _, handles, context = scene
    context.SetTime(t)
    image = handles.color_image.Eval(handles.noisy_camera.GetMyContextFromRoot(context)).data.copy()
    pixels = handles.pads.GetOutputPort("pad_pixels").Eval(handles.pads.GetMyContextFromRoot(context))
    return image, np.asarray(pixels).reshape(4, 2)


def projected_pad_centres(scenario, handles, t):
    """cv2.projectPoints of the pads' top centres with the scenario's K at time t."""
    X_CW = handles.X_WC(t).inverse()
    rvec, _ = cv2.Rodrigues(X_CW.rotation().matrix())
    points, _ = cv2.projectPoints(handles.p_W_pads, rvec, X_CW.translation(), scenario.camera.K, np.zeros(5))
    return points.reshape(4, 2)


@pytest.mark.parametrize("fraction", [0.0, 0.5, 1.0])
def test_pads_are_found_within_a_pixel_of_their_projection(scene, fraction):
    scenario, _, handles, _ = scene
    t = fraction * scenario.duration_s  # the start, the middle and the top of the climb
    _, found = rendered(scene, t)
    expected = projected_pad_centres(scenario, handles, t)
    assert np.all(np.isfinite(found))
    assert np.abs(found - expected).max() < 1.0


def test_the_logged_true_pad_pixels_are_the_pads_projection(scene):
    """true_pad_pixels (the truth the pad centroid errors are taken against) is cv2.projectPoints of the pads'
    centres from the camera's pose at each time: on the climb flown, and from a camera off the pads' axis,
    tilted and yawed (on the climb, straight above the origin looking down, X_WC is its own inverse)."""
    scenario, _, handles, _ = scene
    times = np.array([0.0, 0.5, 1.0]) * scenario.duration_s
    off_axis = dataclasses.replace(handles, body=PrescribedPose(
        RigidTransform(RollPitchYaw(0.05, -0.03, 0.4), [0.03, -0.02, 0.0]).multiply(handles.body.X_WB(0.0)),
        (0.02, 0.01, 0.15)))
    for h in (handles, off_axis):
        expected = [projected_pad_centres(scenario, h, t) for t in times]
        np.testing.assert_allclose(true_pad_pixels(h, scenario.camera.K, times), expected, rtol=0, atol=1e-9)


def test_the_camera_climbs_from_start_height_m_above_the_pads_at_climb_speed_m_s():
    """Without rendering: the pads' top faces lie PAD_THICKNESS_M above the floor (z = 0), the camera
    start_height_m + climb_speed_m_s t above them at time t, and that is the range each ToF sensor's ideal
    ray (cast on the scene's geometry) reads down to its pad."""
    _, scenario = load_scenario("crhf-calibration")
    diagram, handles = build_calibration_scene(scenario)
    context = diagram.CreateDefaultContext()
    true_ranges = handles.tof.GetOutputPort("true_ranges")
    np.testing.assert_array_equal(handles.p_W_pads[:, 2], PAD_THICKNESS_M)
    for t in (0.0, 1.0, 2.5):
        height = 0.3 + 0.15 * t  # start_height_m 0.3 m, climb_speed_m_s 0.15 m/s
        context.SetTime(t)
        assert handles.X_WC(t).translation()[2] == pytest.approx(PAD_THICKNESS_M + height, abs=1e-12)
        np.testing.assert_allclose(true_ranges.Eval(handles.tof.GetMyContextFromRoot(context)), np.full(4, height),
                                   rtol=0, atol=1e-6)


def test_rendered_pad_colours_stay_inside_their_table1_range_only(scene):
    """The renderer's headlight leaves PAD_RGB as it is on the level floor: each pad's pixels
    segment as its own colour and no other, and the floor as none."""
    scenario, _, handles, _ = scene
    image, _ = rendered(scene, 0.0)
    ycbcr = rgb_to_ycbcr(image)
    centres = np.round(projected_pad_centres(scenario, handles, 0.0)).astype(int)
    for colour, (u, v) in zip(PAD_COLOURS, centres):
        patch = image[v - 10:v + 11, u - 10:u + 11, :3].reshape(-1, 3).astype(float)
        assert np.abs(patch.mean(axis=0) - PAD_RGB[colour]).max() < 1.5
        for other in PAD_COLOURS:
            hit = segment_colour(ycbcr[v - 10:v + 11, u - 10:u + 11], other).mean()
            assert hit == (1.0 if other == colour else 0.0), (colour, other)
    floor = ycbcr[240:272, 240:272]
    assert not any(segment_colour(floor, colour).any() for colour in PAD_COLOURS)


def two_pads(green_radius_px: int, red_radius_px: int) -> ImageRgba8U:
    """A 64 x 48 grey frame with a green disc centred at (16, 20) and a red one at (45, 30) (u, v in px)."""
    rgba = np.full((48, 64, 4), 128, np.uint8)
    rgba[..., 3] = 255
    cv2.circle(rgba, (16, 20), green_radius_px, (*PAD_RGB["green"], 255), -1)
    cv2.circle(rgba, (45, 30), red_radius_px, (*PAD_RGB["red"], 255), -1)
    image = ImageRgba8U(64, 48)
    image.mutable_data[:] = rgba
    return image


def pad_pixels(system: PadCentroidsSystem, image: ImageRgba8U) -> np.ndarray:
    """The system's pad_pixels on `image`, one (u, v) row per colour."""
    context = system.CreateDefaultContext()
    system.get_input_port().FixValue(context, image)
    return np.asarray(system.GetOutputPort("pad_pixels").Eval(context)).reshape(-1, 2)


def test_pad_centroids_system_orders_pads_and_flags_missing_ones():
    pixels = pad_pixels(PadCentroidsSystem(64, 48), two_pads(6, 6))
    np.testing.assert_allclose(pixels[PAD_COLOURS.index("red")], [45, 30], atol=0.2)
    np.testing.assert_allclose(pixels[PAD_COLOURS.index("green")], [16, 20], atol=0.2)
    assert np.isnan(pixels[[PAD_COLOURS.index("yellow"), PAD_COLOURS.index("blue")]]).all()


def test_pad_centroids_system_finds_the_colours_it_is_given_in_their_order():
    """colours ("green", "red"): two pads, green's first, not the default four in PAD_COLOURS' order."""
    pixels = pad_pixels(PadCentroidsSystem(64, 48, colours=("green", "red")), two_pads(6, 6))
    np.testing.assert_allclose(pixels, [[16, 20], [45, 30]], atol=0.2)


def test_pad_centroids_system_drops_pads_smaller_than_its_min_area():
    """A 13 px green pad and a 49 px red one: the default system (min_area_px 20) finds the red one only, a
    system with min_area_px 10 finds both, each at its disc's centre."""
    image = two_pads(2, 4)
    ycbcr = rgb_to_ycbcr(image.data)
    assert segment_colour(ycbcr, "green").sum() == 13 and segment_colour(ycbcr, "red").sum() == 49
    green, red = PAD_COLOURS.index("green"), PAD_COLOURS.index("red")
    default = pad_pixels(PadCentroidsSystem(64, 48), image)
    assert np.isnan(default[green]).all()
    np.testing.assert_allclose(default[red], [45, 30], atol=0.2)
    smaller = pad_pixels(PadCentroidsSystem(64, 48, min_area_px=10), image)
    np.testing.assert_allclose(smaller[[green, red]], [[16, 20], [45, 30]], atol=0.2)


def test_leave_one_out_residuals_are_each_interior_sample_against_the_pchip_through_the_others():
    """On samples of Eq. 18's a / r + c: SciPy's PCHIP through all samples but the k-th, at the k-th range,
    less that sample. On a straight line with one sample off it by (1, -0.5) px, the PCHIP through the
    others is the line itself: that sample's residual is (-1, 0.5) px."""
    from scipy.interpolate import PchipInterpolator

    ranges = np.array([0.3, 0.4, 0.55, 0.7, 1.0, 1.4, 2.0])
    pixels = np.column_stack([40.0 / ranges + 250.0, -30.0 / ranges + 260.0])
    expected = [PchipInterpolator(np.delete(ranges, k), np.delete(pixels, k, axis=0), axis=0)(ranges[k]) - pixels[k]
                for k in range(1, len(ranges) - 1)]
    residuals = leave_one_out_residuals(ranges, pixels)
    np.testing.assert_allclose(residuals, expected, rtol=0, atol=1e-12)
    assert np.all(np.abs(residuals) > 1e-3)
    line = np.column_stack([2.0 * ranges + 1.0, -ranges])
    line[3] += [1.0, -0.5]
    np.testing.assert_allclose(leave_one_out_residuals(ranges, line)[2], [-1.0, 0.5], rtol=0, atol=1e-12)


def test_calibration_metrics_against_the_true_camera():
    """A calibration from exact projections u = fx X / r + cx, v = fy Y / r + cy (sensor at X, Y): its
    hyperbolas are the truth. One from a camera with fx 1 % and fy 2 % too small, cx 2 px and cy 3 px too
    large implies those intrinsics: implied_error_percent is (implied - true) / true, signed."""
    _, scenario = load_scenario("crhf-calibration")
    p_C = sensor_positions_C(scenario.tof.arm_m, scenario.tof.angle_deg)
    ranges = np.tile(np.linspace(0.3, 2.3, 41)[:, None], (1, 4))

    def metrics(fx, fy, cx, cy, u_lost=None):
        pixels = np.stack([fx * p_C[:, 0] / ranges + cx, fy * p_C[:, 1] / ranges + cy], axis=-1)
        calibration = PadCalibration.from_frames(ranges, pixels, PAD_COLOURS)
        logged = pixels.copy()
        if u_lost is not None:
            logged[0, u_lost, 0] = np.nan  # that pad's u lost in the first frame, its v still there
        return calibration_metrics(calibration, {"pad_pixels": logged.reshape(-1, 8)}, scenario, p_C)

    exact = metrics(*EQ10)
    for colour in PAD_COLOURS:
        pad = exact["pads"][colour]
        assert pad["detected_fraction"] == 1.0
        np.testing.assert_allclose(pad["hyperbola_vs_truth_rmse_px"], [0.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(pad["pchip_vs_truth_rmse_px"], [0.0, 0.0], atol=0.05)
        np.testing.assert_allclose(list(pad["implied_error_percent"].values()), np.zeros(4), atol=1e-6)
    off = metrics(*(EQ10 * [0.99, 0.98, 1.0, 1.0] + [0.0, 0.0, 2.0, 3.0]))
    expected = {"fx": -1.0, "fy": -2.0, "cx": 100 * 2.0 / EQ10[2], "cy": 100 * 3.0 / EQ10[3]}
    for colour in PAD_COLOURS:
        assert off["pads"][colour]["implied_error_percent"] == pytest.approx(expected, rel=1e-6)
    assert off["implied_error_percent_mean"] == pytest.approx(expected, rel=1e-6)
    # a pad is found in a frame only with both of its coordinates: one lost u of 41 frames leaves it 40 / 41
    half_found = metrics(*EQ10, u_lost=1)
    assert [half_found["pads"][c]["detected_fraction"] for c in PAD_COLOURS] == [1.0, 40 / 41, 1.0, 1.0]


@pytest.mark.slow
def test_a_short_calibration_climb_implies_the_camera_intrinsics(tmp_path):
    name, scenario = load_scenario("crhf-calibration", overrides=["climb_speed_m_s=1.0"], duration_s=2.0)
    metrics = run(name, scenario, tmp_path, RunOptions(progress=False))
    assert metrics["height_m"] == pytest.approx([0.3, 2.3], abs=1e-9)  # from 0.3 m, 2 s at 1 m/s
    calibration = PadCalibration.load(tmp_path / "pad_calibration.npz")
    assert [s.colour for s in calibration.sensors] == list(PAD_COLOURS)
    assert all(len(s.ranges) == 41 for s in calibration.sensors)  # 2 s at 20 Hz, both ends
    implied = calibration.implied_intrinsics(sensor_positions_C(scenario.tof.arm_m, scenario.tof.angle_deg))
    np.testing.assert_allclose(implied[:, :2], np.tile(EQ10[:2], (4, 1)), rtol=0.02)
    np.testing.assert_allclose(implied[:, 2:], np.tile(EQ10[2:], (4, 1)), atol=1.0)
    section = metrics["calibration"]
    assert section["true_intrinsics"] == dict(zip(("fx", "fy", "cx", "cy"), EQ10.tolist()))
    for colour in PAD_COLOURS:
        pad = section["pads"][colour]
        assert pad["samples"] == 41 and pad["detected_fraction"] == 1.0
        assert set(pad["hyperbola"]) == {"u", "v"} and set(pad["hyperbola"]["u"]) >= {"a", "c"}
        assert pad["pchip_leave_one_out_rmse_px"][0] < 5.0
        assert max(pad["hyperbola_vs_truth_rmse_px"]) < 1.0
    true = dict(zip(("fx", "fy", "cx", "cy"), EQ10))
    for colour, row in zip(PAD_COLOURS, implied):
        expected = {k: 100.0 * (v - true[k]) / true[k] for k, v in zip(true, row)}
        assert section["pads"][colour]["implied_error_percent"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # each pad's centroid error: against cv2.projectPoints of that pad at each frame
    _, handles = build_calibration_scene(scenario)
    with np.load(tmp_path / "log.npz") as log:
        t, found = log["t"], log["pad_pixels"].reshape(-1, 4, 2)
    errors = np.linalg.norm(found - np.array([projected_pad_centres(scenario, handles, ti) for ti in t]), axis=2)
    rmse = metrics["perception"]["pad_centroid_error_px_rmse"]
    np.testing.assert_allclose(rmse, np.sqrt(np.mean(errors**2, axis=0)), rtol=1e-6)
    assert max(rmse) < 1.0
    for name in ("log.npz", "metrics.json", "calibration_u.png", "calibration_v.png"):
        assert (tmp_path / name).is_file()


@pytest.mark.parametrize("override, field", [
    ("end_height_m=4.5", "end_height_m"),  # beyond tof.max_range_m
    ("start_height_m=3.95", "start_height_m"),  # not below end_height_m
    ("start_height_m=3.9", "must be below end_height_m"),  # equal to end_height_m
    ("start_height_m=0.02", "is below tof.min_range_m"),  # below tof.min_range_m (0.04 m)
    ("camera.near_m=0.3", "must exceed camera.near_m"),  # start_height_m on the near plane
    ("duration_s=60", "duration_s"),  # runs past end_height_m
    ("duration_s=0.05", "duration_s"),  # fewer than three frames
    ("climb_speed_m_s=0", "climb_speed_m_s"),
    ("pad_radius_m=0.12", "overlap"),  # neighbouring pads overlap
    # 0.2 m across, neighbouring sensors 2 * 0.135 sin 45 deg = 0.191 m apart (opposite ones 0.27 m)
    ("pad_radius_m=0.1", "overlap"),
    ("pad_radius_m=0.02", "pad_radius_m"),  # too small to segment at the top
    ("start_height_m=0.1", "the pads do not fit in the image"),  # the outer pads' rims off the image's edges
    ("camera.cx=100", "principal point 100, "),  # the left pads off the image: the message names the camera
    # the right pads' rims at 289 + 458.5 (0.135 sin 45 deg + 0.05) / 0.3 = 511.31 px, past the last pixel's 511
    ("camera.cx=289", "do not fit in the image"),
    # 380 px * 0.05 m / 3.9 m = 4.87 px at the top in v (458.5 px in u would give 5.88)
    ("camera.fy=380", "is too small"),
    ("tof.noise_std_m=-1", "tof.noise_std_m"),
    ("pad_radius=0.1", "pad_radius"),  # unknown key
])
def test_bad_scenario_values_are_config_errors_naming_the_field(override, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("crhf-calibration", overrides=[override])


@pytest.mark.parametrize("override", [
    "tof.min_range_m=0.3",  # start_height_m (0.3 m) on the ToF's minimum range
    # on tof.max_range_m: the climb takes 3.7 / 0.15 = 24.67 s >= the 24 s flown, a pad 457.855 * 0.05 / 4 = 5.72 px
    "end_height_m=4.0",
    "duration_s=0.1",  # exactly the 3 camera frames (2 periods at 20 Hz) a calibration needs
])
def test_scenario_values_on_their_limits_are_accepted(override):
    _, scenario = load_scenario("crhf-calibration", overrides=[override])
    key, value = override.split("=")
    assert attrgetter(key)(scenario) == float(value)


@pytest.mark.slow
def test_command_line_writes_the_calibration_and_metrics(tmp_path):
    out = tmp_path / "cal"
    done = subprocess.run([*landing_sim_command(), "run", "crhf-calibration", "--duration", "1", "--out", str(out), "--quiet"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert {"scenario", "seed", "sim_time_s", "wall_time_s", "realtime_factor", "calibration"} <= set(metrics)
    assert metrics["scenario"] == "crhf-calibration" and metrics["sim_time_s"] == 1.0
    written = PadCalibration.load(out / "pad_calibration.npz")
    assert len(written.sensors) == 4
    np.testing.assert_array_equal(written.flight.camera, [458.5, 457.855, 258.7735, 252.308, 512, 512])
    np.testing.assert_array_equal(written.flight.distortion, np.zeros(5))
    np.testing.assert_array_equal(written.flight.p_C_sensors, sensor_positions_C(0.135))

    bad = subprocess.run([*landing_sim_command(), "run", "crhf-calibration", "--set", "end_height_m=9",
                         "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert bad.returncode == 2 and "end_height_m" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_the_committed_default_calibration_matches_eq10():
    """models/crhf_pad_calibration.npz, the runtime CRHF estimator's default, is a full climb."""
    calibration = PadCalibration.load(ROOT / "models" / "crhf_pad_calibration.npz")
    assert [s.colour for s in calibration.sensors] == list(PAD_COLOURS)
    assert all(s.ranges[0] < 0.35 and s.ranges[-1] > 3.8 for s in calibration.sensors)
    implied = calibration.implied_intrinsics(sensor_positions_C(0.135))
    np.testing.assert_allclose(implied[:, :2], np.tile(EQ10[:2], (4, 1)), rtol=0.005)
    np.testing.assert_allclose(implied[:, 2:], np.tile(EQ10[2:], (4, 1)), atol=0.5)
