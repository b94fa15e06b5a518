import dataclasses
import math

import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator

from diagrams.landing_metrics import descent_counts, impact, landing_metrics
from diagrams.runner import load_scenario
from systems.control.landing import (
    LandingConfig,
    LandingStateMachine,
    LandingSupervisor,
    Mode,
    SupervisorInputs,
    SupervisorMemory,
    hold_rate,
    next_mode,
    supervisor_step,
)
from systems.perception.seam import HEIGHT

CONFIG = LandingConfig()
TRACKING = np.array([0.9, -0.3])  # what the PID asks for
TRACKING_ACCELERATION = np.array([0.05, 0.12])  # and its acceleration feed-forward
TARGET_VELOCITY = np.array([0.6, -0.2])


class Script:
    """Feeds a LandingStateMachine one step at a time, 20 ms apart, with defaults for the
    inputs a step does not mention. An unseen step's target velocity is NaN (an invalid estimate's
    numbers), so a command that used it, or a memory that kept it, shows."""

    def __init__(self):
        self.machine = LandingStateMachine(CONFIG)
        self.time = 0.0

    def step(self, altitude, seen=True, offset=(0.0, 0.0), height=None, window=(True, True)):
        inputs = SupervisorInputs(
            time_s=self.time, altitude_m=altitude,
            height_above_target_m=altitude if height is None else height, target_valid=seen,
            target_offset_m=np.asarray(offset, dtype=float),
            target_velocity_m_s=TARGET_VELOCITY if seen else np.full(2, np.nan),
            tracking_velocity_m_s=TRACKING, tracking_acceleration_m_s2=TRACKING_ACCELERATION,
            window_open=window[0], window_holds=window[1])
        self.time += 0.02
        self.command = self.machine.step(inputs)
        return self.machine.mode, self.command[:2], self.command[2]

    @property
    def acceleration(self):
        """The acceleration feed-forward of the last command."""
        return self.command[4:7]


def test_nominal_landing_sequence():
    script = Script()
    mode, horizontal, vz = script.step(altitude=0.0, seen=False)
    assert mode == Mode.TAKEOFF and vz == CONFIG.climb_speed_m_s and not horizontal.any()

    mode, horizontal, vz = script.step(altitude=1.0, seen=False)
    assert mode == Mode.CLIMB and vz == CONFIG.climb_speed_m_s and not horizontal.any()

    assert not script.acceleration.any()
    mode, horizontal, vz = script.step(altitude=5.0, offset=(4.0, 0.0))
    assert mode == Mode.CLIMB and vz == CONFIG.climb_speed_m_s  # tracks while it climbs
    np.testing.assert_allclose(horizontal, TRACKING)
    np.testing.assert_allclose(script.acceleration, [*TRACKING_ACCELERATION, 0.0])

    mode, horizontal, vz = script.step(altitude=7.4, offset=(4.0, 0.0))
    assert mode == Mode.FOLLOW and vz == pytest.approx(0.1)  # holds IH, not 7.4 m
    np.testing.assert_allclose(horizontal, TRACKING)

    mode, _, vz = script.step(altitude=7.5, offset=(0.3, 0.2))
    assert mode == Mode.APPROACH and vz == -CONFIG.descent_speed_m_s

    mode, _, _ = script.step(altitude=6.0, offset=(0.8, 0.0))  # inside the hysteresis band
    assert mode == Mode.APPROACH

    mode, _, vz = script.step(altitude=5.0, offset=(1.2, 0.0))  # off centre: stop descending
    assert mode == Mode.FOLLOW
    mode, _, vz = script.step(altitude=4.9, offset=(1.2, 0.0))
    assert mode == Mode.FOLLOW and vz == pytest.approx(0.1)  # holds the 5.0 m where it stopped

    script.step(altitude=5.0, offset=(0.1, 0.0))
    mode, horizontal, vz = script.step(altitude=3.0, offset=(0.1, 0.0), height=1.4)
    assert mode == Mode.LAND and vz == -CONFIG.landing_speed_m_s
    np.testing.assert_allclose(horizontal, TRACKING)
    np.testing.assert_allclose(script.acceleration, [*TRACKING_ACCELERATION, 0.0])

    # Below LH an invalid estimate aborts the landing: climb out at the climb speed, coasting with
    # the target's last velocity (no acceleration feed-forward), never descend.
    mode, horizontal, vz = script.step(altitude=2.5, seen=False, height=0.8)
    assert mode == Mode.ABORT and vz == CONFIG.climb_speed_m_s
    assert np.all(np.isfinite(horizontal))
    np.testing.assert_allclose(horizontal, TARGET_VELOCITY)  # the last seen one, not the NaN fed now
    assert not script.acceleration.any()
    mode, _, vz = script.step(altitude=2.5, seen=False, height=0.05)  # a stale height is no touchdown
    assert mode == Mode.ABORT and vz == CONFIG.climb_speed_m_s

    # Seen again: a retry, from following at that height: centred so descend, and below LH land.
    assert script.step(altitude=2.5, offset=(0.1, 0.0), height=0.9)[0] == Mode.FOLLOW
    assert script.step(altitude=2.5, offset=(0.1, 0.0), height=0.9)[0] == Mode.APPROACH
    mode, _, vz = script.step(altitude=2.4, offset=(0.1, 0.0), height=0.8)
    assert mode == Mode.LAND and vz == -CONFIG.landing_speed_m_s
    mode, horizontal, vz = script.step(altitude=1.7, offset=(0.0, 0.0), height=0.05)
    assert mode == Mode.LANDED and vz == 0.0
    np.testing.assert_allclose(horizontal, TARGET_VELOCITY)
    assert script.step(altitude=1.7, seen=False, height=0.05)[0] == Mode.LANDED  # terminal


