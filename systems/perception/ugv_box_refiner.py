"""The learned UGV detector's boxes checked for the UGV's colour and re-centred on the pad by the classical
detector's colour segmentation (ours: seed 003 uses YOLOv3's boxes as they come).

The CNN (ugv_cnn_detector.py) puts a box's centre on its stride-4 grid plus a regressed offset: its centre lies a
median 3.7 px from the pad's (p95 12.7 px, the UGV's side in an oblique view pulling it off the roof), and one
fisheye pixel is 3.6 cm at 7 m. The classical detector boxes the roof's colour (its end strips and the pad's
white), whole pixels of the image itself, centred on the pad. So `ColourRefinedDetector` keeps the learned
detector's scores and its boxes' widths and heights (the whole vehicle, as the
tracker has followed it), and moves the box's centre to the centre of the classical detector's box found in a
window around it (the box grown by `margin` of its width and height on each side, at least `min_margin_px`)
when that box lies within the network's (at least `min_inside` of its area: the roof is part of the vehicle)
and the window did not cut it (it touches no window edge that is not the image's). Otherwise, and for a box
over `max_box_px` (close up, where the pixels are small and the roof's centre and the body's differ by tens of
pixels), the detection keeps its own box.

A learned detection whose own box holds fewer than `min_body_px` pixels of the UGV's body colour (the classical
detector's HSV band) is dropped: the network's false alarms lie on vehicles of other colours and on the ground. On
800 validation frames (seeds 500300-501099, the training ground; not the held-out ones: `benchmarks/ugv_detection.py
--split validation --first 300 --frames 800 --min-body-px N`) the veto at 5 px drops 14 of the 23 false positives
the refined boxes would have and no true box; 11 px the same (docs/results.md).

Only the centre moves: the two detectors box different extents in an oblique view (the roof, 41 x 44 px, inside
the network's 67 x 65 px), and a box whose size jumped between them from frame to frame gave the box tracker's
constant-velocity filter a size rate that carried its coasting box off the UGV (circle path at 0.8 m/s: the lock
lost for good at 7 s, measured).

Boxes are [x, y, w, h] px in pixel-index space (systems/perception/ugv_detector.py).
"""

from dataclasses import dataclass

import cv2
import numpy as np

from systems.config import require, require_non_negative, require_positive
from systems.perception.box_tracker import intersection_matrix
from systems.perception.ugv_detector import ColourPadDetector, Detection, UgvDetector, to_rgb

REFINEMENTS = ("colour", "none")


@dataclass
class BoxRefinementConfig:
    """How the learned detector's boxes are re-centred: `method` "colour" (the default) on the roof's colour, "none"
    as they come (the estimate 0.009 / 0.012 m off in x / y at IH against 0.005 / 0.006 m, docs/results.md)."""

    method: str = "colour"
    margin: float = 0.5  # the window's growth on each side, in the box's width and height
    min_margin_px: int = 8
    min_inside: float = 0.8  # the fraction of the classical box's area that must lie within the learned one
    # Larger boxes (the UGV within about 4 m) keep the network's box: a pixel there is under 2 cm, and close up
    # the colour's box (the roof and a side) and the network's (the whole body) differ by tens of pixels, so
    # taking one in some frames and the other in the rest made the track jump (measured: 40 px between frames
    # in the climb, figure-eight path at 0.2 m/s, and the lock was lost for good).
    max_box_px: float = 80.0
    min_body_px: int = 5  # fewer body-coloured pixels in a learned box: dropped (module docstring); 0 keeps all

    def validate(self, prefix: str = "hybrid.refinement") -> None:
        require(self.method in REFINEMENTS, f"{prefix}.method '{self.method}' is not one of: {', '.join(REFINEMENTS)}")
        require_non_negative(self.margin, f"{prefix}.margin")
        require_non_negative(self.min_margin_px, f"{prefix}.min_margin_px")
        require(0 < self.min_inside <= 1, f"{prefix}.min_inside must lie in (0, 1], got {self.min_inside}")
        require_positive(self.max_box_px, f"{prefix}.max_box_px")
        require_non_negative(self.min_body_px, f"{prefix}.min_body_px")


class ColourRefinedDetector:
    """A UgvDetector whose boxes the classical detector re-measures (module docstring)."""

    def __init__(self, detector: UgvDetector, classical: ColourPadDetector, config: BoxRefinementConfig | None = None):
        self.detector, self.classical = detector, classical
        self.config = config or BoxRefinementConfig()
        self.config.validate()

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        rgb = to_rgb(rgb)
        return [(self.refine(rgb, box), score) for box, score in self.detector.detect(rgb) if self.coloured(rgb, box)]

    def coloured(self, rgb: np.ndarray, box: np.ndarray) -> bool:
        """Whether `box` holds at least `min_body_px` pixels of the UGV's body colour."""
        if self.config.min_body_px == 0:
            return True
        rows, cols = rgb.shape[:2]
        x0, y0 = max(int(np.floor(box[0])), 0), max(int(np.floor(box[1])), 0)
        x1, y1 = min(int(np.ceil(box[0] + box[2])), cols), min(int(np.ceil(box[1] + box[3])), rows)
        if x1 <= x0 or y1 <= y0:
            return False
        body, _, _ = self.classical.masks(rgb[y0:y1, x0:x1])
        return cv2.countNonZero(body) >= self.config.min_body_px

    def window(self, box: np.ndarray, shape: tuple[int, int]) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) px of the window around `box` in an image of `shape` (rows, cols), clipped to it."""
        c = self.config
        x, y, w, h = box
        mx, my = max(c.margin * w, c.min_margin_px), max(c.margin * h, c.min_margin_px)
        rows, cols = shape
        return (max(int(np.floor(x - mx)), 0), max(int(np.floor(y - my)), 0),
                min(int(np.ceil(x + w + mx)), cols), min(int(np.ceil(y + h + my)), rows))

    def refine(self, rgb: np.ndarray, box: np.ndarray) -> np.ndarray:
        """`box` with its centre moved to that of the classical detector's box lying within it in the window around
        it, else `box` as it is (and for a box larger than `max_box_px` either way)."""
        if max(box[2], box[3]) > self.config.max_box_px:
            return box
        x0, y0, x1, y1 = self.window(box, rgb.shape[:2])
        if x1 - x0 < 2 or y1 - y0 < 2:
            return box
        found = [b + [x0, y0, 0, 0] for b, _ in self.classical.detect(rgb[y0:y1, x0:x1])]
        whole = np.array([b for b in found if not _cut(b, (x0, y0, x1, y1), rgb.shape[:2])]).reshape(-1, 4)
        if not len(whole):
            return box
        overlap, _, area = intersection_matrix(box, whole)
        inside = overlap[0] / area[0]
        if inside.max() < self.config.min_inside:
            return box
        x, y, w, h = whole[int(np.argmax(inside))]
        return np.array([x + (w - box[2]) / 2, y + (h - box[3]) / 2, box[2], box[3]])


def _cut(box: np.ndarray, window: tuple[int, int, int, int], shape: tuple[int, int]) -> bool:
    """Whether `box` touches an edge of `window` that is not an edge of the image (the window may have cut it)."""
    x, y, w, h = box
    x0, y0, x1, y1 = window
    rows, cols = shape
    return ((x <= x0 and x0 > 0) or (y <= y0 and y0 > 0) or (x + w >= x1 and x1 < cols)
            or (y + h >= y1 and y1 < rows))
