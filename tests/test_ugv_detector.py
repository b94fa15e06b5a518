"""Seed 003's UGV detectors (Sec. 2.2.1; systems/perception/ugv_detector.py) on rendered held-out fisheye
frames (diagrams/ugv_detection_scenes.py): both find the UGV and not a distractor of another colour; the
true box's and the pad centre's projections against hand cases; greedy NMS, Table 3's matching and the
classical detector's strip and roof tests on hand cases; the scenes' placement rules, and rendered frames
against their true boxes, their blur and the frame cache. The learned detector's own parts:
tests/test_ugv_cnn_detector.py."""

import dataclasses
import math
import re

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.sensors import ImageRgba8U

from diagrams.ugv_detection_scenes import (
    HELD_OUT_SEEDS,
    UgvScene,
    UgvSceneConfig,
    UgvSceneRenderer,
    box_surface_points,
    distractor_boxes,
    distractor_pool,
    load_or_render_dataset,
    motion_blur,
    pad_centre_pixel,
    projected_box,
    sample_scene,
    seed003_ugv_platform,
    ugv_bounds_V,
    ugv_box,
)
from systems.config import ConfigError
from systems.perception.box_tracker import iou
from systems.perception.ugv_cnn_detector import CnnDetector
from systems.perception.ugv_detector import (
    ColourPadConfig,
    ColourPadDetector,
    UgvDetectorSystem,
    _Part,
    match_truth,
    non_maximum_suppression,
    to_rgb,
)
from systems.sensors.fisheye import FisheyeConfig, theta_distorted

FRAMES = 3  # held-out frames rendered for the detectors


# ---------------------------------------------------------------- the true box


def test_true_box_of_a_square_under_the_lens_matches_the_hand_projection():
    """A flat square of half-side a, d below the lens on its axis: its box spans the radius of its edges'
    midpoints, f theta_d(atan(a / d)) either side of the principal point, not its corners' (whose radius
    is larger but whose x is r / sqrt 2 = smaller: the edges bow outwards)."""
    config = FisheyeConfig()
    a, d = 0.5, 2.0
    box = projected_box(box_surface_points([-a, -a, d], [a, a, d]), config)
    r = config.f * theta_distorted(math.atan(a / d), config.k1, config.k2)
    centre = config.cx + 0.5  # pixel-index space: a point at u lies at u + 0.5
    np.testing.assert_allclose(box, [centre - r, centre - r, 2 * r, 2 * r], atol=1e-6)
    corner_r = config.f * theta_distorted(math.atan(a * math.sqrt(2) / d), config.k1, config.k2)
    assert corner_r / math.sqrt(2) < r - 0.9  # the corners alone: a box about 2 px narrower


@pytest.mark.parametrize("heading, direction", [(0.0, (1.0, 0.0)), (math.pi / 2, (0.0, -1.0))])
def test_pad_centre_pixel_matches_the_hand_projection(heading, direction):
    """The lens 7.5 m up over the UGV's origin looking straight down (C's x = W's x, C's y = -W's y): the pad's
    centre, pad_offset_m ahead of the origin and 0.5 m up, is f theta_d(atan(0.45 / 7)) px from the principal
    point, to the right at heading 0, up the image at 90 deg. Absent, or beyond the rim: None."""
    config = UgvSceneConfig()
    X_WC = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), [0.0, 0.0, 7.5])
    X_WB = X_WC.multiply(config.fisheye.X_BC.inverse())
    scene = UgvScene(0, X_WB, np.array([0.0, 0.0, heading, 0.0]), [], 0.0, 0.0, False)
    f = config.fisheye
    r = f.f * theta_distorted(math.atan(config.platform.pad_offset_m / (7.5 - config.platform.height_m)), f.k1, f.k2)
    np.testing.assert_allclose(pad_centre_pixel(scene, config), np.array([f.cx, f.cy]) + r * np.array(direction),
                               atol=1e-6)
    assert pad_centre_pixel(dataclasses.replace(scene, ugv_state=None), config) is None
    far = dataclasses.replace(scene, ugv_state=np.array([60.0, 0.0, 0.0, 0.0]))  # 83 deg off the axis
    assert pad_centre_pixel(far, config) is None
    # Just past the 75 deg rim: the pad 30.45 m out and 7 m down, atan(30.45 / 7) = 77.05 deg off the axis.
    just_beyond = dataclasses.replace(scene, ugv_state=np.array([30.0, 0.0, 0.0, 0.0]))
    assert math.degrees(math.atan(30.45 / 7.0)) > config.fisheye.fov_deg / 2
    assert pad_centre_pixel(just_beyond, config) is None