def test_target_lost_holds_then_climbs_to_search_then_resumes():
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.2, 0.0))[0] == Mode.APPROACH

    lost_at = script.time
    mode, horizontal, vz = script.step(altitude=4.0, seen=False)
    assert mode == Mode.HOLD and vz == 0.0
    assert np.all(np.isfinite(horizontal))
    np.testing.assert_allclose(horizontal, TARGET_VELOCITY)  # coasts with the last seen velocity
    assert not script.acceleration.any()
    mode, _, vz = script.step(altitude=4.2, seen=False)
    assert mode == Mode.HOLD and vz == 0.0  # above the held 4.0 m, but no blind descent

    while script.machine.mode == Mode.HOLD:
        mode, horizontal, vz = script.step(altitude=4.0, seen=False)
    searched_at = script.time - 0.02
    assert mode == Mode.SEARCH and searched_at - lost_at == pytest.approx(CONFIG.lost_hold_s)
    assert vz == CONFIG.climb_speed_m_s and not horizontal.any()
    mode, _, vz = script.step(altitude=7.9, seen=False)
    assert mode == Mode.SEARCH and vz == 0.0  # above IH: waits, never descends blind

    mode, horizontal, vz = script.step(altitude=7.9, offset=(2.0, 0.0))
    assert mode == Mode.FOLLOW and vz == pytest.approx(0.0)  # holds where it found the target
    np.testing.assert_allclose(horizontal, TRACKING)


def test_never_descends_on_an_invalid_estimate():
    # Random flight at any height, below LH too: unseen means no descent, whatever the mode.
    rng = np.random.default_rng(0)
    script = Script()
    visited, seen = set(), True
    for _ in range(3000):
        seen ^= rng.random() < 0.02  # seen and unseen spells of about a second
        mode, _, vz = script.step(altitude=rng.uniform(0.0, 10.0), seen=seen,
                                  offset=rng.uniform(-1.5, 1.5, 2), height=rng.uniform(0.2, 10.0))
        visited.add(mode)
        if not seen:
            assert vz >= 0.0
    assert {Mode.CLIMB, Mode.FOLLOW, Mode.APPROACH, Mode.LAND, Mode.HOLD, Mode.SEARCH, Mode.ABORT} <= visited


def test_waits_at_lh_for_a_landing_window_and_waves_off_when_it_closes():
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    closed, lh = (False, False), CONFIG.landing_height_m
    mode, horizontal, vz = script.step(altitude=3.0, offset=(0.1, 0.0), height=lh - 0.1, window=closed)
    assert mode == Mode.WAIT and vz == pytest.approx(0.1 * CONFIG.altitude_gain)  # back up to LH
    np.testing.assert_allclose(horizontal, TRACKING)  # tracking the target meanwhile
    mode, _, vz = script.step(altitude=3.0, offset=(0.1, 0.0), height=lh + 0.05, window=(False, True))
    assert mode == Mode.WAIT and vz == pytest.approx(-0.05 * CONFIG.altitude_gain)  # holding LH, not committing
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=lh, window=closed, seen=False)[0] == Mode.ABORT
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=lh)[0] == Mode.FOLLOW
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=lh)[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=lh - 0.02, window=closed)[0] == Mode.WAIT
    mode, _, vz = script.step(altitude=3.0, offset=(0.1, 0.0), height=lh, window=(True, True))
    assert mode == Mode.LAND and vz == -CONFIG.landing_speed_m_s  # the window opened: commit
    assert script.step(altitude=2.7, offset=(0.1, 0.0), height=lh - 0.3, window=(False, True))[0] == Mode.LAND
    mode, _, vz = script.step(altitude=2.6, offset=(0.1, 0.0), height=lh - 0.4, window=closed)
    assert mode == Mode.WAIT and vz > 0  # the deck turned lively: wave off, back up to LH
    assert script.step(altitude=2.6, offset=(0.1, 0.0), height=lh - 0.4, window=(True, True))[0] == Mode.LAND
    assert script.step(altitude=2.0, offset=(0.1, 0.0), height=0.05, window=closed)[0] == Mode.LANDED

    # The target drifting off centre (1.2 m, beyond off_centre_radius_m) while it waits: FOLLOW it again, even as
    # the window opens, rather than commit beside it.
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=lh - 0.1, window=closed)[0] == Mode.WAIT
    mode, horizontal, _ = script.step(altitude=3.0, offset=(1.2, 0.0), height=lh, window=(True, True))
    assert mode == Mode.FOLLOW
    np.testing.assert_allclose(horizontal, TRACKING)


