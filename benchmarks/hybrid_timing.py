"""Seed 003's Table 7 on our pipeline: CPU time per module per 10 Hz fisheye frame (issue 12).

    .venv/bin/python benchmarks/hybrid_timing.py [--frames 40] [--low-frames N] [--repeats 3] [--json FILE]

1. Records real frames of the loop: the ugv-hybrid diagram (learned detector) hovering at IH = 7.5 m over
   the UGV (start.xy_m=[0.5, 0.3], as tests/test_hybrid_landing.py's hover flight), and `--low-frames` of them
   (default a quarter) from a second flight starting at 3 m, simulated in 0.1 s steps. After each step the
   frame's five fisheye faces, the fisheye image, its rectified view and both stereo eyes are read from the
   simulator's context, the faces and eyes rendered afresh and timed (the simulator's cost, reported apart,
   as process CPU time and wall time: VTK renders on its GL driver's threads). The loop's own calls of the
   small steps (altitude filter, hybrid estimate with the UAV's navigation X_WB, stereo pad fix, the velocity
   observer inside the hybrid estimate, PID, supervisor) are recorded with their arguments while it flies
   (the re-render makes the loop take its frame's steps twice, with the same arguments: duplicates, same
   times).
2. Times each module on those frames, `--repeats` times each (the median of the repeats is the frame's
   figure), as CPU time of the calling thread (time.thread_time) with OpenCV on one thread
   (cv2.setNumThreads(1)): the machine is shared with other jobs, so wall time would measure them too.
   Per-frame modules: fisheye correction (rectify; the composition of the five faces, our simulated lens, on
   its own row), stereo matching, detection (learned CNN and classical colour pads, each), tracking
   (each detector's detections through the tracker, in order), motion compensation (ORB + RANSAC homography
   on the rectified view, the UGV's box excluded). Recorded calls, replayed: the altitude filter, the hybrid
   estimate (its velocity observer included, and also timed alone), the stereo eye's pad fix (ArUco), PID and
   supervisor; control per frame at the loop's rates (PID at pid.rate_hz, supervisor at landing.rate_hz, per
   0.1 s frame).
3. Prints a table beside the paper's Table 7 (Jetson TX2, its nodes in parallel: total = slowest thread);
   ours is one core, the modules in series: whole pipeline per frame = the sum, with either detector.
No assertion on time anywhere (tests/test_hybrid_timing.py only checks the entries exist).
"""

import argparse
import copy
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

import systems.control.landing as landing_module
import systems.control.pid as pid_module
import systems.estimators.altitude_kf as altitude_kf_module
import systems.perception.hybrid_pad as hybrid_module
from diagrams.gv_landing import build_gv_landing
from diagrams.outputs import output_file, write_json
from diagrams.runner import load_scenario
from systems.perception.aruco import to_grey
from systems.perception.box_tracker import Detection, TrackerState, step_tracker, target_box
from systems.perception.motion_compensation import (
    MotionCompensationConfig,
    compensate_frames,
    make_detector,
    make_frame,
    make_matcher,
)
from systems.perception.ugv_detector import ColourPadDetector
from systems.sensors.fisheye import FACE_NAMES, rectified_K, rectify, rectify_maps

# Seed 003 Table 7 (NVIDIA Jetson TX2, ms: mean, standard deviation; the five ROS nodes run in parallel).
PAPER_TABLE7 = {"fisheye_correction": (6.15, 1.97), "stereo": (23.77, 2.66), "detection": (51.24, 55.69),
                "tracking": (1.51, 0.86), "motion_compensation": (105.71, 0.03), "control": (0.34, 0.07),
                "total": (110.08, 0.03)}
TARGET_MS = 25.0  # issue 12: the whole pipeline per frame on one core here
STEP_S = 0.1  # the fisheye's period
HOVER = ("start.xy_m=[0.5, 0.3]",)  # over the UGV's start (tests/test_hybrid_landing.py's _hover_flight)
RECORDED = ("altitude_filter", "hybrid_estimate", "stereo_pad_fix", "velocity_observer", "pid", "supervisor")


