"""The landing-sim command: `list`, a short run and what it leaves behind, and bad input, which must
give one line on stderr, exit status 2, no traceback and no output files."""

import argparse
import contextlib
import io
import json
import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import matplotlib.pyplot as plt
import numpy as np
import pytest

from diagrams import runner
from diagrams.cli import DEFAULT_SCENARIO, main
from diagrams.outputs import output_file, save_figure, write_json
from diagrams.scenario import scenario_names
from diagrams.simulate import Simulation
from systems.config import ConfigError
from tests.conftest import landing_sim_command

SYS_OUT = Path("/sys/landing-sim-test/out")  # /sys refuses to create entries, even for root (EPERM)


@pytest.fixture(scope="module")
def console_runs(tmp_path_factory):
    """The installed command run as a separate process (in parallel, to save start-up time)."""
    out = tmp_path_factory.mktemp("console") / "out"
    commands = {"list": ["list"], "bad_name": ["run", "no-such-scenario", "--out", str(out), "--quiet"]}
    processes = {key: subprocess.Popen(landing_sim_command() + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                       text=True) for key, args in commands.items()}
    results = {}
    for key, process in processes.items():
        stdout, stderr = process.communicate(timeout=120)
        results[key] = (process.returncode, stdout, stderr)
    return results, out


def test_list_prints_both_scenarios(console_runs):
    code, stdout, stderr = console_runs[0]["list"]
    assert code == 0, stderr
    names = [line.split()[0] for line in stdout.splitlines() if line.strip()]
    assert "stewart-hover" in names and "stewart-dynamic" in names
    # Each line carries the scenario's description.
    hover = next(line for line in stdout.splitlines() if line.startswith("stewart-hover"))
    assert "static deck" in hover


def test_bad_name_from_the_installed_command(console_runs):
    results, out = console_runs
    code, stdout, stderr = results["bad_name"]
    assert code == 2
    assert stderr.count("\n") == 1 and "no-such-scenario" in stderr and "Traceback" not in stderr
    assert stdout == ""
    assert not out.exists()


def run_main(capfd, *args):
    code = main(list(args))
    captured = capfd.readouterr()
    return code, captured.out, captured.err


