"""Quaternion algebra of seed 002 (Sec. 2.1, Eq. 1-3), scalar LAST, in Markley & Crassidis' convention.

A paper quaternion is q = [q1, q2, q3, q4] = [x, y, z, w]. The paper's q^{B/A} is the attitude of
frame B with respect to frame A: its direction cosine matrix D^{B/A} = dcm(q^{B/A}) maps components
in A to components in B (a_B = D^{B/A} a_A), so in Drake's notation D^{B/A} = R_BA = R_AB^T.

**Conversion to Drake** (`paper_to_drake`, `drake_to_paper`, the one place it happens): the paper's
q^{B/A} holds the same four numbers as Drake's (Hamilton) quaternion of R_AB, reordered from
(w, x, y, z) to [x, y, z, w]. So `drake_to_paper(X_WB.rotation())` is q^{B/R} of the paper (R = the
paper's reference frame, our World W), and `RotationMatrix(paper_to_drake(q^{B/A}))` is R_AB.
SciPy's `Rotation.from_quat` is scalar-last and Hamilton too: `Rotation.from_quat(q^{B/A})` is R_AB.

The two products (Eq. 1, 2): q^A (x) q^B (`otimes`) composes like DCMs,
dcm(q^{C/B} (x) q^{B/A}) = dcm(q^{C/B}) dcm(q^{B/A}), and q^A (.) q^B (`odot`) is the Hamilton
product (Drake's `Quaternion.multiply`); q^A (x) q^B = q^B (.) q^A.

Paper typos fixed here: Eq. (3) prints ones on the diagonal of the skew-symmetric matrix [q x]
(it is zero there), and the DCM is printed as (q4^2 - |q|^2) I3 - ..., which with |q| = 1 would be
(q4^2 - 1) I3; Markley & Crassidis (Eq. 2.125) have (q4^2 - |q_{1:3}|^2) I3.
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix


def skew(v: np.ndarray) -> np.ndarray:
    """[v x] of Eq. (3) (zero diagonal): skew(a) @ b = a x b."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def otimes_matrix(q: np.ndarray) -> np.ndarray:
    """[q (x)] = [[q4 I3 - [q_{1:3} x], q_{1:3}], [-q_{1:3}^T, q4]] of Eq. (1), so that
    otimes(q, p) = otimes_matrix(q) @ p."""
    x, y, z, w = q
    return np.array([[w, z, -y, x], [-z, w, x, y], [y, -x, w, z], [-x, -y, -z, w]])


def odot_matrix(q: np.ndarray) -> np.ndarray:
    """[q (.)] = [[q4 I3 + [q_{1:3} x], q_{1:3}], [-q_{1:3}^T, q4]] of Eq. (2), so that
    odot(q, p) = odot_matrix(q) @ p."""
    x, y, z, w = q
    return np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


def otimes(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """qa (x) qb, Eq. (1): composes attitudes like DCMs, q^{C/A} = q^{C/B} (x) q^{B/A}."""
    return otimes_matrix(qa) @ qb


def odot(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """qa (.) qb, Eq. (2): the Hamilton product; qa (x) qb = qb (.) qa."""
    return odot_matrix(qa) @ qb


def inverse(q: np.ndarray) -> np.ndarray:
    """q^-1 of a unit quaternion (its conjugate [-q_{1:3}, q4]): (q^{B/A})^-1 = q^{A/B}."""
    return np.array([-q[0], -q[1], -q[2], q[3]])


def dcm(q: np.ndarray) -> np.ndarray:
    """D(q) = (q4^2 - |q_{1:3}|^2) I3 - 2 q4 [q_{1:3} x] + 2 q_{1:3} q_{1:3}^T (Sec. 2.1, typo fixed);
    q must be unit. D(q^{B/A}) = D^{B/A} = R_BA."""
    x, y, z, w = q
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y + w * z), 2 * (x * z - w * y)],
        [2 * (x * y - w * z), w * w - x * x + y * y - z * z, 2 * (y * z + w * x)],
        [2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z]])


def xi(q: np.ndarray) -> np.ndarray:
    """Xi(q) = [q4 I3 + [q_{1:3} x]; -q_{1:3}^T] (4x3) of Eq. (11): dq/dt = Xi(q) omega / 2 for the
    angular velocity omega of the frame expressed in that (body) frame."""
    x, y, z, w = q
    return np.array([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])


def omega_matrix(omega: np.ndarray) -> np.ndarray:
    """Omega(omega) = [[-[omega x], omega], [-omega^T, 0]] (4x4), with Xi(q) omega = Omega(omega) q:
    the Jacobian of Eq. (11)'s quaternion step with respect to q."""
    x, y, z = omega
    return np.array([[0.0, z, -y, x], [-z, 0.0, x, y], [y, -x, 0.0, z], [-x, -y, -z, 0.0]])


def paper_to_drake(q: np.ndarray) -> Quaternion:
    """The paper's [x, y, z, w] q^{B/A} as Drake's Quaternion (w, x, y, z) of R_AB (see module
    docstring). Not normalised: RotationMatrix(...) of it requires a unit quaternion."""
    return Quaternion(w=q[3], x=q[0], y=q[1], z=q[2])


def drake_to_paper(rotation: Quaternion | RotationMatrix) -> np.ndarray:
    """The paper's q^{B/A} = [x, y, z, w] from Drake's R_AB (RotationMatrix or Quaternion)."""
    if isinstance(rotation, RotationMatrix):
        rotation = rotation.ToQuaternion()
    w, x, y, z = rotation.wxyz()
    return np.array([x, y, z, w])


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """The rotation vector (angle times unit axis, rad) of unit quaternions q (..., 4); the angle
    is in [0, pi] (q and -q give the same vector)."""
    v, w = q[..., :3], q[..., 3:]
    s = np.sqrt(np.sum(v * v, axis=-1, keepdims=True))  # sin(angle / 2)
    # angle = 2 atan2(s, |w|) about the axis sign(w) v / s (zero vector when s = 0)
    return v * np.copysign(2 * np.arctan2(s, np.abs(w)) / np.where(s > 0, s, 1.0), w)
