"""Quadrotor dynamics of seed 002 (Moura & Goes), Eq. (7)-(8), as a Drake SymbolicVectorSystem.

Frames: World W is z-up; body B is x forward, y left, z up (thrust along +Bz), origin at the
centre of mass. The state vector (17) is

    [p_WB (3), q_WB (4, Drake order w, x, y, z), v_WB (3, expressed in W),
     w_WB_B (3, body angular velocity expressed in B), rotor_speeds (4, rad/s)]

and the input is the four rotor speed commands (rad/s). The quaternion need not stay exactly
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
  the paper's reference [8]).
- Eq. (8) as printed makes the roll torque l1 (f1 - f2 - f3 + f4) and the pitch torque
  l2 (-f1 - f2 + f3 + f4), so rotor 1 sits at (x, y) = (+l2, +l1) (front left), 2 at (+l2, -l1)
  (front right), 3 at (-l2, -l1) (back right), 4 at (-l2, +l1) (back left): l1 is the lateral
  arm and l2 the longitudinal arm, the reverse of the paper's prose. Table 1 has l1 = l2, so the
  numbers do not depend on which reading is right; we follow the matrix.
- Table 1's d = 3.5 m, tau_s and theta_max belong to the ground vehicle (ground_vehicle.py).
"""

from dataclasses import dataclass

import numpy as np
import pydrake.math as dmath
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import Value
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.symbolic import MakeVectorVariable
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import SymbolicVectorSystem

STATE_SIZE = 17
P_WB = slice(0, 3)
Q_WB = slice(3, 7)
V_WB = slice(7, 10)
W_WB_B = slice(10, 13)
ROTOR_SPEEDS = slice(13, 17)


@dataclass
class QuadrotorParams:
    """Airframe and motor constants of seed 002 Table 1 (see the module docstring for how the
    table's symbols map onto Eq. (7)-(8)). Call validate() after loading from YAML."""

    mass: float = 1.2  # m [kg], seed 002 Table 1
    inertia_xx: float = 0.015  # Jx [kg m^2], Table 1 prints 0.15 (see module docstring)
    inertia_yy: float = 0.015  # Jy [kg m^2], Table 1
    inertia_zz: float = 0.03  # Jz [kg m^2], Table 1
    motor_time_constant: float = 0.1  # tau_m [s], Table 1, Eq. (7)
    motor_gain: float = 1.0  # k_m [-], Eq. (7); Table 1 calls it k_p
    thrust_coefficient: float = 1.28e-5  # k_t [N s^2/rad^2], Eq. (7); Table 1 calls it k_m
    drag_torque_coefficient: float = 3.08e-7  # k_d [N m s^2/rad^2], Table 1, Eq. (7)
    arm_lateral: float = 0.25  # l1 [m], Table 1; rotor |y| in Eq. (8)
    arm_longitudinal: float = 0.25  # l2 [m], Table 1; rotor |x| in Eq. (8)
    # w_max [rad/s]: Eq. (7) names it but Table 1 gives no value; 700 rad/s gives a
    # thrust-to-weight ratio of 2.1 with the defaults above.
    max_rotor_speed: float = 700.0
    gravity: float = 9.81  # g [m/s^2]

    def __post_init__(self):
        self.validate()

    def validate(self):
        """Raises ValueError naming the first field that is out of range."""
        positive = (
            "mass", "inertia_xx", "inertia_yy", "inertia_zz", "motor_time_constant",
            "motor_gain", "thrust_coefficient", "drag_torque_coefficient", "arm_lateral",
            "arm_longitudinal", "max_rotor_speed", "gravity",
        )
        for name in positive:
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"QuadrotorParams.{name} must be positive, got {value}")
        Jx, Jy, Jz = self.inertia_diagonal
        if Jx > Jy + Jz or Jy > Jx + Jz or Jz > Jx + Jy:
            raise ValueError(
                "QuadrotorParams.inertia_xx/yy/zz violate the triangle inequality "
                f"(each at most the sum of the other two), got {Jx}, {Jy}, {Jz}"
            )
        if self.hover_rotor_speed() >= self.max_rotor_speed:
            raise ValueError(
                f"QuadrotorParams.max_rotor_speed {self.max_rotor_speed} rad/s cannot hover "
                f"(needs {self.hover_rotor_speed():.1f} rad/s)"
            )

    @property
    def inertia_diagonal(self) -> np.ndarray:
        """[Jx, Jy, Jz] in kg m^2, about the body axes."""
        return np.array([self.inertia_xx, self.inertia_yy, self.inertia_zz])

    def hover_rotor_speed(self) -> float:
        """Rotor speed [rad/s] at which four rotors carry the weight: 4 k_t w^2 = m g."""
        return float(np.sqrt(self.mass * self.gravity / (4.0 * self.thrust_coefficient)))


