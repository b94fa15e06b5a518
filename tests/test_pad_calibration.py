"""Tests of the colour-pad camera-ToF calibration (seed 000, Sec. 2.3)."""

import re
import struct
import zipfile
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from systems.estimators.pad_calibration import (
    FLIGHT_RTOL,
    PAD_COLOURS,
    PAD_RGB,
    YCBCR_RANGES,
    CalibrationError,
    CalibrationFlight,
    PadCalibration,
    SensorCalibration,
    blob_centroid,
    fill_largest_blob,
    fit_hyperbola,
    pad_centroids,
    rgb_to_ycbcr,
    segment_colour,
)
from systems.sensors.tof import sensor_positions_C

FX, FY, CX, CY = 458.5, 457.855, 258.7735, 252.308  # seed 000, Eq. 10
P_C_SENSORS = sensor_positions_C(0.135)
GREY = (128, 128, 128)


def ycbcr_of(rgb):
    return rgb_to_ycbcr(np.array([[rgb]], dtype=np.uint8))[0, 0]


def colours_matching(rgb):
    ycbcr = rgb_to_ycbcr(np.array([[rgb]], dtype=np.uint8))
    return {c for c in YCBCR_RANGES if segment_colour(ycbcr, c)[0, 0]}


@pytest.mark.parametrize(
    "rgb, expected",
    [  # Eq. 11 by hand; MATLAB's rgb2ycbcr rounds these to [81 90 240], [41 240 110], ...
        ((255, 0, 0), (16 + 65.481, 128 - 37.797, 128 + 112)),
        ((0, 0, 255), (16 + 24.966, 128 + 112, 128 - 18.214)),
        ((255, 255, 255), (235, 128, 128)),
        ((0, 0, 0), (16, 128, 128)),
    ],
)
def test_eq11_on_known_colours(rgb, expected):
    np.testing.assert_allclose(ycbcr_of(rgb), expected, atol=1e-3)


def test_eq11_is_opencvs_full_range_ycrcb_rescaled_and_reordered():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=(32, 32, 3), dtype=np.uint8)
    full = cv2.cvtColor(image.astype(np.float32) / 255, cv2.COLOR_RGB2YCrCb)  # Y, Cr, Cb in [0, 1]
    y, cr, cb = np.moveaxis(full, -1, 0)
    studio = np.stack([16 + 219 * y, 128 + 224 * (cb - 0.5), 128 + 224 * (cr - 0.5)], axis=-1)
    np.testing.assert_allclose(rgb_to_ycbcr(image), studio, atol=0.1)
    rgba = np.dstack([image, np.full((32, 32), 255, np.uint8)])
    np.testing.assert_array_equal(rgb_to_ycbcr(rgba), rgb_to_ycbcr(image))


def test_table1_ranges_separate_the_pad_colours():
    for colour, rgb in PAD_RGB.items():
        assert colours_matching(rgb) == {colour}
    assert colours_matching(GREY) == set()
    assert colours_matching((0, 255, 0)) == {"green", "yellow"}  # why PAD_RGB's green is darker


@pytest.mark.parametrize("colour, channel, low_high", [("red", 2, 0), ("yellow", 0, 0), ("blue", 0, 1)])
def test_table1_bounds_are_exclusive(colour, channel, low_high):
    """segment_colour keeps a pixel strictly inside every Table 1 range: a channel on its bound is out, a
    hundredth inside it in (the other channels mid-range)."""
    ycbcr = np.array([[[np.mean(bounds) for bounds in YCBCR_RANGES[colour]]]], dtype=np.float32)
    assert segment_colour(ycbcr, colour)[0, 0] == 1
    bound = YCBCR_RANGES[colour][channel][low_high]
    ycbcr[0, 0, channel] = bound
    assert segment_colour(ycbcr, colour)[0, 0] == 0
    ycbcr[0, 0, channel] = bound + (0.01 if low_high == 0 else -0.01)
    assert segment_colour(ycbcr, colour)[0, 0] == 1


