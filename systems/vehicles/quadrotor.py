"""Quadrotor dynamics of seed 002 (Moura & Goes), Eq. (7)-(8), as a Drake SymbolicVectorSystem.

Frames: World W is z-up; body B is x forward, y left, z up (thrust along +Bz), origin at the
centre of mass. The state vector (17) is

    [p_WB (3), q_WB (4, Drake order w, x, y, z), v_WB (3, expressed in W),
     w_WB_B (3, body angular velocity expressed in B), rotor_speeds (4, rad/s)]

and the input is the four rotor speed commands (rad/s), with the wind velocity v_wind_W (3, m/s, in W)
after them where the quadrotor is built with wind. The quaternion need not stay exactly
unit: the rotation is computed from q / |q|, and the kinematics q_dot = q (x) [0, w] / 2 scale with
|q|, so integration drift in |q| never reaches the physics.

Reading of seed 002 Table 1 against Eq. (7)-(8) (what the defaults below assume):
- Eq. (7) uses k_t (thrust) and k_m (motor gain) but Table 1 lists "k_m = 1.28e-5" and
  "k_p = 1.00", and never k_t. A motor gain of 1.28e-5 would make the rotors spin at 1e-5 of
  their command, while a thrust coefficient of 1.28e-5 N s^2/rad^2 hovers the 1.2 kg airframe at
  479 rad/s (4600 rpm) with k_dt = k_d / k_t = 2.4 cm, both typical of this size. So Table 1's
  k_m is k_t [N s^2/rad^2], its k_p is the motor gain k_m [-], and k_d is [N m s^2/rad^2].
- J = diag(0.15, 0.015, 0.03) violates the inertia triangle inequality (Jy + Jz >= Jx), so no
  rigid body has it; we take Jx = 0.015 (a dropped zero; Jx = Jy as for a symmetric X frame).
- F^g = [0 0 g] [N] is written with the wrong unit and sign for the z-up World that the paper's
  own start point r0 = [0 0 10] m implies: gravity is [0 0 -m g] N here.
- Eq. (7) adds the body thrust [0 0 F^C] to a World acceleration without rotating it, and divides
  the torque by J twice; we use R_WB [0 0 F^C] / m and J w_dot = T^C - w x (J w) (Mahony et al.,
  the paper's reference [8]), with w the body angular velocity.
- Eq. (8) as printed makes the roll torque l1 (f1 - f2 - f3 + f4) and the pitch torque
  l2 (-f1 - f2 + f3 + f4), so rotor 1 sits at (x, y) = (+l2, +l1) (front left), 2 at (+l2, -l1)
  (front right), 3 at (-l2, -l1) (back right), 4 at (-l2, +l1) (back left): l1 is the lateral
  arm and l2 the longitudinal arm, the reverse of the paper's prose. Table 1 has l1 = l2, so the
  numbers do not depend on which reading is right; we follow the matrix.
- Table 1's d = 3.5 m, tau_s and theta_max belong to the ground vehicle (ground_vehicle.py).

Aerodynamic drag (not in seed 002, whose Eq. (7) has none; off by default): the rotor drag of the
RotorS simulator (Furrer et al. 2016, its motor model), each rotor pulled back along the air-relative
velocity's component in the rotor plane in proportion to its speed,
    F_B = -k_rd (w_1 + w_2 + w_3 + w_4) [v_x, v_y, 0]_B,   v_B = R_WB^T (v_WB - v_wind_W),
k_rd `rotor_drag_coefficient` (RotorS's multirotors: 8.06428e-5 N per rad/s per m/s: 0.155 N s/m at
this airframe's hover). Applied at the centre of mass (the rotors' hub velocities from the body's
rotation and the torques about the centre of mass are left out), so air moving along the body's z
axis does not act.
"""

from dataclasses import dataclass

import numpy as np
import pydrake.math as dmath
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import Value
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.symbolic import MakeVectorVariable
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer, Multiplexer, SymbolicVectorSystem

