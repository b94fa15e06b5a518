import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource, VectorLogSink
from scipy.optimize import minimize_scalar

from systems.config import ConfigError
from systems.vehicles.ground_vehicle import (
    GroundVehicle,
    GroundVehicleConfig,
    PathFollower,
    ground_pose,
    make_bicycle_dynamics,
    steering_command,
)
from systems.vehicles.paths import MAX_SIZE_M, PATH_NAMES, PathConfig, make_path

# pydrake filters numpy's "invalid value" warnings from symbolic object arrays when imported;
# pytest resets warning filters per test, so restore that one here.
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


def drive_bicycle(config, state0, steering_command, speed, duration):
    """Eq. (6) alone under constant inputs; returns the logged states (4 x N)."""
    builder = DiagramBuilder()
    bicycle = builder.AddSystem(make_bicycle_dynamics(config))
    source = builder.AddSystem(ConstantVectorSource([steering_command, speed]))
    logger = builder.AddSystem(VectorLogSink(4, 0.1))
    builder.Connect(source.get_output_port(), bicycle.get_input_port())
    builder.Connect(bicycle.get_output_port(), logger.get_input_port())
    simulator = Simulator(builder.Build())
    simulator.get_mutable_integrator().set_target_accuracy(1e-10)
    root = simulator.get_mutable_context()
    bicycle.GetMyMutableContextFromRoot(root).SetContinuousState(state0)
    simulator.AdvanceTo(duration)
    return logger.FindLog(root).data()


def follow(config, speed, distance, time_period=None):
    """GroundVehicle (discretised with `time_period`) on its path; returns (logged states 4 x N,
    final path progress)."""
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(GroundVehicle(config, time_period))
    source = builder.AddSystem(ConstantVectorSource([speed]))
    logger = builder.AddSystem(VectorLogSink(4, 0.1))
    builder.Connect(source.get_output_port(), vehicle.GetInputPort("speed"))
    builder.Connect(vehicle.GetOutputPort("state"), logger.get_input_port())
    simulator = Simulator(builder.Build())
    root = simulator.get_mutable_context()
    vehicle.set_state(root, vehicle.initial_state())
    simulator.AdvanceTo(distance / speed)
    vehicle_context = vehicle.GetMyContextFromRoot(root)
    return logger.FindLog(root).data(), vehicle.GetOutputPort("path_progress").Eval(vehicle_context)[0]


def assert_progress(progress, distance, path, config, speed):
    """The follower's last sample of the arc length matches the distance driven (mod a lap)."""
    lag = speed / config.follower.rate_hz  # the progress output is up to one sample old
    gap = distance - progress
    if path.closed:
        gap = (gap + path.length / 2) % path.length - path.length / 2
    assert -0.1 < gap < lag + 0.2


def cross_track_errors(path, states):
    """Distance from each logged position to the path, following the vehicle's branch."""
    errors, s = [], 0.0
    for x, y in states[:2].T:
        s = path.nearest([x, y], s_hint=s)
        errors.append(np.linalg.norm([x, y] - path.position(s)))
    return np.array(errors)


def test_constant_steering_drives_the_predicted_circle():
    config = GroundVehicleConfig()
    delta = np.radians(12.0)
    radius = config.wheelbase_m / np.tan(delta)  # R = d / tan(delta)
    alpha0 = 0.3
    states = drive_bicycle(config, [1.0, 2.0, alpha0, delta], delta, speed=5.0, duration=25.0)
    centre = np.array([1.0 - radius * np.sin(alpha0), 2.0 + radius * np.cos(alpha0)])
    np.testing.assert_allclose(np.linalg.norm(states[:2].T - centre, axis=1), radius, rtol=1e-6)
    assert 5.0 * 25.0 > 2 * np.pi * radius  # went round at least once