def draw_pads(rng, centres, hole=None):
    """A grey 512x512 RGB image with a 30 px disc per pad colour at sub-pixel centres, noise and a
    stray red speck; `hole` (centre, radius) punches a grey hole into the blue pad."""
    image = np.full((512, 512, 3), GREY, np.uint8)
    for colour, (u, v) in zip(PAD_COLOURS, centres):
        cv2.circle(image, (round(u * 16), round(v * 16)), 30 * 16, PAD_RGB[colour], -1, shift=4)
    if hole is not None:
        cv2.circle(image, hole[0], hole[1], GREY, -1)
    image[20:23, 250:253] = PAD_RGB["red"]
    noise = rng.normal(0, 6, size=image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)


def test_pad_centroids_find_the_drawn_centres():
    rng = np.random.default_rng(1)
    centres = np.array([[113.3, 112.8], [112.5, 400.2], [399.6, 399.9], [400.0, 112.9]])
    hole = ((410, 120), 10)  # off the blue pad's centre
    image = draw_pads(rng, centres, hole)
    found = pad_centroids(image)
    assert np.abs(found - centres).max() < 0.5
    # Without the convex hull the hole would drag the blue centroid away.
    blue = segment_colour(rgb_to_ycbcr(image), "blue")
    assert np.abs(blob_centroid(blue) - centres[3]).max() > 0.5
    # RGBA images (Drake's ImageRgba8U) work alike.
    rgba = np.dstack([image, np.full(image.shape[:2], 255, np.uint8)])
    np.testing.assert_array_equal(pad_centroids(rgba), found)


def test_a_missing_pad_gives_a_nan_row():
    image = np.full((100, 100, 3), GREY, np.uint8)
    cv2.circle(image, (50, 50), 10, PAD_RGB["green"], -1)
    found = pad_centroids(image)
    np.testing.assert_allclose(found[PAD_COLOURS.index("green")], [50, 50], atol=0.15)
    assert np.isnan(np.delete(found, PAD_COLOURS.index("green"), axis=0)).all()


def test_the_largest_blob_is_8_connected():
    """A 30 px diagonal chain (its pixels touch at corners only) beside a 25 px square: 8-connected, the chain is
    the largest blob, and its convex hull is the chain itself (a segment)."""
    chain = np.zeros((50, 50), np.uint8)
    chain[5 + np.arange(30), 5 + np.arange(30)] = 1
    mask = chain.copy()
    mask[5:10, 40:45] = 1  # 5 x 5 px in columns 40-44, clear of the chain (columns 5-34)
    np.testing.assert_array_equal(fill_largest_blob(mask, 1), chain)


@pytest.mark.parametrize("min_area_px, kept", [(20, True), (21, False)])
def test_a_blob_of_exactly_min_area_is_kept(min_area_px, kept):
    """fill_largest_blob returns None only when no blob has at least min_area_px pixels: a 4 x 5 px rectangle
    (20 px, its own convex hull) is kept with min_area_px 20 and dropped with 21."""
    mask = np.zeros((20, 20), np.uint8)
    mask[3:7, 8:13] = 1
    filled = fill_largest_blob(mask, min_area_px)
    if kept:
        np.testing.assert_array_equal(filled, mask)
    else:
        assert filled is None


def test_robust_hyperbola_fit_ignores_outliers():
    rng = np.random.default_rng(2)
    a, c = 44.43, 256.6  # Table 4
    ranges = np.linspace(0.3, 2.0, 40)
    pixels = a / ranges + c + rng.normal(0, 0.05, size=40)
    pixels[[5, 17, 30, 36]] += [25.0, -30.0, 20.0, 40.0]  # mis-segmented frames
    fit = fit_hyperbola(ranges, pixels)
    assert fit.a == pytest.approx(a, abs=0.1)
    assert fit.c == pytest.approx(c, abs=0.1)
    slope, intercept = np.polyfit(1 / ranges, pixels, 1)  # plain least squares does not
    assert abs(slope - a) + abs(intercept - c) > 1.0


