"""The `landing-sim` command.

    landing-sim list
    landing-sim run stewart-hover --duration 20 --seed 3 --out results/run1 [--meshcat] [--record] [--video]
    landing-sim run --config my_scenario.yaml --set platform.roll_amplitude_deg=8
    landing-sim montecarlo gv-marker-ekf --runs 100 --speeds 3 6 12 --workers 2 --out results/mc
    landing-sim montecarlo gv-marker-ekf --runs 1000 --scheduler tcp://host:8786 --out results/mc

Errors in what the user asked for (a bad name, key, value or output path) print one line and exit
with status 2, before anything is written.
"""

import argparse
import sys

from diagrams.scenario import read_scenario, scenario_names, scenario_path
from systems.config import ConfigError

DEFAULT_SCENARIO = "stewart-dynamic"
EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise ConfigError(message)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="landing-sim", description="Simulate vision-based UAV landing scenarios in Drake.")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks of internal errors")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    commands.add_parser("list", help="list the named scenarios")
    run = commands.add_parser("run", help="run a scenario and write its results")
    run.add_argument("scenario", nargs="?", help=f"scenario name (default: {DEFAULT_SCENARIO})")
    run.add_argument("--config", metavar="FILE", help="a scenario YAML file instead of a named scenario")
    run.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append", default=[],
                     help="override a scenario field, e.g. platform.roll_amplitude_deg=8 (repeatable)")
    run.add_argument("--duration", type=float, metavar="S", help="simulated time (s)")
    run.add_argument("--seed", type=int, help="seed of every noise source")
    run.add_argument("--out", metavar="DIR", help="output directory (default: results/<scenario>)")
    run.add_argument("--meshcat", action="store_true", help="serve the live scene in Meshcat (real time)")
    run.add_argument("--meshcat-host", default="localhost",
                     help="interface Meshcat listens on (default: localhost; 0.0.0.0 for every interface)")
    run.add_argument("--meshcat-port", type=int, help="Meshcat's port, 1024 to 65535 or 0: any free one "
                     "(default: the first free from 7000)")
    run.add_argument("--record", action="store_true", help="write meshcat.html, a self-contained recording")
    run.add_argument("--video", action="store_true", help="write camera.mp4, the camera stream")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    mc = commands.add_parser("montecarlo", help="run a Monte Carlo campaign of a scenario (resumable)")
    mc.add_argument("scenario", help="the scenario whose campaign to run")
    mc.add_argument("--runs", type=int, metavar="N", help="runs per case (default: the campaign's)")
    mc.add_argument("--speeds", "--cases", dest="cases", nargs="+", metavar="CASE",
                    help="the cases to run, e.g. vehicle speeds in m/s (default: the campaign's)")
    mc.add_argument("--case", dest="case_options", metavar="KEY=V1,V2", action="append", default=[],
                    help="a field and its values (repeatable): landings of a landing scenario (a gv scenario that "
                         "lands, deck-landing or deck-landing-hardware) over the grid of their product, e.g. "
                         "--case vehicle.speed=3,6,12 --case wind.mean_m_s=0,5")
    mc.add_argument("--seed", type=int, default=0, help="base seed; run i of a case always gets the same seed")
    mc.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append", default=[],
                    help="override a scenario field in every run (repeatable)")
    mc.add_argument("--out", metavar="DIR", help="output directory (default: results/<scenario>-mc); "
                    "running the same command again resumes the campaign there")
    executors = mc.add_mutually_exclusive_group()
    executors.add_argument("--workers", type=int, metavar="N",
                           help="local worker processes (default: one per core; 0: in this process)")
    executors.add_argument("--scheduler", metavar="ADDRESS",
                           help="run on an existing Dask distributed cluster, e.g. tcp://host:8786")
    mc.add_argument("--retry-failed", action="store_true", help="run again the runs recorded as failed")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _list() -> None:
    for name in scenario_names():
        description = read_scenario(scenario_path(name)).get("description", "")
        print(f"{name:24s} {description}")


def _run(args) -> None:
    from diagrams.runner import RunOptions, load_scenario, run

    if args.scenario and args.config:
        raise ConfigError("give a scenario name or --config FILE, not both")
    name, scenario = load_scenario(None if args.config else (args.scenario or DEFAULT_SCENARIO), args.config,
                                   args.overrides, args.duration, args.seed)
    out_dir = args.out or f"results/{name}"
    options = RunOptions(meshcat=args.meshcat, meshcat_host=args.meshcat_host, meshcat_port=args.meshcat_port,
                         record=args.record, video=args.video, progress=not args.quiet)
    metrics = run(name, scenario, out_dir, options)
    print(f"{name}: {metrics['sim_time_s']:.1f} s simulated in {metrics['wall_time_s']:.1f} s "
          f"(real-time factor {metrics['realtime_factor']:.2f}); results in {out_dir}/")
    if args.meshcat and sys.stdin.isatty():
        input("Meshcat keeps serving the scene; press Enter to exit. ")


def _montecarlo(args) -> None:
    from diagrams.montecarlo import campaign_definition, campaign_settings, run_campaign
    from diagrams.montecarlo.grid import grid_settings

    if args.case_options:
        if args.cases:
            raise ConfigError("--case and --cases do not mix: give the grid's fields with --case")
        definition, settings = grid_settings(args.scenario, args.case_options, args.runs, args.seed, args.overrides)
    else:
        definition = campaign_definition(args.scenario)
        settings = campaign_settings(definition, args.scenario, args.cases, args.runs, args.seed, args.overrides)
    out_dir = args.out or f"results/{args.scenario}-mc"
    summary = run_campaign(definition, settings, out_dir, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet, retry_failed=args.retry_failed)
    runs = summary["runs"]
    rate = f", {summary['runs_per_s']:.2f} runs/s" if summary["runs_per_s"] else ""
    print(f"{args.scenario}: {runs['done']} of {runs['requested']} runs done, {runs['failed']} failed "
          f"({runs['computed_now']} run now in {summary['wall_time_s']:.1f} s{rate}); "
          f"summary in {out_dir}/summary.json")


def main(argv=None) -> int:
    args = None
    try:
        args = _parser().parse_args(argv)
        if args.command == "list":
            _list()
        elif args.command == "montecarlo":
            _montecarlo(args)
        else:
            _run(args)
        return 0
    except ConfigError as e:
        print(f"landing-sim: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("landing-sim: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if args is not None and args.debug:
            raise
        print(f"landing-sim: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
