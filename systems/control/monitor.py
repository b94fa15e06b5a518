"""Ends a landing run, as the simulation's referee: it reads the truth, not what the UAV believes.

`LandingMonitor`'s periodic update returns EventStatus.ReachedTermination with a message
"<reason>: <details>", reason one of FAILURE_REASONS or "landed", when the supervisor reports
touchdown (LANDED), the UAV's gear touches the pad (its body `touchdown_height_m` above the pad's
top while over the pad), it hits the ground or the vehicle, the state diverges or turns non-finite,
or the seam has had no valid estimate for `lost_timeout_s`. There is no contact dynamics: the
first touch ends the run.
"""

import math
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem

from systems.config import require, require_positive
from systems.control.landing import Mode
from systems.flags import is_set
from systems.perception.seam import HEIGHT, P_BP_W, RELATIVE_STATE_SIZE
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, V_WB

FAILURE_REASONS = ("crash", "diverged", "target_lost", "timeout", "missed_pad")
SUPERVISOR_LANDED = "landed: the supervisor reported touchdown"  # how a run ends on the supervisor's LANDED
GEAR_TOUCHED = "landed: the gear touched the pad"  # and on the gear touching the pad
GV_X, GV_Y, GV_HEADING, GV_STEERING = range(4)  # in the ground vehicle's state [x, y, heading, steering]