@pytest.fixture
def bad_config(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("platform:\n  motion: sinusoid\n  rol_amplitude_deg: [8.0]\n")
    return path


@pytest.mark.parametrize("args, named", [
    (["run", "stewart-hoover"], "stewart-hoover"),
    (["run", "--config", "{bad_config}"], "platform.rol_amplitude_deg"),
    (["run", "stewart-hover", "--set", "camera.rate_hz=-1"], "camera.rate_hz"),
    (["run", "stewart-hover", "--set", "platform.tag_size_m=2"], "platform.tag_size_m"),
    (["run", "stewart-hover", "--duration", "-1"], "duration_s"),
    (["run", "stewart-hover", "--set", "camera.rate_hz=fast"], "camera.rate_hz"),
    (["run", "stewart-hover", "--config", "{bad_config}"], "not both"),
    (["run", "stewart-hover", "--frobnicate"], "--frobnicate"),
    (["run", "--config", "{missing}"], "missing.yaml"),
    (["run", "--config", "{latin1_config}"], "latin1.yaml is not UTF-8 text (byte 18: b'\\xe9')"),
    (["run", "open-landing", "--set", "platform.pattern=markers"], "platform.pattern"),
    (["run", "open-landing", "--set", "estimation.source=detector"], "estimation.source"),
    (["run", "open-landing", "--set", "federated.camera.blackouts_s=[[2.0, 1.0]]"], "blackouts_s"),
    (["run", "open-landing", "--set", "federated.imu.rate_hz=70.0"], "federated.camera.rate_hz"),
    (["run", "open-landing", "--set", "platform.rqrlp.border_m=0.0002"], "platform.rqrlp.border_m"),
    (["run", "open-landing", "--set", "platform.rqrlp.texture_cell_m=2.0"], "platform.rqrlp.texture_cell_m"),
    (["run", "rqrlp-maneuvers", "--set", "manoeuvres=[[0.0, 1, 0, 0, 0]]"], "manoeuvres"),
    (["run", "deck-landing", "--set", "platform.z_amplitude_m=[0.3]"], "stroke"),
    (["run", "stewart-hardware", "--set", "platform.z_amplitude_m=[0.5]"], "stroke"),
    (["run", "stewart-hover", "--set", "platform.roll_amplitude_deg=[8]", "--set", "platform.roll_frequency_hz=[0.05]"],
     "platform.roll_amplitude_deg is [8.0] but platform.motion is 'static'"),
    (["run", "stewart-dynamic", "--seed", "-1"], "seed"),
    (["run", "stewart-dynamic", "--set", "tof.angle_deg=0.0"], "tof.angle_deg"),
    (["run", "stewart-dynamic", "--set", "tof.angle_deg=1e-9"], "tof.arm_m and tof.angle_deg give the sensors |y|"),
    (["run", "stewart-hover", "--set", "estimators=[crhf, crhf]"], "estimators: each may be listed once"),
    (["run", "stewart-hover", "--set", "camera.fx=550"], "flown with camera [fx, fy, cx, cy, width, height]"),
    (["run", "deck-landing", "--set", "tof.arm_m=0.2"], "flown with ToF sensors at (x, y, z)"),
    (["run", "ugv-hybrid", "--set", "hybrid.ground.texture_seed=-1"], "hybrid.ground.texture_seed"),
    (["run", "ugv-hybrid", "--set", "hybrid.tracker.cue_px=[1e9,1e9]"], "hybrid.tracker.cue_px"),
    (["run", "deck-landing", "--duration", "-1"], "duration_s"),
    (["run", "stewart-dynamic", "--set", "platform.base_joint_height_m=-1.0"], "platform.base_joint_height_m"),
    (["run", "deck-landing", "--set", "perception.source=ct_ekf"], "perception.source"),
    (["run", "deck-landing", "--set", "landing.initial_height_m=1.2"], "landing.initial_height_m"),
    (["run", "deck-landing", "--set", "estimate_latency_frames=-1"], "estimate_latency_frames"),
    (["run", "deck-landing-hardware", "--set", "tof.time_offset_s=0.04"], "tof.time_offset_s"),
    (["run", "ugv-hybrid", "--set", "hybrid.model_path={missing_model}"], "missing.onnx"),
    (["run", "ugv-hybrid", "--set", "hybrid.model_path={corrupt_model}"], "corrupt.onnx"),
    (["run", "stewart-hover", "--duration", "0.1", "--meshcat-port", "99999"], "--meshcat-port"),  # wrapped before
    (["run", "stewart-hover", "--duration", "0.1", "--record", "--meshcat-port", "80"], "--meshcat-port"),
    (["run", "stewart-hover", "--duration", "0.1", "--record", "--meshcat-port", "-1"], "--meshcat-port"),
    # the scene's config checks uav.*: unchecked, Drake's Cylinder() failed on the radius, naming no field
    (["run", "stewart-hover", "--set", "uav.propeller_radius_m=0"], "uav.propeller_radius_m must be positive"),
], ids=["bad-name", "unknown-key", "negative-rate", "tag-too-big", "negative-duration", "type-error",
        "name-and-config", "unknown-option", "missing-config", "latin1-config", "federated-on-markers", "two-cameras",
        "backward-blackout", "imu-rate", "rqrlp-border-under-a-pixel",
        "rqrlp-texture-cell-beyond-the-pattern", "empty-manoeuvre", "deck-beyond-stroke", "stewart-beyond-stroke",
        "motion-on-a-static-deck",
        "negative-seed", "tof-on-the-axes", "tof-near-an-axis", "estimator-twice", "crhf-calibration-camera",
        "crhf-calibration-tof", "negative-texture-seed", "cue-outside-the-fisheye", "negative-duration-deck",
        "negative-joint-height",
        "deck-source", "deck-ih", "deck-negative-latency", "tof-phase-beyond-period",
        "missing-detector-model", "corrupt-detector-model", "meshcat-port-beyond-65535", "meshcat-port-below-1024",
        "meshcat-port-negative", "zero-propeller-radius"])
def test_bad_input_gives_one_line_and_exit_2_and_writes_nothing(capfd, tmp_path, bad_config, args, named):
    out = tmp_path / "new" / "out"  # two folders to make: a build's error removes both
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(b"\x08\x07not a network")
    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes("description: a caf\u00e9 deck\n".encode("latin-1"))
    args = [a.format(bad_config=bad_config, missing=tmp_path / "missing.yaml", missing_model=tmp_path / "missing.onnx",
                     corrupt_model=corrupt, latin1_config=latin1) for a in args]
    code, stdout, stderr = run_main(capfd, *args, "--out", str(out), "--quiet")
    assert code == 2
    assert stderr.count("\n") == 1 and stderr.startswith("landing-sim: error: "), stderr
    assert named in stderr
    assert "Traceback" not in stderr and stdout == ""
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("args, named", [
    # refused while the diagram is built, after the video's recorder was added
    (["run", "ugv-hybrid", "--duration", "1", "--set", "estimation.source=detector", "--set",
      "hybrid.model_path={missing_model}"], "missing.onnx"),
    # refused after the simulation, whose video was already whole: too short a calibration flight
    (["run", "crhf-calibration", "--duration", "0.3", "--set", "tof.bias_m=-3"], "usable samples"),
], ids=["refused-while-built", "refused-after-simulating"])
def test_a_refused_run_with_video_leaves_the_folder_as_it_was(capfd, tmp_path, args, named):
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("an earlier run's")
    args = [a.format(missing_model=tmp_path / "missing.onnx") for a in args]
    code, stdout, stderr = run_main(capfd, *args, "--video", "--out", str(out), "--quiet")
    assert code == 2 and stderr.count("\n") == 1 and named in stderr, stderr
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]  # no video, no hidden partial one
    assert (out / "metrics.json").read_text() == "an earlier run's"


