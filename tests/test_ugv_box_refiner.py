"""The learned detector's boxes re-centred by the colour (systems/perception/ugv_box_refiner.py), on drawn
frames: a UGV seen from above (two body-coloured end strips, the pad's white between them) on a grey ground,
whose enclosing box the classical detector finds exactly."""

import numpy as np
import pytest

from diagrams.hybrid_perception import HybridPerceptionConfig
from systems.config import ConfigError
from systems.perception.ugv_box_refiner import BoxRefinementConfig, ColourRefinedDetector
from systems.perception.ugv_cnn_detector import CnnDetector
from systems.perception.ugv_detector import ColourPadDetector

BODY = (191, 77, 38)  # GroundVehicleGeometry's (0.75, 0.3, 0.15)


def draw_ugv(image: np.ndarray, x: int, y: int, width: int = 40) -> np.ndarray:
    """A UGV from above with its top-left corner at (x, y): strips of 10 px, the pad 30 px; its box [x, y, w, 50]."""
    image[y:y + 10, x:x + width] = BODY
    image[y + 10:y + 40, x:x + width] = 240
    image[y + 40:y + 50, x:x + width] = BODY
    return np.array([x, y, width, 50], float)


def ground(rows: int = 200, cols: int = 300) -> np.ndarray:
    return np.full((rows, cols, 3), 110, np.uint8)


class FixedDetector:
    """A stand-in learned detector: the given detections, whatever the frame."""

    def __init__(self, *detections):
        self.detections = list(detections)

    def detect(self, rgb):
        return [(np.array(box, float), score) for box, score in self.detections]


def refined(detections, image, **config):
    return ColourRefinedDetector(FixedDetector(*detections), ColourPadDetector(), BoxRefinementConfig(**config)
                                 ).detect(image)


def centre(box) -> np.ndarray:
    return np.asarray(box[:2]) + np.asarray(box[2:]) / 2


def test_a_box_around_the_roof_takes_its_centre_and_keeps_its_size_and_score():
    image = ground()
    truth = draw_ugv(image, 100, 80)
    (box, score), = refined([([103.5, 76.0, 46.0, 55.0], 0.83)], image)
    np.testing.assert_array_equal(centre(box), centre(truth))
    np.testing.assert_array_equal(box[2:], [46.0, 55.0])
    assert score == 0.83


def test_an_oblique_view_is_recentred_where_the_boxes_disagree_in_size():
    """The network boxes the whole vehicle, its side too (70 x 75 px); the colour the roof in its top-left part
    (40 x 50 px, IOU 0.38): the roof lies within the network's box, so the box moves onto it, its size kept."""
    image = ground()
    truth = draw_ugv(image, 100, 80)
    (box, _), = refined([([98.0, 78.0, 70.0, 75.0], 0.9)], image)
    np.testing.assert_array_equal(centre(box), centre(truth))
    np.testing.assert_array_equal(box[2:], [70.0, 75.0])


def test_a_box_without_the_classical_detection_in_its_window_keeps_its_box():
    """Body colour in the box (a lone strip: no pad, so not the classical detector's UGV): kept, not moved."""
    image = ground()
    draw_ugv(image, 200, 120)
    image[40:50, 25:55] = BODY
    (box, _), = refined([([20.0, 20.0, 40.0, 50.0], 0.7)], image)
    np.testing.assert_array_equal(box, [20.0, 20.0, 40.0, 50.0])


@pytest.mark.parametrize("body_px, min_body_px, kept", [(0, 5, False), (4, 5, False), (5, 5, True), (40, 5, True),
                                                       (0, 1, False), (1, 1, True)])
