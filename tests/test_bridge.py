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


@pytest.mark.parametrize("setting, message", [("bridge.clearance_m=0.4", "bridge.clearance_m"),
                                              ("bridge.length_m=0", "bridge.length_m"),
                                              ("bridge.at_m=-50", "bridge.at_m must not be negative"),  # clipped
                                              ("bridge.at_m=2001", "beyond the end of the vehicle's straight path"),
                                              ("bridge.pier_m=3", "bridge.width_m (6 m) must exceed twice"),
                                              ("bridge.width_m=1.7", "narrower than its body"),  # piers on the road
                                              ])
def test_bad_bridge_names_the_field(setting, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_scenario("ugv-hybrid", overrides=["bridge.enabled=true", setting])


def test_the_vehicle_fits_between_the_piers_and_a_closed_path_passes_any_arc_length():
    _, scenario = load_scenario("ugv-hybrid", overrides=["bridge.enabled=true", "bridge.width_m=2.2",
                                                         "vehicle.path=circle", "bridge.at_m=2001"])
    assert scenario.bridge.gap_m == pytest.approx(1.4) and scenario.platform.body_width_m < 1.4
