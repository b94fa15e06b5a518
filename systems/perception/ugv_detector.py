"""Two UGV detectors for seed 003's fisheye frames (Sec. 2.2.1: the paper detects the UGV with YOLOv3 in the
raw fisheye image; Table 3 scores it), behind one interface:

    detector.detect(rgb) -> [(box, score), ...]

`rgb` is an (H, W, 3) RGB or (H, W, 4) RGBA uint8 fisheye image; `box` is [x, y, w, h] px, (x, y) the
top-left corner, covering [x, x + w) x [y, y + h) in pixel-index space (OpenCV's Rect, the project's box:
systems/perception/box_tracker.py); `score` in [0, 1], 0.5 at the detector's decision threshold, highest
first. Both run on the raw fisheye image, as the paper does: its rectified pinhole view (100 deg) drops
everything beyond 50 deg off the axis, where the small, distant targets are.

(a) `HogSvmDetector`, learned: Dalal and Triggs's HOG (grey gradients [-1, 0, 1], 9 unsigned orientation
bins voted between the nearest two, 4 px cells, 2 x 2-cell blocks at a one-cell stride, L2-Hys) on a
square 6 x 6-cell window, plus per-cell colour channels (saturation in 6 hue bins and brightness, as in
Dollar's aggregated channel features: HOG alone is colour-blind and, on the grey, square-textured ground,
gave F1 0.78-0.84 on validation frames against 0.95 with them), scored by a linear SVM densely over an
image pyramid (every cell of every level: one correlation of the weight templates with the level's
maps), the windows above threshold refined by a linear box regression from the same features (the window
is square; the UGV's box is not), then greedy non-maximum suppression (also dropping a box lying mostly
inside a better one: a part of the UGV found at a smaller scale). Trained by models/train_ugv_detector.py;
its model file (models/ugv_detector.yml, cv2.FileStorage YAML) holds the layout, the weights, the bias,
the threshold, the pyramid and the regression. OpenCV 5 moved `HOGDescriptor` (to contrib's xobjdetect)
and `cv2.ml` (to contrib) out of opencv-python-headless, the project's OpenCV: the features and the scan
are written here on numpy and cv2's core, and the SVM is trained with SciPy.

(b) `ColourPadDetector`, classical: the UGV's body colour segmented in HSV (the textured ground is
grey, so saturation alone separates coloured things from it), its connected parts grouped (seen from
above, the pad on the roof splits the body into two strips), and a group accepted only when its
convex hull holds the white of the pad (a plain box of the UGV's own colour has none). Its box is the
group's enclosing box.

`UgvDetectorSystem` wraps either as a LeafSystem.
"""

import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.config import ConfigError, require

DEFAULT_MODEL_PATH = Path(__file__).resolve().parents[2] / "models" / "ugv_detector.yml"
MODEL_FORMAT = "ugv_hog_svm_v2"
NMS_CONTAINMENT = 0.6  # the learned detector drops a box that lies this much inside a better one
MAX_CANDIDATES = 100  # the learned detector regresses and suppresses only its highest-margin windows

Detection = tuple[np.ndarray, float]  # (box [x, y, w, h] px, score in [0, 1])


class UgvDetector(Protocol):
    """What every UGV detector offers (module docstring)."""

    def detect(self, rgb: np.ndarray) -> list[Detection]: ...


def iou(a, b) -> float:
    """Intersection over union of two boxes [x, y, w, h] (seed 003 Eq. 2)."""
    ax, ay, aw, ah = a
    bx, by, bw, bh = b
    w = min(ax + aw, bx + bw) - max(ax, bx)
    h = min(ay + ah, by + bh) - max(ay, by)
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return float(inter / (aw * ah + bw * bh - inter))


def iou_many(box, boxes: np.ndarray) -> np.ndarray:
    """IOU of one box with each of `boxes` (N, 4)."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    w = np.minimum(box[0] + box[2], boxes[:, 0] + boxes[:, 2]) - np.maximum(box[0], boxes[:, 0])
    h = np.minimum(box[1] + box[3], boxes[:, 1] + boxes[:, 3]) - np.maximum(box[1], boxes[:, 1])
    inter = np.clip(w, 0, None) * np.clip(h, 0, None)
    return inter / (box[2] * box[3] + boxes[:, 2] * boxes[:, 3] - inter)


def overlap_of_smaller(box, boxes: np.ndarray) -> np.ndarray:
    """The intersection of one box with each of `boxes` (N, 4) over the smaller of the two's area."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    w = np.minimum(box[0] + box[2], boxes[:, 0] + boxes[:, 2]) - np.maximum(box[0], boxes[:, 0])
    h = np.minimum(box[1] + box[3], boxes[:, 1] + boxes[:, 3]) - np.maximum(box[1], boxes[:, 1])
    inter = np.clip(w, 0, None) * np.clip(h, 0, None)
    return inter / np.minimum(box[2] * box[3], boxes[:, 2] * boxes[:, 3])


