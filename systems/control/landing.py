"""Landing supervisor of seed 003 (Sec. 2.3 and 3): the mode logic around the tracking PID.

The UAV takes off, climbs to the initial altitude IH, follows the target with the PID, descends
towards it while it is centred in the downward view, and below the landing height LH lands
vertically. It reads the perception seam (systems/perception/seam.py), so "seen" is the
estimate's valid flag. Ours, beyond the paper (which lands below LH without further checks because
there the target floods its camera's view): the final landing also stops on an invalid estimate.
With no valid estimate it holds its altitude, coasting with the target's last velocity, and after
`lost_hold_s` climbs back to IH to search; below LH it aborts instead: it climbs out, coasting, and
tries again from FOLLOW once it sees the target. It never descends on an invalid estimate. (A filter
that predicts through a blind last metre keeps its estimate valid while its covariance allows.)
With a rendezvous source (the vehicle's broadcast navigation, systems/perception/rendezvous.py; the input
`rendezvous_valid`) the UAV tracks that coarse target wherever it has no vision: climbing, holding,
searching and aborting fly towards the vehicle instead of standing still or coasting, never descending
on it (a climb that starts above IH waits there, following it, until the camera has the target).
On a moving deck the final descent also waits for a landing window (the input `landing_window`, from
systems/control/landing_window.py; always open where it is not connected): at LH the UAV holds LH above
the target until the window opens, and a descent whose window closes goes back up to LH (an abort).

Modes and what they command (velocities in World, z up; "hold" is a P loop on altitude):

    TAKEOFF   straight up at climb speed, until takeoff_height_m          -> CLIMB
    CLIMB     to IH, tracking the target if seen                          -> FOLLOW (seen) / SEARCH
    FOLLOW    track, hold altitude; target centred                        -> APPROACH
    APPROACH  track, descend; height above target <= LH                   -> LAND (window open) / WAIT
              target off centre                                           -> FOLLOW
    LAND      track, descend at landing speed (hold the height while the target is beyond
              land_acceptance_radius_m, where set); touchdown             -> LANDED
              not seen                                                    -> ABORT
              the window closes                                           -> WAIT
    WAIT      track, hold LH above the target; window open                -> LAND
              not seen -> ABORT; target off centre -> FOLLOW
    LANDED    keep the target's velocity; no vertical speed (the motors stop and the run ends), or, with
              touchdown_by contact, track and descend at landing speed as in LAND until the gear touches
              (not seen -> ABORT, as in LAND)
    HOLD      not seen in FOLLOW/APPROACH (ABORT instead where the last valid estimate was below LH):
              coast, hold altitude; seen -> FOLLOW; lost_hold_s -> SEARCH
    SEARCH    no horizontal speed, back to IH (entered from CLIMB within altitude_tolerance_m of IH, or from HOLD
              or ABORT at or below it: a climb, or a descent of about that tolerance at most); seen -> FOLLOW
    ABORT     coast, climb towards IH at climb speed (slowing to stop there, as SEARCH); seen -> FOLLOW
              (a retry); lost_hold_s -> SEARCH
    (with a valid rendezvous target, CLIMB, HOLD, SEARCH and ABORT track it instead of coasting or standing)

One transition per step; the command is that of the mode after the transition.
"""

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.flags import is_set


class Mode(IntEnum):
    TAKEOFF = 0
    CLIMB = 1
    FOLLOW = 2
    APPROACH = 3
    LAND = 4
    LANDED = 5
    HOLD = 6
    SEARCH = 7
    ABORT = 8
    WAIT = 9


TOUCHDOWN_BY = ("estimate", "contact")


