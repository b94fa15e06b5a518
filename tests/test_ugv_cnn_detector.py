"""The learned UGV detector's network (systems/perception/ugv_cnn_detector.py) and its trainer's pure parts
(models/train_ugv_cnn.py, importable without the train extra): the trainer's targets decode to the box they
were made from, its turned boxes follow np.rot90 and np.fliplr, decoding keeps peaks at or above min_score, drops
overlaps and caps the count, and a missing or corrupt model file is one ConfigError line naming it. Finding the UGV
on rendered held-out frames: tests/test_ugv_detector.py."""

import cv2
import numpy as np
import pytest

from diagrams.ugv_detection_scenes import UgvDataset
from models.train_ugv_cnn import CROP_PX, STRIDE, best_threshold, sample, targets_for, turn_box
from systems.config import PROJECT_ROOT, ConfigError
from systems.estimators.crhf import CrhfConfig
from systems.perception.ugv_cnn_detector import DEFAULT_MODEL_PATH, CnnDetector, decode


@pytest.mark.parametrize("box", [[100.0, 60.0, 40.0, 30.0], [7.3, 250.9, 13.0, 11.5], [300.2, 301.7, 150.0, 170.0]])
def test_training_targets_decode_to_their_box(box):
    t = targets_for(np.array(box), 512)
    out = np.transpose(t[..., :5], (2, 0, 1)).copy()  # heat, offset x/y, log w/h, as the network gives them
    found = decode(out, STRIDE, min_score=0.5)
    assert len(found) == 1
    np.testing.assert_allclose(found[0][0], box, atol=1e-4)
    assert found[0][1] == 1.0


def heat_map(peaks: dict[tuple[int, int], float], cells: int = 32) -> np.ndarray:
    """A network output (5, cells, cells) with the given heat peaks {(row, col): heat}, each a box of 4 x 4 cells
    centred on its cell (offsets 0)."""
    out = np.zeros((5, cells, cells), np.float32)
    out[3:] = np.log(4.0)
    for (row, col), heat in peaks.items():
        out[0, row, col] = heat
    return out


def test_decode_keeps_at_most_max_detections_the_best_first():
    """12 separate peaks (boxes at most touching: IOU 0): the 10 best, highest score first."""
    scores = [0.9 - 0.01 * k for k in range(12)]
    out = heat_map({(2 * k % 32, 4 * k % 32 + 2): score for k, score in enumerate(scores)})
    found = decode(out, 4, 0.5, max_detections=10)
    np.testing.assert_allclose([score for _, score in found], scores[:10], rtol=1e-6)
    assert len(decode(out, 4, 0.5, max_detections=12)) == 12


def test_decode_drops_a_box_overlapping_a_better_one():
    """Two peaks 2 cells apart (both 3 x 3 maxima), their 16 px boxes 8 px apart: IOU 128 / 384 = 0.33, over nms_iou
    0.3, so the weaker goes; at nms_iou 0.4 both stay."""
    out = heat_map({(10, 10): 0.9, (10, 12): 0.8})
    found = decode(out, 4, 0.5, nms_iou=0.3)
    assert len(found) == 1 and found[0][1] == pytest.approx(0.9)
    np.testing.assert_allclose(found[0][0], [32.0, 32.0, 16.0, 16.0], atol=1e-5)
    assert len(decode(out, 4, 0.5, nms_iou=0.4)) == 2


def test_decode_scales_the_box_by_the_stride():
    """A stride-8 grid, one peak at row 10, column 20, offsets 0.5, log w = log 3, log h = log 2 (cells): the box
    is centred at (20.5, 10.5) cells, 3 x 2 cells: [164 - 12, 84 - 8, 24, 16] px."""
    out = heat_map({(10, 20): 0.9}, cells=64)
    out[1:3, 10, 20] = 0.5
    out[3:, 10, 20] = np.log(3.0), np.log(2.0)
    found = decode(out, 8, 0.5)
    assert len(found) == 1
    np.testing.assert_allclose(found[0][0], [152.0, 76.0, 24.0, 16.0], rtol=1e-6)


def test_decode_keeps_a_peak_at_min_score_and_drops_one_under_it():
    """The docstring's "at or above min_score": a peak of exactly 0.5 is a detection, one of 0.49 is not."""
    assert len(decode(heat_map({(10, 10): 0.5}), 4, 0.5)) == 1
    assert decode(heat_map({(10, 10): 0.49}), 4, 0.5) == []