def test_lost_below_lh_climbs_out_whatever_the_mode():
    """A retry found low after an abort (FOLLOW 0.8 m over the target) and a WAIT that loses the estimate climb
    out at the climb speed (ABORT), as LAND does, rather than holding a low altitude blind (before: HOLD); a FOLLOW
    lost above LH still holds."""
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=1.0)[0] == Mode.LAND
    assert script.step(altitude=2.9, height=0.9, seen=False)[0] == Mode.ABORT
    assert script.step(altitude=2.8, offset=(0.7, 0.0), height=0.8)[0] == Mode.FOLLOW  # the retry, low
    mode, _, vz = script.step(altitude=2.8, height=0.8, seen=False)
    assert mode == Mode.ABORT and vz == CONFIG.climb_speed_m_s
    assert script.step(altitude=4.0, offset=(0.7, 0.0), height=3.0)[0] == Mode.FOLLOW  # found again, higher
    # Lost with a low height on the invalid estimate: the last valid height (3 m, above LH) decides, so it holds.
    assert script.step(altitude=4.0, height=0.5, seen=False)[0] == Mode.HOLD

    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=1.4, window=(False, False))[0] == Mode.WAIT
    mode, _, vz = script.step(altitude=3.0, height=1.4, seen=False)
    assert mode == Mode.ABORT and vz == CONFIG.climb_speed_m_s

    # "Below LH" is strictly below: a FOLLOW or APPROACH whose last valid height was exactly LH holds when lost.
    for mode in (Mode.FOLLOW, Mode.APPROACH):
        memory = SupervisorMemory(mode, 0.0, 3.0, (0.0, 0.0), CONFIG.landing_height_m)
        inputs = SupervisorInputs(1.0, 3.0, CONFIG.landing_height_m, False)
        assert next_mode(memory, inputs, CONFIG) == Mode.HOLD, mode.name


def test_abort_climbs_towards_ih_and_stops_there():
    """ABORT climbs at the climb speed while far below IH, slows on the altitude hold's P loop near it (as SEARCH)
    and does not climb past it, however long `lost_hold_s` keeps it in ABORT (before: +climb speed at any
    altitude, up to the monitor's max_altitude_m)."""
    config = dataclasses.replace(CONFIG, lost_hold_s=30.0)
    machine = LandingStateMachine(config)
    machine.memory = machine.memory._replace(mode=Mode.LAND, last_height_m=1.0)
    for time_s, altitude, seen, expected in ((0.0, 2.6, True, -config.landing_speed_m_s),
                                             (0.02, 2.6, False, config.climb_speed_m_s),
                                             (5.0, 7.0, False, config.altitude_gain * 0.5),
                                             (6.0, 7.5, False, 0.0), (7.0, 9.0, False, 0.0), (8.0, 20.0, False, 0.0)):
        command = machine.step(SupervisorInputs(time_s=time_s, altitude_m=altitude, height_above_target_m=1.0,
                                                target_valid=seen))
        assert machine.mode == (Mode.LAND if seen else Mode.ABORT)
        assert command[2] == pytest.approx(expected)


def test_abort_lost_for_lost_hold_s_turns_to_search_and_stops_coasting():
    """ABORT coasts sideways at the last seen velocity, but only for lost_hold_s: then SEARCH, standing."""
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(0.1, 0.0), height=1.0)[0] == Mode.LAND
    lost_at = script.time
    mode, horizontal, _ = script.step(altitude=2.9, height=0.9, seen=False)
    assert mode == Mode.ABORT
    np.testing.assert_allclose(horizontal, TARGET_VELOCITY)
    while script.machine.mode == Mode.ABORT and script.time - lost_at < 2 * CONFIG.lost_hold_s:
        mode, horizontal, _ = script.step(altitude=4.0, seen=False)
    assert mode == Mode.SEARCH and script.time - 0.02 - lost_at == pytest.approx(CONFIG.lost_hold_s)
    assert not horizontal.any()


