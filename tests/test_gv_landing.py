"""The gv-landing diagram (issue 4): a full landing, failures reported in metrics, configuration
errors naming their field, the true relative state, the two flight controller backends flying alike,
the discrete vehicles against the continuous ones, the monitor, Meshcat, and the CLI run."""

import dataclasses
import json
import re

import numpy as np
import pytest
from pydrake.geometry import Meshcat
from pydrake.math import RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.primitives import LinearSystem
from scipy.integrate import solve_ivp

from diagrams.cli import main
from diagrams.deck_landing import build_deck_landing
from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_config import (
    EXPLICIT_STABILITY_LIMITS,
    FIXED_STEP_SCHEMES,
    INTEGRATION_SCHEMES,
    GvLandingConfig,
    IntegrationConfig,
)
from diagrams.gv_landing_run import fly, fly_diagram, summary_lines
from diagrams.rqrlp_maneuvers import build_rqrlp_maneuvers
from diagrams.rqrlp_maneuvers_run import fly as fly_maneuvers
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.control.landing import Mode
from systems.control.monitor import (
    FAILURE_REASONS,
    LandingMonitor,
    TerminationConfig,
    gear_on_pad,
    pad_offset,
)
from systems.perception.seam import A_WP, HEIGHT, P_BP_B, P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID, SeamSplit
from systems.perception.truth import PadMotionTruth, PadPose, PadVelocity, RelativeStateTruth, in_view, pad_motion
from systems.vehicles.ground_vehicle import bicycle_state_derivative
from systems.vehicles.quadrotor import (
    P_WB,
    V_WB,
    hover_state,
    pose_from_state,
    quadrotor_state,
    quadrotor_state_derivative,
)
from tests.conftest import wiring

# pydrake filters numpy's "invalid value" warnings from symbolic object arrays when imported;
# pytest resets warning filters per test, so restore that one here.
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


@pytest.fixture(scope="module")
def straight_landing():
    """The gv-landing scenario as shipped: straight path, 0.5 m/s."""
    _, scenario = load_scenario("gv-landing")
    metrics, flight = fly(scenario, scenario.duration_s)
    return scenario, metrics, flight


def test_full_landing_on_a_straight_path_at_half_a_metre_per_second(straight_landing):
    scenario, metrics, flight = straight_landing
    assert (scenario.vehicle.path, scenario.vehicle.speed) == ("straight", 0.5)
    landing = metrics["landing"]
    assert landing["success"] and landing["failure_reason"] is None
    assert landing["touchdown_error_m"] < 0.10
    assert landing["touchdown_rel_speed_mps"] < 0.5
    assert 10.0 < landing["time_to_land_s"] < scenario.duration_s
    # The supervisor went through its modes in order, and touchdown is within its threshold.
    times = landing["mode_entry_times_s"]
    assert times["takeoff"] < times["climb"] < times["follow"] < times["approach"] < times["land"] < times["landed"]
    assert 0.0 < landing["touchdown_height_m"] <= scenario.landing.touchdown_height_m
    assert landing["aborts"] == landing["retries"] == 0
    # Seed 003 Fig. 8: the tracking error settles to about 0.01 m before the final descent.
    assert max(metrics["tracking"]["before_final_descent_max_abs_xy_m"]) < 0.01
    assert flight.status.startswith("landed")
    assert flight.log["quadrotor_state"].shape[1] == 17 and np.isfinite(flight.log["quadrotor_state"]).all()


def test_tracks_a_curving_vehicle_to_a_centimetre_at_its_real_speed():
    # Seed 003's real vehicle limit (1.5 m/s) on the 15 m circle: the tracking error before the final
    # descent within Fig. 8's ~0.01 m thanks to the feed-forwards (without them: ~0.06 m).
    _, scenario = load_scenario("gv-landing", overrides=["vehicle.path=circle", "vehicle.speed=1.5"])
    metrics, _ = fly(scenario, scenario.duration_s)
    assert metrics["landing"]["meets_targets"] and metrics["landing"]["vehicle_turn_radius_at_touchdown_m"] < 16
    assert max(metrics["tracking"]["before_final_descent_max_abs_xy_m"]) < 0.01


def test_unstable_gains_end_as_a_failure_in_the_metrics():
    _, scenario = load_scenario("gv-landing", overrides=["pid.gains_above.kp=8", "pid.gains_below.kp=8"],
                                duration_s=70.0)
    metrics, _ = fly(scenario, scenario.duration_s)
    landing = metrics["landing"]
    assert not landing["success"] and not landing["meets_targets"]
    assert landing["failure_reason"] in FAILURE_REASONS and landing["failure_detail"]
    assert not landing["failure_detail"].startswith(landing["failure_reason"])  # said once: "diverged: ..."