@pytest.mark.parametrize("changes, low, high", [
    ({}, [-0.25, -0.55, 0.0], [1.15, 0.55]),
    ({"rear_overhang_m": 0.05, "body_length_m": 1.0}, [-0.12, -0.55, 0.0], [1.02, 0.55]),
], ids=["seed003", "wheels-outside-the-body"])
def test_ugv_bounds_enclose_body_wheels_and_pad(changes, low, high):
    """Seed 003's UGV (1.4 x 1.0 m body from 0.25 m behind V's origin, the 1.0 m pad centred 0.45 m ahead,
    0.12 m wheels on axles at x 0 and the 0.9 m wheelbase, half their 0.1 m width outside the body): x from
    the body's rear -0.25 to its front 1.15, y +-(0.5 + 0.05). With the body 1.0 m long from 0.05 m behind
    the axle, the wheels stick out: x from the rear wheel's -0.12 to the front wheel's 0.9 + 0.12 = 1.02.
    Up to the pad's top, height_m (0.5 m) (within a mm)."""
    platform = dataclasses.replace(seed003_ugv_platform(), **changes)
    lower, upper = ugv_bounds_V(platform, wheelbase_m=0.9)
    np.testing.assert_allclose(lower, low, atol=1e-12)
    np.testing.assert_allclose(upper[:2], high, atol=1e-12)
    assert platform.height_m <= upper[2] <= platform.height_m + 0.002


def test_a_box_under_min_box_px_in_one_direction_only_is_none():
    """A 1.0 x 0.002 m bar 2 m down the axis: f theta_d(atan(0.25)) either side, about 98 px wide, but 0.2 px
    tall (under min_box_px 3 px): None. Turned 90 deg: None too."""
    config = FisheyeConfig()
    assert 2 * config.f * theta_distorted(math.atan(0.25), config.k1, config.k2) > 90
    assert projected_box(box_surface_points([-0.5, -0.001, 2.0], [0.5, 0.001, 2.0]), config) is None
    assert projected_box(box_surface_points([-0.001, -0.5, 2.0], [0.001, 0.5, 2.0]), config) is None


def test_a_distractor_under_the_lens_is_centred_on_the_principal_point():
    """A pool box (longer than wide) at the origin, heading 0, the lens 7.5 m up looking straight down: its
    base centred on D's origin, so its box is centred on the principal point (cx + 0.5 in pixel-index space),
    wider (along x) than tall."""
    config = UgvSceneConfig()
    pool = distractor_pool(config)
    index = 0
    assert pool[index].size_m[0] > pool[index].size_m[1]
    X_WC = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), [0.0, 0.0, 7.5])
    scene = UgvScene(0, X_WC.multiply(config.fisheye.X_BC.inverse()), None, [(index, RigidTransform())], 0.0, 0.0,
                     False)
    [(x, y, w, h)] = distractor_boxes(scene, config, pool)
    f = config.fisheye
    np.testing.assert_allclose([x + w / 2, y + h / 2], [f.cx + 0.5, f.cy + 0.5], atol=1e-6)
    assert w > h


@pytest.mark.parametrize("changes", [
    {"height_range_m": [5.0, 5.0]}, {"small_height_range_m": [8.0, 8.0]}, {"small_off_axis_range_deg": [60.0, 60.0]},
    {"small_fraction": 0.5, "empty_fraction": 0.5}, {"small_fraction": 1.0, "empty_fraction": 0.0},
    {"max_distractors": 18}, {"max_distractors": 0}, {"tilt_max_deg": 0.0},
    {"max_off_axis_deg": 74.9}, {"distractor_off_axis_max_deg": 74.9}, {"small_off_axis_range_deg": [55.0, 74.9]},
])
def test_scene_settings_at_their_limits_are_accepted(changes):
    """Equal low and high; fractions summing to exactly 1; one distractor per pool box (18: 2 of 9 colours);
    angles just inside the fisheye's 75 deg half field of view."""
    assert len(distractor_pool(UgvSceneConfig())) == 18
    UgvSceneConfig(**changes).validate()


@pytest.mark.parametrize("changes, name", [
    ({"height_range_m": [5.0, 4.0]}, "height_range_m"), ({"height_range_m": [0.0, 4.0]}, "height_range_m"),
    ({"small_fraction": 0.6, "empty_fraction": 0.6}, "small_fraction"), ({"small_fraction": 1.1}, "small_fraction"),
    ({"max_distractors": 19}, "max_distractors"), ({"max_distractors": -1}, "max_distractors"),
    ({"max_off_axis_deg": 75.0}, "max_off_axis_deg"), ({"max_off_axis_deg": 0.0}, "max_off_axis_deg"),
    ({"distractor_off_axis_max_deg": 75.0}, "distractor_off_axis_max_deg"),
    ({"small_off_axis_range_deg": [55.0, 75.0]}, "small_off_axis_range_deg"), ({"tilt_max_deg": 45.0}, "tilt_max_deg"),
    ({"max_blur_px": -1.0}, "max_blur_px"),
])
def test_scene_settings_past_their_limits_name_the_field(changes, name):
    with pytest.raises(ConfigError, match=rf"ugv_scenes\.{name}"):
        UgvSceneConfig(**changes).validate()