from systems.config import require, require_non_negative, require_positive
from systems.quaternion import quaternion_rate, rotation_from_quaternion
from systems.vehicles.integration import discretise, set_vehicle_state

STATE_SIZE = 17
P_WB = slice(0, 3)
Q_WB = slice(3, 7)
V_WB = slice(7, 10)
W_WB_B = slice(10, 13)
ROTOR_SPEEDS = slice(13, 17)


@dataclass
class QuadrotorParams:
    """Airframe and motor constants of seed 002 Table 1 (see the module docstring for how the
    table's symbols map onto Eq. (7)-(8))."""

    mass_kg: float = 1.2  # m, seed 002 Table 1
    inertia_xx_kg_m2: float = 0.015  # Jx; Table 1 prints 0.15 (see the module docstring)
    inertia_yy_kg_m2: float = 0.015  # Jy, Table 1
    inertia_zz_kg_m2: float = 0.03  # Jz, Table 1
    motor_time_constant_s: float = 0.1  # tau_m, Table 1, Eq. (7)
    motor_gain: float = 1.0  # k_m [-], Eq. (7); Table 1 calls it k_p
    thrust_coefficient: float = 1.28e-5  # k_t [N s^2/rad^2], Eq. (7); Table 1 calls it k_m
    drag_torque_coefficient: float = 3.08e-7  # k_d [N m s^2/rad^2], Table 1, Eq. (7)
    arm_lateral_m: float = 0.25  # l1, Table 1; rotor |y| in Eq. (8)
    arm_longitudinal_m: float = 0.25  # l2, Table 1; rotor |x| in Eq. (8)
    # w_max: Eq. (7) names it but Table 1 gives no value; 700 rad/s gives a thrust-to-weight
    # ratio of 2.1 with the defaults above.
    max_rotor_speed_rad_s: float = 700.0
    gravity_m_s2: float = 9.81  # g; the value of Drake's QuadrotorPlant and MultibodyPlant
    # k_rd [N/((rad/s)(m/s))], the rotor drag of the module docstring: 0 is seed 002's model (no
    # drag); RotorS uses 8.06428e-5.
    rotor_drag_coefficient: float = 0.0

    def validate(self, prefix: str = "quadrotor") -> None:
        """Raises ConfigError (a ValueError) naming the first field out of range."""
        for name in (
            "mass_kg", "inertia_xx_kg_m2", "inertia_yy_kg_m2", "inertia_zz_kg_m2",
            "motor_time_constant_s", "motor_gain", "thrust_coefficient",
            "drag_torque_coefficient", "arm_lateral_m", "arm_longitudinal_m",
            "max_rotor_speed_rad_s", "gravity_m_s2",
        ):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_non_negative(self.rotor_drag_coefficient, f"{prefix}.rotor_drag_coefficient")
        Jx, Jy, Jz = self.inertia_diagonal
        require(Jx <= Jy + Jz and Jy <= Jx + Jz and Jz <= Jx + Jy,
                f"{prefix}.inertia_xx/yy/zz_kg_m2 = {Jx}, {Jy}, {Jz} violate the triangle "
                "inequality (each must be at most the sum of the other two)")
        require(self.hover_rotor_speed() < self.max_rotor_speed_rad_s,
                f"{prefix}.max_rotor_speed_rad_s = {self.max_rotor_speed_rad_s} cannot hover "
                f"(needs {self.hover_rotor_speed():.1f} rad/s)")

    @property
    def inertia_diagonal(self) -> np.ndarray:
        """[Jx, Jy, Jz] in kg m^2, about the body axes."""
        return np.array([self.inertia_xx_kg_m2, self.inertia_yy_kg_m2, self.inertia_zz_kg_m2])

    def hover_rotor_speed(self) -> float:
        """Rotor speed [rad/s] at which four rotors carry the weight: 4 k_t w^2 = m g."""
        return float(np.sqrt(self.mass_kg * self.gravity_m_s2 / (4.0 * self.thrust_coefficient)))