def test_steering_lag_and_limit():
    config = GroundVehicleConfig()
    tau = config.steering_time_constant_s
    states = drive_bicycle(config, [0, 0, 0, 0], steering_command=1.0, speed=1.0, duration=tau)
    limit = np.radians(config.max_steering_deg)
    assert states[3, -1] == pytest.approx(limit * (1 - np.exp(-1.0)), rel=1e-6)
    # the same limit turning right: -1 rad is held at -theta_max
    states = drive_bicycle(config, [0, 0, 0, 0], steering_command=-1.0, speed=1.0, duration=tau)
    assert states[3, -1] == pytest.approx(-limit * (1 - np.exp(-1.0)), rel=1e-6)


@pytest.mark.parametrize("yaml, message", [
    ("wheelbase_m: 0.0", "vehicle.wheelbase_m must be positive"),
    ("max_steering_deg: 0.0", "vehicle.max_steering_deg must be in"),
    ("path: zigzag", "vehicle.path 'zigzag' is not a path"),
    ("{path: circle, path_radius_m: 5.0}", r"vehicle.path 'circle' turns on a 5.0 m radius at its tightest, under "
                                           r"the vehicle's minimum turning radius 9.6 m .*raise vehicle.path_radius_m"),
    # Eq. (13)'s tightest bend, 41.4 m, needs 4.8 deg of steering
    ("{path: sine, max_steering_deg: 3.0}", r"vehicle.path 'sine' turns on a 41.4 m radius at its tightest, under "
                                            r"the vehicle's minimum turning radius 66.8 m .*raise vehicle.max_st"),
    ("{path: turn-90, path_length_m: 30.0}", r"vehicle.path_length_m = 30.0 is too short"),
    # Eq. (13) cut at 5 cm kept a single sample: ZeroDivisionError
    ("{path: sine, path_length_m: 0.05}", r"^vehicle.path_length_m must be at least two sample spacings, 0.2 m, "
                                          r"got 0.05$"),
    ("{speed_schedule_times_s: [0, 1], speed_schedule_m_s: [1]}", "must have the same length"),
    ("{speed_schedule_times_s: [0, 0], speed_schedule_m_s: [1, 2]}", "vehicle.speed_schedule_times_s must increase"),
    # A path sampled every 0.1 m over 1e9 m: MemoryError (75 GiB) before
    ("{path: straight, path_length_m: 1.0e9}", r"^vehicle.path_length_m must be at most 100000 m \(the path is "
                                               r"sampled every 0.1 m\), got 1e\+09$"),
    ("{path: circle, path_radius_m: 2.0e5}", r"^vehicle.path_radius_m must be at most 100000 m"),
    # 12 m/s at 20 Hz drives 0.6 m per follower update: a 5 cm window lost the path at once
    ("{path: sine, speed: 12.0, follower: {search_window_m: 0.05}}",
     r"^vehicle.follower.search_window_m \(0.05 m\) must exceed the distance driven per follower update, "
     r"vehicle.speed 12 m/s / vehicle.follower.rate_hz 20 Hz, plus the path's 0.1 m sample spacing: 0.7 m$"),
    ("{speed_schedule_times_s: [0, 5], speed_schedule_m_s: [0, 10], follower: {search_window_m: 0.45, rate_hz: 25}}",
     r"vehicle.speed_schedule_m_s's top 10 m/s / vehicle.follower.rate_hz 25 Hz, .*: 0.5 m$"),
    # The top speed counts, not the last: 10 m/s / 25 Hz + 0.1 m = 0.5 m (the last, 2 m/s, would need 0.18 m).
    ("{speed_schedule_times_s: [0, 5, 10], speed_schedule_m_s: [0, 10, 2], "
     "follower: {search_window_m: 0.45, rate_hz: 25}}",
     r"vehicle.speed_schedule_m_s's top 10 m/s / vehicle.follower.rate_hz 25 Hz, .*: 0.5 m$"),
    # The window must exceed what is needed: 12 m/s / 20 Hz + 0.1 m is 0.7 m exactly (in floats too), refused.
    ("{path: straight, speed: 12.0, follower: {search_window_m: 0.7}}",
     r"^vehicle.follower.search_window_m \(0.7 m\) must exceed .*: 0.7 m$"),
    # Eq. (13)'s first 100 m bend right only, tightest at x = 59.4 m: a 45.8 m radius, under 3.5 m / tan(3 deg)
    ("{path: sine, path_length_m: 100.0, max_steering_deg: 3.0}",
     r"vehicle.path 'sine' turns on a 45.8 m radius at its tightest, under the vehicle's minimum turning radius "
     r"66.8 m"),
])
def test_bad_config_is_rejected_by_name(yaml, message):
    config = yaml_load_typed(schema=GroundVehicleConfig, data=yaml)
    with pytest.raises(ValueError, match=message):
        GroundVehicle(config)