@dataclass
class LandingConfig:
    rate_hz: float = 50.0  # supervisor update rate (not in the paper)
    initial_height_m: float = 7.5  # IH, seed 003 Sec. 3.1.2 (simulation)
    landing_height_m: float = 1.5  # LH, seed 003 Sec. 3.1.2 (simulation)
    # The rest are not in the paper.
    takeoff_height_m: float = 1.0  # straight up until clear of the ground
    climb_speed_m_s: float = 1.0
    descent_speed_m_s: float = 0.5  # while approaching, above LH
    landing_speed_m_s: float = 0.5  # final vertical landing, below LH
    altitude_gain: float = 1.0  # [1/s], altitude hold and climb to IH
    altitude_tolerance_m: float = 0.2  # IH reached
    centred_radius_m: float = 0.5  # start descending when the target is this close horizontally (or closer)
    off_centre_radius_m: float = 1.0  # stop descending when it is farther than this (hysteresis)
    # LAND descends only while the target is this close horizontally, else holds its height and tracks
    # (PX4's precision landing, PLD_HACC_RAD; 0.2 m there): a pad that drifted off the centre during a
    # coast is caught up with before the gear comes down. 0: LAND descends whatever the offset.
    land_acceptance_radius_m: float = 0.0
    lost_hold_s: float = 1.0  # hold before climbing to search
    touchdown_height_m: float = 0.1  # height above the landing surface that is touchdown
    # What ends the landing: "estimate", the motors stop at LANDED (the estimated height at touchdown_height_m)
    # and the UAV falls what is left; "contact", LANDED descends on at landing speed until the gear touches
    # (a contact switch on the gear, or an autopilot's land detector: PX4 descends at its land speed until
    # it detects the ground), so an estimate a little high or low costs no fall.
    touchdown_by: str = "estimate"
    yaw_deg: float = 0.0  # commanded heading

    @property
    def motors_stop_at_landed(self) -> bool:
        """The supervisor's LANDED ends the landing (touchdown_by estimate), rather than the gear's touch."""
        return self.touchdown_by == "estimate"

    def validate(self, prefix: str = "landing") -> None:
        for name in ("rate_hz", "initial_height_m", "landing_height_m", "takeoff_height_m",
                     "climb_speed_m_s", "descent_speed_m_s", "landing_speed_m_s", "altitude_gain",
                     "altitude_tolerance_m", "centred_radius_m", "off_centre_radius_m",
                     "lost_hold_s", "touchdown_height_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        # The altitude hold's P loop sampled at rate_hz closes altitude_gain / rate_hz of its error per sample (the
        # velocity loop following at once): beyond 1 it overshoots every sample.
        require(self.rate_hz >= self.altitude_gain,
                f"{prefix}.rate_hz ({self.rate_hz:g} Hz) must be at least {prefix}.altitude_gain "
                f"({self.altitude_gain:g} /s): the altitude hold would overshoot every sample")
        require(self.initial_height_m > self.landing_height_m,
                f"{prefix}.initial_height_m (IH = {self.initial_height_m}) must be above "
                f"{prefix}.landing_height_m (LH = {self.landing_height_m})")
        require(self.takeoff_height_m < self.initial_height_m,
                f"{prefix}.takeoff_height_m must be below {prefix}.initial_height_m")
        require(self.touchdown_height_m < self.landing_height_m,
                f"{prefix}.touchdown_height_m must be below {prefix}.landing_height_m")
        require(self.touchdown_by in TOUCHDOWN_BY,
                f"{prefix}.touchdown_by must be one of {', '.join(TOUCHDOWN_BY)}, not {self.touchdown_by!r}")
        require(self.off_centre_radius_m >= self.centred_radius_m,
                f"{prefix}.off_centre_radius_m must be at least {prefix}.centred_radius_m")
        require(self.land_acceptance_radius_m >= 0, f"{prefix}.land_acceptance_radius_m must not be negative")


@dataclass
class SupervisorInputs:
    """What the supervisor sees at one step. Positions, velocities and accelerations are World x-y."""

    time_s: float
    altitude_m: float  # UAV above the ground
    height_above_target_m: float  # UAV above the landing surface (stereo depth or an estimate)
    target_valid: bool  # the target is seen
    target_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(2))  # target - UAV
    target_velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    tracking_velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(2))  # PID, Eq. 26-27
    tracking_acceleration_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(2))  # PID's feed-forward
    window_open: bool = True  # the landing window (module docstring): commit to the final descent
    window_holds: bool = True  # a committed descent may go on
    rendezvous_valid: bool = False  # the coarse target (the vehicle's broadcast) steers the PID where unseen