@dataclass
class TerminationConfig:
    """When `LandingMonitor` ends a run (not from the papers)."""

    rate_hz: float = 10.0  # checks per second (a run goes on up to one period past its end)
    stop_on_landed: bool = True  # false: fly on after touchdown (the supervisor keeps the vehicle's speed)
    lost_timeout_s: float = 20.0  # no valid estimate this long: "target_lost"
    max_speed_m_s: float = 40.0  # |v_WB| beyond this: "diverged"
    max_altitude_m: float = 60.0  # "diverged"
    max_distance_m: float = 200.0  # horizontal distance to the pad: "diverged"
    ground_tolerance_m: float = 0.02  # the UAV's centre this far below the ground: "crash"

    def validate(self, prefix: str = "termination") -> None:
        for name in ("rate_hz", "lost_timeout_s", "max_speed_m_s", "max_altitude_m", "max_distance_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.ground_tolerance_m >= 0, f"{prefix}.ground_tolerance_m must not be negative")


def gear_on_pad(relative: np.ndarray, heading, touchdown_height_m: float, pad_size_m: float,
                pad_thickness_m: float) -> np.ndarray:
    """Whether the gear touches the pad (bool, (...)), from relative states (..., RELATIVE_STATE_SIZE) and the
    pad's headings (...) [rad]: at most touchdown_height_m [m] above its top, from above (not under its
    underside, pad_thickness_m below the top) and over its pad_size_m square."""
    height = relative[..., HEIGHT]
    over = np.all(np.abs(pad_offset(relative, heading)) <= pad_size_m / 2, axis=-1)
    return (height <= touchdown_height_m) & (height > -pad_thickness_m) & over


def pad_offset(relative: np.ndarray, heading) -> np.ndarray:
    """The UAV's horizontal offset from the pad centre in the pad frame P [m] (x along the vehicle),
    (..., 2), from relative states (..., RELATIVE_STATE_SIZE: pad minus UAV in W) and the vehicle's
    headings (...) [rad]."""
    dx, dy = -relative[..., P_BP_W.start], -relative[..., P_BP_W.start + 1]
    c, s = np.cos(heading), np.sin(heading)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def inside_carrier(platform: PlatformConfig, p_WB, vehicle) -> bool:
    """Whether the UAV's centre p_WB (3, World, m) lies in the carrier's body for its state `vehicle` [x, y,
    heading, steering] (m, rad): over its footprint in the vehicle frame V (x along it, from the rear overhang to
    the front; y across) and below the pad's underside."""
    c, s = math.cos(vehicle[GV_HEADING]), math.sin(vehicle[GV_HEADING])
    dx, dy = p_WB[0] - vehicle[GV_X], p_WB[1] - vehicle[GV_Y]
    along, across = c * dx + s * dy, -s * dx + c * dy  # UAV in the vehicle frame V
    return bool(-platform.rear_overhang_m < along < platform.body_length_m - platform.rear_overhang_m
                and abs(across) < platform.body_width_m / 2 and p_WB[2] < platform.height_m - platform.pad_thickness_m)


class LandingMonitor(LeafSystem):
    """Inputs `quadrotor_state` (17), `vehicle_state` (4), `true_relative_state` (the seam's layout,
    from the truth), `target_valid` (1, the vision seam's flag: with a rendezvous the broadcast may steer
    while the pad is out of view, and target_lost waits for the camera) and `mode` (1)."""

    def __init__(self, termination: TerminationConfig, platform: PlatformConfig, touchdown_height_m: float,
                 ends_on_landed: bool = True):
        """`ends_on_landed`: the supervisor's LANDED ends the run (its motors stop there); false where it
        descends on until the gear touches (landing.touchdown_by contact)."""
        super().__init__()
        self._termination, self._platform, self._touchdown = termination, platform, touchdown_height_m
        self._ends_on_landed = ends_on_landed
        self._quad = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self._vehicle = self.DeclareVectorInputPort("vehicle_state", 4)
        self._relative = self.DeclareVectorInputPort("true_relative_state", RELATIVE_STATE_SIZE)
        self._valid = self.DeclareVectorInputPort("target_valid", 1)
        self._mode = self.DeclareVectorInputPort("mode", 1)
        self._last_seen = self.DeclareDiscreteState([0.0, 0.0])  # [time last valid (s), valid at all (0/1)]
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / termination.rate_hz, 0.0, self._update)

    def check(self, t: float, quad, vehicle, relative, mode: int, last_seen: float,
              seen_ever: bool = True) -> str | None:
        """The termination message for these values (`relative` the true relative state), or None."""
        term, platform = self._termination, self._platform
        quad = np.asarray(quad, dtype=float)
        if not (np.isfinite(quad).all() and np.isfinite(vehicle).all()):
            return f"diverged: non-finite state at t = {t:.2f} s"
        landed = mode == Mode.LANDED and self._ends_on_landed
        if landed and term.stop_on_landed:
            return f"{SUPERVISOR_LANDED} by t = {t:.2f} s"
        if term.stop_on_landed and gear_on_pad(relative, vehicle[GV_HEADING], self._touchdown, platform.pad_size_m,
                                               platform.pad_thickness_m):
            return f"{GEAR_TOUCHED} at t = {t:.2f} s"
        px, py, pz = quad[P_WB].tolist()
        speed = math.hypot(*quad[V_WB].tolist())
        if pz < -term.ground_tolerance_m:
            return f"crash: hit the ground at t = {t:.2f} s, {speed:.1f} m/s"
        if inside_carrier(platform, (px, py, pz), vehicle):
            return f"crash: hit the ground vehicle at t = {t:.2f} s"
        if speed > term.max_speed_m_s:
            return f"diverged: speed {speed:.1f} m/s at t = {t:.2f} s"
        if pz > term.max_altitude_m:
            return f"diverged: altitude {pz:.1f} m at t = {t:.2f} s"
        distance = math.hypot(*relative[P_BP_W][:2])
        if distance > term.max_distance_m:
            return f"diverged: {distance:.0f} m from the pad at t = {t:.2f} s"
        if t - last_seen > term.lost_timeout_s and not landed:  # flying on after touchdown needs no estimate
            if not seen_ever:
                return f"target_lost: no valid estimate of the pad in the first {t:.1f} s"
            return f"target_lost: no valid estimate for {t - last_seen:.1f} s at t = {t:.2f} s"
        return None

    def _update(self, context, discrete_state):
        t = context.get_time()
        last_seen, seen_ever = context.get_discrete_state(self._last_seen).get_value()
        if is_set(self._valid.Eval(context)[0]):
            last_seen, seen_ever = t, 1.0
        discrete_state.set_value(self._last_seen, [last_seen, seen_ever])
        message = self.check(t, self._quad.Eval(context), self._vehicle.Eval(context), self._relative.Eval(context),
                             int(round(self._mode.Eval(context)[0])), last_seen, bool(seen_ever))
        return EventStatus.ReachedTermination(self, message) if message else EventStatus.Succeeded()