def test_the_detector_drops_a_box_overlapping_a_better_one_by_default(monkeypatch):
    """detect decodes at the detector's nms_iou, 0.3 by default: the network's two peaks of
    test_decode_drops_a_box_overlapping_a_better_one (IOU 0.33) give one detection, the better."""
    detector = CnnDetector()
    out = heat_map({(10, 10): 0.9, (10, 12): 0.8}, cells=512 // detector.stride)
    monkeypatch.setattr(detector, "_forward", lambda rgb: out)
    found = detector.detect(np.zeros((512, 512, 3), np.uint8))
    assert len(found) == 1 and found[0][1] == pytest.approx(0.9)
    s = detector.stride
    np.testing.assert_allclose(found[0][0], [8 * s, 8 * s, 4 * s, 4 * s], atol=1e-5)  # 4 x 4 cells about (10, 10)


def draw_ugv(image: np.ndarray, row: int, col: int) -> None:
    """A UGV drawn on `image` from its top-left pixel (row, col): 40 px wide, two 10 px strips of its colour with the
    pad's white 30 px between."""
    image[row:row + 10, col:col + 40] = image[row + 40:row + 50, col:col + 40] = (191, 77, 38)
    image[row + 10:row + 40, col:col + 40] = 240


def test_the_detector_keeps_only_what_scores_at_least_its_min_score():
    """A drawn UGV (strips of its colour, the pad's white between) on grey, which the network scores between 0.5
    and 0.99: a detector at min_score m gives exactly a lax detector's detections scoring at least m."""
    image = np.full((512, 512, 3), 110, np.uint8)
    draw_ugv(image, 200, 200)
    lax = CnnDetector(min_score=0.01).detect(image)
    assert any(0.5 <= score < 0.99 for _, score in lax)
    for m in (0.5, 0.99):
        strict = CnnDetector(min_score=m).detect(image)
        assert [(box.tolist(), score) for box, score in strict] == \
            [(box.tolist(), score) for box, score in lax if score >= m]


def test_the_detector_keeps_at_most_max_detections_the_best_first():
    """Two drawn UGVs, each boxed by the network (a box centred on each): a detector of max_detections 1 keeps only
    the better scoring of the two."""
    image = np.full((512, 512, 3), 110, np.uint8)
    ugvs = [(200, 200), (350, 350)]
    for row, col in ugvs:
        draw_ugv(image, row, col)
    both = CnnDetector().detect(image)
    assert len(both) == 2
    for row, col in ugvs:
        assert sum(col <= x + w / 2 < col + 40 and row <= y + h / 2 < row + 50 for (x, y, w, h), _ in both) == 1
    best = max(both, key=lambda d: d[1])
    found = CnnDetector(max_detections=1).detect(image)
    assert len(found) == 1 and found[0][1] == best[1]
    np.testing.assert_array_equal(found[0][0], best[0])


@pytest.mark.parametrize("min_score", [0.0, 1.0, -0.1, 1.5])
def test_a_min_score_outside_the_open_unit_interval_is_refused(min_score):
    """The detector's min_score lies strictly between 0 and 1: 0, 1 and values beyond are a ConfigError."""
    with pytest.raises(ConfigError, match=r"min_score must lie in \(0, 1\)"):
        CnnDetector(min_score=min_score)


def test_a_box_centred_outside_the_crop_has_no_target():
    t = targets_for(np.array([-30.0, 10.0, 40.0, 40.0]), 320)  # centre at x = -10 px
    assert t.max() == 0.0


@pytest.mark.parametrize("flip", [False, True])
@pytest.mark.parametrize("turns", [0, 1, 2, 3])
def test_turned_box_follows_the_turned_pixels(flip, turns):
    mask = np.zeros((20, 20), bool)
    mask[5:12, 3:7] = True  # the box [3, 5, 4, 7]
    turned = np.rot90(np.fliplr(mask) if flip else mask, turns)
    ys, xs = np.nonzero(turned)
    expected = [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
    np.testing.assert_array_equal(turn_box(np.array([3, 5, 4, 7]), 20, turns, flip), expected)


def test_augmented_crops_keep_their_targets_on_the_object():
    """A white box on black: in every sampled crop (turned, mirrored, brightness jittered) the decoded target,
    cut to the crop, is the box of the crop's bright pixels."""
    image = np.zeros((512, 512, 3), np.uint8)
    image[200:230, 300:345] = 255  # the box [300, 200, 45, 30]
    dataset = UgvDataset(image[None], np.array([[300.0, 200.0, 45.0, 30.0]]), [np.zeros((0, 4))], np.array([0]),
                         np.array([0.0]), np.array([False]))
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(40):
        crop, t = sample(dataset, rng)
        assert crop.shape == (CROP_PX, CROP_PX, 3) and crop.dtype == np.float32
        bright = crop.mean(axis=2) > 0.6
        decoded = decode(np.transpose(t[..., :5], (2, 0, 1)).copy(), STRIDE, min_score=0.5)
        if t[..., 5].sum() == 0:
            continue  # the box's centre fell outside this crop
        found += 1
        x, y, w, h = decoded[0][0]
        x0, y0, x1, y1 = np.clip([x, y, x + w, y + h], 0, CROP_PX)  # the crop may cut the box
        ys, xs = np.nonzero(bright)
        np.testing.assert_allclose([x0, y0, x1, y1], [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], atol=1e-4)
    assert found >= 20  # two crops in three are drawn around the object


def test_best_threshold_maximises_f1():
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.3])
    hits = np.array([True, True, False, True, False])
    threshold, p, r, f1 = best_threshold(scores, hits, targets=4)
    assert threshold == 0.6  # 3 of 4 found, 1 false: F1 0.75; at 0.8: 2 of 4, none false: 0.667
    assert (p, r) == (0.75, 0.75) and f1 == pytest.approx(0.75)