@pytest.mark.parametrize("exception", [KeyboardInterrupt(), RuntimeError("the integrator diverged")],
                         ids=["ctrl-c", "error"])
def test_a_run_that_fails_removes_what_it_wrote_and_the_folders_it_made(monkeypatch, tmp_path, exception):
    """runner.run, on any exception (Ctrl-C too): the files of a run's kinds that it wrote, new or replacing an
    earlier one, are removed; the files it did not touch stay as they were; the folders it made are removed."""
    import diagrams.stewart_run
    from diagrams.outputs import write_text

    def failing_run(scenario, ctx):
        write_text(ctx.out_dir / "pose_translation.png", "half a plot")
        write_json(ctx.out_dir / "metrics.json", {"seed": scenario.seed})  # replaces an earlier run's
        raise exception

    monkeypatch.setattr(diagrams.stewart_run, "run", failing_run)
    _, scenario = runner.load_scenario("stewart-hover")
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("an earlier run's")
    (out / "camera.mp4").write_text("an earlier run's video")
    with pytest.raises(type(exception)):
        runner.run("stewart-hover", scenario, out, runner.RunOptions(progress=False))
    assert {p.name: p.read_text() for p in out.iterdir()} == {"camera.mp4": "an earlier run's video"}
    with pytest.raises(type(exception)):
        runner.run("stewart-hover", scenario, tmp_path / "new" / "out", runner.RunOptions(progress=False))
    assert not (tmp_path / "new").exists()


def test_meshcat_takes_port_0_or_1024_to_65535():
    """make_meshcat refuses a port Meshcat does not take (1 to 1023, past 65535) before anything is served;
    without a scene to show or record it serves none."""
    for port in (1023, 65536):
        with pytest.raises(ConfigError, match=f"--meshcat-port must be 0 .* got {port}"):
            runner.make_meshcat(runner.RunOptions(meshcat_port=port))
    for port in (None, 0, 1024, 65535):
        assert runner.make_meshcat(runner.RunOptions(meshcat_port=port)) is None


