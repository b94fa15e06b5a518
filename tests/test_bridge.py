"""The bridge over the path (systems/environment/bridge.py): where it stands, what it registers, and the
scenario's errors."""

import re

import numpy as np
import pytest
from pydrake.geometry import Role, SceneGraph

from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.environment.bridge import BridgeConfig, bridge_pose, register_bridge
from systems.vehicles.ground_vehicle import GroundVehicleConfig
from systems.vehicles.paths import make_path


@pytest.mark.parametrize("path_name, at_m", [("straight", 4.0), ("circle", 30.0)])
def test_bridge_stands_across_the_path(path_name, at_m):
    path = make_path(GroundVehicleConfig(path=path_name).path_config())
    X_WD = bridge_pose(path, BridgeConfig(enabled=True, at_m=at_m))
    assert np.allclose(X_WD.translation(), [*path.position(at_m), 0.0])
    x_D = X_WD.rotation().matrix()[:, 0]
    assert np.allclose(x_D[:2], [np.cos(path.heading(at_m)), np.sin(path.heading(at_m))])


def test_deck_and_piers_are_registered_for_the_cameras():
    scene_graph = SceneGraph()
    config = BridgeConfig(enabled=True)
    register_bridge(scene_graph, make_path(GroundVehicleConfig().path_config()), config)
    inspector = scene_graph.model_inspector()
    names = {inspector.GetName(g) for g in inspector.GetAllGeometryIds(Role.kPerception)}
    assert names == {"bridge_deck", "bridge_pier_1", "bridge_pier_-1"}
    deck = next(g for g in inspector.GetAllGeometryIds() if inspector.GetName(g).endswith("bridge_deck"))
    assert inspector.GetPoseInFrame(deck).translation()[2] == pytest.approx(config.clearance_m + config.thickness_m / 2)


def test_deck_and_piers_span_the_boxes_the_config_describes():
    """Each registered box, in the bridge frame D (x along the path, on the ground), is axis-aligned and spans:
    the deck x in +-length/2, y in +-width/2, z from the clearance up by its thickness; each pier the deck's
    length, across from the gap between the piers' inner faces (gap_m, centred on the path) out to the deck's
    edge, and from the ground up to the deck's underside. On a circle, where D is turned in W."""
    config = BridgeConfig(enabled=True, at_m=30.0)
    path = make_path(GroundVehicleConfig(path="circle").path_config())
    scene_graph = SceneGraph()
    register_bridge(scene_graph, path, config)
    inspector = scene_graph.model_inspector()
    X_DW = bridge_pose(path, config).inverse()
    half_length, half_width, clearance = config.length_m / 2, config.width_m / 2, config.clearance_m
    expected = {"bridge_deck": [[-half_length, -half_width, clearance],
                                [half_length, half_width, clearance + config.thickness_m]],
                "bridge_pier_1": [[-half_length, config.gap_m / 2, 0.0], [half_length, half_width, clearance]],
                "bridge_pier_-1": [[-half_length, -half_width, 0.0], [half_length, -config.gap_m / 2, clearance]]}
    spans = {}
    for geometry in inspector.GetAllGeometryIds(Role.kPerception):
        box, X_DG = inspector.GetShape(geometry), X_DW.multiply(inspector.GetPoseInFrame(geometry))
        assert np.allclose(X_DG.rotation().matrix(), np.eye(3), atol=1e-12)
        half = np.array([box.width(), box.depth(), box.height()]) / 2
        spans[inspector.GetName(geometry).split("::")[-1]] = [X_DG.translation() - half, X_DG.translation() + half]
    assert spans.keys() == expected.keys()
    for name, span in expected.items():
        np.testing.assert_allclose(spans[name], span, rtol=0, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("setting, message", [("bridge.clearance_m=0.4", "bridge.clearance_m"),
                                              ("bridge.length_m=0", "bridge.length_m"),
                                              ("bridge.at_m=-50", "bridge.at_m must not be negative"),  # clipped
                                              ("bridge.at_m=2001", "beyond the end of the vehicle's straight path"),
                                              ("bridge.pier_m=3", "bridge.width_m (6 m) must exceed twice"),
                                              ("bridge.pier_m=0", "bridge.pier_m must be positive"),
                                              ("bridge.pier_m=-0.4", "bridge.pier_m must be positive"),
                                              ("bridge.width_m=1.7", "narrower than its body"),  # piers on the road
                                              # 1.8 - 2 x 0.4: the gap is the 1 m body's width, no room to pass
                                              ("bridge.width_m=1.8", "leave 1 m (bridge.width_m - 2 bridge.pier_m) "
                                                                     "for the vehicle, narrower than its body"),
                                              ])
def test_bad_bridge_names_the_field(setting, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_scenario("ugv-hybrid", overrides=["bridge.enabled=true", setting])


def test_the_vehicle_fits_between_the_piers_and_a_closed_path_passes_any_arc_length():
    _, scenario = load_scenario("ugv-hybrid", overrides=["bridge.enabled=true", "bridge.width_m=2.2",
                                                         "vehicle.path=circle", "bridge.at_m=2001"])
    assert scenario.bridge.gap_m == pytest.approx(1.4) and scenario.platform.body_width_m < 1.4