class SupervisorMemory(NamedTuple):
    mode: Mode = Mode.TAKEOFF
    mode_since_s: float = 0.0
    altitude_hold_m: float = 0.0
    last_target_velocity_m_s: tuple = (0.0, 0.0)
    last_height_m: float = math.inf  # height above the target at the last valid estimate (m)


def next_mode(memory: SupervisorMemory, inputs: SupervisorInputs, config: LandingConfig) -> Mode:
    mode, seen = memory.mode, inputs.target_valid
    offset = math.hypot(inputs.target_offset_m[0], inputs.target_offset_m[1])
    if mode == Mode.TAKEOFF and inputs.altitude_m >= config.takeoff_height_m:
        return Mode.CLIMB
    if mode == Mode.CLIMB and abs(inputs.altitude_m - config.initial_height_m) <= config.altitude_tolerance_m:
        return Mode.FOLLOW if seen else Mode.SEARCH
    # Lost below LH climbs out (ABORT) rather than holding a low altitude blind: LAND, WAIT (LH over the target,
    # or under it after a wave-off), and a FOLLOW or APPROACH whose last valid estimate was below LH (a retry
    # found low); a touchdown by contact still descends in LANDED, so needs the estimate as LAND does.
    low = mode in (Mode.LAND, Mode.WAIT) or (mode in (Mode.FOLLOW, Mode.APPROACH)
                                             and memory.last_height_m < config.landing_height_m)
    if not seen and (low or (mode == Mode.LANDED and not config.motors_stop_at_landed)):
        return Mode.ABORT
    if mode in (Mode.FOLLOW, Mode.APPROACH) and not seen:
        return Mode.HOLD
    if mode == Mode.FOLLOW and offset <= config.centred_radius_m:
        return Mode.APPROACH
    # Off centre before LH: a target that drifted off while approaching is followed again, not landed beside.
    if mode in (Mode.APPROACH, Mode.WAIT) and offset > config.off_centre_radius_m:
        return Mode.FOLLOW
    if mode == Mode.APPROACH and inputs.height_above_target_m <= config.landing_height_m:
        return Mode.LAND if inputs.window_open else Mode.WAIT
    if mode == Mode.WAIT and inputs.window_open:
        return Mode.LAND
    if mode == Mode.LAND and inputs.height_above_target_m <= config.touchdown_height_m:
        return Mode.LANDED
    if mode == Mode.LAND and not inputs.window_holds:
        return Mode.WAIT
    if mode in (Mode.HOLD, Mode.SEARCH, Mode.ABORT) and seen:
        return Mode.FOLLOW
    if mode in (Mode.HOLD, Mode.ABORT) and inputs.time_s - memory.mode_since_s >= config.lost_hold_s:
        return Mode.SEARCH
    return mode


_ZERO = (0.0, 0.0)


def landing_rate(inputs: SupervisorInputs, config: LandingConfig) -> float:
    """The final descent's vertical speed [m/s, World z up]: down at landing speed, or none while the target
    lies beyond `land_acceptance_radius_m` (where set)."""
    radius = config.land_acceptance_radius_m
    if radius > 0 and math.hypot(inputs.target_offset_m[0], inputs.target_offset_m[1]) > radius:
        return 0.0
    return -config.landing_speed_m_s


def hold_rate(height_error_m: float, config: LandingConfig) -> float:
    """The altitude hold's P loop: the vertical speed [m/s, World z up] for a height error (wanted minus
    present, m): altitude_gain times it, at most descent speed down and climb speed up, so a climb towards a
    height slows and stops there."""
    return min(max(config.altitude_gain * height_error_m, -config.descent_speed_m_s), config.climb_speed_m_s)