def test_a_meshcat_port_in_use_gives_one_line_and_exit_2_and_writes_nothing(capfd, tmp_path):
    with socket.socket() as busy:
        busy.bind(("localhost", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, stdout, stderr = run_main(capfd, "run", "stewart-hover", "--duration", "0.1", "--record",
                                        "--meshcat-port", str(port), "--out", str(tmp_path / "out"), "--quiet")
    assert code == 2 and stdout == "" and not (tmp_path / "out").exists()
    assert stderr.count("\n") == 1 and f"Meshcat cannot listen on localhost:{port}" in stderr, stderr


def test_unwritable_output_directory_under_sys(capfd):
    assert not SYS_OUT.parent.exists()
    code, stdout, stderr = run_main(capfd, "run", "stewart-hover", "--duration", "0.5", "--out", str(SYS_OUT),
                                    "--quiet")
    assert code == 2
    assert stderr.count("\n") == 1 and str(SYS_OUT) in stderr and "cannot write" in stderr, stderr
    assert "Traceback" not in stderr and stdout == ""
    assert not SYS_OUT.parent.exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a mode 0500 directory; the /sys test covers root")
def test_unwritable_output_directory_by_mode(capfd, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        code, stdout, stderr = run_main(capfd, "run", "stewart-hover", "--duration", "0.5", "--out",
                                        str(locked / "out"), "--quiet")
        assert code == 2
        assert stderr.count("\n") == 1 and "cannot write" in stderr and "Traceback" not in stderr, stderr
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)


def test_output_path_that_is_a_file(capfd, tmp_path):
    path = tmp_path / "a_file"
    path.write_text("x")
    code, _, stderr = run_main(capfd, "run", "stewart-hover", "--duration", "0.5", "--out", str(path), "--quiet")
    assert code == 2 and stderr.count("\n") == 1 and "not a directory" in stderr
    assert path.read_text() == "x"


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """`landing-sim run stewart-hover --duration 0.5 --out <tmp>/nested/hover --quiet --video`, in-process."""
    out = tmp_path_factory.mktemp("run") / "nested" / "hover"  # parents are created
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["run", "stewart-hover", "--duration", "0.5", "--out", str(out), "--quiet", "--video"])
    return code, out, stdout.getvalue(), stderr.getvalue()


def test_a_short_run_succeeds_and_says_where_its_results_are(short_run):
    code, out, stdout, stderr = short_run
    assert code == 0, stderr
    assert stdout.count("\n") == 1 and stdout.startswith("stewart-hover:") and str(out) in stdout
    assert stderr == ""


def test_a_short_run_writes_metrics_log_and_plots(short_run):
    code, out, _, _ = short_run
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("scenario", "seed", "sim_time_s", "wall_time_s", "realtime_factor"):
        assert key in metrics
    assert metrics["scenario"] == "stewart-hover" and metrics["seed"] == 0 and metrics["sim_time_s"] == 0.5
    assert metrics["wall_time_s"] > 0
    assert metrics["realtime_factor"] == pytest.approx(metrics["sim_time_s"] / metrics["wall_time_s"])
    with np.load(out / "log.npz") as log:
        np.testing.assert_allclose(log["t"], np.arange(11) * 0.05, atol=1e-9)
        assert log["tag_corners"].shape == (11, 8) and np.all(np.isfinite(log["tag_corners"]))
    plots = sorted(out.glob("*.png"))
    assert len(plots) >= 1
    for plot in plots:
        image = cv2.imread(str(plot))
        assert image is not None and image.shape[0] > 100 and image.std() > 5, plot.name


def _no_nan(constant):
    raise ValueError(f"metrics.json holds {constant}: not strict JSON")


@pytest.mark.slow  # renders
@pytest.mark.parametrize("name", scenario_names())
def test_every_shipped_scenario_runs_briefly_and_writes_its_metrics_log_plots_and_recording(tmp_path, name):
    """`landing-sim run NAME --record` for every scenario in scenarios/, a fraction of a second (gv-marker-ekf past
    its 2 s settling, before which nothing is scored), seed 3: exit 0, metrics.json strict JSON naming the
    scenario, the seed and the time flown, log.npz's clock within it, every plot an image with something drawn,
    and the scene's Meshcat recording (its viewers wired) written."""
    duration = 2.1 if name == "gv-marker-ekf" else 0.2
    out = tmp_path / "out"
    assert main(["run", name, "--duration", str(duration), "--seed", "3", "--record", "--out", str(out),
                 "--quiet"]) == 0
    assert (out / "meshcat.html").stat().st_size > 100_000
    metrics = json.loads((out / "metrics.json").read_text(), parse_constant=_no_nan)
    assert (metrics["scenario"], metrics["seed"], metrics["sim_time_s"]) == (name, 3, pytest.approx(duration))
    with np.load(out / "log.npz") as log:
        assert log["t"][0] >= 0.0 and log["t"][-1] <= duration + 1e-9
    plots = sorted(out.glob("*.png"))
    assert plots
    for plot in plots:
        image = cv2.imread(str(plot))
        assert image is not None and image.shape[0] > 100 and image.std() > 5, plot.name


def test_a_short_run_leaves_no_partial_files(short_run):
    _, out, _, _ = short_run
    names = [p.name for p in out.rglob("*")]  # pathlib's glob includes hidden names
    assert names and not [n for n in names if "partial" in n or n.startswith(".landing-sim-probe")], names


def test_video_has_one_frame_per_camera_sample(short_run):
    _, out, _, _ = short_run
    video = cv2.VideoCapture(str(out / "camera.mp4"))
    try:
        assert video.isOpened()
        frames = []
        while True:
            ok, frame = video.read()
            if not ok:
                break
            frames.append(frame)
    finally:
        video.release()
    assert len(frames) == 11
    assert frames[0].shape == (512, 512, 3)
    assert np.std(frames[-1]) > 20  # the tag is in view, not a blank frame


def test_a_run_into_an_earlier_runs_directory_names_what_it_did_not_write(tmp_path, capfd):
    out = tmp_path / "run"
    assert main(["run", "stewart-hover", "--duration", "0.05", "--seed", "1", "--record", "--quiet",
                 "--out", str(out)]) == 0
    assert "did not write" not in capfd.readouterr().err
    (out / "comparison.png").write_bytes(b"the user's own")
    assert main(["run", "stewart-hover", "--duration", "0.02", "--seed", "2", "--quiet", "--out", str(out)]) == 0
    lines = [line for line in capfd.readouterr().err.splitlines() if "did not write" in line]
    assert len(lines) == 1 and lines[0].endswith(": comparison.png, meshcat.html")  # the seed-1 recording
    assert json.loads((out / "metrics.json").read_text())["seed"] == 2
    assert (out / "meshcat.html").exists() and (out / "comparison.png").read_bytes() == b"the user's own"


# ---- what every file is written with (diagrams/outputs.py) ----

def _refusing_constants(name):
    raise ValueError(f"{name} is no JSON number")


def test_write_json_writes_every_non_finite_number_as_null(tmp_path):
    """Python's, numpy's, in arrays, lists and tuples, at any depth: json.dumps(allow_nan=False) would raise on each."""
    nan, inf = float("nan"), float("inf")
    write_json(tmp_path / "a.json", {"inf": inf, "ninf": np.float64(-inf), "f32": np.float32(nan),
                                     "ok": np.float64(2.5), "arr": np.array([nan, 1.0]),
                                     "grid": np.array([[inf, 0.5], [1.5, -inf]]), "tup": (nan, 2.0),
                                     "nested": [{"x": (inf, [nan])}], "n": 3, "s": "nan"})
    data = json.loads((tmp_path / "a.json").read_text(), parse_constant=_refusing_constants)  # strict JSON
    assert data == {"inf": None, "ninf": None, "f32": None, "ok": 2.5, "arr": [None, 1.0],
                    "grid": [[None, 0.5], [1.5, None]], "tup": [None, 2.0], "nested": [{"x": [None, [None]]}], "n": 3,
                    "s": "nan"}


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077], ids=["022", "002", "077"])
def test_a_written_file_gets_the_mode_the_umask_gives_not_mkstemps_0600(tmp_path, umask):
    """As open() would create it: 0o666 less the umask (the temporary file it is renamed from is 0600)."""
    previous = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {})
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o666 & ~umask


