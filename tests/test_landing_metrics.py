"""metrics.json's landing timings against the supervisor's own record: its mode is discrete state, so a
logger at its rate shows at t_i the mode it decided at t_(i-1) (diagrams/landing_metrics.entered)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from diagrams.landing_metrics import SETTLED_TOLERANCE_M, SETTLED_WINDOW_S, impact, pad_landing, tracking_metrics
from diagrams.simulate import COMPLETED
from systems.control.landing import LandingConfig, LandingSupervisor, Mode
from systems.perception.seam import HEIGHT, P_BP_W, RELATIVE_STATE_SIZE, V_WP
from systems.vehicles.quadrotor import STATE_SIZE, V_WB


def test_mode_entry_times_are_when_the_supervisor_decided_them():
    config = LandingConfig()
    builder = DiagramBuilder()
    supervisor = builder.AddSystem(LandingSupervisor(config))
    climb_at = 0.1  # the altitude steps above the take-off height here: TAKEOFF -> CLIMB
    altitude = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        [0.0, climb_at, 10.0], np.array([[0.0, 2.0, 2.0]]))))
    builder.Connect(altitude.get_output_port(), supervisor.GetInputPort("altitude"))
    for name, size, value in (("height_above_target", 1, 5.0), ("target_valid", 1, 0.0), ("target_offset", 2, 0.0),
                              ("target_velocity", 2, 0.0), ("tracking_velocity", 2, 0.0),
                              ("tracking_acceleration", 2, 0.0)):
        source = builder.AddSystem(ConstantVectorSource(np.full(size, value)))
        builder.Connect(source.get_output_port(), supervisor.GetInputPort(name))
    logger = LogVectorOutput(supervisor.GetOutputPort("mode"), builder, 1.0 / config.rate_hz)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.3)
    context = simulator.get_context()
    since = supervisor.GetMyContextFromRoot(context).get_discrete_state(0).get_value()[0]  # mode_since_s
    log = logger.FindLog(context)
    t, mode = log.sample_times(), log.data()[0]
    assert Mode(int(mode[-1])) == Mode.CLIMB and since == climb_at

    relative = np.zeros((len(t), RELATIVE_STATE_SIZE))
    relative[:, HEIGHT] = 5.0
    quadrotor = np.zeros((len(t), STATE_SIZE))
    quadrotor[:, 0] = 1.0
    landing, _ = pad_landing({"t": t, "mode": mode, "true_relative_state": relative, "quadrotor_state": quadrotor},
                             COMPLETED, np.zeros(len(t)), 1.0, 0.02, 0.1, 9.81)
    assert landing["mode_entry_times_s"] == {"takeoff": 0.0, "climb": climb_at}


def test_tracking_metrics_on_a_hand_built_log():
    """Unevenly spaced samples; the errors (pad minus UAV, x y) chosen so that each metric has one right value."""
    F, A, L = Mode.FOLLOW, Mode.APPROACH, Mode.LAND
    t = np.array([0.0, 0.4, 1.0, 2.2, 3.1, 4.0, 4.5])
    mode = np.array([F, F, A, A, A, L, L], dtype=int)
    error = np.array([[0.30, -0.20],  # acquiring: outside the tolerance
                      [0.004, 0.0],  # inside
                      [0.02, 0.0],  # a gust: outside again, so it settles only after this one
                      [0.005, -0.008],  # inside from here to LAND
                      [-0.002, 0.004],
                      [0.05, 0.0],  # in LAND: left out
                      [0.1, 0.1]])
    assert SETTLED_TOLERANCE_M == 0.01 and SETTLED_WINDOW_S == 2.0  # the values the figures below assume
    relative = np.zeros((len(t), RELATIVE_STATE_SIZE))
    relative[:, P_BP_W.start:P_BP_W.start + 2] = error
    out = tracking_metrics({"t": t, "mode": mode, "true_relative_state": relative})
    np.testing.assert_allclose(out["approach_rmse_xy_m"], [np.sqrt((0.02**2 + 0.005**2 + 0.002**2) / 3),
                                                           np.sqrt((0.008**2 + 0.004**2) / 3)])
    np.testing.assert_allclose(out["approach_max_abs_xy_m"], [0.02, 0.008])
    assert out["settling_time_s"] == pytest.approx(2.2)  # inside from t = 2.2 s on (the last outside: 1.0 s)
    np.testing.assert_allclose(out["at_final_descent_xy_m"], [-0.002, 0.004])  # decided at 3.1 s, logged at 4.0
    # The window: the 2 s before LAND (t = 4.0 s) are the samples at 2.2 and 3.1 s; their largest |error|.
    np.testing.assert_allclose(out["before_final_descent_max_abs_xy_m"], [0.005, 0.008])


def _landed(gap_m: float, p_BP_xy, v_WB) -> tuple[dict, int | None]:
    """pad_landing of a hand-built log (headed 0, a 1 m pad 0.02 m thick, touchdown height 0.1 m, g = 10 m/s^2):
    at k = 4, the sample before the supervisor's LANDED was logged, the gear gap_m [m] over its touchdown height and
    the pad minus the UAV p_BP_xy [m] in x, y; the pad moving at (1, 0, 0) m/s, the UAV at v_WB [m/s]."""
    F, A, W, L, D = Mode.FOLLOW, Mode.APPROACH, Mode.WAIT, Mode.LAND, Mode.LANDED
    t = np.array([0.0, 0.3, 0.7, 1.2, 2.0, 2.1, 2.15])
    mode = np.array([F, A, W, W, L, D, D], dtype=int)
    n, k, touchdown_height = len(t), 4, 0.1
    relative = np.zeros((n, RELATIVE_STATE_SIZE))
    relative[:, HEIGHT] = 3.0
    relative[k, HEIGHT] = touchdown_height + gap_m
    relative[k, P_BP_W] = [*p_BP_xy, -relative[k, HEIGHT]]
    relative[:, V_WP] = [1.0, 0.0, 0.0]  # the pad
    quadrotor = np.zeros((n, STATE_SIZE))
    quadrotor[:, V_WB] = v_WB
    log = {"t": t, "mode": mode, "true_relative_state": relative, "quadrotor_state": quadrotor}
    return pad_landing(log, "landed: the supervisor reported touchdown by t = 2.10 s", np.zeros(n), pad_size_m=1.0,
                       pad_thickness_m=0.02, touchdown_height_m=touchdown_height, gravity_m_s2=10.0)


def test_pad_landing_on_a_hand_built_log():
    """The supervisor's LANDED with the gear 16 mm over its touchdown height, descending at 0.2 m/s relative to
    the pad and drifting at (0.3, -0.4) m/s: g = 10 m/s^2 gives an impact at 0.6 m/s after 0.04 s, 0.05 m from
    the centre. Waits on unevenly spaced samples."""
    out, index = _landed(0.016, [0.042, 0.024], [1.3, -0.4, -0.2])  # the UAV: (0.3, -0.4, -0.2) m/s relative to the pad
    assert index == 4 and out["touchdown_by"] == "supervisor" and out["success"]
    # speed^2 = 0.2^2 + 2 g 0.016 = 0.36; fall = (0.6 - 0.2) / g = 0.04 s; drift 0.04 (0.3, -0.4) = (0.012, -0.016),
    # so the pad minus UAV at impact is (0.042 - 0.012, 0.024 + 0.016) = (0.03, 0.04), 0.05 m off.
    assert out["touchdown_rel_speed_mps"] == pytest.approx(0.6)
    assert out["time_to_land_s"] == pytest.approx(2.04)
    assert out["touchdown_gap_m"] == pytest.approx(0.016)
    assert out["touchdown_error_m"] == pytest.approx(0.05)
    np.testing.assert_allclose(out["touchdown_offset_pad_xy_m"], [-0.03, -0.04], atol=1e-12)  # UAV - pad, heading 0
    assert out["touchdown_rel_speed_horizontal_mps"] == pytest.approx(0.5)
    assert not out["meets_targets"]  # on the pad, 5 cm off, but at 0.6 m/s (the target: under 0.5)
    # One wait, from 0.7 to 2.0 s (the samples at 0.7 and 1.2 s, each until the next).
    assert out["waits"] == 1 and out["wait_s"] == pytest.approx(1.3)


@pytest.mark.parametrize("p_BP_xy, descent_mps, error_m, meets", [
    ([0.12, -0.16], 0.3, 0.2, False),
    ([0.03, 0.04], 0.3, 0.05, True),
    ([0.1, 0.0], 0.3, 0.1, False),  # exactly the 10 cm target: not under it
    ([0.03, 0.04], 0.5, 0.05, False),  # exactly the 0.5 m/s target: not under it
])
def test_the_targets_are_under_10_cm_and_under_0_5_m_s(p_BP_xy, descent_mps, error_m, meets):
    """A landing on the 1 m pad with the gear at its touchdown height (no fall), descending at descent_mps: it
    meets the targets under 0.1 m from the centre and under 0.5 m/s (both strict), though on the pad either way."""
    out, index = _landed(0.0, p_BP_xy, [1.0, 0.0, -descent_mps])
    assert index == 4 and out["success"] and out["touchdown_rel_speed_mps"] == pytest.approx(descent_mps)
    assert out["touchdown_error_m"] == pytest.approx(error_m)
    assert out["meets_targets"] == meets


@pytest.mark.parametrize("gap_m, p_BP_xy", [
    (0.0, [0.03, 0.04]),  # the gear exactly at its touchdown height
    (-0.05, [0.03, 0.04]),  # 5 cm under it
    (0.0, [0.5, 0.0]),  # on the 1 m pad's edge (UAV minus pad (-0.5, 0))
])
def test_a_touchdown_at_or_under_the_touchdown_height_is_the_supervisors_without_a_fall(gap_m, p_BP_xy):
    """The supervisor's LANDED and the gear's touch at the same sample (k = 4): the supervisor's (its motors stop
    first); with the gear at or under its touchdown height there is nothing to fall (gap 0, impact at t[4] at the
    0.3 m/s descent), and a touchdown on the pad's edge is on the pad."""
    out, index = _landed(gap_m, p_BP_xy, [1.0, 0.0, -0.3])
    assert index == 4 and out["touchdown_by"] == "supervisor"
    assert out["touchdown_gap_m"] == 0.0 and out["touchdown_height_m"] == pytest.approx(0.1 + gap_m)
    assert out["time_to_land_s"] == 2.0 and out["touchdown_rel_speed_mps"] == pytest.approx(0.3)
    assert out["success"] and out["failure_reason"] is None
    np.testing.assert_allclose(out["touchdown_offset_pad_xy_m"], -np.array(p_BP_xy), atol=1e-12)


