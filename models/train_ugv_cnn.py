"""Trains the learned UGV detector's network (systems/perception/ugv_cnn_detector.py, CnnDetector) and writes
models/ugv_detector.onnx, run at simulation time by OpenCV's dnn module.

    pip install -e '.[train]'        # JAX (CPU), optax, onnx: the trainer only
    .venv/bin/python models/train_ugv_cnn.py [--frames 4800] [--steps 16000] [--validation-frames 300]

The network is a small fully convolutional centre-point detector (Zhou, Wang and Kraehenbuehl 2019,
"Objects as Points"), the one-stage, single-class counterpart of seed 003's YOLOv3-tiny: a stride-4 stem,
three stride-2 stages, a top-down path adding each stage back at stride 4 (a feature pyramid, Lin et al.
2017), and per stride-4 cell five outputs: the UGV-centre heat (sigmoid), the centre's offset in the cell
(2) and log of the box's width and height in cells (2). About 0.3 GMAC per 512 x 512 frame, 0.19 M weights.

Data: rendered fisheye frames (diagrams/ugv_detection_scenes.py) over the training ground texture (seed 1),
scene seeds TRAIN_SEEDS[:frames]; the decision threshold (the best F1) is chosen on VALIDATION_SEEDS
(`--validation-frames`) through OpenCV's dnn module, as the detector runs; the held-out frames (benchmarks/ugv_detection.py: other seeds,
another ground texture) are never seen. Frames are rendered once and cached under results/ (4800 frames:
about 10 min of rendering, 3.6 GB in memory). The shipped model (2026-12-07, on the frames smeared by the
camera's exposure kernel): the defaults, 41 min of training on two cores here, its first half beside other work.

Training: 320 x 320 crops (2 in 3 holding the UGV), turned by multiples of 90 deg and mirrored (the fisheye
is symmetric about its centre: a turned frame is a frame), brightness and contrast jittered; the
penalty-reduced focal loss on the heat (Zhou et al. Eq. 1, alpha 2, beta 4, a Gaussian per box with
sigma a sixth of its size in cells) and L1 on offset and log size at the centre cell (Eq. 2-3); Adam with
a cosine learning rate. Input in [0, 1] RGB; the 0.5 centring is folded into the first layer's bias on export,
and the threshold into the heat's bias, so the exported heat is 0.5 at the decision threshold.
"""

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from diagrams.ugv_detection_scenes import (
    TRAIN_SEEDS,
    VALIDATION_SEEDS,
    UgvDataset,
    load_or_render_dataset,
    training_scene_config,
)
from systems.perception.ugv_cnn_detector import DEFAULT_MODEL_PATH, CnnDetector
from systems.perception.ugv_detector import match_truth

STRIDE = 4
CROP_PX = 320
# (output channels, kernel, stride, a pyramid level's last layer) per convolution of the backbone
BACKBONE = ((16, 4, 4, False), (24, 3, 1, True),
            (32, 3, 2, False), (32, 3, 1, False), (32, 3, 1, True),
            (48, 3, 2, False), (48, 3, 1, False), (48, 3, 1, True),
            (64, 3, 2, False), (64, 3, 1, False), (64, 3, 1, True))
TOP_DOWN = 16  # channels of the top-down path
OUTPUTS = 5  # heat, offset x, offset y, log w, log h
HEAT_PRIOR = 0.01  # the heat's initial probability (Zhou et al.: its bias at -log((1 - p) / p))


def init_params(rng: np.random.Generator) -> dict:
    """He-initialised weights, HWIO, and zero biases (the heat's at HEAT_PRIOR)."""
    def conv(cin, cout, k):
        return {"w": (rng.standard_normal((k, k, cin, cout)) * math.sqrt(2.0 / (cin * k * k))).astype(np.float32),
                "b": np.zeros(cout, np.float32)}
    params, cin = {"backbone": [], "lateral": []}, 3
    for cout, k, _, level in BACKBONE:
        params["backbone"].append(conv(cin, cout, k))
        cin = cout
        if level:
            params["lateral"].append(conv(cout, TOP_DOWN, 1))
    params["fuse"] = conv(TOP_DOWN, TOP_DOWN, 3)
    params["head"] = conv(TOP_DOWN, OUTPUTS, 1)
    params["head"]["w"] *= 0.1
    params["head"]["b"][0] = -math.log((1 - HEAT_PRIOR) / HEAT_PRIOR)
    return params


