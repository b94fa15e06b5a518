"""CRHF and ATDA against seed 000's Table 5 (mean absolute error of the tag pose X_CT).

    .venv/bin/python benchmarks/crhf_table5.py [--duration 200] [--quick | --hardware]

Runs stewart-dynamic (default noise), then unseen motions: random-walk deck motion with three seeds
not used for tuning, and the camera at 1.5 m and 3 m. Prints each run's MAE beside the paper's, the pose-flip
count (frames with rotation error > 10 deg) and CRHF's per-frame compute time (both filters, the
corners' PnP normal and its fusion, and the pose, replayed on the run's own logged corners and
ranges: no rendering, no detection).

`--hardware` runs stewart-hardware (sensors as imperfect as seed 000's hardware, issue 13) against the
issue's targets (each of the 12 figures within 0.5x-2x of Table 5, CRHF below ATDA on every axis, no
CRHF flips), then stewart-dynamic with each of its effects alone, to say which effect makes which error.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from diagrams.outputs import check_writable, output_file, write_json
from diagrams.runner import RunOptions, load_scenario, run
from diagrams.scenario import read_scenario, scenario_path
from diagrams.stewart_scene import StewartSceneConfig
from systems.config import ConfigError
from systems.estimators.crhf import CrhfEstimator, CrhfState
from systems.sensors.tof import sensor_positions_C

PAPER = {  # seed 000 Table 5: x, y, z (m), roll, pitch, yaw (deg)
    "atda": [0.0157, 0.0129, 0.0687, 3.9043, 1.7684, 1.7859],
    "crhf": [0.0047, 0.0042, 0.0051, 1.4239, 1.5231, 1.3290],
}
CASES = {
    "stewart-dynamic": [],
    # CRHF's filters were tuned on stewart-dynamic seed 0 and a random walk with seed 1: these are unseen.
    "random-walk seed 11": ["platform.motion=random_walk", "seed=11"],
    "random-walk seed 12": ["platform.motion=random_walk", "seed=12"],
    "random-walk seed 13": ["platform.motion=random_walk", "seed=13"],
    "camera at 1.5 m": ["hover.height_above_deck_m=1.5"],
    "camera at 3 m": ["hover.height_above_deck_m=3.0"],
}
DEFAULT_OUT = Path("results/crhf_table5.json")  # its folder made at the end if missing


# stewart-hardware's effects, each a group of its settings, switched on one at a time over stewart-dynamic.
HARDWARE_EFFECTS = {
    "lens distortion": ["camera.distortion"],
    "calibration error": ["camera.calibration_error"],
    "sensor noise": ["camera.pixel_noise_std", "camera.full_well_e", "camera.read_noise_e", "camera.analog_gain"],
    "motion blur": ["camera.exposure_s"],
    "ToF cone": ["tof.cone_deg"],
    "ToF noise and bias": ["tof.noise_std_m", "tof.noise_std_per_m", "tof.bias_m", "crhf.range_filter"],
    "ToF clock": ["tof.trigger", "tof.rate_hz", "tof.time_offset_s"],
    "latency": ["estimate_latency_frames"],
}


def hardware_cases() -> dict[str, tuple[str, list[str]]]:
    """{case: (scenario, overrides)}: stewart-hardware whole, then each effect alone on stewart-dynamic,
    its values read from scenarios/stewart-hardware.yaml."""
    raw = read_scenario(scenario_path("stewart-hardware"))
    # The VL53L1X's narrowest region of interest (4x4 of its 16x16 SPADs, about 15 deg: ST's AN5191): the
    # cone a user would set to keep the footprint on a 1 m deck from 2 m.
    cases = {"stewart-hardware": ("stewart-hardware", []),
             "stewart-hardware, ToF ROI 15 deg": ("stewart-hardware", ["tof.cone_deg=15.0"])}
    for effect, keys in HARDWARE_EFFECTS.items():
        overrides = []
        for key in keys:
            value = raw
            for part in key.split("."):
                value = value[part]
            overrides.append(f"{key}={json.dumps(value)}")  # JSON is YAML
        cases[f"only {effect}"] = ("stewart-dynamic", overrides)
    return cases


def hardware_verdicts(ours: dict) -> list[str]:
    """The issue's stewart-hardware targets for one case, each with its outcome."""
    lines = []
    for estimator in ("atda", "crhf"):
        ratio = np.array(ours[estimator]["mae_xyz_m"] + ours[estimator]["mae_rpy_deg"]) / PAPER[estimator]
        inside = (ratio >= 0.5) & (ratio <= 2.0)
        lines.append(f"{estimator.upper()} within 0.5x-2x of Table 5: {inside.sum()}/6 (ratios "
                     + " ".join(f"{r:.2f}" for r in ratio) + ")")
    return lines + verdicts(ours)[1:]


