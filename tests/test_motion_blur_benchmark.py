"""benchmarks/motion_blur.py: its smears are the ones the Diagram's camera applies; a scenario without an
exposure is one line and exit 2."""

import numpy as np
import pytest

from benchmarks.motion_blur import main, stewart_smears
from diagrams.runner import load_scenario
from diagrams.stewart_scene import build_stewart_scene
from systems.sensors.camera import motion_blur_flow


def test_a_stewart_scene_s_smears_are_the_camera_s_own():
    _, config = load_scenario("stewart-hardware", overrides=["hover.offset_xy_m=[0.3, -0.2]"])
    smears = stewart_smears(config, 2.0)
    diagram, handles = build_stewart_scene(config)
    context = diagram.CreateDefaultContext()
    camera = handles.noisy_camera
    expected = []
    for t in np.arange(0.0, 2.0, config.camera.period_s):
        context.SetTime(t)
        flow = camera.GetInputPort("axis_flow").Eval(camera.GetMyContextFromRoot(context))
        expected.append(np.linalg.norm(motion_blur_flow(config.camera.K, flow, config.camera.exposure_s)))
    assert len(smears) == 40 and np.all(smears > 0)
    np.testing.assert_allclose(smears, expected, rtol=1e-12)


def test_without_an_exposure_it_says_so_and_exits_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--scenario", "stewart-dynamic"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip() == "stewart-dynamic: camera.exposure_s is 0, no motion blur"
