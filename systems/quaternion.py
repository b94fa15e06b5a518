"""Quaternions, in the two conventions the project uses.

**Drake order** (the simulation: the quadrotor state, poses, Drake's `Quaternion`): q = [w, x, y, z],
scalar first, Hamilton product (`quat_multiply`, Drake's `Quaternion.multiply`). The quaternion of
R_AB gives R_AB = rotation_from_quaternion(q) (any nonzero norm), R(a b) = R(a) R(b), and the
conjugate (`quat_conjugate`) of a unit q is the quaternion of R_BA. `quaternion_rate` is q_dot for
the angular velocity of B in A expressed in B.

**Paper order** (seed 002 Sec. 2.1, Eq. 1-3, Markley & Crassidis' convention; the marker filters):
q = [q1, q2, q3, q4] = [x, y, z, w], scalar last. q^{B/A} is the attitude of frame B with respect to
frame A: D^{B/A} = dcm(q^{B/A}) maps components in A to components in B (a_B = D^{B/A} a_A), so in
Drake's notation D^{B/A} = R_BA = R_AB^T. The products (Eq. 1, 2): `otimes` composes like DCMs,
dcm(q^{C/B} (x) q^{B/A}) = dcm(q^{C/B}) dcm(q^{B/A}); `odot` is the Hamilton product; a (x) b = b (.) a.

**Converting**: the paper's q^{B/A} holds the same four numbers as Drake's quaternion of R_AB,
reordered: `paper_to_drake` and `drake_to_paper` for Drake's objects; on arrays, q[..., [1, 2, 3, 0]]
is Drake to paper and q[..., [3, 0, 1, 2]] paper to Drake. So drake_to_paper(X_WB.rotation()) is the
paper's q^{B/R} (R = the paper's reference frame, our World W). SciPy's `Rotation.from_quat` is
scalar-last Hamilton: Rotation.from_quat(q^{B/A}) is R_AB.

Paper typos fixed here: Eq. (3)'s [q x] has zeros on its diagonal (printed as ones); the DCM's first
term is (q4^2 - |q_{1:3}|^2) I3 (Markley & Crassidis Eq. 2.125), printed as (q4^2 - |q|^2) I3.
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix

# ----------------------------------------------------------------------------------------------
# Drake order [w, x, y, z]

_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b of (..., 4) quaternions [w, x, y, z] (broadcast): R(a b) = R(a) R(b)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """[w, -x, -y, -z] of (..., 4) quaternions: the inverse of a unit quaternion (R(q*) = R(q)^T)."""
    return np.asarray(q) * _CONJUGATE


def _components(v):
    """The k components of v (..., k), as k arrays (...); one vector (a sequence or a 1-D array) as it
    is, so that a single quaternion costs no reshuffling (the dynamics and controller call these
    every step)."""
    return np.moveaxis(v, -1, 0) if isinstance(v, np.ndarray) and v.ndim > 1 else v


def rotation_from_quaternion(q):
    """The rotation matrix of a quaternion [w, x, y, z] of any nonzero norm (it is scaled by 1 / |q|^2):
    (3, 3) for one quaternion, of floats or of pydrake.symbolic Expressions; (..., 3, 3) for a
    (..., 4) array. For the quaternion of R_AB it is R_AB."""
    w, x, y, z = _components(q)
    n = w * w + x * x + y * y + z * z
    R = np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ]) / n
    return np.moveaxis(R, (0, 1), (-2, -1)) if R.ndim > 2 else R  # (3, 3, ...) to (..., 3, 3)


def quaternion_rate(q, w_B):
    """q_dot = q [0, w_B] / 2 (Hamilton product) for q [w, x, y, z] of R_AB and the angular velocity
    w_B of B in A, expressed in B: q (4,) and w_B (3,), floats or Expressions, or arrays (..., 4) and
    (..., 3) that broadcast."""
    w, x, y, z = _components(q)
    p, r, s = _components(w_B)
    rate = 0.5 * np.array([
        -x * p - y * r - z * s,
        w * p + y * s - z * r,
        w * r + z * p - x * s,
        w * s + x * r - y * p,
    ])
    return np.moveaxis(rate, 0, -1) if rate.ndim > 1 else rate


# ----------------------------------------------------------------------------------------------
# Paper order [x, y, z, w] (seed 002 Sec. 2.1)


def _floats(v):
    """The components of one vector, or of a stack (..., k) as k arrays (...). One vector's as Python
    floats (a 1-D array's tolist(): the matrices below are built several times per filter step, and
    numpy scalars cost more than the arithmetic); any other sequence as it is."""
    if isinstance(v, np.ndarray):
        return v.tolist() if v.ndim == 1 else np.moveaxis(v, -1, 0)
    return v


def _matrix(rows) -> np.ndarray:
    """np.array(rows) of components from `_floats`: (r, c) for one vector, (..., r, c) for a stack
    (every entry a component: no constants, which would not broadcast)."""
    m = np.array(rows)
    return m if m.ndim == 2 else np.moveaxis(m, (0, 1), (-2, -1))


def skew(v: np.ndarray) -> np.ndarray:
    """[v x] of Eq. (3) (zero diagonal): skew(a) @ b = a x b."""
    x, y, z = _floats(v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def otimes_matrix(q: np.ndarray) -> np.ndarray:
    """[q (x)] = [[q4 I3 - [q_{1:3} x], q_{1:3}], [-q_{1:3}^T, q4]] of Eq. (1), so that
    otimes(q, p) = otimes_matrix(q) @ p. A stack q (..., 4) gives (..., 4, 4)."""
    x, y, z, w = _floats(q)
    return _matrix([[w, z, -y, x], [-z, w, x, y], [y, -x, w, z], [-x, -y, -z, w]])


def odot_matrix(q: np.ndarray) -> np.ndarray:
    """[q (.)] = [[q4 I3 + [q_{1:3} x], q_{1:3}], [-q_{1:3}^T, q4]] of Eq. (2), so that
    odot(q, p) = odot_matrix(q) @ p. A stack q (..., 4) gives (..., 4, 4)."""
    x, y, z, w = _floats(q)
    return _matrix([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


def otimes(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """qa (x) qb, Eq. (1): composes attitudes like DCMs, q^{C/A} = q^{C/B} (x) q^{B/A}."""
    return otimes_matrix(qa) @ qb


def odot(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """qa (.) qb, Eq. (2): the Hamilton product; qa (x) qb = qb (.) qa."""
    return odot_matrix(qa) @ qb


_INVERSE = np.array([-1.0, -1.0, -1.0, 1.0])


def inverse(q: np.ndarray) -> np.ndarray:
    """q^-1 of a unit quaternion (its conjugate [-q_{1:3}, q4]), or of a stack (..., 4): (q^{B/A})^-1 = q^{A/B}."""
    return np.asarray(q) * _INVERSE


def toward(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """q (..., 4), each quaternion negated where it points away from `reference` (broadcast against q): q and -q
    are one attitude, and a difference or a sum of quaternions needs them on one side."""
    return q * np.where(np.sum(q * reference, axis=-1) < 0, -1.0, 1.0)[..., None]


def dcm(q: np.ndarray) -> np.ndarray:
    """D(q) = (q4^2 - |q_{1:3}|^2) I3 - 2 q4 [q_{1:3} x] + 2 q_{1:3} q_{1:3}^T (Sec. 2.1, typo fixed);
    q must be unit. D(q^{B/A}) = D^{B/A} = R_BA. A stack q (..., 4) gives (..., 3, 3)."""
    x, y, z, w = _floats(q)
    return _matrix([
        [w * w + x * x - y * y - z * z, 2 * (x * y + w * z), 2 * (x * z - w * y)],
        [2 * (x * y - w * z), w * w - x * x + y * y - z * z, 2 * (y * z + w * x)],
        [2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z]])


def xi(q: np.ndarray) -> np.ndarray:
    """Xi(q) = [q4 I3 + [q_{1:3} x]; -q_{1:3}^T] (4x3) of Eq. (11): dq/dt = Xi(q) omega / 2 for the
    angular velocity omega of the frame expressed in that (body) frame. A stack q (..., 4) gives (..., 4, 3)."""
    x, y, z, w = _floats(q)
    return _matrix([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])


def omega_matrix(omega: np.ndarray) -> np.ndarray:
    """Omega(omega) = [[-[omega x], omega], [-omega^T, 0]] (4x4), with Xi(q) omega = Omega(omega) q:
    the Jacobian of Eq. (11)'s quaternion step with respect to q. A stack omega (..., 3) gives (..., 4, 4)."""
    x, y, z = _floats(omega)
    zero = np.zeros_like(x) if isinstance(x, np.ndarray) else 0.0
    return _matrix([[zero, z, -y, x], [-z, zero, x, y], [y, -x, zero, z], [-x, -y, -z, zero]])


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """The rotation vector (angle times unit axis, rad) of unit quaternions q (..., 4); the angle
    is in [0, pi] (q and -q give the same vector)."""
    v, w = q[..., :3], q[..., 3:]
    s = np.sqrt((v * v).sum(axis=-1, keepdims=True))  # sin(angle / 2)
    # angle = 2 atan2(s, |w|) about the axis sign(w) v / s (zero vector when s = 0: angle 0)
    scale = 2 * np.arctan2(s, np.abs(w))
    np.divide(scale, s, out=scale, where=s > 0)
    return v * np.copysign(scale, w)


# ----------------------------------------------------------------------------------------------
# Conversions


def paper_to_drake(q: np.ndarray) -> Quaternion:
    """The paper's [x, y, z, w] q^{B/A} as Drake's Quaternion (w, x, y, z) of R_AB. Not normalised:
    RotationMatrix(...) of it requires a unit quaternion."""
    return Quaternion(w=q[3], x=q[0], y=q[1], z=q[2])


def drake_to_paper(rotation: Quaternion | RotationMatrix | np.ndarray) -> np.ndarray:
    """The paper's q^{B/A} = [x, y, z, w] from Drake's R_AB: a RotationMatrix, a Quaternion, or
    quaternions (..., 4) in Drake's order [w, x, y, z]."""
    if isinstance(rotation, np.ndarray):
        return rotation[..., [1, 2, 3, 0]]
    if isinstance(rotation, RotationMatrix):
        rotation = rotation.ToQuaternion()
    w, x, y, z = rotation.wxyz()
    return np.array([x, y, z, w])