def eq19_slopes(x, y):
    """Eq. 19-20 by hand (with the paper's garbled conditions read as in Fritsch-Carlson):
    interior slopes are weighted harmonic means of the neighbouring secants when those have the
    same sign and zero otherwise; end slopes are the one-sided three-point estimate, made
    shape-preserving as in SciPy's documentation (Moler's pchiptx)."""
    h = np.diff(x)
    d = np.diff(y) / h
    slopes = np.zeros_like(y)
    for k in range(1, len(x) - 1):
        if np.sign(d[k]) == np.sign(d[k - 1]) and d[k] != 0:
            w1, w2 = 2 * h[k] + h[k - 1], h[k] + 2 * h[k - 1]
            slopes[k] = (w1 + w2) / (w1 / d[k - 1] + w2 / d[k])

    def end(h0, h1, m0, m1):
        s = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        if np.sign(s) != np.sign(m0):
            return 0.0
        if np.sign(m0) != np.sign(m1) and abs(s) > 3 * abs(m0):
            return 3 * m0
        return s

    slopes[0] = end(h[0], h[1], d[0], d[1])
    slopes[-1] = end(h[-1], h[-2], d[-1], d[-2])
    return slopes


@pytest.mark.parametrize(
    "ranges, u",
    [
        # monotone with a plateau and a jump, where a cubic spline overshoots
        ([0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.3], [400.0, 390.0, 389.0, 389.0, 300.0, 295.0, 294.0]),
        # a local extremum and ends where the three-point estimate needs clipping
        ([0.3, 0.35, 0.5, 0.6, 0.9, 1.0], [100.0, 150.0, 120.0, 118.0, 130.0, 90.0]),
    ],
)
def test_pchip_interpolant_follows_eq19_and_keeps_shape(ranges, u):
    ranges, u = np.array(ranges), np.array(u)
    sensor = SensorCalibration("red", ranges, np.column_stack([u, u[::-1]]))
    np.testing.assert_allclose(sensor.interpolant(ranges)[:, 0], u)
    slopes = sensor.interpolant.derivative()(ranges)[:, 0]
    np.testing.assert_allclose(slopes, eq19_slopes(ranges, u))
    dense = np.linspace(ranges[0], ranges[-1], 2000)
    values = sensor.interpolant(dense)[:, 0]
    # Shape preservation: between nodes the curve stays within its two node values.
    segment = np.clip(np.searchsorted(ranges, dense, side="right") - 1, 0, len(ranges) - 2)
    low = np.minimum(u[segment], u[segment + 1])
    high = np.maximum(u[segment], u[segment + 1])
    assert np.all((values >= low - 1e-9) & (values <= high + 1e-9))
    assert np.any(np.diff(CubicSpline(ranges, u)(dense)) > 0)  # the property is not free


def synthetic_frames(ranges):
    """Pad centroids of each sensor projected through Eq. 10's K at the given ranges."""
    X, Y = P_C_SENSORS[:, 0], P_C_SENSORS[:, 1]
    z = np.asarray(ranges)[:, None]
    return np.stack([FX * X / z + CX, FY * Y / z + CY], axis=-1)  # (F, 4, 2)


def calibration(ranges=np.linspace(0.3, 2.0, 60)):
    per_frame = np.tile(np.asarray(ranges)[:, None], 4)
    return PadCalibration.from_frames(per_frame, synthetic_frames(ranges))


def test_touch_pixels_by_pchip_and_by_hyperbola():
    cal = calibration()
    ranges = np.array([0.45, 0.9, 1.3, 1.77])
    truth = np.array([synthetic_frames([r])[0, i] for i, r in enumerate(ranges)])
    np.testing.assert_allclose(cal.touch_pixels(ranges), truth, atol=0.05)
    np.testing.assert_allclose(cal.touch_pixels(ranges, method="hyperbola"), truth, atol=1e-6)
    outside = np.array([0.2, 1.0, 2.5, np.nan])
    pchip = cal.touch_pixels(outside)
    assert np.isnan(pchip[[0, 2, 3]]).all() and np.isfinite(pchip[1]).all()
    assert np.isfinite(cal.touch_pixels(outside[:3], method="hyperbola")).all()
    with pytest.raises(ValueError, match="unknown touch-pixel method"):
        cal.touch_pixels(ranges, method="spline")


