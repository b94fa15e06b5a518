"""Seed 003's UGV detection (Sec. 2.2.1, Table 3): the learned (a small CNN through cv2.dnn,
systems/perception/ugv_cnn_detector.py), the learned with its boxes checked for the UGV's colour and re-centred
on it (systems/perception/ugv_box_refiner.py; the loop's default, hybrid.refinement.method colour) and the
classical (HSV body colour + pad, systems/perception/ugv_detector.py) detectors on the same held-out rendered
fisheye frames (diagrams/ugv_detection_scenes.py: heights 2-10 m, distractor vehicles, one of the UGV's
own colour in 30 % of frames, motion blur in 40 %, small far off-axis targets in 20 %, no UGV in 10 %).

    .venv/bin/python benchmarks/ugv_detection.py [--frames 400] [--json FILE]
        [--split validation --first 300] [--min-body-px N] [--model FILE]

`--split validation` scores validation frames instead, on the training ground as the trainer renders them (for
choosing settings without touching the held-out frames or their ground; the trainer picks its threshold on the
validation split's first 300, so start past them with `--first 300`); `--min-body-px` sets the colour check of the
refined detector's boxes (0 keeps every box).

Scoring, per frame: a detection with IOU >= 0.5 against the true UGV box is a true positive (the
highest-scoring one, if several); every other detection is a false positive (on a distractor or not);
a frame whose UGV is seen and not matched is a false negative. Precision, recall and F1 over all frames,
against Table 3's totals (P 99.62 %, R 99.59 %, F1 99.60 %), and by kind of frame; the true positives'
centres' distance from the pad's centre in px (the hybrid estimate takes a box's centre for it); the scores of the
true and of the false positives (what the tracker's `lock_min_score` separates). Per-frame cost:
median and mean wall time of `detect` on one 512 x 512 RGB frame, OpenCV on one thread, against Table 7's
detection (51.24 +- 55.69 ms, YOLOv3 on a Jetson TX2's GPU). The frames are rendered once and cached under
results/; the held-out seeds and ground texture are never used in training or validation (models/train_ugv_cnn.py).
"""

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from diagrams.outputs import output_file, write_json
from diagrams.ugv_detection_scenes import (
    HELD_OUT_SEEDS,
    VALIDATION_SEEDS,
    UgvDataset,
    UgvSceneConfig,
    distractor_pool,
    load_or_render_dataset,
    pad_centre_pixel,
    sample_scene,
    training_scene_config,
)
from systems.config import ConfigError
from systems.perception.box_tracker import box_centre_pixel, iou_matrix
from systems.perception.ugv_box_refiner import BoxRefinementConfig, ColourRefinedDetector
from systems.perception.ugv_cnn_detector import DEFAULT_MODEL_PATH, CnnDetector
from systems.perception.ugv_detector import ColourPadDetector, match_truth

TABLE3 = {"precision": 0.9962, "recall": 0.9959, "f1": 0.9960}  # seed 003 Table 3, "Total"
TABLE7_DETECTION_MS = (51.24, 55.69)  # seed 003 Table 7: mean, standard deviation
SPLITS = {"held-out": HELD_OUT_SEEDS, "validation": VALIDATION_SEEDS}


def score_frame(detections, truth: np.ndarray | None, distractors: np.ndarray, pad_px: np.ndarray | None) -> dict:
    """TP/FP/FN counts of one frame's detections (module docstring), how many false positives lie on a
    distractor (IOU >= 0.3 with one's box), the true positive's centre distance from the pad's centre
    `pad_px` [px] (the point the hybrid estimate takes it for), and the true and false positives' scores."""
    boxes, scores, matched = match_truth(detections, truth)
    on_distractor = 0
    for box in boxes[~matched]:
        if len(distractors) and np.any(iou_matrix(box, distractors) >= 0.3):
            on_distractor += 1
    centre_px = [float(np.hypot(*(box_centre_pixel(box) - pad_px))) for box in boxes[matched] if pad_px is not None]
    return {"tp": int(matched.sum()), "fp": int((~matched).sum()), "fn": int(truth is not None and not matched.any()),
            "fp_on_distractor": on_distractor, "centre_px": centre_px,
            "tp_scores": scores[matched].tolist(), "fp_scores": scores[~matched].tolist()}


