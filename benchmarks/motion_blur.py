"""How long the camera's motion blur is over a run (issue 13's `camera.exposure_s`), in pixels.

    .venv/bin/python benchmarks/motion_blur.py [--scenario stewart-hardware] [--duration 200] [--seed 0]

The smear of a frame is how far the deck's point on the optical axis crosses the image over the exposure
(`ground_truth.axis_flow`, `camera.motion_blur_flow`); `NoisyCamera` applies a kernel from half a pixel on.
A Stewart scene's camera pose is a function of time, so each frame's smear is computed directly; a
deck-landing scenario is flown first, and the smear computed from its logged quadrotor state at the
supervisor's rate. Prints the median, 95th percentile and largest smear and the share of samples at or
above half a pixel.
"""

import argparse

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform

from diagrams.deck_landing_config import DeckLandingConfig
from diagrams.deck_landing_run import fly
from diagrams.runner import load_scenario
from diagrams.stewart_scene import StewartSceneConfig, build_stewart_scene
from systems.config import ConfigError
from systems.platforms.stewart import StewartPlatform
from systems.sensors.camera import motion_blur_flow
from systems.sensors.ground_truth import axis_flow, camera_motion
from systems.vehicles.quadrotor import P_WB, Q_WB, V_WB, W_WB_B


def smear_px(config: StewartSceneConfig | DeckLandingConfig, platform: StewartPlatform, t: float,
             X_WB: RigidTransform, V_WB: np.ndarray) -> float:
    """The smear (px) of a frame exposed at t [s] by a body at X_WB moving at V_WB ([w; v] in W)."""
    X_WC, V_WC = camera_motion(X_WB, V_WB, config.camera.X_BC)
    flow = axis_flow(X_WC, V_WC, platform.X_WP(t), platform.V_WP(t))
    return float(np.linalg.norm(motion_blur_flow(config.camera.K, flow, config.camera.exposure_s)))


def stewart_smears(config: StewartSceneConfig, duration_s: float) -> np.ndarray:
    """Each camera frame's smear (px) over duration_s of a Stewart scene."""
    _, handles = build_stewart_scene(config)
    body, smears = handles.body, []
    context = body.CreateDefaultContext()
    for t in np.arange(0.0, duration_s, config.camera.period_s):
        context.SetTime(t)
        smears.append(smear_px(config, handles.platform, t, body.GetOutputPort("X_WB").Eval(context),
                               body.GetOutputPort("V_WB").Eval(context)))
    return np.array(smears)


def flight_smears(config: DeckLandingConfig, duration_s: float) -> np.ndarray:
    """The smear (px) at each supervisor sample of a deck-landing flight of duration_s."""
    _, flight = fly(config, duration_s)
    smears = []
    for t, x in zip(flight.log["t"], flight.log["quadrotor_state"]):
        X_WB = RigidTransform(Quaternion(x[Q_WB] / np.linalg.norm(x[Q_WB])), x[P_WB])
        V_WB_W = np.concatenate([X_WB.rotation().multiply(x[W_WB_B]), x[V_WB]])
        smears.append(smear_px(config, flight.handles.platform, t, X_WB, V_WB_W))
    return np.array(smears)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="stewart-hardware", help="a Stewart or deck-landing scenario")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: the scenario's)")
    parser.add_argument("--seed", type=int, help="the scenario's seed (default: its own)")
    args = parser.parse_args(argv)
    try:
        name, config = load_scenario(args.scenario, duration_s=args.duration, seed=args.seed)
    except ConfigError as e:
        parser.exit(2, f"{e}\n")
    if not isinstance(config, StewartSceneConfig | DeckLandingConfig):
        parser.exit(2, f"{name}: not a Stewart or deck-landing scenario\n")
    if config.camera.exposure_s <= 0:
        parser.exit(2, f"{name}: camera.exposure_s is 0, no motion blur\n")
    smears = (stewart_smears if isinstance(config, StewartSceneConfig) else flight_smears)(config, config.duration_s)
    print(f"{name} ({config.duration_s:g} s, exposure {config.camera.exposure_s * 1e3:g} ms): smear median "
          f"{np.median(smears):.3f} px, 95th percentile {np.percentile(smears, 95):.3f} px, largest "
          f"{smears.max():.3f} px; {np.mean(smears >= 0.5):.1%} of {len(smears)} samples at or above half a pixel")


if __name__ == "__main__":
    main()
