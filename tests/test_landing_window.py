"""The landing window (systems/control/landing_window.py) on analytic deck motions."""

import math

import numpy as np
import pytest

from systems.config import ConfigError
from systems.control.landing_window import (
    LandingWindow,
    LandingWindowConfig,
    time_to_touchdown,
    window_flags,
)
from systems.estimators.deck_predictor import PREDICTED, PREDICTION_STEP_S, constant_rate_prediction, prediction_size
from systems.estimators.deck_tracker import tilt_deg

CONFIG = LandingWindowConfig()
GRID_SIZE = (prediction_size(CONFIG.predictor) - 2) // PREDICTED  # the deck predictor's horizons


def motion(n_xy=(0.0, 0.0), n_rate=(0.0, 0.0), heave_rate=0.0, valid=True):
    return np.array([*n_xy, *n_rate, 0.69, heave_rate, 1.0 if valid else 0.0, 0.0])


def sin_deg(deg):
    return math.sin(math.radians(deg))


def autoregressive(values):
    """The deck predictor's output, valid and autoregressive, with `values` (PREDICTED, GRID_SIZE) on its grid."""
    return np.r_[1.0, 1.0, values.ravel()]


def test_predicted_tilt_is_the_normal_moved_at_its_rate():
    m = motion((sin_deg(3.0), 0.0), (-sin_deg(3.0) / 2.0, 0.0))  # back to level in 2 s
    tilt = tilt_deg(constant_rate_prediction(m, np.array([0.0, 1.0, 2.0, 4.0]))[:, :2])
    np.testing.assert_allclose(tilt, [3.0, math.degrees(math.asin(sin_deg(3.0) / 2)), 0.0, 3.0], atol=1e-9)


def test_a_level_still_deck_opens_the_window():
    assert window_flags(motion(), 2.0, CONFIG) == (True, True)


@pytest.mark.parametrize("deck, config", [
    # tilt_deg's own arithmetic, degrees(asin(|n_xy|)): the threshold is that tilt to the last bit
    (motion((0.03, 0.0)), LandingWindowConfig(max_tilt_deg=math.degrees(math.asin(0.03)))),
    (motion(heave_rate=CONFIG.max_heave_rate_m_s), CONFIG),
], ids=["tilt", "heave_rate"])
def test_the_window_opens_at_its_limits_themselves(deck, config):
    """A still deck tilted exactly max_tilt_deg, or heaving at exactly max_heave_rate_m_s: open."""
    assert window_flags(deck, 2.0, config) == (True, True)


@pytest.mark.parametrize("deck, config", [
    # tilt_deg's own arithmetic, degrees(asin(|n_xy|)): the threshold is that tilt to the last bit
    (motion((0.05, 0.0)), LandingWindowConfig(abort_tilt_deg=math.degrees(math.asin(0.05)))),
    (motion(heave_rate=2 * CONFIG.max_heave_rate_m_s), CONFIG),
], ids=["tilt", "heave_rate"])
def test_a_committed_descent_holds_at_the_abort_limits_themselves(deck, config):
    """3 s from touchdown (past no_return_s), a still deck tilted exactly abort_tilt_deg (2.87 deg, over
    max_tilt_deg), or heaving at exactly twice max_heave_rate_m_s: closed to a commit, but a descent holds."""
    assert window_flags(deck, 3.0, config) == (False, True)


def test_the_tilt_at_touchdown_decides_not_the_tilt_now():
    # 4 deg now, levelling at 2 deg/s: level in 2 s, when the UAV would touch down.
    levelling = motion((sin_deg(4.0), 0.0), (-sin_deg(4.0) / 2.0, 0.0))
    assert window_flags(levelling, 2.0, CONFIG)[0]
    assert not window_flags(levelling, 0.5, CONFIG)[0]  # touching down in 0.5 s: still 3 deg


def test_hysteresis_and_no_return():
    # 2.8 deg predicted at touchdown: too much to commit, not enough to abort a committed descent.
    m = motion((sin_deg(2.8), 0.0))
    assert window_flags(m, 2.0, CONFIG) == (False, True)
    tilting = motion((sin_deg(2.0), 0.0), (sin_deg(2.0), 0.0))  # 2 deg now, 2 more per second
    assert window_flags(tilting, 2.0, CONFIG) == (False, False)
    assert window_flags(tilting, CONFIG.no_return_s, CONFIG) == (False, True)  # too late to climb out


def test_the_touchdown_window_never_reaches_into_the_past():
    """tau is clamped at 0 and its window starts no earlier than now. A deck at 2 deg tilting 2 deg/s more, with
    the height already under touchdown (tau -0.2 s): judged as tau 0, over the next 0.3 s, where it reaches 2.6 deg:
    closed (not over the 0.1 s that -0.2 + 0.3 leaves). A deck at 2.4 deg levelling at 2 deg/s, 0.1 s from
    touchdown: at most 2.4 deg from now on: open (its 2.8 deg of 0.2 s ago does not count)."""
    tilting = motion((sin_deg(2.0), 0.0), (sin_deg(2.0), 0.0))
    assert window_flags(tilting, -0.2, CONFIG) == window_flags(tilting, 0.0, CONFIG) == (False, True)
    levelling = motion((sin_deg(2.4), 0.0), (-sin_deg(2.0), 0.0))
    assert window_flags(levelling, 0.1, CONFIG) == (True, True)


