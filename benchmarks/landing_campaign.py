"""Issue 10's targets: landing campaigns by vision on a vehicle up to 12 m/s, in wind, on the UAV's own
navigation and through occlusions; and the campaign's throughput.

    .venv/bin/python benchmarks/landing_campaign.py [--runs 20] [--rendered-runs 5] [--workers 2]
        [--throughput-runs 100] [--scaling-runs 20] [--only GROUP ...] [--set KEY=VALUE ...] [--out DIR]
        [--json FILE]

Every group is a `landing-sim montecarlo marker-landing-wind --case ...` campaign (diagrams/montecarlo/grid.py)
steered by ct_ekf, on Eq. 13's path (sine), the vehicle's broadcast as the rendezvous target, the gear's contact
ending the descent (the scenario's `landing.touchdown_by: contact`). Each runs twice: on the paper's synthetic
marker stream (seed 002's 0.1 m and 5 deg on every marker in view, no render; `--runs` per case) and on the
rendered camera (ArUco + solvePnP; `--rendered-runs` per case), the same seeds.

- still: still air, 3, 6 and 12 m/s. Targets: 100 % success at 3 and 6, >= 95 % at 12; touchdown error
  p95 < 0.10 m at 3 and 6, < 0.20 m at 12; relative vertical speed < 0.5 m/s (max).
- wind: the scenario's 5 m/s crosswind, moderate turbulence and gust, 3 and 6 m/s. Targets: >= 95 % success,
  error p95 < 0.15 m.
- navigation: still air on the consumer GNSS/INS grade (`navigation.source: gnss_ins`), 3, 6 and 12 m/s:
  reported beside the truth's (still).
- occlusion: still air, random 0.5 s occlusion bursts (0.2 per second), 3, 6 and 12 m/s. Target: no crash,
  every failed run an abort (target lost, or a timeout), no touchdown off the pad.
- throughput: a --throughput-runs synthetic campaign on --workers (runs/s), and --scaling-runs on 1 and on
  2 workers (target >= 1.7x); each from the campaign's wall time (summary.json's wall_time_s: the pool's
  start-up and the runs, not the summary and plots written after them).
Prints PASS/FAIL per target and Feng et al. (2018)'s 0.37 m at 12 m/s beside ours, and exits 1 on any
FAIL; never a timed assertion in a test. Campaign directories under --out are resumed when run again
(delete them for a fresh run).
"""

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from diagrams.montecarlo import run_campaign  # noqa: E402
from diagrams.montecarlo.grid import grid_settings  # noqa: E402
from diagrams.outputs import check_writable, output_file, write_json  # noqa: E402
from systems.config import ConfigError  # noqa: E402

SCENARIO = "marker-landing-wind"
STILL_AIR = ["wind.mean_m_s=0", "wind.turbulence=none", "wind.gusts=[]"]
COMMON = ["rendezvous.source=broadcast"]
OCCLUSION = ["faults.occlusion_rate_hz=0.2", "faults.occlusion_duration_s=0.5"]
GROUPS = {  # name: (speeds, overrides)
    "still": ("3,6,12", STILL_AIR),
    "wind": ("3,6", []),
    "navigation": ("3,6,12", STILL_AIR + ["navigation.source=gnss_ins"]),
    "occlusion": ("3,6,12", STILL_AIR + OCCLUSION),
}
STREAMS = {"synthetic": "estimation.source=synthetic", "rendered": "estimation.source=detector"}
# Issue 10's occlusion target: a failed run is an abort, not a touchdown off the pad: it lost the target and
# climbed out, or it kept aborting until the time ran out. A crash, a divergence, a touchdown off the pad or a
# run that raised is not.
SAFE_FAILURES = ("target_lost", "timeout")
FENG_2018_M = 0.37  # Feng et al. 2018 (Drones 2(4)): within 0.37 m of the platform's centre at 12 m/s