def test_sampled_scenes_follow_the_documented_draws():
    """Over 300 held-out draws: a small-target frame always shows the UGV; the other frames' UGV centres are
    uniform in solid angle up to max_off_axis_deg (62 deg), so (1 - cos 31) / (1 - cos 62) = 0.27 of them lie
    within 31 deg (uniform in angle: 0.5); some frame shows a distractor of the UGV's own colour; blur never
    exceeds max_blur_px and rarely reaches it (speed x exposure x f / height passes 15 px only for speeds over
    7.5 m/s at heights under 2.1 m), and with max_blur_px 3 it caps some frames; the UAV anywhere over the
    ground's middle (0.3 of its size either way)."""
    config = UgvSceneConfig()
    pool = distractor_pool(config)
    low, high = ugv_bounds_V(config.platform)
    centre_V = np.array([*(low[:2] + high[:2]) / 2, config.platform.height_m / 2])
    near, far, same_colour, blurred, capped = 0, 0, 0, 0, 0
    reach = 0.3 * config.ground.size_m
    positions = []
    for seed in HELD_OUT_SEEDS[:300]:
        scene = sample_scene(seed, config, pool)
        positions.append(scene.X_WB.translation()[:2])
        if scene.small:
            assert scene.ugv_state is not None, f"seed {seed}: a small-target frame without the UGV"
        elif scene.ugv_state is not None:
            x, y, heading, _ = scene.ugv_state
            p_Wcentre = RigidTransform(RollPitchYaw(0.0, 0.0, heading), [x, y, 0.0]).multiply(centre_V)
            p_C = scene.X_WB.multiply(config.fisheye.X_BC).inverse().multiply(p_Wcentre)
            if math.degrees(math.atan2(math.hypot(p_C[0], p_C[1]), p_C[2])) < 31.0:
                near += 1
            else:
                far += 1
        same_colour += any(pool[index].colour == "ugv" for index, _ in scene.distractors)
        assert 0.0 <= scene.blur_px <= config.max_blur_px, f"seed {seed}"
        blurred += scene.blur_px > 0
        capped += scene.blur_px == config.max_blur_px
    expected = (1 - math.cos(math.radians(31))) / (1 - math.cos(math.radians(62)))
    assert expected == pytest.approx(0.27, abs=0.005)
    assert 0.17 <= near / (near + far) <= 0.37
    assert same_colour > 0
    assert blurred > 0 and capped < 0.1 * blurred
    assert np.abs(positions).max() <= reach
    assert np.all(np.min(positions, axis=0) < -0.5 * reach) and np.all(np.max(positions, axis=0) > 0.5 * reach)
    low_cap = dataclasses.replace(config, max_blur_px=3.0)
    blur = np.array([sample_scene(seed, low_cap, pool).blur_px for seed in HELD_OUT_SEEDS[:300]])
    assert blur.max() == low_cap.max_blur_px


def test_true_box_is_clipped_to_the_field_of_view_and_none_behind_the_lens():
    config = FisheyeConfig()
    assert projected_box(box_surface_points([-0.5, -0.5, -3.0], [0.5, 0.5, -2.0]), config) is None
    # A long bar from the axis out past the 75 deg rim along +x: its box stops at the rim's radius.
    box = projected_box(box_surface_points([0.0, -0.05, 1.0], [20.0, 0.05, 1.0]), config)
    assert box[0] + box[2] == pytest.approx(config.cx + 0.5 + config.radius_px, abs=0.3)


def test_points_behind_the_lens_do_not_count_at_the_rim():
    """A bar from (1, 0, 1) m, 45 deg off the axis along +x, down through the lens's plane to (-1, 0, -5),
    behind it: its box runs from the 45 deg point out to the rim at azimuth 0 (where it leaves the view in
    front of the lens), not across to the rim at azimuth 180 deg (its part behind the lens lies at x < 0)."""
    config = FisheyeConfig()
    t = np.linspace(0.0, 1.0, 601)[:, None]
    bar = np.vstack([np.array([1.0, y, 1.0]) + t * np.array([-2.0, 0.0, -6.0]) for y in (-0.05, 0.0, 0.05)])
    box = projected_box(bar, config)
    centre = config.cx + 0.5  # pixel-index space
    assert box[0] == pytest.approx(centre + config.f * theta_distorted(math.pi / 4, config.k1, config.k2), abs=0.5)
    assert box[0] + box[2] == pytest.approx(centre + config.radius_px, abs=1e-6)


def test_scene_draws_repeat_and_give_boxes_in_the_image():
    config = UgvSceneConfig()
    pool = distractor_pool(config)
    first, again = sample_scene(HELD_OUT_SEEDS[0], config, pool), sample_scene(HELD_OUT_SEEDS[0], config, pool)
    assert np.array_equal(first.X_WB.GetAsMatrix4(), again.X_WB.GetAsMatrix4())
    present, distractors = 0, 0
    for seed in HELD_OUT_SEEDS[:50]:
        scene = sample_scene(seed, config, pool)
        ugv = ugv_box(scene, config)
        # The UGV centre is placed within max_off_axis_deg (inside the half field of view): in the image when drawn.
        assert (ugv is None) == (scene.ugv_state is None)
        present += ugv is not None
        others = [box for box in distractor_boxes(scene, config, pool) if box is not None]
        distractors += len(others)
        for box in ([] if ugv is None else [ugv]) + others:
            assert box[0] >= 0 and box[1] >= 0 and box[0] + box[2] <= 512 and box[1] + box[3] <= 512
    assert present >= 40 and distractors > 0  # measured: the UGV in 47 of the 50 frames, 97 distractor boxes