@pytest.mark.parametrize("yaml", ["{path: straight, wheelbase_m: 6.0}", "{path: sine, max_steering_deg: 5.0}",
                                  "{path: circle, path_radius_m: 9.7}"])
def test_a_path_within_the_steering_limit_is_accepted(yaml):
    """Each path's own tightest radius counts: a straight has none, Eq. (13)'s is 41.4 m (4.8 deg), a 9.7 m
    circle's is above the 9.6 m the default 3.5 m wheelbase turns at 20 deg."""
    GroundVehicle(yaml_load_typed(schema=GroundVehicleConfig, data=yaml))


def test_a_circle_is_refused_just_under_the_minimum_turning_radius_and_accepted_just_over_it():
    """The minimum turning radius R = d / tan(theta_max) = 3.5 m / tan(20 deg) = 9.62 m is where the circle's radius
    stops being followable: 1 % under it is refused, 1 % over it accepted."""
    radius = 3.5 / np.tan(np.radians(20.0))
    with pytest.raises(ValueError, match=r"vehicle.path 'circle' turns on a 9.5 m radius at its tightest, under the "
                                         r"vehicle's minimum turning radius 9.6 m"):
        GroundVehicleConfig(path="circle", path_radius_m=0.99 * radius).validate()
    GroundVehicleConfig(path="circle", path_radius_m=1.01 * radius).validate()


def test_a_circle_of_exactly_the_minimum_turning_radius_is_accepted():
    """The path's tightest radius may equal the vehicle's minimum turning radius R = d / tan(theta_max) (only under it
    is refused): the default 3.5 m wheelbase at 20 deg, a circle of that R (its curvature 1 / R times R is 1 in
    floats too)."""
    radius = 3.5 / np.tan(np.radians(20.0))
    assert (1.0 / radius) * radius == 1.0
    GroundVehicleConfig(path="circle", path_radius_m=radius).validate()


def test_a_path_as_long_as_the_largest_size_is_accepted():
    PathConfig(name="straight", length_m=MAX_SIZE_M).validate()


@pytest.mark.parametrize("name", ["sine", "straight"])
def test_an_open_path_as_short_as_accepted_is_a_path(name):
    path = make_path(PathConfig(name=name, length_m=0.2))
    assert len(path.s) >= 2 and 0.0 < path.spacing <= 0.1
    assert path.nearest(path.position(path.length)) == pytest.approx(path.length)


def test_a_manoeuvre_path_exactly_as_long_as_its_lead_and_turn_is_accepted():
    """turn-90 of lead_m + radius_m pi/2 (what its validation says it needs) is a path: it ends where the quarter
    circle does, (lead + r, r) off its start, turned 90 deg; a centimetre shorter is refused, naming the length."""
    lead, radius = 20.0, 15.0
    needed = lead + abs(np.pi / 2) * radius
    path = make_path(PathConfig(name="turn-90", length_m=needed, lead_m=lead, radius_m=radius))
    end = path.position(path.length)
    np.testing.assert_allclose(np.abs(end[:2] - path.position(0.0)[:2]), [lead + radius, radius], atol=1e-6)
    with pytest.raises(ValueError, match=r"path_length_m = .* is too short for 'turn-90' \(needs at least 43.56"):
        make_path(PathConfig(name="turn-90", length_m=needed - 0.01, lead_m=lead, radius_m=radius))


