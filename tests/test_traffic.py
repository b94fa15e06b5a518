"""Distractor vehicles (systems/vehicles/traffic.py): seeded draws within their settings, poses in their lanes
along the UGV's path, SceneGraph posing them from the time, and the scenario's errors."""

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.systems.framework import DiagramBuilder

from diagrams.gv_landing import build_gv_landing
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.vehicles.ground_vehicle import GroundVehicleConfig
from systems.vehicles.paths import make_path
from systems.vehicles.traffic import (
    DISTRACTOR_COLOURS,
    Distractor,
    DistractorsConfig,
    Traffic,
    distractor_pose,
    draw_distractors,
)

CONFIG = DistractorsConfig(count=6, same_colour=2)


def test_draws_are_seeded_and_within_the_settings():
    a, b, c = (draw_distractors(CONFIG, seed) for seed in (0, 0, 1))
    assert a == b and a != c
    assert [d.colour for d in a[:2]] == ["ugv", "ugv"] and all(d.colour != "ugv" for d in a[2:])
    assert all(d.rgb == DISTRACTOR_COLOURS[d.colour] for d in a)
    for d in a:
        assert CONFIG.lane_min_m <= abs(d.lane_m) <= CONFIG.lane_max_m
        assert 0.6 <= d.speed_factor <= 1.4 and 0 <= d.s0_m <= CONFIG.ahead_max_m
    # One stream per distractor: a seventh leaves the first six as they were.
    assert draw_distractors(DistractorsConfig(count=7, same_colour=2), 0)[:6] == a


def test_the_rest_wear_the_other_colours_in_turn_from_the_first():
    """The module docstring: the first same_colour wear the UGV's colour, the rest the other colours in turn,
    starting from the first (red) whatever same_colour is, and round again after the eighth."""
    colours = [d.colour for d in draw_distractors(DistractorsConfig(count=12, same_colour=2), 0)]
    assert colours == ["ugv", "ugv", "red", "green", "blue", "yellow", "white", "dark", "purple", "cyan", "red",
                       "green"]


def test_lanes_are_drawn_on_either_side_of_the_path():
    """The lane's side is drawn too: among 16 distractors some drive left of the path (+) and some right (-)."""
    signs = {np.sign(d.lane_m) for d in draw_distractors(DistractorsConfig(count=16), 0)}
    assert signs == {-1.0, 1.0}


@pytest.mark.parametrize("path_name", ["straight", "circle"])
def test_pose_keeps_its_lane_along_the_path(path_name):
    vehicle = GroundVehicleConfig(path=path_name)
    path = make_path(vehicle.path_config())
    for d in draw_distractors(CONFIG, 3):
        for t in (0.0, 7.0, 30.0):
            X_WD = distractor_pose(path, vehicle, d, t)
            s = d.s0_m + d.speed_factor * 0.5 * t
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
    vehicle = GroundVehicleConfig()
    path = make_path(vehicle.path_config())
    distractors = draw_distractors(CONFIG, 0)
    traffic = builder.AddSystem(Traffic(scene_graph, path, vehicle, distractors))
    builder.Connect(traffic.get_output_port(), scene_graph.get_source_pose_port(traffic.source_id))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    context.SetTime(12.0)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    for i, d in enumerate(distractors):
        frame = next(f for f in inspector.GetAllFrameIds() if inspector.GetName(f).endswith(f"distractor_{i}"))
        assert query.GetPoseInWorld(frame).IsNearlyEqualTo(distractor_pose(path, vehicle, d, 12.0), 1e-12)


def test_each_box_stands_on_its_frame_length_along_x():
    """register_box: each distractor frame D holds one Box, its (width, depth, height) along (x_D, y_D, z_D) the
    draw's (length, width, height), centred half its height above D's origin (on the ground)."""
    scene_graph = SceneGraph()
    vehicle = GroundVehicleConfig()
    distractors = draw_distractors(CONFIG, 0)
    traffic = Traffic(scene_graph, make_path(vehicle.path_config()), vehicle, distractors)
    inspector = scene_graph.model_inspector()
    for frame, d in zip(traffic._frames, distractors):
        (geometry,) = inspector.GetGeometries(frame)
        box = inspector.GetShape(geometry)
        assert d.size_m[0] != d.size_m[1]  # length and width tell apart
        assert (box.width(), box.depth(), box.height()) == d.size_m
        np.testing.assert_array_equal(inspector.GetPoseInFrame(geometry).translation(), [0.0, 0.0, d.size_m[2] / 2])


