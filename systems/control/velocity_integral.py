"""Integral action on the horizontal velocity error (ours; seed 003's loop has none): a steady force
such as the rotor drag in a wind leaves the flight controller's proportional velocity loop
(K_v, systems/control/flight_controller.py) a steady error a_d / K_v, which the tracking PID turns
into a position offset a_d / (K_v Kp) (5 m/s of air on seed 002's airframe with RotorS's rotor
drag: 0.64 m/s^2, 0.21 m below 4 m). Integrating the error and adding K_i times it to the command's
acceleration feed-forward removes it:

    a_ff,xy <- a_ff,xy + K_i I,    I_{k+1} = I_k + T (v_des - v_WB)_xy,    |K_i I| <= a_max,

sampled at the flight controller's rate T. K_i = K_v^2 / 4 makes the velocity loop
s^2 + K_v s + K_i critically damped.
"""

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.control.flight_controller import COMMAND_SIZE, FlightControllerConfig
from systems.vehicles.quadrotor import STATE_SIZE, V_WB


def integral_step(integral: np.ndarray, v_desired_xy: np.ndarray, v_xy: np.ndarray, period_s: float, gain: float,
                  max_accel_m_s2: float) -> np.ndarray:
    """The integral (2, m) one period later, clamped so that gain * |integral| <= max_accel_m_s2."""
    integral = integral + period_s * (np.asarray(v_desired_xy) - np.asarray(v_xy))
    norm = np.linalg.norm(integral) * gain
    return integral * (max_accel_m_s2 / norm) if norm > max_accel_m_s2 else integral


class VelocityIntegral(LeafSystem):
    """Between the supervisor and the flight controller: input `command` (COMMAND_SIZE, see
    flight_controller.flight_command) and `state` (17, the quadrotor's), output `command` with K_i I
    added to the acceleration feed-forward's x and y (m/s^2, in W); I is stepped at the
    controller's rate from zero."""

    def __init__(self, config: FlightControllerConfig):
        super().__init__()
        self._gain, self._max = config.velocity_integral_gain_xy, config.max_integral_accel_m_s2
        self._period = 1.0 / config.rate_hz
        self._command = self.DeclareVectorInputPort("command", COMMAND_SIZE)
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._integral = self.DeclareDiscreteState(2)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._step)
        self.DeclareVectorOutputPort("command", COMMAND_SIZE, self._calc)

    def _step(self, context, discrete_state):
        command, state = self._command.Eval(context), self._state.Eval(context)
        discrete_state.set_value(integral_step(context.get_discrete_state_vector().value(), command[0:2],
                                               state[V_WB][0:2], self._period, self._gain, self._max))

    def _calc(self, context, output):
        command = self._command.Eval(context).copy()
        command[4:6] += self._gain * context.get_discrete_state_vector().value()
        output.SetFromVector(command)