def test_max_curvature_is_the_tightest_bend():
    assert make_path(PathConfig(name="straight")).max_curvature == 0.0
    assert make_path(PathConfig(name="figure-eight", radius_m=12.0)).max_curvature == pytest.approx(1 / 12.0)
    x = np.linspace(0.0, 2000.0, 200001)  # Eq. (13)'s curvature y'' / (1 + y'^2)^1.5, sampled finely
    a, b = 2 * np.pi / 500, 2 * np.pi / 200
    dy, ddy = 30 * a * np.cos(a * x) + 20 * b * np.cos(b * x), -30 * a**2 * np.sin(a * x) - 20 * b**2 * np.sin(b * x)
    assert make_path(PathConfig(name="sine")).max_curvature == pytest.approx(
        np.abs(ddy / (1 + dy**2) ** 1.5).max(), rel=1e-4)


def test_max_curvature_counts_a_right_bend():
    """Eq. (13)'s first 100 m of arc (to x = 86 m) bend right only (y'' < 0): the tightest bend is the largest
    |curvature|, 1 / 45.8 m at x = 59.4 m, found here by minimising y'' / (1 + y'^2)^1.5 over x."""
    a, b = 2 * np.pi / 500, 2 * np.pi / 200

    def curvature(x):
        dy = 30 * a * np.cos(a * x) + 20 * b * np.cos(b * x)
        ddy = -30 * a**2 * np.sin(a * x) - 20 * b**2 * np.sin(b * x)
        return ddy / (1 + dy**2) ** 1.5

    tightest = minimize_scalar(curvature, bounds=(0.0, 80.0), method="bounded", options={"xatol": 1e-9})
    assert tightest.fun < 0.0 and 50.0 < tightest.x < 70.0  # a right bend, inside the first 100 m
    assert make_path(PathConfig(name="sine", length_m=100.0)).max_curvature == pytest.approx(-tightest.fun, rel=1e-4)


def test_sine_path_is_seed_002_eq_13():
    path = make_path(PathConfig(name="sine", length_m=800.0))
    for s in np.linspace(0.0, 800.0, 9):
        x, y = path.position(s)
        assert y == pytest.approx(30 * np.sin(2 * np.pi * x / 500) + 20 * np.sin(2 * np.pi * x / 200),
                                  abs=1e-3)
    assert path.heading(0.0) == pytest.approx(np.arctan(2 * np.pi * (30 / 500 + 20 / 200)))


@pytest.mark.parametrize("name", PATH_NAMES)
def test_paths_start_at_the_origin_heading_as_documented(name):
    """paths.py's docstring: along +x, but sine (Eq. 13's slope) and figure-eight (45 deg)."""
    path = make_path(PathConfig(name=name))
    np.testing.assert_allclose(path.position(0.0), [0.0, 0.0], atol=1e-12)
    expected = {"sine": np.arctan(2 * np.pi * (30 / 500 + 20 / 200)), "figure-eight": np.pi / 4}.get(name, 0.0)
    assert path.heading(0.0) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("name", ["circle", "rectangle", "figure-eight"])
def test_closed_paths_close_smoothly(name):
    path = make_path(PathConfig(name=name))
    assert path.closed
    np.testing.assert_allclose(path.position(path.length), path.position(0.0), atol=1e-9)
    assert np.cos(path.heading(path.length - 1e-6) - path.heading(0.0)) == pytest.approx(1.0)


def test_nearest_keeps_to_its_branch_where_the_figure_eight_crosses():
    path = make_path(PathConfig(name="figure-eight"))
    crossing_again = path.length / 2  # the straight between the lobes crosses the origin mid-way
    np.testing.assert_allclose(path.position(crossing_again), [0.0, 0.0], atol=1e-6)
    assert path.nearest([0.01, 0.0], s_hint=1.0) == pytest.approx(0.0, abs=0.02)
    assert path.nearest([0.01, 0.0], s_hint=crossing_again - 1.0) == pytest.approx(
        crossing_again, abs=0.02)