def test_sampled_scenes_keep_their_placement_rules():
    """Over 300 held-out draws: the UGV's centre (the middle of its bounding box, half its height up) within
    max_off_axis_deg of the fisheye's axis (small-target frames: small_off_axis_range_deg), no pool box shown
    twice in a frame, and the UGV's and the distractors' centres at least min_separation_m apart."""
    config = UgvSceneConfig()
    pool = distractor_pool(config)
    low, high = ugv_bounds_V(config.platform)
    centre_V = np.array([*(low[:2] + high[:2]) / 2, config.platform.height_m / 2])
    for seed in HELD_OUT_SEEDS[:300]:
        scene = sample_scene(seed, config, pool)
        slots = [index for index, _ in scene.distractors]
        assert len(slots) == len(set(slots)), f"seed {seed}: a pool box shown twice"
        spots = [X_WD.translation()[:2] for _, X_WD in scene.distractors]
        if scene.ugv_state is not None:
            x, y, heading, _ = scene.ugv_state
            p_Wcentre = RigidTransform(RollPitchYaw(0.0, 0.0, heading), [x, y, 0.0]).multiply(centre_V)
            p_C = scene.X_WB.multiply(config.fisheye.X_BC).inverse().multiply(p_Wcentre)
            limit = config.small_off_axis_range_deg[1] if scene.small else config.max_off_axis_deg
            assert math.degrees(math.atan2(math.hypot(p_C[0], p_C[1]), p_C[2])) <= limit + 1e-9, f"seed {seed}"
            spots.insert(0, p_Wcentre[:2])
        for k, a in enumerate(spots):
            for b in spots[k + 1:]:
                assert np.linalg.norm(a - b) >= config.min_separation_m - 1e-9, f"seed {seed}: centres too close"


@pytest.mark.parametrize("length_px, angle_rad", [(8.0, 0.0), (9.0, math.pi / 2), (1.5, math.pi), (6.0, 0.7)])
def test_motion_blur_smears_a_point_evenly_along_its_direction_about_itself(length_px, angle_rad):
    """A point's smear keeps its brightness and its centroid (the exposure's middle), spreads as a uniform segment
    of length L along the direction and stays on its line: a smear along a row leaves the other rows dark (the
    line kernel drawn before leaked a tenth of it into the next row, 0.1 px off centre)."""
    image = np.zeros((31, 31), np.float32)
    image[15, 15] = 1.0
    smear = motion_blur(image, length_px, angle_rad)
    rows, cols = np.mgrid[:31, :31] - 15.0
    direction = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    along, across = cols * direction[0] + rows * direction[1], -cols * direction[1] + rows * direction[0]
    assert smear.sum() == pytest.approx(1.0, abs=1e-5)
    assert (smear * cols).sum() == pytest.approx(0.0, abs=1e-5)
    assert (smear * rows).sum() == pytest.approx(0.0, abs=1e-5)
    # the segment's L^2 / 12 and the bilinear sharing of its sub-pixel positions, a (1 - a) on average 1 / 6 px^2
    assert math.sqrt((smear * along**2).sum()) == pytest.approx(math.sqrt(length_px**2 / 12 + 1 / 6), rel=0.1)
    assert math.sqrt((smear * across**2).sum()) < 0.6
    if angle_rad in (0.0, math.pi):
        assert not smear[np.arange(31) != 15].any()
    assert motion_blur(image, 0.4, 1.0) is image  # under half a pixel: no smear


def test_nms_keeps_the_best_and_drops_only_what_overlaps_a_kept_box():
    keep = non_maximum_suppression(np.array([[0, 0, 10, 10], [1, 1, 10, 10], [30, 30, 10, 10]]),
                                   np.array([0.6, 0.9, 0.5]), 0.3)
    assert list(keep) == [1, 2]
    boxes, scores = np.array([[0, 0, 40, 40], [2, 2, 12, 12]]), np.array([0.9, 0.7])  # IOU 0.09, all inside
    assert list(non_maximum_suppression(boxes, scores, 0.3)) == [0, 1]
    # An empty box overlaps nothing: IOU 0 (box_tracker's, Eq. 2), not 0 / 0 = NaN, so it is not dropped.
    assert list(non_maximum_suppression(np.array([[0, 0, 10, 10], [50, 50, 0, 0]]), np.array([0.9, 0.8]), 0.3)) \
        == [0, 1]


def test_nms_keeps_a_box_whose_iou_equals_the_threshold():
    """A box goes only when its IOU exceeds the threshold: [0, 0, 10, 5] inside [0, 0, 10, 10] has IOU 50 / 100 =
    0.5, so at 0.5 it stays."""
    boxes, scores = np.array([[0, 0, 10, 10], [0, 0, 10, 5]]), np.array([0.9, 0.8])
    assert list(non_maximum_suppression(boxes, scores, 0.5)) == [0, 1]


def test_nms_keeps_at_most_max_keep_boxes_the_best_first():
    boxes = np.array([[0, 0, 10, 10], [20, 0, 10, 10], [40, 0, 10, 10], [60, 0, 10, 10]])  # none overlapping
    scores = np.array([0.5, 0.9, 0.7, 0.8])
    assert list(non_maximum_suppression(boxes, scores, 0.3, max_keep=2)) == [1, 3]
    assert list(non_maximum_suppression(boxes, scores, 0.3)) == [1, 3, 2, 0]


def test_match_truth_takes_the_best_scoring_overlap_only():
    truth = np.array([10.0, 10.0, 20.0, 20.0])
    detections = [(np.array([11.0, 10.0, 20.0, 20.0]), 0.6), (np.array([10.0, 12.0, 20.0, 20.0]), 0.9),
                  (np.array([100.0, 100.0, 20.0, 20.0]), 0.95)]
    _, scores, matched = match_truth(detections, truth)
    assert list(matched) == [False, True, False] and list(scores) == [0.6, 0.9, 0.95]
    assert not match_truth(detections, None)[2].any()