def cpu_ms(repeats: int, fn: Callable, *args, **kwargs) -> float:
    """The median over `repeats` calls of fn(*args, **kwargs)'s CPU time on this thread [ms]."""
    samples = []
    for _ in range(repeats):
        t0 = time.thread_time()
        fn(*args, **kwargs)
        samples.append(time.thread_time() - t0)
    return 1000.0 * float(np.median(samples))


def stats(values) -> dict:
    v = np.asarray(values, dtype=float)
    return {"median_ms": float(np.median(v)), "p90_ms": float(np.percentile(v, 90)), "mean_ms": float(v.mean()),
            "n": int(v.size)}


@dataclass
class Frame:
    flight: str  # "7.5 m" or "3 m": the flight's start height
    t: float
    fisheye: np.ndarray  # raw fisheye RGBA (512 x 512)
    rectified: np.ndarray  # the FisheyeCamera's rectified view
    faces: list[np.ndarray]  # the five face renders, FACE_NAMES' order
    left: np.ndarray  # stereo eyes RGBA (752 x 480), noise included
    right: np.ndarray


@dataclass
class Recording:
    frames: list[Frame] = field(default_factory=list)
    calls: dict[str, list[tuple]] = field(default_factory=lambda: {name: [] for name in RECORDED})
    render_cpu_ms: dict[str, list[float]] = field(default_factory=dict)  # the process's CPU time (all threads)
    render_wall_ms: dict[str, list[float]] = field(default_factory=dict)
    layout: object = None  # the fisheye's FisheyeLayout
    altimeter: object = None  # the loop's StereoAltitudeEstimator
    config: object = None  # the scenario (the first flight's)
    pid_inputs: str = "recorded"  # "synthetic" when the loop never stepped its PID (the target not yet seen)


def _copied(args, kwargs):
    try:
        return copy.deepcopy((args, kwargs))
    except TypeError:  # not deep-copyable: the arguments as they are (the steps are pure)
        return args, kwargs


@contextmanager
def recording_calls(calls: dict[str, list], finder, flight: str):
    """Wraps the loop's small steps so each call's arguments are kept (the modules' globals the systems
    look up at call time; the stereo pad finder's `find` on the instance)."""
    targets = [(altitude_kf_module, "altitude_kf_step", "altitude_filter"),
               (hybrid_module, "hybrid_step", "hybrid_estimate"),
               (hybrid_module, "step_observer", "velocity_observer"),
               (pid_module, "pid_step", "pid"), (landing_module, "supervisor_step", "supervisor")]
    originals = [(module, attr, getattr(module, attr)) for module, attr, _ in targets]

    def wrap(fn, name):
        def recorder(*args, **kwargs):
            calls[name].append((fn, *_copied(args, kwargs), flight))
            return fn(*args, **kwargs)
        return recorder

    for (module, attr, name), (_, _, fn) in zip(targets, originals):
        setattr(module, attr, wrap(fn, name))
    if finder is not None:
        finder.find = wrap(finder.find, "stereo_pad_fix")
    try:
        yield
    finally:
        for module, attr, fn in originals:
            setattr(module, attr, fn)
        if finder is not None:
            del finder.find


def _timed_eval(port, context, record: Recording, name: str):
    """Evaluates `port`, timing it by the process's CPU time (VTK renders on its GL driver's threads, which the
    calling thread's CPU time misses) and by wall time."""
    t0, w0 = time.process_time(), time.perf_counter()
    value = port.Eval(context)
    record.render_cpu_ms.setdefault(name, []).append(1000.0 * (time.process_time() - t0))
    record.render_wall_ms.setdefault(name, []).append(1000.0 * (time.perf_counter() - w0))
    return value


