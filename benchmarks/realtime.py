"""Real-time factor of the stewart-dynamic scene (camera, four ToF sensors and tag detection at
20 Hz, IMU at 200 Hz), with a per-frame breakdown of where the time goes.

    .venv/bin/python benchmarks/realtime.py [--duration 60] [--scenario stewart-dynamic] [--set KEY=VALUE]...
                                            [--out FILE]

The breakdown times each stage on its own at the camera's frame times: render (512x512 colour; wider by the
lens's reach where the scenario distorts, camera.render_margin_px: 528x528 in stewart-hardware), the
camera's processing of it (lens, blur and pixel noise), ToF (the rays cast on the scene, or the cones'
shared depth render, and the readings, times the readings per frame when they keep their own clock), tag
detection, 4 frames after each simulated second, so the render and the simulation are timed under the same
load; "rest" is the simulation's wall time per frame minus those (logging, IMU, events, Python overhead). `--out`
writes the figures as JSON too (`render_ms`, `per_frame_ms`, their ratio, the real-time factor, the stages and
`stage_frames`, the frames their medians are over), beside the printout. `--set` overrides a scenario field as
`landing-sim run` does (e.g. `estimators=[]` or `camera.pixel_noise_std=0.0`, to see what a part of the scene
costs).
"""

import argparse
import sys
import time

import numpy as np
from pydrake.systems.analysis import Simulator

from diagrams.outputs import output_file, write_json
from diagrams.runner import load_scenario
from diagrams.stewart_scene import StewartSceneConfig, build_stewart_scene
from systems.config import ConfigError
from systems.sensors.camera import image_to_numpy


class StageTimer:
    """Times each stage on its own at successive frame times, in a context of its own: the render, the
    camera's own processing of it (lens, blur, noise: `NoisyCamera` on the cached render), the ToF
    sensors' readings (their rays cast, or their cones' depth render), and tag detection. `sample`
    between stretches of the simulation keeps the two under the same machine load."""

    def __init__(self, diagram, handles, period_s: float):
        self._handles, self._period, self._k = handles, period_s, 0
        self._context = diagram.CreateDefaultContext()
        self._camera = handles.camera.GetMyContextFromRoot(self._context)
        self._noisy = handles.noisy_camera.GetMyContextFromRoot(self._context)
        self._tof = handles.tof.GetMyContextFromRoot(self._context)
        self.times = {"render": [], "noise": [], "tof": [], "detection": []}
        handles.camera.color_image_output_port().Eval(self._camera)  # the first render sets VTK up

    def sample(self, frames: int) -> None:
        h = self._handles
        for _ in range(frames):
            self._k += 1
            self._context.SetTime(self._k * self._period)
            t0 = time.perf_counter()
            h.camera.color_image_output_port().Eval(self._camera)
            t1 = time.perf_counter()
            noisy = image_to_numpy(h.color_image.Eval(self._noisy))
            t2 = time.perf_counter()
            h.tof.readings(self._tof)  # the rays (or the cones' depth render) and readings, whatever their clock
            t3 = time.perf_counter()
            h.detector._detector.detect(noisy)
            t4 = time.perf_counter()
            for name, dt in zip(self.times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                self.times[name].append(dt * 1e3)

    @property
    def frames(self) -> int:
        """The frames each stage has been timed on."""
        return self._k

    def medians_ms(self) -> dict[str, float]:
        """Median milliseconds per frame of each stage over every sample."""
        return {name: float(np.median(v)) for name, v in self.times.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default 60)")
    parser.add_argument("--scenario", default="stewart-dynamic", help="a Stewart scene (default stewart-dynamic)")
    parser.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append", default=[],
                        help="override a scenario field (repeatable), e.g. estimators=[]")
    parser.add_argument("--out", type=output_file, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)

    try:
        name, scenario = load_scenario(args.scenario, overrides=args.overrides, duration_s=args.duration)
    except ConfigError as e:
        print(f"realtime: {e}", file=sys.stderr)
        return 2
    if not isinstance(scenario, StewartSceneConfig):
        parser.exit(2, f"{name}: not a Stewart scene\n")
    # The first camera period is simulated before the timing (VTK's set-up); the figures are per timed frame.
    if args.duration < 2 * scenario.camera.period_s - 1e-9:
        parser.error(f"--duration must be at least {2 * scenario.camera.period_s:g} s (one {scenario.camera.rate_hz:g} "
                     f"Hz camera frame before the timing, one timed), got {args.duration:g}")
    diagram, handles = build_stewart_scene(scenario)
    simulator = Simulator(diagram)
    simulator.Initialize()
    simulator.AdvanceTo(scenario.camera.period_s)  # exclude VTK's one-off set-up from the timing
    timer = StageTimer(diagram, handles, scenario.camera.period_s)
    # One simulated second at a time, each followed by the stages timed on 4 frames: the ratio's two
    # sides measured under the same load (this machine's speed drifts by 30 % within minutes).
    wall, t = 0.0, scenario.camera.period_s
    while t < args.duration - 1e-9:
        t = min(t + 1.0, args.duration)
        start = time.perf_counter()
        simulator.AdvanceTo(t)
        wall += time.perf_counter() - start
        timer.sample(4)
    simulated = args.duration - scenario.camera.period_s
    frames = round(simulated * scenario.camera.rate_hz)

    stages = timer.medians_ms()
    # On their own clock the ToF sensors read rate_hz / camera rate times per frame (1.5 at 30 Hz).
    tof_readings = scenario.tof.rate_hz / scenario.camera.rate_hz if scenario.tof.trigger == "own_clock" else 1.0
    stages["tof"] *= tof_readings
    per_frame = wall / frames * 1e3
    print(f"{args.scenario}, {simulated:.1f} s simulated in {wall:.1f} s: real-time factor {simulated / wall:.2f}")
    print(f"per frame ({frames} frames at {scenario.camera.rate_hz:g} Hz): {per_frame:.1f} ms, "
          f"{per_frame / stages['render']:.2f}x the render; each stage the median of {timer.frames} frames")
    for name, ms in stages.items():
        print(f"  {name:10s} {ms:6.1f} ms" + (f" ({tof_readings:g} readings per frame)" if name == "tof" else ""))
    print(f"  {'rest':10s} {per_frame - sum(stages.values()):6.1f} ms (logging, IMU, events)")
    if args.out is not None:
        write_json(args.out, {"scenario": args.scenario, "overrides": args.overrides, "simulated_s": simulated,
                              "wall_s": wall,
                              "realtime_factor": simulated / wall, "frames": frames, "render_ms": stages["render"],
                              "per_frame_ms": per_frame, "per_frame_over_render": per_frame / stages["render"],
                              "stages_ms": {**stages, "rest": per_frame - sum(stages.values())},
                              "stage_frames": timer.frames})
    return 0


if __name__ == "__main__":
    sys.exit(main())
