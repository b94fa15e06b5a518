"""The stereo left eye's pad fix (systems/perception/stereo_pad.py): the pad's centre from its markers against
the pose a synthetic view was drawn at, the World transform and the plane check, and the hybrid estimator's
use of every fix it gives."""

import math
from dataclasses import replace

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.sensors import ImageRgba8U

from diagrams.gv_landing import build_gv_landing
from diagrams.hybrid_perception import hybrid_stereo
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.velocity_observer import VelocityObserverConfig
from systems.perception.hybrid_pad import HybridPadConfig, HybridPadState, hybrid_step
from systems.perception.marker_detector import detect_marker_poses
from systems.perception.stereo_pad import StereoPadConfig, StereoPadFinder, pad_centre_in_eye
from systems.sensors.fisheye import FisheyeConfig
from tests.conftest import pose
from tests.test_markers import LAYOUT, X_CP_at, render_pad

STEREO = hybrid_stereo()
EYE = STEREO.eye()
Z_PAD = 0.5


@pytest.mark.parametrize("height_m, xy, yaw_deg", [(2.0, (0.2, -0.1), 23.0), (1.0, (0.1, 0.05), -40.0),
                                                   (0.5, (0.05, 0.0), 90.0), (0.3, (0.0, 0.02), 5.0)])
def test_pad_centre_from_the_markers(height_m, xy, yaw_deg):
    """From 2 m down to 0.3 m (only the centre marker in view), the centre within 1 % of the distance."""
    X_LP = X_CP_at(height_m, xy, yaw_deg)
    p_LP = pad_centre_in_eye(render_pad(X_LP, camera=EYE), EYE.K, LAYOUT)
    assert p_LP is not None
    assert np.linalg.norm(p_LP - X_LP.translation()) < 0.01 * height_m


@pytest.mark.parametrize("height_m, xy, yaw_deg", [(3.0, (0.4, -0.3), 60.0), (1.5, (-0.2, 0.1), -75.0),
                                                   (0.7, (0.08, 0.05), 140.0), (0.26, (0.0, 0.01), 10.0)])
def test_one_threshold_window_gives_the_default_searchs_fix(height_m, xy, yaw_deg):
    """The finder's one 23 px threshold window (StereoPadConfig) against OpenCV's three (3, 13, 23 px), from
    3 m to the last decimetres: the same markers found, the fix within 0.1 % of the distance of the default
    search's (both refine the corners on the grey image; measured: equal below 2 m, 1.0 mm apart at 3 m),
    and within 1 % of the truth."""
    X_LP = X_CP_at(height_m, xy, yaw_deg)
    image = render_pad(X_LP, camera=EYE)
    window = StereoPadConfig().threshold_window_px
    ids = [sorted(m.marker_id for m in detect_marker_poses(image, EYE.K, LAYOUT, threshold_window_px=w))
           for w in (window, None)]
    assert ids[0] == ids[1] and ids[0]
    one = pad_centre_in_eye(image, EYE.K, LAYOUT, window)
    three = pad_centre_in_eye(image, EYE.K, LAYOUT)
    assert np.linalg.norm(one - three) < 0.001 * height_m
    assert np.linalg.norm(one - X_LP.translation()) < 0.01 * height_m


@pytest.mark.parametrize("rpy_deg", [(15.0, 10.0, 0.0), (-15.0, 10.0, 0.0)])
def test_pad_centre_from_a_tilted_eye(rpy_deg):
    """The eye rolled 15 deg and pitched 10 deg at 1.5 m, so that R_LM is no longer a symmetric half turn: each
    marker's centre taken back by R_LM p_PM, the fix within 1 % of the distance (by R_LM^T instead: 6-8 cm off,
    measured)."""
    X_LP = pose([0.0, 0.0, 0.0], rpy_deg).inverse().multiply(X_CP_at(1.5, (0.1, -0.05), 20.0))
    p_LP = pad_centre_in_eye(render_pad(X_LP, camera=EYE), EYE.K, LAYOUT)
    assert p_LP is not None
    assert np.linalg.norm(p_LP - X_LP.translation()) < 0.01 * 1.5


def test_one_misplaced_marker_does_not_move_the_fix():
    """Marker 1 surveyed 0.3 m off where the pad has it (its offset in the finder's layout wrong): the five markers
    found give four centres at the pad's and one 0.3 m off, and the fix, their median, stays within 1 % of the
    distance of the truth (their mean would be 6 cm off)."""
    X_LP = X_CP_at(1.5, (0.1, -0.05), 20.0)
    image = render_pad(X_LP, camera=EYE)
    offsets = [list(o) for o in LAYOUT.offsets_m]
    offsets[LAYOUT.index(1)][0] += 0.3
    misplaced = replace(LAYOUT, offsets_m=offsets)
    assert len(detect_marker_poses(image, EYE.K, misplaced, threshold_window_px=23)) == 5
    p_LP = pad_centre_in_eye(image, EYE.K, misplaced, 23)
    assert np.linalg.norm(p_LP - X_LP.translation()) < 0.01 * 1.5


