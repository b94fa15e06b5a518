"""Real-time factor of the stewart-dynamic scene (camera, four ToF sensors and tag detection at
20 Hz, IMU at 200 Hz), with a per-frame breakdown of where the time goes.

    .venv/bin/python benchmarks/realtime.py [--duration 60] [--scenario stewart-dynamic] [--out FILE]

The breakdown times each stage on its own at the camera's frame times: render (512x512 colour), the
camera's processing of it (lens, blur and pixel noise), ToF (the sensors' one shared depth render and
their readings), tag detection; "rest" is the simulation's wall time per frame minus those (logging,
IMU, events, Python overhead). `--out` writes the figures as JSON too (`render_ms`, `per_frame_ms`,
their ratio, the real-time factor and the stages), beside the printout.
"""

import argparse
import time
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator

from diagrams.outputs import write_json
from diagrams.runner import load_scenario
from diagrams.stewart_scene import build_stewart_scene
from systems.sensors.camera import image_to_numpy


def stage_times_ms(diagram, handles, period_s: float, frames: int) -> dict[str, float]:
    """Median milliseconds per frame of each stage, evaluated at successive frame times: the render, the
    camera's own processing of it (lens, blur, noise: `NoisyCamera` on the cached render), the ToF
    sensors' shared depth render and readings, and tag detection."""
    context = diagram.CreateDefaultContext()
    camera_context = handles.camera.GetMyContextFromRoot(context)
    noisy_context = handles.noisy_camera.GetMyContextFromRoot(context)
    tof_context = handles.tof.GetMyContextFromRoot(context)
    times = {"render": [], "noise": [], "tof": [], "detection": []}
    handles.camera.color_image_output_port().Eval(camera_context)  # the first render sets VTK up
    for k in range(1, frames + 1):
        context.SetTime(k * period_s)
        t0 = time.perf_counter()
        handles.camera.color_image_output_port().Eval(camera_context)
        t1 = time.perf_counter()
        noisy = image_to_numpy(handles.color_image.Eval(noisy_context))
        t2 = time.perf_counter()
        handles.tof.GetOutputPort("ranges").Eval(tof_context)
        t3 = time.perf_counter()
        handles.detector._detector.detect(noisy)
        t4 = time.perf_counter()
        for name, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            times[name].append(dt * 1e3)
    return {name: float(np.median(v)) for name, v in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default 60)")
    parser.add_argument("--scenario", default="stewart-dynamic", help="a Stewart scene (default stewart-dynamic)")
    parser.add_argument("--out", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args()

    _, scenario = load_scenario(args.scenario, duration_s=args.duration)
    diagram, handles = build_stewart_scene(scenario)
    simulator = Simulator(diagram)
    simulator.Initialize()
    simulator.AdvanceTo(scenario.camera.period_s)  # exclude VTK's one-off set-up from the timing
    start = time.perf_counter()
    simulator.AdvanceTo(args.duration)
    wall = time.perf_counter() - start
    simulated = args.duration - scenario.camera.period_s
    frames = round(simulated * scenario.camera.rate_hz)

    stages = stage_times_ms(diagram, handles, scenario.camera.period_s, frames=100)
    per_frame = wall / frames * 1e3
    print(f"{args.scenario}, {simulated:.1f} s simulated in {wall:.1f} s: real-time factor {simulated / wall:.2f}")
    print(f"per frame ({frames} frames at {scenario.camera.rate_hz:g} Hz): {per_frame:.1f} ms, "
          f"{per_frame / stages['render']:.2f}x the render")
    for name, ms in stages.items():
        print(f"  {name:10s} {ms:6.1f} ms")
    print(f"  {'rest':10s} {per_frame - sum(stages.values()):6.1f} ms (logging, IMU, events)")
    if args.out is not None:
        write_json(args.out, {"scenario": args.scenario, "simulated_s": simulated, "wall_s": wall,
                              "realtime_factor": simulated / wall, "frames": frames, "render_ms": stages["render"],
                              "per_frame_ms": per_frame, "per_frame_over_render": per_frame / stages["render"],
                              "stages_ms": {**stages, "rest": per_frame - sum(stages.values())}})


if __name__ == "__main__":
    main()
