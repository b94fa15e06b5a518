"""Cascaded flight controller: desired World velocity, yaw and acceleration feed-forward -> rotor
speed commands.

Three loops, tuned for the seed 002 Table 1 airframe (systems/vehicles/quadrotor.py):
1. velocity: a_des = a_ff + K_v (v_des - v_WB), limited in climb/sink and in tilt, plus gravity,
   gives the desired thrust vector; its direction and the desired yaw give R_WB_des, its projection
   on the current body z axis gives the collective thrust. a_ff is the acceleration the velocity
   setpoint itself has (a curving target's): without it the loop lags the setpoint by a_ff / K_v;
2. attitude on SO(3) (Lee, Leok & McClamroch 2010): T_B = J (-k_R e_R - k_w w_B) + w_B x J w_B;
3. rotors: Eq. (8) inverted gives the rotor thrusts and speeds w_des, and the command
   w_cmd = (w + (tau_m / tau_a) (w_des - w)) / k_m makes the first-order motor lag of Eq. (7)
   reach w_des with the time constant tau_a instead of tau_m (rotor speeds are in the state).

The attitude gains come from pole placement on J tau_a s^3 + J s^2 + J k_w s + J k_R (one axis
about hover, with the compensated rotor lag tau_a): a complex pair of natural frequency w_n and
damping zeta, and a real pole at -(1/tau_a - 2 zeta w_n).

One law, two backends. `FlightLaw` is the law, written once in scalar arithmetic that works on
floats and on pydrake.symbolic Expressions alike, with its constants (gains, the inverse mixer)
computed once:
- `FlightController` (Python): a LeafSystem calling `FlightLaw` on floats;
- `SymbolicFlightController` (C++): the same `FlightLaw` stages traced into Expressions, one small
  SymbolicVectorSystem per stage, with no Python in the loop. tests check that the two give the
  same commands.
Both either sample and hold at `rate_hz` (`held`, for a continuous quadrotor) or compute the law
when pulled (for a quadrotor discretised per controller period, which holds its input itself).
"""

from dataclasses import dataclass

import numpy as np
import pydrake.math as dmath
from pydrake.symbolic import MakeVectorVariable
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, Multiplexer, SymbolicVectorSystem, ZeroOrderHold

from systems.config import require, require_non_negative, require_positive
from systems.vehicles.quadrotor import (
    P_WB, Q_WB, ROTOR_SPEEDS, STATE_SIZE, V_WB, W_WB_B, QuadrotorParams, mixer_matrix, rotation_from_quaternion,
)

# The fastest flight controller accepted [Hz]: above any autopilot's inner loop (PX4's rate loop runs at its gyro's
# rate, at most 8 kHz); each period is a simulation step (of both vehicles too), 50 times the default's at 10 kHz.
MAX_RATE_HZ = 10_000.0

# The `command` input: [v_WB_desired (3, m/s, in W), yaw_desired (rad), a_WB_feed_forward (3, m/s^2, in W)].
COMMAND_SIZE = 7