def test_implied_intrinsics_are_the_camera_s():
    implied = calibration().implied_intrinsics(P_C_SENSORS)
    np.testing.assert_allclose(implied, np.tile([FX, FY, CX, CY], (4, 1)), rtol=1e-9)


def test_from_frames_drops_missing_samples_and_merges_repeated_ranges():
    ranges = np.tile(np.array([0.3, 0.3, 0.5, 0.7, np.nan])[:, None], 4)  # no range in frame 4
    good = synthetic_frames([0.3, 0.3, 0.5, 0.7, 1.0])
    good[0, :, 0] += 1.0  # two readings at 0.3 m, averaging to the truth
    good[1, :, 0] -= 1.0
    red = PadCalibration.from_frames(ranges, good).sensors[0]
    np.testing.assert_array_equal(red.ranges, [0.3, 0.5, 0.7])
    np.testing.assert_allclose(red.pixels, synthetic_frames([0.3, 0.5, 0.7])[:, 0])

    pixels = good.copy()
    pixels[[2, 3], 1] = np.nan  # yellow pad missed twice: only 0.3 m is left
    with pytest.raises(CalibrationError, match="yellow pad: usable samples at 1 distinct ranges"):
        PadCalibration.from_frames(ranges, pixels)


@pytest.mark.parametrize("bad_range, bad_pixel", [
    (-0.5, [450.0, 450.0]), (0.0, [450.0, 450.0]), (np.inf, [450.0, 450.0]),
    (0.8, [np.nan, 450.0]), (0.8, [450.0, np.nan]),
], ids=["negative-range", "zero-range", "infinite-range", "nan-u", "nan-v"])
def test_non_positive_or_non_finite_samples_are_dropped(bad_range, bad_pixel):
    """A sensor calibration keeps samples with a finite positive range and both pixel coordinates finite: a
    negative, zero or infinite range (with a finite pixel), or a pixel with one NaN coordinate (the other 450 px,
    off the curve), is dropped, and Eq. 18 fits the rest exactly (pixel = 100 / range + 250)."""
    ranges = np.array([bad_range, 0.5, 1.0, 1.5, 2.0])
    pixels = np.column_stack([100.0 / ranges[1:] + 250.0] * 2)
    sensor = SensorCalibration("red", ranges, np.vstack([bad_pixel, pixels]))
    np.testing.assert_array_equal(sensor.ranges, [0.5, 1.0, 1.5, 2.0])
    np.testing.assert_array_equal(sensor.pixels, pixels)
    for fit in (sensor.fit_u, sensor.fit_v):
        assert fit.a == pytest.approx(100.0, rel=1e-9) and fit.c == pytest.approx(250.0, rel=1e-9)


def test_save_load_round_trip(tmp_path):
    cal = calibration()
    path = tmp_path / "pads.npz"
    cal.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["pads.npz"]
    loaded = PadCalibration.load(path)
    for a, b in zip(cal.sensors, loaded.sensors):
        assert a.colour == b.colour and a.fit_u == b.fit_u and a.fit_v == b.fit_v
        np.testing.assert_array_equal(a.ranges, b.ranges)
        np.testing.assert_array_equal(a.pixels, b.pixels)
    ranges = [0.5, 0.6, 0.7, 0.8]
    np.testing.assert_array_equal(loaded.touch_pixels(ranges), cal.touch_pixels(ranges))


