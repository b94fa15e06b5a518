"""Trains the learned UGV detector (systems/perception/ugv_detector.py, HogSvmDetector) and writes
models/ugv_detector.yml.

    .venv/bin/python models/train_ugv_detector.py [--frames 800] [--out models/ugv_detector.yml]

Data: rendered fisheye frames (diagrams/ugv_detection_scenes.py) over a ground texture (seed 1) that the
held-out frames (texture seed 0, benchmarks/ugv_detection.py) never show, scene seeds TRAIN_SEEDS for
the examples and VALIDATION_SEEDS for the thresholds; both disjoint from the held-out HELD_OUT_SEEDS.
Rendered frames are cached under results/ (git ignores it).

Steps (Dalal and Triggs's recipe, with one model per range of sizes):
1. Positives: each true UGV box's window (square, `context` times the box's larger side, centred on it),
   jittered by up to half a pyramid step in scale and half a stride in position, in 4 rotations x 2
   mirrorings (the fisheye's model is symmetric about its centre, so a turned frame is a frame);
   negatives: random windows over the pyramid's scales away from the UGV (IOU of the window's object box
   with the true box under 0.3) and windows on every distractor (in 4 rotations). Each example goes to
   the component of its size (SIZE_SPLITS_PX; within a pyramid step of a split, to both).
2. Per component, a linear SVM (L2-regularised squared hinge, the primal solved by SciPy's L-BFGS;
   OpenCV 5's opencv-python-headless has no cv2.ml), class-balanced.
3. Hard-negative mining: the scan on the training frames (round k on every k-th of them); its false
   windows (margin above -1, object box IOU with the truth under 0.3) join their component's negatives;
   retrain. Twice.
4. Per component, a box regression (ridge) from the positives' features to the true box relative to the
   window.
5. The thresholds: per component, the margins that maximise F1 on the validation frames together,
   scored as the benchmark scores (IOU >= 0.5 with the true UGV box; every other detection a false
   positive).
"""

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from diagrams.ugv_detection_scenes import (
    TRAIN_SEEDS,
    VALIDATION_SEEDS,
    UgvDataset,
    load_or_render_dataset,
    training_scene_config,
)
from systems.perception.ugv_detector import (
    DEFAULT_MODEL_PATH,
    HogLayout,
    HogSvmDetector,
    HogSvmModel,
    crop_patch,
    iou,
    iou_many,
    object_box,
    patch_features,
    regression_targets,
)

MIN_OBJECT_PX = 13.0  # the smallest UGV box side the pyramid reaches (its largest level)
MAX_OBJECT_PX = 300.0
LEVELS_PER_OCTAVE = 3
SIZE_SPLITS_PX = (32.0,)  # component boundaries in object size (the box's larger side): small, large
NEGATIVE_IOU = 0.3
MINING_MARGIN = -1.0


def pyramid_scales(layout: HogLayout, min_object_px: float = MIN_OBJECT_PX, max_object_px: float = MAX_OBJECT_PX,
                   per_octave: int = LEVELS_PER_OCTAVE) -> np.ndarray:
    """Level scales from the one where a `min_object_px` object fills the window down to `max_object_px`."""
    top, bottom = layout.object_px / min_object_px, layout.object_px / max_object_px
    count = math.ceil(per_octave * math.log2(top / bottom)) + 1
    return top * 2.0 ** (-np.arange(count) / per_octave)


def components_of(size_px: float, step: float, splits=SIZE_SPLITS_PX) -> list[int]:
    """The components an example of this object size trains: its range's, and the neighbour's within a
    pyramid step of the boundary (the scan may find it on either side)."""
    out = {int(np.searchsorted(splits, size_px))}
    for i, split in enumerate(splits):
        if split / step <= size_px < split:
            out.add(i + 1)
        if split <= size_px < split * step:
            out.add(i)
    return sorted(out)


def window_for(box: np.ndarray, layout: HogLayout) -> tuple[np.ndarray, float]:
    """The centre (px) and level scale of the window that frames `box` as the positives do."""
    centre = np.array([box[0] + box[2] / 2, box[1] + box[3] / 2])
    return centre, layout.object_px / max(box[2], box[3])