@pytest.mark.parametrize("status, reason, detail", [
    ("crash: hit the ground at t = 3.0 s", "crash", "hit the ground at t = 3.0 s"),
    ("stopped: by hand", "diverged", "stopped: by hand"),  # not a failure reason: "diverged", the whole status
])
def test_a_run_ended_without_a_touchdown_fails_for_its_reason(status, reason, detail):
    n = 4
    relative = np.zeros((n, RELATIVE_STATE_SIZE))
    relative[:, HEIGHT] = 3.0
    log = {"t": np.arange(n) * 0.5, "mode": np.full(n, int(Mode.APPROACH)), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, STATE_SIZE))}
    out, index = pad_landing(log, status, np.zeros(n), 1.0, 0.02, 0.1, 9.81)
    assert index is None and not out["success"] and not out["meets_targets"]
    assert (out["failure_reason"], out["failure_detail"]) == (reason, detail)


def test_gv_landing_scores_the_contact_sample_in_the_pad_frame():
    """landing_metrics of a gv flight at the contact sample k (the third; the vehicle turning, so its heading
    changes per sample): the UAV's offset in the pad frame (Drake's R_WP^T applied to UAV minus pad), the
    vehicle's speed at k (not the log's last) and its bicycle turn radius wheelbase / tan(steering)."""
    from pydrake.math import RollPitchYaw, RotationMatrix

    from diagrams.landing_metrics import landing_metrics
    from diagrams.runner import load_scenario
    config = load_scenario("gv-landing")[1]
    n, k, steering = 5, 2, 0.2
    heading = np.array([0.3, 0.8, 1.3, 1.8, 2.3])
    relative = np.zeros((n, RELATIVE_STATE_SIZE))
    relative[:, HEIGHT] = 2.0
    relative[k:, HEIGHT] = config.landing.touchdown_height_m - 0.05  # the gear on the pad from sample k
    relative[:, P_BP_W.start:P_BP_W.start + 2] = [-0.3, 0.1]  # pad minus UAV in W
    vehicle = np.zeros((n, 4))
    vehicle[:, 2], vehicle[:, 3] = heading, steering
    log = {"t": 0.02 * np.arange(n), "mode": np.full(n, int(Mode.LAND)), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, STATE_SIZE)), "vehicle_state": vehicle,
           "vehicle_speed": np.array([5.0, 6.0, 7.0, 8.0, 9.0])}
    out = landing_metrics(log, COMPLETED, config)
    assert out["touchdown_by"] == "contact" and out["time_to_land_s"] == pytest.approx(log["t"][k])
    R_WP = RotationMatrix(RollPitchYaw(0.0, 0.0, heading[k]))
    np.testing.assert_allclose(out["touchdown_offset_pad_xy_m"], R_WP.inverse().multiply([0.3, -0.1, 0.0])[:2],
                               atol=1e-12)
    assert out["vehicle_speed_at_touchdown_m_s"] == 7.0
    assert out["vehicle_turn_radius_at_touchdown_m"] == pytest.approx(config.vehicle.wheelbase_m / np.tan(steering))