def test_heave_rate_closes_it_and_no_estimate_closes_everything():
    assert window_flags(motion(heave_rate=0.15), 2.0, CONFIG) == (False, True)
    assert window_flags(motion(heave_rate=0.25), 2.0, CONFIG) == (False, False)
    assert window_flags(motion(valid=False), 2.0, CONFIG) == (False, False)
    assert window_flags(motion(valid=False), 0.5, CONFIG) == (False, False)
    nan_flag = motion()
    nan_flag[6] = np.nan  # a broken tracker's flag is no estimate either, whatever its other numbers say
    assert window_flags(nan_flag, 2.0, CONFIG) == (False, False)
    # heaving down as fast: the same (the rate's size decides, not its sign)
    assert window_flags(motion(heave_rate=-0.15), 2.0, CONFIG) == (False, True)
    assert window_flags(motion(heave_rate=-0.25), 2.0, CONFIG) == (False, False)


@pytest.mark.parametrize("tau, peak_s", [(2.0, 2.0), (1.95, 1.8)])
def test_the_heave_rate_is_the_largest_over_the_touchdown_window_not_at_its_end(tau, peak_s):
    """An autoregressive prediction whose dz/dt peaks (0.3 m/s, on one grid sample) inside tau +- the margin m
    (0.3 s) and is zero at its ends: closed. Peaking at tau, or at tau - m / 2: 1.8 s with tau 1.95 s, between the
    window's samples tau - m (1.65 s) and tau (1.95 s) and more than a grid step (0.1 s) from each, so only a
    window sampled as finely as m / 2 sees it."""
    values = np.zeros((PREDICTED, GRID_SIZE))
    values[3, round(peak_s / PREDICTION_STEP_S)] = 0.3
    assert window_flags(motion(), tau, CONFIG, autoregressive(values)) == (False, False)


@pytest.mark.parametrize("flag", [0.0, np.nan])
def test_a_prediction_flagged_invalid_is_not_used(flag):
    """The deck predictor's output with its valid flag 0 or NaN (its other entries a lively deck's): the window is
    the constant rate's, open over a level, still deck."""
    prediction = np.full(prediction_size(CONFIG.predictor), 0.5)
    prediction[0] = flag
    assert window_flags(motion(), 1.0, CONFIG, prediction) == (True, True)
    prediction[0] = 1.0  # the same numbers, valid: n_xy (0.5, 0.5) is a 45 deg deck
    assert window_flags(motion(), 1.0, CONFIG, prediction)[0] is False


def test_the_system_times_touchdown_from_the_seam_height():
    window = LandingWindow(CONFIG, touchdown_height_m=0.1, landing_speed_m_s=0.4)
    context = window.CreateDefaultContext()
    levelling = motion((sin_deg(4.0), 0.0), (-sin_deg(4.0) / 2.0, 0.0))  # level 2 s from now
    window.GetInputPort("deck_motion").FixValue(context, levelling)
    window.GetInputPort("height_above_target").FixValue(context, [0.9])  # 2 s to touchdown
    np.testing.assert_array_equal(window.get_output_port().Eval(context), [1.0, 1.0])
    window.GetInputPort("height_above_target").FixValue(context, [2.5])  # 6 s: past level, tilting the other way
    assert window.get_output_port().Eval(context)[0] == 0.0


def test_the_system_uses_the_deck_prediction_when_given():
    """A level, still tracked deck 2 s from touchdown, but a valid prediction of a 30 deg deck (n_x 0.5):
    closed, not to be committed to nor held."""
    window = LandingWindow(CONFIG, touchdown_height_m=0.1, landing_speed_m_s=0.4)
    context = window.CreateDefaultContext()
    window.GetInputPort("deck_motion").FixValue(context, motion())
    window.GetInputPort("height_above_target").FixValue(context, [0.9])
    np.testing.assert_array_equal(window.get_output_port().Eval(context), [1.0, 1.0])  # the tracked deck's
    values = np.zeros((PREDICTED, GRID_SIZE))
    values[0] = 0.5
    window.GetInputPort("deck_prediction").FixValue(context, autoregressive(values))
    np.testing.assert_array_equal(window.get_output_port().Eval(context), [0.0, 0.0])


@pytest.mark.parametrize("fields, message", [
    (dict(max_tilt_deg=3.0, abort_tilt_deg=2.0), "abort_tilt_deg must be at least max_tilt_deg"),
    (dict(max_heave_rate_m_s=0.0), "max_heave_rate_m_s must be positive"),
])
def test_bad_thresholds_are_config_errors(fields, message):
    """Also from the system itself."""
    with pytest.raises(ConfigError, match=message):
        LandingWindowConfig(**fields).validate()
    with pytest.raises(ConfigError, match=message):
        LandingWindow(LandingWindowConfig(**fields), touchdown_height_m=0.1, landing_speed_m_s=0.4)