def augment(patch: np.ndarray, target: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The patch in 4 rotations x 2 mirrorings, with its regression target (dx, dy, log w, log h)
    turned alike: np.rot90 takes (dx, dy) to (dy, -dx) and swaps w and h; np.fliplr negates dx."""
    out = []
    for flip in (False, True):
        p = np.fliplr(patch) if flip else patch
        t = target * np.array([-1, 1, 1, 1]) if flip else target.copy()
        for _ in range(4):
            out.append((np.ascontiguousarray(p), t.copy()))
            p = np.rot90(p)
            t = np.array([t[1], -t[0], t[3], t[2]])
    return out


def positives(dataset: UgvDataset, layout: HogLayout, step: float, rng: np.random.Generator):
    """Features (N, d), regression targets (N, 4) and object sizes at their window's scale (N,) px of the
    jittered, turned windows on the UGV."""
    features, targets, sizes = [], [], []
    for i in range(len(dataset)):
        box = dataset.ugv_box(i)
        if box is None:
            continue
        image = dataset.images[i]
        centre, scale = window_for(box, layout)
        scale *= step ** rng.uniform(-0.5, 0.5)
        side = layout.window_px / scale  # the window's side in the image
        centre = centre + rng.uniform(-0.5, 0.5, 2) * layout.cell_px / scale
        window = np.array([centre[0] - side / 2, centre[1] - side / 2, side, side])
        target = regression_targets(window, box)[0]
        for patch, t in augment(crop_patch(image, centre, scale, layout), target):
            features.append(patch_features(patch, layout))
            targets.append(t)
            sizes.append(layout.object_px / scale)
    return np.asarray(features, np.float32), np.asarray(targets), np.asarray(sizes)


def negatives(dataset: UgvDataset, layout: HogLayout, scales: np.ndarray, per_frame: int, per_distractor: int,
              step: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Features (N, d) and object sizes at their scale (N,) px of random windows away from the UGV and of
    windows on the distractors."""
    features, sizes = [], []
    log_low, log_high = math.log(scales.min()), math.log(scales.max())
    for i in range(len(dataset)):
        image = dataset.images[i]
        truth = dataset.ugv_box(i)
        h, w = image.shape[:2]
        windows = [(rng.uniform([0, 0], [w, h]), math.exp(rng.uniform(log_low, log_high)), 1)
                   for _ in range(per_frame)]
        for box in dataset.distractor_boxes[i]:  # the look-alikes, in the positives' 4 rotations
            for _ in range(per_distractor):
                centre, scale = window_for(box, layout)
                windows.append((centre + rng.uniform(-0.15, 0.15, 2) * max(box[2:]),
                                scale * step ** rng.uniform(-1, 1), 4))
        for centre, scale, turns in windows:
            side = layout.window_px / scale
            window = np.array([centre[0] - side / 2, centre[1] - side / 2, side, side])
            if truth is not None and iou(object_box(window, layout)[0], truth) >= NEGATIVE_IOU:
                continue
            patch = crop_patch(image, centre, scale, layout)
            for k in range(turns):
                features.append(patch_features(np.ascontiguousarray(np.rot90(patch, k)), layout))
                sizes.append(layout.object_px / scale)
    return np.asarray(features, np.float32), np.asarray(sizes)


def train_svm(x_pos: np.ndarray, x_neg: np.ndarray, c: float, w0: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Linear SVM, primal: min 0.5 |w|^2 + C sum_i a_i max(0, 1 - y_i (w . x_i + b))^2, each class's
    weights a_i summing to half the samples (balanced); L-BFGS from w0. Returns (w, b)."""
    x = np.vstack([x_pos, x_neg]).astype(np.float64)
    y = np.concatenate([np.ones(len(x_pos)), -np.ones(len(x_neg))])
    a = np.where(y > 0, len(y) / (2 * len(x_pos)), len(y) / (2 * len(x_neg)))
    d = x.shape[1]

    def objective(theta):
        w, b = theta[:d], theta[d]
        slack = np.maximum(0.0, 1 - y * (x @ w + b))
        loss = 0.5 * w @ w + c * np.sum(a * slack**2)
        g = -2 * c * a * slack * y
        return loss, np.concatenate([w + x.T @ g, [g.sum()]])

    theta0 = np.zeros(d + 1) if w0 is None else w0
    result = minimize(objective, theta0, jac=True, method="L-BFGS-B", options={"maxiter": 2000})
    return result.x[:d], float(result.x[d])


def hard_negatives(detector: HogSvmDetector, dataset: UgvDataset, per_frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Features and components of the scan's false windows (margin over threshold above MINING_MARGIN,
    object box IOU with the truth under 0.3), the highest `per_frame` per frame."""
    layout = detector.model.layout
    features, components = [], []
    for i in range(len(dataset)):
        found = detector.windows(dataset.images[i], MINING_MARGIN)
        if len(found.margins) == 0:
            continue
        false = np.ones(len(found.margins), bool)
        truth = dataset.ugv_box(i)
        if truth is not None:
            false = iou_many(truth, object_box(found.boxes, layout)) < NEGATIVE_IOU
        order = np.flatnonzero(false)[np.argsort(-found.margins[false])][:per_frame]
        features.append(found.features[order])
        components.append(found.components[order])
    if not features:
        return np.zeros((0, layout.feature_size), np.float32), np.zeros(0, int)
    return np.vstack(features), np.concatenate(components)


def fit_regression(features: np.ndarray, targets: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge regression (d + 1, 4) from [features, 1] to the targets (the constant unpenalised)."""
    x = np.column_stack([features, np.ones(len(features))]).astype(np.float64)
    penalty = ridge * np.eye(x.shape[1])
    penalty[-1, -1] = 0.0
    return np.linalg.solve(x.T @ x + penalty, x.T @ targets)


def score_frames(detector: HogSvmDetector, dataset: UgvDataset, low: float) -> list[tuple]:
    """Per frame, the detections above margin `low` (over the model's thresholds) after NMS: their margins,
    their components, which one (if any) matches the truth (IOU >= 0.5, the best-scoring match), and
    whether the frame has a true box."""
    out = []
    for i in range(len(dataset)):
        boxes, margins, components = detector.detect_with_margins(dataset.images[i], low)
        truth = dataset.ugv_box(i)
        match = np.zeros(len(margins), bool)
        if truth is not None and len(boxes):
            hits = np.flatnonzero(iou_many(truth, boxes) >= 0.5)
            if hits.size:
                match[hits[np.argmax(margins[hits])]] = True
        out.append((margins, components, match, truth is not None))
    return out


def f1_at(frames, offsets: np.ndarray) -> tuple[float, float, float]:
    """(P, R, F1) of the scored frames when component c keeps margins >= offsets[c]."""
    tp = fp = 0
    for margins, components, match, _ in frames:
        kept = margins >= offsets[components] if len(margins) else np.zeros(0, bool)
        tp += int(np.count_nonzero(match & kept))
        fp += int(np.count_nonzero(~match & kept))
    targets = sum(has for _, _, _, has in frames)
    p, r = tp / max(tp + fp, 1), tp / max(targets, 1)
    return p, r, 2 * p * r / max(p + r, 1e-12)


def best_offsets(frames, components: int, low: float, sweeps: int = 3) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Per component, the margin offset (>= low) that maximises F1 over the scored frames together:
    coordinate ascent over each component's margin quantiles (60), the others held."""
    grids = []
    for c in range(components):
        values = np.concatenate([m[k == c] for m, k, _, _ in frames] + [[low]])
        grids.append(np.unique(np.quantile(values, np.linspace(0, 1, 60))))
    offsets = np.full(components, low)
    best = f1_at(frames, offsets)
    for _ in range(sweeps):
        for c in range(components):
            for value in grids[c]:
                trial = offsets.copy()
                trial[c] = value
                scored = f1_at(frames, trial)
                if scored[2] > best[2] + 1e-12:
                    offsets, best = trial, scored
    return offsets, best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=800, help="training frames (TRAIN_SEEDS from 0)")
    parser.add_argument("--validation-frames", type=int, default=150)
    parser.add_argument("--mining-rounds", type=int, default=2)
    parser.add_argument("--c", type=float, default=0.02, help="the SVMs' C")
    parser.add_argument("--out", type=Path, default=DEFAULT_MODEL_PATH)
    parser.add_argument("--cache-dir", type=Path, default=None, help="rendered frames' cache (default results/)")
    parser.add_argument("--seed", type=int, default=0, help="the sampling of windows")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    layout = HogLayout()
    scales = pyramid_scales(layout)
    step = 2.0 ** (1 / LEVELS_PER_OCTAVE)
    level_component = np.searchsorted(SIZE_SPLITS_PX, layout.object_px / scales)
    k = len(SIZE_SPLITS_PX) + 1
    config = training_scene_config()

    def log(message):
        print(f"[{time.perf_counter() - start:6.1f} s] {message}", flush=True)

    train = load_or_render_dataset(TRAIN_SEEDS[:args.frames], config, args.cache_dir)
    validation = load_or_render_dataset(VALIDATION_SEEDS[:args.validation_frames], config, args.cache_dir)
    log(f"frames: {len(train)} training, {len(validation)} validation")
    x_pos, t_pos, pos_sizes = positives(train, layout, step, rng)
    x_neg, neg_sizes = negatives(train, layout, scales, per_frame=40, per_distractor=4, step=step, rng=rng)
    pos_of = [np.array([c in components_of(s, step) for s in pos_sizes]) for c in range(k)]
    negs = [x_neg[np.array([c in components_of(s, step) for s in neg_sizes])] for c in range(k)]
    log(f"features ({layout.feature_size} each): positives {[int(m.sum()) for m in pos_of]}, "
        f"negatives {[len(n) for n in negs]} per component (sizes split at {SIZE_SPLITS_PX} px)")
    svms = [train_svm(x_pos[pos_of[c]], negs[c], args.c) for c in range(k)]
    regression = np.stack([fit_regression(x_pos[pos_of[c]], t_pos[pos_of[c]], ridge=1.0) for c in range(k)])

    def model(thresholds=None):
        return HogSvmModel(layout, np.stack([w for w, _ in svms]).astype(np.float32),
                           np.array([b for _, b in svms]), np.zeros(k) if thresholds is None else thresholds,
                           scales, level_component, regression)

    for round_index in range(args.mining_rounds):
        frames = np.arange(round_index, len(train), args.mining_rounds)
        subset = UgvDataset(train.images[frames], train.ugv_boxes[frames], [train.distractor_boxes[i] for i in frames],
                            train.seeds[frames], train.blur_px[frames], train.small[frames])
        mined, mined_components = hard_negatives(HogSvmDetector(model=model()), subset, per_frame=30)
        for c in range(k):
            negs[c] = np.vstack([negs[c], mined[mined_components == c]])
            svms[c] = train_svm(x_pos[pos_of[c]], negs[c], args.c, np.concatenate([svms[c][0], [svms[c][1]]]))
        log(f"mining round {round_index + 1}: {len(mined)} hard negatives, now {[len(n) for n in negs]}")
    low = -0.5
    frames = score_frames(HogSvmDetector(model=model()), validation, low)
    offsets, (p, r, f1) = best_offsets(frames, k, low)
    log(f"validation with thresholds {np.round(offsets, 3)}: precision {p:.4f}, recall {r:.4f}, F1 {f1:.4f}")
    final = model(offsets)
    final.trained = (f"train_ugv_detector.py --frames {args.frames} --c {args.c} --mining-rounds {args.mining_rounds}: "
                     f"{len(x_pos)} positives, {sum(len(n) for n in negs)} negatives, {k} components; "
                     f"validation P {p:.4f} R {r:.4f} F1 {f1:.4f}")
    final.validate("trained model")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    final.save(args.out)
    log(f"wrote {args.out} ({args.out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