def test_the_flight_is_saved_and_loaded_and_compared_within_one_part_in_a_million(tmp_path):
    camera = SimpleNamespace(fx=FX, fy=FY, cx=CX, cy=CY, width=512, height=512, distortion=[0.0] * 5)
    flight = CalibrationFlight.of(camera, P_C_SENSORS)
    path = tmp_path / "pads.npz"
    PadCalibration(calibration().sensors, flight).save(path)
    loaded = PadCalibration.load(path).flight
    np.testing.assert_array_equal(loaded.camera, [FX, FY, CX, CY, 512, 512])
    np.testing.assert_array_equal(loaded.distortion, np.zeros(5))
    np.testing.assert_array_equal(loaded.p_C_sensors, P_C_SENSORS)
    assert flight.mismatch(loaded) is None
    assert flight.mismatch(CalibrationFlight.of(camera, sensor_positions_C(0.135 * (1 + 1e-7)))) is None
    assert flight.mismatch(CalibrationFlight.of(camera, sensor_positions_C(0.135 * (1 + 1e-5)))).startswith(
        "ToF sensors at (x, y, z) [[-0.095459, -0.095459, 0.0]")
    lower = P_C_SENSORS + [0.0, 0.0, 0.01]  # the same x and y, 1 cm lower: named by the z it differs in
    assert flight.mismatch(CalibrationFlight.of(camera, lower)).startswith(
        "ToF sensors at (x, y, z) [[-0.095459, -0.095459, 0.0]")
    assert "the scene's [[-0.095459, -0.095459, 0.01]" in flight.mismatch(CalibrationFlight.of(camera, lower))
    other_camera = SimpleNamespace(**{**vars(camera), "cy": CY + 0.01})
    assert flight.mismatch(CalibrationFlight.of(other_camera, P_C_SENSORS)) == (
        f"camera [fx, fy, cx, cy, width, height] {[FX, FY, CX, CY, 512.0, 512.0]} px, the scene's "
        f"{[FX, FY, CX, CY + 0.01, 512.0, 512.0]} px")
    calibration().save(path)
    assert PadCalibration.load(path).flight is None


def test_a_scene_with_another_number_of_tof_sensors_is_named():
    """Three ToF sensors in the scene where the flight had four: the mismatch names both layouts, rather than
    numpy failing to compare arrays of shapes (4, 3) and (3, 3)."""
    camera = SimpleNamespace(fx=FX, fy=FY, cx=CX, cy=CY, width=512, height=512, distortion=[0.0] * 5)
    flight = CalibrationFlight.of(camera, P_C_SENSORS)
    assert flight.mismatch(CalibrationFlight.of(camera, P_C_SENSORS[:3])) == (
        f"ToF sensors at (x, y, z) {np.round(P_C_SENSORS, 6).tolist()} m in C, "
        f"the scene's {np.round(P_C_SENSORS[:3], 6).tolist()} m")


@pytest.mark.parametrize("factor, accepted", [(0.5, True), (2.0, False)])
def test_the_flight_is_compared_within_flight_rtol_of_each_arrays_largest_entry(factor, accepted):
    """A scene differing from the flight by half FLIGHT_RTOL of an array's largest entry is the flight's, by
    twice it is not: the sensor arms scaled (the largest entry arm cos 45 deg) and cy moved by a fraction of
    the 512 px image width (the camera array's largest entry)."""
    camera = SimpleNamespace(fx=FX, fy=FY, cx=CX, cy=CY, width=512, height=512, distortion=[0.0] * 5)
    flight = CalibrationFlight.of(camera, P_C_SENSORS)
    arms = CalibrationFlight.of(camera, sensor_positions_C(0.135 * (1 + factor * FLIGHT_RTOL)))
    assert (flight.mismatch(arms) is None) == accepted
    moved = SimpleNamespace(**{**vars(camera), "cy": CY + factor * FLIGHT_RTOL * 512})
    assert (flight.mismatch(CalibrationFlight.of(moved, P_C_SENSORS)) is None) == accepted