def crhf_compute_ms(config: StewartSceneConfig, log: dict) -> float:
    """Median ms per frame of CRHF's own work (filters, normal fusion and pose) on logged inputs."""
    crhf = CrhfEstimator(config.crhf, sensor_positions_C(config.tof.arm_m, config.tof.angle_deg),
                         config.platform.tag_size_m, config.camera.period_s, config.camera)
    state, times = CrhfState(), []
    for t, corners, ranges in zip(log["t"], log["tag_corners"], log["ranges"]):
        start = time.perf_counter()
        state, _ = crhf.step(state, corners.reshape(4, 2), ranges, t)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def row(name: str, values) -> str:
    return f"  {name:14s}" + "".join(f"{v:9.5f}" for v in values)


def verdicts(ours: dict) -> list[str]:
    """The issue's targets for one case, each with its outcome."""
    crhf = np.array(ours["crhf"]["mae_xyz_m"] + ours["crhf"]["mae_rpy_deg"])
    atda = np.array(ours["atda"]["mae_xyz_m"] + ours["atda"]["mae_rpy_deg"])
    return [f"CRHF <= paper CRHF on all six axes: {'yes' if np.all(crhf <= PAPER['crhf']) else 'NO'}",
            f"CRHF < our ATDA on all six axes: {'yes' if np.all(crhf < atda) else 'NO'}",
            f"CRHF flips: {ours['crhf']['flips']} (target 0)"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=200.0, help="simulated seconds per run")
    parser.add_argument("--quick", action="store_true", help="stewart-dynamic only")
    parser.add_argument("--hardware", action="store_true",
                        help="stewart-hardware, then each of its effects alone on stewart-dynamic")
    parser.add_argument("--out", type=output_file,
                        help=f"where to write the figures as JSON (default {DEFAULT_OUT}, its folder made if missing)")
    args = parser.parse_args(argv)
    if args.out is None:
        try:
            check_writable(DEFAULT_OUT.parent)
        except ConfigError as e:
            parser.error(f"--out (default {DEFAULT_OUT}): {e}")
    out_file = args.out or DEFAULT_OUT
    results = {}
    cases = {case: ("stewart-dynamic", overrides) for case, overrides in CASES.items()}
    if args.quick:
        cases = {"stewart-dynamic": ("stewart-dynamic", [])}
    elif args.hardware:
        cases = hardware_cases()
    # Every case's scenario before the first run: a bad --duration is refused before the work, not after it.
    try:
        scenarios = {case: load_scenario(scenario_name, overrides=["estimators=[atda, crhf]", *overrides],
                                         duration_s=args.duration)
                     for case, (scenario_name, overrides) in cases.items()}
    except ConfigError as e:
        parser.exit(2, f"{e}\n")
    header = "  " + " " * 14 + "".join(f"{h:>9s}" for h in ("x m", "y m", "z m", "roll", "pitch", "yaw"))
    with tempfile.TemporaryDirectory() as tmp:
        for case, (name, scenario) in scenarios.items():
            out = Path(tmp) / case.replace(" ", "_")
            metrics = run(name, scenario, out, RunOptions(progress=False))
            log = dict(np.load(out / "log.npz"))
            print(f"\n{case} ({args.duration:g} s, real-time factor {metrics['realtime_factor']:.2f})")
            print(header)
            for estimator in ("atda", "crhf"):
                m = metrics["estimators"][estimator]
                print(row(f"{estimator} (paper)", PAPER[estimator]))
                print(row(f"{estimator} (ours)", m["mae_xyz_m"] + m["mae_rpy_deg"])
                      + f"   valid {m['valid_fraction']:.3f}, flips {m['flips']}")
            compute_ms = crhf_compute_ms(scenario, log)
            print(f"  crhf compute per frame: {compute_ms:.2f} ms (target < 2 ms)")
            for line in (hardware_verdicts if args.hardware else verdicts)(metrics["estimators"]):
                print(f"  {line}")
            results[case] = {"estimators": metrics["estimators"], "crhf_compute_ms": compute_ms,
                             "realtime_factor": metrics["realtime_factor"], "duration_s": args.duration}
    out_file.parent.mkdir(parents=True, exist_ok=True)
    write_json(out_file, {"paper_mae": PAPER, "cases": results})
    print(f"\nfigures written to {out_file}")


if __name__ == "__main__":
    main()