def mode_command(memory: SupervisorMemory, inputs: SupervisorInputs, config: LandingConfig) -> np.ndarray:
    """The FlightController command for memory.mode: [v_WB_desired (3, m/s), yaw (rad),
    a_WB_feed_forward (3, m/s^2)]. The acceleration feed-forward is the tracking PID's while it
    tracks a seen (or rendezvous) target, else zero (coasting keeps the last target velocity, not its
    acceleration)."""
    mode, seen, rendezvous = memory.mode, inputs.target_valid, inputs.rendezvous_valid
    coast = memory.last_target_velocity_m_s
    if seen or rendezvous:  # the PID on the vision target, or on the rendezvous one where unseen
        tracking, acceleration = inputs.tracking_velocity_m_s, inputs.tracking_acceleration_m_s2
    else:
        tracking, acceleration = coast, _ZERO

    def towards(altitude):
        return hold_rate(altitude - inputs.altitude_m, config)

    if mode == Mode.TAKEOFF:
        horizontal, acceleration, vertical = _ZERO, _ZERO, config.climb_speed_m_s
    elif mode == Mode.CLIMB:
        if not (seen or rendezvous):
            tracking = _ZERO
        horizontal, vertical = tracking, towards(config.initial_height_m)
    elif mode == Mode.FOLLOW:
        horizontal, vertical = tracking, towards(memory.altitude_hold_m)
    elif mode == Mode.APPROACH:
        horizontal, vertical = tracking, -config.descent_speed_m_s
    elif mode == Mode.LAND:
        horizontal, vertical = tracking, landing_rate(inputs, config)
    elif mode == Mode.WAIT:  # LH above the target, from above or (after an abort) from below
        horizontal, vertical = tracking, hold_rate(config.landing_height_m - inputs.height_above_target_m, config)
    elif mode == Mode.LANDED and not config.motors_stop_at_landed:  # on down to the gear's touch, as in LAND
        horizontal, vertical = tracking, landing_rate(inputs, config)
    elif mode == Mode.LANDED:
        horizontal, acceleration, vertical = coast, _ZERO, 0.0
    elif mode == Mode.HOLD:
        horizontal, vertical = tracking, towards(memory.altitude_hold_m)
    elif mode == Mode.ABORT:  # up towards IH (never down: the estimate is not valid), waiting there
        horizontal, vertical = tracking, towards(config.initial_height_m)
    else:  # SEARCH
        horizontal, acceleration = (tracking, acceleration) if rendezvous else (_ZERO, _ZERO)
        vertical = towards(config.initial_height_m)
    if not seen and mode != Mode.LANDED:
        vertical = max(vertical, 0.0)  # never descend on an invalid estimate
    return np.array([horizontal[0], horizontal[1], vertical, math.radians(config.yaw_deg),
                     acceleration[0], acceleration[1], 0.0], dtype=float)


def supervisor_step(memory: SupervisorMemory, inputs: SupervisorInputs, config: LandingConfig):
    """One step: (new memory, command [v_WB_desired (3), yaw, a_WB_feed_forward (3)])."""
    if inputs.target_valid:
        velocity = inputs.target_velocity_m_s
        memory = memory._replace(last_target_velocity_m_s=(float(velocity[0]), float(velocity[1])),
                                 last_height_m=float(inputs.height_above_target_m))
    mode = next_mode(memory, inputs, config)
    if mode != memory.mode:
        hold = config.initial_height_m if memory.mode == Mode.CLIMB else inputs.altitude_m
        memory = memory._replace(mode=mode, mode_since_s=inputs.time_s, altitude_hold_m=hold)
    return memory, mode_command(memory, inputs, config)


