"""Seed 003's mission steered by the hybrid array (scenario ugv-hybrid) over the eight paths at one speed:
success, touchdown error (p95) and the hybrid estimate's accuracy, per run and over all; per run the estimate's
MAE per axis from the climb's end on (seed 003 section 3.1.2: <= 0.01, 0.01, 0.08 m after settling) and the
tracker's identity switches (one UGV: each a lost lock taken again under a new track).

    .venv/bin/python benchmarks/hybrid.py [--speed 0.5] [--seeds 0 1] [--paths straight circle ...]
                                          [--jobs N] [--duration 120] [--json FILE] [--set KEY=VALUE ...]

Each run renders the fisheye (five faces) and the stereo pair at 10 Hz and runs the learned detector: about
3-4 s of wall time per simulated second on one core (a landing takes 30-60 s of flight), so the full sweep
(8 paths x 2 seeds) is 30-60 minutes on two cores; `--paths` picks a few.
"""

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from diagrams.gv_landing_run import fly
from diagrams.outputs import output_file, write_json
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.vehicles.paths import PATH_NAMES


def task_scenario(task: tuple):
    """The ugv-hybrid scenario of one run, `task` = (path, speed [m/s], seed, duration [s], overrides); a
    ConfigError names what it refuses."""
    path, speed, seed, duration_s, extra = task
    return load_scenario("ugv-hybrid", overrides=[f"vehicle.path={path}", f"vehicle.speed={speed}", *extra],
                         seed=seed, duration_s=duration_s)[1]


def one_run(task: tuple) -> dict:
    path, speed, seed, _, _ = task
    scenario = task_scenario(task)
    start = time.perf_counter()
    metrics, _ = fly(scenario, scenario.duration_s, progress=False)
    landing, hybrid = metrics["landing"], metrics["estimators"]["hybrid"]
    return {"path": path, "speed": speed, "seed": seed, "success": landing["success"],
            "touchdown_error_m": landing["touchdown_error_m"], "rel_speed_mps": landing["touchdown_rel_speed_mps"],
            "time_to_land_s": landing["time_to_land_s"], "failure": landing["failure_reason"],
            "hybrid_rmse_horizontal_m": hybrid["position_m"].get("rmse_horizontal"),
            "hybrid_mae_after_climb_xyz_m": hybrid.get("position_m_after_climb", {}).get("mae_xyz"),
            "hybrid_valid_fraction": hybrid["valid_fraction"],
            "identity_switches": metrics["estimators"]["hybrid_detector"]["identity_switches"],
            "sim_time_s": metrics["sim_time_s"], "wall_s": time.perf_counter() - start}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=0.5)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--paths", nargs="+", default=list(PATH_NAMES), choices=PATH_NAMES)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--json", type=output_file)
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")
    tasks = [(p, args.speed, s, args.duration, tuple(args.overrides)) for p in args.paths for s in args.seeds]
    try:  # every run's scenario here, not a traceback from the process pool
        for task in tasks:
            task_scenario(task)
    except ConfigError as e:
        parser.exit(2, f"{e}\n")
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        runs = list(pool.map(one_run, tasks))
    print(f"{'path':<13}{'seed':>5}{'ok':>4}{'error m':>9}{'v_rel':>7}{'t land':>8}{'est rms':>9}{'valid':>7}"
          f"{'switch':>7}{'wall s':>8}{'MAE x / y / z after the climb, m':>34}  failure")
    for r in runs:
        fmt = (lambda v, f: "-" if v is None else format(v, f))
        mae = r["hybrid_mae_after_climb_xyz_m"]
        after_climb = "-" if mae is None else " / ".join(f"{v:.4f}" for v in mae)
        print(f"{r['path']:<13}{r['seed']:>5}{'y' if r['success'] else 'n':>4}{fmt(r['touchdown_error_m'], '.3f'):>9}"
              f"{fmt(r['rel_speed_mps'], '.2f'):>7}{fmt(r['time_to_land_s'], '.1f'):>8}"
              f"{fmt(r['hybrid_rmse_horizontal_m'], '.3f'):>9}{r['hybrid_valid_fraction']:>7.2f}"
              f"{r['identity_switches']:>7}{r['wall_s']:>8.0f}"
              f"{after_climb:>34}"
              f"  {r['failure'] or ''}")
    errors = [r["touchdown_error_m"] for r in runs if r["touchdown_error_m"] is not None]  # off the pad too
    success = sum(r["success"] for r in runs) / len(runs)
    p95 = float(np.percentile(errors, 95)) if errors else None
    print(f"speed {args.speed} m/s: success {success:.0%} of {len(runs)}, touchdown error p95 "
          f"{'-' if p95 is None else f'{p95:.3f} m'}")
    if args.json:
        write_json(args.json, {"speed": args.speed, "success_rate": success, "touchdown_error_p95_m": p95,
                               "runs": runs})


if __name__ == "__main__":
    main()
