"""Two-stage tracking PID of seed 003 (Sec. 2.3): horizontal offset to the target -> UAV velocity.

Per horizontal World axis, sampled once per vision frame (Eq. 24-25):

    v_ctrl(k) = Kp e(k) + Ki sum_{n<=k} e(n) + Kd (e(k) - e(k-1)),   e(k) = target - UAV position,

with the Table 2 gain set chosen by the UAV's height above the target, and the target's velocity
fed forward (Eq. 26-27): v_uav = v_ugv + v_ctrl. Kd multiplies the raw difference between frames
(Eq. 24 folds Kp Td / T into it), so the gains belong to the frame rate they were tuned at; the
default rate is the paper's. Eq. (24)-(27) act on each horizontal axis alone, so they hold as
written in our z-up World; seed 003's NED frame (Eq. 20-22) needs no conversion here.

Our choices where the paper is silent: the first sample after a start or a lost target has no
derivative term (e(-1) = e(0)), a lost target resets the sums, the commanded speed is limited, and
the sum does not wind up against that limit (conditional integration, `pid_step`). The sum is kept
as it is when the Table 2 gain set switches at 4 m: the paper says nothing of it (its Ki is 0).
A change of the offset's source (the vision seam and the vehicle's broadcast, which differ by the
broadcast's GNSS error) restarts the PID as a lost target does: Kd would otherwise act on the jump
between the two, a velocity kick of Kd times the sources' disagreement for one sample.

Ours, beyond Eq. (24)-(27) (both can be switched off to get the paper's loop alone):
- `latest_feed_forward`: Eq. (26)'s v_ugv is the latest target velocity whenever the command is
  read (the supervisor's 50 Hz), not the one of the last PID sample: with the PID at the frame rate
  (4 Hz) a curving target's velocity held for a frame leaves the UAV behind by ~a T / (2 Kp).
- `acceleration_feed_forward`: the target's acceleration (from the perception seam, the rate of
  its velocity) is passed on as `acceleration_command`, the flight controller's acceleration
  feed-forward. Without it the velocity loop lags a curving target by a / K_v, which the PID
  (Ki = 0 in Table 2) leaves as a position error of a / (K_v Kp): 5 cm at 1.5 m/s on a 15 m arc.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.flags import is_set

# Layout of the PID memory vector.
ERROR_SUM = slice(0, 2)
PREVIOUS_ERROR = slice(2, 4)
STARTED = 4
MEMORY_SIZE = 5


@dataclass
class PidGains:
    kp: float = 0.0  # [1/s]
    ki: float = 0.0  # [1/s] per sample
    kd: float = 0.0  # [1/s] per sample difference


@dataclass
class TrackingPidConfig:
    # Seed 003 Sec. 3.1.1: AirSim delivered 3-5 frames/s on the TX2, one PID step per frame.
    rate_hz: float = 4.0
    switch_height_m: float = 4.0  # seed 003 Table 2, simulation row
    gains_above: PidGains = field(  # height >= switch_height_m: seed 003 Table 2, simulation
        default_factory=lambda: PidGains(kp=0.80, ki=0.00, kd=0.35))
    gains_below: PidGains = field(  # height < switch_height_m: seed 003 Table 2, simulation
        default_factory=lambda: PidGains(kp=1.50, ki=0.00, kd=0.50))
    # Not in the paper: above the fastest ground vehicle of seed 002 (12 m/s).
    max_speed_m_s: float = 15.0
    # Ours, not in the paper (see the module docstring); false for Eq. (24)-(27) alone.
    latest_feed_forward: bool = True  # Eq. (26)'s v_ugv read when the command is read
    acceleration_feed_forward: bool = True  # the target's acceleration to the flight controller

    def validate(self, prefix: str = "pid") -> None:
        for name in ("rate_hz", "switch_height_m", "max_speed_m_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        for group in ("gains_above", "gains_below"):
            gains = getattr(self, group)
            for name in ("kp", "ki", "kd"):
                require(getattr(gains, name) >= 0, f"{prefix}.{group}.{name} must not be negative")


def gains_for_height(height: float, config: TrackingPidConfig) -> PidGains:
    """Seed 003 Table 2: one gain set at or above the switch height [m], the other below it."""
    return config.gains_above if height >= config.switch_height_m else config.gains_below


def initial_memory() -> np.ndarray:
    return np.zeros(MEMORY_SIZE)


def pid_step(memory: np.ndarray, error, height: float, config: TrackingPidConfig, target_velocity=(0.0, 0.0)):
    """One sample of Eq. (24): `error` = target minus UAV horizontal position [m] (World x, y),
    `height` above the target [m], `target_velocity` Eq. (26)'s v_ugv [m/s] (World x, y) at the sample.
    Returns (v_ctrl [m/s], new memory).

    Anti-windup by conditional integration (clamping; ours, Table 2's Ki is 0): an axis's error is left out
    of its sum while Eq. (27)'s v_ugv + v_ctrl is beyond `max_speed_m_s` (so `feed_forward` limits it) and
    that error has the sign of the command on that axis, i.e. while integrating it would only push further
    into the limit; an error against the command is integrated, unwinding the sum."""
    error = np.asarray(error, dtype=float)
    previous = memory[PREVIOUS_ERROR] if memory[STARTED] else error
    gains = gains_for_height(height, config)
    proportional_derivative = gains.kp * error + gains.kd * (error - previous)
    error_sum = memory[ERROR_SUM] + error
    command = np.asarray(target_velocity, dtype=float) + proportional_derivative + gains.ki * error_sum
    if math.hypot(command[0], command[1]) > config.max_speed_m_s:
        error_sum = np.where(error * command > 0, memory[ERROR_SUM], error_sum)
    v_ctrl = proportional_derivative + gains.ki * error_sum
    return v_ctrl, np.concatenate([error_sum, error, [1.0]])


def feed_forward(v_ctrl, target_velocity, max_speed: float) -> np.ndarray:
    """Eq. (26)-(27): v_uav = v_ugv + v_ctrl, scaled down to at most max_speed [m/s]."""
    vx, vy = float(target_velocity[0]) + float(v_ctrl[0]), float(target_velocity[1]) + float(v_ctrl[1])
    speed = math.hypot(vx, vy)
    scale = 1.0 if speed <= max_speed else max_speed / speed
    return np.array([vx * scale, vy * scale])


class HeightScheduledPid:
    """Eq. (24)-(27) for scripts and tests; step() once per frame."""

    def __init__(self, config: TrackingPidConfig):
        config.validate()
        self.config = config
        self.memory = initial_memory()

    def step(self, error, height: float, target_velocity=(0.0, 0.0)) -> np.ndarray:
        """Horizontal UAV velocity command [m/s] in World."""
        v_ctrl, self.memory = pid_step(self.memory, error, height, self.config, target_velocity)
        return feed_forward(v_ctrl, target_velocity, self.config.max_speed_m_s)


class TrackingPid(LeafSystem):
    """Eq. (24)-(27) sampled at `config.rate_hz`.

    Inputs: `target_offset` (2, target minus UAV position in World x-y [m]), `target_velocity`
    (2, World [m/s]), `target_acceleration` (2, World [m/s^2]), `height` (1, UAV above the target
    [m]), `target_valid` (1, over 0.5 when the target is seen; NaN is not), `source` (1, optional: a label of the
    seam the offset comes from; a sample whose label differs from the last one's restarts the PID).
    Outputs: `velocity_command` (2, World x-y [m/s]): Eq. (27), v_ugv + v_ctrl, with v_ctrl held
    between samples and v_ugv the latest target velocity (`latest_feed_forward`) or the sampled one;
    while the target is not seen it is the target velocity alone and the PID restarts.
    `acceleration_command` (2, World x-y [m/s^2]): the target's acceleration while it is seen and
    `acceleration_feed_forward` is on, else zero.
    """

    def __init__(self, config: TrackingPidConfig):
        super().__init__()
        config.validate()
        self._config = config
        self._offset = self.DeclareVectorInputPort("target_offset", 2)
        self._velocity = self.DeclareVectorInputPort("target_velocity", 2)
        self._acceleration = self.DeclareVectorInputPort("target_acceleration", 2)
        self._height = self.DeclareVectorInputPort("height", 1)
        self._valid = self.DeclareVectorInputPort("target_valid", 1)
        self._source = self.DeclareVectorInputPort("source", 1)
        self._memory = self.DeclareDiscreteState(initial_memory())
        self._last_source = self.DeclareDiscreteState(1)  # the label of the last sample's offset
        # [v_ctrl (2), v_ugv at the sample (2)]
        self._sample = self.DeclareDiscreteState(4)
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.rate_hz, 0.0, self._update)
        self.DeclareVectorOutputPort("velocity_command", 2, self._calc_velocity)
        self.DeclareVectorOutputPort("acceleration_command", 2, self._calc_acceleration)

    def _seen(self, context) -> bool:
        """Whether target_valid is set (systems.flags.is_set)."""
        return is_set(self._valid.Eval(context)[0])

    def _update(self, context, discrete_state):
        memory = context.get_discrete_state(self._memory).get_value()
        seen = self._seen(context)
        source = self._source.Eval(context)[0] if self._source.HasValue(context) else 0.0
        if source != context.get_discrete_state(self._last_source).get_value()[0]:
            memory = initial_memory()  # another seam's offset: no derivative of the jump between them
        discrete_state.set_value(self._last_source, [source])
        target_velocity = self._velocity.Eval(context)
        if seen:
            v_ctrl, memory = pid_step(memory, self._offset.Eval(context),
                                      self._height.Eval(context)[0], self._config, target_velocity)
        else:
            v_ctrl, memory = np.zeros(2), initial_memory()
        discrete_state.set_value(self._memory, memory)
        discrete_state.set_value(self._sample, np.r_[v_ctrl, target_velocity])

    def _calc_velocity(self, context, output):
        sample = context.get_discrete_state(self._sample).get_value()
        target_velocity = self._velocity.Eval(context) if self._config.latest_feed_forward else sample[2:4]
        v_ctrl = sample[0:2] if self._seen(context) else np.zeros(2)  # unseen: the target's velocity alone
        output.SetFromVector(feed_forward(v_ctrl, target_velocity, self._config.max_speed_m_s))

    def _calc_acceleration(self, context, output):
        if self._config.acceleration_feed_forward and self._seen(context):
            output.SetFromVector(self._acceleration.Eval(context))
        else:
            output.SetFromVector(np.zeros(2))