def test_nearest_with_a_hint_searches_across_a_closed_paths_closing_point():
    """On the circle, a hint just before the end finds a point just past the start, and a hint just past the start
    a point just before the end: the search window wraps round the closing point (the nearest is the point
    itself)."""
    path = make_path(PathConfig(name="circle"))
    for s_true, s_hint in ((0.3, path.length - 0.2), (path.length - 0.3, 0.2)):
        p = path.position(s_true)
        found = path.nearest(p, s_hint=s_hint)
        np.testing.assert_allclose(path.position(found), p, atol=1e-3)
        assert (found - s_true + path.length / 2) % path.length - path.length / 2 == pytest.approx(0.0, abs=1e-3)


@pytest.mark.parametrize("name", ["circle", "figure-eight"])
@pytest.mark.parametrize("s_hint", [None, -0.2, 0.2])
def test_a_point_within_half_a_spacing_of_the_closing_point_is_found_on_either_side_of_it(name, s_hint):
    """The first and last samples of a closed path are one point: a point 0.03 m before it (the spacing is about
    0.1 m) lies on the closing chord, not at s = 0, and one 0.03 m after it on the first chord, with or without a
    hint either side."""
    path = make_path(PathConfig(name=name))
    assert path.spacing > 2 * 0.03
    for s_true in (path.length - 0.03, 0.03):
        found = path.nearest(path.position(s_true), s_hint=None if s_hint is None else s_hint % path.length)
        assert (found - s_true + path.length / 2) % path.length - path.length / 2 == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("s", [10.0, 12.0, -1.0])
def test_sample_of_an_open_path_is_held_at_its_ends(s):
    """sample() at an open path's end or past either end (the follower's look-ahead reaches past it) is its end
    point: (x, y, heading, curvature) of the straight 10 m path at x = 10 m, or at x = 0 before its start."""
    path = make_path(PathConfig(name="straight", length_m=10.0))
    end = min(max(s, 0.0), 10.0)
    assert path.sample(s) == pytest.approx((end, 0.0, 0.0, 0.0), abs=1e-12)


def test_nearest_past_an_open_paths_end_is_its_end():
    path = make_path(PathConfig(name="straight", length_m=10.0))
    assert path.nearest([12.0, 0.0]) == pytest.approx(10.0, abs=1e-12)


def test_nearest_with_a_hint_searches_the_whole_window():
    """window_m 0.25 over the 0.1 m samples reaches the third sample (0.3 m) past the hint 0: the point at 0.35 m
    lies on the chord after it, and is found there."""
    path = make_path(PathConfig(name="straight"))
    assert path.spacing == pytest.approx(0.1, rel=1e-12)
    assert path.nearest([0.35, 0.0], s_hint=0.0, window_m=0.25) == pytest.approx(0.35, abs=1e-9)


def test_the_s_shape_turns_left_then_right():
    """MANOEUVRE_TURNS: after the 20 m lead a left half-circle of R = 15 m (centre (20, 15)) to (20, 30) heading pi,
    then a right one (centre (20, 45)) to (20, 60) heading 0: 10 m on, at (30, 60) heading 0; the second half-circle's
    curvature is -1 / R."""
    path = make_path(PathConfig(name="s-shape"))
    lead, radius = 20.0, 15.0
    s = lead + 2 * np.pi * radius + 10.0
    np.testing.assert_allclose(path.position(s), [30.0, 60.0], atol=1e-3)
    assert path.heading(s) == pytest.approx(0.0, abs=1e-6)
    assert path.curvature(lead + np.pi * radius + 1.0) == pytest.approx(-1.0 / radius, rel=1e-9)


def test_the_rectangle_is_side_m_by_half_of_it_with_rounded_corners():
    """PathConfig: the rectangle's long straight is side_m, the short one side_m / 2, joined by quarter circles of
    radius_m: its extent is side_m + 2 radius_m by side_m / 2 + 2 radius_m."""
    side, radius = 40.0, 10.0
    path = make_path(PathConfig(name="rectangle", side_m=side, radius_m=radius))
    np.testing.assert_allclose(path.xy.max(axis=0) - path.xy.min(axis=0), [side + 2 * radius, side / 2 + 2 * radius],
                               atol=1e-3)
    assert path.length == pytest.approx(2 * (side + side / 2) + 2 * np.pi * radius, rel=1e-9)


