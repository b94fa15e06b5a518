"""Seed 003's tracking-by-detection (Sec. 2.2.1, Eq. 2-6): detector boxes -> tracks -> the UGV's box.

Boxes are [x, y, w, h] in pixels with (x, y) the top-left corner, OpenCV's Rect (the project's box, as
in motion_compensation.py; the paper's detector gives (x, y) as the centre, Sec. 2.2.1: `centre_form`
converts); image +x right, +y down. A box covers [x, x + w) x [y, y + h) in pixel-index space (pixel i
spans [i, i + 1), as in diagrams/ugv_detection_scenes.py); its centre there is (x + w/2, y + h/2), half a
pixel more than in OpenCV's pixel coordinates (centres at integers). The tracks' Kalman filters work on
the centre form [x_c, y_c, w, h], where a growing box stays put.

Per frame, as in the paper:
- IOU of two boxes, Eq. 2, and its cost s_IOU = 1 - IOU, Eq. 3 (`iou`, `iou_matrix`).
- The appearance: one 1-D histogram of 25 bins per colour channel (R, G, B of the image), concatenated
  into n = 75 bins and L1-normalised (the 75 sum to 1); similarity by histogram intersection,
  sum_k min(c_i^k, c_j^k) (cv2.HISTCMP_INTERSECT), cost s_colour = 1 - intersection, Eq. 4
  (`colour_histogram`, `histogram_similarity`).
- The combined cost s = a1 s_IOU + a2 s_colour with a1 = a2 = 0.5, Eq. 5, for every (track, detection)
  pair: the matrix D of Eq. 6, solved by the Hungarian algorithm (scipy's linear_sum_assignment).
- A Kalman filter predicts each track's box (the paper's refs. 36-37, no model given): constant velocity
  on [x_c, y_c, w, h] (systems/estimators/track_filter.py's model), so D compares a track's box predicted
  to this frame (not last frame's box) with this frame's detections, and a missed frame is bridged.

Ours, where the paper is silent:
- Gates: a pair is not assignable when the detection's innovation chi-square against the track's
  prediction exceeds `gate_chi2`, when its colour cost exceeds `max_colour_cost`, or its combined cost
  exceeds `max_cost`. The Hungarian algorithm otherwise pairs every track with some detection, however
  far; the colour term (its gate, and its half of Eq. 5's cost) is what keeps a differently coloured
  newcomer from taking a coasting track (tests/test_box_tracker.py).
- Recovery, OC-SORT's observation-centric recovery (Cao et al., CVPR 2023, Sec. 3.3): a second association
  of the tracks and detections the first one left unmatched, on each track's last observed box (the detection
  it last matched) in place of its prediction, gated by IOU >= `recovery_min_iou` and the colour and cost
  gates, not the innovation's. A recovered track's kinematics restart at the detection (a new track's state
  and covariance), since its velocity is what failed: the UAV's own rotation jerks the target's box back
  and forth by tens of pixels a frame, a constant-velocity filter takes the jerks for motion, and its
  prediction runs off while the target stays where it was last seen.
- Life cycle (SORT's): an unmatched detection starts a tentative track; `min_hits` matched frames
  confirm it; a tentative track dies at its first miss, a confirmed one after more than `max_misses`.
  Detections scoring under `min_score` are not used.
- A partial view: a detection lying within a confirmed track's predicted box, narrower or shorter than
  `min_size_ratio` of it and keeping at least PARTIAL_WHOLE_EXTENT of its extent the other way (the target half
  under a bridge, or cut by the image's edge: the cut leaves the extent across it whole, and the fragment's
  centre is not the target's) is neither associated nor starts a track: the track coasts as if unseen (and dies after
  `max_misses`), nothing measures from the fragment, and the track's appearance stays the whole target's,
  for the re-acquisition when it reappears. A detection that another track's gate takes is that track's
  whole view, not a fragment (a smaller vehicle seen over a larger one). A box smaller both ways is a whole
  view too: the target seen smaller than the track's box (the learned detector's first boxes near the ground
  are oversized, and the true ones after them lie inside, half its width and under two thirds of its height: taken
  for fragments, they left the locked track unmeasured until it died, measured in ugv-hybrid's climb).
- A track's appearance is a running mean of its matched detections' histograms (`appearance_update`
  the weight of the newest), so one frame of a box overlapping another object moves it little. A track
  started on a frame without an image has no appearance yet (all zeros, colour cost 0 against anything)
  and takes its first matched detection's histogram.
- The target: the paper lands on "the" UGV; here the target is locked once, on the track nearest a cue
  (`cue_px`, the image centre when empty; the first track without either) as soon as that track is
  confirmed (a distractor confirmed first is not taken), and kept while its track lives. When
  the locked track dies, the lock passes to the confirmed track nearest the target's last measured box
  (where a detection last placed it, not where the track's coasting carried it: a track that took jumpy boxes
  for motion coasts off at their rate) within `reacquire_radius_px` whose colour matches the target's
  (`max_colour_cost`): a new id, which `count_identity_switches` counts as a switch. Either way only a track
  one of whose detections scored at least `lock_min_score` is taken (a detector's confident boxes are the
  target, its marginal ones often false alarms).

`step_tracker` is a pure function of (TrackerState, detections, image, time, config); `BoxTracker` holds
the state for scripts; `BoxTrackerSystem` (box_tracker_system.py) holds it in a Drake context.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from systems.config import require, require_non_negative, require_positive
from systems.estimators.track_filter import TrackFilterParams, constant_velocity_model, kalman_predict, kalman_update

BINS_PER_CHANNEL = 25  # Sec. 2.2.1: "each color channel using 25 bins"
HISTOGRAM_SIZE = 3 * BINS_PER_CHANNEL  # n = 75, Eq. 4
_INFEASIBLE = 1e6  # cost of a gated pair in the assignment
PARTIAL_INSIDE = 0.8  # a partial view lies at least this fraction of its area within the track's predicted box
PARTIAL_WHOLE_EXTENT = 0.8  # ... and keeps at least this fraction of the box's extent across the cut


@dataclass(frozen=True)
class Detection:
    """One detector box: `box` [x, y, w, h] px ((x, y) the top-left corner), `score` in [0, 1] (Eq. 1's
    confidence). `truth_id`: the true object's id, for evaluation only (a synthetic detector knows it;
    the tracker never reads it); -1 when unknown."""

    box: np.ndarray
    score: float = 1.0
    truth_id: int = -1


@dataclass
class BoxTrackerConfig:
    """The tracker's settings: pixels, seconds, Hz. Eq. 5's weights are the paper's; the rest is ours."""

    rate_hz: float = 10.0  # seed 003 runs its pipeline at about 9 Hz (Table 7), the fisheye's 10 Hz
    iou_weight: float = 0.5  # a1, Eq. 5
    colour_weight: float = 0.5  # a2, Eq. 5 (a1 + a2 = 1)
    min_score: float = 0.5  # detections scoring under this are dropped
    max_cost: float = 0.75  # combined cost (Eq. 5) above which a pair is not assigned: with IOU 0, colour cost <= 0.5
    max_colour_cost: float = 0.5  # Eq. 4's cost above which a pair is not assigned (intersection under 0.5)
    gate_chi2: float = 18.47  # innovation chi-square on [x, y, w, h] (4 dof, p = 0.001)
    min_hits: int = 3  # N: matched frames that confirm a track
    max_misses: int = 15  # M: missed frames a confirmed track coasts before it dies (1.5 s at 10 Hz)
    measurement_std_px: float = 2.0  # detector box noise
    acceleration_std_px_s2: float = 100.0  # the box's unmodelled acceleration in the image (the UAV's own motion)
    initial_velocity_std_px_s: float = 100.0  # a new track's velocity is unknown
    appearance_update: float = 0.3  # weight of the newest matched histogram in a track's appearance
    min_size_ratio: float = 0.6  # a confirmed track's detection narrower or shorter than this is a partial view
    lock_min_score: float = 0.0  # the lock takes (or re-takes) only a track with a detection scoring this high
    cue_px: list[float] = field(default_factory=list)  # [u, v] px in the image, near the target at first; empty: centre
    cue_radius_px: float = 120.0  # the locked track must start this close to the cue (a quarter of the fisheye's width)
    reacquire_radius_px: float = 150.0  # a lost target is re-locked on a track this close to its last box
    recovery_min_iou: float = 0.3  # a track is recovered by a detection this close to its last one (OC-SORT's 0.3)

    def validate(self, prefix: str = "box_tracker", width: int | None = None, height: int | None = None) -> None:
        """ConfigError naming the field for a setting the tracker cannot run with; with the image's `width` x
        `height` [px] (where known), a cue outside it too."""
        for name in ("rate_hz", "measurement_std_px", "acceleration_std_px_s2", "initial_velocity_std_px_s",
                     "gate_chi2", "max_cost", "max_colour_cost", "cue_radius_px", "reacquire_radius_px"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        for name in ("iou_weight", "colour_weight", "min_score", "lock_min_score"):
            require_non_negative(getattr(self, name), f"{prefix}.{name}")
        require(abs(self.iou_weight + self.colour_weight - 1.0) < 1e-9,
                f"{prefix}.iou_weight + {prefix}.colour_weight must be 1 (Eq. 5), got "
                f"{self.iou_weight} + {self.colour_weight}")
        require(isinstance(self.min_hits, int) and self.min_hits >= 1,
                f"{prefix}.min_hits must be an integer of at least 1, got {self.min_hits}")
        require(isinstance(self.max_misses, int) and self.max_misses >= 0,
                f"{prefix}.max_misses must be a non-negative integer, got {self.max_misses}")
        require(0 <= self.min_size_ratio < 1, f"{prefix}.min_size_ratio must lie in [0, 1), got {self.min_size_ratio}")
        for name in ("min_score", "lock_min_score"):  # a score above 1 drops every detection
            require(getattr(self, name) <= 1, f"{prefix}.{name} must lie in [0, 1] (a detector's score), got "
                    f"{getattr(self, name)}")
        require(0 < self.recovery_min_iou <= 1,
                f"{prefix}.recovery_min_iou must lie in (0, 1], got {self.recovery_min_iou}")
        require(0 < self.appearance_update <= 1,
                f"{prefix}.appearance_update must lie in (0, 1], got {self.appearance_update}")
        require(len(self.cue_px) in (0, 2), f"{prefix}.cue_px needs 2 numbers [u, v] or none, got {len(self.cue_px)}")
        if self.cue_px:  # a cue nowhere near the image (or NaN) never finds a track: the target is never locked
            require(all(math.isfinite(c) for c in self.cue_px), f"{prefix}.cue_px must be finite, got {self.cue_px}")
            if width is not None and height is not None:
                require(0 <= self.cue_px[0] < width and 0 <= self.cue_px[1] < height,
                        f"{prefix}.cue_px {self.cue_px} must lie in the {width} x {height} px image "
                        f"(0 <= u < {width}, 0 <= v < {height})")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


# ----------------------------------------------------------------------------------------------
# Eq. 2-4: the two similarity measures


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """(..., 4) [x_min, y_min, x_max, y_max] px of (..., 4) boxes [x, y, w, h] ((x, y) the top-left)."""
    boxes = np.asarray(boxes, dtype=float)
    return np.concatenate([boxes[..., :2], boxes[..., :2] + boxes[..., 2:]], axis=-1)


def centre_form(boxes: np.ndarray) -> np.ndarray:
    """(..., 4) [x_c, y_c, w, h] px (the centre; the paper's detector form) of boxes [x, y, w, h] (top-left)."""
    boxes = np.asarray(boxes, dtype=float)
    return np.concatenate([boxes[..., :2] + boxes[..., 2:] / 2, boxes[..., 2:]], axis=-1)


def corner_form(boxes: np.ndarray) -> np.ndarray:
    """(..., 4) [x, y, w, h] px (top-left) of boxes [x_c, y_c, w, h] (centre); the inverse of centre_form."""
    boxes = np.asarray(boxes, dtype=float)
    return np.concatenate([boxes[..., :2] - boxes[..., 2:] / 2, boxes[..., 2:]], axis=-1)


def box_centre_pixel(box: np.ndarray) -> np.ndarray:
    """The centre of a box [x, y, w, h] (pixel-index space) in OpenCV's pixel coordinates (centres at
    integers): x + w/2 - 0.5, y + h/2 - 0.5 (px)."""
    x, y, w, h = np.asarray(box, float)
    return np.array([x + w / 2 - 0.5, y + h / 2 - 0.5])


def intersection_matrix(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p, q) intersection areas of p boxes a with q boxes b, [x, y, w, h] px, and the areas of a (p, 1) and
    of b (1, q) [px^2]."""
    ca, cb = box_corners(np.reshape(a, (-1, 4)))[:, None, :], box_corners(np.reshape(b, (-1, 4)))[None, :, :]
    w = np.clip(np.minimum(ca[..., 2], cb[..., 2]) - np.maximum(ca[..., 0], cb[..., 0]), 0.0, None)
    h = np.clip(np.minimum(ca[..., 3], cb[..., 3]) - np.maximum(ca[..., 1], cb[..., 1]), 0.0, None)
    return (w * h, (ca[..., 2] - ca[..., 0]) * (ca[..., 3] - ca[..., 1]),
            (cb[..., 2] - cb[..., 0]) * (cb[..., 3] - cb[..., 1]))


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(p, q) IOU (Eq. 2) of p boxes a against q boxes b, [x, y, w, h] px; 0 for disjoint or empty boxes."""
    inter, area_a, area_b = intersection_matrix(a, b)
    union = area_a + area_b - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """IOU (Eq. 2) of two boxes [x, y, w, h] px."""
    return float(iou_matrix(a, b)[0, 0])


def box_pixels(box: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """The columns and rows (x0, y0, x1, y1), end exclusive, of a box [x, y, w, h] in an image of width x
    height: its corners rounded (an integer box is cv2.Rect's), clipped to the image."""
    x_min, y_min, x_max, y_max = (math.floor(v + 0.5) for v in box_corners(box))
    x0, y0, x1, y1 = max(0, x_min), max(0, y_min), min(width, x_max), min(height, y_max)
    return x0, y0, max(x0, x1), max(y0, y1)


def colour_histogram(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The (75,) float32 appearance of Eq. 4: one 25-bin histogram over [0, 256) of each of the first three
    channels (R, G, B of an RGB or RGBA uint8 image) of the box's pixels, concatenated and normalised to
    sum 1 (L1). All zeros when the box covers no pixel of the image."""
    x0, y0, x1, y1 = box_pixels(box, image.shape[1], image.shape[0])
    if x1 <= x0 or y1 <= y0:
        return np.zeros(HISTOGRAM_SIZE, np.float32)
    roi = np.ascontiguousarray(image[y0:y1, x0:x1])
    h = np.concatenate([cv2.calcHist([roi], [c], None, [BINS_PER_CHANNEL], [0, 256]).ravel() for c in range(3)])
    return (h / h.sum()).astype(np.float32)


def histogram_similarity(h1: np.ndarray, h2: np.ndarray) -> float:
    """Histogram intersection sum_k min(h1_k, h2_k) (cv2.compareHist, HISTCMP_INTERSECT): 1 for equal
    L1-normalised histograms, 0 for disjoint ones. Eq. 4's s_colour is 1 minus this."""
    return float(cv2.compareHist(np.asarray(h1, np.float32), np.asarray(h2, np.float32), cv2.HISTCMP_INTERSECT))


def colour_cost_matrix(track_histograms: np.ndarray, detection_histograms: np.ndarray) -> np.ndarray:
    """(p, q) Eq. 4 costs 1 - sum_k min(c_i^k, c_j^k) (the intersection vectorised; equal to
    1 - histogram_similarity pair by pair where both are seen). A histogram of all zeros is an appearance
    not yet seen (a track started on a frame without an image, a box covering no pixel): its pairs cost 0,
    judged on their boxes alone, so the track takes its first histogram when it is next matched."""
    t = np.reshape(track_histograms, (-1, HISTOGRAM_SIZE))[:, None, :]
    d = np.reshape(detection_histograms, (-1, HISTOGRAM_SIZE))[None, :, :]
    seen = t.any(axis=-1) & d.any(axis=-1)
    return np.where(seen, 1.0 - np.minimum(t, d).sum(axis=-1), 0.0)


def combined_cost(iou_values: np.ndarray, colour_costs: np.ndarray, config: BoxTrackerConfig) -> np.ndarray:
    """Eq. 5 (elementwise, so on Eq. 6's matrix too): a1 (1 - IOU) (Eq. 3) + a2 s_colour (Eq. 4)."""
    return config.iou_weight * (1.0 - np.asarray(iou_values)) + config.colour_weight * np.asarray(colour_costs)


# ----------------------------------------------------------------------------------------------
# Tracks


@dataclass(frozen=True)
class BoxTrack:
    """One track after a frame. x: (8,) the centre form [x_c, y_c, w, h] px and its rates px/s; P: its
    covariance.
    hits: matched frames; misses: consecutive unmatched frames; confirmed once hits reached min_hits.
    histogram: the (75,) appearance (zeros without images). detection: index, in that frame's detection
    list, of the detection it was matched with, or None (coasting). score: the best detector score among
    its matched detections (what the lock asks of a track, `lock_min_score`). observed: the last matched
    detection's box [x, y, w, h] px (what recovery measures from); None for a track built without one."""

    id: int
    x: np.ndarray
    P: np.ndarray
    hits: int = 1
    misses: int = 0
    confirmed: bool = False
    histogram: np.ndarray = field(default_factory=lambda: np.zeros(HISTOGRAM_SIZE, np.float32))
    detection: int | None = None
    score: float = 0.0
    observed: np.ndarray | None = None

    @property
    def box(self) -> np.ndarray:
        """[x, y, w, h] px ((x, y) the top-left): filtered when matched this frame, predicted when coasting."""
        return corner_form(self.x[:4])

    @property
    def centre(self) -> np.ndarray:
        """[x_c, y_c] px, the box's centre (pixel-index space: subtract 0.5 for OpenCV's pixel coordinates)."""
        return self.x[:2].copy()

    @property
    def velocity(self) -> np.ndarray:
        """[dx/dt, dy/dt] px/s of the box's centre."""
        return self.x[4:6].copy()


@dataclass(frozen=True)
class TargetLock:
    """The target's identity. track_id: the locked track, or None (never locked, or lost and not yet
    re-acquired). box, histogram: the target's last measured box (its track's last observed box, the detection it
    last matched) and appearance (for re-acquiring it)."""

    track_id: int | None = None
    box: np.ndarray | None = None
    histogram: np.ndarray | None = None


@dataclass(frozen=True)
class TrackerState:
    """All tracks after the frame at `time` [s] (None before the first), the next id, and the lock."""

    time: float | None = None
    tracks: tuple[BoxTrack, ...] = ()
    next_id: int = 0
    lock: TargetLock = field(default_factory=TargetLock)

    def track(self, track_id: int | None) -> BoxTrack | None:
        return next((t for t in self.tracks if t.id == track_id), None)

    @property
    def target(self) -> BoxTrack | None:
        """The locked target's track, or None."""
        return self.track(self.lock.track_id)


def _filter_params(config: BoxTrackerConfig, dt: float) -> TrackFilterParams:
    return TrackFilterParams(dt_s=dt, measurement_std=config.measurement_std_px,
                             acceleration_std=config.acceleration_std_px_s2,
                             initial_velocity_std=config.initial_velocity_std_px_s, max_coast_steps=config.max_misses)


def predict_track(track: BoxTrack, dt: float, config: BoxTrackerConfig) -> BoxTrack:
    """The track's box predicted dt [s] ahead by its constant-velocity Kalman filter (Eq. 30-31 of
    track_filter), its width and height kept at least one pixel."""
    F, Q, _, _ = constant_velocity_model(_filter_params(config, dt), 4)
    x, P = kalman_predict(track.x, track.P, F, Q)
    x[2:4] = np.maximum(x[2:4], 1.0)
    return replace(track, x=x, P=P, detection=None)


def innovation_chi2(track: BoxTrack, boxes: np.ndarray, config: BoxTrackerConfig) -> np.ndarray:
    """(q,) squared Mahalanobis distances r^T S^-1 r of q detection boxes [x, y, w, h] from a (predicted)
    track's box in the centre form, S = H P H^T + R."""
    S = track.P[:4, :4] + config.measurement_std_px**2 * np.eye(4)
    r = centre_form(np.reshape(boxes, (-1, 4))) - track.x[:4]
    return np.einsum("qi,qi->q", r, np.linalg.solve(S, r.T).T)


def initial_state(box: np.ndarray, config: BoxTrackerConfig) -> tuple[np.ndarray, np.ndarray]:
    """A new track's (x, P) at a detection box [x, y, w, h] px: its centre form, rates 0, their variances."""
    std = np.r_[np.full(4, config.measurement_std_px), np.full(4, config.initial_velocity_std_px_s)]
    return np.r_[centre_form(box), np.zeros(4)], np.diag(std**2)


def new_track(track_id: int, box: np.ndarray, histogram: np.ndarray, detection: int,
              config: BoxTrackerConfig, score: float = 0.0) -> BoxTrack:
    x, P = initial_state(box, config)
    return BoxTrack(track_id, x, P, hits=1, confirmed=config.min_hits <= 1, histogram=histogram,
                    detection=detection, score=score, observed=np.array(box, dtype=float))


def _costs(track_boxes: np.ndarray, boxes: np.ndarray, track_histograms: np.ndarray | None,
           detection_histograms: np.ndarray | None, config: BoxTrackerConfig):
    """(IOU, colour cost, Eq. 5's D), each (p, q), of p track boxes against q detection boxes [x, y, w, h] px."""
    ious = iou_matrix(track_boxes, boxes)
    colour = (np.zeros_like(ious) if track_histograms is None or detection_histograms is None
              else colour_cost_matrix(track_histograms, detection_histograms))
    return ious, colour, combined_cost(ious, colour, config)


def _assign(feasible: np.ndarray, D: np.ndarray) -> list[tuple[int, int]]:
    """The Hungarian algorithm's (row, column) pairs on the costs D, the infeasible ones left out."""
    rows, cols = linear_sum_assignment(np.where(feasible, D, _INFEASIBLE))
    return [(int(r), int(c)) for r, c in zip(rows, cols) if feasible[r, c]]


def associate(tracks: Sequence[BoxTrack], boxes: np.ndarray, track_histograms: np.ndarray,
              detection_histograms: np.ndarray, config: BoxTrackerConfig) -> list[tuple[int, int]]:
    """(track index, detection index) pairs: Eq. 6's matrix D of Eq. 5 costs between the tracks (boxes
    already predicted to this frame) and the detections, gated (module docstring), solved by the
    Hungarian algorithm. Histograms: (p, 75) and (q, 75), or None to use the boxes alone (a2's term 0)."""
    if not len(tracks) or not len(boxes):
        return []
    _, colour, D = _costs(np.array([t.box for t in tracks]), boxes, track_histograms, detection_histograms, config)
    chi2 = np.array([innovation_chi2(t, boxes, config) for t in tracks])
    return _assign((chi2 <= config.gate_chi2) & (colour <= config.max_colour_cost) & (D <= config.max_cost), D)


def recover(tracks: Sequence[BoxTrack], boxes: np.ndarray, track_histograms: np.ndarray | None,
            detection_histograms: np.ndarray | None, config: BoxTrackerConfig) -> list[tuple[int, int]]:
    """(track index, detection index) pairs of OC-SORT's observation-centric recovery (module docstring) among
    the tracks and detections the first association left unmatched: `associate` on the tracks' last observed
    boxes, gated by IOU >= recovery_min_iou in place of the innovation. A track without one takes none (an empty
    box stands in for it: IOU 0 with every box)."""
    if not len(tracks) or not len(boxes):
        return []
    observed = np.array([t.observed if t.observed is not None else np.zeros(4) for t in tracks])
    ious, colour, D = _costs(observed, boxes, track_histograms, detection_histograms, config)
    return _assign((ious >= config.recovery_min_iou) & (colour <= config.max_colour_cost) & (D <= config.max_cost), D)


def _cue(config: BoxTrackerConfig, image: np.ndarray | None) -> np.ndarray | None:
    if config.cue_px:
        return np.asarray(config.cue_px, dtype=float)
    if image is not None:
        return np.array([image.shape[1] / 2, image.shape[0] / 2])  # pixel-index space, as BoxTrack.centre
    return None


def _update_lock(lock: TargetLock, tracks: tuple[BoxTrack, ...], image: np.ndarray | None,
                 config: BoxTrackerConfig, use_colour: bool) -> TargetLock:
    """The lock after this frame's tracks: kept while its track lives, else (re-)acquired (module docstring)."""
    locked = next((t for t in tracks if t.id == lock.track_id), None)
    if locked is None and lock.track_id is not None:  # lost: remember where and what it was
        lock = TargetLock(None, lock.box, lock.histogram)
    if locked is None:
        tracks = [t for t in tracks if t.score >= config.lock_min_score]
        if lock.box is None:  # never locked: the track nearest the cue, once it is confirmed
            candidates, cue, radius = list(tracks), _cue(config, image), config.cue_radius_px
        else:  # re-acquire: the confirmed track nearest the last box, of the target's colour
            candidates, cue, radius = [t for t in tracks if t.confirmed], centre_form(lock.box)[:2], \
                config.reacquire_radius_px
            if use_colour:
                candidates = [t for t in candidates
                              if colour_cost_matrix(lock.histogram, t.histogram)[0, 0] <= config.max_colour_cost]
        if cue is not None:
            distances = [float(np.linalg.norm(t.centre - cue)) for t in candidates]
            candidates = [t for d, t in sorted(zip(distances, candidates), key=lambda p: p[0]) if d <= radius]
        if not candidates or not candidates[0].confirmed:
            return lock
        locked = candidates[0]
    box = locked.observed if locked.observed is not None else locked.box  # the last measured one
    return TargetLock(locked.id, box, locked.histogram.copy())


def partial_views(tracks: Sequence[BoxTrack], boxes: np.ndarray, config: BoxTrackerConfig) -> dict[int, int]:
    """{detection index: track index}: detections (q, 4) lying at least PARTIAL_INSIDE within a confirmed
    track's predicted box, narrower or shorter than `min_size_ratio` of it and at least PARTIAL_WHOLE_EXTENT of
    it the other way (module docstring), unless
    another track's gate (`innovation_chi2`) takes it: then it is that track's whole view, a smaller object
    seen over the larger one."""
    confirmed = [k for k, t in enumerate(tracks) if t.confirmed]
    if not confirmed or not len(boxes) or config.min_size_ratio <= 0:
        return {}
    predicted = np.array([tracks[k].box for k in confirmed])
    inter, _, area = intersection_matrix(predicted, boxes)
    inside = np.divide(inter, area, out=np.zeros_like(inter), where=area > 0) >= PARTIAL_INSIDE
    w_ratio, h_ratio = boxes[None, :, 2] / predicted[:, None, 2], boxes[None, :, 3] / predicted[:, None, 3]
    smaller = (((w_ratio < config.min_size_ratio) & (h_ratio >= PARTIAL_WHOLE_EXTENT))
               | ((h_ratio < config.min_size_ratio) & (w_ratio >= PARTIAL_WHOLE_EXTENT)))
    candidates = list(zip(*np.nonzero(inside & smaller)))
    if not candidates:  # the usual frame: no gate to evaluate (associate evaluates it for the whole views)
        return {}
    gated = np.array([innovation_chi2(t, boxes, config) <= config.gate_chi2 for t in tracks])  # (tracks, q)
    out = {}
    for i, j in candidates:
        if not np.delete(gated[:, j], confirmed[i]).any():
            out.setdefault(int(j), confirmed[i])
    return out


def step_tracker(state: TrackerState, detections: Sequence[Detection], image: np.ndarray | None, time: float,
                 config: BoxTrackerConfig) -> TrackerState:
    """One frame at `time` [s]: predict every track to it, associate (Eq. 3-6), recover, update, start, confirm
    and end tracks, and keep the target's lock. image: the frame (rows, cols, 3 or 4) uint8 the boxes were
    detected in, for the histograms; None to track on boxes alone. Pure: `state` is not changed."""
    dt = 0.0 if state.time is None else max(0.0, time - state.time)
    use_colour = image is not None and config.colour_weight > 0
    used = [i for i, d in enumerate(detections)
            if d.score >= config.min_score and np.all(np.isfinite(d.box)) and d.box[2] > 0 and d.box[3] > 0]
    boxes = np.array([detections[i].box for i in used], dtype=float).reshape(-1, 4)
    histograms = np.array([colour_histogram(image, b) for b in boxes]) if use_colour else None

    predicted = [predict_track(t, dt, config) for t in state.tracks]
    partial = partial_views(predicted, boxes, config)
    whole = [j for j in range(len(boxes)) if j not in partial]
    track_histograms = np.array([t.histogram for t in predicted]) if use_colour and predicted else None
    pairs = associate(predicted, boxes[whole], track_histograms, histograms[whole] if use_colour else None, config)

    matched = {k: whole[j] for k, j in pairs}
    lost = [k for k in range(len(predicted)) if k not in matched]
    left = [j for j in whole if j not in matched.values()]
    recovered = {lost[k]: left[j] for k, j in recover(
        [predicted[k] for k in lost], boxes[left], track_histograms[lost] if track_histograms is not None else None,
        histograms[left] if use_colour else None, config)}
    matched.update(recovered)
    _, _, H, R = constant_velocity_model(_filter_params(config, dt), 4)
    tracks = []
    for k, track in enumerate(predicted):
        if k in matched:
            j = matched[k]
            x, P = (initial_state(boxes[j], config) if k in recovered
                    else kalman_update(track.x, track.P, centre_form(boxes[j]), H, R))
            histogram = track.histogram
            if use_colour:
                a = config.appearance_update
                histogram = histograms[j] if not track.histogram.any() else (1 - a) * track.histogram + a * histograms[j]
            hits = track.hits + 1
            tracks.append(replace(track, x=x, P=P, hits=hits, misses=0, confirmed=track.confirmed or
                                  hits >= config.min_hits, histogram=histogram, detection=used[j],
                                  score=max(track.score, detections[used[j]].score), observed=boxes[j].copy()))
        elif track.confirmed and track.misses < config.max_misses:
            tracks.append(replace(track, misses=track.misses + 1))
    next_id = state.next_id
    for j in sorted(set(whole) - set(matched.values())):
        histogram = histograms[j] if use_colour else np.zeros(HISTOGRAM_SIZE, np.float32)
        tracks.append(new_track(next_id, boxes[j], histogram, used[j], config, detections[used[j]].score))
        next_id += 1
    tracks = tuple(tracks)
    return TrackerState(time, tracks, next_id, _update_lock(state.lock, tracks, image, config, use_colour))


def target_box(state: TrackerState) -> tuple[np.ndarray, bool]:
    """(box [x, y, w, h] px, top-left, valid): the locked target's box (filtered, or predicted while it coasts), or
    NaN and False when no target is locked."""
    target = state.target
    if target is None:
        return np.full(4, np.nan), False
    return target.box, True


class BoxTracker:
    """`step_tracker` with its state held: `tracker.step(detections, image, time)` returns the new state."""

    def __init__(self, config: BoxTrackerConfig | None = None):
        self.config = config or BoxTrackerConfig()
        self.config.validate()
        self.state = TrackerState()

    def step(self, detections: Sequence[Detection], image: np.ndarray | None, time: float) -> TrackerState:
        self.state = step_tracker(self.state, detections, image, time, self.config)
        return self.state


# ----------------------------------------------------------------------------------------------
# Evaluation


@dataclass(frozen=True)
class IdentitySwitches:
    """Identity switches of the locked target over a run. id_changes: frames where the lock came back under
    another track id than the one it last had (lost and re-acquired, or jumped). object_changes: frames
    where the locked id, unchanged, was matched with another true object than the one it last matched.
    A frame counts once (an id change that also changes the object is an id change).
    frames_on_target, frames_off_target: frames whose locked track matched a detection of, or not of,
    `target_truth_id` (when given)."""

    id_changes: int = 0
    object_changes: int = 0
    frames_on_target: int = 0
    frames_off_target: int = 0

    @property
    def total(self) -> int:
        return self.id_changes + self.object_changes


def locked_truth_id(state: TrackerState, truth_ids: Sequence[int]) -> int | None:
    """The true object id of the detection the locked track was matched with in this frame (truth_ids:
    one per detection of the frame, as given to step_tracker), or None (no lock, or coasting)."""
    target = state.target
    if target is None or target.detection is None:
        return None
    return int(truth_ids[target.detection])


def count_identity_switches(locked_ids: Sequence[int | None], truth_ids: Sequence[int | None],
                            target_truth_id: int | None = None) -> IdentitySwitches:
    """Counts identity switches from, per frame, the locked track's id (None: no lock) and the true object
    id of the detection it matched (None: no lock or coasting; `locked_truth_id`). See IdentitySwitches."""
    require(len(locked_ids) == len(truth_ids), "locked_ids and truth_ids need one entry per frame each")
    id_changes = object_changes = on = off = 0
    last_id = last_truth = None
    for locked, truth in zip(locked_ids, truth_ids):
        if locked is None:
            continue
        if last_id is not None and locked != last_id:
            id_changes += 1
        elif truth is not None and last_truth is not None and truth != last_truth:
            object_changes += 1
        if locked != last_id:
            last_truth = None
        last_id = locked
        if truth is not None:
            last_truth = truth
            if target_truth_id is not None:
                on, off = (on + 1, off) if truth == target_truth_id else (on, off + 1)
    return IdentitySwitches(id_changes, object_changes, on, off)