def campaign(group: str, stream: str, runs: int, workers: int, out: Path, speeds: str | None = None,
             extra: tuple[str, ...] = ()) -> dict:
    """One group's campaign on one stream, `extra` scenario overrides after the group's: its summary
    (diagrams/montecarlo/campaign.py)."""
    group_speeds, overrides = GROUPS[group]
    definition, settings = grid_settings(SCENARIO, [f"vehicle.speed={speeds or group_speeds}"], runs, 0,
                                         COMMON + overrides + [STREAMS[stream], *extra])
    return run_campaign(definition, settings, out, workers=workers, progress=False)


def cell(figures: dict | None) -> str:
    """p50 / p95 / max of a case's figures, or a dash."""
    return "-" if not figures else f"{figures['p50']:.3f} / {figures['p95']:.3f} / {figures['max']:.3f}"


def print_table(title: str, summary: dict) -> None:
    print(f"\n### {title} ({summary['runs']['done']} runs, {summary['wall_time_s']:.0f} s wall)\n")
    print("| case | landed | touchdown error p50 / p95 / max (m) | rel. vertical speed p50 / p95 / max (m/s) "
          "| aborts | failures |")
    print("|---|---|---|---|---|---|")
    for case, c in summary["cases"].items():
        reasons = ", ".join(f"{k} {v}" for k, v in c["failure_reasons"].items()) or "-"
        print(f"| {case} | {c['landed']}/{c['ended']} | {cell(c['touchdown_error_m'])} | "
              f"{cell(c['touchdown_rel_speed_mps'])} | {c['aborts']} | {reasons} |")


def speed_case(summary: dict, speed: int) -> dict:
    return summary["cases"][f"vehicle.speed={speed}"]


def checks_for(group: str, stream: str, summary: dict) -> list[tuple[str, bool, str]]:
    """(target, met, figure) for a group's campaign."""
    out = []
    if group == "still":
        for speed, rate, p95 in ((3, 1.0, 0.10), (6, 1.0, 0.10), (12, 0.95, 0.20)):
            c = speed_case(summary, speed)
            error, vz = c["touchdown_error_m"], c["touchdown_rel_speed_mps"]
            out += [(f"{stream} still air {speed} m/s: success >= {rate:.0%}", (c["success_rate"] or 0) >= rate,
                     f"{c['success_rate']}"),
                    (f"{stream} still air {speed} m/s: error p95 < {p95} m", bool(error) and error["p95"] < p95,
                     f"{error and round(error['p95'], 4)}"),
                    (f"{stream} still air {speed} m/s: rel. vertical speed < 0.5 m/s", bool(vz) and vz["max"] < 0.5,
                     f"{vz and round(vz['max'], 3)}")]
    elif group == "wind":
        for speed in (3, 6):
            c = speed_case(summary, speed)
            error = c["touchdown_error_m"]
            out += [(f"{stream} wind {speed} m/s: success >= 95%", (c["success_rate"] or 0) >= 0.95,
                     f"{c['success_rate']}"),
                    (f"{stream} wind {speed} m/s: error p95 < 0.15 m", bool(error) and error["p95"] < 0.15,
                     f"{error and round(error['p95'], 4)}")]
    elif group == "occlusion":
        for case, c in summary["cases"].items():
            bad = {k: v for k, v in c["failure_reasons"].items() if k not in SAFE_FAILURES}
            out.append((f"{stream} occlusion {case}: no crash, no touchdown off the pad", not bad,
                        json.dumps(c["failure_reasons"])))
    return out