@pytest.mark.parametrize("gap_m, vertical_speed, speed", [
    (0.0, -0.4, 0.4),  # at the touchdown height, descending
    (-0.01, 0.3, 0.0),  # under it, rising
    (0.0, 0.3, 0.0),  # at it, rising: no gap, so no rise and fall back
])
def test_impact_of_a_uav_at_the_pad_is_its_descent_speed_and_zero_when_rising(gap_m, vertical_speed, speed):
    """At or under the touchdown height the motors stop on the pad: the impact is at once at the downward speed,
    and none for a UAV moving up at that moment (it lifts off the pad, it does not hit it)."""
    assert impact(gap_m, vertical_speed, 9.81) == (0.0, pytest.approx(speed))


def test_tracking_metrics_leave_out_an_approach_after_the_final_descent_and_keep_the_window_edge():
    """Only what comes before the first LAND counts: an APPROACH after a retried LAND is left out of the
    approach figures; the 2 s window before LAND includes a sample exactly 2 s before it."""
    F, A, L = Mode.FOLLOW, Mode.APPROACH, Mode.LAND
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    mode = np.array([F, A, A, A, L, A, L], dtype=int)
    error = np.array([[0.5, 0.5], [0.04, -0.01], [0.03, -0.06], [0.01, 0.02], [0.0, 0.0], [0.9, -0.9], [0.0, 0.0]])
    relative = np.zeros((len(t), RELATIVE_STATE_SIZE))
    relative[:, P_BP_W.start:P_BP_W.start + 2] = error
    out = tracking_metrics({"t": t, "mode": mode, "true_relative_state": relative})
    np.testing.assert_allclose(out["approach_max_abs_xy_m"], [0.04, 0.06])
    np.testing.assert_allclose(out["approach_rmse_xy_m"], np.sqrt(np.mean(error[1:4] ** 2, axis=0)))
    np.testing.assert_allclose(out["before_final_descent_max_abs_xy_m"], [0.03, 0.06])  # t = 2.0 = 4.0 - 2.0 in


def test_an_error_exactly_at_the_tolerance_is_settled():
    """The x error 0.5 m in FOLLOW, then exactly SETTLED_TOLERANCE_M (within it: settled from t = 1 s), then 0."""
    F, A, L = Mode.FOLLOW, Mode.APPROACH, Mode.LAND
    t = np.arange(4.0)
    relative = np.zeros((4, RELATIVE_STATE_SIZE))
    relative[:, P_BP_W.start] = [0.5, SETTLED_TOLERANCE_M, 0.0, 0.0]
    out = tracking_metrics({"t": t, "mode": np.array([F, A, A, L], dtype=int), "true_relative_state": relative})
    assert out["settling_time_s"] == 1.0


def test_a_follow_only_after_the_final_descent_has_no_settling_figures():
    """FOLLOW first logged after LAND: nothing before the final descent to settle."""
    mode = np.array([Mode.APPROACH, Mode.LAND, Mode.FOLLOW], dtype=int)
    relative = np.zeros((3, RELATIVE_STATE_SIZE))
    out = tracking_metrics({"t": np.arange(3.0), "mode": mode, "true_relative_state": relative})
    assert "settling_time_s" not in out and "settled_within_m" not in out