@pytest.mark.parametrize("assignment, field", [
    ("landing.initial_height_m=1.0", "landing.initial_height_m"),  # IH below LH
    ("vehicle.path=zigzag", "vehicle.path"),
    ("vehicle.wheelbase_m=0", "vehicle.wheelbase_m"),
    ("vehicle.max_steering_deg=0", "vehicle.max_steering_deg"),
    ("quadrotor.mass_kg=-1.2", "quadrotor.mass_kg"),
    ("platform.pad_size_m=2.5", "platform.pad_size_m"),
    ("platform.pad_size_m=0.8", "platform.markers"),  # the corner markers hang off a smaller pad
    ("platform.markers.ids=[0, 1, 2, 3, 99]", "platform.markers.ids"),
    ("integration.scheme=runge_kutta9", "integration.scheme"),
    ("integration.accuracy=1", "integration.accuracy must be in"),  # (0, 1): open at 1
    ("estimation.sigma_deg=-1", "estimation.sigma_p_m and sigma_deg must not be negative"),
    # The loops nest: the supervisor reads the PID, the flight controller the supervisor (and logs at its rate).
    ("pid.rate_hz=60", "controller.rate_hz >= landing.rate_hz >= pid.rate_hz: they are 200, 50 and 60 Hz"),
    ("landing.rate_hz=250", "controller.rate_hz >= landing.rate_hz >= pid.rate_hz: they are 200, 250 and 4 Hz"),
    ("controller.rate_hz=0.01", "controller.rate_hz"),  # froze both vehicles over the run
    ("landing.rate_hz=0.01", "landing.rate_hz"),  # dated the metrics at t = 0
])
def test_impossible_configuration_is_a_config_error_naming_the_field(assignment, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_scenario("gv-landing", overrides=[assignment])


@pytest.mark.parametrize("watching", ["[]", "[ct_ekf]"])
def test_the_steering_filter_s_history_must_cover_the_stream_s_latency(watching):
    """estimation.ekf.history_s under the stream's latency (one 35 ms period) leaves every sample too late for the
    filter that steers as for one that only watches (the check had looked at the watching ones alone, so a run
    steered by ct_ekf with none watching loaded)."""
    overrides = ["perception.source=ct_ekf", "estimation.source=synthetic", "estimation.ekf.history_s=0.01",
                 f"estimation.filters={watching}"]
    with pytest.raises(ConfigError, match=r"^estimation\.ekf\.history_s \(0\.01 s\) must be at least the stream's "
                                          r"latency, estimation\.latency_periods x the filter step \(0\.035 s\)"):
        load_scenario("gv-landing", overrides=overrides)
    assert load_scenario("gv-landing", overrides=overrides[:2] + [f"estimation.filters={watching}"])[1].filter_names \
        == ["ct_ekf"]


@pytest.mark.parametrize("overrides, message", [
    (["perception.source=federated", "platform.pattern=rqrlp", "estimation.source=detector"],
     "perception.source 'federated' brings its own camera: estimation.source detector would add a second one"),
    (["platform.pattern=rqrlp", "estimation.source=synthetic"],
     "estimation.source synthetic measures the ArUco markers, and platform.pattern is rqrlp"),
], ids=["second-camera", "no-markers"])
def test_a_marker_stream_needs_the_markers_and_no_second_camera(overrides, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_scenario("gv-landing", overrides=overrides)


def test_a_history_of_exactly_the_streams_latency_covers_it():
    """Three 35 ms periods of latency with 105 ms of history: the last sample is just in time (3 x 0.035 is a hair
    over 0.105 in floats, and the check allows for that)."""
    assert 3 * 0.035 > 0.105
    _, scenario = load_scenario("gv-marker-ekf", overrides=["estimation.latency_periods=3",
                                                            "estimation.ekf.history_s=0.105"])
    assert scenario.filter_names


@pytest.mark.parametrize("overrides, named", [
    (["start.xy_m=[0.5, 0.0]"], "start.xy_m [0.5, 0.0] at start.height_m (0 m) is inside the ground vehicle's body"),
    (["start.xy_m=[1.75, 0.0]", "start.height_m=1.5"], "start.xy_m [1.75, 0.0] at start.height_m (1.5 m) is inside"),
    (["start.height_m=70"], "start.height_m (70 m) is above termination.max_altitude_m (60 m)"),
    (["start.xy_m=[300.0, 0.0]"], "start.xy_m [300.0, 0.0] is 298.2 m from the pad, beyond termination.max_distance_m"),
    (["termination.max_altitude_m=7"], "landing.initial_height_m (IH, 7.5 m above the ground) must be below "
                                       "termination.max_altitude_m (7 m)"),
    # IH at the limit: the climb reaches it and the monitor ends the run there
    (["termination.max_altitude_m=7.5", "landing.initial_height_m=7.5"],
     "landing.initial_height_m (IH, 7.5 m above the ground) must be below termination.max_altitude_m (7.5 m)"),
], ids=["in-the-body", "under-the-pad", "above-max-altitude", "beyond-max-distance", "ih-above-max-altitude",
        "ih-at-max-altitude"])
def test_a_start_the_scene_contradicts_is_one_line_and_exit_2(capfd, tmp_path, overrides, named):
    """Before: each ran, ending at t = 0 (or on the climb to IH) as a failure, exit 0 and its files written."""
    out = tmp_path / "out"
    code = main(["run", "gv-landing", *(a for o in overrides for a in ("--set", o)), "--duration", "3",
                 "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and named in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_a_start_beside_over_or_far_from_the_vehicle_within_the_limits_is_accepted():
    for overrides in (["start.xy_m=[1.75, 0.0]", "start.height_m=1.7"],  # over the pad, above the body
                      ["start.xy_m=[1.75, 1.0]"],  # beside the 1.8 m wide body, on the ground
                      ["start.xy_m=[201.75, 0.0]", "start.height_m=60"]):  # at both limits
        load_scenario("gv-landing", overrides=overrides)


@pytest.mark.parametrize("name, builder", [("gv-landing", build_gv_landing), ("deck-landing", build_deck_landing),
                                           ("rqrlp-maneuvers", build_rqrlp_maneuvers)])
def test_the_uav_starts_turned_by_start_yaw_deg_counterclockwise(name, builder):
    """start.yaw_deg = 30 starts the UAV level and turned 30 degrees counterclockwise seen from above (about
    +z, toward +y): its body x axis points along (cos 30, sin 30, 0) in World, at the start position; in each
    scenario that flies from a StartConfig."""
    _, scenario = load_scenario(name, overrides=["start.yaw_deg=30", "start.xy_m=[-2.0, 1.0]"])
    diagram, handles = builder(scenario)
    context = diagram.CreateDefaultContext()
    handles.initialize(context)
    X_WB = handles.quadrotor.GetOutputPort("X_WB").Eval(handles.quadrotor.GetMyContextFromRoot(context))
    R = X_WB.rotation().matrix()
    np.testing.assert_allclose(R[:, 0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(X_WB.translation(), [-2.0, 1.0, scenario.start.height_m], atol=1e-12)


def test_a_path_tighter_than_the_vehicle_turns_names_its_radius():
    with pytest.raises(ConfigError, match=r"vehicle\.path_radius_m"):
        load_scenario("gv-landing", overrides=["vehicle.path=circle", "vehicle.path_radius_m=5"])
    load_scenario("gv-landing", overrides=["vehicle.path_radius_m=5"])  # the straight path has no arcs


@pytest.mark.parametrize("overrides, shortest", [
    (["vehicle.steering_time_constant_s=0.001"], "0.00151"),  # RK5's fixed 5 ms steps: 5 ms / 3.3066
    (["vehicle.steering_time_constant_s=0.001", "integration.discrete=false"], "0.00151"),  # the Simulator's steps
    (["vehicle.steering_time_constant_s=0.002", "integration.scheme=explicit_euler"], "0.0025"),
    # exactly at explicit Euler's bound, h / tau = 2: R = 1 - 2 = -1, an error that never decays
    (["vehicle.steering_time_constant_s=0.0025", "integration.scheme=explicit_euler"], "0.0025"),
    # explicit Euler has no error estimate: its steps stay fixed
    (["vehicle.steering_time_constant_s=0.002", "integration.scheme=explicit_euler", "integration.error_control=true"],
     "0.0025"),
    (["vehicle.steering_time_constant_s=0.002", "integration.max_step_s=0.02", "controller.rate_hz=50"], "0.00605"),
])
def test_a_steering_lag_too_short_for_the_fixed_steps_names_both_keys(overrides, shortest):
    """A lag shorter than the fixed steps integrate stably had the vehicle's state go non-finite, and the run
    blamed the UAV ("diverged")."""
    with pytest.raises(ConfigError, match=rf"^vehicle\.steering_time_constant_s \(\S+ s\) must exceed {shortest} s: "
                                          rf"integration\.scheme .*integration\.max_step_s"):
        load_scenario("gv-landing", overrides=overrides)


@pytest.mark.parametrize("overrides", [
    ["vehicle.steering_time_constant_s=0.0016"],  # above RK5's 1.51 ms
    ["vehicle.steering_time_constant_s=0.002", "integration.max_step_s=0.01"],  # the steps end at the 5 ms period
    ["vehicle.steering_time_constant_s=0.001", "integration.error_control=true"],
    ["vehicle.steering_time_constant_s=0.001", "integration.scheme=radau3"],  # A-stable
])
def test_a_steering_lag_the_steps_integrate_stably_is_accepted(overrides):
    load_scenario("gv-landing", overrides=overrides)


@pytest.mark.parametrize("scheme", INTEGRATION_SCHEMES)
def test_the_stability_limits_are_drakes(scheme):
    """y' = -y integrated with fixed steps h just under the scheme's limit decays, just over it grows; the schemes
    with no error estimate keep fixed steps under error control, the others do not."""
    def magnitude_after_steps(step: float, error_control: bool = False) -> tuple[float, bool]:
        system = LinearSystem([[-1.0]], [[0.0]], [[1.0]], [[0.0]])
        simulator = Simulator(system)
        ApplySimulatorConfig(SimulatorConfig(integration_scheme=scheme, max_step_size=step,
                                             use_error_control=error_control), simulator)
        context = simulator.get_mutable_context()
        context.SetContinuousState([1.0])
        system.get_input_port().FixValue(context, [0.0])
        simulator.AdvanceTo(3000 * step)
        return abs(context.get_continuous_state_vector()[0]), simulator.get_integrator().get_fixed_step_mode()

    limit = EXPLICIT_STABILITY_LIMITS.get(scheme)
    if limit is None:  # implicit: stable at any step
        assert magnitude_after_steps(10.0)[0] < 1e-3
    else:
        assert magnitude_after_steps(0.999 * limit)[0] < 1.0 < magnitude_after_steps(1.001 * limit)[0]
    assert magnitude_after_steps(0.01, error_control=True)[1] == (scheme in FIXED_STEP_SCHEMES)


def test_a_path_too_short_for_its_manoeuvre_names_the_flattened_field():
    with pytest.raises(ConfigError, match=r"vehicle\.path_length_m"):
        load_scenario("gv-landing", overrides=["vehicle.path=s-shape", "vehicle.path_length_m=50"])


@pytest.mark.parametrize("overrides, named", [
    (["vehicle.speed=1.0"], "vehicle.speed is 1 m/s"),
    (["vehicle.speed_schedule_times_s=[0, 10]", "vehicle.speed_schedule_m_s=[0, 2]"],
     "vehicle.speed_schedule_m_s reaches 2 m/s"),
])
def test_a_pad_on_the_ground_needs_the_vehicle_at_rest(overrides, named):
    """platform.carrier ground draws no vehicle: a moving one had slid the pad over the ground."""
    with pytest.raises(ConfigError, match=f"platform.carrier ground .*{named}: set platform.carrier vehicle"):
        load_scenario("open-landing", overrides=overrides)
    # open-landing's moving variant, and a schedule that keeps the vehicle still
    load_scenario("open-landing", overrides=["platform.carrier=vehicle", "platform.height_m=1.6", *overrides])
    load_scenario("open-landing", overrides=["vehicle.speed=1.0", "vehicle.speed_schedule_times_s=[0]",
                                             "vehicle.speed_schedule_m_s=[0]"])


def test_the_truth_gives_the_true_relative_state_and_the_split_names_its_parts():
    config = GvLandingConfig()
    truth = RelativeStateTruth(config.vehicle, config.platform, config.perception.field_of_view_deg,
                               config.perception.max_range_m)
    context = truth.CreateDefaultContext()
    # Vehicle at (10, 0) heading +y, steering 0.1 rad (and commanded there: no steering rate),
    # 2 m/s at constant speed; the pad is 1.75 m ahead of the rear axle.
    steering, speed = 0.1, 2.0
    truth.GetInputPort("vehicle_state").FixValue(context, [10.0, 0.0, np.pi / 2, steering])
    truth.GetInputPort("vehicle_speed").FixValue(context, [speed, 0.0])
    truth.GetInputPort("vehicle_steering_command").FixValue(context, [steering])
    X_WB = truth.GetInputPort("X_WB")
    X_WB.FixValue(context, pose_from_state(hover_state(config.quadrotor, [11.0, 2.0, 5.0], yaw=np.pi / 2)))
    relative = truth.get_output_port().Eval(context)
    split = SeamSplit()
    split_context = split.CreateDefaultContext()
    split.get_input_port().FixValue(split_context, relative)
    out = lambda name: split.GetOutputPort(name).Eval(split_context)  # noqa: E731
    p_WP = np.array([10.0, 1.75, 1.6])
    np.testing.assert_allclose(out("p_BP_W"), p_WP - [11.0, 2.0, 5.0], atol=1e-12)
    np.testing.assert_allclose(out("target_offset"), [-1.0, -0.25], atol=1e-12)
    np.testing.assert_allclose(out("p_BP_B"), [-0.25, 1.0, -3.4], atol=1e-12)  # yawed 90 deg: x_B = +y_W
    np.testing.assert_allclose(out("height_above_target"), [3.4], atol=1e-12)
    # The pad turns about the rear axle at v tan(steering) / d: its velocity gains -w * 1.75 along x.
    yaw_rate = speed * np.tan(steering) / config.vehicle.wheelbase_m
    np.testing.assert_allclose(out("target_velocity"), [-yaw_rate * 1.75, speed], atol=1e-12)
    # On a circle about the turn centre (d / tan(steering) left of the rear axle), the pad's
    # acceleration is centripetal: |v_P|^2 / radius, towards the centre.
    centre = np.array([10.0 - config.vehicle.wheelbase_m / np.tan(steering), 0.0])
    to_centre = centre - p_WP[:2]
    v_P = np.hypot(speed, yaw_rate * 1.75)
    np.testing.assert_allclose(out("target_acceleration"), v_P**2 / np.linalg.norm(to_centre)**2 * to_centre,
                               atol=1e-12)
    assert out("target_valid")[0] == 1.0
    np.testing.assert_allclose(relative[P_BP_W], out("p_BP_W"))
    np.testing.assert_allclose(relative[P_BP_B], out("p_BP_B"))
    assert relative[HEIGHT] == pytest.approx(3.4) and relative[V_WP][2] == 0.0 and relative[A_WP][2] == 0.0
    np.testing.assert_allclose(relative[A_WP][:2], out("target_acceleration"))
    # Rolled 80 deg, the camera cone (150 deg) no longer holds the pad: not valid.
    X_WB.FixValue(context, pose_from_state(quadrotor_state(p_WB=[11.0, 2.0, 5.0],
                                                           R_WB=RotationMatrix(RollPitchYaw(1.4, 0, 0)))))
    assert truth.get_output_port().Eval(context)[VALID] == 0.0


@pytest.mark.parametrize("p_WB, roll_rad, valid", [
    ([11.0, 2.0, 5.0], 0.0, 1.0),
    # rolled 1.4 rad, the pad at (10, 1.75, 1.6) lies 84.6 deg off -z_B: outside the 150 deg cone, inside 180 deg
    ([11.0, 2.0, 5.0], 1.4, 0.0),
    ([11.0, 2.0, 40.0], 0.0, 0.0),  # 38.4 m from the pad, beyond 30 m
])
def test_the_truths_default_view_is_the_150_deg_cone_out_to_30_m(p_WB, roll_rad, valid):
    """RelativeStateTruth without view arguments: the perception config's defaults, seed 003's fisheye."""
    config = GvLandingConfig()
    truth = RelativeStateTruth(config.vehicle, config.platform)
    context = truth.CreateDefaultContext()
    # At rest at (10, 0) heading +y: the pad 1.75 m ahead of the rear axle, at (10, 1.75, 1.6)
    truth.GetInputPort("vehicle_state").FixValue(context, [10.0, 0.0, np.pi / 2, 0.0])
    truth.GetInputPort("vehicle_speed").FixValue(context, [0.0, 0.0])
    truth.GetInputPort("vehicle_steering_command").FixValue(context, [0.0])
    truth.GetInputPort("X_WB").FixValue(context, pose_from_state(quadrotor_state(
        p_WB=p_WB, R_WB=RotationMatrix(RollPitchYaw(roll_rad, 0, 0)))))
    assert truth.get_output_port().Eval(context)[VALID] == valid


@pytest.mark.parametrize("p_BP_B, seen", [
    ([0.0, 0.0, -3.0], True),  # straight below
    ([0.0, 0.0, 3.0], False),  # straight above
    ([0.0, 0.0, 0.0], True),  # at the camera: no direction, but no distance either
    ([0.0, 0.0, -29.0], True), ([0.0, 0.0, -31.0], False),  # either side of the 30 m range
    ([0.0, 0.0, -30.0], True),  # at the range
    # 74 and 76 deg off -z_B, either side of the cone's 75 deg half angle
    ([5.0 * np.sin(np.radians(74.0)), 0.0, -5.0 * np.cos(np.radians(74.0))], True),
    ([0.0, -5.0 * np.sin(np.radians(76.0)), -5.0 * np.cos(np.radians(76.0))], False),
])
def test_the_pad_is_in_view_inside_the_downward_cone_and_range(p_BP_B, seen):
    """in_view: the cone of 150 deg about -z_B, out to 30 m."""
    assert in_view(np.array(p_BP_B), 150.0, 30.0) == seen


@pytest.mark.parametrize("view", [(150.0, 30.0), ()], ids=["given", "default"])
@pytest.mark.parametrize("p_WB, roll_deg, valid", [([0.0, 0.0, 5.0], 0.0, 1.0), ([0.0, 0.0, 5.0], 80.0, 0.0),
                                                   ([0.0, 0.0, 40.0], 0.0, 0.0)])
def test_the_given_pad_motions_truth_is_valid_only_in_view(p_WB, roll_deg, valid, view):
    """PadMotionTruth (the Stewart deck's seam), given the view or by default: valid level 5 m over the pad, not rolled
    80 deg (the pad 80 deg off -z_B, outside the 150 deg cone) nor 40 m over it (beyond 30 m). The pad's motion
    [p; v; a] gives the seam's position, velocity and acceleration."""
    truth = PadMotionTruth(*view)
    context = truth.CreateDefaultContext()
    truth.GetInputPort("pad_motion").FixValue(context, [0.0, 0.0, 0.0, 1.0, 2.0, 0.0, 3.0, 4.0, 0.0])
    truth.GetInputPort("X_WB").FixValue(context, pose_from_state(quadrotor_state(
        p_WB=p_WB, R_WB=RotationMatrix(RollPitchYaw(np.radians(roll_deg), 0, 0)))))
    relative = truth.get_output_port().Eval(context)
    assert relative[VALID] == valid
    np.testing.assert_allclose(relative[P_BP_W], -np.array(p_WB), atol=1e-12)
    np.testing.assert_array_equal(relative[V_WP], [1.0, 2.0, 0.0])
    np.testing.assert_array_equal(relative[A_WP], [3.0, 4.0, 0.0])


def test_the_pads_acceleration_is_the_rate_of_its_velocity():
    # Along an S with the speed scheduled up and down: the seam's acceleration against the
    # central difference of its velocity at 50 Hz (they differ only where the speed's rate jumps).
    _, scenario = load_scenario("gv-landing", overrides=[
        "vehicle.path=s-shape", "vehicle.path_lead_m=2", "vehicle.speed_schedule_times_s=[0, 5, 10]",
        "vehicle.speed_schedule_m_s=[0, 3, 2]", "termination.stop_on_landed=false"])
    diagram, handles = build_gv_landing(scenario)
    flight = fly_diagram(diagram, handles, 20.0)
    t, relative = flight.log["t"], flight.log["true_relative_state"]
    acceleration = relative[:, A_WP]
    difference = np.abs(np.gradient(relative[:, V_WP], t, axis=0) - acceleration)
    assert np.abs(acceleration[:, :2]).max() > 0.5 and not acceleration[:, 2].any()
    assert np.percentile(difference, 95) < 2e-3 and np.median(difference) < 1e-4


def test_the_pads_acceleration_is_the_rate_of_its_velocity_at_a_large_steering_angle():
    """pad_motion's a_WP against the central difference of its v_WP along the bicycle model (seed 002 Eq. 6) at
    steering 0.5 rad turning back at 0.5 rad/s, the speed rising: d tan(steering)/dt is the steering rate times
    sec^2(steering), 1.3 times the rate here (the S above steers too little to show it)."""
    config = GvLandingConfig()
    vehicle = dataclasses.replace(config.vehicle, max_steering_deg=45.0)
    state, speed, speed_rate, dt = np.array([3.0, -1.0, 0.4, 0.5]), 4.0, 0.5, 1e-5
    rate = bicycle_state_derivative(state, 0.0, speed, vehicle)  # steering back towards 0
    assert rate[3] == pytest.approx(-0.5 / vehicle.steering_time_constant_s)

    def motion(step):
        return pad_motion(state + step * rate, speed + step * speed_rate, speed_rate, rate[3], vehicle,
                          config.platform)

    np.testing.assert_allclose(motion(0.0)[2], (motion(dt)[1] - motion(-dt)[1]) / (2 * dt), atol=1e-6)


def test_the_pad_velocity_is_the_rate_of_the_pad_pose():
    """PadVelocity's [w; v] (which feeds the camera's motion-blur flow) against the central difference of
    PadPose's X_WP along the bicycle model, turning left at steering 0.2 rad: w is the heading's rate about +z_W."""
    config = GvLandingConfig()
    velocity, pose = PadVelocity(config.vehicle, config.platform), PadPose(config.platform)
    state, speed, dt = np.array([3.0, -1.0, 0.4, 0.2]), 4.0, 1e-5
    context = velocity.CreateDefaultContext()
    velocity.GetInputPort("vehicle_state").FixValue(context, state)
    velocity.GetInputPort("vehicle_speed").FixValue(context, [speed, 0.0])
    V_WP = velocity.get_output_port().Eval(context)
    rate = bicycle_state_derivative(state, state[3], speed, config.vehicle)  # steering held

    def X_WP(step):
        pose_context = pose.CreateDefaultContext()
        pose.get_input_port().FixValue(pose_context, state + step * rate)
        return pose.get_output_port().Eval(pose_context)

    before, after = X_WP(-dt), X_WP(dt)
    turn = after.rotation().multiply(before.rotation().inverse()).ToAngleAxis()
    assert V_WP[2] > 0.1
    np.testing.assert_allclose(V_WP[:3], turn.axis() * turn.angle() / (2 * dt), atol=1e-6)
    np.testing.assert_allclose(V_WP[3:], (after.translation() - before.translation()) / (2 * dt), atol=1e-6)


@pytest.mark.parametrize("overrides, reported, speed", [
    ([], {"speed_m_s": 0.5}, 0.5),
    (["vehicle.speed_schedule_times_s=[0, 10, 12]", "vehicle.speed_schedule_m_s=[0, 0, 2]"],
     {"speed_schedule_times_s": [0.0, 10.0, 12.0], "speed_schedule_m_s": [0.0, 0.0, 2.0]}, 0.0),
])
def test_metrics_report_the_speed_the_vehicle_drives(overrides, reported, speed):
    """A schedule replaces vehicle.speed: metrics.json had reported vehicle.speed (0.5 m/s) under it. The log's
    vehicle_speed is the speed [m/s] at each sample (not its rate): 0.5 m/s, or the schedule's 0 over its first
    10 s."""
    _, scenario = load_scenario("gv-landing", overrides=overrides)
    metrics, flight = fly(scenario, 0.2)
    assert metrics["vehicle"] == {"path": "straight", **reported}
    json.dumps(metrics)
    assert flight.log["vehicle_speed"].shape == flight.log["t"].shape and len(flight.log["t"]) > 1
    np.testing.assert_array_equal(flight.log["vehicle_speed"], speed)


def test_the_run_lays_the_ground_under_all_it_drives():
    """A run's build covers its length: gv-marker-ekf's 500 m of the sine path, not the first 400 m only."""
    _, scenario = load_scenario("gv-marker-ekf")
    diagram, handles = build_gv_landing(scenario, duration_s=scenario.run_length_s)
    scene_graph = diagram.GetSubsystemByName("scene_graph")
    inspector = scene_graph.model_inspector()
    ground = next(g for g in inspector.GetAllGeometryIds() if inspector.GetName(g).endswith("ground"))
    centre, size = inspector.GetPoseInFrame(ground).translation(), inspector.GetShape(ground).size()
    end = handles.vehicle.path.position(500.0)  # x 441 m
    assert np.all(np.abs(end - centre[:2]) <= size[:2] / 2 - 20.0)
    assert centre[2] + size[2] / 2 == pytest.approx(0.0, abs=1e-12)  # its top at z = 0, the wheels' ground


def test_the_ground_reaches_as_far_as_the_distractors_drive():
    """Distractors drive up to 15 m ahead of the UGV at up to 1.4 times its speed: the ground covers the furthest
    (ugv-hybrid, straight, 1.5 m/s, 300 s: the UGV at x 450 m, a distractor up to 645 m; before, 475 m)."""
    _, scenario = load_scenario("ugv-hybrid", overrides=["vehicle.path=straight", "vehicle.speed=1.5",
                                                         "distractors.count=4"])
    diagram, handles = build_gv_landing(scenario, duration_s=300.0)
    inspector = diagram.GetSubsystemByName("scene_graph").model_inspector()
    ground = next(g for g in inspector.GetAllGeometryIds() if inspector.GetName(g).endswith("ground"))
    centre, size = inspector.GetPoseInFrame(ground).translation(), inspector.GetShape(ground).size()
    furthest = 15.0 + 1.4 * 1.5 * 300.0
    assert centre[0] + size[0] / 2 >= furthest + 20.0


def _positions(overrides, duration_s):
    _, scenario = load_scenario("gv-landing", overrides=overrides)
    diagram, handles = build_gv_landing(scenario)
    flight = fly_diagram(diagram, handles, duration_s)
    return flight.log["t"], flight.log["quadrotor_state"][:, P_WB], flight.log["vehicle_state"][:, :2]


def test_discrete_vehicles_follow_the_continuous_ones():
    # Take-off, climb and following on a circle: the discretised vehicles (RK3 per 5 ms period)
    # against the simulator integrating the continuous ones (RK3, error-controlled at 1e-7).
    path = ["vehicle.path=circle", "vehicle.speed=1.5"]
    t, uav, ugv = _positions(path, 6.0)
    t_c, uav_c, ugv_c = _positions(path + ["integration.discrete=false", "integration.error_control=true",
                                           "integration.accuracy=1.0e-7"], 6.0)
    np.testing.assert_allclose(t, t_c)
    assert np.abs(uav - uav_c).max() < 2e-3  # m, after 8 m of flight
    # The discrete bicycle gets each steering command (20 Hz) 5 ms later: ~1 mm after 9 m on the circle.
    assert np.abs(ugv - ugv_c).max() < 3e-3


@pytest.mark.parametrize("integration", [
    [],  # discretised vehicles, the law evaluated when the quadrotor samples it
    ["integration.discrete=false", "integration.error_control=true", "integration.accuracy=1.0e-7"],  # held
])
def test_python_flight_controller_flies_the_same_as_the_symbolic_one(integration):
    _, uav, _ = _positions(integration, 3.0)
    _, uav_python, _ = _positions(integration + ["controller_implementation=python"], 3.0)
    assert np.abs(uav - uav_python).max() < 1e-6


@pytest.mark.parametrize("name, fly_scenario", [("gv-landing", fly), ("rqrlp-maneuvers", fly_maneuvers)])
def test_continuous_vehicles_integrate_as_the_scenario_says(recorded_simulators, name, fly_scenario):
    """With integration.discrete false the Simulator integrates the vehicles, with the scenario's scheme and
    step (fixed-step RK2 at 1 ms here), not Drake's default (error-controlled RK3)."""
    _, scenario = load_scenario(name, overrides=[
        "integration.discrete=false", "integration.scheme=runge_kutta2", "integration.max_step_s=0.001",
        "integration.error_control=false"])
    fly_scenario(scenario, 0.06)
    integrator = recorded_simulators[-1].get_integrator()
    assert type(integrator).__name__ == "RungeKutta2Integrator"
    assert integrator.get_fixed_step_mode() and integrator.get_maximum_step_size() == 0.001


def test_the_simulator_integrates_with_the_integration_settings_only_for_continuous_vehicles():
    """Discrete vehicles step themselves: the Simulator gets no integrator settings. Continuous ones: all of them,
    error control included."""
    assert IntegrationConfig().diagram_integrator() is None
    config = IntegrationConfig(discrete=False, scheme="runge_kutta3", max_step_s=0.002, error_control=True,
                               accuracy=1e-5).diagram_integrator()
    assert (config.integration_scheme, config.max_step_size, config.use_error_control, config.accuracy) == (
        "runge_kutta3", 0.002, True, 1e-5)


@pytest.mark.parametrize("scheme", ["explicit_euler", "runge_kutta5"])
def test_discrete_vehicles_step_with_the_scenarios_scheme(scheme):
    """The discretised quadrotor and ground vehicle of the built diagram integrate each 5 ms period with the
    scenario's integration.scheme: explicit Euler's step is exactly x + T f(x, u), f their dynamics (seed 002
    Eq. 6-8; 0.037 rad/s off the true step in the rotor speeds here), RK5's the true step within 1e-8 (SciPy's
    DOP853 at 1e-13)."""
    _, config = load_scenario("gv-landing", overrides=[f"integration.scheme={scheme}"])
    _, handles = build_gv_landing(config)
    period = config.period_s
    x = hover_state(config.quadrotor, [1.0, 2.0, 5.0])
    x[V_WB] = [1.0, -0.5, 0.3]
    u = config.quadrotor.hover_rotor_speed() + np.array([30.0, -20.0, 10.0, -15.0])
    bicycle, steering, speed = np.array([1.0, 2.0, 0.3, 0.1]), 0.2, 3.0
    for dynamics, state, inputs, f in (
            (handles.quadrotor.dynamics, x, u, lambda y: quadrotor_state_derivative(y, u, config.quadrotor)),
            (handles.vehicle.dynamics, bicycle, [steering, speed],
             lambda y: bicycle_state_derivative(y, steering, speed, config.vehicle))):
        context = dynamics.CreateDefaultContext()
        context.SetDiscreteState(state)
        dynamics.get_input_port().FixValue(context, inputs)
        stepped = dynamics.EvalUniquePeriodicDiscreteUpdate(context).get_vector().CopyToVector()
        if scheme == "explicit_euler":
            np.testing.assert_allclose(stepped, state + period * f(state), rtol=0, atol=1e-12)
        else:
            true = solve_ivp(lambda t, y: f(y), (0.0, period), state, method="DOP853", rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(stepped, true.y[:, -1], rtol=0, atol=1e-8)


def test_monitor_names_each_way_a_run_ends():
    config = GvLandingConfig()
    monitor = LandingMonitor(config.termination, config.platform, config.landing.touchdown_height_m)
    quad = hover_state(config.quadrotor, [20.0, 0.0, 5.0])
    vehicle = np.array([0.0, 0.0, 0.0, 0.0])
    relative = np.zeros(14)
    relative[P_BP_W], relative[HEIGHT] = [-18.25, 0.0, -3.4], 3.4  # the true relative state of `quad`

    def check(quad=quad, mode=Mode.FOLLOW, last_seen=1.0, t=1.0, seen_ever=True, relative=relative, vehicle=vehicle):
        return monitor.check(t, quad, vehicle, relative, mode, last_seen, seen_ever)

    assert check() is None
    assert check(mode=Mode.LANDED).startswith("landed: the supervisor")
    touching = relative.copy()
    touching[P_BP_W], touching[HEIGHT] = [0.3, -0.2, -0.08], 0.08  # the gear on the pad, whatever the estimate
    assert check(relative=touching).startswith("landed: the gear touched the pad")
    beside = touching.copy()
    beside[P_BP_W] = [0.9, 0.0, -0.08]  # as low, but off the 1 m pad: no touchdown
    assert check(relative=beside) is None
    # The pad turns with the vehicle's heading (not its steering): headed 45 deg, 0.6 m along World x from the centre
    # is (0.6 cos 45, -0.6 sin 45) = (0.42, -0.42) m in the pad frame, on the 1 m pad (0.6 m along P's x is off it).
    touching45 = relative.copy()
    touching45[P_BP_W], touching45[HEIGHT] = [-0.6, 0.0, -0.08], 0.08
    assert check(relative=touching45, vehicle=np.array([0.0, 0.0, np.pi / 4, 0.0])).startswith(
        "landed: the gear touched the pad")
    under = touching.copy()  # over the pad's footprint, under the vehicle's body: not a touchdown, a crash
    under[P_BP_W], under[HEIGHT] = [0.3, -0.2, 1.0], -1.0
    assert check(quad=hover_state(config.quadrotor, [2.0, 0.3, 0.6]), relative=under).startswith(
        "crash: hit the ground vehicle")
    flying_on = LandingMonitor(dataclasses.replace(config.termination, stop_on_landed=False), config.platform,
                               config.landing.touchdown_height_m)  # after touchdown: no estimate needed, no crash
    assert flying_on.check(30.0, quad, vehicle, relative, Mode.LANDED, 1.0) is None
    assert flying_on.check(1.0, hover_state(config.quadrotor, [20.0, 0.0, -0.5]), vehicle, relative, Mode.LANDED,
                           1.0).startswith("crash: hit the ground")
    assert flying_on.check(1.0, hover_state(config.quadrotor, [20.0, 0.0, 80.0]), vehicle, relative, Mode.LANDED,
                           1.0).startswith("diverged: altitude")
    contact = LandingMonitor(config.termination, config.platform, config.landing.touchdown_height_m,
                             ends_on_landed=False)  # landing.touchdown_by contact: LANDED descends on to the touch
    assert contact.check(1.0, quad, vehicle, relative, Mode.LANDED, 1.0) is None
    assert contact.check(1.0, quad, vehicle, touching, Mode.LANDED, 1.0).startswith("landed: the gear touched")
    nan = quad.copy()
    nan[8] = np.nan
    assert check(quad=nan).startswith("diverged")
    assert check(vehicle=np.array([np.nan, 0.0, 0.0, 0.0])).startswith("diverged: non-finite state")
    assert check(quad=hover_state(config.quadrotor, [20.0, 0.0, -0.5])).startswith("crash: hit the ground")
    assert check(quad=hover_state(config.quadrotor, [2.0, 0.3, 1.0])).startswith("crash: hit the ground vehicle")
    fast = quad.copy()
    fast[7] = 100.0
    assert check(quad=fast).startswith("diverged")
    assert check(t=30.0, last_seen=5.0).startswith("target_lost: no valid estimate for 25.0 s")
    assert check(t=30.0, last_seen=0.0, seen_ever=False).startswith("target_lost: no valid estimate of the pad")
    # exactly lost_timeout_s (20 s) without an estimate is not yet lost (t - last_seen is exactly 20.0 here)
    assert check(t=5.0 + config.termination.lost_timeout_s, last_seen=5.0) is None
    assert check(t=25.5, last_seen=5.0).startswith("target_lost: no valid estimate for 20.5 s")
    tolerance = config.termination.ground_tolerance_m  # 2 cm: the centre this far under the ground is no crash yet
    assert check(quad=hover_state(config.quadrotor, [20.0, 0.0, -0.5 * tolerance])) is None
    assert check(quad=hover_state(config.quadrotor, [20.0, 0.0, -1.5 * tolerance])).startswith(
        "crash: hit the ground at")
    far = relative.copy()  # the horizontal distance to the pad against max_distance_m (200 m), not max_altitude_m
    far[P_BP_W] = [-100.0, 0.0, -3.4]
    assert check(relative=far) is None
    far[P_BP_W] = [-150.0, -150.0, -3.4]  # 150 m each way: 212 m
    assert check(relative=far).startswith("diverged: 212 m from the pad")
    high_far = relative.copy()  # 195 m behind the pad, 50 m above it: 201 m away, but only 195 m horizontally
    high_far[P_BP_W], high_far[HEIGHT] = [-195.0, 0.0, -50.0], 50.0
    assert check(quad=hover_state(config.quadrotor, [195.0, 0.0, 51.6]), relative=high_far) is None
    at_touchdown = relative.copy()  # over the pad's centre, exactly touchdown_height_m above its top: touching
    at_touchdown[P_BP_W] = [0.0, 0.0, -config.landing.touchdown_height_m]
    at_touchdown[HEIGHT] = config.landing.touchdown_height_m
    assert check(relative=at_touchdown).startswith("landed: the gear touched the pad")


@pytest.mark.parametrize("limit", ["altitude", "speed", "distance"])
def test_the_monitor_s_divergence_limits_themselves_are_not_diverged(limit):
    """Diverged is beyond max_altitude_m, max_speed_m_s or max_distance_m (60 m, 40 m/s, 200 m): exactly at one
    (each exactly representable) the run goes on."""
    config = GvLandingConfig()
    term = config.termination
    monitor = LandingMonitor(term, config.platform, config.landing.touchdown_height_m)
    quad = hover_state(config.quadrotor, [20.0, 0.0, term.max_altitude_m if limit == "altitude" else 5.0])
    relative = np.zeros(RELATIVE_STATE_SIZE)
    relative[P_BP_W], relative[HEIGHT] = [-18.25, 0.0, -3.4], 3.4  # far from the pad's gear
    if limit == "speed":
        quad[V_WB] = [term.max_speed_m_s, 0.0, 0.0]
    if limit == "distance":
        relative[P_BP_W] = [-term.max_distance_m, 0.0, -3.4]
    assert monitor.check(1.0, quad, np.zeros(4), relative, Mode.FOLLOW, 1.0) is None


def test_the_pads_underside_is_not_its_top():
    """The gear touches the pad from above its underside, pad_thickness_m (2 cm) under the top, exclusive: exactly
    at the underside (under the pad, not on it) is no touch, a centimetre above it is."""
    thickness = GvLandingConfig().platform.pad_thickness_m
    relative = np.zeros(RELATIVE_STATE_SIZE)
    relative[P_BP_W], relative[HEIGHT] = [0.3, -0.2, thickness], -thickness
    assert not gear_on_pad(relative, 0.0, 0.1, 1.0, thickness)
    relative[HEIGHT] = -0.5 * thickness
    assert gear_on_pad(relative, 0.0, 0.1, 1.0, thickness)


def test_a_ground_tolerance_of_zero_is_valid():
    """ground_tolerance_m must not be negative: zero (a crash at the ground itself) is allowed."""
    TerminationConfig(ground_tolerance_m=0.0).validate()


def test_the_monitor_counts_a_vertical_dive_and_without_stop_on_landed_flies_on_over_the_pad():
    """The speed that counts as "diverged" is |v_WB| with its vertical part: a straight dive at 45 m/s (over
    max_speed 40) ends the run. With termination.stop_on_landed false the gear's touch in FOLLOW does not end it."""
    config = GvLandingConfig()
    monitor = LandingMonitor(config.termination, config.platform, config.landing.touchdown_height_m)
    quad, vehicle = hover_state(config.quadrotor, [20.0, 0.0, 5.0]), np.zeros(4)
    relative = np.zeros(RELATIVE_STATE_SIZE)
    relative[P_BP_W], relative[HEIGHT] = [-18.25, 0.0, -3.4], 3.4  # the true relative state of `quad`
    dive = quad.copy()
    dive[9] = -45.0  # v_WB's z
    assert monitor.check(1.0, dive, vehicle, relative, Mode.FOLLOW, 1.0).startswith("diverged: speed 45.0 m/s")
    flying_on = LandingMonitor(dataclasses.replace(config.termination, stop_on_landed=False), config.platform,
                               config.landing.touchdown_height_m)
    touching = relative.copy()
    touching[P_BP_W], touching[HEIGHT] = [0.3, -0.2, -0.08], 0.08  # the gear on the pad
    assert monitor.check(1.0, quad, vehicle, touching, Mode.FOLLOW, 1.0).startswith("landed: the gear touched")
    assert flying_on.check(1.0, quad, vehicle, touching, Mode.FOLLOW, 1.0) is None


@pytest.mark.parametrize("touchdown_by", ["estimate", "contact"])
def test_the_stacks_monitor_ends_on_landed_as_the_landing_says_and_the_pid_descends_on_the_seam(touchdown_by):
    """In the built diagram the monitor ends the run on the supervisor's LANDED only with landing.touchdown_by
    estimate (contact descends on until the gear touches), and the tracking PID's height is the seam's height
    above the target, not the UAV's altitude."""
    _, config = load_scenario("gv-landing", overrides=[f"landing.touchdown_by={touchdown_by}"])
    diagram, handles = build_gv_landing(config)
    quad = hover_state(config.quadrotor, [20.0, 0.0, 5.0])
    relative = np.zeros(RELATIVE_STATE_SIZE)
    relative[P_BP_W], relative[HEIGHT] = [-18.25, 0.0, -3.4], 3.4  # far from the pad's gear
    ended = handles.monitor.check(1.0, quad, np.zeros(4), relative, Mode.LANDED, 1.0)
    if touchdown_by == "estimate":
        assert ended.startswith("landed: the supervisor")
    else:
        assert ended is None
    wired = wiring(diagram)
    assert wired["tracking_pid", "height"] == ("seam", "height_above_target")


@pytest.mark.parametrize("seen_s, lost_flag, message", [
    (0.0, 0.0, "target_lost: no valid estimate of the pad"),
    (0.0, np.nan, "target_lost: no valid estimate of the pad"),
    (0.5, 0.0, "target_lost: no valid estimate for"),
    (0.5, np.nan, "target_lost: no valid estimate for"),
    (2.0, 0.0, ""),
])
def test_the_monitor_ends_a_run_without_a_valid_estimate_as_target_lost(seen_s, lost_flag, message):
    """The monitor reads its target_valid input: held at 0 the run ends "target_lost" one check after
    lost_timeout_s, the pad never seen; at 1 until 0.5 s, then 0, it ends so too, saying for how long the pad has
    been lost; held at 1 the same hover flies on. A NaN flag (a broken estimator's) is not valid either, as 0."""
    config = GvLandingConfig()
    termination = dataclasses.replace(config.termination, lost_timeout_s=0.5)
    monitor = LandingMonitor(termination, config.platform, config.landing.touchdown_height_m)
    context = monitor.CreateDefaultContext()
    relative = np.zeros(RELATIVE_STATE_SIZE)
    relative[P_BP_W], relative[HEIGHT] = [-18.25, 0.0, -3.4], 3.4  # the true relative state of the hover
    monitor.GetInputPort("quadrotor_state").FixValue(context, hover_state(config.quadrotor, [20.0, 0.0, 5.0]))
    monitor.GetInputPort("vehicle_state").FixValue(context, np.zeros(4))
    monitor.GetInputPort("true_relative_state").FixValue(context, relative)
    monitor.GetInputPort("mode").FixValue(context, [float(Mode.FOLLOW)])
    simulator = Simulator(monitor, context)
    if seen_s > 0:
        monitor.GetInputPort("target_valid").FixValue(context, [1.0])
        simulator.AdvanceTo(seen_s)
    monitor.GetInputPort("target_valid").FixValue(context, [lost_flag])
    status = simulator.AdvanceTo(2.0)
    if message:
        assert status.message().startswith(message)
        assert context.get_time() <= seen_s + 0.5 + 1.0 / termination.rate_hz + 1e-9
    else:
        assert status.message() == "" and context.get_time() == 2.0


@pytest.mark.parametrize("heading_deg", [0.0, 30.0, 90.0, -135.0])
def test_pad_offset_is_the_uav_in_the_pad_frame_turned_with_the_vehicle(heading_deg):
    """pad_offset is R_WP^T (p_WB - p_WP) for the pad frame P yawed by the vehicle's heading (Drake's
    rotation as the truth), and the gear touches the 1 m pad by that offset: 0.45 m along and 0.3 m across
    the vehicle is on it, 0.55 m along is off it, at any heading."""
    heading = np.radians(heading_deg)
    R_WP = RotationMatrix.MakeZRotation(heading)
    for offset_P, on_pad in (([0.45, 0.3, 0.0], True), ([0.55, 0.0, 0.0], False)):
        relative = np.zeros(RELATIVE_STATE_SIZE)
        relative[P_BP_W], relative[HEIGHT] = -R_WP.multiply(offset_P), 0.05  # pad minus UAV; 5 cm above it
        np.testing.assert_allclose(pad_offset(relative, heading), offset_P[:2], atol=1e-12)
        assert gear_on_pad(relative, heading, 0.1, 1.0, 0.02) == on_pad


def test_meshcat_shows_the_scene_path_and_trail():
    meshcat = Meshcat()
    _, scenario = load_scenario("gv-landing", overrides=["vehicle.path=figure-eight"])
    diagram, handles = build_gv_landing(scenario, meshcat)
    assert handles.meshcat_visualizer is not None
    fly_diagram(diagram, handles, 1.0, record=True)
    for path in ("gv_landing/path", "gv_landing/uav_trail", "/drake/visualizer/uav_body",
                 "/drake/visualizer/gv_body/gv_pad_pattern", "/drake/visualizer/gv_wheel_fl"):
        assert meshcat.HasPath(path), path
    assert len(meshcat.StaticHtml()) > 100_000  # the recording, with the pad's texture


def test_cli_run_writes_metrics_with_the_landing_section(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "gv-landing", "--out", str(out), "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "gv-landing" and metrics["realtime_factor"] > 0
    landing = metrics["landing"]
    for key in ("success", "touchdown_error_m", "touchdown_rel_speed_mps", "time_to_land_s", "failure_reason"):
        assert key in landing
    assert landing["success"] and landing["touchdown_error_m"] < 0.10
    log = np.load(out / "log.npz")
    assert {"t", "quadrotor_state", "vehicle_state", "relative_state", "mode"} <= set(log.files)
    for name in ("trajectories_3d", "trajectories_top", "altitude", "velocity", "tracking_error"):
        assert (out / f"{name}.png").stat().st_size > 10_000


def test_video_without_a_camera_is_a_one_line_error(capfd, tmp_path):
    out = tmp_path / "video"
    code = main(["run", "gv-landing", "--video", "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and "gv-landing has none" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_video_path_for_a_scene_without_a_camera_is_a_config_error(tmp_path):
    """build_gv_landing refuses a video_path where nothing renders (gv-landing: truth, no marker detector)."""
    _, scenario = load_scenario("gv-landing")
    assert not scenario.has_video
    with pytest.raises(ConfigError, match="a video records the camera, and this scene has none"):
        build_gv_landing(scenario, video_path=tmp_path / "camera.mp4")
    assert not (tmp_path / "camera.mp4").exists()


def test_the_summary_of_a_run_that_did_not_land_gives_its_failure():
    landing = {"success": False, "failure_reason": "timeout", "failure_detail": "no touchdown by t = 3.0 s",
               "touchdown_error_m": None, "touchdown_rel_speed_mps": None, "time_to_land_s": None}
    lines = summary_lines("gv-landing", {"landing": landing, "perception": {"source": "truth"}})
    assert lines == ["gv-landing: no landing (timeout: no touchdown by t = 3.0 s)"]


@pytest.mark.parametrize("source, steered", [("truth", False), ("ct_ekf", True)])
def test_the_summary_says_what_steered_only_for_an_estimate(source, steered):
    """The truth steering scores RMS 0 against itself: no "steered by" line for it, one for an estimator."""
    perception = {"source": source, "rms_position_m": 0.0, "valid_fraction": 1.0, "longest_invalid_s": 0.0}
    lines = summary_lines("gv-landing", {"perception": perception})
    assert lines == ([f"gv-landing: steered by {source}: RMS position 0.000 m over the flight, valid 100%, longest "
                      "without a valid estimate 0.00 s"] if steered else [])