def throughput(runs: int, scaling_runs: int, workers: int, out: Path) -> tuple[dict, list]:
    """runs/s of a synthetic still-air campaign on `workers`, and 1 against 2 workers on scaling_runs."""
    result, checks = {}, []
    if runs:
        shutil.rmtree(out / "throughput", ignore_errors=True)
        summary = campaign("still", "synthetic", -(-runs // 3), workers, out / "throughput")
        result["campaign"] = {"runs": summary["runs"]["computed_now"], "workers": workers,
                              "wall_time_s": summary["wall_time_s"], "runs_per_s": summary["runs_per_s"]}
        print(f"\nthroughput: {summary['runs']['computed_now']} runs on {workers} workers in "
              f"{summary['wall_time_s']:.1f} s: {summary['runs_per_s']:.3f} runs/s")
    if scaling_runs:
        rates, walls = {}, {}
        for n in (1, 2):
            shutil.rmtree(out / f"scaling-{n}", ignore_errors=True)
            summary = campaign("still", "synthetic", scaling_runs, n, out / f"scaling-{n}", speeds="6")
            # The campaign's own wall time, as the throughput's: its pool's start-up and the runs, not the
            # summary and the plots written after them.
            walls[n], rates[n] = summary["wall_time_s"], summary["runs_per_s"]
        ratio = rates[2] / rates[1]
        result["scaling"] = {"runs": scaling_runs, "runs_per_s_1": rates[1], "runs_per_s_2": rates[2], "ratio": ratio,
                             "wall_time_s_1": walls[1], "wall_time_s_2": walls[2]}
        print(f"scaling on {scaling_runs} runs: 1 worker {rates[1]:.3f} runs/s, 2 workers {rates[2]:.3f} runs/s, "
              f"{ratio:.2f}x")
        checks.append(("scaling from 1 to 2 workers >= 1.7x", ratio >= 1.7, f"{ratio:.2f}"))
    return result, checks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="synthetic-stream runs per case")
    parser.add_argument("--rendered-runs", type=int, default=5, help="rendered-camera runs per case")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--throughput-runs", type=int, default=100)
    parser.add_argument("--scaling-runs", type=int, default=20)
    parser.add_argument("--only", nargs="+", choices=sorted(GROUPS), default=sorted(GROUPS))
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "landing-campaign")
    parser.add_argument("--json", type=output_file, help="write the figures and checks here")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario field in every group's runs (repeatable), e.g. "
                             "landing.land_acceptance_radius_m=0.15")
    args = parser.parse_args(argv)
    # 0 skips a stream or a measurement (--workers 0: every run in this process); checked before any campaign.
    for name in ("runs", "rendered_runs", "throughput_runs", "scaling_runs", "workers"):
        if getattr(args, name) < 0:
            parser.error(f"--{name.replace('_', '-')} must not be negative, got {getattr(args, name)}")
    report, checks = {}, []
    try:
        grid_settings(SCENARIO, ["vehicle.speed=3"], 1, 0, COMMON + args.set)
        check_writable(args.out)
    except ConfigError as e:
        print(f"landing_campaign: {e}", file=sys.stderr)
        return 2
    for group in args.only:
        for stream, runs in (("synthetic", args.runs), ("rendered", args.rendered_runs)):
            if runs <= 0:
                continue
            summary = campaign(group, stream, runs, args.workers, args.out / f"{group}-{stream}", extra=tuple(args.set))
            print_table(f"{group}, {stream} stream", summary)
            report[f"{group}-{stream}"] = {"wall_time_s": summary["wall_time_s"], "cases": summary["cases"]}
            checks += checks_for(group, stream, summary)
    for key in ("still-synthetic", "still-rendered"):
        if key in report:
            error = report[key]["cases"]["vehicle.speed=12"]["touchdown_error_m"]
            if error:
                print(f"\n12 m/s, {key}: touchdown error p95 {error['p95']:.3f} m, max {error['max']:.3f} m against "
                      f"Feng et al. 2018's {FENG_2018_M} m")
    report["throughput"], more = throughput(args.throughput_runs, args.scaling_runs, args.workers, args.out)
    checks += more
    print()
    for name, met, figure in checks:
        print(f"{'PASS' if met else 'FAIL'}  {name}  ({figure})")
    if args.json:
        write_json(args.json, {"figures": report, "checks": checks})
    return 0 if all(met for _, met, _ in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