def forward(params, x):
    """The network on a batch x (N, H, W, 3) in [0, 1]: (N, H / 4, W / 4, 5), the heat as a logit."""
    import jax
    import jax.numpy as jnp

    def conv(p, x, k, s):
        pad = (k // 2, k // 2) if k == 3 else (0, 0)
        y = jax.lax.conv_general_dilated(x, p["w"], (s, s), (pad, pad), dimension_numbers=("NHWC", "HWIO", "NHWC"))
        return y + p["b"]

    x = x - 0.5
    levels = []
    for p, (_, k, s, level) in zip(params["backbone"], BACKBONE):
        x = jax.nn.relu(conv(p, x, k, s))
        if level:
            levels.append(x)
    top = None
    for p, f in zip(reversed(params["lateral"]), reversed(levels)):
        lateral = conv(p, f, 1, 1)
        top = lateral if top is None else lateral + jnp.repeat(jnp.repeat(top, 2, axis=1), 2, axis=2)
    return conv(params["head"], jax.nn.relu(conv(params["fuse"], top, 3, 1)), 1, 1)


# ---------------------------------------------------------------------------------------------------------
# Targets and samples


def targets_for(box: np.ndarray | None, size: int) -> np.ndarray:
    """The training targets (size / 4, size / 4, 6) of one crop: heat (a Gaussian peak of 1 at the box's centre
    cell), offset x/y of the centre in its cell, log w/h in cells, and the centre-cell mask."""
    cells = size // STRIDE
    out = np.zeros((cells, cells, 6), np.float32)
    if box is None:
        return out
    cx, cy = (box[0] + box[2] / 2) / STRIDE, (box[1] + box[3] / 2) / STRIDE
    i, j = int(cy), int(cx)
    if not (0 <= i < cells and 0 <= j < cells):
        return out
    sigma_x, sigma_y = max(box[2] / STRIDE / 6, 0.5), max(box[3] / STRIDE / 6, 0.5)
    ys, xs = np.arange(cells)[:, None], np.arange(cells)[None, :]
    out[..., 0] = np.exp(-0.5 * ((xs - j) ** 2 / sigma_x**2 + (ys - i) ** 2 / sigma_y**2))
    out[i, j, 0] = 1.0
    out[i, j, 1:5] = [cx - j, cy - i, math.log(box[2] / STRIDE), math.log(box[3] / STRIDE)]
    out[i, j, 5] = 1.0
    return out


def turn_box(box: np.ndarray, size: int, turns: int, flip: bool) -> np.ndarray:
    """A box [x, y, w, h] in a size x size crop after np.fliplr (if flip), then np.rot90 `turns` times:
    np.rot90 takes (x, y, w, h) to (y, size - x - w, h, w)."""
    x, y, w, h = box
    if flip:
        x = size - x - w
    for _ in range(turns):
        x, y, w, h = y, size - x - w, h, w
    return np.array([x, y, w, h])


def sample(dataset: UgvDataset, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One augmented crop (CROP_PX, CROP_PX, 3) float32 in [0, 1] and its targets."""
    i = int(rng.integers(len(dataset)))
    image, box = dataset.images[i], dataset.ugv_box(i)
    h, w = image.shape[:2]
    if box is not None and rng.random() < 2 / 3:  # a crop holding the UGV's centre, away from the crop's rim
        cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
        x0 = int(np.clip(cx - rng.uniform(0.2, 0.8) * CROP_PX, 0, w - CROP_PX))
        y0 = int(np.clip(cy - rng.uniform(0.2, 0.8) * CROP_PX, 0, h - CROP_PX))
    else:
        x0, y0 = int(rng.integers(w - CROP_PX + 1)), int(rng.integers(h - CROP_PX + 1))
    crop = image[y0:y0 + CROP_PX, x0:x0 + CROP_PX]
    local = None
    if box is not None:
        local = box - np.array([x0, y0, 0, 0])
        cx, cy = local[0] + local[2] / 2, local[1] + local[3] / 2
        if not (0 <= cx < CROP_PX and 0 <= cy < CROP_PX):
            local = None
    flip, turns = bool(rng.random() < 0.5), int(rng.integers(4))
    if flip:
        crop = np.fliplr(crop)
    crop = np.rot90(crop, turns)
    if local is not None:
        local = turn_box(local, CROP_PX, turns, flip)
    x = crop.astype(np.float32) / 255.0
    x = np.clip((x - 0.5) * rng.uniform(0.8, 1.2) + 0.5 + rng.uniform(-0.08, 0.08), 0.0, 1.0)
    return x, targets_for(local, CROP_PX)


def batch(dataset: UgvDataset, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    pairs = [sample(dataset, rng) for _ in range(size)]
    return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])


def loss_fn(params, x, t):
    """Zhou et al.'s focal loss on the heat (Eq. 1) plus L1 on offset and log size at the centre (Eq. 2-3),
    over the batch's object count."""
    import jax
    import jax.numpy as jnp

    y = forward(params, x)
    heat, gauss, mask = y[..., 0], t[..., 0], t[..., 5]
    log_p, log_q = jax.nn.log_sigmoid(heat), jax.nn.log_sigmoid(-heat)
    p = jnp.exp(log_p)
    positive = gauss >= 1.0
    focal = jnp.where(positive, (1 - p) ** 2 * log_p, (1 - gauss) ** 4 * p**2 * log_q)
    objects = jnp.maximum(mask.sum(), 1.0)
    box = jnp.sum(jnp.abs(y[..., 1:5] - t[..., 1:5]) * mask[..., None])
    return (-focal.sum() + box) / objects


# ---------------------------------------------------------------------------------------------------------
# Export


def to_onnx(params, threshold_logit: float):
    """The network as an ONNX model (NCHW, input [1, 3, H, W] RGB in [0, 1]; output [1, 5, H / 4, W / 4], the
    heat through a sigmoid shifted so that 0.5 is the decision threshold)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, weights = [], []

    def conv(name, p, x, k, s, relu, bias_shift=None):
        w = np.transpose(np.asarray(p["w"], np.float32), (3, 2, 0, 1))  # HWIO -> OIHW
        b = np.asarray(p["b"], np.float32).copy()
        if bias_shift is not None:
            b = b + bias_shift(w)
        weights.extend([numpy_helper.from_array(np.ascontiguousarray(w), name + "_w"),
                        numpy_helper.from_array(b, name + "_b")])
        pad = k // 2 if k == 3 else 0
        nodes.append(helper.make_node("Conv", [x, name + "_w", name + "_b"], [name], kernel_shape=[k, k],
                                      strides=[s, s], pads=[pad] * 4))
        if not relu:
            return name
        nodes.append(helper.make_node("Relu", [name], [name + "_relu"]))
        return name + "_relu"

    x, levels = "input", []
    for n, (p, (_, k, s, level)) in enumerate(zip(params["backbone"], BACKBONE)):
        centring = (lambda w: -0.5 * w.sum(axis=(1, 2, 3))) if n == 0 else None  # conv(x - 0.5) = conv(x) - 0.5 sum w
        x = conv(f"backbone{n}", p, x, k, s, True, centring)
        if level:
            levels.append(x)
    weights.append(numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "twice"))
    top = None
    for n, (p, f) in enumerate(zip(reversed(params["lateral"]), reversed(levels))):
        lateral = conv(f"lateral{n}", p, f, 1, 1, False)
        if top is not None:
            nodes.append(helper.make_node("Resize", [top, "", "twice"], [f"up{n}"], mode="nearest",
                                          coordinate_transformation_mode="asymmetric", nearest_mode="floor"))
            nodes.append(helper.make_node("Add", [lateral, f"up{n}"], [f"top{n}"]))
            lateral = f"top{n}"
        top = lateral
    fused = conv("fuse", params["fuse"], top, 3, 1, True)
    shift = np.zeros(OUTPUTS, np.float32)
    shift[0] = -threshold_logit
    head = conv("head", params["head"], fused, 1, 1, False, lambda w: shift)
    # the heat through a sigmoid, the other four as they are
    weights.append(numpy_helper.from_array(np.array([1, OUTPUTS - 1], np.int64), "split"))
    nodes.append(helper.make_node("Split", [head, "split"], ["heat_logit", "box"], axis=1))
    nodes.append(helper.make_node("Sigmoid", ["heat_logit"], ["heat"]))
    nodes.append(helper.make_node("Concat", ["heat", "box"], ["output"], axis=1))
    graph = helper.make_graph(nodes, "ugv_centre_net",
                              [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 512, 512])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, OUTPUTS, 128, 128])],
                              weights)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], producer_name="train_ugv_cnn.py")
    onnx.checker.check_model(model)
    return model


# ---------------------------------------------------------------------------------------------------------
# Threshold


def validation_f1(detector: CnnDetector, dataset: UgvDataset) -> tuple[np.ndarray, np.ndarray, int]:
    """Per detection over the validation frames (the detector at a low threshold): its score and whether it
    is the frame's true positive (IOU >= 0.5, the best-scoring match); and the count of frames with the UGV."""
    scores, hits = [], []
    for i in range(len(dataset)):
        _, s, match = match_truth(detector.detect(dataset.images[i]), dataset.ugv_box(i))
        scores.append(s)
        hits.append(match)
    targets = int(np.sum(~np.isnan(dataset.ugv_boxes[:, 0])))
    return np.concatenate(scores), np.concatenate(hits), targets


def best_threshold(scores: np.ndarray, hits: np.ndarray, targets: int) -> tuple[float, float, float, float]:
    """The score threshold that maximises F1, and (P, R, F1) there; ties go to the middle of the best run."""
    candidates = np.unique(scores)
    best, results = -1.0, []
    for t in candidates:
        kept = scores >= t
        tp, fp = int(np.sum(hits & kept)), int(np.sum(~hits & kept))
        p, r = tp / max(tp + fp, 1), tp / max(targets, 1)
        f1 = 2 * p * r / max(p + r, 1e-12)
        results.append((t, p, r, f1))
        best = max(best, f1)
    run = [row for row in results if row[3] >= best - 1e-12]
    return run[len(run) // 2]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4800, help="training frames (TRAIN_SEEDS from 0)")
    parser.add_argument("--validation-frames", type=int, default=300)
    parser.add_argument("--steps", type=int, default=16000)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--learning-rate", type=float, default=2e-3)
    parser.add_argument("--out", type=Path, default=DEFAULT_MODEL_PATH)
    parser.add_argument("--cache-dir", type=Path, default=None, help="rendered frames' cache (default results/)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        import jax
        import onnx  # noqa: F401
        import optax
    except ImportError as e:
        print(f"the trainer needs the train extra (pip install -e '.[train]'): {e}", file=sys.stderr)
        return 2
    start = time.perf_counter()

    def log(message):
        print(f"[{time.perf_counter() - start:7.1f} s] {message}", flush=True)

    config = training_scene_config()
    chunks = [load_or_render_dataset(TRAIN_SEEDS[a:min(b, args.frames)], config, args.cache_dir)  # as cached
              for a, b in ((0, 800), (800, 2800), (2800, 10**9)) if a < args.frames]
    train = UgvDataset(np.concatenate([c.images for c in chunks]), np.concatenate([c.ugv_boxes for c in chunks]),
                       [b for c in chunks for b in c.distractor_boxes], np.concatenate([c.seeds for c in chunks]),
                       np.concatenate([c.blur_px for c in chunks]), np.concatenate([c.small for c in chunks]))
    validation = load_or_render_dataset(VALIDATION_SEEDS[:args.validation_frames], config, args.cache_dir)
    log(f"frames: {len(train)} training, {len(validation)} validation")
    rng = np.random.default_rng(args.seed)
    params = jax.tree_util.tree_map(jax.numpy.asarray, init_params(rng))
    schedule = optax.warmup_cosine_decay_schedule(0.0, args.learning_rate, 200, args.steps, args.learning_rate / 50)
    optimiser = optax.adam(schedule)
    state = optimiser.init(params)

    @jax.jit
    def step(params, state, x, t):
        loss, grads = jax.value_and_grad(loss_fn)(params, x, t)
        updates, state = optimiser.update(grads, state, params)
        return optax.apply_updates(params, updates), state, loss

    losses = []
    for n in range(args.steps):
        x, t = batch(train, args.batch, rng)
        params, state, loss = step(params, state, x, t)
        losses.append(float(loss))
        if (n + 1) % 250 == 0:
            log(f"step {n + 1}/{args.steps}: loss {np.mean(losses[-250:]):.4f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    trial = args.out.with_suffix(".trial.onnx")
    trial.write_bytes(to_onnx(params, 0.0).SerializeToString())
    scores, hits, targets = validation_f1(CnnDetector(trial, min_score=0.05), validation)
    threshold, p, r, f1 = best_threshold(scores, hits, targets)
    trial.unlink()
    log(f"validation at threshold {threshold:.3f}: precision {p:.4f}, recall {r:.4f}, F1 {f1:.4f}")
    logit = math.log(threshold / (1 - threshold))
    args.out.write_bytes(to_onnx(params, logit).SerializeToString())
    log(f"wrote {args.out} ({args.out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