def test_no_markers_no_fix():
    assert pad_centre_in_eye(np.full((EYE.height, EYE.width), 120, np.uint8), EYE.K, LAYOUT) is None


def _finder_view(z_pad: float, config: StereoPadConfig | None = None, height_m: float = 1.0):
    """The finder and the view of a pad whose centre is at p_WP = [2, 1, 0.5], the left eye height_m over it."""
    X_LP = X_CP_at(height_m, (0.1, -0.05), 30.0)
    X_WP = RigidTransform([2.0, 1.0, Z_PAD])
    X_WB = X_WP.multiply(X_LP.inverse()).multiply(STEREO.X_BL.inverse())
    return StereoPadFinder(STEREO, LAYOUT, z_pad, config), render_pad(X_LP, camera=EYE), X_WB


@pytest.mark.parametrize("config", [None, StereoPadConfig(threshold_window_px=0)], ids=["default", "opencv-windows"])
def test_finder_places_the_pad_in_world(config):
    """With the default config and with threshold_window_px 0 (OpenCV's own three windows)."""
    finder, image, X_WB = _finder_view(Z_PAD, config)
    assert np.allclose(finder.find(image, X_WB), [2.0, 1.0, Z_PAD], atol=0.01)


def test_finder_off_the_plane_is_nan():
    finder, image, X_WB = _finder_view(Z_PAD + 0.3)
    assert np.all(np.isnan(finder.find(image, X_WB)))


@pytest.mark.parametrize("off_m, kept", [(0.10, True), (-0.10, True), (0.20, False), (-0.20, False)])
def test_finder_keeps_a_fix_within_the_height_tolerance_of_the_plane(off_m, kept):
    """The finder's plane off the pad's by less than height_tolerance_m (0.15 m) keeps the fix, at the pad's
    true centre; by more, on either side, it is NaN."""
    finder, image, X_WB = _finder_view(Z_PAD + off_m)
    p_WP = finder.find(image, X_WB)
    assert np.allclose(p_WP, [2.0, 1.0, Z_PAD], atol=0.01) if kept else np.all(np.isnan(p_WP))


@pytest.mark.parametrize("side", [1.0, -1.0], ids=["below", "above"])
@pytest.mark.parametrize("beyond, kept", [(False, True), (True, False)])
def test_a_fix_exactly_height_tolerance_m_off_the_plane_is_kept(side, beyond, kept):
    """The finder's plane exactly height_tolerance_m (0.125 m, a power of two: the difference exact) below or above
    the fix keeps it; one ulp further off, NaN."""
    finder, image, X_WB = _finder_view(Z_PAD)
    p_WP = finder.find(image, X_WB)
    z_pad = p_WP[2] - side * 0.125
    if beyond:
        z_pad = np.nextafter(z_pad, -side * np.inf)
    assert abs(p_WP[2] - z_pad) > 0.125 if beyond else abs(p_WP[2] - z_pad) == 0.125
    found = StereoPadFinder(STEREO, LAYOUT, z_pad, StereoPadConfig(height_tolerance_m=0.125)).find(image, X_WB)
    np.testing.assert_array_equal(found, p_WP if kept else np.full(3, np.nan))


@pytest.mark.parametrize("config, window", [(None, 23), (StereoPadConfig(threshold_window_px=0), None),
                                            (StereoPadConfig(threshold_window_px=13), 13)])
def test_finder_thresholds_with_its_configured_window(monkeypatch, config, window):
    """The ArUco threshold window the finder asks for: by default one of 23 px (docs/results.md, Table 7), 0 for
    OpenCV's three (None), or the one given."""
    asked = []

    def spy(image, K, layout, threshold_window_px=None):
        asked.append(threshold_window_px)
        return []

    monkeypatch.setattr("systems.perception.stereo_pad.detect_marker_poses", spy)
    blank = np.full((EYE.height, EYE.width), 120, np.uint8)
    assert np.all(np.isnan(StereoPadFinder(STEREO, LAYOUT, Z_PAD, config).find(blank, RigidTransform())))
    assert asked == [window]


@pytest.mark.parametrize("window", [0, 3, 23])
def test_threshold_windows_that_validate(window):
    """0 (OpenCV's three windows) or an odd number of pixels, at least 3."""
    StereoPadConfig(threshold_window_px=window).validate()


def _validate(config: StereoPadConfig) -> None:
    config.validate()


def _make_finder(config: StereoPadConfig) -> None:
    StereoPadFinder(STEREO, LAYOUT, Z_PAD, config)


