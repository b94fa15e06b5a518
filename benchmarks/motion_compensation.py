"""Seed 003's motion compensation (section 2.2.2) on 512 x 512 frames: cost per stage and accuracy, ORB
against SIFT (issue 12 part 5).

    .venv/bin/python benchmarks/motion_compensation.py [--pairs 12] [--repeats 3] [--max-yaw-deg 5] [--threads 1]
        [--json FILE]

Frames: the project's ground texture (models/ground_texture.py, one texel a pixel at 4 m) seen by the
rectified fisheye's pinhole K (215 px) from a random pose, then after a random UAV motion between two
frames at 10 Hz (up to 0.3 m across, 0.24 m down, 5 deg of yaw (--max-yaw-deg), 2 deg of tilt), 2 levels
of pixel noise.
The true inter-frame homography is that of the two views of the plane.

1. Per-step cost (ms, median over pairs and repeats) of what `MotionCompensator` runs each frame:
   features of the new frame (detect), ratio-test matching against the previous frame's (match), the
   ground's homography (H: RANSAC, the Lucas-Kanade refinement of its inliers, RANSAC again, the checks),
   and their sum (step); `ransac` is the homography without the refinement, for comparison.
2. Accuracy: the largest distance between the image corners mapped by the estimate and by the truth (px),
   median and worst over the pairs, with the refinement and (in brackets) without.
Never a timed assertion in a test.
"""

import argparse
import time

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from diagrams.outputs import output_file, write_json
from models.ground_texture import ground_texture_image
from systems.perception.motion_compensation import (
    MotionCompensationConfig,
    detect_features,
    ground_homography,
    make_detector,
    make_matcher,
    map_point,
    match_features,
)
from systems.sensors.fisheye import FisheyeConfig, rectified_K

K = rectified_K(FisheyeConfig())  # the fisheye's rectified view (100 deg across)
SIZE, FOCAL = FisheyeConfig().width, K[0, 0]
TEXELS = 2048
HEIGHT_M = 4.0
TEXEL_M = HEIGHT_M / FOCAL
CORNERS = np.array([[0, 0], [SIZE - 1, 0], [SIZE - 1, SIZE - 1], [0, SIZE - 1]], float)


def texture_to_image(yaw_deg: float, roll_deg: float, pitch_deg: float, p_WC: np.ndarray) -> np.ndarray:
    """Texel -> pixel homography of a downward camera at p_WC (m), turned and tilted (deg)."""
    R_WC = Rotation.from_euler("zyx", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix() @ np.diag([1, -1, -1])
    R_CW, p_CW = R_WC.T, -R_WC.T @ p_WC
    c = (TEXELS - 1) / 2
    S = np.array([[TEXEL_M, 0, -TEXEL_M * c], [0, TEXEL_M, -TEXEL_M * c], [0, 0, 1.0]])
    A = K @ np.c_[R_CW[:, 0], R_CW[:, 1], p_CW] @ S
    return A / A[2, 2]


def pairs(count: int, seed: int, max_yaw_deg: float = 5.0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(previous grey, current grey, true H) for `count` random UAV motions."""
    texture = ground_texture_image(3, TEXELS, 2, 8)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        p0 = np.r_[rng.uniform(-3, 3, 2), HEIGHT_M]
        yaw0 = rng.uniform(-180, 180)
        A0 = texture_to_image(yaw0, 0.0, 0.0, p0)
        A1 = texture_to_image(yaw0 + rng.uniform(-max_yaw_deg, max_yaw_deg), *rng.uniform(-2, 2, 2),
                              p0 + np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.24, 0.24)])
        frames = [cv2.warpPerspective(texture, A, (SIZE, SIZE), flags=cv2.INTER_LINEAR) for A in (A0, A1)]
        frames = [np.clip(f + rng.normal(0, 2.0, f.shape), 0, 255).astype(np.uint8) for f in frames]
        H = A1 @ np.linalg.inv(A0)
        out.append((frames[0], frames[1], H / H[2, 2]))
    return out


def corner_error(H: np.ndarray, H_true: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(map_point(H, CORNERS) - map_point(H_true, CORNERS), axis=1)))


def run(detector_name: str, cases, repeats: int) -> dict:
    config = MotionCompensationConfig(detector=detector_name)
    detector, matcher = make_detector(config), make_matcher(config)
    stages = {"detect": [], "match": [], "ransac": [], "homography": []}
    errors, raw_errors, inliers = [], [], []
    for previous, current, H_true in cases:
        before = detect_features(previous, detector)
        for _ in range(repeats):
            t0 = time.perf_counter()
            after = detect_features(current, detector)
            t1 = time.perf_counter()
            src, dst = match_features(before, after, matcher, config.ratio)
            t2 = time.perf_counter()
            raw = ground_homography(src, dst, current.shape, config)
            t3 = time.perf_counter()
            ground = ground_homography(src, dst, current.shape, config, previous, current)
            t4 = time.perf_counter()
            for name, dt in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t4 - t3), strict=True):
                stages[name].append(1000 * dt)
        errors.append(corner_error(ground.H, H_true) if ground.valid else np.inf)
        raw_errors.append(corner_error(raw.H, H_true) if raw.valid else np.inf)
        inliers.append(ground.inliers)
    ms = {name: float(np.median(values)) for name, values in stages.items()}
    ms["step"] = float(np.median(np.sum([stages[name] for name in ("detect", "match", "homography")], axis=0)))
    return {"ms": ms, "features": len(after.points), "inliers_median": float(np.median(inliers)),
            "corner_error_px": {"median": float(np.median(errors)), "max": float(np.max(errors))},
            "corner_error_unrefined_px": {"median": float(np.median(raw_errors)), "max": float(np.max(raw_errors))}}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-yaw-deg", type=float, default=5.0, help="the UAV's largest turn between frames")
    parser.add_argument("--threads", type=int, default=1, help="OpenCV's threads (cv2.setNumThreads)")
    parser.add_argument("--json", type=output_file)
    args = parser.parse_args(argv)
    for name in ("pairs", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if not 0.0 <= args.max_yaw_deg <= 180.0:  # NaN fails too
        parser.error(f"--max-yaw-deg must lie in [0, 180], got {args.max_yaw_deg:g}")
    cv2.setNumThreads(args.threads)
    cases = pairs(args.pairs, args.seed, args.max_yaw_deg)
    results = {name: run(name, cases, args.repeats) for name in ("orb", "sift")}
    print(f"{args.pairs} pairs of {SIZE} x {SIZE} frames, yaw up to {args.max_yaw_deg:g} deg a frame, {args.repeats} "
          f"repeats, {args.threads} OpenCV thread(s)")
    print(f"{'':5} {'detect':>7} {'match':>7} {'ransac':>7} {'H':>7} {'step':>7} ms | corner error px: "
          "median / max (unrefined)")
    for name, r in results.items():
        ms, e, u = r["ms"], r["corner_error_px"], r["corner_error_unrefined_px"]
        print(f"{name:5} {ms['detect']:7.1f} {ms['match']:7.1f} {ms['ransac']:7.1f} {ms['homography']:7.1f} "
              f"{ms['step']:7.1f}    | {e['median']:.3f} / {e['max']:.3f} ({u['median']:.3f} / {u['max']:.3f}), "
              f"{r['inliers_median']:.0f} inliers of {r['features']} features")
    if args.json:
        write_json(args.json, results)


if __name__ == "__main__":
    main()