def mixer_matrix(params: QuadrotorParams) -> np.ndarray:
    """Seed 002 Eq. (8): maps rotor thrusts f (N) to [F^C (N), T^C_B (N m)], torque in B."""
    l1, l2 = params.arm_lateral, params.arm_longitudinal
    k_dt = params.drag_torque_coefficient / params.thrust_coefficient
    return np.array([
        [1.0, 1.0, 1.0, 1.0],
        [l1, -l1, -l1, l1],
        [-l2, -l2, l2, l2],
        [k_dt, -k_dt, k_dt, -k_dt],
    ])


def rotation_from_quaternion(q):
    """R_WB (3x3) from a quaternion [w, x, y, z] of any nonzero norm; works on floats and
    pydrake.symbolic Expressions alike."""
    w, x, y, z = q
    n = w * w + x * x + y * y + z * z
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ]) / n


def quaternion_rate(q, w_B):
    """q_dot = q (x) [0, w_B] / 2 for Drake's [w, x, y, z] order and body angular velocity."""
    w, x, y, z = q
    p, r, s = w_B
    return 0.5 * np.array([
        -x * p - y * r - z * s,
        w * p + y * s - z * r,
        w * r + z * p - x * s,
        w * s + x * r - y * p,
    ])


def quadrotor_state_derivative(state, rotor_speed_commands, params: QuadrotorParams):
    """Seed 002 Eq. (7)-(8) (with the corrections in the module docstring).

    state: the 17-vector described in the module docstring; rotor_speed_commands: 4 [rad/s].
    Returns d(state)/dt. Works on floats and on pydrake.symbolic Expressions."""
    q = state[Q_WB]
    v_WB = state[V_WB]
    w_B = state[W_WB_B]
    rotor_speeds = state[ROTOR_SPEEDS]

    targets = [
        dmath.min(dmath.max(params.motor_gain * c, 0.0), params.max_rotor_speed)
        for c in rotor_speed_commands
    ]
    rotor_accelerations = (np.array(targets) - rotor_speeds) / params.motor_time_constant

    thrusts = params.thrust_coefficient * rotor_speeds**2
    wrench = mixer_matrix(params) @ thrusts
    collective, torque_B = wrench[0], wrench[1:]

    R_WB = rotation_from_quaternion(q)
    a_WB = R_WB[:, 2] * collective / params.mass - np.array([0.0, 0.0, params.gravity])

    J = params.inertia_diagonal
    alpha_B = (torque_B - np.cross(w_B, J * w_B)) / J

    return np.concatenate([v_WB, quaternion_rate(q, w_B), a_WB, alpha_B, rotor_accelerations])


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


def make_quadrotor_dynamics(params: QuadrotorParams) -> SymbolicVectorSystem:
    """Eq. (7)-(8) as a SymbolicVectorSystem: input 4 rotor speed commands [rad/s], continuous
    state and output the 17-vector state. Per-step evaluation stays in C++."""
    params.validate()
    x = MakeVectorVariable(STATE_SIZE, "x")
    u = MakeVectorVariable(4, "w_cmd")
    return SymbolicVectorSystem(
        state=x, input=u, dynamics=quadrotor_state_derivative(x, u, params), output=x)


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

    Input `rotor_speed_commands` (4, rad/s). Outputs `state` (17, see module docstring) and
    `X_WB` (abstract RigidTransform). The continuous state of this diagram is the 17-vector:
    `quadrotor.GetMyMutableContextFromRoot(root).SetContinuousState(hover_state(...))`.
    """

    def __init__(self, params: QuadrotorParams):
        super().__init__()
        self.params = params
        builder = DiagramBuilder()
        dynamics = builder.AddNamedSystem("dynamics", make_quadrotor_dynamics(params))
        pose = builder.AddNamedSystem("pose", StateToPose())
        builder.Connect(dynamics.get_output_port(), pose.get_input_port())
        builder.ExportInput(dynamics.get_input_port(), "rotor_speed_commands")
        builder.ExportOutput(dynamics.get_output_port(), "state")
        builder.ExportOutput(pose.get_output_port(), "X_WB")
        builder.BuildInto(self)
        self.set_name("quadrotor")