def test_a_flight_through_a_lens_is_recorded_and_refused_whatever_the_scenes_lens(tmp_path):
    """CRHF takes the pad pixels as they are and the tag's corners undistorted into the pinhole image, so only a
    calibration flown without a lens has the corners' pixels, in a scene with a lens or without."""
    lens = [-0.2, 0.05, 0.001, -0.002, 0.0]
    camera = SimpleNamespace(fx=FX, fy=FY, cx=CX, cy=CY, width=512, height=512, distortion=lens)
    path = tmp_path / "lens.npz"
    PadCalibration(calibration().sensors, CalibrationFlight.of(camera, P_C_SENSORS)).save(path)
    flight = PadCalibration.load(path).flight
    np.testing.assert_array_equal(flight.distortion, lens)
    named = f"a lens, distortion [k1, k2, p1, p2, k3] {lens}, where CRHF needs none"
    for scene_lens in (lens, [0.0] * 5):
        scene = CalibrationFlight.of(SimpleNamespace(**{**vars(camera), "distortion": scene_lens}), P_C_SENSORS)
        assert flight.mismatch(scene).startswith(named)
    lens_free = CalibrationFlight.of(SimpleNamespace(**{**vars(camera), "distortion": [0.0] * 5}), P_C_SENSORS)
    assert lens_free.mismatch(CalibrationFlight.of(camera, P_C_SENSORS)) is None  # a lens-free flight fits a lens


def test_load_errors_name_the_file_and_the_problem(tmp_path):
    missing = tmp_path / "none.npz"
    with pytest.raises(CalibrationError, match=re.escape(f"{missing} does not exist")):
        PadCalibration.load(missing)

    garbage = tmp_path / "garbage.npz"
    garbage.write_text("not a calibration")
    with pytest.raises(CalibrationError, match=re.escape(f"{garbage} is unreadable")):
        PadCalibration.load(garbage)

    incomplete = tmp_path / "incomplete.npz"
    np.savez(incomplete, colours=np.array(PAD_COLOURS), ranges_0=np.ones(3))
    message = f"{incomplete} lacks the arrays ['pixels_0'"
    with pytest.raises(CalibrationError, match=re.escape(message)):
        PadCalibration.load(incomplete)

    short = tmp_path / "short.npz"
    ranges = np.array([0.3, 0.4, 0.5])
    arrays = {"colours": np.array(PAD_COLOURS)}
    for i in range(4):
        keep = slice(2) if PAD_COLOURS[i] == "green" else slice(None)
        arrays[f"ranges_{i}"] = ranges[keep]
        arrays[f"pixels_{i}"] = synthetic_frames(ranges)[keep, i]
    np.savez(short, **arrays)
    message = f"{short}: green pad: usable samples at 2 distinct ranges"
    with pytest.raises(CalibrationError, match=re.escape(message)):
        PadCalibration.load(short)

    message = ("the flight needs flight_camera (6,), flight_distortion (5,) and flight_p_C_sensors (4, 3); "
               "re-run `landing-sim run crhf-calibration` to write them")
    half_flight = tmp_path / "half_flight.npz"  # a flight's camera without its sensors
    np.savez(half_flight, **arrays, flight_camera=np.array([FX, FY, CX, CY, 512.0, 512.0]))
    with pytest.raises(CalibrationError, match=re.escape(f"{half_flight}: {message}")):
        PadCalibration.load(half_flight)
    no_lens = tmp_path / "no_lens.npz"  # written before the flight's lens was recorded
    np.savez(no_lens, **arrays, flight_camera=np.array([FX, FY, CX, CY, 512.0, 512.0]), flight_p_C_sensors=P_C_SENSORS)
    with pytest.raises(CalibrationError, match=re.escape(f"{no_lens}: {message}")):
        PadCalibration.load(no_lens)