def test_writing_a_file_never_sets_the_umask_not_even_for_a_moment(tmp_path, monkeypatch):
    """The umask is read, not set to 0 and back: meanwhile another thread's new file would get mode 0666."""
    def no_setting(mask):
        raise AssertionError(f"os.umask({mask:#o}) called while writing")

    set_umask = os.umask
    previous = set_umask(0o027)
    try:
        monkeypatch.setattr(os, "umask", no_setting)
        write_json(tmp_path / "a.json", {})
    finally:
        set_umask(previous)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o640


def test_a_figures_file_in_a_folder_that_cannot_be_written_is_refused_at_argument_time(tmp_path):
    """output_file (a benchmark's --json) probes the file's folder: /sys exists but nothing can be created in it,
    even by root, so the mistake is an argument error before the work, not a failed write after it."""
    assert Path("/sys").is_dir()
    with pytest.raises(argparse.ArgumentTypeError, match="cannot write"):
        output_file("/sys/landing-sim-figures.json")
    assert output_file(str(tmp_path / "figures.json")) == tmp_path / "figures.json"


def test_a_file_is_written_beside_its_target_and_renamed_into_place(tmp_path, monkeypatch):
    """The partial file lives in the target's folder (not the system's temporary one), so the rename that puts it
    in place is atomic (one file system)."""
    renamed, replace = [], os.replace

    def recording(source, target):
        renamed.append((Path(source), Path(target)))
        replace(source, target)

    monkeypatch.setattr(os, "replace", recording)
    write_json(tmp_path / "a.json", {"n": 1})
    [(source, target)] = renamed
    assert target == tmp_path / "a.json" and source.parent == tmp_path and source.name.endswith(".partial")
    assert json.loads(target.read_text()) == {"n": 1}