@pytest.mark.parametrize("touchdown, speed, response, message", [
    (0.1, 0.0, 0.0, "landing_speed_m_s must be positive"),  # tau divides by it
    (0.1, np.nan, 0.0, "landing_speed_m_s must be positive"),
    (0.0, 0.4, 0.0, "touchdown_height_m must be positive"),
    (0.1, 0.4, -0.1, "response_time_s must not be negative"),
])
def test_the_systems_own_arguments_are_checked(touchdown, speed, response, message):
    with pytest.raises(ConfigError, match=message):
        LandingWindow(CONFIG, touchdown_height_m=touchdown, landing_speed_m_s=speed, response_time_s=response)


@pytest.mark.parametrize("fields", [dict(abort_tilt_deg=CONFIG.max_tilt_deg), dict(timing_margin_s=0.0),
                                    dict(no_return_s=0.0)])
def test_thresholds_at_their_limits_are_valid(fields):
    """No hysteresis, no timing margin, no point of no return: valid (the limits are inclusive)."""
    LandingWindowConfig(**fields).validate()


def test_time_to_touchdown_is_that_of_a_first_order_descent():
    # v(t) = V (1 - exp(-t / T)) from a hover covers h in tau with h = V (tau - T (1 - exp(-tau / T))):
    # for tau >> T, tau = h / V + T. Integrated numerically against the formula.
    V, T, h = 0.4, 1.0 / 3.0, 0.8
    dt, t, z = 1e-4, 0.0, 0.0
    while z < h:
        z += V * (1 - math.exp(-t / T)) * dt
        t += dt
    assert time_to_touchdown(h, V, 0.0, T) == pytest.approx(t, abs=0.01)  # exp(-tau / T) ~ 0.1 % here
    assert time_to_touchdown(h, V, V, T) == pytest.approx(h / V)  # at speed: no lag
    assert time_to_touchdown(h, V, 2 * V, T) == pytest.approx(h / V)  # taken within [0, V]
    assert time_to_touchdown(h, V, -V, T) == pytest.approx(h / V + T)  # climbing: as from a hover


@pytest.mark.parametrize("descent, tau", [(0.5, -0.2), (0.0, 0.3)])
def test_a_height_under_the_touchdown_height_gives_the_formulas_tau_not_a_clamped_one(descent, tau):
    """h / V + T (1 - v / V) for h -0.1 m (the seam's height already 0.1 m under touchdown_height_m), V 0.5 m/s and
    T 0.5 s: at speed -0.2 s (window_flags clamps a negative tau, itself); from a hover the lag less the 0.2 s,
    0.3 s, not the lag alone."""
    assert time_to_touchdown(-0.1, 0.5, descent, 0.5) == pytest.approx(tau)


def test_the_window_counts_the_descents_lag_when_it_knows_the_vertical_velocity():
    window = LandingWindow(CONFIG, touchdown_height_m=0.1, landing_speed_m_s=0.4, response_time_s=0.5)
    context = window.CreateDefaultContext()
    n0 = math.sin(math.radians(12.5))
    levelling = motion((n0, 0.0), (-n0 / 2.5, 0.0))  # 12.5 deg, level 2.5 s from now (about 5 deg/s)
    window.GetInputPort("deck_motion").FixValue(context, levelling)
    window.GetInputPort("height_above_target").FixValue(context, [0.9])  # 2 s at speed, 2.5 s from a hover
    window.GetInputPort("vertical_velocity").FixValue(context, [0.0])
    assert window.get_output_port().Eval(context)[0] == 1.0
    window.GetInputPort("vertical_velocity").FixValue(context, [-0.4])  # already descending: 2 s, 2.5 deg off
    assert window.get_output_port().Eval(context)[0] == 0.0


def test_without_the_vertical_velocity_the_window_leaves_the_descents_lag_out():
    """`vertical_velocity` unconnected: tau is h / V (as at speed), not h / V + T (as from a hover). On the deck
    above, levelling 2.5 s from now, tau 2 s (closed) rather than 2.5 s (open)."""
    window = LandingWindow(CONFIG, touchdown_height_m=0.1, landing_speed_m_s=0.4, response_time_s=0.5)
    context = window.CreateDefaultContext()
    n0 = math.sin(math.radians(12.5))
    levelling = motion((n0, 0.0), (-n0 / 2.5, 0.0))
    window.GetInputPort("deck_motion").FixValue(context, levelling)
    window.GetInputPort("height_above_target").FixValue(context, [0.9])
    assert window_flags(levelling, 0.8 / 0.4, CONFIG)[0] is False and window_flags(levelling, 2.5, CONFIG)[0]
    np.testing.assert_array_equal(window.get_output_port().Eval(context), window_flags(levelling, 2.0, CONFIG))