def mixer_matrix(params: QuadrotorParams) -> np.ndarray:
    """Seed 002 Eq. (8): maps rotor thrusts f (N) to [F^C (N), T^C_B (N m)], torque in B."""
    l1, l2 = params.arm_lateral_m, params.arm_longitudinal_m
    k_dt = params.drag_torque_coefficient / params.thrust_coefficient
    return np.array([
        [1.0, 1.0, 1.0, 1.0],
        [l1, -l1, -l1, l1],
        [-l2, -l2, l2, l2],
        [k_dt, -k_dt, k_dt, -k_dt],
    ])


def rotor_drag_W(state, R_WB, params: QuadrotorParams, v_wind_W):
    """The rotor drag force in W [N] (module docstring) on the air-relative velocity
    v_WB - v_wind_W [m/s, in W]. Works on floats and on pydrake.symbolic Expressions."""
    v_B = R_WB.T @ (state[V_WB] - np.asarray(v_wind_W))
    in_plane_B = np.array([v_B[0], v_B[1], 0.0 * v_B[2]])
    return R_WB @ in_plane_B * (-params.rotor_drag_coefficient * np.sum(state[ROTOR_SPEEDS]))


def rigid_body_accelerations(state, params: QuadrotorParams, v_wind_W=None):
    """(a_WB in W [m/s^2], alpha_WB_B in B [rad/s^2]) from the rotor speeds in `state`, with the
    rotor drag on the velocity relative to the air moving at v_wind_W [m/s, in W] (None: still air)
    where the airframe has one. Works on floats and on pydrake.symbolic Expressions."""
    w_B = state[W_WB_B]
    thrusts = params.thrust_coefficient * state[ROTOR_SPEEDS] ** 2
    wrench = mixer_matrix(params) @ thrusts
    collective, torque_B = wrench[0], wrench[1:]
    R_WB = rotation_from_quaternion(state[Q_WB])
    a_WB = R_WB[:, 2] * collective / params.mass_kg - np.array([0.0, 0.0, params.gravity_m_s2])
    if params.rotor_drag_coefficient:
        a_WB = a_WB + rotor_drag_W(state, R_WB, params, np.zeros(3) if v_wind_W is None else v_wind_W) / params.mass_kg
    J = params.inertia_diagonal
    alpha_WB_B = (torque_B - np.cross(w_B, J * w_B)) / J
    return a_WB, alpha_WB_B


def quadrotor_state_derivative(state, rotor_speed_commands, params: QuadrotorParams, v_wind_W=None):
    """Seed 002 Eq. (7)-(8) (with the corrections in the module docstring).

    state: the 17-vector described in the module docstring; rotor_speed_commands: 4 [rad/s],
    each driving its rotor towards k_m * command clipped to [0, w_max]; v_wind_W: the air's
    velocity [m/s, in W] (None: still). Returns d(state)/dt.
    Works on floats and on pydrake.symbolic Expressions."""
    targets = [
        dmath.min(dmath.max(params.motor_gain * c, 0.0), params.max_rotor_speed_rad_s)
        for c in rotor_speed_commands
    ]
    rotor_accelerations = (np.array(targets) - state[ROTOR_SPEEDS]) / params.motor_time_constant_s
    a_WB, alpha_WB_B = rigid_body_accelerations(state, params, v_wind_W)
    return np.concatenate([
        state[V_WB], quaternion_rate(state[Q_WB], state[W_WB_B]), a_WB, alpha_WB_B,
        rotor_accelerations,
    ])