@pytest.mark.parametrize("lost_mode", [Mode.HOLD, Mode.ABORT], ids=lambda mode: mode.name)
def test_search_begins_exactly_lost_hold_s_after_the_target_was_lost(lost_mode):
    """The boundary itself: lost_hold_s after entering HOLD or ABORT (times exactly representable) it is SEARCH,
    a step before it is not."""
    config = dataclasses.replace(CONFIG, lost_hold_s=0.75)
    machine = LandingStateMachine(config)
    machine.memory = machine.memory._replace(mode=lost_mode, mode_since_s=0.25, altitude_hold_m=5.0)

    def step(time_s):
        machine.step(SupervisorInputs(time_s=time_s, altitude_m=5.0, height_above_target_m=5.0, target_valid=False))
        return machine.mode

    assert step(0.5) == lost_mode
    assert step(1.0) == Mode.SEARCH


@pytest.mark.parametrize("climb, descent", [(1.0, 0.5), (0.5, 2.0)])
def test_the_altitude_hold_is_limited_to_the_descent_speed_down_and_the_climb_speed_up(climb, descent):
    """hold_rate's P loop saturates at -descent_speed_m_s towards a height far below and at +climb_speed_m_s
    towards one far above (the two speeds set apart, either the larger); near the height it is altitude_gain x the
    error."""
    config = dataclasses.replace(CONFIG, climb_speed_m_s=climb, descent_speed_m_s=descent)
    assert hold_rate(-5.0, config) == -descent
    assert hold_rate(5.0, config) == climb
    assert hold_rate(-0.25, config) == pytest.approx(-0.25 * config.altitude_gain)


def test_approach_descends_at_the_descent_speed_not_the_landing_speed():
    """APPROACH, above LH, comes down at descent_speed_m_s; landing_speed_m_s is LAND's, below LH (the two set
    apart, as open-landing.yaml does: 1.0 and 0.3 m/s)."""
    config = LandingConfig(descent_speed_m_s=1.0, landing_speed_m_s=0.3)
    memory, command = supervisor_step(SupervisorMemory(mode=Mode.APPROACH, last_height_m=5.0),
                                      SupervisorInputs(0.0, 5.0, 5.0, True), config)
    assert memory.mode == Mode.APPROACH and command[2] == -1.0


@pytest.mark.parametrize("offset_m, mode", [(0.3, Mode.LAND), (1.2, Mode.FOLLOW), (5.0, Mode.FOLLOW)])
def test_reaching_lh_off_centre_follows_rather_than_lands(offset_m, mode):
    """APPROACH reaching LH with the target beyond off_centre_radius_m (1 m) follows it again; before, LAND came
    first and, with no off-centre exit, landed beside a target 5 m away."""
    script = Script()
    for altitude in (1.0, 7.5, 7.5):
        script.step(altitude=altitude, offset=(0.2, 0.0))
    assert script.step(altitude=6.0, offset=(0.1, 0.0))[0] == Mode.APPROACH
    assert script.step(altitude=3.0, offset=(offset_m, 0.0), height=CONFIG.landing_height_m - 0.05)[0] == mode


@pytest.mark.parametrize("mode, offset_m, height_m, expected", [
    (Mode.FOLLOW, CONFIG.centred_radius_m, 5.0, Mode.APPROACH),  # centred: within centred_radius_m
    (Mode.APPROACH, CONFIG.off_centre_radius_m, 5.0, Mode.APPROACH),  # off centre only beyond off_centre_radius_m
    (Mode.APPROACH, 0.0, CONFIG.landing_height_m, Mode.LAND),  # height above target <= LH
    (Mode.LAND, 0.0, CONFIG.touchdown_height_m, Mode.LANDED),  # touchdown at touchdown_height_m
    (Mode.FOLLOW, 0.8, 5.0, Mode.FOLLOW),  # the hysteresis band: beyond centred_radius_m, not yet off centre
], ids=["centred", "off-centre", "lh", "touchdown", "band"])
def test_each_threshold_exactly_at_its_limit_takes_the_documented_transition(mode, offset_m, height_m, expected):
    """The supervisor's limits as the module docstring and LandingConfig give them: the target exactly
    centred_radius_m off is centred, exactly off_centre_radius_m off is not yet off centre, a height above the
    target exactly LH lands and exactly touchdown_height_m is touchdown; FOLLOW with the target in the band
    between the two radii (0.8 m, between 0.5 and 1) does not start the descent."""
    memory = SupervisorMemory(mode, 0.0, height_m, (0.0, 0.0), height_m)
    inputs = SupervisorInputs(1.0, height_m, height_m, True, np.array([offset_m, 0.0]))
    assert next_mode(memory, inputs, CONFIG) == expected