def record_flight(record: Recording, overrides: list[str], frames: int, flight: str) -> None:
    """`frames` frames (0.1 s steps from t = 0.1 s) of one ugv-hybrid flight into `record`."""
    _, scenario = load_scenario("ugv-hybrid", overrides=overrides)
    diagram, handles = build_gv_landing(scenario)
    get = diagram.GetSubsystemByName
    fisheye, left, right = get("fisheye"), get("stereo_left"), get("stereo_right")
    sensors = [get(f"fisheye_{name}_sensor") for name in FACE_NAMES]
    eye_sensors = [get("stereo_left_sensor"), get("stereo_right_sensor")]
    finder = get("stereo_pad") if diagram.HasSubsystemNamed("stereo_pad") else None
    if record.config is None:
        record.layout, record.altimeter, record.config = fisheye.layout, get("stereo_altimeter").estimator, scenario
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    handles.initialize(context)
    integration = scenario.integration
    if not integration.discrete:
        ApplySimulatorConfig(integration.simulator_config(), simulator)
    with recording_calls(record.calls, finder, flight):
        simulator.Initialize()
        for k in range(1, frames + 1):
            simulator.AdvanceTo(k * STEP_S)
            # The loop has rendered this frame already (its loggers publish at the frame's time): the same time
            # set again marks the cached renders out of date, so they render afresh (the same images) and are
            # timed. Not a second context: rendering one disturbs the simulator's VTK renders (measured).
            context.SetTime(context.get_time())
            faces = []
            for name, sensor in zip(FACE_NAMES, sensors):
                image = _timed_eval(sensor.color_image_output_port(), sensor.GetMyContextFromRoot(context), record,
                                    "fisheye_faces")
                faces.append(np.array(image.data))
            eyes = []
            for sensor, noisy in zip(eye_sensors, (left, right)):
                _timed_eval(sensor.color_image_output_port(), sensor.GetMyContextFromRoot(context), record,
                            "stereo_eye_render")
                eyes.append(np.array(_timed_eval(noisy.get_output_port(), noisy.GetMyContextFromRoot(context), record,
                                                 "stereo_eye_noise").data))
            camera_context = fisheye.GetMyContextFromRoot(context)
            raw = np.array(fisheye.GetOutputPort("color_image").Eval(camera_context).data)
            rectified = np.array(fisheye.GetOutputPort("rectified_image").Eval(camera_context).data)
            record.frames.append(Frame(flight, context.get_time(), raw, rectified, faces, *eyes))
    # Per frame: the faces' and eyes' samples summed within each frame.
    for name, per in (("fisheye_faces", len(sensors)), ("stereo_eye_render", 2), ("stereo_eye_noise", 2)):
        for table in (record.render_cpu_ms, record.render_wall_ms):
            values = table[name]
            head, tail = values[:-frames * per], values[-frames * per:]
            table[name] = head + list(np.add.reduceat(tail, np.arange(0, len(tail), per)))


def box_in_rectified(box: np.ndarray, fisheye_config, K_rect: np.ndarray) -> np.ndarray | None:
    """The raw fisheye box [x, y, w, h] as the bounding box of its corners in the rectified view."""
    if not np.all(np.isfinite(box)):
        return None
    x, y, w, h = box
    corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], dtype=float).reshape(-1, 1, 2)
    uv = cv2.fisheye.undistortPoints(corners, fisheye_config.K, fisheye_config.D, P=K_rect).reshape(-1, 2)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    return np.array([lo[0], lo[1], *(hi - lo)])


def track_step(state: TrackerState, found, image: np.ndarray, t: float, config) -> TrackerState:
    """The loop's DetectionsToTracker and BoxTrackerSystem step on one frame's detections."""
    return step_tracker(state, [Detection(np.asarray(box, float), float(score)) for box, score in found], image, t,
                        config)


def motion_step(rectified: np.ndarray, box, previous, config, detector, matcher):
    """The compensator's step: this frame's features (the box excluded), then the match with the previous."""
    frame = make_frame(to_grey(rectified), box, detector, config)
    return frame, (None if previous is None else compensate_frames(previous, frame, config, matcher))


