"""Distractor vehicles (systems/vehicles/traffic.py): seeded draws within their settings, poses in their lanes
along the UGV's path, SceneGraph posing them from the time, and the scenario's errors."""

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.systems.framework import DiagramBuilder

from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.vehicles.ground_vehicle import GroundVehicleConfig
from systems.vehicles.paths import make_path
from systems.vehicles.traffic import DISTRACTOR_COLOURS, DistractorsConfig, Traffic, distractor_pose, draw_distractors

CONFIG = DistractorsConfig(count=6, same_colour=2)


def test_draws_are_seeded_and_within_the_settings():
    a, b, c = (draw_distractors(CONFIG, 0.5, seed) for seed in (0, 0, 1))
    assert a == b and a != c
    assert [d.colour for d in a[:2]] == ["ugv", "ugv"] and all(d.colour != "ugv" for d in a[2:])
    assert all(d.rgb == DISTRACTOR_COLOURS[d.colour] for d in a)
    for d in a:
        assert CONFIG.lane_min_m <= abs(d.lane_m) <= CONFIG.lane_max_m
        assert 0.5 * 0.6 <= d.speed_m_s <= 0.5 * 1.4 and 0 <= d.s0_m <= CONFIG.ahead_max_m
    # One stream per distractor: a seventh leaves the first six as they were.
    assert draw_distractors(DistractorsConfig(count=7, same_colour=2), 0.5, 0)[:6] == a


@pytest.mark.parametrize("path_name", ["straight", "circle"])
def test_pose_keeps_its_lane_along_the_path(path_name):
    path = make_path(GroundVehicleConfig(path=path_name).path_config())
    for d in draw_distractors(CONFIG, 0.5, 3):
        for t in (0.0, 7.0, 30.0):
            X_WD = distractor_pose(path, d, t)
            s = d.s0_m + d.speed_m_s * t
            offset = X_WD.translation()[:2] - path.position(s)
            heading = path.heading(s)
            assert np.linalg.norm(offset) == pytest.approx(abs(d.lane_m), abs=1e-9)
            # to the path's left for a positive lane, facing along it
            assert np.sign(np.cos(heading) * offset[1] - np.sin(heading) * offset[0]) == np.sign(d.lane_m)
            assert X_WD.rotation().ToRollPitchYaw().yaw_angle() == pytest.approx(np.arctan2(np.sin(heading),
                                                                                              np.cos(heading)))


def test_scene_graph_poses_them_from_the_time():
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    path = make_path(GroundVehicleConfig().path_config())
    distractors = draw_distractors(CONFIG, 0.5, 0)
    traffic = builder.AddSystem(Traffic(scene_graph, path, distractors))
    builder.Connect(traffic.get_output_port(), scene_graph.get_source_pose_port(traffic.source_id))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    context.SetTime(12.0)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    for i, d in enumerate(distractors):
        frame = next(f for f in inspector.GetAllFrameIds() if inspector.GetName(f).endswith(f"distractor_{i}"))
        assert query.GetPoseInWorld(frame).IsNearlyEqualTo(distractor_pose(path, d, 12.0), 1e-12)


@pytest.mark.parametrize("setting, field", [("distractors.count=17", "distractors.count"),
                                            ("distractors.same_colour=1", "distractors.same_colour"),
                                            ("distractors.lane_min_m=0", "distractors.lane_min_m"),
                                            ("distractors.speed_factor_range=[1.5, 1.0]",
                                             "distractors.speed_factor_range")])
def test_bad_setting_names_the_field(setting, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("ugv-hybrid", overrides=[setting])