@pytest.mark.parametrize("altitude_m", [7.25, 7.75])
@pytest.mark.parametrize("seen, expected", [(True, Mode.FOLLOW), (False, Mode.SEARCH)], ids=["seen", "unseen"])
def test_climb_reaches_ih_exactly_altitude_tolerance_m_away(altitude_m, seen, expected):
    """CLIMB has reached IH (7.5 m) within altitude_tolerance_m, the limit included: 0.25 m below or above it
    (all exactly representable) it follows a seen target or searches for an unseen one."""
    config = LandingConfig(altitude_tolerance_m=0.25)
    inputs = SupervisorInputs(1.0, altitude_m, altitude_m, seen)
    assert next_mode(SupervisorMemory(Mode.CLIMB), inputs, config) == expected


def test_waits_and_wave_offs_are_counted():
    modes = [Mode.APPROACH, Mode.WAIT, Mode.WAIT, Mode.LAND, Mode.WAIT, Mode.LAND, Mode.LAND, Mode.ABORT,
             Mode.FOLLOW, Mode.APPROACH, Mode.LAND]
    t = 0.5 * np.arange(len(modes))
    out = descent_counts(t, np.array(modes, dtype=int))
    assert out == {"aborts": 2, "retries": 2, "waits": 2, "wait_s": 1.5}


@pytest.mark.parametrize("modes, aborts", [([Mode.APPROACH, Mode.WAIT, Mode.LAND, Mode.LANDED], 0),
                                            ([Mode.LAND, Mode.WAIT, Mode.LAND], 1)], ids=["approach-wait", "land-wait"])
def test_a_wave_off_is_land_back_to_wait_only(modes, aborts):
    """A wave-off gives up the final descent: LAND back to WAIT counts as an abort; waiting from APPROACH (the
    window not yet open) gives nothing up."""
    t = 0.5 * np.arange(len(modes))
    assert descent_counts(t, np.array(modes, dtype=int))["aborts"] == aborts


@pytest.mark.parametrize("yaml, message", [
    ("initial_height_m: 1.0", r"landing.initial_height_m \(IH = 1.0\) must be above"),
    ("landing_height_m: 8.0", r"must be above landing.landing_height_m \(LH = 8.0\)"),
    ("climb_speed_m_s: 0.0", "landing.climb_speed_m_s must be positive"),
    ("off_centre_radius_m: 0.2", "landing.off_centre_radius_m must be at least"),
    ("takeoff_height_m: 7.5", "landing.takeoff_height_m must be below landing.initial_height_m"),  # IH itself
    ("land_acceptance_radius_m: -0.1", "landing.land_acceptance_radius_m must not be negative"),
    ("rate_hz: 0.5", r"landing.rate_hz \(0.5 Hz\) must be at least landing.altitude_gain \(1 /s\)"),
    ("touchdown_height_m: 1.5", "landing.touchdown_height_m must be below landing.landing_height_m"),  # LH itself
    ("initial_height_m: 1.5", r"landing.initial_height_m \(IH = 1.5\) must be above"),  # LH itself
])
def test_bad_config_is_rejected_by_name(yaml, message):
    config = yaml_load_typed(schema=LandingConfig, data=yaml)
    with pytest.raises(ValueError, match=message):
        LandingSupervisor(config)


@pytest.mark.parametrize("fields", [dict(centred_radius_m=0.5, off_centre_radius_m=0.5),
                                    dict(rate_hz=1.0, altitude_gain=1.0)], ids=["radii", "rate"])
def test_configs_at_their_limits_are_accepted(fields):
    """off_centre_radius_m must be at least centred_radius_m: equal (no hysteresis band) is allowed; rate_hz must
    be at least altitude_gain: equal (the hold closes all its error in one sample, no overshoot) is allowed."""
    LandingConfig(**fields).validate()


def supervisor_at(height_m: float, valid: float, config: LandingConfig = CONFIG):
    """A LandingSupervisor (`config`) in a Simulator, its inputs fixed: altitude and height above the target
    `height_m`, target_valid `valid`, the target centred, TARGET_VELOCITY and the tracking commands."""
    system = LandingSupervisor(config)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    for name, value in (("altitude", [height_m]), ("height_above_target", [height_m]), ("target_valid", [valid]),
                        ("target_offset", [0.0, 0.0]), ("target_velocity", TARGET_VELOCITY),
                        ("tracking_velocity", TRACKING), ("tracking_acceleration", TRACKING_ACCELERATION)):
        system.GetInputPort(name).FixValue(context, value)
    return system, simulator, context