@pytest.mark.parametrize("name", [n for n in PATH_NAMES if n != "sine"])
def test_follower_tracks_seed_003_figure_9_paths(name):
    config = GroundVehicleConfig(path=name)
    path = make_path(config.path_config())
    distance = path.length if path.closed else 200.0  # past the manoeuvre
    states, progress = follow(config, speed=2.0, distance=distance)
    errors = cross_track_errors(path, states)
    assert errors.max() < 0.2 and np.sqrt(np.mean(errors**2)) < 0.05
    assert_progress(progress, distance, path, config, speed=2.0)


def test_follower_keeps_to_the_circle_past_its_closing_point():
    """On a closed path the path's heading jumps back by 2 pi where the arc length wraps, the vehicle's does not: 1.3
    laps of the 15 m circle (centre (0, 15), turning left from the origin) at 2 m/s stay on it."""
    config = GroundVehicleConfig(path="circle")
    laps = 1.3
    states, _ = follow(config, speed=2.0, distance=laps * 2 * np.pi * 15.0)
    off_circle = np.abs(np.linalg.norm(states[:2].T - [0.0, 15.0], axis=1) - 15.0)
    assert off_circle.max() < 0.05  # m: the seed-003 paths' RMS bound above; started on the circle, it stays on it
    assert states[2, -1] > 2 * np.pi * (laps - 0.05)  # went round, past the closing point


@pytest.mark.parametrize("speed", [3.0, 6.0, 12.0])  # seed 002 cases C1, C2, C3
def test_follower_tracks_seed_002_sine_path(speed):
    config = GroundVehicleConfig(path="sine", path_length_m=700.0)
    states, progress = follow(config, speed=speed, distance=600.0)
    path = make_path(config.path_config())
    errors = cross_track_errors(path, states)
    assert errors.max() < 0.1
    assert_progress(progress, 600.0, path, config, speed)
    assert np.degrees(np.abs(states[3]).max()) < config.max_steering_deg


def test_the_narrowest_search_window_accepted_keeps_up_with_the_vehicle():
    """12 m/s on Eq. (13) at 20 Hz: 0.6 m per update plus the 0.1 m spacing; a 0.71 m window still follows."""
    config = GroundVehicleConfig(path="sine", speed=12.0, path_length_m=300.0)
    config.follower.search_window_m = 0.71
    states, progress = follow(config, speed=12.0, distance=240.0, time_period=0.005)
    path = make_path(config.path_config())
    assert cross_track_errors(path, states).max() < 0.1
    assert_progress(progress, 240.0, path, config, speed=12.0)


def test_the_follower_searches_near_its_last_point_where_the_figure_eight_crosses():
    """The figure-eight (R = 15 m, length L = 4 R + 3 pi R) crosses itself at the origin: at s = 0 heading 45 deg, and
    at s = L / 2 heading 45 - 270 = -225 deg. A vehicle 0.1 m left of the second branch 2 cm past the crossing is
    2 cm from the first branch (at s = L - 0.1 m); the follower, last at L / 2, keeps to the second."""
    config = GroundVehicleConfig(path="figure-eight")
    path = make_path(config.path_config())
    R = 15.0
    L = 4 * R + 3 * np.pi * R
    assert path.length == pytest.approx(L, rel=1e-9)
    heading = np.pi / 4 - 1.5 * np.pi
    along, left = np.array([np.cos(heading), np.sin(heading)]), np.array([-np.sin(heading), np.cos(heading)])
    position = 0.02 * along + 0.1 * left
    follower = PathFollower(path, config)
    context = follower.CreateDefaultContext()
    follower.GetInputPort("state").FixValue(context, [*position, heading, 0.0])
    follower.GetInputPort("speed").FixValue(context, [2.0])
    context.SetDiscreteState(0, [L / 2])  # path_progress
    progress = follower.EvalUniquePeriodicDiscreteUpdate(context).get_vector(0).GetAtIndex(0)
    assert progress == pytest.approx(L / 2 + 0.02, abs=1e-3)


