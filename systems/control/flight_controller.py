"""Cascaded flight controller: desired World velocity and yaw -> rotor speed commands.

Three loops, tuned for the seed 002 Table 1 airframe (systems/vehicles/quadrotor.py):
1. velocity: a_des = K_v (v_des - v_WB), limited in climb/sink and in tilt, plus gravity, gives
   the desired thrust vector; its direction and the desired yaw give R_WB_des, its projection on
   the current body z axis gives the collective thrust;
2. attitude on SO(3) (Lee, Leok & McClamroch 2010): T_B = J (-k_R e_R - k_w w_B) + w_B x J w_B;
3. rotors: Eq. (8) inverted gives the rotor thrusts and speeds w_des, and the command
   w_cmd = (w + (tau_m / tau_a) (w_des - w)) / k_m makes the first-order motor lag of Eq. (7)
   reach w_des with the time constant tau_a instead of tau_m (rotor speeds are in the state).

The attitude gains come from pole placement on J tau_a s^3 + J s^2 + J k_w s + J k_R (one axis
about hover, with the compensated rotor lag tau_a): a complex pair of natural frequency w_n and
damping zeta, and a real pole at -(1/tau_a - 2 zeta w_n).

`FlightController` samples the law at `rate_hz` in Python, about 0.1 ms a sample (2 % of real
time at 200 Hz). A discrete SymbolicVectorSystem would keep it in C++, and the law is written to
accept pydrake.symbolic Expressions for that, but Drake 1.58 aborts in
SymbolicVectorSystem::DoCalcTimeDerivatives when a SymbolicVectorSystem without continuous state
sits in a diagram that has continuous state.
"""

from dataclasses import dataclass

import numpy as np
import pydrake.math as dmath
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.vehicles.quadrotor import (
    Q_WB, ROTOR_SPEEDS, STATE_SIZE, V_WB, W_WB_B, QuadrotorParams, mixer_matrix,
    rotation_from_quaternion,
)

COMMAND_SIZE = 4  # [v_WB_desired (3, m/s, in W), yaw_desired (rad)]