def test_system_wraps_the_state_machine():
    system, simulator, context = supervisor_at(0.0, 0.0)
    command, mode = system.GetOutputPort("command"), system.GetOutputPort("mode")
    assert mode.Eval(context)[0] == Mode.TAKEOFF
    np.testing.assert_allclose(command.Eval(context), np.zeros(7))

    simulator.AdvanceTo(0.01)  # the sample at t = 0
    np.testing.assert_allclose(command.Eval(context), [0, 0, CONFIG.climb_speed_m_s, 0, 0, 0, 0])

    system.GetInputPort("altitude").FixValue(context, [7.5])
    simulator.AdvanceTo(0.05)  # two samples: TAKEOFF -> CLIMB -> SEARCH (target not seen)
    assert mode.Eval(context)[0] == Mode.SEARCH
    system.GetInputPort("target_valid").FixValue(context, [1.0])
    simulator.AdvanceTo(0.07)
    assert mode.Eval(context)[0] == Mode.FOLLOW
    np.testing.assert_allclose(command.Eval(context), [*TRACKING, 0.0, 0.0, *TRACKING_ACCELERATION, 0.0])
    system.GetInputPort("target_valid").FixValue(context, [0.0])
    simulator.AdvanceTo(0.09)
    assert mode.Eval(context)[0] == Mode.ABORT  # its memory kept the last valid height, 0 m: below LH


def test_the_commanded_yaw_is_yaw_deg_in_radians():
    """The command's yaw (index 3) is LandingConfig.yaw_deg in radians: 90 deg is pi / 2, from the state machine,
    and from the system both before its first sample and after it."""
    config = LandingConfig(yaw_deg=90.0)
    command = LandingStateMachine(config).step(SupervisorInputs(0.0, 0.0, 0.0, False))
    assert command[3] == pytest.approx(math.pi / 2)
    system, simulator, context = supervisor_at(0.0, 0.0, config)
    command = system.GetOutputPort("command")
    assert command.Eval(context)[3] == pytest.approx(math.pi / 2)
    simulator.AdvanceTo(0.01)  # the sample at t = 0
    np.testing.assert_allclose(command.Eval(context), [0, 0, config.climb_speed_m_s, math.pi / 2, 0, 0, 0])


def approaching_system(window=None):
    """A LandingSupervisor flown by fixed inputs to APPROACH at IH over a centred, seen target (samples at 0, 20,
    40 and 60 ms: TAKEOFF -> CLIMB -> FOLLOW -> APPROACH); `window` fixes its landing_window input."""
    system, simulator, context = supervisor_at(7.5, 1.0)
    if window is not None:
        system.GetInputPort("landing_window").FixValue(context, window)
    simulator.AdvanceTo(0.07)
    assert system.GetOutputPort("mode").Eval(context)[0] == Mode.APPROACH
    return system, simulator, context


def test_system_reads_the_landing_window_as_open_then_holds():
    """The landing_window port is [open, holds]: reaching LH with [0, 1] waits at LH, with [1, 0] commits to LAND
    and, its window not holding, waves off to WAIT at the next sample."""
    system, simulator, context = approaching_system(window=[0.0, 1.0])
    mode = system.GetOutputPort("mode")
    system.GetInputPort("height_above_target").FixValue(context, [CONFIG.landing_height_m - 0.1])
    simulator.AdvanceTo(0.09)
    assert mode.Eval(context)[0] == Mode.WAIT

    system, simulator, context = approaching_system(window=[1.0, 0.0])
    system.GetInputPort("height_above_target").FixValue(context, [CONFIG.landing_height_m - 0.1])
    simulator.AdvanceTo(0.09)
    assert system.GetOutputPort("mode").Eval(context)[0] == Mode.LAND
    simulator.AdvanceTo(0.11)
    assert system.GetOutputPort("mode").Eval(context)[0] == Mode.WAIT


def test_system_takes_a_nan_flag_as_false():
    """A NaN on target_valid, landing_window or rendezvous_valid is no flag raised (bool(nan) is True): the search
    goes on, the final descent waits at LH, and the unseen target gives no horizontal command."""
    system, simulator, context = supervisor_at(7.5, np.nan)
    system.GetInputPort("rendezvous_valid").FixValue(context, [np.nan])
    mode, command = system.GetOutputPort("mode"), system.GetOutputPort("command")
    simulator.AdvanceTo(0.05)  # TAKEOFF -> CLIMB -> SEARCH (nothing seen)
    assert mode.Eval(context)[0] == Mode.SEARCH
    np.testing.assert_array_equal(command.Eval(context)[[0, 1, 4, 5]], np.zeros(4))  # no rendezvous to track

    system, simulator, context = approaching_system(window=[np.nan, np.nan])
    system.GetInputPort("height_above_target").FixValue(context, [CONFIG.landing_height_m - 0.1])
    simulator.AdvanceTo(0.09)
    assert system.GetOutputPort("mode").Eval(context)[0] == Mode.WAIT