@pytest.mark.parametrize("dx, matched", [(8.0, False), (0.0, True)])
def test_match_truth_needs_an_iou_of_one_half(dx, matched):
    """Table 3's true positive needs IOU >= 0.5 with the true box: a detection shifted 8 px along a 20 px box
    (IOU 240 / 560 = 0.43) is not one; half the true box (IOU exactly 0.5) is."""
    truth = np.array([0.0, 0.0, 20.0, 20.0])
    box = np.array([dx, 0.0, 20.0, 20.0]) if dx else np.array([0.0, 0.0, 20.0, 10.0])
    assert list(match_truth([(box, 0.9)], truth)[2]) == [matched]


@pytest.mark.parametrize("field, value, message", [
    ("max_strip_angle_deg", -5.0, "must lie in (0, 90]"), ("max_strip_angle_deg", 0.0, "must lie in (0, 90]"),
    ("max_strip_angle_deg", 91.0, "must lie in (0, 90]"), ("min_part_px", -1, "must be an integer of at least 1"),
    ("min_part_px", 0, "must be an integer of at least 1"), ("min_part_px", 2.5, "must be an integer of at least 1"),
    ("min_box_px", -3, "must be an integer of at least 1"), ("min_shaped_part_px", -1.0, "must not be negative")])
def test_bad_classical_settings_name_the_field(field, value, message):
    """Settings that silently lose the UGV (no strip pair passes a negative angle) or mean nothing (a negative
    pixel count) are refused."""
    with pytest.raises(ConfigError, match=rf"hybrid\.classical\.{field} {re.escape(message)}"):
        ColourPadConfig(**{field: value}).validate("hybrid.classical")
    ColourPadConfig(max_strip_angle_deg=90.0, min_part_px=1, min_box_px=1, min_shaped_part_px=0.0).validate()


def test_detectors_refuse_an_image_that_is_not_uint8():
    with pytest.raises(ConfigError, match="uint8 image, got \\(4, 4, 3\\) float32"):
        to_rgb(np.zeros((4, 4, 3), np.float32))


# ---------------------------------------------------------------- the classical detector on hand cases

BODY = (191, 77, 38)  # GroundVehicleGeometry's (0.75, 0.3, 0.15)


def strip(x: float, y: float, length: float, width: float, angle: float = 0.0) -> _Part:
    """A body-coloured part centred at (x, y) px, its long axis at `angle` rad (only its shape: no pixels)."""
    return _Part(np.zeros((1, 2), np.int32), np.array([x, y]), length, width, angle)


@pytest.mark.parametrize("p, q, paired", [
    (strip(0, 0, 30, 8), strip(0, 30, 30, 8), True),  # side by side, a length apart: the UGV's end strips
    (strip(0, 0, 30, 8), strip(0, 30, 30, 8, math.pi / 2), False),  # at right angles (over 27 deg)
    (strip(0, 0, 30, 8), strip(40, 0, 30, 8), False),  # end to end: the offset runs along the strips
    (strip(0, 0, 30, 28), strip(0, 30, 30, 28), False),  # squares, not strips (elongation 1.07 < 1.6)
    (strip(0, 0, 20, 5), strip(0, 20, 12, 10), False),  # one a strip (4), the other not (1.2 < 1.6)
    (strip(0, 0, 30, 8), strip(0, 3, 30, 8), False),  # 3 px apart: under 0.3 of their length
    (strip(0, 0, 30, 8), strip(0, 45, 90, 8), False),  # lengths 1 : 3 (over 2.5)
], ids=["pair", "crossed", "end-to-end", "not-elongated", "one-not-elongated", "too-close", "unequal"])
def test_each_strip_test_alone_rejects_a_pair(p, q, paired):
    """ColourPadConfig's strip tests, one failing at a time on parts that pass all the others."""
    detector = ColourPadDetector()
    assert detector._strip_pair(p, q) is paired
    assert detector._strip_pair(q, p) is paired


TURNED = math.pi / 4
SLANT, ACROSS = 0.2, 0.2 + math.radians(35.0)


@pytest.mark.parametrize("p, q", [
    (strip(0, 0, 20, 5, TURNED), strip(-20 * math.sin(TURNED), 20 * math.cos(TURNED), 20, 5, TURNED)),
    (strip(0, 0, 20, 5, SLANT), strip(20 * math.cos(ACROSS), 20 * math.sin(ACROSS), 20, 5, SLANT)),
    (strip(0, 0, 20, 5), strip(0, 14, 8, 4)),
], ids=["turned-45-deg", "offset-35-deg-off-across", "length-ratio-2.5"])
def test_strips_pair_turned_off_the_image_axes_and_at_the_limits(p, q):
    """Pairs that pass every strip test: parallel strips at 45 deg side by side (their angle apart 0, not their
    sum's 90 deg); parallel strips at 0.2 rad whose offset is 35 deg off straight across (along their mean
    axis 20 cos 35 deg = 16.4 <= 0.85 * 20 = 17 px; not the 45 deg axis of cos 2a - cos 2b = 0, along which it
    would be 20.0 px); lengths 20 : 8, exactly max_length_ratio 2.5."""
    detector = ColourPadDetector()
    assert detector.config.max_length_ratio == 2.5
    assert detector._strip_pair(p, q) is True
    assert detector._strip_pair(q, p) is True