def time_modules(record: Recording, repeats: int) -> dict[str, list[float]]:
    """Per-frame CPU ms of the frame modules (one entry a frame) and per-call ms of the recorded steps."""
    hybrid = record.config.hybrid
    fe = hybrid.fisheye
    maps = rectify_maps(fe)
    detectors = {"learned": hybrid.make_detector(), "classical": ColourPadDetector(hybrid.classical)}
    mc_config = MotionCompensationConfig()
    mc_detector, mc_matcher = make_detector(mc_config), make_matcher(mc_config)
    K_rect = rectified_K(fe)
    out = {name: [] for name in ("fisheye_rectify", "fisheye_compose", "stereo_match", "detection_learned",
                                 "detection_classical", "tracking_learned", "tracking_classical",
                                 "motion_compensation")}
    trackers = {name: TrackerState() for name in detectors}
    previous, previous_t = None, None
    for f in record.frames:
        if previous_t is not None and abs(f.t - previous_t - STEP_S) > 1e-6:  # the next flight's first frame
            previous, trackers = None, {name: TrackerState() for name in detectors}
        out["fisheye_rectify"].append(cpu_ms(repeats, rectify, f.fisheye, maps))
        out["fisheye_compose"].append(cpu_ms(repeats, record.layout.compose, f.faces))
        out["stereo_match"].append(cpu_ms(repeats, record.altimeter.estimate, f.left, f.right))
        for name, detector in detectors.items():
            out[f"detection_{name}"].append(cpu_ms(repeats, detector.detect, f.fisheye))
            found = detector.detect(f.fisheye)
            args = (trackers[name], found, f.fisheye, f.t, hybrid.tracker)
            out[f"tracking_{name}"].append(cpu_ms(repeats, track_step, *args))
            trackers[name] = track_step(*args)
        box = box_in_rectified(target_box(trackers["learned"])[0], fe, K_rect)
        args = (f.rectified, box, previous, mc_config, mc_detector, mc_matcher)
        out["motion_compensation"].append(cpu_ms(repeats, motion_step, *args))
        previous = motion_step(*args)[0]
        previous_t = f.t
    if not record.calls["pid"]:  # the loop steps the PID only while the target is seen: none in so short a run
        record.pid_inputs = "synthetic"
        memory, flight = pid_module.initial_memory(), record.frames[0].flight
        record.calls["pid"] = [(pid_module.pid_step, (memory, np.array([0.3, -0.2]), 7.0, record.config.pid), {},
                                flight)]
    for name in RECORDED:
        out[name] = [cpu_ms(repeats, fn, *args, **kwargs) for fn, args, kwargs, _ in record.calls[name]]
    return out