def test_a_box_without_the_body_colour_is_dropped(body_px, min_body_px, kept):
    """A learned box over another colour's vehicle holding `body_px` pixels of the UGV's colour: dropped under
    min_body_px (the default 5, or 1: one pixel is enough, none is not), the UGV's own box beside it kept either
    way; with min_body_px 0 every box is kept."""
    image = ground()
    truth = draw_ugv(image, 200, 120)
    image[30:80, 30:70] = (40, 90, 200)  # a blue vehicle
    for k in range(body_px):  # in rows of 5
        image[30 + k // 5, 30 + k % 5] = BODY
    detections = [([28.0, 28.0, 44.0, 54.0], 0.8), ([198.0, 118.0, 44.0, 54.0], 0.9)]
    out = refined(detections, image, min_body_px=min_body_px)
    assert [score for _, score in out] == ([0.8, 0.9] if kept else [0.9])
    np.testing.assert_array_equal(centre(out[-1][0]), centre(truth))
    assert len(refined(detections, image, min_body_px=0)) == 2


@pytest.mark.parametrize("outside", [[-80.0, 20.0, 40.0, 50.0], [-60.0, 20.0, 40.0, 50.0], [340.0, 20.0, 40.0, 50.0],
                                     [20.0, -75.0, 40.0, 50.0], [20.0, 225.0, 40.0, 50.0]],
                         ids=["left", "left-window-at-edge", "right", "top", "bottom"])
def test_with_min_body_px_0_even_a_box_off_the_image_is_kept(outside):
    """min_body_px 0 keeps every learned box: one wholly outside the 300 x 200 px frame (no pixel to count) comes
    back as it was, beside the UGV's own, refined. Its window (the box grown by 20 px left and right, 25 px up and
    down) lies off the image too, ending at its left or top edge (x or y 0) or starting at its right or bottom one
    (x 320 > 300, y 200): no pixel to search."""
    image = ground()
    truth = draw_ugv(image, 200, 120)
    out = refined([(outside, 0.7), ([198.0, 118.0, 44.0, 54.0], 0.9)], image, min_body_px=0)
    assert [score for _, score in out] == [0.7, 0.9]
    np.testing.assert_array_equal(out[0][0], outside)
    np.testing.assert_array_equal(centre(out[1][0]), centre(truth))


@pytest.mark.parametrize("box", [[300.0, 20.0, 40.0, 50.0], [-40.0, 20.0, 40.0, 50.0], [20.0, 200.0, 40.0, 50.0],
                                 [20.0, -50.0, 40.0, 50.0]], ids=["right", "left", "bottom", "top"])
def test_a_box_just_beyond_the_image_edge_has_no_body_pixels(box):
    """A learned box starting at the 300 x 200 px frame's right or bottom edge, or ending at its left or top one:
    clipped to the image, no pixel left to count, so dropped by the default min_body_px."""
    assert refined([(box, 0.8)], ground()) == []


@pytest.mark.parametrize("box", [[29.5, 30.0, 20.0, 30.0], [10.0, 30.0, 19.5, 30.0]], ids=["left", "right"])
@pytest.mark.parametrize("body", [True, False])
def test_a_pixel_the_box_covers_in_part_is_counted(box, body):
    """Ten body-coloured pixels in column 29 only (rows 40-49): a box starting at x = 29.5 or ending at x = 29.5
    covers half of that column, whose pixels count: kept; the same box on plain ground is dropped."""
    image = ground()
    if body:
        image[40:50, 29] = BODY
    assert len(refined([(box, 0.8)], image)) == (1 if body else 0)


@pytest.mark.parametrize("x, kept", [(30.0, False), (50.0, True)])
def test_body_pixels_are_counted_within_the_box_width_only(x, kept):
    """A tall box, 20 px wide and 60 px high, and 60 body-coloured pixels in columns 55-60: at x = 30 they lie
    beyond its width (though within x + its height): dropped; at x = 50 inside it: kept."""
    image = ground()
    image[40:50, 55:61] = BODY
    out = refined([([x, 30.0, 20.0, 60.0], 0.8)], image)
    assert len(out) == (1 if kept else 0)


def test_a_colour_box_not_within_the_network_box_is_not_taken():
    """A small box on one corner of the UGV: the colour's box (the whole roof) lies 0.16 within it, the
    network's part, not the whole."""
    image = ground()
    truth = draw_ugv(image, 100, 80)
    part = [120.0, 76.0, 24.0, 20.0]
    (box, _), = refined([(part, 0.6)], image, margin=3.0)
    np.testing.assert_array_equal(box, part)
    (box, _), = refined([(part, 0.6)], image, margin=3.0, min_inside=0.1)  # the same window, a lax agreement
    np.testing.assert_array_equal(centre(box), centre(truth))


def test_a_colour_box_cut_by_the_window_is_not_taken():
    """The window around a box on the UGV's left 70 % ends inside the UGV (at x = 131): the colour box there,
    [100, 80, 31, 50], agrees with it (IOU 0.9) but is cut by the window."""
    image = ground()
    draw_ugv(image, 100, 80)
    left = [100.0, 80.0, 28.0, 50.0]
    (box, _), = refined([(left, 0.9)], image, margin=0.1, min_margin_px=0)
    np.testing.assert_array_equal(box, left)


def turned(image: np.ndarray) -> np.ndarray:
    """The image mirrored about its diagonal (rows for columns): a UGV drawn by draw_ugv turned, strips left and
    right; a box [x, y, w, h] in it is [y, x, h, w]."""
    return np.ascontiguousarray(image.transpose(1, 0, 2))


@pytest.mark.parametrize("side, detection", [
    ("left", [112.0, 80.0, 28.0, 50.0]),  # the window starts at x = 109
    ("top", [80.0, 112.0, 50.0, 28.0]),  # turned: the window starts at y = 109
    ("bottom", [80.0, 100.0, 50.0, 28.0]),  # turned: the window ends at y = 131
])
def test_a_colour_box_cut_on_any_other_side_is_not_taken(side, detection):
    """As above on the other sides: a box on 70 % of the UGV's length (the UGV turned for top and bottom), a window of
    margin 0.1 ending inside the UGV; the colour box there touches that edge and agrees with the box (0.9 inside)."""
    image = ground()
    draw_ugv(image, 100, 80)
    if side != "left":
        image = turned(image)
    (box, _), = refined([(detection, 0.9)], image, margin=0.1, min_margin_px=0)
    np.testing.assert_array_equal(box, detection)


@pytest.mark.parametrize("config", [BoxRefinementConfig(margin=0.5, min_margin_px=8), BoxRefinementConfig()],
                         ids=["given", "default"])
def test_the_window_grows_the_box_by_margin_of_its_own_width_and_height(config):
    """margin 0.5 of a 40 x 10 px box: 20 px left and right, 5 (so min_margin_px, 8) above and below; outwards to whole
    pixels, clipped to the image. The defaults are those: margin 0.5, min_margin_px 8."""
    refiner = ColourRefinedDetector(FixedDetector(), ColourPadDetector(), config)
    assert refiner.window(np.array([100.0, 50.0, 40.0, 10.0]), (200, 300)) == (80, 42, 160, 68)
    assert refiner.window(np.array([100.5, 50.5, 40.0, 10.0]), (200, 300)) == (80, 42, 161, 69)
    assert refiner.window(np.array([10.0, 5.0, 40.0, 10.0]), (200, 300)) == (0, 0, 70, 23)
    assert refiner.window(np.array([270.0, 185.0, 40.0, 10.0]), (200, 300)) == (250, 177, 300, 200)


@pytest.mark.parametrize("which", [0, 1])
def test_of_two_colour_boxes_in_the_window_the_one_within_the_box_is_taken(which):
    """A wide window (margin 3) around a box on one of two UGVs holds both whole: the box moves onto its own."""
    image = ground()
    truths = [draw_ugv(image, 20, 20), draw_ugv(image, 100, 110)]
    detection = truths[which] + [-2.0, -4.0, 4.0, 8.0]
    (box, _), = refined([(detection, 0.9)], image, margin=3.0)
    np.testing.assert_array_equal(centre(box), centre(truths[which]))


@pytest.mark.parametrize("corner, detection", [((0, 0), [0.0, 0.0, 44.0, 54.0]),
                                               ((260, 150), [256.0, 146.0, 44.0, 54.0])],
                         ids=["top-left", "bottom-right"])
def test_a_ugv_at_the_image_edge_is_refined(corner, detection):
    """A window clipped by the image is not a cut: the UGV in a corner of the 300 x 200 px frame (touching its left
    and top edges, or its right and bottom ones) is still re-measured."""
    image = ground()
    truth = draw_ugv(image, *corner)
    (box, _), = refined([(detection, 0.9)], image)
    np.testing.assert_array_equal(centre(box), centre(truth))


@pytest.mark.parametrize("turn", [False, True])
def test_a_box_over_max_box_px_keeps_its_own(turn):
    """Close up (a box over 80 px wide, or turned, high) the network's box stays; allowed larger boxes, the colour's
    is taken."""
    image = ground(400, 400)
    truth = draw_ugv(image, 100, 80, width=110)  # 110 x 50 px
    detection = ([98.0, 76.0, 116.0, 58.0], 0.9)
    if turn:
        image, truth, detection = turned(image), truth[[1, 0, 3, 2]], ([76.0, 98.0, 58.0, 116.0], 0.9)
    (box, _), = refined([detection], image)
    np.testing.assert_array_equal(box, detection[0])
    (box, _), = refined([detection], image, max_box_px=120.0)
    np.testing.assert_array_equal(centre(box), centre(truth))


@pytest.mark.parametrize("width, refined_", [(76, True), (84, False)])
def test_a_box_up_to_the_default_max_box_px_is_refined(width, refined_):
    """The default max_box_px, 80: a UGV `width` px wide (50 high) and a learned box 4 px wider and 8 px higher
    around it, 2 px left and up of its centre, 80 px wide (at the limit: refined, its centre the roof's) or 88 px
    (over it: kept as it came)."""
    image = ground(400, 400)
    truth = draw_ugv(image, 100, 80, width=width)
    detection = truth + [-4.0, -6.0, 4.0, 8.0]
    (box, _), = refined([(detection, 0.9)], image)
    np.testing.assert_array_equal(centre(box), centre(truth if refined_ else detection))
    np.testing.assert_array_equal(box[2:], detection[2:])


@pytest.mark.parametrize("detection, expected", [([100.0, 80.0, 40.0, 40.0], [100.0, 85.0, 40.0, 40.0]),
                                                 ([102.0, 80.0, 30.0, 50.0], [102.0, 80.0, 30.0, 50.0])],
                         ids=["0.8-inside", "0.75-inside"])
def test_the_colour_box_must_lie_at_least_min_inside_within_the_box(detection, expected):
    """The default min_inside, 0.8: the roof's box [100, 80, 40, 50] lies 1600 / 2000 = 0.8 within a learned box over
    its top 40 rows (taken: the box's centre moves 5 px down onto the roof's) and 30 x 50 / 2000 = 0.75 within one
    over 30 of its 40 columns (not taken, the box kept)."""
    image = ground()
    draw_ugv(image, 100, 80)
    (box, _), = refined([(detection, 0.9)], image)
    np.testing.assert_array_equal(box, expected)


def test_every_detection_is_refined_on_its_own():
    image = ground()
    first, second = draw_ugv(image, 30, 30), draw_ugv(image, 200, 120)
    out = refined([([32.0, 28.0, 42.0, 52.0], 0.9), ([197.0, 122.0, 45.0, 46.0], 0.6)], image)
    np.testing.assert_array_equal(centre(out[0][0]), centre(first))
    np.testing.assert_array_equal(centre(out[1][0]), centre(second))
    assert [score for _, score in out] == [0.9, 0.6]


def _validate(config: BoxRefinementConfig) -> None:
    config.validate()


def _make_refiner(config: BoxRefinementConfig) -> None:
    ColourRefinedDetector(FixedDetector(), ColourPadDetector(), config)


@pytest.mark.parametrize("check", [_validate, _make_refiner], ids=["validate", "refiner"])
@pytest.mark.parametrize("setting, named", [({"method": "yolo"}, "method"), ({"margin": -1.0}, "margin"),
                                            ({"min_inside": 0.0}, "min_inside"), ({"max_box_px": 0.0}, "max_box_px"),
                                            ({"min_body_px": -1}, "min_body_px")])
def test_bad_settings_name_the_field(setting, named, check):
    """A bad setting is a ConfigError naming it, from validate() and from the refiner built with it."""
    with pytest.raises(ConfigError, match=f"hybrid.refinement.{named}"):
        check(BoxRefinementConfig(**setting))


@pytest.mark.parametrize("setting", [{"min_inside": 1.0}, {"margin": 0.0, "min_margin_px": 0}, {"min_body_px": 0}])
def test_settings_at_their_bounds_are_valid(setting):
    """min_inside may be 1 (the colour box wholly within), margin and min_margin_px 0, min_body_px 0 (keep all)."""
    _make_refiner(BoxRefinementConfig(**setting))


def test_an_rgba_frame_gives_its_rgb_boxes():
    """The camera's stream is RGBA: its alpha channel ignored, the boxes those of its RGB channels."""
    image = ground()
    truth = draw_ugv(image, 100, 80)
    rgba = np.dstack([image, np.full(image.shape[:2], 255, np.uint8)])
    (box, _), = refined([([103.5, 76.0, 46.0, 55.0], 0.83)], rgba)
    np.testing.assert_array_equal(centre(box), centre(truth))


@pytest.mark.parametrize("detector, method, made", [("learned", "colour", ColourRefinedDetector),
                                                    ("learned", "none", CnnDetector),
                                                    ("classical", "colour", ColourPadDetector)])
def test_the_scenario_refines_the_learned_detector_only(detector, method, made):
    config = HybridPerceptionConfig(detector=detector, refinement=BoxRefinementConfig(method=method))
    assert type(config.make_detector()) is made


@pytest.mark.parametrize("method", ["colour", "none"])
def test_the_learned_detector_loads_the_model_path_given(method):
    """model_path, where set, is the network loaded (empty: models/ugv_detector.onnx): a missing file is a
    ConfigError naming it, not the default model silently."""
    config = HybridPerceptionConfig(model_path="models/missing.onnx", refinement=BoxRefinementConfig(method=method))
    with pytest.raises(ConfigError, match=r"model file \S*models/missing\.onnx does not exist"):
        config.make_detector()
