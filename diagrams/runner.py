"""Running a scenario: load it, build its diagram, simulate, and write what DESIGN.md says a run
leaves behind (metrics.json, log.npz, plots, and on request a Meshcat recording and a video)."""

import sys
from dataclasses import dataclass
from pathlib import Path

from pydrake.geometry import Meshcat, MeshcatParams

from diagrams.outputs import check_writable, write_json, write_text
from diagrams.scenario import load_typed, normalise, read_scenario, scenario_path, set_override
from diagrams.simulate import simulate
from systems.config import ConfigError


@dataclass
class RunOptions:
    """How to run, as opposed to what to simulate (that is the scenario)."""

    meshcat: bool = False  # serve the live scene in Meshcat
    meshcat_host: str = "localhost"
    meshcat_port: int | None = None
    record: bool = False  # write meshcat.html, a self-contained recording
    video: bool = False  # write camera.mp4, the camera stream
    progress: bool = True


@dataclass
class RunContext:
    """What a diagram's run function gets besides its scenario."""

    name: str
    out_dir: Path
    options: RunOptions
    meshcat: Meshcat | None


def _diagrams():
    """Diagram name -> module with a `Scenario` dataclass and a `run(scenario, ctx)` function.
    Imported here so that `landing-sim list` and scenario errors do not wait for every diagram."""
    import importlib

    return {name: importlib.import_module(module) for name, module in DIAGRAM_MODULES.items()}


DIAGRAM_MODULES = {
    "stewart_scene": "diagrams.stewart_run",
    "crhf_calibration": "diagrams.crhf_calibration",
    "gv_landing": "diagrams.gv_landing_run",
    "deck_landing": "diagrams.deck_landing_run",
    "gv_marker_ekf": "diagrams.gv_marker_ekf",
    "rqrlp_maneuvers": "diagrams.rqrlp_maneuvers_run",
}


def load_scenario(name: str | None = None, config_path: str | Path | None = None, overrides=(),
                  duration_s: float | None = None, seed: int | None = None):
    """(scenario name, typed scenario) from a named scenario or a YAML file, with `--set` overrides, and
    `duration_s` [s] and `seed` (--duration, --seed) over both; ConfigError when a --set gives either another value."""
    path = Path(config_path) if config_path else scenario_path(name)
    raw = read_scenario(path)
    for assignment in overrides:
        set_override(raw, assignment)
    set_keys = {assignment.partition("=")[0] for assignment in overrides}
    for key, value, option in (("duration_s", duration_s, "--duration"), ("seed", seed, "--seed")):
        if value is None:
            continue
        if key in set_keys and raw[key] != value:
            raise ConfigError(f"{option} {value} and --set {key}={raw[key]} differ: give one")
        raw[key] = value
    diagrams = _diagrams()
    diagram = raw.get("diagram", "stewart_scene")
    if not isinstance(diagram, str) or diagram not in diagrams:
        raise ConfigError(f"{path}: unknown diagram {diagram!r} (known: {', '.join(diagrams)})")
    schema = diagrams[diagram].Scenario
    scenario = load_typed(normalise(raw, schema), schema, str(path))
    scenario.validate()
    return path.stem, scenario


def make_meshcat(options: RunOptions) -> Meshcat | None:
    """A Meshcat server when the run shows or records the scene; bound to localhost by default. ConfigError
    for a port Meshcat does not take (it wants 0, any free port, or 1024 to 65535) or cannot listen on."""
    port = options.meshcat_port
    if port is not None and port != 0 and not 1024 <= port <= 65535:
        raise ConfigError(f"--meshcat-port must be 0 (any free port) or 1024 to 65535, got {port}")
    if not (options.meshcat or options.record):
        return None
    try:
        return Meshcat(MeshcatParams(host=options.meshcat_host, port=port))
    except RuntimeError:  # Drake: "Meshcat failed to open a websocket port."
        where = f"{options.meshcat_host}:{'7000 to 7999' if port is None else port}"
        raise ConfigError(f"Meshcat cannot listen on {where} (the port in use, or the host not this machine's); "
                          f"give another --meshcat-port or --meshcat-host") from None


def simulate_scene(diagram, handles, scenario, ctx: RunContext):
    """Simulates a scene whose handles carry `meshcat_visualizer` and `video` (see
    `stewart_scene.add_viewers`) for `duration_s`; returns (metrics common to every run, final
    context)."""
    run = simulate(diagram, scenario.duration_s, realtime=ctx.options.meshcat, progress=ctx.options.progress,
                   visualizer=handles.meshcat_visualizer, record=ctx.options.record, video=handles.video)
    metrics = {"scenario": ctx.name, "seed": scenario.seed, "sim_time_s": run.sim_time_s,
               "wall_time_s": run.wall_time_s, "realtime_factor": run.realtime_factor}
    return metrics, run.context


def finish_run(ctx: RunContext, metrics: dict) -> dict:
    """Writes the Meshcat recording if asked, and metrics.json last."""
    if ctx.options.record:
        write_text(ctx.out_dir / "meshcat.html", ctx.meshcat.StaticHtml())
    write_json(ctx.out_dir / "metrics.json", metrics)
    return metrics


OUTPUT_SUFFIXES = (".json", ".html", ".png", ".npz", ".mp4")  # the kinds of file a run writes


def _files(out_dir: Path) -> dict[Path, int]:
    """{file: inode} of the files of the kinds a run writes in `out_dir`. Every output is written to a new
    file and renamed into place (diagrams/outputs.py), so one a run writes again gets a new inode."""
    return {p: p.stat().st_ino for p in out_dir.iterdir() if p.is_file() and p.suffix in OUTPUT_SUFFIXES}


def run(name: str, scenario, out_dir: str | Path, options: RunOptions) -> dict:
    """Runs a loaded scenario, writing its outputs to `out_dir`; returns its metrics. Files there of the
    kinds a run writes that this one did not write (an earlier run's video, say, when this one records
    none) are named in one line on stderr when it has finished; nothing is removed. A run that fails
    removes what it wrote (a file of those kinds new or replaced since it started, a hidden partial one
    too) and the folders it made, leaving the files that were there before it."""
    out_dir = Path(out_dir)
    check_writable(out_dir)
    created = [p for p in (out_dir, *out_dir.parents) if not p.exists()]  # the folders mkdir makes, deepest first
    out_dir.mkdir(parents=True, exist_ok=True)
    before = _files(out_dir)
    try:
        meshcat = make_meshcat(options)
        if meshcat is not None and options.meshcat:
            print(f"Meshcat is serving the scene at {meshcat.web_url()}", flush=True)
        metrics = _diagrams()[scenario.diagram].run(scenario, RunContext(name, out_dir, options, meshcat))
        kept = sorted(p.name for p, inode in _files(out_dir).items() if before.get(p) == inode)
        if kept:
            print(f"landing-sim: {out_dir} also holds files this run did not write (an earlier run's?): "
                  f"{', '.join(kept)}", file=sys.stderr)
        return metrics
    except BaseException:
        for path, inode in _files(out_dir).items():
            if before.get(path) != inode:
                path.unlink(missing_ok=True)
        for folder in created:  # each left empty, deepest first: one holding a file stays, with those above it
            try:
                folder.rmdir()
            except OSError:
                break
        raise