def summary(counts: list[dict]) -> dict:
    """The counts' totals and scores; a score whose denominator is zero (no detection, no UGV in view) is None,
    as in diagrams/hybrid_metrics.detection_scores."""
    tp, fp, fn = (sum(c[k] for c in counts) for k in ("tp", "fp", "fn"))
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else None
    centre_px = [d for c in counts for d in c["centre_px"]]
    tp_scores, fp_scores = ([s for c in counts for s in c[k]] for k in ("tp_scores", "fp_scores"))
    return {"frames": len(counts), "targets": tp + fn, "tp": tp, "fp": fp, "fn": fn,
            "fp_on_distractor": sum(c["fp_on_distractor"] for c in counts),
            "precision": precision, "recall": recall, "f1": f1,
            "centre_error_px": {"median": float(np.median(centre_px)) if centre_px else None,
                                "p95": float(np.percentile(centre_px, 95)) if centre_px else None},
            "scores": {"tp_median": float(np.median(tp_scores)) if tp_scores else None,
                       "tp_p10": float(np.percentile(tp_scores, 10)) if tp_scores else None,
                       "fp_median": float(np.median(fp_scores)) if fp_scores else None,
                       "fp_max": float(np.max(fp_scores)) if fp_scores else None}}


def percent(score: float | None, sign: str = "%") -> str:
    return "n/a" if score is None else f"{100 * score:.2f}{sign}"