class LandingStateMachine:
    """The supervisor for scripts and tests: step(inputs) -> command."""

    def __init__(self, config: LandingConfig):
        config.validate()
        self.config = config
        self.memory = SupervisorMemory()

    @property
    def mode(self) -> Mode:
        return self.memory.mode

    def step(self, inputs: SupervisorInputs) -> np.ndarray:
        """[v_WB_desired (3, m/s, World), yaw (rad), a_WB_feed_forward (3, m/s^2)]: the
        FlightController `command`."""
        self.memory, command = supervisor_step(self.memory, inputs, self.config)
        return command


class LandingSupervisor(LeafSystem):
    """The supervisor sampled at `config.rate_hz`.

    Inputs (World x-y where 2-vectors): `altitude` (1, m), `height_above_target` (1, m),
    `target_valid` (1, over 0.5 when seen; NaN is not), `target_offset` (2, target - UAV, m),
    `target_velocity` (2, m/s), `tracking_velocity` (2, m/s) and `tracking_acceleration` (2, m/s^2),
    the TrackingPid outputs, and optionally `landing_window` (2: [open, holds], over 0.5 when true;
    both true when not connected) and `rendezvous_valid` (1: the PID tracks the rendezvous target where
    the vision one is not valid; false when not connected).
    Outputs: `command` (7, for the FlightController) and `mode` (1, a Mode value), held between
    samples; `command` starts at zero velocity. The memory is discrete state (a vector, so Drake
    copies it without Python).
    """

    def __init__(self, config: LandingConfig):
        super().__init__()
        config.validate()
        self._config = config
        ports = [self.DeclareVectorInputPort(name, size) for name, size in (
            ("altitude", 1), ("height_above_target", 1), ("target_valid", 1), ("target_offset", 2),
            ("target_velocity", 2), ("tracking_velocity", 2), ("tracking_acceleration", 2))]
        (self._altitude, self._height, self._valid, self._offset, self._target_velocity, self._tracking_velocity,
         self._tracking_acceleration) = ports
        self._window = self.DeclareVectorInputPort("landing_window", 2)
        self._rendezvous = self.DeclareVectorInputPort("rendezvous_valid", 1)
        # [mode_since_s, altitude_hold_m, last target velocity (2), last valid height]; the mode is its own group
        # (an output).
        self._memory = self.DeclareDiscreteState(np.array([0.0, 0.0, 0.0, 0.0, math.inf]))
        self._mode = self.DeclareDiscreteState([float(Mode.TAKEOFF)])
        self._command = self.DeclareDiscreteState(np.array([0, 0, 0, np.radians(config.yaw_deg), 0, 0, 0]))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.rate_hz, 0.0, self._update)
        self.DeclareStateOutputPort("command", self._command)
        self.DeclareStateOutputPort("mode", self._mode)

    def _read_inputs(self, context) -> SupervisorInputs:
        def scalar(port):  # without the copy that Eval makes
            return port.EvalBasicVector(context).GetAtIndex(0)

        window_open = window_holds = True
        if self._window.HasValue(context):
            window_open, window_holds = (bool(is_set(flag)) for flag in self._window.Eval(context))
        rendezvous = self._rendezvous.HasValue(context) and is_set(scalar(self._rendezvous))
        return SupervisorInputs(
            context.get_time(), scalar(self._altitude), scalar(self._height), is_set(scalar(self._valid)),
            self._offset.Eval(context), self._target_velocity.Eval(context), self._tracking_velocity.Eval(context),
            self._tracking_acceleration.Eval(context), window_open, window_holds, rendezvous)

    def _update(self, context, discrete_state):
        since, hold, vx, vy, height = context.get_discrete_state(self._memory).get_value().tolist()
        mode = Mode(int(context.get_discrete_state(self._mode).get_value()[0]))
        memory, command = supervisor_step(SupervisorMemory(mode, since, hold, (vx, vy), height),
                                          self._read_inputs(context), self._config)
        discrete_state.set_value(self._memory, [memory.mode_since_s, memory.altitude_hold_m,
                                                *memory.last_target_velocity_m_s, memory.last_height_m])
        discrete_state.set_value(self._mode, [float(memory.mode)])
        discrete_state.set_value(self._command, command)