def non_maximum_suppression(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float,
                            max_keep: int | None = None, containment: float = 1.0) -> np.ndarray:
    """Indices of the boxes kept by greedy NMS, highest score first: a box goes when its IOU with a kept
    one exceeds `iou_threshold`, or when more than `containment` of the smaller one lies in the other (a
    part of an object found at a smaller scale)."""
    order = np.argsort(-np.asarray(scores))
    keep = []
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    while order.size and (max_keep is None or len(keep) < max_keep):
        i = order[0]
        keep.append(i)
        rest = order[1:]
        order = rest[(iou_many(boxes[i], boxes[rest]) <= iou_threshold)
                     & (overlap_of_smaller(boxes[i], boxes[rest]) <= containment)]
    return np.asarray(keep, int)


def to_rgb(image: np.ndarray) -> np.ndarray:
    """The RGB channels of an RGB or RGBA uint8 image (a view)."""
    require(image.ndim == 3 and image.shape[2] in (3, 4) and image.dtype == np.uint8,
            f"a UGV detector needs an (H, W, 3 or 4) uint8 image, got {image.shape} {image.dtype}")
    return image[..., :3]


# ---------------------------------------------------------------------------------------------------------
# HOG features and the dense linear scan


@dataclass(frozen=True)
class HogLayout:
    """HOG's geometry [px, cells] and the window's context (the window's side over the object's larger
    side, so the object fills window_px / context px of it)."""

    cell_px: int = 4
    window_cells: int = 6
    bins: int = 9
    clip: float = 0.2  # L2-Hys
    context: float = 1.15
    colour_bins: int = 6  # per-cell colour channels: saturation-weighted hue bins (0: HOG alone), and brightness

    @property
    def window_px(self) -> int:
        return self.cell_px * self.window_cells

    @property
    def blocks_per_side(self) -> int:
        return self.window_cells - 1

    @property
    def block_size(self) -> int:
        return 4 * self.bins

    @property
    def hog_size(self) -> int:
        return self.blocks_per_side**2 * self.block_size

    @property
    def colour_size(self) -> int:
        """Per-cell colour channels: the hue bins and brightness, or none."""
        return self.colour_bins + 1 if self.colour_bins else 0

    @property
    def feature_size(self) -> int:
        return self.hog_size + self.window_cells**2 * self.colour_size

    def split(self, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A flat weight vector (feature_size) as the HOG template (n, n, block_size) and the colour
        template (window_cells, window_cells, colour_size)."""
        n, w = self.blocks_per_side, self.window_cells
        weights = np.asarray(weights, np.float32).ravel()
        return weights[:self.hog_size].reshape(n, n, self.block_size), weights[self.hog_size:].reshape(w, w, -1)

    @property
    def object_px(self) -> float:
        """The object's larger side [px] when it fills the window at level scale 1."""
        return self.window_px / self.context


def grey(image: np.ndarray) -> np.ndarray:
    """Grey uint8 of an RGB(A) or grey image."""
    if image.ndim == 2:
        return image
    return cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2GRAY)


_CELL_INDEX_CACHE: dict = {}