@pytest.mark.parametrize("exception", [KeyboardInterrupt(), RuntimeError("disk full")], ids=["ctrl-c", "error"])
def test_a_write_that_fails_raises_and_leaves_no_partial_file(tmp_path, monkeypatch, exception):
    """Any exception (Ctrl-C too) while the file is put in place is raised, and the partial file is removed."""
    monkeypatch.setattr(os, "replace", _raising(exception))
    with pytest.raises(type(exception)):
        write_json(tmp_path / "a.json", {"n": 1})
    assert list(tmp_path.iterdir()) == []


def test_write_json_writes_numpy_scalars_as_their_python_values_and_ends_with_a_newline(tmp_path):
    """An integer stays an integer (not 3.0), a bool a JSON bool (not 1.0); the text ends with a newline."""
    write_json(tmp_path / "a.json", {"n": np.int64(3), "b": np.bool_(True)})
    assert (tmp_path / "a.json").read_text() == '{\n  "n": 3,\n  "b": true\n}\n'


def test_save_figure_writes_a_png_and_closes_the_figure(tmp_path):
    fig = plt.figure()
    save_figure(fig, tmp_path / "a.png")
    assert not plt.fignum_exists(fig.number)
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---- exit statuses past bad input: Ctrl-C, an internal error ----

def _raising(exception):
    def run(*args, **kwargs):
        raise exception
    return run


def test_ctrl_c_during_a_run_is_one_line_and_exit_130(monkeypatch, capfd, tmp_path):
    """128 + SIGINT, as a shell reports a command that Ctrl-C ended; no traceback."""
    monkeypatch.setattr(runner, "run", _raising(KeyboardInterrupt()))
    code, stdout, stderr = run_main(capfd, "run", "stewart-hover", "--out", str(tmp_path / "out"), "--quiet")
    assert code == 128 + signal.SIGINT == 130
    assert stderr == "landing-sim: interrupted\n" and stdout == ""


