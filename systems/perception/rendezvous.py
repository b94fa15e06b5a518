"""Rendezvous (issue 10): the vehicle's own navigation, broadcast over a radio link, brings the UAV to
it before the camera has it, as Borowczyk et al. (2017) fly to a car whose GPS/IMU state reaches the
UAV by radio. A coarse seam beside the vision one: the supervisor follows it at IH, never descends on
it, and hands over to the vision estimate once that is valid (systems/control/landing.py).

The broadcast: every 1 / rate_hz the pad's position and velocity in W as the vehicle's consumer-grade
GNSS/INS gives them (the true ones plus the second-order Gauss-Markov error of
systems/sensors/navigation.py: position_std_m over position_time_constant_s, the velocity error its
rate), received `latency_periods` messages later. Between messages the UAV dead-reckons the last one
(position plus velocity times its age); a message older than `max_age_s` is no longer valid.
Frames: World W (z up); m, s.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.flags import is_set
from systems.noise import sample_index, sample_rng
from systems.perception.seam import P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID, seam_vector
from systems.sensors.navigation import SecondOrderGaussMarkov
from systems.stepped import TIME_TOLERANCE_S
from systems.vehicles.quadrotor import P_WB, STATE_SIZE

SOURCES = ("none", "broadcast")
MESSAGE_SIZE = 7  # [p_WP (3), v_WP (3), time it describes (s)]; time NaN before the first


@dataclass
class RendezvousConfig:
    """`source`: none, or broadcast (module docstring). The GNSS grade is seed 000's reference [21]'s
    consumer one, as `navigation`'s; the link's rate and latency are ours (a telemetry radio at 10 Hz)."""

    source: str = "none"
    rate_hz: float = 10.0
    latency_periods: int = 1
    position_std_m: float = 2.0
    position_time_constant_s: float = 60.0
    max_age_s: float = 1.0
    # The search about the broadcast where vision is lost (systems/perception/rendezvous_search.py); ours.
    search_spacing_m: float = 0.0  # between the spiral's turns; 0: no search
    search_radius_m: float = 8.0
    search_speed_m_s: float = 2.0
    search_after_s: float = 2.0  # vision invalid this long before the search begins

    def validate(self, prefix: str = "rendezvous") -> None:
        require(self.source in SOURCES, f"{prefix}.source '{self.source}' is not one of {', '.join(SOURCES)}")
        for name in ("rate_hz", "position_time_constant_s", "max_age_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_non_negative(self.position_std_m, f"{prefix}.position_std_m")
        require_non_negative(self.search_spacing_m, f"{prefix}.search_spacing_m")
        for name in ("search_radius_m", "search_speed_m_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_non_negative(self.search_after_s, f"{prefix}.search_after_s")
        require(self.search_spacing_m <= self.search_radius_m,
                f"{prefix}.search_spacing_m must not exceed {prefix}.search_radius_m")
        require(self.latency_periods >= 0, f"{prefix}.latency_periods must not be negative")
        # A message arrives latency_periods / rate_hz old and is held until the next replaces it a period later.
        held_s = (self.latency_periods + 1) / self.rate_hz
        require(self.max_age_s >= held_s,
                f"{prefix}.max_age_s ({self.max_age_s:g} s) must be at least the oldest a held message gets, "
                f"({prefix}.latency_periods + 1) / rate_hz ({held_s:g} s): the broadcast would turn invalid every "
                f"period")


class VehicleBroadcast(LeafSystem):
    """Inputs `true_relative_state` (the truth's seam) and `quadrotor_state` (17, the truth): the pad's
    true position and velocity in W. Input `X_WB` (RigidTransform): the UAV's own navigation. Output
    `relative_state` (the seam's layout) from the newest received message, dead-reckoned to now; valid
    while it is at most max_age_s old, within TIME_TOLERANCE_S (at a send time, before its update, the held
    message is (latency_periods + 1) / rate_hz old up to the times' round-off). Discrete state: the GNSS
    error (3 axes x [e, e'], units of position_std_m) and the messages in flight (latency_periods + 1 of
    MESSAGE_SIZE, newest last)."""

    def __init__(self, config: RendezvousConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed, self._period = config, seed, 1.0 / config.rate_hz
        self._error_model = SecondOrderGaussMarkov(config.position_time_constant_s, self._period)
        error = self._error_model.initial(sample_rng(seed, "rendezvous", 0).standard_normal(6))
        empty = np.tile(np.r_[np.zeros(6), np.nan], config.latency_periods + 1)
        self._error = self.DeclareDiscreteState(error)
        self._messages = self.DeclareDiscreteState(empty)
        self._relative = self.DeclareVectorInputPort("true_relative_state", RELATIVE_STATE_SIZE)
        self._quad = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._send)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _send(self, context, discrete_state):
        """A message of the truth now plus the GNSS error; the in-flight queue moves on by one."""
        c = self._config
        error = context.get_discrete_state(self._error).get_value().reshape(3, 2)
        relative, quad = self._relative.Eval(context), self._quad.Eval(context)
        p_WP = quad[P_WB] + relative[P_BP_W]
        meters = error * c.position_std_m  # [e, e'] per axis: m and m/s
        message = np.r_[p_WP + meters[:, 0], relative[V_WP] + meters[:, 1], context.get_time()]
        queue = context.get_discrete_state(self._messages).get_value()
        discrete_state.set_value(self._messages, np.r_[queue[MESSAGE_SIZE:], message])
        k = sample_index(context.get_time(), self._period)
        noise = sample_rng(self._seed, "rendezvous", k + 1).standard_normal(6)
        discrete_state.set_value(self._error, self._error_model.step(error, noise))

    def _calc(self, context, output):
        received = context.get_discrete_state(self._messages).get_value()[:MESSAGE_SIZE]
        age = context.get_time() - received[6]
        valid = bool(np.isfinite(age) and age <= self._config.max_age_s + TIME_TOLERANCE_S)
        p_WP = received[:3] + (received[3:6] * age if valid else 0.0)
        output.SetFromVector(seam_vector(self._X_WB.Eval(context), p_WP, received[3:6], np.zeros(3), valid))


class SeamSelect(LeafSystem):
    """The vision seam where it is valid, else the rendezvous seam. Inputs `vision` and `rendezvous`
    (the seam's layout). Outputs `relative_state` (the chosen one; valid when either is),
    `vision_valid` (1) and `rendezvous_valid` (1)."""

    def __init__(self):
        super().__init__()
        self._vision = self.DeclareVectorInputPort("vision", RELATIVE_STATE_SIZE)
        self._rendezvous = self.DeclareVectorInputPort("rendezvous", RELATIVE_STATE_SIZE)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)
        self.DeclareVectorOutputPort("vision_valid", 1, lambda c, o: o.SetFromVector([self._vision.Eval(c)[VALID]]))
        self.DeclareVectorOutputPort("rendezvous_valid", 1,
                                     lambda c, o: o.SetFromVector([self._rendezvous.Eval(c)[VALID]]))

    def _calc(self, context, output):
        vision = self._vision.Eval(context)
        output.SetFromVector(vision if is_set(vision[VALID]) else self._rendezvous.Eval(context))