def test_under_a_speed_schedule_they_keep_their_factor_of_the_ugvs_speed():
    """Each distractor drives its factor times the UGV's distance; they had moved at vehicle.speed (0.5 m/s)
    times it while the schedule drove the UGV at 2 m/s."""
    _, config = load_scenario("gv-landing", overrides=[
        "distractors.count=3", "vehicle.speed_schedule_times_s=[0, 2, 4]", "vehicle.speed_schedule_m_s=[1, 3, 2]"])
    diagram, handles = build_gv_landing(config)
    context = diagram.CreateDefaultContext()
    handles.initialize(context)
    traffic, path = diagram.GetSubsystemByName("traffic"), handles.vehicle.path

    def arc_lengths(time_s):  # each distractor's place along the (straight) path
        context.SetTime(time_s)
        poses = traffic.get_output_port().Eval(traffic.GetMyContextFromRoot(context))
        return np.array([path.nearest(poses.value(frame).translation()[:2]) for frame in traffic._frames])

    ugv = 2.0 * 2 + 2.5 * 2 + 2.0 * 2  # m: 1 -> 3 m/s over 0-2 s, 3 -> 2 m/s over 2-4 s, held at 2 m/s to 6 s
    ratios = (arc_lengths(6.0) - arc_lengths(0.0)) / ugv
    assert np.all((0.6 <= ratios) & (ratios <= 1.4))  # distractors.speed_factor_range
    assert config.vehicle.distance_driven_m(6.0) == pytest.approx(ugv)
    np.testing.assert_allclose(ratios, [d.speed_factor for d in draw_distractors(config.distractors, config.seed)],
                               atol=1e-9)


def test_the_settings_limits_are_accepted():
    """As many distractors as allowed (16), and a single lane width (lane_min_m = lane_max_m: every distractor that
    far to one side or the other) are valid settings."""
    _, config = load_scenario("ugv-hybrid", overrides=["distractors.count=16"])
    assert len(draw_distractors(config.distractors, config.seed)) == 16
    _, config = load_scenario("ugv-hybrid", overrides=["distractors.count=4", "distractors.lane_min_m=5",
                                                       "distractors.lane_max_m=5"])
    assert [abs(d.lane_m) for d in draw_distractors(config.distractors, config.seed)] == [5.0] * 4


@pytest.mark.parametrize("setting, field", [("distractors.count=17", "distractors.count"),
                                            ("distractors.same_colour=1", "distractors.same_colour"),
                                            ("distractors.lane_min_m=0", "distractors.lane_min_m"),
                                            ("distractors.speed_factor_range=[1.5, 1.0]",
                                             "distractors.speed_factor_range"),
                                            ("distractors.lane_max_m=2.0", "distractors.lane_max_m must not be under"),
                                            ("distractors.size_low_m=[2.0, 0.8, 0.35]",
                                             "distractors.size_low_m/size_high_m")])