@pytest.mark.parametrize("p, q, paired", [
    (strip(0, 0, 15, 3), strip(0, 12, 7, 3, math.pi / 2), False),  # the longer 15 px: the shape tests apply
    (strip(0, 0, 7, 3), strip(0, 8, 6, 3, math.pi / 2), True),  # both under 8 px: only sizes and distance count
], ids=["one-long-enough", "both-short"])
def test_shape_tests_apply_once_the_longer_part_reaches_min_shaped_part_px(p, q, paired):
    """Crossed parts of lengths 15 : 7 (or 7 : 6) that pass the length ratio and distance tests: rejected as at
    right angles when the longer is at least min_shaped_part_px (8) long, accepted when both are shorter."""
    detector = ColourPadDetector()
    assert detector._strip_pair(p, q) is paired
    assert detector._strip_pair(q, p) is paired


def grey_ground() -> np.ndarray:
    return np.full((200, 300, 3), 110, np.uint8)


@pytest.mark.parametrize("rows, cols, length, width, vertical", [
    ((50, 60), (100, 140), 40.0, 10.0, False), ((50, 51), (100, 140), 40.0, 1.0, False),
    ((50, 90), (100, 110), 40.0, 10.0, True)], ids=["40x10", "one-pixel-line", "10x40"])
def test_a_drawn_body_rectangle_is_one_part_of_its_pixel_extent(rows, cols, length, width, vertical):
    """A body-coloured rectangle of whole pixels is one part whose long and short sides are its pixels' extent (a
    one-pixel line 1 px wide, not 0), its centre the pixels' mean, its long axis along the longer side."""
    image = grey_ground()
    image[rows[0]:rows[1], cols[0]:cols[1]] = BODY
    detector = ColourPadDetector()
    [part] = detector.parts(detector.masks(image)[0])
    assert (part.length, part.width) == (length, width)
    np.testing.assert_allclose(part.centre, [(cols[0] + cols[1] - 1) / 2, (rows[0] + rows[1] - 1) / 2])
    assert abs(math.sin(part.angle)) == pytest.approx(1.0 if vertical else 0.0, abs=1e-9)


def test_a_dark_pixel_of_the_bodys_hue_is_not_body():
    """RGB (10, 4, 2): hue 15 deg (OpenCV's 7-8) and saturation 204 inside the body's band, value 10 under
    min_value 20: too dark to be the body."""
    image = np.full((3, 3, 3), (10, 4, 2), np.uint8)
    h, s, v = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)[0, 0].tolist()
    config = ColourPadConfig()
    assert config.hue_low <= h <= config.hue_high and s >= config.min_saturation and v < config.min_value
    assert not ColourPadDetector(config).masks(image)[0].any()


@pytest.mark.parametrize("length, count", [(2, 0), (3, 1)])
def test_a_part_needs_min_part_px_pixels(length, count):
    """A one-pixel line of `length` px (unchanged by the 3 x 3 closing) is a part from min_part_px (3) pixels."""
    body = np.zeros((20, 20), np.uint8)
    body[10, 5:5 + length] = 255
    detector = ColourPadDetector()
    assert detector.config.min_part_px == 3
    assert len(detector.parts(body)) == count


def test_a_strip_belongs_to_one_ugv_only():
    """Three body-coloured strips with the pad's white between each two: the middle strip is paired once, so one
    roof is found (the first pair's, rows 60-110), not also the two others sharing its strips."""
    image = grey_ground()
    for y in (60, 100, 140):
        image[y:y + 10, 100:140] = BODY
    image[70:100, 100:140] = image[110:140, 100:140] = 240
    assert [box.tolist() for box, _ in ColourPadDetector().detect(image)] == [[100, 60, 40, 50]]


def test_a_strip_paired_with_an_earlier_one_is_not_paired_again():
    """Strips A (row 60), B (80) and C (120), grey ground between A and B, the pad's white between B and C: (A, B)
    fails the roof test (no white), (A, C) passes and takes C; (B, C) would pass too, but C is taken: one roof."""
    image = grey_ground()
    for y in (60, 80, 120):
        image[y:y + 10, 100:140] = BODY
    image[90:120, 100:140] = 240
    assert [box.tolist() for box, _ in ColourPadDetector().detect(image)] == [[100, 60, 40, 70]]


def test_a_body_coloured_box_with_a_white_spot_is_not_the_ugv():
    """A 40 px box of the UGV's colour with a 14 px white centre: white enough (0.12 of its hull), but the body's
    colour fills 0.88 of it (over max_body_fraction 0.72): a plain box of that colour, not the roof."""
    image = grey_ground()
    image[50:90, 50:90] = BODY
    image[63:77, 63:77] = 240
    assert ColourPadDetector().detect(image) == []


def test_strips_with_ground_between_are_not_the_ugv():
    """Two strips that pair 80 px apart around a small white patch: their joint hull is 0.66 grey ground (over
    max_ground_fraction 0.45), not a roof."""
    image = grey_ground()
    image[60:70, 100:140] = image[140:150, 100:140] = BODY
    image[98:112, 105:135] = 240
    assert ColourPadDetector().detect(image) == []


