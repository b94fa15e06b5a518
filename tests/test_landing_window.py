"""The landing window (systems/control/landing_window.py) on analytic deck motions."""

import math

import numpy as np
import pytest

from systems.control.landing_window import (
    LandingWindow,
    LandingWindowConfig,
    time_to_touchdown,
    window_flags,
)
from systems.estimators.deck_predictor import PREDICTED, PREDICTION_STEP_S, constant_rate_prediction, prediction_size
from systems.estimators.deck_tracker import tilt_deg

CONFIG = LandingWindowConfig()


def motion(n_xy=(0.0, 0.0), n_rate=(0.0, 0.0), heave_rate=0.0, valid=True):
    return np.array([*n_xy, *n_rate, 0.69, heave_rate, 1.0 if valid else 0.0, 0.0])


def sin_deg(deg):
    return math.sin(math.radians(deg))


def test_predicted_tilt_is_the_normal_moved_at_its_rate():
    m = motion((sin_deg(3.0), 0.0), (-sin_deg(3.0) / 2.0, 0.0))  # back to level in 2 s
    tilt = tilt_deg(constant_rate_prediction(m, np.array([0.0, 1.0, 2.0, 4.0]))[:, :2])
    np.testing.assert_allclose(tilt, [3.0, math.degrees(math.asin(sin_deg(3.0) / 2)), 0.0, 3.0], atol=1e-9)


def test_a_level_still_deck_opens_the_window():
    assert window_flags(motion(), 2.0, CONFIG) == (True, True)


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


def test_the_heave_rate_is_the_largest_over_the_touchdown_window_not_at_its_end():
    """An autoregressive prediction whose dz/dt peaks at tau = 2 s and is zero at tau +- the margin: closed."""
    size = prediction_size(CONFIG.predictor)
    values = np.zeros((PREDICTED, (size - 2) // PREDICTED))
    values[3, round(2.0 / PREDICTION_STEP_S)] = 0.3
    assert window_flags(motion(), 2.0, CONFIG, np.r_[1.0, 1.0, values.ravel()]) == (False, False)


@pytest.mark.parametrize("flag", [0.0, np.nan])
def test_a_prediction_flagged_invalid_is_not_used(flag):
    """The deck predictor's output with its valid flag 0 or NaN (its other entries a lively deck's): the window is
    the constant rate's, open over a level, still deck."""
    prediction = np.full(prediction_size(CONFIG.predictor), 0.5)
    prediction[0] = flag
    assert window_flags(motion(), 1.0, CONFIG, prediction) == (True, True)
    prediction[0] = 1.0  # the same numbers, valid: n_xy 0.5 is a 30 deg deck
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


def test_bad_thresholds_are_config_errors():
    from systems.config import ConfigError

    with pytest.raises(ConfigError, match="abort_tilt_deg"):
        LandingWindowConfig(max_tilt_deg=3.0, abort_tilt_deg=2.0).validate()


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