def cut_in_half(path):
    """A saved calibration truncated to its first half: the zip's magic is there, its central directory is not."""
    PadCalibration(calibration().sensors).save(path)
    content = path.read_bytes()
    path.write_bytes(content[: len(content) // 2])


def a_member_damaged(path):
    """A saved calibration with one bit of pixels_0's last value flipped: the archive opens, the member's CRC-32
    fails when it is read."""
    PadCalibration(calibration().sensors).save(path)
    with zipfile.ZipFile(path) as archive:
        member = archive.getinfo("pixels_0.npy")
    content = bytearray(path.read_bytes())
    name_length, extra_length = struct.unpack("<HH", content[member.header_offset + 26: member.header_offset + 30])
    content[member.header_offset + 30 + name_length + extra_length + member.compress_size - 1] ^= 1
    path.write_bytes(bytes(content))


def plain_array(path):
    """One array written by np.save (a .npy file) under the .npz name."""
    with open(path, "wb") as f:
        np.save(f, np.ones(3))


@pytest.mark.parametrize("write, magic, problem", [
    (cut_in_half, b"PK\x03\x04", "is unreadable: "),
    (a_member_damaged, b"PK\x03\x04", "is unreadable: Bad CRC-32 for file 'pixels_0.npy'"),
    (plain_array, b"\x93NUMPY", "is not an .npz archive"),
], ids=["cut-in-half", "member-damaged", "plain-array"])
def test_a_damaged_or_non_npz_file_is_a_calibration_error_naming_the_file(tmp_path, write, magic, problem):
    """A truncated archive or a damaged member (zipfile's BadZipFile, neither an OSError nor a ValueError, raised
    by np.load or when the member is read) or a single .npy array (np.load returns an ndarray, not an archive): a
    CalibrationError naming the file and the problem."""
    path = tmp_path / "pads.npz"
    write(path)
    assert path.read_bytes().startswith(magic)  # np.load takes the first for an archive, the second for an array
    with pytest.raises(CalibrationError, match=re.escape(f"pad calibration file {path} {problem}")):
        PadCalibration.load(path)


@pytest.mark.parametrize("bad, problem", [
    ({"pixels_0": np.array([{"u": 1.0}], dtype=object)}, "is unreadable: Object arrays cannot be loaded"),
    ({"flight_camera": np.array(["a"] * 6), "flight_distortion": np.zeros(5), "flight_p_C_sensors": P_C_SENSORS},
     ": could not convert string to float"),
], ids=["object-array", "flight-of-text"])
def test_an_array_that_is_no_numbers_is_a_calibration_error_naming_the_file(tmp_path, bad, problem):
    """An array numpy will not load without pickle (an object array), or a flight array of text of the right shape:
    a CalibrationError naming the file, not numpy's bare ValueError (CRHF loads the file at build time)."""
    path = tmp_path / "pads.npz"
    PadCalibration(calibration().sensors).save(path)
    with np.load(path) as data:
        arrays = dict(data)
    np.savez(path, **{**arrays, **bad})
    with pytest.raises(CalibrationError, match=re.escape(f"pad calibration file {path}") + ".*" + re.escape(problem)):
        PadCalibration.load(path)


@pytest.mark.parametrize("wrong", [{"flight_camera": np.zeros(5)}, {"flight_distortion": np.zeros(4)},
                                   {"flight_p_C_sensors": np.zeros((3, 3))}], ids=["camera", "distortion", "sensors"])
def test_a_flight_array_of_the_wrong_shape_is_refused_at_load(tmp_path, wrong):
    """All three flight arrays present but one of the wrong shape: a CalibrationError naming the file and the
    shapes, not a flight that fails later."""
    flight = {"flight_camera": np.array([FX, FY, CX, CY, 512.0, 512.0]), "flight_distortion": np.zeros(5),
              "flight_p_C_sensors": P_C_SENSORS}
    path = tmp_path / "wrong_shape.npz"
    PadCalibration(calibration().sensors).save(path)
    with np.load(path) as data:
        arrays = dict(data)
    np.savez(path, **arrays, **{**flight, **wrong})
    message = "the flight needs flight_camera (6,), flight_distortion (5,) and flight_p_C_sensors (4, 3)"
    with pytest.raises(CalibrationError, match=re.escape(f"{path}: {message}")):
        PadCalibration.load(path)