@pytest.mark.parametrize("ground_rows, score", [(0, 1.0), (15, 0.875), (22, 0.525)])
def test_a_roof_scores_one_half_at_the_limits_and_one_from_a_margin_of_0_2(ground_rows, score):
    """Two 40 x 10 px strips 30 rows apart, `ground_rows` of those grey ground and the rest white: the hull's
    fractions (body 0.4, ground g = ground_rows / 50, white 0.6 - g) are at least `margin` inside all three
    limits, and the score is 0.5 + 0.5 min(1, margin / 0.2): margin 0.32, 0.15, 0.01 (ground 0, 0.3, 0.44)."""
    image = grey_ground()
    image[60:70, 100:140] = image[100:110, 100:140] = BODY
    image[70 + ground_rows:100, 100:140] = 240
    [(box, found)] = ColourPadDetector().detect(image)
    assert box.tolist() == [100, 60, 40, 50]
    assert found == pytest.approx(score, abs=1e-12)


def test_detections_come_highest_score_first():
    """A strip pair whose hull is 0.3 grey ground (score 0.875, found first: pairs are) and a ring of the body's
    colour around a white square (a margin over 0.2: score 1): the ring comes first."""
    image = grey_ground()
    image[20:30, 20:60] = image[60:70, 20:60] = BODY
    image[30:60, 20:40] = 240  # the pair's hull 40 x 50 px: body 0.4, white 0.3, grey ground 0.3
    image[20:60, 220:260] = BODY
    image[25:55, 225:255] = 240  # the ring's hull 40 x 40 px: body 0.44, white 0.56
    detections = ColourPadDetector().detect(image)
    assert [box.tolist() for box, _ in detections] == [[220, 20, 40, 40], [20, 20, 40, 50]]
    assert detections[0][1] > detections[1][1]


def test_a_dark_shadow_on_the_roof_is_not_ground():
    """A roof of 5 px strips and a 10 px white band whose hull is 0.6 dark grey (value 30, under the ground's mid-greys
    from 60): the ground mask leaves it out (ground fraction 0, not 0.6 over 0.45), so the roof is found."""
    shadow = 30
    assert cv2.cvtColor(np.full((1, 1, 3), shadow, np.uint8), cv2.COLOR_RGB2HSV)[0, 0].tolist() == [0, 0, shadow]
    image = grey_ground()
    image[60:65, 100:140] = image[105:110, 100:140] = BODY
    image[65:75, 100:140] = 240
    image[75:105, 100:140] = shadow
    assert [box.tolist() for box, _ in ColourPadDetector().detect(image)] == [[100, 60, 40, 50]]


# ---------------------------------------------------------------- rendered held-out frames


def chosen_seeds(config: UgvSceneConfig, count: int) -> list[int]:
    """The first held-out seeds whose frame shows the UGV at a moderate size (25-150 px, not a small-target
    frame) and a distractor of another colour: count - 1 of them, then one that also shows a distractor
    of the UGV's own colour."""
    pool = distractor_pool(config)
    plain, same = [], []
    for seed in HELD_OUT_SEEDS:
        scene = sample_scene(seed, config, pool)
        box = ugv_box(scene, config)
        colours = [pool[index].colour for index, _ in scene.distractors]
        if box is None or scene.small or not 25 <= max(box[2:]) <= 150 or not set(colours) - {"ugv"}:
            continue
        (same if "ugv" in colours else plain).append(seed)
        if len(plain) >= count - 1 and same:
            return plain[:count - 1] + same[:1]
    raise AssertionError("no such held-out frames")


@pytest.fixture(scope="module")
def held_out():
    """Rendered held-out frames: (image, true UGV box, [(distractor box, colour)])."""
    renderer = UgvSceneRenderer(UgvSceneConfig())
    frames = []
    for seed in chosen_seeds(renderer.config, FRAMES):
        frame = renderer.frame(seed)
        colours = [renderer.pool[index].colour for index, _ in frame.scene.distractors]
        boxes = distractor_boxes(frame.scene, renderer.config, renderer.pool)
        frames.append((frame.image, frame.ugv_box, list(zip(boxes, colours))))
    return frames


@pytest.mark.slow
@pytest.mark.parametrize("make", [CnnDetector, ColourPadDetector], ids=["learned", "classical"])
def test_detector_finds_the_ugv_and_not_a_distractor_of_another_colour(held_out, make):
    detector = make()
    for image, truth, distractors in held_out:
        detections = detector.detect(image)
        assert detections, "nothing detected"
        best = max(iou(box, truth) for box, _ in detections)
        assert best >= 0.5, f"best IOU with the UGV {best:.2f}"
        for box, score in detections:
            assert 0.0 <= score <= 1.0
            for distractor, colour in distractors:
                if colour != "ugv":
                    assert iou(box, distractor) < 0.3, f"a detection on the {colour} distractor"


@pytest.mark.slow
def test_detector_system_outputs_the_detectors_detections(held_out):
    image = held_out[0][0]
    rgba = ImageRgba8U(image.shape[1], image.shape[0])
    rgba.mutable_data[..., :3] = image
    rgba.mutable_data[..., 3] = 255
    detector = ColourPadDetector()
    system = UgvDetectorSystem(detector)
    context = system.CreateDefaultContext()
    system.get_input_port().FixValue(context, rgba)
    out = system.GetOutputPort("detections").Eval(context)
    expected = detector.detect(image)
    assert len(out) == len(expected) >= 1
    for (box, score), (box_e, score_e) in zip(out, expected):
        np.testing.assert_array_equal(box, box_e)
        assert score == score_e


