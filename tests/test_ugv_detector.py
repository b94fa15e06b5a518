"""Seed 003's UGV detectors (Sec. 2.2.1; systems/perception/ugv_detector.py) on rendered held-out fisheye
frames (diagrams/ugv_detection_scenes.py): both find the UGV and not a distractor of another colour; the
learned one's model file missing or corrupt is one ConfigError line naming it; the true box's projection
against a hand case; the pieces of the HOG scan against each other."""

import math

import numpy as np
import pytest
from pydrake.systems.sensors import ImageRgba8U

from diagrams.ugv_detection_scenes import (
    HELD_OUT_SEEDS,
    UgvSceneConfig,
    UgvSceneRenderer,
    box_surface_points,
    distractor_boxes,
    distractor_pool,
    motion_blur_kernel,
    projected_box,
    sample_scene,
    ugv_box,
)
from systems.config import ConfigError
from systems.perception.ugv_detector import (
    DEFAULT_MODEL_PATH,
    ColourPadDetector,
    HogLayout,
    HogSvmDetector,
    HogSvmModel,
    UgvDetectorSystem,
    apply_regression,
    colour_cells,
    crop_patch,
    iou,
    level_maps,
    non_maximum_suppression,
    patch_features,
    regression_targets,
    window_features,
    window_scores,
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


def test_true_box_is_clipped_to_the_field_of_view_and_none_behind_the_lens():
    config = FisheyeConfig()
    assert projected_box(box_surface_points([-0.5, -0.5, -3.0], [0.5, 0.5, -2.0]), config) is None
    # A long bar from the axis out past the 75 deg rim along +x: its box stops at the rim's radius.
    box = projected_box(box_surface_points([0.0, -0.05, 1.0], [20.0, 0.05, 1.0]), config)
    assert box[0] + box[2] == pytest.approx(config.cx + 0.5 + config.radius_px, abs=0.3)


def test_scene_draws_repeat_and_give_boxes_in_the_image():
    config = UgvSceneConfig()
    pool = distractor_pool(config)
    first, again = sample_scene(HELD_OUT_SEEDS[0], config, pool), sample_scene(HELD_OUT_SEEDS[0], config, pool)
    assert np.array_equal(first.X_WB.GetAsMatrix4(), again.X_WB.GetAsMatrix4())
    for seed in HELD_OUT_SEEDS[:50]:
        scene = sample_scene(seed, config, pool)
        for box in [ugv_box(scene, config)] + distractor_boxes(scene, config, pool):
            if box is not None:
                assert box[0] >= 0 and box[1] >= 0 and box[0] + box[2] <= 512 and box[1] + box[3] <= 512


def test_motion_blur_kernel_is_a_normalised_line_of_the_given_length():
    kernel = motion_blur_kernel(9.0, math.pi / 2)  # along +y (image down)
    assert kernel.sum() == pytest.approx(1.0, abs=1e-6)
    rows, cols = np.mgrid[:kernel.shape[0], :kernel.shape[1]] - (kernel.shape[0] - 1) / 2
    # A uniform segment of length L has standard deviation L / sqrt(12) along it; across it, under a pixel.
    assert math.sqrt((kernel * rows**2).sum()) == pytest.approx(9 / math.sqrt(12), rel=0.1)
    assert math.sqrt((kernel * cols**2).sum()) < 0.6
    assert motion_blur_kernel(0.5, 1.0).shape == (1, 1)


# ---------------------------------------------------------------- the HOG scan's pieces


def test_window_scores_are_the_dot_products_of_the_window_features():
    layout = HogLayout()
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (64, 80, 3), dtype=np.uint8)
    maps = level_maps(image, layout)
    weights = rng.normal(size=layout.feature_size).astype(np.float32)
    scores = window_scores(maps, weights, layout)
    assert scores.shape == (64 // 4 - layout.window_cells + 1, 80 // 4 - layout.window_cells + 1)
    rows, cols = np.array([0, 3, scores.shape[0] - 1]), np.array([0, 5, scores.shape[1] - 1])
    direct = window_features(maps, rows, cols, layout) @ weights
    np.testing.assert_allclose(scores[rows, cols], direct, rtol=1e-4, atol=1e-4)


def test_a_cropped_window_has_the_dense_scans_features():
    """crop_patch + patch_features (training) give the scan's features of a cell-aligned window at scale 1."""
    layout = HogLayout()
    image = np.random.default_rng(1).integers(0, 255, (96, 96, 3), dtype=np.uint8)
    row, col = 5, 7  # the window's top-left cell
    centre = (col * layout.cell_px + layout.window_px / 2, row * layout.cell_px + layout.window_px / 2)
    dense = window_features(level_maps(image, layout), [row], [col], layout)[0]
    np.testing.assert_allclose(patch_features(crop_patch(image, centre, 1.0, layout), layout), dense, atol=1e-5)


def test_colour_cells_put_a_saturated_colour_in_its_hue_bin():
    layout = HogLayout()
    image = np.zeros((8, 8, 3), np.uint8)
    image[:4, :4] = (200, 0, 0)  # red: hue 0, bin 0
    image[:4, 4:] = (0, 0, 200)  # blue: hue 120 deg, OpenCV 120, bin 4 of 6
    image[4:, :] = 128  # grey: no saturation
    cells = colour_cells(image, layout)
    np.testing.assert_allclose(cells[0, 0], [1, 0, 0, 0, 0, 0, 200 / 255], atol=1e-6)
    np.testing.assert_allclose(cells[0, 1], [0, 0, 0, 0, 1, 0, 200 / 255], atol=1e-6)
    np.testing.assert_allclose(cells[1, 0], [0, 0, 0, 0, 0, 0, 128 / 255], atol=1e-6)


def test_box_regression_targets_round_trip_and_nms_keeps_the_best():
    windows = np.array([[10.0, 20.0, 40.0, 40.0], [0.0, 0.0, 24.0, 24.0]])
    boxes = np.array([[12.0, 25.0, 30.0, 22.0], [3.0, 1.0, 10.0, 20.0]])
    np.testing.assert_allclose(apply_regression(windows, regression_targets(windows, boxes)), boxes)
    keep = non_maximum_suppression(np.array([[0, 0, 10, 10], [1, 1, 10, 10], [30, 30, 10, 10]]),
                                   np.array([0.6, 0.9, 0.5]), 0.3)
    assert list(keep) == [1, 2]
    assert iou([0, 0, 10, 10], [5, 0, 10, 10]) == pytest.approx(1 / 3)


# ---------------------------------------------------------------- the model file


def test_missing_model_file_is_one_config_error_line_naming_it(tmp_path):
    path = tmp_path / "ugv_detector.yml"
    with pytest.raises(ConfigError) as error:
        HogSvmDetector(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message


@pytest.mark.parametrize("content", [
    b"\x00\x01garbage{{{ not yaml",  # not OpenCV YAML at all
    b"%YAML:1.0\n---\nformat: ugv_hog_svm_v2\ncell_px: 4\n",  # a model cut short
    b"%YAML:1.0\n---\nformat: something_else\n",  # another file
])
def test_corrupt_model_file_is_one_config_error_line_naming_it(tmp_path, content):
    path = tmp_path / "ugv_detector.yml"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as error:
        HogSvmDetector(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message


def test_truncated_model_file_is_one_config_error_line_naming_it(tmp_path):
    path = tmp_path / "ugv_detector.yml"
    path.write_bytes(DEFAULT_MODEL_PATH.read_bytes()[:40_000])  # cut inside the weights
    with pytest.raises(ConfigError) as error:
        HogSvmDetector(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message


def test_model_with_wrong_weight_count_is_a_config_error(tmp_path):
    model = HogSvmModel.load(DEFAULT_MODEL_PATH)
    path = tmp_path / "short.yml"
    model.save(path)
    text = path.read_text()
    assert "window_cells: 6" in text
    path.write_text(text.replace("window_cells: 6", "window_cells: 7"))
    with pytest.raises(ConfigError, match="weights"):
        HogSvmModel.load(path)


def test_model_file_round_trips(tmp_path):
    model = HogSvmModel.load(DEFAULT_MODEL_PATH)
    assert DEFAULT_MODEL_PATH.stat().st_size < 2_000_000
    model.save(tmp_path / "copy.yml")
    again = HogSvmModel.load(tmp_path / "copy.yml")
    assert again.layout == model.layout
    np.testing.assert_allclose(again.thresholds, model.thresholds)
    np.testing.assert_array_equal(again.level_component, model.level_component)
    np.testing.assert_allclose(again.weights, model.weights)
    np.testing.assert_allclose(again.regression, model.regression, rtol=1e-6)


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
@pytest.mark.parametrize("make", [HogSvmDetector, ColourPadDetector], ids=["learned", "classical"])
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
