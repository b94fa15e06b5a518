"""The pad's markers seen by the gv scene's rendered camera (diagrams/marker_visibility.py): the
nested layout of marker-landing-wind keeps a marker in view at 0.3 m off the pad's centre, where the
default five show none; both show the corner markers from 10 m (benchmarks/marker_visibility.py has
the whole grid)."""

import pytest

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


def test_the_rig_needs_the_camera():
    with pytest.raises(ConfigError, match="estimation.source"):
        VisibilityRig(load_scenario("gv-landing")[1])