def summarise(times: dict[str, list[float]], record: Recording) -> dict:
    """The table: per module median / p90 [ms CPU per frame], the whole pipeline per detector."""
    config = record.config
    per_frame_pid = config.pid.rate_hz * STEP_S
    per_frame_supervisor = config.landing.rate_hz * STEP_S
    medians = {name: float(np.median(v)) for name, v in times.items() if len(v)}
    n = len(record.frames)
    frame_modules = {"fisheye_correction": np.array(times["fisheye_rectify"]),
                     "stereo": np.array(times["stereo_match"]) + medians["altitude_filter"],
                     "tracking_learned": np.array(times["tracking_learned"]),
                     "tracking_classical": np.array(times["tracking_classical"]),
                     "detection_learned": np.array(times["detection_learned"]),
                     "detection_classical": np.array(times["detection_classical"]),
                     "motion_compensation": np.array(times["motion_compensation"])}
    estimate = medians["hybrid_estimate"] + medians.get("stereo_pad_fix", 0.0)  # the observer is the estimate's
    control = medians["pid"] * per_frame_pid + medians["supervisor"] * per_frame_supervisor
    rows = {"fisheye_correction": stats(frame_modules["fisheye_correction"]),
            "fisheye_composition": stats(times["fisheye_compose"]),
            "stereo": stats(frame_modules["stereo"]),
            "stereo_match": stats(times["stereo_match"]), "altitude_filter": stats(times["altitude_filter"]),
            "detection_learned": stats(times["detection_learned"]),
            "detection_classical": stats(times["detection_classical"]),
            "tracking_learned": stats(times["tracking_learned"]),
            "tracking_classical": stats(times["tracking_classical"]),
            "motion_compensation": stats(times["motion_compensation"]),
            "estimate": {"median_ms": estimate}, "hybrid_estimate": stats(times["hybrid_estimate"]),
            "velocity_observer": stats(times["velocity_observer"]),
            "control": {"median_ms": control, "pid_per_frame": per_frame_pid,
                        "supervisor_per_frame": per_frame_supervisor},
            "pid": {**stats(times["pid"]), "inputs": record.pid_inputs}, "supervisor": stats(times["supervisor"])}
    if times["stereo_pad_fix"]:
        rows["stereo_pad_fix"] = stats(times["stereo_pad_fix"])
    totals = {}
    for detector in ("learned", "classical"):
        per_frame = (frame_modules["fisheye_correction"] + frame_modules["stereo"]
                     + frame_modules[f"detection_{detector}"] + frame_modules[f"tracking_{detector}"]
                     + frame_modules["motion_compensation"] + estimate + control)
        totals[detector] = {**stats(per_frame), "with_composition_median_ms":
                            float(np.median(per_frame + np.array(times["fisheye_compose"]))),
                            # our loop steers by the world-frame observer: no motion compensation in it
                            "without_motion_compensation_median_ms":
                            float(np.median(per_frame - frame_modules["motion_compensation"])),
                            "meets_target": bool(np.median(per_frame) < TARGET_MS)}
    flights = [f.flight for f in record.frames]
    by_flight = {}
    for name, values in times.items():
        # A recorded step by the flight of each of its calls (its count may equal the frames' by chance),
        # a per-frame module by its frame's.
        labels = [c[3] for c in record.calls[name]] if name in record.calls else flights
        if len(labels) == len(values) and values:
            by_flight[name] = {flight: float(np.median([v for v, fl in zip(values, labels) if fl == flight]))
                               for flight in dict.fromkeys(labels)}
    renders = {name: {"cpu_process": stats(record.render_cpu_ms[name]), "wall": stats(record.render_wall_ms[name])}
               for name in record.render_cpu_ms}
    return {"frames": n, "modules": rows, "median_ms_by_flight": by_flight, "whole_pipeline": totals, "target_ms": TARGET_MS,
            "renders_simulator": renders, "paper_table7_tx2_ms": PAPER_TABLE7,
            "timing": "CPU time of the calling thread (time.thread_time), cv2.setNumThreads(1); per frame the "
                      "median of the repeats; the machine shared with other jobs"}