def body_kinematics(state, params: QuadrotorParams, v_wind_W=None):
    """(V_WB, A_WB) in the layout of the airframe/IMU seam (systems/vehicles/airframe.py):
    V_WB = [w_WB; v_WB] and A_WB = [alpha_WB; a_WB], all expressed in W (the air at v_wind_W)."""
    R_WB = rotation_from_quaternion(state[Q_WB])
    a_WB, alpha_WB_B = rigid_body_accelerations(state, params, v_wind_W)
    return (np.concatenate([R_WB @ state[W_WB_B], state[V_WB]]),
            np.concatenate([R_WB @ alpha_WB_B, a_WB]))


def quadrotor_state(p_WB=(0.0, 0.0, 0.0), R_WB=None, v_WB=(0.0, 0.0, 0.0),
                    w_WB_B=(0.0, 0.0, 0.0), rotor_speeds=(0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """Packs a 17-vector state; R_WB is a RotationMatrix (identity when None)."""
    R_WB = RotationMatrix() if R_WB is None else R_WB
    return np.concatenate([
        p_WB, R_WB.ToQuaternion().wxyz(), v_WB, w_WB_B, rotor_speeds,
    ]).astype(float)


def hover_state(params: QuadrotorParams, p_WB, yaw: float = 0.0) -> np.ndarray:
    """State at rest at p_WB (m) with heading yaw (rad) and rotors at hover speed."""
    return quadrotor_state(
        p_WB=p_WB,
        R_WB=RotationMatrix.MakeZRotation(yaw),
        rotor_speeds=np.full(4, params.hover_rotor_speed()),
    )


def pose_from_state(state) -> RigidTransform:
    """X_WB from a 17-vector state (the quaternion is normalised)."""
    q = np.asarray(state[Q_WB], dtype=float)
    return RigidTransform(Quaternion(q / np.linalg.norm(q)), np.asarray(state[P_WB]))


def _symbolic_model(params: QuadrotorParams, wind: bool = False):
    """(x (17), u (4, or 7 with the wind's velocity in W after the commands), dx/dt, V_WB, A_WB) of
    Eq. (7)-(8) in pydrake.symbolic variables."""
    x = MakeVectorVariable(STATE_SIZE, "x")
    u = MakeVectorVariable(4 + 3 * wind, "u")
    v_wind_W = u[4:7] if wind else None
    with np.errstate(invalid="ignore"):  # numpy's float-flag check on arrays of Expressions
        V_WB, A_WB = body_kinematics(x, params, v_wind_W)
        return x, u, quadrotor_state_derivative(x, u[:4], params, v_wind_W), V_WB, A_WB


def make_quadrotor_dynamics(params: QuadrotorParams, wind: bool = False) -> SymbolicVectorSystem:
    """Eq. (7)-(8) as a SymbolicVectorSystem: input 4 rotor speed commands [rad/s] (and with
    `wind` the air's velocity in W [m/s] after them), continuous state the 17-vector, output
    [state (17), V_WB (6), A_WB (6)] (see body_kinematics). Per-step evaluation stays in C++."""
    params.validate()
    x, u, dynamics, V_WB, A_WB = _symbolic_model(params, wind)
    return SymbolicVectorSystem(state=x, input=u, dynamics=dynamics, output=np.concatenate([x, V_WB, A_WB]))


class StateToPose(LeafSystem):
    """Input `state` (17) -> abstract output `X_WB` (RigidTransform). Computed only when pulled,
    so a scene pays for it at its own rate."""

    def __init__(self):
        super().__init__()
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self.DeclareAbstractOutputPort(
            "X_WB", lambda: Value(RigidTransform()), self._calc_pose)

    def _calc_pose(self, context, output):
        output.set_value(pose_from_state(self._state.Eval(context)))


class Quadrotor(Diagram):
    """Seed 002 quadrotor with named ports.

    Input `rotor_speed_commands` (4, rad/s), and with `wind` `wind_velocity_W` (3, m/s, in W: the
    air's velocity, which acts through the rotor drag). Outputs `state` (17, see the module docstring),
    `X_WB` (abstract RigidTransform), `V_WB` and `A_WB` (6 each, see body_kinematics), the
    kinematics seam that AirframeGeometry and the IMU read.

    `time_period` None: the state is the continuous state of the subsystem `dynamics`.
    `time_period` T: Eq. (7)-(8) are integrated over each period T in C++ with `integration`
    (systems/vehicles/integration.py), the input held over the period; the state is then the
    discrete state of `dynamics`. Discretised, `V_WB` and `A_WB` are a separate stateless stage,
    evaluated only when pulled (Drake 1.58 aborts on such a stage in a diagram with continuous
    state, so use the discretised quadrotor in diagrams without any). Either way:
    `quadrotor.set_state(root_context, hover_state(...))`.
    """

    def __init__(self, params: QuadrotorParams, time_period: float | None = None,
                 integration: SimulatorConfig | None = None, wind: bool = False):
        super().__init__()
        params.validate()
        self.params = params
        builder = DiagramBuilder()
        pose = builder.AddNamedSystem("pose", StateToPose())
        inputs = []  # the ports that take the commands, and the wind's
        if time_period is None:
            self.dynamics = dynamics = builder.AddNamedSystem("dynamics", make_quadrotor_dynamics(params, wind))
            split = builder.AddNamedSystem("split", Demultiplexer([STATE_SIZE, 6, 6]))
            builder.Connect(dynamics.get_output_port(), split.get_input_port())
            state, V_WB, A_WB = (split.get_output_port(i) for i in range(3))
            inputs.append(dynamics.get_input_port())
        else:
            x, u, derivative, V_WB_x, A_WB_x = _symbolic_model(params, wind)
            self.dynamics = dynamics = builder.AddNamedSystem("dynamics", discretise(
                SymbolicVectorSystem(state=x, input=u, dynamics=derivative, output=x), time_period, integration,
                "quadrotor"))
            # V_WB and A_WB from the state (and the wind: the drag's acceleration), evaluated when pulled.
            kinematics = builder.AddNamedSystem("kinematics", SymbolicVectorSystem(
                input=np.concatenate([x, u[4:]]), output=np.concatenate([V_WB_x, A_WB_x])))
            split = builder.AddNamedSystem("split", Demultiplexer([6, 6]))
            builder.Connect(kinematics.get_output_port(), split.get_input_port())
            state, V_WB, A_WB = dynamics.get_output_port(), split.get_output_port(0), split.get_output_port(1)
            if wind:
                to_kinematics = builder.AddNamedSystem("kinematics_input", Multiplexer([STATE_SIZE, 3]))
                builder.Connect(state, to_kinematics.get_input_port(0))
                builder.Connect(to_kinematics.get_output_port(), kinematics.get_input_port())
                inputs.append(to_kinematics.get_input_port(1))
            else:
                builder.Connect(state, kinematics.get_input_port())
            inputs.insert(0, dynamics.get_input_port())
        if wind:
            # The dynamics' one input is [commands; wind]: two diagram inputs, joined.
            joined = builder.AddNamedSystem("input", Multiplexer([4, 3]))
            builder.Connect(joined.get_output_port(), inputs[0])
            builder.ExportInput(joined.get_input_port(0), "rotor_speed_commands")
            wind_input = builder.ExportInput(joined.get_input_port(1), "wind_velocity_W")
            for port in inputs[1:]:
                builder.ConnectInput(wind_input, port)
        else:
            builder.ExportInput(inputs[0], "rotor_speed_commands")
        builder.Connect(state, pose.get_input_port())
        builder.ExportOutput(state, "state")
        builder.ExportOutput(pose.get_output_port(), "X_WB")
        builder.ExportOutput(V_WB, "V_WB")
        builder.ExportOutput(A_WB, "A_WB")
        builder.BuildInto(self)
        self.set_name("quadrotor")

    def set_state(self, root_context, x) -> None:
        """Sets the 17-vector state in a context of a diagram that contains this system."""
        set_vehicle_state(self, root_context, x)