def number(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def frame_kinds(dataset: UgvDataset, config: UgvSceneConfig) -> dict[str, np.ndarray]:
    """Boolean masks over the frames: small, blurred, with a same-colour distractor, without the UGV,
    and the UGV's box's larger side under 20 px."""
    pool = distractor_pool(config)
    same = np.array([any(pool[index].colour == "ugv" for index, _ in sample_scene(int(seed), config, pool).distractors)
                     for seed in dataset.seeds])
    sizes = np.where(np.isnan(dataset.ugv_boxes[:, 2]), np.inf, np.max(np.nan_to_num(dataset.ugv_boxes[:, 2:]), axis=1))
    return {"small (7-10 m, 55-68 deg off-axis)": dataset.small, "motion blur": dataset.blur_px >= 1.0,
            "same-colour distractor": same, "no UGV in view": np.isnan(dataset.ugv_boxes[:, 0]),
            "UGV box under 20 px": sizes < 20}


def run(detector, dataset: UgvDataset, pads: list) -> tuple[list[dict], np.ndarray]:
    counts, times = [], []
    detector.detect(dataset.images[0])  # warm-up (caches)
    for i in range(len(dataset)):
        t0 = time.perf_counter()
        detections = detector.detect(dataset.images[i])
        times.append(1e3 * (time.perf_counter() - t0))
        counts.append(score_frame(detections, dataset.ugv_box(i), dataset.distractor_boxes[i], pads[i]))
    return counts, np.asarray(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=400, help="frames of the split")
    parser.add_argument("--split", choices=SPLITS, default="held-out")
    parser.add_argument("--first", type=int, default=0, help="the split's first frame scored (its index)")
    parser.add_argument("--min-body-px", type=int, default=BoxRefinementConfig().min_body_px,
                        help="the refined detector's colour check: body-coloured pixels a box needs (0: none)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_PATH)
    parser.add_argument("--cache-dir", type=Path, default=None)
    parser.add_argument("--json", type=output_file, help="write the figures here")
    args = parser.parse_args(argv)
    seeds = SPLITS[args.split]
    if not 0 <= args.first < len(seeds):
        parser.error(f"--first must lie in 0..{len(seeds) - 1} (the {args.split} seeds), got {args.first}")
    if not 1 <= args.frames <= len(seeds) - args.first:
        parser.error(f"--frames must lie in 1..{len(seeds) - args.first} (the {args.split} seeds from --first "
                     f"{args.first}), got {args.frames}")
    if args.min_body_px < 0:
        parser.error(f"--min-body-px must be 0 or more, got {args.min_body_px}")
    cv2.setNumThreads(1)  # one core, as Table 7's comparison here counts it
    try:
        learned = CnnDetector(args.model)
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    config = UgvSceneConfig() if args.split == "held-out" else training_scene_config()  # the trainer's validation
    t0 = time.perf_counter()
    dataset = load_or_render_dataset(seeds[args.first:args.first + args.frames], config, args.cache_dir)
    first = seeds[args.first]
    print(f"{len(dataset)} {args.split} frames (seeds {first}-{first + len(dataset) - 1}, "
          f"ground texture {config.ground.texture_seed}), loaded or rendered in {time.perf_counter() - t0:.1f} s; "
          f"{int(np.sum(~np.isnan(dataset.ugv_boxes[:, 0])))} with the UGV in view")
    print(f"learned model: {args.model}")
    kinds = frame_kinds(dataset, config)
    pool = distractor_pool(config)
    pads = [pad_centre_pixel(sample_scene(int(seed), config, pool), config) for seed in dataset.seeds]
    results = {}
    refined = ColourRefinedDetector(learned, ColourPadDetector(), BoxRefinementConfig(min_body_px=args.min_body_px))
    detectors = {"learned_cnn": learned, "learned_refined": refined,
                 "classical_colour_pad": ColourPadDetector()}
    for name, detector in detectors.items():
        counts, times = run(detector, dataset, pads)
        total = summary(counts)
        total["per_frame_ms"] = {"median": float(np.median(times)), "mean": float(np.mean(times)),
                                 "std": float(np.std(times)), "p95": float(np.percentile(times, 95))}
        total["by_kind"] = {kind: summary([c for c, m in zip(counts, mask) if m]) for kind, mask in kinds.items()}
        results[name] = total
    print("\n                       frames targets   TP   FP (on distr.)  FN   precision  recall     F1     ms/frame "
          "(median, mean +- std)   centre from the pad's, px (median, p95)")
    print(f"  {'Table 3 (YOLOv3)':20s} {'':6s} {5898:7d} {5874:4d} {2:4d} {'':10s} {24:4d}   "
          f"{100 * TABLE3['precision']:7.2f}%  {100 * TABLE3['recall']:6.2f}%  {100 * TABLE3['f1']:6.2f}%   "
          f"{'':8s}{TABLE7_DETECTION_MS[0]:.2f} +- {TABLE7_DETECTION_MS[1]:.2f} (Table 7, TX2 GPU)")
    for name, r in results.items():
        ms = r["per_frame_ms"]
        print(f"  {name:20s} {r['frames']:6d} {r['targets']:7d} {r['tp']:4d} {r['fp']:4d} ({r['fp_on_distractor']:4d})    "
              f"{r['fn']:4d}   {percent(r['precision']):>8s}  {percent(r['recall']):>7s}  {percent(r['f1']):>7s}   "
              f"{ms['median']:8.1f}, {ms['mean']:.1f} +- {ms['std']:.1f}       "
              f"{number(r['centre_error_px']['median'])}, {number(r['centre_error_px']['p95'])}")
    print("\nby kind of frame (precision / recall / F1 %, targets, FP):")
    for kind, mask in kinds.items():
        line = f"  {kind:36s} {int(mask.sum()):4d} frames"
        for name, r in results.items():
            k = r["by_kind"][kind]
            line += (f" | {name}: {percent(k['precision'], ''):>6s} / {percent(k['recall'], ''):>6s} / "
                     f"{percent(k['f1'], ''):>6s}, {k['targets']:3d}, {k['fp']:2d}")
        print(line)
    print("\nscores (true positives: median, 10th percentile | false positives: median, max):")
    for name, r in results.items():
        sc = r["scores"]
        print(f"  {name:20s} {number(sc['tp_median'])}, {number(sc['tp_p10'])} | "
              f"{number(sc['fp_median'])}, {number(sc['fp_max'])}")
    if args.json:
        write_json(args.json, {"frames": len(dataset), "split": args.split, "first_seed": first,
                               "ground_texture_seed": config.ground.texture_seed,
                               "min_body_px": args.min_body_px, "table3": TABLE3,
                               "table7_detection_ms": TABLE7_DETECTION_MS, "detectors": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
