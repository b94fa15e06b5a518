"""Seed 003's UGV detectors for its fisheye frames (Sec. 2.2.1: the paper detects the UGV with YOLOv3 in the
raw fisheye image; Table 3 scores it), behind one interface:

    detector.detect(rgb) -> [(box, score), ...]

`rgb` is an (H, W, 3) RGB or (H, W, 4) RGBA uint8 fisheye image; `box` is [x, y, w, h] px, (x, y) the
top-left corner, covering [x, x + w) x [y, y + h) in pixel-index space (OpenCV's Rect, the project's box:
systems/perception/box_tracker.py); `score` in [0, 1], 0.5 at the detector's decision threshold, highest
first. Both run on the raw fisheye image, as the paper does: its rectified pinhole view (100 deg) drops
everything beyond 50 deg off the axis, where the small, distant targets are.

(a) `CnnDetector` (systems/perception/ugv_cnn_detector.py), learned: a small convolutional network from an
ONNX file, run by OpenCV's dnn module.

(b) `ColourPadDetector` (here), classical: the UGV's body colour segmented in HSV (the textured ground is
grey, so saturation alone separates coloured things from it), its connected parts grouped (seen from
above, the pad on the roof splits the body into two strips), and a group accepted only when its
convex hull holds the white of the pad (a plain box of the UGV's own colour has none). Its box is the
group's enclosing box.

Here too: greedy NMS and the scoring against a true box (on box_tracker's IOU), and `UgvDetectorSystem`,
either as a LeafSystem.
"""

import math
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.config import require, require_non_negative
from systems.perception.box_tracker import iou_matrix

Detection = tuple[np.ndarray, float]  # (box [x, y, w, h] px, score in [0, 1])


class UgvDetector(Protocol):
    """What every UGV detector offers (module docstring)."""

    def detect(self, rgb: np.ndarray) -> list[Detection]: ...


def non_maximum_suppression(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float,
                            max_keep: int | None = None) -> np.ndarray:
    """Indices of the boxes [x, y, w, h] px kept by greedy NMS, highest score first: a box goes when its IOU
    (box_tracker's, Eq. 2) with a kept one exceeds `iou_threshold`."""
    order = np.argsort(-np.asarray(scores))
    keep = []
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    while order.size and (max_keep is None or len(keep) < max_keep):
        i = order[0]
        keep.append(i)
        rest = order[1:]
        order = rest[iou_matrix(boxes[i], boxes[rest])[0] <= iou_threshold]
    return np.asarray(keep, int)


def match_truth(detections: list[Detection], truth: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seed 003 Table 3's scoring of one frame: boxes (N, 4), scores (N,) and which one is the true positive
    (the highest-scoring detection with IOU >= 0.5 against the true box; none without a true box)."""
    boxes = np.array([box for box, _ in detections], float).reshape(-1, 4)
    scores = np.array([score for _, score in detections], float)
    matched = np.zeros(len(boxes), bool)
    if truth is not None and len(boxes):
        hits = np.flatnonzero(iou_matrix(truth, boxes)[0] >= 0.5)
        if hits.size:
            matched[hits[np.argmax(scores[hits])]] = True
    return boxes, scores, matched


def to_rgb(image: np.ndarray) -> np.ndarray:
    """The RGB channels of an RGB or RGBA uint8 image (a view)."""
    require(image.ndim == 3 and image.shape[2] in (3, 4) and image.dtype == np.uint8,
            f"a UGV detector needs an (H, W, 3 or 4) uint8 image, got {image.shape} {image.dtype}")
    return image[..., :3]


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
    strip_distance_range: list[float] = field(default_factory=lambda: [0.3, 3.0])  # [low, high]: the centres'
    #   distance over the strips' mean length
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
        # At 0 deg or under no pair of shaped strips passes: the UGV seen from above is lost.
        require(0 < self.max_strip_angle_deg <= 90,
                f"{prefix}.max_strip_angle_deg must lie in (0, 90], got {self.max_strip_angle_deg}")
        for name in ("min_part_px", "min_box_px"):
            require(isinstance(getattr(self, name), int) and getattr(self, name) >= 1,
                    f"{prefix}.{name} must be an integer of at least 1, got {getattr(self, name)}")
        require_non_negative(self.min_shaped_part_px, f"{prefix}.min_shaped_part_px")


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