def flight_command(v_WB_desired, yaw: float = 0.0, a_WB_feed_forward=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Packs a `command` vector."""
    return np.array([*v_WB_desired, yaw, *a_WB_feed_forward], dtype=float)


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
    # Integral action on the horizontal velocity error (systems/control/velocity_integral.py): K_i
    # [1/s^2], 0 for none (the default; K_v^2 / 4 = 1.0 is critically damped), and its limit.
    velocity_integral_gain_xy: float = 0.0
    max_integral_accel_m_s2: float = 3.0

    def validate(self, prefix: str = "flight_controller", quad: QuadrotorParams | None = None) -> None:
        """Raises ConfigError naming the first field out of range; with `quad` (the `quadrotor` section) also
        the vertical acceleration limit against its gravity."""
        for name in ("rate_hz", "velocity_gain_xy", "velocity_gain_z", "max_vertical_accel_m_s2",
                     "attitude_frequency_rad_s", "yaw_frequency_rad_s", "attitude_damping",
                     "rotor_time_constant_s", "max_integral_accel_m_s2"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_non_negative(self.velocity_integral_gain_xy, f"{prefix}.velocity_integral_gain_xy")
        # The rotor stage asks each rotor to close its gap to w_des with the time constant tau_a; held over a period
        # T the rotor (lag tau_m) closes (tau_m / tau_a)(1 - exp(-T / tau_m)) <= T / tau_a of it, so T <= tau_a never
        # overshoots w_des. Longer periods do every period (seed 002's tau_m = 0.1 s: from 35 Hz; the gv flight
        # crashed at 10 Hz). T is also the period the vehicles are integrated over, their inputs held.
        require(self.rate_hz * self.rotor_time_constant_s >= 1.0,
                f"{prefix}.rate_hz ({self.rate_hz:g} Hz) must be at least 1 / {prefix}.rotor_time_constant_s "
                f"({1.0 / self.rotor_time_constant_s:g} Hz): held longer than tau_a the rotor commands overshoot")
        require(self.rate_hz <= MAX_RATE_HZ,
                f"{prefix}.rate_hz ({self.rate_hz:g} Hz) must be at most {MAX_RATE_HZ:g} Hz, beyond any autopilot's")
        require(0 < self.max_tilt_deg < 90, f"{prefix}.max_tilt_deg must be in (0, 90)")
        if quad is not None:  # a full sink commands g - a_max of thrust
            require(self.max_vertical_accel_m_s2 < quad.gravity_m_s2,
                    f"{prefix}.max_vertical_accel_m_s2 ({self.max_vertical_accel_m_s2:g} m/s^2) must be below "
                    f"quadrotor.gravity_m_s2 ({quad.gravity_m_s2:g} m/s^2)")
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


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _normalized(v):
    n = dmath.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return [v[0] / n, v[1] / n, v[2] / n]


def _as_list(v) -> list:
    return v.tolist() if isinstance(v, np.ndarray) else list(v)


class FlightLaw:
    """The control law of the module docstring with its constants computed once.

    Each stage takes and returns plain lists (rotations as 9 entries, row-major) of floats or of
    pydrake.symbolic Expressions: the Python backend calls it on floats, the C++ backend traces
    each stage into a SymbolicVectorSystem."""

    def __init__(self, quad: QuadrotorParams, config: FlightControllerConfig):
        quad.validate()
        config.validate(quad=quad)
        self.quad, self.config = quad, config
        k_R, k_w = config.attitude_gains()
        J = quad.inertia_diagonal
        self._J = J.tolist()
        self._J_k_R, self._J_k_w = (J * k_R).tolist(), (J * k_w).tolist()
        self._mixer_inverse = np.linalg.inv(mixer_matrix(quad)).tolist()
        self._lag_ratio = quad.motor_time_constant_s / config.rotor_time_constant_s
        self._tan_tilt = float(np.tan(np.radians(config.max_tilt_deg)))

    def rotation(self, q_WB) -> list:
        """R_WB (9, row-major) from the quaternion of the state (rotation_from_quaternion)."""
        return rotation_from_quaternion(_as_list(q_WB)).ravel().tolist()

    def thrust(self, v_WB, v_WB_desired, a_WB_feed_forward) -> list:
        """Velocity loop: the thrust vector f_W [N] that gives the limited desired acceleration."""
        quad, config = self.quad, self.config
        g, a_max, a_ff = quad.gravity_m_s2, config.max_vertical_accel_m_s2, a_WB_feed_forward
        a_z = dmath.min(dmath.max(a_ff[2] + config.velocity_gain_z * (v_WB_desired[2] - v_WB[2]), -a_max), a_max)
        a_x = a_ff[0] + config.velocity_gain_xy * (v_WB_desired[0] - v_WB[0])
        a_y = a_ff[1] + config.velocity_gain_xy * (v_WB_desired[1] - v_WB[1])
        a_xy_max = (g + a_z) * self._tan_tilt
        scale = quad.mass_kg * a_xy_max / dmath.max(dmath.sqrt(a_x * a_x + a_y * a_y), a_xy_max)
        return [scale * a_x, scale * a_y, quad.mass_kg * (g + a_z)]

    @staticmethod
    def thrust_direction(f_W) -> list:
        """z_B desired: along the thrust."""
        return _normalized(f_W)

    @staticmethod
    def lateral_axis(z_desired, yaw) -> list:
        """y_B desired: normal to z_desired and to the heading `yaw` (rad)."""
        return _normalized(_cross(z_desired, [dmath.cos(yaw), dmath.sin(yaw), 0.0]))

    @staticmethod
    def desired_rotation(y_desired, z_desired) -> list:
        """R_WB_des (9, row-major): columns x = y x z, y, z."""
        x = _cross(y_desired, z_desired)
        return [x[0], y_desired[0], z_desired[0], x[1], y_desired[1], z_desired[1],
                x[2], y_desired[2], z_desired[2]]

    def torque(self, R, R_desired, w_B) -> list:
        """Attitude loop: T_B = J (-k_R e_R - k_w w_B) + w_B x J w_B,
        e_R = vee(R_des^T R - R^T R_des) / 2."""
        def m(i, j):  # (R_des^T R)_ij
            return R_desired[i] * R[j] + R_desired[3 + i] * R[3 + j] + R_desired[6 + i] * R[6 + j]

        e_R = [0.5 * (m(2, 1) - m(1, 2)), 0.5 * (m(0, 2) - m(2, 0)), 0.5 * (m(1, 0) - m(0, 1))]
        J, w = self._J, _as_list(w_B)
        gyroscopic = _cross(w, [J[0] * w[0], J[1] * w[1], J[2] * w[2]])
        return [-self._J_k_R[i] * e_R[i] - self._J_k_w[i] * w[i] + gyroscopic[i] for i in range(3)]

    def rotor_commands(self, f_W, R, torque_B, rotor_speeds) -> list:
        """Eq. (8) inverted for the collective thrust f_W . z_B and the torque, rotor speeds
        w_des, and the commands that make the motor lag reach them with tau_a."""
        quad = self.quad
        wrench = [f_W[0] * R[2] + f_W[1] * R[5] + f_W[2] * R[8], *torque_B]
        out = []
        for row, w in zip(self._mixer_inverse, _as_list(rotor_speeds)):
            f = row[0] * wrench[0] + row[1] * wrench[1] + row[2] * wrench[2] + row[3] * wrench[3]
            w_des = dmath.sqrt(dmath.max(f, 0.0) / quad.thrust_coefficient)
            out.append((w + self._lag_ratio * (w_des - w)) / quad.motor_gain)
        return out

    def __call__(self, state, command) -> np.ndarray:
        """Quadrotor `state` (17) and `command` (COMMAND_SIZE) -> rotor speed commands (4)."""
        x, c = _as_list(state), _as_list(command)
        R = self.rotation(x[Q_WB])
        f_W = self.thrust(x[V_WB], c[0:3], c[4:7])
        z = self.thrust_direction(f_W)
        R_desired = self.desired_rotation(self.lateral_axis(z, c[3]), z)
        torque_B = self.torque(R, R_desired, x[W_WB_B])
        return np.array(self.rotor_commands(f_W, R, torque_B, x[ROTOR_SPEEDS]))


def rotor_speed_commands(state, command, quad: QuadrotorParams, config: FlightControllerConfig):
    """The control law once: quadrotor `state` (17) and `command` (see COMMAND_SIZE) -> rotor speed
    commands (4, rad/s). Works on floats and on pydrake.symbolic Expressions. Systems
    keep a FlightLaw instead (its constants computed once)."""
    return FlightLaw(quad, config)(state, command)


def hover_command(quad: QuadrotorParams) -> np.ndarray:
    """The rotor speed commands that hold hover (the controllers' output before their first sample)."""
    return np.full(4, quad.hover_rotor_speed() / quad.motor_gain)


class FlightController(LeafSystem):
    """The Python backend: velocity and yaw controller for the seed 002 quadrotor.

    Inputs `state` (17, the Quadrotor `state` output) and `command` (7: desired velocity of B in
    W [m/s], desired yaw [rad], acceleration feed-forward in W [m/s^2]; see flight_command).
    Output `rotor_speed_commands` (4, rad/s).
    `held`: sampled at `config.rate_hz` and held, starting at hover (for a continuous quadrotor).
    Not held: the law at the current inputs, computed when pulled (for a quadrotor discretised per
    controller period, which samples and holds it itself).
    """

    def __init__(self, quad: QuadrotorParams, config: FlightControllerConfig, held: bool = True):
        super().__init__()
        self.law = FlightLaw(quad, config)
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._command = self.DeclareVectorInputPort("command", COMMAND_SIZE)
        if held:
            held_state = self.DeclareDiscreteState(hover_command(quad))
            self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.rate_hz, 0.0, self._update)
            self.DeclareStateOutputPort("rotor_speed_commands", held_state)
        else:
            self.DeclareVectorOutputPort("rotor_speed_commands", 4, self._calc)

    def _update(self, context, discrete_state):
        discrete_state.set_value(self.law(self._state.Eval(context), self._command.Eval(context)))

    def _calc(self, context, output):
        output.SetFromVector(self.law(self._state.Eval(context), self._command.Eval(context)))

    def initialize(self, root_context) -> None:
        """Nothing to do (the held command starts at hover); for symmetry with SymbolicFlightController."""


def _stage(inputs, outputs, dummy_state: bool) -> SymbolicVectorSystem:
    """A stateless SymbolicVectorSystem y = f(u). Drake 1.58 aborts in DoCalcTimeDerivatives for a
    SymbolicVectorSystem without continuous state inside a diagram with continuous state, so in such
    a diagram (`dummy_state`) it carries one constant dummy state (derivative 0)."""
    if not dummy_state:
        return SymbolicVectorSystem(input=inputs, output=outputs)
    unused = MakeVectorVariable(1, "unused")
    return SymbolicVectorSystem(state=unused, dynamics=[0.0 * unused[0]], input=inputs, output=outputs)


class _SymbolicChain:
    """Wires stateless SymbolicVectorSystem stages into a DiagramBuilder by signal name: each stage
    takes named signals (vector output ports), sees each as a vector of symbolic variables, and
    adds its output as a new signal. Small stages with few inputs keep Drake's tree-walking
    evaluation (which repeats shared subexpressions) and its variable look-ups cheap."""

    def __init__(self, builder: DiagramBuilder, dummy_state: bool):
        self._builder, self._dummy_state = builder, dummy_state
        self.signals = {}  # name -> OutputPort

    def split(self, port, names_sizes) -> None:
        """Adds the pieces of a vector port as signals."""
        demux = self._builder.AddNamedSystem(f"split_{'_'.join(n for n, _ in names_sizes)}",
                                             Demultiplexer([size for _, size in names_sizes]))
        self._builder.Connect(port, demux.get_input_port())
        for i, (name, _) in enumerate(names_sizes):
            self.signals[name] = demux.get_output_port(i)

    def stage(self, name: str, inputs: list[str], function) -> SymbolicVectorSystem:
        """Adds signal `name` = function(*input signals as variable vectors)."""
        ports = [self.signals[n] for n in inputs]
        variables = [MakeVectorVariable(p.size(), n) for n, p in zip(inputs, ports)]
        with np.errstate(invalid="ignore"):  # numpy's float-flag check on arrays of Expressions
            output = np.asarray(function(*variables)).ravel()
        system = self._builder.AddNamedSystem(name, _stage(np.concatenate(variables), output, self._dummy_state))
        if len(ports) == 1:
            self._builder.Connect(ports[0], system.get_input_port())
        else:
            mux = self._builder.AddNamedSystem(f"{name}_inputs", Multiplexer([p.size() for p in ports]))
            for i, port in enumerate(ports):
                self._builder.Connect(port, mux.get_input_port(i))
            self._builder.Connect(mux.get_output_port(), system.get_input_port())
        self.signals[name] = system.get_output_port()
        return system


class SymbolicFlightController(Diagram):
    """The C++ backend: `FlightLaw` evaluated by SymbolicVectorSystems, with FlightController's
    ports (inputs `state` (17) and `command` (7), output `rotor_speed_commands` (4)). One
    SymbolicVectorSystem per FlightLaw stage: traced whole, the law is an expression of 95,000
    characters per rotor, far slower to evaluate.

    `held` (for a continuous quadrotor): the output is sampled and held at `config.rate_hz` from
    the hover command on, exactly as FlightController does (call `initialize`). Not held: the law at
    the current inputs, evaluated only when pulled. A second output `law` is always the unheld law.
    """

    def __init__(self, quad: QuadrotorParams, config: FlightControllerConfig, held: bool = True):
        super().__init__()
        self.law = law = FlightLaw(quad, config)
        self._initial = hover_command(quad)
        builder = DiagramBuilder()
        chain = _SymbolicChain(builder, dummy_state=held)
        state = builder.AddNamedSystem("state", Demultiplexer([STATE_SIZE]))  # named input ports
        command = builder.AddNamedSystem("command", Demultiplexer([COMMAND_SIZE]))
        builder.ExportInput(state.get_input_port(), "state")
        builder.ExportInput(command.get_input_port(), "command")
        assert (P_WB.stop, Q_WB.stop, V_WB.stop, W_WB_B.stop, ROTOR_SPEEDS.stop) == (3, 7, 10, 13, 17)
        chain.split(state.get_output_port(0), [("p_WB", 3), ("q_WB", 4), ("v_WB", 3), ("w_WB_B", 3),
                                              ("rotor_speeds", 4)])
        chain.split(command.get_output_port(0), [("v_WB_desired", 3), ("yaw_desired", 1), ("a_WB_feed_forward", 3)])
        # The stages of FlightLaw.__call__, in its order.
        chain.stage("R_WB", ["q_WB"], law.rotation)
        chain.stage("f_W", ["v_WB", "v_WB_desired", "a_WB_feed_forward"], law.thrust)
        chain.stage("z_desired", ["f_W"], law.thrust_direction)
        chain.stage("y_desired", ["z_desired", "yaw_desired"], lambda z, yaw: law.lateral_axis(z, yaw[0]))
        chain.stage("R_WB_desired", ["y_desired", "z_desired"], law.desired_rotation)
        chain.stage("torque_B", ["R_WB", "R_WB_desired", "w_WB_B"], law.torque)
        output = chain.stage("law", ["f_W", "R_WB", "torque_B", "rotor_speeds"], law.rotor_commands).get_output_port()
        self.hold = None
        if held:
            self.hold = builder.AddNamedSystem("hold", ZeroOrderHold(1.0 / config.rate_hz, 4))
            builder.Connect(output, self.hold.get_input_port())
            builder.ExportOutput(self.hold.get_output_port(), "rotor_speed_commands")
        else:
            builder.ExportOutput(output, "rotor_speed_commands")
        builder.ExportOutput(output, "law")
        builder.BuildInto(self)
        self.set_name("flight_controller")

    def initialize(self, root_context) -> None:
        """Holds the hover command until the first sample, as FlightController does."""
        if self.hold is not None:
            self.hold.SetVectorState(self.hold.GetMyMutableContextFromRoot(root_context), self._initial)


BACKENDS = ("symbolic", "python")


def make_flight_controller(quad: QuadrotorParams, config: FlightControllerConfig, backend: str = "symbolic",
                           held: bool = True):
    """SymbolicFlightController ("symbolic", C++) or FlightController ("python"): the same law and ports."""
    require(backend in BACKENDS, f"flight controller backend '{backend}' is not one of {', '.join(BACKENDS)}")
    cls = SymbolicFlightController if backend == "symbolic" else FlightController
    return cls(quad, config, held=held)