@pytest.mark.parametrize("speed", [10.0, 2.0])
def test_the_follower_places_the_three_poles_at_minus_a(speed):
    """The module docstring's linearised model about a straight path, per distance travelled, state (e, psi, theta):
    e' = psi, psi' = theta / d, theta' = (theta_cmd - theta) / (v tau_s), with the command's gains on e (y here),
    psi (alpha) and theta by finite differences; its characteristic polynomial is (s + a)^3,
    a = 1 / max(preview_time_s v, min_preview_m) (1 / 10 m at 10 m/s, 1 / 5 m at 2 m/s)."""
    config = GroundVehicleConfig(wheelbase_m=3.5, steering_time_constant_s=1.0)
    path = make_path(config.path_config())
    d, lag = 3.5, speed * 1.0
    a = 1.0 / max(config.follower.preview_time_s * speed, config.follower.min_preview_m)
    assert a == {10.0: 0.1, 2.0: 0.2}[speed]  # the defaults: 1 s, 5 m
    state, h = np.array([5.0, 0.0, 0.0, 0.0]), 1e-4
    command0 = steering_command(state, speed, path, 5.0, config)
    gradient = np.array([(steering_command(state + h * np.eye(4)[i], speed, path, 5.0, config) - command0) / h
                         for i in (1, 2, 3)])  # d command / d (e, psi, theta)
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0 / d], (gradient - [0.0, 0.0, 1.0]) / lag])
    np.testing.assert_allclose(np.poly(A), [1.0, 3 * a, 3 * a**2, a**3], rtol=1e-6)


def test_discretised_vehicle_drives_as_the_continuous_one():
    # The bicycle integrated per 5 ms period (the gv-landing default) gets each 20 Hz steering
    # command one period late: ~4 mm apart after 100 m of the figure-eight at 3 m/s.
    config = GroundVehicleConfig(path="figure-eight")
    positions = []
    for time_period in (None, 0.005):
        builder = DiagramBuilder()
        vehicle = builder.AddSystem(GroundVehicle(config, time_period))
        source = builder.AddSystem(ConstantVectorSource([3.0]))
        builder.Connect(source.get_output_port(), vehicle.GetInputPort("speed"))
        simulator = Simulator(builder.Build())
        simulator.get_mutable_integrator().set_target_accuracy(1e-9)
        root = simulator.get_mutable_context()
        vehicle.set_state(root, vehicle.initial_state())
        assert root.num_continuous_states() == (4 if time_period is None else 0)
        state = vehicle.GetOutputPort("state")
        positions.append([])
        for t in range(1, 34):  # whole periods: the discrete state is the state at t
            simulator.AdvanceTo(float(t))
            positions[-1].append(state.Eval(vehicle.GetMyContextFromRoot(root))[:2].copy())
    continuous, discrete = np.array(positions)
    assert np.linalg.norm(np.diff(continuous, axis=0), axis=1).sum() > 90.0  # along the lobes
    assert np.abs(discrete - continuous).max() < 6e-3