def test_system_coasts_with_the_last_target_velocity_it_kept():
    """The system's memory keeps the last valid target velocity as (x, y): lost above LH, HOLD coasts with exactly
    it (not the NaN of the invalid estimate now, nor its axes swapped)."""
    system, simulator, context = approaching_system()
    system.GetInputPort("target_valid").FixValue(context, [0.0])
    system.GetInputPort("target_velocity").FixValue(context, [np.nan, np.nan])
    simulator.AdvanceTo(0.09)
    assert system.GetOutputPort("mode").Eval(context)[0] == Mode.HOLD
    np.testing.assert_array_equal(system.GetOutputPort("command").Eval(context)[:2], TARGET_VELOCITY)


def test_aborted_and_retried_final_descents_are_counted():
    modes = [Mode.FOLLOW, Mode.APPROACH, Mode.LAND, Mode.LAND, Mode.ABORT, Mode.FOLLOW, Mode.APPROACH, Mode.LAND,
             Mode.ABORT, Mode.ABORT, Mode.SEARCH, Mode.FOLLOW, Mode.LAND, Mode.LAND]
    n = len(modes)
    relative = np.zeros((n, 14))
    relative[:, HEIGHT] = 5.0  # never down: no touchdown
    log = {"t": 0.02 * np.arange(n), "mode": np.array(modes, dtype=int), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, 17)), "vehicle_state": np.zeros((n, 4))}
    out = landing_metrics(log, "timeout: no touchdown", load_scenario("gv-landing")[1])
    assert out["aborts"] == 2 and out["retries"] == 2


def test_a_run_ended_on_the_supervisors_landed_is_a_touchdown_even_if_the_log_missed_it():
    # The run stops at the step the supervisor declares LANDED: its last logged sample is still LAND.
    n = 5
    relative = np.zeros((n, 14))
    relative[:, HEIGHT] = np.linspace(0.5, 0.15, n)  # the true gear still 5 cm up when the estimate said down
    log = {"t": 0.02 * np.arange(n), "mode": np.full(n, int(Mode.LAND)), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, 17)), "vehicle_state": np.zeros((n, 4)), "vehicle_speed": np.zeros(n)}
    config = load_scenario("gv-landing")[1]
    out = landing_metrics(log, "landed: the supervisor reported touchdown by t = 0.08 s", config)
    assert out["success"] and out["failure_reason"] is None and out["touchdown_by"] == "supervisor"
    assert out["touchdown_rel_speed_mps"] == pytest.approx(np.sqrt(2 * 9.81 * 0.05))  # the fall from 5 cm
    relative[:, 0] = 0.9  # the pad 0.9 m away: down beside it
    out = landing_metrics(log, "landed: the supervisor reported touchdown by t = 0.08 s", config)
    assert not out["success"] and out["failure_reason"] == "missed_pad"


def test_a_run_ended_on_the_gears_touch_is_a_touchdown_even_if_the_log_missed_it():
    # The monitor's touch and the loggers' last sample are at the same time; the run stops before that sample.
    n = 5
    relative = np.zeros((n, 14))
    relative[:, HEIGHT] = np.linspace(0.3, 0.1002, n)
    log = {"t": 0.02 * np.arange(n), "mode": np.full(n, int(Mode.LAND)), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, 17)), "vehicle_state": np.zeros((n, 4)), "vehicle_speed": np.zeros(n)}
    config = load_scenario("gv-landing")[1]
    out = landing_metrics(log, "landed: the gear touched the pad at t = 0.10 s", config)
    assert out["success"] and out["touchdown_by"] == "contact" and out["time_to_land_s"] == pytest.approx(0.08, abs=0.01)
    out = landing_metrics(log, "timeout: no touchdown", config)
    assert not out["success"]


def test_under_the_pad_is_not_a_touchdown():
    """The UAV under the pad's footprint, beneath its underside (the Stewart deck's 0.7 m over the ground): its
    height above the pad is under touchdown_height_m, but it is not on the pad."""
    n = 5
    relative = np.zeros((n, 14))
    relative[:, HEIGHT] = -0.7
    log = {"t": 0.02 * np.arange(n), "mode": np.full(n, int(Mode.TAKEOFF)), "true_relative_state": relative,
           "quadrotor_state": np.zeros((n, 17)), "vehicle_state": np.zeros((n, 4)), "vehicle_speed": np.zeros(n)}
    config = load_scenario("gv-landing")[1]
    out = landing_metrics(log, "timeout: no touchdown", config)
    assert not out["success"] and out["touchdown_error_m"] is None and out["failure_reason"] == "timeout"
    relative[:, HEIGHT] = 0.05  # on it
    assert landing_metrics(log, "timeout: no touchdown", config)["success"]