@pytest.mark.parametrize("check", [_validate, _make_finder], ids=["validate", "finder"])
@pytest.mark.parametrize("window", [1, 4, -3])
def test_bad_threshold_windows_name_the_field(window, check):
    """1 (under 3), 4 (even) or negative: a ConfigError naming the field, from validate() and the finder built."""
    with pytest.raises(ConfigError, match="hybrid.stereo_pad.threshold_window_px"):
        check(StereoPadConfig(threshold_window_px=window))


@pytest.mark.parametrize("enabled", [True, False])
def test_disabled_fix_is_not_in_the_diagram(enabled):
    _, scenario = load_scenario("ugv-hybrid", overrides=[f"hybrid.stereo_pad.enabled={str(enabled).lower()}"])
    diagram, _ = build_gv_landing(scenario)
    assert diagram.HasSubsystemNamed("stereo_pad") == enabled


def _finder_output(max_height_m: float | None, height_m: float = 1.0) -> np.ndarray:
    """The finder system's output (p_WP [m], NaN for none) with the left eye height_m over the pad, searching up
    to max_height_m over it (None: the default)."""
    config = StereoPadConfig() if max_height_m is None else StereoPadConfig(max_height_m=max_height_m)
    finder, image, X_WB = _finder_view(Z_PAD, config, height_m)
    context = finder.CreateDefaultContext()
    frame = ImageRgba8U(EYE.width, EYE.height)
    frame.mutable_data[..., :3] = image[..., None]
    frame.mutable_data[..., 3] = 255
    finder.GetInputPort("left_image").FixValue(context, frame)
    finder.GetInputPort("X_WB").FixValue(context, X_WB)
    return finder.get_output_port().Eval(context)


@pytest.mark.parametrize("max_height_m, height_m, found", [(3.0, 1.0, True), (0.5, 1.0, False), (None, 2.9, True),
                                                            (None, 3.1, False)])
def test_finder_system_searches_only_low_over_the_pad(max_height_m, height_m, found):
    """The system's output: the fix with the eye height_m over the pad, NaN when that is above max_height_m (the
    default: 3 m)."""
    p_WP = _finder_output(max_height_m, height_m)
    assert np.allclose(p_WP, [2.0, 1.0, Z_PAD], atol=0.01 * height_m) if found else np.all(np.isnan(p_WP))


@pytest.mark.parametrize("below, found", [(False, True), (True, False)])
def test_finder_system_searches_with_the_eye_exactly_at_max_height_m(below, found):
    """max_height_m exactly the eye's height over the pad (the same sum as the finder's): searched, the fix
    found; one ulp lower, NaN."""
    _, _, X_WB = _finder_view(Z_PAD)
    eye_m = X_WB.multiply(STEREO.X_BL).translation()[2] - Z_PAD
    p_WP = _finder_output(np.nextafter(eye_m, 0.0) if below else eye_m)
    assert np.allclose(p_WP, [2.0, 1.0, Z_PAD], atol=0.01) if found else np.all(np.isnan(p_WP))


def test_finder_system_searches_by_the_eyes_height_over_the_pad():
    """max_height_m bounds the left eye's height over the pad, not the body's: with the eye 1.0 m over it and the
    body 1.05 m (the eye mounted 5 cm below), a limit between the two still searches and finds the pad."""
    _, _, X_WB = _finder_view(Z_PAD)
    eye_m, body_m = X_WB.multiply(STEREO.X_BL).translation()[2] - Z_PAD, X_WB.translation()[2] - Z_PAD
    assert eye_m < body_m - 0.04
    assert np.allclose(_finder_output((eye_m + body_m) / 2), [2.0, 1.0, Z_PAD], atol=0.01)


@pytest.mark.parametrize("height_m", [2.0, 2.9])
def test_estimator_uses_every_fix_the_finder_gives(height_m):
    """No box at all: the fix alone measures 1.45 m over the pad (inside landing_zone_m) and 2.35 m over it, above
    the zone, where the descent's finder fixes the pad within 4 mm (before: in the zone only, which the stereo's h,
    reading the UGV's roof, had put 2.5 m over the pad in the descent; the finder's max_height_m bounds it)."""
    fisheye, X_WB = FisheyeConfig(), RigidTransform([0.0, 0.0, height_m])
    h = X_WB.multiply(fisheye.X_BC).translation()[2]
    state = HybridPadState()
    for k in range(3):
        fix = np.array([0.3 + 0.05 * k, -0.2, Z_PAD + 0.02])
        state = hybrid_step(state, 0.1 * k, np.full(4, np.nan), False, h, True, X_WB, fisheye, Z_PAD,
                            HybridPadConfig(), VelocityObserverConfig(), pad_fix=fix)
    assert state.estimate.valid and state.fixed
    assert state.observer.precise == (True,) * 2  # the fixes feed the observer's line
    # on the pad's known plane, the fix's own height not used
    assert np.allclose(state.estimate.X_RT.translation(), [0.4, -0.2, Z_PAD])
    assert math.sqrt(state.estimate.covariance[3, 3]) == pytest.approx(HybridPadConfig().position_std_m)