def _cell_index(rows: int, cols: int, cell_px: int, bins: int) -> np.ndarray:
    key = (rows, cols, cell_px, bins)
    if key not in _CELL_INDEX_CACHE:
        wc = cols // cell_px
        _CELL_INDEX_CACHE[key] = ((np.arange(rows)[:, None] // cell_px) * wc
                                  + np.arange(cols)[None, :] // cell_px).astype(np.int64).ravel() * bins
        if len(_CELL_INDEX_CACHE) > 64:
            _CELL_INDEX_CACHE.pop(next(iter(_CELL_INDEX_CACHE)))
    return _CELL_INDEX_CACHE[key]


def hog_cells(image: np.ndarray, layout: HogLayout) -> np.ndarray:
    """Cell histograms (rows // cell, cols // cell, bins) of a grey uint8 image: gradients by [-1, 0, 1]
    (reflected at the border), unsigned orientation. Each pixel's magnitude goes to one of 2 bins
    half-bins (one bincount, several times cheaper than voting each pixel into two bins), and each bin
    then takes 3/4 of its own two half-bins and 1/4 of the two beyond them: linear voting between the
    two nearest bin centres with the orientation rounded to its half-bin's centre."""
    c, bins = layout.cell_px, layout.bins
    rows, cols = (image.shape[0] // c) * c, (image.shape[1] // c) * c
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=1)[:rows, :cols]
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=1)[:rows, :cols]
    magnitude, angle = cv2.cartToPolar(gx, gy)  # angle in [0, 2 pi]
    # floor(angle / (pi / 2 bins)) by rounding (convertScaleAbs) of half a step less, then mod 2 bins.
    half = cv2.LUT(cv2.convertScaleAbs(angle, alpha=2 * bins / np.pi, beta=-0.5), _half_bin_lut(bins))
    index = _cell_index(rows, cols, c, 2 * bins)
    halves = np.bincount(index + half.ravel(), magnitude.ravel(), (rows // c) * (cols // c) * 2 * bins)
    h = halves.astype(np.float32).reshape(-1, 2 * bins)
    h = np.concatenate([h[:, -1:], h, h[:, :1]], axis=1)  # circular: h[:, k + 1] is half-bin k
    cells = 0.75 * (h[:, 1:-1:2] + h[:, 2::2]) + 0.25 * (h[:, 0:-2:2] + h[:, 3::2])
    return cells.reshape(rows // c, cols // c, bins)


def _half_bin_lut(bins: int) -> np.ndarray:
    return (np.arange(256) % (2 * bins)).astype(np.uint8)


def hog_blocks(cells: np.ndarray, layout: HogLayout) -> np.ndarray:
    """Block vectors (rows - 1, cols - 1, 4 bins) of 2 x 2 cells at a one-cell stride, L2-Hys normalised."""
    v = np.concatenate([cells[:-1, :-1], cells[1:, :-1], cells[:-1, 1:], cells[1:, 1:]], axis=2)
    eps = np.float32(1e-3 * layout.cell_px**2)
    v /= np.sqrt((v * v).sum(axis=2, keepdims=True) + eps**2)
    np.minimum(v, np.float32(layout.clip), out=v)
    v /= np.sqrt((v * v).sum(axis=2, keepdims=True) + np.float32(1e-6))
    return v


def hog_blocks_of(image: np.ndarray, layout: HogLayout) -> np.ndarray:
    """hog_blocks(hog_cells(grey image))."""
    return hog_blocks(hog_cells(grey(image), layout), layout)


def _hue_bin_lut(bins: int) -> np.ndarray:
    """OpenCV's 8-bit hue (0-179) to `bins` bins, the first centred on red (0)."""
    width = 180 / bins
    return (np.floor((np.arange(256) + width / 2) / width) % bins).astype(np.uint8)


def colour_cells(rgb: np.ndarray, layout: HogLayout) -> np.ndarray:
    """Per-cell colour channels (rows // cell, cols // cell, colour_size) of an RGB uint8 image, as in
    Dollar's channel features: for each of `colour_bins` hue bins the cell's mean saturation over its
    pixels in that bin (0-1), then the cell's mean brightness (V, 0-1)."""
    c, bins = layout.cell_px, layout.colour_bins
    rows, cols = (rgb.shape[0] // c) * c, (rgb.shape[1] // c) * c
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb[:rows, :cols]), cv2.COLOR_RGB2HSV)
    hue = cv2.LUT(hsv[..., 0], _hue_bin_lut(bins))
    index = _cell_index(rows, cols, c, bins)
    size = (rows // c) * (cols // c)
    saturation = np.bincount(index + hue.ravel(), hsv[..., 1].ravel(), size * bins).reshape(rows // c, cols // c, bins)
    value = cv2.resize(hsv[..., 2], (cols // c, rows // c), interpolation=cv2.INTER_AREA)
    out = np.empty((rows // c, cols // c, bins + 1), np.float32)
    out[..., :bins] = saturation * (1.0 / (255 * c * c))
    out[..., bins] = value * (1.0 / 255)
    return out


@dataclass
class LevelMaps:
    """A pyramid level's feature maps: HOG blocks (rows - 1, cols - 1, block_size) and colour cells
    (rows, cols, colour_size; empty without colour), rows x cols the level's cells."""

    blocks: np.ndarray
    colour: np.ndarray


def level_maps(rgb: np.ndarray, layout: HogLayout) -> LevelMaps:
    """The feature maps of an RGB uint8 image."""
    colour = colour_cells(rgb, layout) if layout.colour_size else np.zeros((0, 0, 0), np.float32)
    return LevelMaps(hog_blocks_of(rgb, layout), colour)


def _correlate(maps: np.ndarray, template: np.ndarray, rows: int, cols: int) -> np.ndarray:
    out = None
    for d in range(maps.shape[2]):
        part = cv2.filter2D(np.ascontiguousarray(maps[..., d]), -1, np.ascontiguousarray(template[..., d]),
                            anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
        out = part if out is None else cv2.add(out, part)
    return out[:rows, :cols]


def window_scores(maps: LevelMaps, weights: np.ndarray, layout: HogLayout) -> np.ndarray:
    """w . features of every window of a level (weights flat, feature_size): (cell rows - window_cells + 1,
    cell cols - window_cells + 1), entry (i, j) the window whose top-left cell is (i, j)."""
    hog, colour = layout.split(weights)
    n = layout.blocks_per_side
    rows, cols = maps.blocks.shape[0] - n + 1, maps.blocks.shape[1] - n + 1
    if rows <= 0 or cols <= 0:
        return np.zeros((0, 0), np.float32)
    scores = _correlate(maps.blocks, hog, rows, cols)
    if layout.colour_size:
        scores = cv2.add(scores, _correlate(maps.colour, colour, rows, cols))
    return scores


def window_features(maps: LevelMaps, rows, cols, layout: HogLayout) -> np.ndarray:
    """Feature vectors (k, feature_size) of the windows whose top-left cells are (rows, cols): the HOG
    blocks, then the colour cells, each in its template's C order."""
    rows, cols = np.asarray(rows, int), np.asarray(cols, int)
    parts = []
    for grid, n in ((maps.blocks, layout.blocks_per_side), (maps.colour, layout.window_cells)):
        if grid.size == 0:
            continue
        di, dj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        parts.append(grid[rows[:, None, None] + di, cols[:, None, None] + dj].reshape(len(rows), -1))
    return np.hstack(parts)


def resize_level(image: np.ndarray, scale: float) -> np.ndarray:
    """The image scaled by `scale` (INTER_AREA down, INTER_LINEAR up), as every pyramid level is made."""
    if scale == 1.0:
        return image
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)


def crop_patch(image: np.ndarray, centre_xy, scale: float, layout: HogLayout) -> np.ndarray:
    """The level-`scale` pixels of the window centred at `centre_xy` (original px) with one cell of margin
    ((window_px + 2 cell_px) square), made as the scan makes its levels (`resize_level`, black beyond the
    image) from the region around the window only. For training and tests."""
    cx, cy = float(centre_xy[0]), float(centre_xy[1])
    half = (layout.window_px / 2 + 2 * layout.cell_px) / scale
    x0, y0 = math.floor(cx - half), math.floor(cy - half)
    x1, y1 = math.ceil(cx + half) + 1, math.ceil(cy + half) + 1
    h, w = image.shape[:2]
    region = cv2.copyMakeBorder(image[max(y0, 0):min(y1, h), max(x0, 0):min(x1, w)], max(-y0, 0), max(y1 - h, 0),
                                max(-x0, 0), max(x1 - w, 0), cv2.BORDER_CONSTANT, value=0)
    level = resize_level(region, scale)
    left = round((cx - x0) * scale - layout.window_px / 2) - layout.cell_px
    top = round((cy - y0) * scale - layout.window_px / 2) - layout.cell_px
    side = layout.window_px + 2 * layout.cell_px
    patch = level[max(top, 0):top + side, max(left, 0):left + side]
    if patch.shape[:2] != (side, side):
        patch = cv2.copyMakeBorder(patch, 0, side - patch.shape[0], 0, side - patch.shape[1], cv2.BORDER_CONSTANT)
    return patch


def patch_features(patch: np.ndarray, layout: HogLayout) -> np.ndarray:
    """The window's feature vector from a `crop_patch` of an RGB image (its one-cell margin dropped after
    the gradients)."""
    return window_features(level_maps(patch, layout), [1], [1], layout)[0]


def regression_targets(window_boxes: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The box regression's targets (N, 4) of true boxes relative to square windows [x, y, s, s]: centre
    offsets over s, log of width and height over s."""
    window_boxes, boxes = np.atleast_2d(window_boxes), np.atleast_2d(boxes)
    s = window_boxes[:, 2]
    return np.column_stack([(boxes[:, 0] + boxes[:, 2] / 2 - window_boxes[:, 0] - s / 2) / s,
                            (boxes[:, 1] + boxes[:, 3] / 2 - window_boxes[:, 1] - s / 2) / s,
                            np.log(boxes[:, 2] / s), np.log(boxes[:, 3] / s)])


def apply_regression(window_boxes: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The boxes (N, 4) that `targets` (regression_targets' form) give for the windows."""
    window_boxes, targets = np.atleast_2d(window_boxes), np.atleast_2d(targets)
    s = window_boxes[:, 2]
    w, h = s * np.exp(targets[:, 2]), s * np.exp(targets[:, 3])
    cx = window_boxes[:, 0] + s / 2 + targets[:, 0] * s
    cy = window_boxes[:, 1] + s / 2 + targets[:, 1] * s
    return np.column_stack([cx - w / 2, cy - h / 2, w, h])


def object_box(window_boxes: np.ndarray, layout: HogLayout) -> np.ndarray:
    """The square object boxes that the windows stand for before regression (the window shrunk by the context)."""
    window_boxes = np.atleast_2d(window_boxes)
    s = window_boxes[:, 2] / layout.context
    return np.column_stack([window_boxes[:, 0] + (window_boxes[:, 2] - s) / 2,
                            window_boxes[:, 1] + (window_boxes[:, 2] - s) / 2, s, s])


@dataclass
class HogSvmModel:
    """The learned detector's parameters: the feature layout; k linear SVMs ("components", one per range
    of object sizes, as in multi-resolution detectors: a 15 px UGV is a blur, a 100 px one shows its
    markers), component i's margin w_i . x + b_i and its decision threshold t_i; the pyramid's scales and
    the component that scans each level; per component a box regression ((feature_size + 1, 4): features
    then 1); the NMS overlap; and a line on how it was trained."""

    layout: HogLayout
    weights: np.ndarray  # (k, feature_size)
    bias: np.ndarray  # (k,)
    thresholds: np.ndarray  # (k,)
    scales: np.ndarray  # (levels,)
    level_component: np.ndarray  # (levels,) int
    regression: np.ndarray  # (k, feature_size + 1, 4)
    nms_iou: float = 0.3
    trained: str = ""

    @property
    def components(self) -> int:
        return len(self.bias)

    def validate(self, name: str) -> None:
        k, d = self.components, self.layout.feature_size
        require(k >= 1, f"{name}: no components")
        require(self.weights.shape == (k, d), f"{name}: weights have shape {self.weights.shape}, the feature "
                                              f"layout and {k} components need {(k, d)}")
        require(self.thresholds.shape == (k,), f"{name}: {self.thresholds.size} thresholds for {k} components")
        require(self.regression.shape == (k, d + 1, 4),
                f"{name}: regression has shape {self.regression.shape}, needs {(k, d + 1, 4)}")
        require(self.scales.ndim == 1 and self.scales.size >= 1 and np.all(self.scales > 0),
                f"{name}: scales must be a non-empty list of positive numbers")
        require(self.level_component.shape == self.scales.shape and np.all(self.level_component >= 0)
                and np.all(self.level_component < k), f"{name}: level_component needs one component (< {k}) per scale")
        require(all(np.all(np.isfinite(a)) for a in (self.weights, self.bias, self.thresholds, self.regression,
                                                      self.scales)), f"{name}: holds non-finite numbers")
        require(0 < self.nms_iou < 1, f"{name}: nms_iou must lie in (0, 1)")

    def save(self, path: Path) -> None:
        """Writes the model as OpenCV YAML (cv2.FileStorage), to a temporary name then renamed."""
        path = Path(path)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.stem + ".", suffix=path.suffix)
        os.close(fd)
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        fs.write("format", MODEL_FORMAT)
        fs.write("trained", self.trained)
        for key in ("cell_px", "window_cells", "bins", "colour_bins"):
            fs.write(key, int(getattr(self.layout, key)))
        fs.write("clip", float(self.layout.clip))
        fs.write("context", float(self.layout.context))
        fs.write("nms_iou", float(self.nms_iou))
        fs.write("scales", self.scales.astype(np.float64).reshape(-1, 1))
        fs.write("level_component", self.level_component.astype(np.int32).reshape(-1, 1))
        fs.write("bias", self.bias.astype(np.float64).reshape(-1, 1))
        fs.write("thresholds", self.thresholds.astype(np.float64).reshape(-1, 1))
        fs.write("weights", self.weights.astype(np.float32))
        fs.write("regression", self.regression.reshape(-1, 4).astype(np.float32))
        fs.release()
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would survive the rename
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path) -> "HogSvmModel":
        """Reads a model written by `save`; a missing, unreadable or inconsistent file raises ConfigError
        with one line naming it."""
        path = Path(path)
        name = f"UGV detector model {path}"
        require(path.is_file(), f"{name} is missing (make it with: python models/train_ugv_detector.py)")
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
            opened = fs.isOpened()
        except (cv2.error, SystemError) as e:  # OpenCV's parser errors; SystemError wraps one from the constructor
            cause = e.__cause__ if isinstance(e, SystemError) and e.__cause__ is not None else e
            raise ConfigError(f"{name} is not a readable OpenCV YAML file "
                              f"({' '.join(str(cause).split())[-120:]})") from None
        require(opened, f"{name} could not be opened")
        try:
            require(fs.getNode("format").string() == MODEL_FORMAT,
                    f"{name} is not a '{MODEL_FORMAT}' model (its 'format' is "
                    f"'{fs.getNode('format').string()}')")

            def number(key):
                node = fs.getNode(key)
                require(node.isReal() or node.isInt(), f"{name} lacks the number '{key}'")
                return node.real()

            def matrix(key):
                value = fs.getNode(key).mat()
                require(value is not None, f"{name} lacks the matrix '{key}'")
                return np.asarray(value, np.float64)

            layout = HogLayout(int(number("cell_px")), int(number("window_cells")), int(number("bins")),
                               number("clip"), number("context"), int(number("colour_bins")))
            require(layout.cell_px >= 2 and layout.window_cells >= 2 and layout.bins >= 2 and layout.colour_bins >= 0,
                    f"{name}: cell_px, window_cells and bins must be at least 2, colour_bins not negative")
            bias = matrix("bias").ravel()
            weights = matrix("weights").astype(np.float32)
            require(weights.shape == (bias.size, layout.feature_size),
                    f"{name}: weights have shape {weights.shape}, the feature layout and {bias.size} components "
                    f"need {(bias.size, layout.feature_size)}")
            regression = matrix("regression")
            require(regression.size == bias.size * (layout.feature_size + 1) * 4,
                    f"{name}: regression has {regression.size} numbers, needs "
                    f"{bias.size * (layout.feature_size + 1) * 4}")
            model = cls(layout, weights, bias, matrix("thresholds").ravel(), matrix("scales").ravel(),
                        matrix("level_component").ravel().astype(int),
                        regression.reshape(bias.size, layout.feature_size + 1, 4), number("nms_iou"),
                        fs.getNode("trained").string())
        finally:
            fs.release()
        model.validate(name)
        return model


@dataclass
class Windows:
    """Scanned windows: square boxes (N, 4) px in the image, margins over their component's threshold
    (N,), features (N, feature_size), components (N,)."""

    boxes: np.ndarray
    margins: np.ndarray
    features: np.ndarray
    components: np.ndarray


class HogSvmDetector:
    """The learned detector (module docstring (a)): HOG + colour channels and linear SVMs scanned densely
    over the model's pyramid, boxes refined by regression, greedy NMS. Loads its model at construction
    (`HogSvmModel.load`: ConfigError naming the file when it is missing or corrupt)."""

    def __init__(self, model_path: Path | str = DEFAULT_MODEL_PATH, max_detections: int = 10,
                 model: HogSvmModel | None = None):
        self.model = model if model is not None else HogSvmModel.load(Path(model_path))
        self.max_detections = max_detections

    def windows(self, rgb: np.ndarray, min_margin: float, per_level: int = 200) -> Windows:
        """Every window whose margin over its component's threshold exceeds `min_margin`, at most
        `per_level` per level."""
        model, layout = self.model, self.model.layout
        image = np.ascontiguousarray(to_rgb(rgb))
        boxes, margins, features, components = [], [], [], []
        for scale, component in zip(model.scales, model.level_component):
            level = resize_level(image, float(scale))
            if min(level.shape[:2]) < layout.window_px:
                continue
            maps = level_maps(level, layout)
            scores = window_scores(maps, model.weights[component], layout)
            scores += np.float32(model.bias[component] - model.thresholds[component])
            if scores.size == 0:
                continue
            flat = np.flatnonzero(scores > min_margin)
            if flat.size > per_level:
                flat = flat[np.argpartition(-scores.ravel()[flat], per_level)[:per_level]]
            if flat.size == 0:
                continue
            rows, cols = np.unravel_index(flat, scores.shape)
            # The level's pixel p spans original pixels [p / s', (p + 1) / s'), s' the level's true scale.
            sx, sy = level.shape[1] / image.shape[1], level.shape[0] / image.shape[0]
            side = layout.window_px
            boxes.append(np.column_stack([cols * layout.cell_px / sx, rows * layout.cell_px / sy,
                                          np.full(flat.size, side / sx), np.full(flat.size, side / sy)]))
            margins.append(scores.ravel()[flat])
            features.append(window_features(maps, rows, cols, layout))
            components.append(np.full(flat.size, component))
        if not boxes:
            return Windows(np.zeros((0, 4)), np.zeros(0), np.zeros((0, layout.feature_size), np.float32),
                           np.zeros(0, int))
        return Windows(np.vstack(boxes), np.concatenate(margins), np.vstack(features), np.concatenate(components))

    def detect_with_margins(self, rgb: np.ndarray,
                            min_margin: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Regressed boxes (N, 4), margins over threshold (N,) and components (N,) after NMS, highest
        first, of the windows above `min_margin` (0: the model's decision)."""
        found = self.windows(rgb, min_margin)
        if len(found.margins) == 0:
            return np.zeros((0, 4)), np.zeros(0), np.zeros(0, int)
        best = np.argsort(-found.margins)[:MAX_CANDIDATES]
        windows, margins, components = found.boxes[best], found.margins[best], found.components[best]
        x = np.column_stack([found.features[best], np.ones(len(best), np.float32)])
        targets = np.zeros((len(x), 4))
        for component in np.unique(components):
            mine = components == component
            targets[mine] = x[mine] @ self.model.regression[component].astype(np.float32)
        boxes = apply_regression(windows, targets)
        keep = non_maximum_suppression(boxes, margins, self.model.nms_iou, self.max_detections, NMS_CONTAINMENT)
        return boxes[keep], margins[keep], components[keep]

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        boxes, margins, _ = self.detect_with_margins(rgb)
        # Score: the logistic of the margin over the threshold (0.5 at the threshold).
        return [(box, float(1 / (1 + math.exp(-2.0 * m)))) for box, m in zip(boxes, margins)]


# ---------------------------------------------------------------------------------------------------------
# The classical detector


@dataclass
class ColourPadConfig:
    """HSV thresholds (OpenCV's 8-bit HSV: hue 0-179 in 2 deg steps, saturation and value 0-255) and shape
    tests of the classical detector. The body's hue is GroundVehicleGeometry's (0.75, 0.3, 0.15): 7-8;
    red (0) and yellow (26) lie outside the band."""

    hue_low: int = 3
    hue_high: int = 13
    min_saturation: int = 90  # the grey ground's saturation stays under 15; motion blur halves the body's
    min_value: int = 20  # the body's unlit sides are dark but keep their hue
    white_max_saturation: int = 60  # the pad's white (and the ground's bright patches)
    white_min_value: int = 165
    min_part_px: int = 3  # smaller body-coloured specks are ignored
    # The UGV as one part (seen obliquely: end strips and sides in one ring around the pad), judged by its
    # convex hull: pad white inside, not a solid body-coloured box, little mid-grey ground.
    min_white_fraction: float = 0.1
    max_body_fraction: float = 0.72  # a plain box of the UGV's colour fills its hull at 0.8-0.95
    max_ground_fraction: float = 0.45
    # Seen from above, the pad splits the body into its two end strips: two elongated parts of similar
    # length, about parallel, side by side at about their length apart; then their joint hull is judged.
    min_strip_elongation: float = 1.6  # long over short side of each part's minimum-area rectangle
    max_length_ratio: float = 2.5
    max_strip_angle_deg: float = 27.0  # between the two strips' long axes
    strip_distance_range: tuple = (0.3, 3.0)  # the centres' distance over the strips' mean length
    max_along_cosine: float = 0.85  # the centres' offset must run across the strips, not along them
    min_shaped_part_px: float = 8.0  # shorter parts have no reliable shape: only their sizes and distance count
    min_box_px: int = 5

    def validate(self, prefix: str = "colour_pad") -> None:
        require(0 <= self.hue_low <= self.hue_high <= 179, f"{prefix}.hue_low/high must satisfy 0 <= low <= high <= 179")
        for name in ("min_saturation", "min_value", "white_max_saturation", "white_min_value"):
            require(0 <= getattr(self, name) <= 255, f"{prefix}.{name} must lie in [0, 255]")
        for name in ("min_white_fraction", "max_body_fraction", "max_ground_fraction", "max_along_cosine"):
            require(0 <= getattr(self, name) <= 1, f"{prefix}.{name} must lie in [0, 1]")
        require(self.max_length_ratio >= 1 and self.min_strip_elongation >= 1,
                f"{prefix}.max_length_ratio and min_strip_elongation must be at least 1")
        require(len(self.strip_distance_range) == 2 and 0 <= self.strip_distance_range[0] <= self.strip_distance_range[1],
                f"{prefix}.strip_distance_range must be [low, high] with 0 <= low <= high")


@dataclass
class _Part:
    """A body-coloured connected part: its pixels (N, 2) [x, y], centre, long side, short side, long
    axis's angle [rad]."""

    points: np.ndarray
    centre: np.ndarray
    length: float
    width: float
    angle: float


class ColourPadDetector:
    """The classical detector (module docstring (b))."""

    def __init__(self, config: ColourPadConfig | None = None):
        self.config = config or ColourPadConfig()
        self.config.validate()

    def masks(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(body, white, ground) uint8 masks: the body's hue; white; unsaturated mid-greys."""
        c = self.config
        hsv = cv2.cvtColor(np.ascontiguousarray(to_rgb(rgb)), cv2.COLOR_RGB2HSV)
        body = cv2.inRange(hsv, (c.hue_low, c.min_saturation, c.min_value), (c.hue_high, 255, 255))
        white = cv2.inRange(hsv, (0, 0, c.white_min_value), (179, c.white_max_saturation, 255))
        ground = cv2.inRange(hsv, (0, 0, 60), (179, c.white_max_saturation, c.white_min_value - 1))
        return body, white, ground

    def parts(self, body: np.ndarray) -> list[_Part]:
        """The body mask's connected parts (after a 3 x 3 closing) of at least `min_part_px` pixels."""
        body = cv2.morphologyEx(body, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        count, labels, stats, _ = cv2.connectedComponentsWithStats(body, connectivity=8)
        parts = []
        for i in range(1, count):
            if stats[i, cv2.CC_STAT_AREA] < self.config.min_part_px:
                continue
            x, y, w, h = stats[i, :4]
            rows, cols = np.nonzero(labels[y:y + h, x:x + w] == i)
            points = np.column_stack([cols + x, rows + y]).astype(np.int32)
            (cx, cy), (a, b), angle = cv2.minAreaRect(points)
            # The pixels' own extent: a one-pixel-wide line has a zero-width rectangle.
            a, b = a + 1.0, b + 1.0
            long_angle = math.radians(angle) + (0.0 if a >= b else math.pi / 2)
            parts.append(_Part(points, np.array([cx, cy]), max(a, b), min(a, b), long_angle))
        return parts

    def _strip_pair(self, p: _Part, q: _Part) -> bool:
        """Whether two parts look like the UGV's two end strips (ColourPadConfig's strip tests)."""
        c = self.config
        if max(p.length, q.length) > c.max_length_ratio * min(p.length, q.length):
            return False
        offset = q.centre - p.centre
        distance = float(np.hypot(*offset))
        mean_length = (p.length + q.length) / 2
        if not c.strip_distance_range[0] * mean_length <= distance <= c.strip_distance_range[1] * mean_length:
            return False
        if max(p.length, q.length) < c.min_shaped_part_px:  # too few pixels for a shape: the hull decides
            return True
        if min(p.length / p.width, q.length / q.width) < c.min_strip_elongation:
            return False
        if abs(math.sin(p.angle - q.angle)) > math.sin(math.radians(c.max_strip_angle_deg)):
            return False
        # The mean axis of two undirected lines: half the angle of the summed doubled-angle vectors.
        mean = 0.5 * math.atan2(math.sin(2 * p.angle) + math.sin(2 * q.angle), math.cos(2 * p.angle) + math.cos(2 * q.angle))
        axis = np.array([math.cos(mean), math.sin(mean)])
        return abs(float(offset @ axis)) <= c.max_along_cosine * distance

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        c = self.config
        body, white, ground = self.masks(rgb)
        parts = self.parts(body)
        found, used = [], set()
        for i, p in enumerate(parts):  # pairs of strips first: they give the whole roof
            for j in range(i + 1, len(parts)):
                if i in used or j in used or not self._strip_pair(p, parts[j]):
                    continue
                points = np.vstack([p.points, parts[j].points])
                score = self._roof(points, white, body, ground)
                if score is not None:
                    found.append((points, score))
                    used.update((i, j))
        for i, p in enumerate(parts):
            if i not in used:
                score = self._roof(p.points, white, body, ground)
                if score is not None:
                    found.append((p.points, score))
        detections = []
        for points, score in found:
            x, y, w, h = cv2.boundingRect(points)
            if min(w, h) >= c.min_box_px:
                detections.append((np.array([x, y, w, h], float), score))
        detections.sort(key=lambda d: -d[1])
        return detections

    def _roof(self, points: np.ndarray, white, body, ground) -> float | None:
        """The score of the convex hull of `points` as the UGV's roof (pad white, some but not only body
        colour, little mid-grey ground), or None when it is not one."""
        c = self.config
        hull = cv2.convexHull(points)
        x, y, w, h = cv2.boundingRect(hull)
        if min(w, h) < c.min_box_px:
            return None
        mask = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(mask, hull - np.array([x, y], np.int32), 255)
        area = float(np.count_nonzero(mask))
        white_fraction, body_fraction, ground_fraction = (
            float(np.count_nonzero(cv2.bitwise_and(m[y:y + h, x:x + w], mask))) / area for m in (white, body, ground))
        if (white_fraction < c.min_white_fraction or body_fraction > c.max_body_fraction
                or ground_fraction > c.max_ground_fraction):
            return None
        # 0.5 at the acceptance limits, towards 1 with a hull clearly inside all three.
        margin = min(white_fraction - c.min_white_fraction, c.max_body_fraction - body_fraction,
                     c.max_ground_fraction - ground_fraction)
        return 0.5 + 0.5 * min(1.0, margin / 0.2)


# ---------------------------------------------------------------------------------------------------------


class UgvDetectorSystem(LeafSystem):
    """Input `color_image` (ImageRgba8U, the fisheye's); output `detections` (list of (box [x, y, w, h] px,
    score), the detector's), computed when evaluated: evaluate it at the camera's rate."""

    def __init__(self, detector: UgvDetector, width: int = 512, height: int = 512):
        super().__init__()
        self.detector = detector
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclareAbstractOutputPort("detections", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        output.set_value(self.detector.detect(self.get_input_port().Eval(context).data))