def test_touchdown_by_contact_descends_on_at_landing_speed_from_landed():
    config = LandingConfig(touchdown_by="contact")
    machine = LandingStateMachine(config)
    machine.memory = machine.memory._replace(mode=Mode.LAND)
    inputs = SupervisorInputs(time_s=0.0, altitude_m=1.7, height_above_target_m=0.05, target_valid=True,
                              target_velocity_m_s=TARGET_VELOCITY, tracking_velocity_m_s=TRACKING)
    command = machine.step(inputs)
    assert machine.mode == Mode.LANDED and command[2] == -config.landing_speed_m_s
    np.testing.assert_allclose(command[:2], TRACKING)  # still tracking the pad (at 12 m/s it curves away)
    command = machine.step(dataclasses.replace(inputs, time_s=0.02, target_valid=False))
    assert machine.mode == Mode.ABORT and command[2] == config.climb_speed_m_s  # it never descends unseen
    with pytest.raises(ValueError, match="landing.touchdown_by must be one of estimate, contact, not 'gear'"):
        LandingConfig(touchdown_by="gear").validate()


def test_with_touchdown_by_contact_only_the_gears_touch_is_the_touchdown():
    # The supervisor's LANDED 5 cm early; the UAV goes on at 0.3 m/s and the gear touches two samples later.
    n = 7
    relative = np.zeros((n, 14))
    relative[:, HEIGHT] = np.linspace(0.25, 0.07, n)
    quad = np.zeros((n, 17))
    quad[:, 9] = -0.3  # v_WB z
    log = {"t": 0.02 * np.arange(n), "mode": np.array([Mode.LAND] * 3 + [Mode.LANDED] * 4, dtype=int),
           "true_relative_state": relative, "quadrotor_state": quad, "vehicle_state": np.zeros((n, 4)),
           "vehicle_speed": np.zeros(n)}
    config = load_scenario("marker-landing-wind")[1]
    assert config.landing.touchdown_by == "contact"
    out = landing_metrics(log, "landed: the gear touched the pad at t = 0.12 s", config)
    assert out["touchdown_by"] == "contact" and out["touchdown_gap_m"] == 0.0
    assert out["touchdown_rel_speed_mps"] == pytest.approx(0.3)  # no fall
    assert out["time_to_land_s"] == pytest.approx(0.10)


@pytest.mark.parametrize("touchdown_by", ["estimate", "contact"])
def test_final_descent_holds_its_height_while_the_target_is_beyond_the_acceptance_radius(touchdown_by):
    config = LandingConfig(land_acceptance_radius_m=0.15, touchdown_by=touchdown_by)
    machine = LandingStateMachine(config)
    machine.memory = machine.memory._replace(mode=Mode.LAND)

    def step(time, offset, height=0.6):
        inputs = SupervisorInputs(time_s=time, altitude_m=2.2, height_above_target_m=height, target_valid=True,
                                  target_offset_m=np.asarray(offset, float), target_velocity_m_s=TARGET_VELOCITY,
                                  tracking_velocity_m_s=TRACKING)
        return machine.step(inputs)

    command = step(0.0, (0.12, 0.12))  # 0.17 m off: hold, track, no abort
    assert machine.mode == Mode.LAND and command[2] == 0.0
    np.testing.assert_allclose(command[:2], TRACKING)
    assert step(0.02, (0.1, 0.1))[2] == -config.landing_speed_m_s  # 0.14 m: descend
    assert step(0.03, (0.15, 0.0))[2] == -config.landing_speed_m_s  # exactly the radius: within it, descend
    command = step(0.04, (0.0, 0.2), height=0.05)  # at touchdown height 0.2 m off
    assert machine.mode == Mode.LANDED
    assert command[2] == 0.0  # contact: waits there for the pad; estimate: the motors stop
    assert step(0.06, (0.0, 0.1), height=0.05)[2] == (-config.landing_speed_m_s if touchdown_by == "contact" else 0.0)
    # Without a radius (the default) the final descent goes on whatever the offset.
    machine = LandingStateMachine(LandingConfig(touchdown_by=touchdown_by))
    machine.memory = machine.memory._replace(mode=Mode.LAND)
    assert step(0.0, (0.5, 0.5))[2] == -LandingConfig().landing_speed_m_s


@pytest.mark.parametrize("gap_m, vertical_speed", [(0.2, 0.5), (0.05, 0.3), (0.1, -0.4), (0.0, -0.3)])
def test_the_fall_after_the_motors_stop_is_ballistic(gap_m, vertical_speed):
    """impact's time and speed solve gap + v t - g t^2 / 2 = 0 with speed g t - v, a UAV still rising (v > 0)
    included (before: its upward speed was dropped, the fall 0.20 instead of 0.26 s at 0.2 m and 0.5 m/s)."""
    g = 9.81
    t, speed = impact(gap_m, vertical_speed, g)
    assert gap_m + vertical_speed * t - g * t * t / 2 == pytest.approx(0.0, abs=1e-12)
    assert speed == pytest.approx(g * t - vertical_speed) and t >= 0