# ---------------------------------------------------------------- the renderer against the true boxes


@pytest.fixture(scope="module")
def renderer():
    return UgvSceneRenderer(UgvSceneConfig())


def looking_down_from_2_m(config: UgvSceneConfig, **fields) -> UgvScene:
    """The lens 2 m over the origin looking straight down, nothing shown, no blur; `fields` replace those."""
    X_WC = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), [0.0, 0.0, 2.0])
    scene = UgvScene(0, X_WC.multiply(config.fisheye.X_BC.inverse()), None, [], 0.0, 0.0, False)
    return dataclasses.replace(scene, **fields)


def changed_pixels_rect(image: np.ndarray, empty: np.ndarray) -> np.ndarray:
    """[x0, y0, x1, y1] px (pixel-index space) of the pixels that differ from `empty` by over 10 levels."""
    x, y, w, h = cv2.boundingRect((np.abs(image.astype(int) - empty).max(axis=2) > 10).astype(np.uint8))
    return np.array([x, y, x + w, y + h], float)


@pytest.mark.slow
def test_the_true_boxes_enclose_the_rendered_ugv_and_distractor(renderer):
    """The UGV beside the nadir (its side and wheels towards the lens) and the longer red pool box 2.3 m off,
    each rendered alone over the empty ground: the pixels they change lie inside their true boxes (to 1.5 px:
    the rendered fisheye's interpolation), the UGV's box meets them on some side (its 3-D bounding box is
    larger than the vehicle at its corners), and the distractor's, a box's own, meets them on all four."""
    config, pool = renderer.config, renderer.pool
    red = [i for i, box in enumerate(pool) if box.colour == "red"]
    index = max(red, key=lambda i: pool[i].size_m[0])  # the other red box is 0.37 m shorter
    # The vehicle's centre (0.45 m ahead of V's origin) 0.6 m to the side of the nadir.
    ugv = looking_down_from_2_m(config, ugv_state=np.array([-0.45, 0.6, 0.0, 0.0]))
    distractor = looking_down_from_2_m(
        config, distractors=[(index, RigidTransform(RollPitchYaw(0.0, 0.0, 0.3), [0.5, -2.3, 0.0]))])
    empty = renderer.render(looking_down_from_2_m(config)).astype(int)

    def outside(scene, box):  # how far (px) the rendered pixels reach beyond the box on each side
        rendered = changed_pixels_rect(renderer.render(scene), empty)
        x, y, w, h = box
        return np.array([x - rendered[0], y - rendered[1], rendered[2] - (x + w), rendered[3] - (y + h)])

    beyond = outside(ugv, ugv_box(ugv, config))
    assert -1.5 <= beyond.max() <= 1.5
    [box] = distractor_boxes(distractor, config, pool)
    np.testing.assert_allclose(outside(distractor, box), 0.0, atol=1.5)


@pytest.mark.slow
def test_a_blurred_frame_is_smeared_along_its_blur_direction(renderer):
    """A frame drawn with 9 px of blur along the image's y is the sharp frame through motion_blur at that length
    and direction: its vertical gradients lose more than its horizontal ones."""
    config = renderer.config
    sharp_scene = looking_down_from_2_m(config, ugv_state=np.array([-0.45, 0.6, 0.0, 0.0]))
    sharp = renderer.render(sharp_scene)
    blurred = renderer.render(dataclasses.replace(sharp_scene, blur_px=9.0, blur_angle_rad=math.pi / 2))
    np.testing.assert_array_equal(blurred, motion_blur(sharp, 9.0, math.pi / 2))

    def kept(axis):  # the fraction of the sharp frame's gradient energy along `axis` (0: image y) left
        return np.abs(np.diff(blurred.astype(float), axis=axis)).sum() / np.abs(np.diff(sharp.astype(float),
                                                                                        axis=axis)).sum()

    assert kept(0) < 0.75 * kept(1)  # measured: 0.37 of the vertical, 0.62 of the horizontal


@pytest.mark.slow
def test_a_cached_dataset_reads_back_as_rendered(renderer, tmp_path):
    """Two held-out frames (one blurred with 3 distractors, one a small-target frame with a blur and none) rendered
    into an empty cache, then read back from it: every field the same, in the same dtypes."""
    seeds = [HELD_OUT_SEEDS[2], HELD_OUT_SEEDS[10]]
    rendered = load_or_render_dataset(seeds, cache_dir=tmp_path, renderer=renderer)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    cached = load_or_render_dataset(seeds, cache_dir=tmp_path, renderer=renderer)
    assert rendered.blur_px.tolist() != rendered.small.tolist()
    assert [len(boxes) for boxes in rendered.distractor_boxes] == [3, 0]
    for name in ("images", "ugv_boxes", "seeds", "blur_px", "small"):
        a, b = getattr(rendered, name), getattr(cached, name)
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert len(cached.distractor_boxes) == 2
    for a, b in zip(rendered.distractor_boxes, cached.distractor_boxes):
        np.testing.assert_array_equal(a, b)
