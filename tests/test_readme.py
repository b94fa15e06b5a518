"""README's "In a script" examples, run as they are written there: a user copies them first, so a
change of a builder's name, a handle or a metrics field must fail here, not in a user's script."""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

README = Path(__file__).resolve().parent.parent / "README.md"


def readme_snippets() -> list[str]:
    """The README's ```python blocks, in order."""
    return re.findall(r"^```python\n(.*?)^```", README.read_text(), flags=re.S | re.M)


def run_snippet(index: int) -> dict:
    namespace = {"__name__": "readme_snippet"}
    exec(compile(readme_snippets()[index], f"README.md python block {index + 1}", "exec"), namespace)
    return namespace


def test_readme_has_the_two_script_examples():
    snippets = readme_snippets()
    assert len(snippets) == 2
    assert "build_stewart_scene" in snippets[0] and "fly(" in snippets[1]


@pytest.mark.slow
def test_readme_stewart_scene_example_logs_the_camera_pose_in_the_platform():
    """5 s of the 20 Hz camera: 101 poses X_CP as [xyz, quaternion wxyz]. The tag stays 2 m down the
    optical axis (the hover's default height, the deck rolling about the tag's centre), and at 5 s the
    block's roll, 8 deg at 0.05 Hz, is at its peak: the tag turned 8 deg from its first pose."""
    truth = run_snippet(0)["truth"]
    assert truth.shape == (7, 101)
    np.testing.assert_allclose(truth[0:3], np.tile([[0.0], [0.0], [2.0]], 101), atol=1e-6)
    R_first, R_last = (Rotation.from_quat(truth[3:7, k], scalar_first=True) for k in (0, -1))
    assert np.rad2deg((R_first.inv() * R_last).magnitude()) == pytest.approx(8.0, abs=0.01)


@pytest.mark.slow
def test_readme_vision_landing_example_lands_on_paper_ekf(capsys):
    """marker-landing steered by paper_ekf lands on the pad, and the block prints the three figures it
    names (touchdown error, the steering estimate's and ct_ekf's RMS position, in m)."""
    namespace = run_snippet(1)
    metrics = namespace["metrics"]
    assert metrics["landing"]["success"]
    printed = [float(x) for x in capsys.readouterr().out.split()]
    assert printed == [metrics["landing"]["touchdown_error_m"], metrics["perception"]["rms_position_m"],
                       metrics["estimators"]["ct_ekf"]["rms_position_m"]]
    assert 0.0 <= printed[0] < 0.5 and 0.0 < printed[1] < 0.5 and 0.0 < printed[2] < printed[1]