def test_shipped_model_loads_and_scores_a_blank_frame_below_threshold():
    detector = CnnDetector()
    assert detector.stride == STRIDE
    assert detector.detect(np.full((512, 512, 3), 128, np.uint8)) == []


def test_network_input_is_opencvs_blob_of_the_frame():
    """The detector's own NCHW [0, 1] input gives the network's output on cv2.dnn.blobFromImage's, exactly, from
    an RGB frame and from the RGB view of an RGBA one (the camera's)."""
    rgba = np.random.default_rng(3).integers(0, 256, (512, 512, 4), np.uint8)
    rgb = np.ascontiguousarray(rgba[..., :3])
    detector = CnnDetector()
    ours, from_view = detector._forward(rgb).copy(), detector._forward(rgba[..., :3]).copy()
    detector.net.setInput(cv2.dnn.blobFromImage(rgb, scalefactor=1.0 / 255.0))
    opencv = np.asarray(detector.net.forward())[0]
    np.testing.assert_array_equal(ours, opencv)
    np.testing.assert_array_equal(from_view, opencv)


@pytest.mark.parametrize("shape", [(4, 128, 128), (5, 170, 170), (5, 128, 64)],
                         ids=["four-outputs", "no-whole-stride", "not-square"])
def test_a_network_of_another_output_shape_is_refused(monkeypatch, shape):
    """The probe's blank frame must give (5, 512 / s, 512 / s) for a whole stride s."""
    monkeypatch.setattr(CnnDetector, "_forward", lambda self, rgb: np.zeros(shape, np.float32))
    with pytest.raises(ConfigError, match=rf"gives outputs of shape \({shape[0]}, {shape[1]}, {shape[2]}\)"):
        CnnDetector()


def test_missing_model_file_is_one_config_error_line_naming_it(tmp_path):
    path = tmp_path / "ugv_detector.onnx"
    with pytest.raises(ConfigError) as error:
        CnnDetector(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message


@pytest.mark.parametrize("content", [b"\x00\x01garbage{{{ not onnx", DEFAULT_MODEL_PATH.read_bytes()[:20_000]],
                         ids=["garbage", "truncated"])
def test_corrupt_model_file_is_one_config_error_line_naming_it(tmp_path, content):
    path = tmp_path / "ugv_detector.onnx"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as error:
        CnnDetector(path)
    message = str(error.value)
    assert str(path) in message and "\n" not in message


def test_relative_model_path_falls_back_to_the_project_root_as_the_crhf_calibration_does(tmp_path, monkeypatch):
    """docs/scenarios.md gives both defaults as models/...: outside the checkout both resolve under its root."""
    monkeypatch.chdir(tmp_path)
    assert CnnDetector("models/ugv_detector.onnx").model_path == DEFAULT_MODEL_PATH
    calibration = CrhfConfig(calibration_file="models/crhf_pad_calibration.npz").calibration_path()
    assert calibration == PROJECT_ROOT / "models" / "crhf_pad_calibration.npz" and calibration.is_file()


def test_relative_model_path_in_the_working_directory_comes_first(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "ugv_detector.onnx").write_bytes(b"not onnx")
    with pytest.raises(ConfigError, match="model file models/ugv_detector.onnx is not a readable"):
        CnnDetector("models/ugv_detector.onnx")


def test_frame_of_another_size_is_a_config_error():
    with pytest.raises(ConfigError, match="512 x 512"):
        CnnDetector().detect(np.zeros((480, 640, 3), np.uint8))