def print_table(result: dict, repeats: int) -> None:
    m, totals, paper = result["modules"], result["whole_pipeline"], result["paper_table7_tx2_ms"]
    print(f"{result['frames']} frames, {repeats} repeats each; ms of CPU time on one thread per 10 Hz frame "
          "(OpenCV 1 thread; other jobs shared the machine)")
    print(f"{'module':<42}{'median':>8}{'p90':>8}   paper TX2 mean (sd)")

    def row(label, key, paper_key=None, indent=False):
        entry = m.get(key)
        if entry is None:
            return
        p90 = entry.get("p90_ms")
        ref = f"{paper[paper_key][0]:8.2f} ({paper[paper_key][1]:.2f})" if paper_key else ""
        print(f"{('  ' if indent else '') + label:<42}{entry['median_ms']:8.2f}"
              f"{'' if p90 is None else format(p90, '8.2f'):>8}   {ref}")
    row("fisheye correction (rectify)", "fisheye_correction", "fisheye_correction")
    row("fisheye composition (5 faces; sim. lens)", "fisheye_composition", indent=True)
    row("stereo depth (SGBM window + filter)", "stereo", "stereo")
    row("stereo matching", "stereo_match", indent=True)
    row("altitude filter (per call)", "altitude_filter", indent=True)
    row("detection, learned (CNN, cv2.dnn)", "detection_learned", "detection")
    row("detection, classical (colour pads)", "detection_classical")
    row("tracking (learned detections)", "tracking_learned", "tracking")
    row("tracking (classical detections)", "tracking_classical")
    row("motion compensation (ORB + RANSAC H)", "motion_compensation", "motion_compensation")
    row("estimate (hybrid + pad fix)", "estimate")
    row("hybrid estimate (per call)", "hybrid_estimate", indent=True)
    row("  its velocity observer (per call)", "velocity_observer", indent=True)
    row("stereo pad fix, ArUco (per call)", "stereo_pad_fix", indent=True)
    c = m["control"]
    print(f"{'control (PID + supervisor, loop rates)':<42}{c['median_ms']:8.3f}{'':>8}   "
          f"{paper['control'][0]:8.2f} ({paper['control'][1]:.2f})")
    row("PID (per call)", "pid", indent=True)
    row("supervisor (per call)", "supervisor", indent=True)
    for name, total in totals.items():
        met = "met" if total["meets_target"] else "NOT met"
        ref = f"{paper['total'][0]:8.2f} (max thread)" if name == "learned" else ""
        print(f"{'whole pipeline, ' + name + ' detector':<42}{total['median_ms']:8.2f}{total['p90_ms']:8.2f}   {ref}"
              f"  < {result['target_ms']:g} ms: {met}")
        print(f"{'':<4}with the composition {total['with_composition_median_ms']:.1f}; without motion compensation "
              f"(not in our loop) {total['without_motion_compensation_median_ms']:.1f}")
    for flight, ms in result["median_ms_by_flight"].get("stereo_pad_fix", {}).items():
        print(f"stereo pad fix median, flight from {flight}: {ms:.2f} ms")
    ratio = result.get("process_over_thread_cpu")
    if ratio is not None:
        print(f"process CPU / thread CPU while timing: {ratio:.3f} (1: no helper threads missed)")
    print("simulator's renders (not the pipeline's), per frame, median ms: process CPU (all threads) / wall")
    for name, r in result["renders_simulator"].items():
        print(f"  {name:<40}{r['cpu_process']['median_ms']:8.2f} / {r['wall']['median_ms']:.2f}")


def run(frames: int, low_frames: int, repeats: int, threads: int = 1) -> dict:
    cv2.setNumThreads(threads)
    record = Recording()
    high = frames - low_frames
    if high > 0:
        record_flight(record, [*HOVER, "start.height_m=7.5"], high, "7.5 m")
    if low_frames > 0:
        record_flight(record, [*HOVER, "start.height_m=3"], low_frames, "3 m")
    t0, p0 = time.thread_time(), time.process_time()
    times = time_modules(record, repeats)
    thread_s, process_s = time.thread_time() - t0, time.process_time() - p0
    result = summarise(times, record)
    # Near 1: the modules ran on this thread alone (no BLAS or OpenCV helper threads that thread_time misses).
    result["process_over_thread_cpu"] = process_s / thread_s if thread_s > 0 else None
    result.update({"repeats": repeats, "opencv_threads": threads, "flights": {"7.5 m": high, "3 m": low_frames}})
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames in all (10 Hz)")
    parser.add_argument("--low-frames", type=int, default=None, help="of them from a flight starting at 3 m "
                                                                      "(default a quarter)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=output_file)
    args = parser.parse_args(argv)
    for name in ("frames", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    low = args.frames // 4 if args.low_frames is None else args.low_frames
    if not 0 <= low <= args.frames:
        parser.error(f"--low-frames must lie in 0..{args.frames} (of the --frames), got {low}")
    result = run(args.frames, low, args.repeats)
    print_table(result, args.repeats)
    if args.json:
        write_json(args.json, result)


if __name__ == "__main__":
    main()
