"""The pad's markers seen by the gv scene's rendered camera (diagrams/marker_visibility.py): the
nested layout of marker-landing-wind keeps a marker in view at 0.3 m off the pad's centre, where the
default five show none; both show the corner markers from 10 m (benchmarks/marker_visibility.py has
the whole grid)."""

import numpy as np
import pytest
from pydrake.math import RollPitchYaw, RotationMatrix

from diagrams.marker_visibility import VisibilityRig
from diagrams.runner import load_scenario
from systems.config import ConfigError

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


@pytest.fixture(scope="module")
def rigs():
    return {name: VisibilityRig(load_scenario(name)[1]) for name in ("marker-landing", "marker-landing-wind")}


def test_the_nested_layout_keeps_a_marker_in_view_down_to_0_3_m(rigs):
    five, nine = rigs["marker-landing"], rigs["marker-landing-wind"]
    for offset, tilt_deg in (((0.1, 0.0), 0.0), ((0.1, 0.1), 10.0), ((-0.12, 0.05), -10.0)):
        assert not five.detected(0.3, offset, tilt_deg)  # the centre marker is cut by the image's edge
        assert nine.detected(0.3, offset, tilt_deg) & {5, 6, 7, 8}  # a 6 cm marker is whole in view
    assert five.detected(0.3) == nine.detected(0.3) == {0}  # over the centre: the centre marker
    assert {1, 2, 3, 4} <= five.detected(10.0) and {1, 2, 3, 4} <= nine.detected(10.0)


def test_the_rig_poses_the_camera_over_the_pad(rigs):
    """The body's horizontal offset from the pad's centre is in P; the camera (X_BC on the body rolled by the tilt
    about x_B, x_B along x_P) is camera_height_m above the pad's top."""
    rig = rigs["marker-landing"]
    rig.detected(0.3, (0.1, 0.05), 10.0)
    quad = rig._handles.quadrotor
    p_WB = quad.GetOutputPort("state").Eval(quad.GetMyContextFromRoot(rig._context))[0:3]
    R_WP = RotationMatrix.MakeZRotation(rig.yaw_WP)
    R_WB = R_WP.multiply(RotationMatrix(RollPitchYaw(np.radians(10.0), 0.0, 0.0)))
    np.testing.assert_allclose(p_WB[:2], rig.p_WP[:2] + R_WP.matrix()[:2, :2] @ [0.1, 0.05], atol=1e-9)
    p_WC = p_WB + R_WB.multiply(rig.config.estimation.camera.X_BC.translation())
    assert p_WC[2] - rig.p_WP[2] == pytest.approx(0.3, abs=1e-9)


def test_the_rig_needs_the_camera():
    with pytest.raises(ConfigError, match="estimation.source"):
        VisibilityRig(load_scenario("gv-landing")[1])