@pytest.mark.parametrize("times, speeds", [([], []), ([5.0, 10.0], [1.0, 2.0]), ([3.0], [1.5])])
def test_distance_driven_is_the_simulated_vehicles(times, speeds):
    """distance_driven_m against the vehicle on a straight path driven by speed_profile's TrajectorySource (held
    before the first point and after the last); the discrete vehicle holds each 5 ms speed sample, so lags a
    little while the speed changes (half a period times the speed gained)."""
    config = GroundVehicleConfig(speed=0.7, speed_schedule_times_s=times, speed_schedule_m_s=speeds)
    builder = DiagramBuilder()
    vehicle = builder.AddSystem(GroundVehicle(config, 0.005))
    profile = config.speed_profile()
    source = builder.AddSystem(ConstantVectorSource([config.speed]) if profile is None else
                               TrajectorySource(profile, 0, True))
    builder.Connect(source.get_output_port(), vehicle.GetInputPort("speed"))
    simulator = Simulator(builder.Build())
    root = simulator.get_mutable_context()
    vehicle.set_state(root, vehicle.initial_state())
    for t in (3.0, 7.5, 12.0):
        simulator.AdvanceTo(t)
        x = vehicle.GetOutputPort("state").Eval(vehicle.GetMyContextFromRoot(root))[0]
        assert config.distance_driven_m(t) == pytest.approx(x, abs=3e-3)  # lag: 1 m/s gained x 2.5 ms
    expected = {(): 0.7 * 12.0, (5.0, 10.0): 5.0 + 7.5 + 4.0, (3.0,): 1.5 * 12.0}[tuple(times)]
    assert config.distance_driven_m(12.0) == pytest.approx(expected, rel=1e-12)
    assert config.distance_driven_m(12.0, 0.5) == pytest.approx(expected / 2, rel=1e-12)


def test_the_ground_covers_what_the_vehicle_drives_in_the_run():
    """gv-marker-ekf drives 500 m of the sine path (to x 441 m); the ground had covered its first 400 m (x 380 m)."""
    config = GroundVehicleConfig(path="sine", speed=6.0)
    path = make_path(config.path_config())
    lower, upper = config.ground_extent(duration_s=500.0 / 6.0)
    end = path.position(500.0)
    assert np.all(lower + 25.0 <= end) and np.all(end <= upper - 24.0)
    # Within 400 m the ground is as it was: 120 s at 0.5 m/s, or no run length given.
    for short in (GroundVehicleConfig(), GroundVehicleConfig(path="sine", speed=3.0)):
        np.testing.assert_array_equal(short.ground_extent(duration_s=120.0), short.ground_extent())
        xy = make_path(short.path_config()).polyline(400.0)
        np.testing.assert_array_equal(short.ground_extent()[1], xy.max(axis=0) + 25.0)


def test_the_ground_reaches_the_furthest_distractor():
    """With distractors' lead (factor 1.4, ahead 15 m), the ground covers where the furthest one gets: it starts
    15 m ahead and drives 1.4 times the UGV's 10 m/s, 15 + 1.4 x 10 x 100 = 1415 m along at 100 s (the ahead
    metres are not scaled by the factor, nor dropped)."""
    config = GroundVehicleConfig(path="straight", speed=10.0)
    assert config.ground_length_m(100.0, (1.4, 15.0)) == pytest.approx(15.0 + 1.4 * 10.0 * 100.0, rel=1e-12)


def test_ground_pose():
    X_WV = ground_pose([3.0, -4.0, np.pi / 2, 0.1])
    np.testing.assert_allclose(X_WV.translation(), [3.0, -4.0, 0.0])
    np.testing.assert_allclose(X_WV.rotation().matrix() @ [1, 0, 0], [0, 1, 0], atol=1e-15)


@pytest.mark.parametrize("time_period", [None, 0.005])
def test_the_state_does_not_feed_through_from_the_speed(time_period):
    # The speed drives the state's derivative, never the state output itself (no algebraic loop for
    # a controller that sets the speed from the state).
    vehicle = GroundVehicle(GroundVehicleConfig(), time_period)
    speed, state = vehicle.GetInputPort("speed").get_index(), vehicle.GetOutputPort("state").get_index()
    assert not vehicle.HasDirectFeedthrough(speed, state)


@pytest.mark.parametrize("time_period", [0.0, -0.005])
def test_a_time_period_that_is_not_positive_is_a_config_error(time_period):
    """Unchecked, DiscreteTimeApproximation fails its time_period > 0 check: pydrake raises SystemExit."""
    with pytest.raises(ConfigError, match="ground vehicle time_period must be positive"):
        GroundVehicle(GroundVehicleConfig(), time_period)