def test_bad_setting_names_the_field(setting, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("ugv-hybrid", overrides=[setting])


def test_the_ground_reaches_the_ugv_when_every_distractor_is_slower():
    """lead() sizes the ground (GroundVehicleConfig.ground_length_m: as far as anything on the path gets): with
    distractors at 0.5-0.8 of the UGV's speed the ground must still reach as far as the UGV itself drives."""
    config, vehicle, duration = DistractorsConfig(count=4, speed_factor_range=[0.5, 0.8]), GroundVehicleConfig(), 2000.0
    driven = vehicle.distance_driven_m(duration)
    furthest = max(d.s0_m + d.speed_factor * driven for d in draw_distractors(config, 0))
    assert furthest < driven  # the UGV is the furthest thing on the path
    assert vehicle.ground_length_m(duration, config.lead()) >= driven


def test_without_distractors_the_ground_is_the_ugvs():
    """lead() is (1, 0) without distractors (not the default range's 1.4 and ahead_max_m 15 m): the ground of a
    100 s run at 10 m/s on the straight path reaches the 1000 m the UGV drives."""
    config = DistractorsConfig()
    assert config.count == 0 and config.lead() == (1.0, 0.0)
    vehicle = GroundVehicleConfig(path="straight", speed=10.0)
    assert vehicle.ground_length_m(100.0, config.lead()) == pytest.approx(1000.0, rel=1e-12)


@pytest.mark.parametrize("settings, field, expected", [
    ({"ahead_max_m": 0.0}, "s0_m", 0.0),
    ({"speed_factor_range": [1.0, 1.0]}, "speed_factor", 1.0),
    ({"size_low_m": [1.4, 1.0, 0.5], "size_high_m": [1.4, 1.0, 0.5]}, "size_m", (1.4, 1.0, 0.5)),
])
def test_a_range_of_one_value_is_accepted_and_drawn(settings, field, expected):
    """Each range's limits may meet: ahead_max_m 0 (all start with the UGV), speed_factor_range [1, 1], size_low_m =
    size_high_m; every draw is then that value."""
    config = DistractorsConfig(count=5, **settings)
    config.validate()
    assert [getattr(d, field) for d in draw_distractors(config, 0)] == [expected] * 5


def test_without_distractors_any_lane_width_passes():
    """check_lanes refuses lanes wider than the path's tightest radius only when there are distractors to drive
    them: 30 m lanes on the 15 m circle pass with count 0, are refused with 4."""
    path = make_path(GroundVehicleConfig(path="circle").path_config())
    DistractorsConfig(count=0, lane_min_m=20.0, lane_max_m=30.0).check_lanes(path, "vehicle.path 'circle'")
    with pytest.raises(ConfigError, match=r"lane_max_m \(30 m\) must be under the tightest radius"):
        DistractorsConfig(count=4, lane_min_m=20.0, lane_max_m=30.0).check_lanes(path, "vehicle.path 'circle'")


def test_a_lane_wider_than_the_paths_tightest_radius_is_refused():
    """On the 15 m circle a 20-30 m lane put distractors past its centre, driving backwards."""
    lanes = ["distractors.count=4", "distractors.lane_min_m=20", "distractors.lane_max_m=30"]
    with pytest.raises(ConfigError, match=r"^distractors\.lane_max_m \(30 m\) must be under the tightest radius of "
                                          r"vehicle\.path 'circle', 15\.0 m: "):
        load_scenario("ugv-hybrid", overrides=["vehicle.path=circle", *lanes])
    load_scenario("ugv-hybrid", overrides=["vehicle.path=straight", *lanes])  # no curve
    load_scenario("ugv-hybrid", overrides=["vehicle.path=sine", *lanes])  # Eq. (13)'s tightest radius: 41.4 m


def test_a_lane_as_wide_as_the_paths_tightest_radius_is_refused():
    """A 15 m lane on the 15 m circle puts a distractor in the left lane on the curve's centre, (0, 15), where it
    stands whatever the time (it turns on the spot): refused, like a wider one."""
    vehicle = GroundVehicleConfig(path="circle")
    path = make_path(vehicle.path_config())
    at_centre = Distractor("red", DISTRACTOR_COLOURS["red"], (1.4, 1.0, 0.5), 3.0, 1.0, 15.0)
    for t in (0.0, 7.0, 30.0):
        # the path is 0.1 m chords of the circle, 0.1 mm inside it at most
        np.testing.assert_allclose(distractor_pose(path, vehicle, at_centre, t).translation(), [0.0, 15.0, 0.0],
                                   atol=1e-3)
    lanes = ["distractors.count=4", "distractors.lane_min_m=14", "distractors.lane_max_m=15"]
    with pytest.raises(ConfigError, match=r"^distractors\.lane_max_m \(15 m\) must be under the tightest radius of "
                                          r"vehicle\.path 'circle', 15\.0 m: "):
        load_scenario("ugv-hybrid", overrides=["vehicle.path=circle", *lanes])


def test_lanes_under_the_tightest_radius_keep_the_distractors_driving_forward():
    _, config = load_scenario("ugv-hybrid", overrides=["vehicle.path=circle", "distractors.count=8",
                                                       "distractors.lane_min_m=10", "distractors.lane_max_m=14.5"])
    path = make_path(config.vehicle.path_config())
    for d in draw_distractors(config.distractors, config.seed):
        a, b = (distractor_pose(path, config.vehicle, d, t) for t in (10.0, 10.1))
        velocity = (b.translation() - a.translation())[:2]
        assert a.rotation().col(0)[:2] @ velocity > 0.99 * np.linalg.norm(velocity)  # facing the way it drives