@dataclass
class FlightControllerConfig:
    """Gains and limits; none come from the seeds (seed 002 gives the airframe, not its autopilot;
    seed 003 commands velocities to a DJI autopilot)."""

    rate_hz: float = 200.0  # a typical autopilot inner-loop rate
    velocity_gain_xy: float = 2.0  # K_v horizontal [1/s], a fifth of the attitude bandwidth
    velocity_gain_z: float = 3.0  # K_v vertical [1/s]
    max_vertical_accel_m_s2: float = 4.0  # climb and sink acceleration limit, below g
    max_tilt_deg: float = 30.0  # tilt limit of the desired thrust direction
    attitude_frequency_rad_s: float = 10.0  # w_n of roll and pitch
    yaw_frequency_rad_s: float = 2.0  # w_n of yaw; drag torque k_dt = 2.4 cm gives little authority
    attitude_damping: float = 0.8  # zeta of roll, pitch and yaw
    rotor_time_constant_s: float = 0.025  # tau_a, the compensated motor lag

    def validate(self, prefix: str = "flight_controller") -> None:
        for name in ("rate_hz", "velocity_gain_xy", "velocity_gain_z", "max_vertical_accel_m_s2",
                     "attitude_frequency_rad_s", "yaw_frequency_rad_s", "attitude_damping",
                     "rotor_time_constant_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(0 < self.max_tilt_deg < 90, f"{prefix}.max_tilt_deg must be in (0, 90)")
        for name in ("attitude_frequency_rad_s", "yaw_frequency_rad_s"):
            require(2 * self.attitude_damping * getattr(self, name) < 1 / self.rotor_time_constant_s,
                    f"{prefix}.{name} is too fast for {prefix}.rotor_time_constant_s "
                    "(needs 2 zeta w_n < 1 / tau_a)")

    def attitude_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """(k_R, k_w) per body axis [1/s^2, 1/s] from the pole placement in the module docstring."""
        tau = self.rotor_time_constant_s
        zeta = self.attitude_damping
        w_n = np.array([self.attitude_frequency_rad_s] * 2 + [self.yaw_frequency_rad_s])
        real_pole = 1.0 / tau - 2.0 * zeta * w_n
        return tau * real_pole * w_n**2, tau * (w_n**2 + 2.0 * zeta * w_n * real_pole)


def vee(M):
    """[M21, M02, M10] of a skew-symmetric 3x3 matrix."""
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def normalized(v):
    return v / dmath.sqrt(v @ v)


def desired_thrust(v_WB, v_WB_desired, quad: QuadrotorParams, config: FlightControllerConfig):
    """Velocity loop: the thrust vector f_W [N] that gives the limited desired acceleration."""
    k_xy, k_z = config.velocity_gain_xy, config.velocity_gain_z
    a_max = config.max_vertical_accel_m_s2
    a_z = dmath.min(dmath.max(k_z * (v_WB_desired[2] - v_WB[2]), -a_max), a_max)
    a_xy = k_xy * (v_WB_desired[:2] - v_WB[:2])
    a_xy_max = (quad.gravity_m_s2 + a_z) * np.tan(np.radians(config.max_tilt_deg))
    scale = a_xy_max / dmath.max(dmath.sqrt(a_xy @ a_xy), a_xy_max)
    return quad.mass_kg * np.array([scale * a_xy[0], scale * a_xy[1], quad.gravity_m_s2 + a_z])


def desired_attitude(f_W, yaw):
    """R_WB_des: body z along the thrust f_W, body x towards heading `yaw` (rad)."""
    z = normalized(f_W)
    y = normalized(np.cross(z, np.array([dmath.cos(yaw), dmath.sin(yaw), 0.0])))
    return np.column_stack([np.cross(y, z), y, z])


def rotor_speed_commands(state, command, quad: QuadrotorParams, config: FlightControllerConfig):
    """The control law: quadrotor `state` (17) and `command` [v_WB_desired (3), yaw] -> rotor
    speed commands (4, rad/s). Works on floats and on pydrake.symbolic Expressions."""
    R_WB = rotation_from_quaternion(state[Q_WB])
    w_B = state[W_WB_B]
    rotor_speeds = state[ROTOR_SPEEDS]

    f_W = desired_thrust(state[V_WB], command[:3], quad, config)
    R_des = desired_attitude(f_W, command[3])
    e_R = 0.5 * vee(R_des.T @ R_WB - R_WB.T @ R_des)
    k_R, k_w = config.attitude_gains()
    J = quad.inertia_diagonal
    torque_B = J * (-k_R * e_R - k_w * w_B) + np.cross(w_B, J * w_B)

    thrusts = np.linalg.inv(mixer_matrix(quad)) @ np.concatenate(
        [[f_W @ R_WB[:, 2]], torque_B])
    w_des = np.array([dmath.sqrt(dmath.max(f, 0.0) / quad.thrust_coefficient) for f in thrusts])
    lag_ratio = quad.motor_time_constant_s / config.rotor_time_constant_s
    return (rotor_speeds + lag_ratio * (w_des - rotor_speeds)) / quad.motor_gain


class FlightController(LeafSystem):
    """Velocity and yaw controller for the seed 002 quadrotor, sampled at `config.rate_hz`.

    Inputs `state` (17, the Quadrotor `state` output) and `command` (4: desired velocity of B in
    W [m/s], desired yaw [rad]). Output `rotor_speed_commands` (4, rad/s), held between samples;
    it starts at the hover speed.
    """

    def __init__(self, quad: QuadrotorParams, config: FlightControllerConfig):
        super().__init__()
        quad.validate()
        config.validate()
        require(config.max_vertical_accel_m_s2 < quad.gravity_m_s2,
                "flight_controller.max_vertical_accel_m_s2 must be below gravity")
        self._quad, self._config = quad, config
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._command = self.DeclareVectorInputPort("command", COMMAND_SIZE)
        held = self.DeclareDiscreteState(np.full(4, quad.hover_rotor_speed() / quad.motor_gain))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.rate_hz, 0.0, self._update)
        self.DeclareStateOutputPort("rotor_speed_commands", held)

    def _update(self, context, discrete_state):
        discrete_state.set_value(rotor_speed_commands(
            self._state.Eval(context), self._command.Eval(context), self._quad, self._config))