def test_an_internal_error_is_one_line_and_exit_1_and_with_debug_its_traceback(monkeypatch, capfd, tmp_path):
    """Without --debug one line that says how to see more; with --debug the exception itself, for its traceback."""
    monkeypatch.setattr(runner, "run", _raising(RuntimeError("the integrator diverged")))
    args = ["run", "stewart-hover", "--out", str(tmp_path / "out"), "--quiet"]
    code, _, stderr = run_main(capfd, *args)
    assert code == 1 and stderr == ("landing-sim: internal error: RuntimeError: the integrator diverged "
                                    "(run with --debug for the traceback)\n")
    with pytest.raises(RuntimeError, match="the integrator diverged"):
        main(["--debug", *args])


# ---- what the command and runner.simulate_scene pass on (runner.run and simulate faked) ----

def _fake_run(calls: list):
    """runner.run noting the scenario name and output folder it gets, with the metrics of a run."""
    def run(name, scenario, out_dir, options):
        calls.append((name, out_dir))
        return {"sim_time_s": 0.0, "wall_time_s": 1.0, "realtime_factor": 0.0}
    return run


def test_run_without_a_name_runs_the_default_scenario_into_results(monkeypatch, capfd, tmp_path):
    calls = []
    monkeypatch.setattr(runner, "run", _fake_run(calls))
    monkeypatch.chdir(tmp_path)
    code, _, stderr = run_main(capfd, "run", "--quiet")
    assert code == 0, stderr
    assert calls == [(DEFAULT_SCENARIO, f"results/{DEFAULT_SCENARIO}")]


def test_meshcat_does_not_wait_for_enter_when_stdin_is_no_terminal(monkeypatch, capfd, tmp_path):
    """With stdin not a terminal (a pipe, /dev/null, a batch job) a --meshcat run ends when it is done instead
    of asking for Enter (input() would meet end-of-file at once)."""
    calls = []
    monkeypatch.setattr(runner, "run", _fake_run(calls))
    monkeypatch.setattr(sys, "stdin", io.StringIO())
    code, stdout, stderr = run_main(capfd, "run", "stewart-hover", "--meshcat", "--quiet", "--out", str(tmp_path / "o"))
    assert code == 0, stderr
    assert calls == [("stewart-hover", str(tmp_path / "o"))]
    assert "press Enter" not in stdout


def test_no_command_is_a_usage_error_naming_it(capfd):
    code, stdout, stderr = run_main(capfd)
    assert code == 2 and stdout == ""
    assert stderr == "landing-sim: error: the following arguments are required: command\n"


@pytest.mark.parametrize("record, meshcat", [(True, False), (False, True)], ids=["record", "meshcat"])
def test_simulate_scene_records_on_record_paces_on_meshcat_and_reports_the_simulated_time(monkeypatch, record,
                                                                                          meshcat):
    """simulate gets `record` from --record and real-time pacing from --meshcat alone; the metrics carry the time
    simulated (0.3 s of a 2 s scenario: a run ended early) and its ratio to the wall time."""
    calls = []

    def fake_simulate(diagram, duration_s, **kwargs):
        calls.append((diagram, duration_s, kwargs))
        return Simulation("landed: touchdown", 0.3, 0.6, "final context", 0.5)

    monkeypatch.setattr(runner, "simulate", fake_simulate)
    handles = SimpleNamespace(meshcat_visualizer="visualizer", video="video")
    scenario = SimpleNamespace(duration_s=2.0, seed=7)
    ctx = runner.RunContext("a-scene", Path("out"), runner.RunOptions(meshcat=meshcat, record=record,
                                                                      progress=False), None)
    metrics, context = runner.simulate_scene("diagram", handles, scenario, ctx)
    ((diagram, duration_s, kwargs),) = calls
    assert (diagram, duration_s) == ("diagram", 2.0)
    assert kwargs == {"realtime": meshcat, "progress": False, "visualizer": "visualizer", "record": record,
                      "video": "video"}
    assert metrics == {"scenario": "a-scene", "seed": 7, "sim_time_s": 0.3, "wall_time_s": 0.6,
                       "realtime_factor": pytest.approx(0.3 / 0.6)}
    assert context == "final context"
