"""systems/quaternion.py against Drake's Quaternion and RotationMatrix and SciPy's Rotation: the
Drake-order helpers (w, x, y, z; one, vectorised, non-unit, symbolic) and seed 002's algebra (Eq. 1-3,
scalar last)."""

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix
from pydrake.symbolic import Evaluate, MakeVectorVariable
from scipy.spatial.transform import Rotation

from systems.quaternion import (dcm, drake_to_paper, inverse, odot, odot_matrix, omega_matrix, otimes, otimes_matrix,
                                paper_to_drake, quat_conjugate, quat_multiply, quaternion_rate,
                                rotation_from_quaternion, rotation_vector, skew, toward, xi)

rng = np.random.default_rng(7)
PAIRS = [(Rotation.random(random_state=rng).as_quat(), Rotation.random(random_state=rng).as_quat()) for _ in range(5)]


def drake_product(a, b):
    """Drake's Hamilton product a * b, computed on Drake's (w, x, y, z) quaternions."""
    return drake_to_paper(paper_to_drake(a).multiply(paper_to_drake(b)))


def test_skew_is_the_cross_product():
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b))
    np.testing.assert_array_equal(np.diag(skew(a)), 0.0)  # Eq. (3) prints ones there


@pytest.mark.parametrize("a, b", PAIRS)
def test_odot_is_drakes_hamilton_product_and_otimes_its_reverse(a, b):
    np.testing.assert_allclose(odot(a, b), drake_product(a, b), atol=1e-12)
    np.testing.assert_allclose(otimes(a, b), drake_product(b, a), atol=1e-12)
    np.testing.assert_allclose(otimes(a, b), odot(b, a), atol=1e-12)  # the note after Eq. (3)
    np.testing.assert_allclose(otimes_matrix(a) @ b, otimes(a, b))
    np.testing.assert_allclose(odot_matrix(a) @ b, odot(a, b))


@pytest.mark.parametrize("a, b", PAIRS)
def test_odot_matches_scipy_composition(a, b):
    product = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
    product *= np.sign(product @ odot(a, b))  # q and -q are the same rotation
    np.testing.assert_allclose(odot(a, b), product, atol=1e-12)


@pytest.mark.parametrize("a, b", PAIRS)
def test_otimes_composes_like_direction_cosine_matrices(a, b):
    # q^{C/A} = q^{C/B} (x) q^{B/A}  <=>  D^{C/A} = D^{C/B} D^{B/A}
    np.testing.assert_allclose(dcm(otimes(a, b)), dcm(a) @ dcm(b), atol=1e-12)
    np.testing.assert_allclose(dcm(inverse(a)), dcm(a).T, atol=1e-12)
    np.testing.assert_allclose(otimes(a, inverse(a)), [0, 0, 0, 1], atol=1e-12)


@pytest.mark.parametrize("a, _", PAIRS)
def test_conversion_helpers_and_dcm_convention(a, _):
    R_AB = RotationMatrix(paper_to_drake(a))
    np.testing.assert_allclose(R_AB.matrix(), Rotation.from_quat(a).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(dcm(a), R_AB.matrix().T, atol=1e-12)  # D^{B/A} = R_BA
    q = drake_to_paper(R_AB)
    np.testing.assert_allclose(q * np.sign(q @ a), a, atol=1e-12)
    np.testing.assert_allclose(drake_to_paper(Quaternion(wxyz=[a[3], *a[:3]])), a)


def test_xi_is_body_rate_kinematics():
    q = Rotation.random(random_state=rng).as_quat()
    omega_B = np.array([0.3, -0.2, 0.9])  # rad/s, in the rotating frame B
    dt = 1e-6
    R_next = Rotation.from_quat(q) * Rotation.from_rotvec(omega_B * dt)  # R_AB(t + dt) = R_AB Exp(omega_B dt)
    q_next = R_next.as_quat() * np.sign(R_next.as_quat() @ q)
    np.testing.assert_allclose((q_next - q) / dt, xi(q) @ omega_B / 2, atol=1e-5)
    np.testing.assert_allclose(omega_matrix(omega_B) @ q, xi(q) @ omega_B, atol=1e-15)


@pytest.mark.parametrize("a, _", PAIRS)
def test_product_matrices_are_the_blocks_of_eq_1_and_2(a, _):
    v, w = a[:3], a[3]
    eq1 = np.block([[w * np.eye(3) - skew(v), v[:, None]], [-v[None, :], np.array([[w]])]])
    eq2 = np.block([[w * np.eye(3) + skew(v), v[:, None]], [-v[None, :], np.array([[w]])]])
    np.testing.assert_allclose(otimes_matrix(a), eq1)
    np.testing.assert_allclose(odot_matrix(a), eq2)
    np.testing.assert_allclose(xi(a), eq2[:, :3])  # Xi(q) of Eq. (11)
    D = (w * w - v @ v) * np.eye(3) - 2 * w * skew(v) + 2 * np.outer(v, v)  # the DCM of Sec. 2.1, typo fixed
    np.testing.assert_allclose(dcm(a), D, atol=1e-15)


def test_rotation_vector_matches_scipy_for_either_sign():
    rotations = Rotation.random(8, random_state=rng)
    q = rotations.as_quat()
    q[::2] *= -1
    np.testing.assert_allclose(rotation_vector(q), rotations.as_rotvec(), atol=1e-12)
    np.testing.assert_allclose(rotation_vector(np.array([0.0, 0.0, 1.0, 0.0])), [0, 0, np.pi])


def test_rotation_vector_of_the_identity_is_exactly_zero():
    """The identity (either sign) has angle 0: its rotation vector is exactly zero, not 0/0 = NaN, also in a stack."""
    for w in (1.0, -1.0):
        assert np.array_equal(rotation_vector(np.array([0.0, 0.0, 0.0, w])), np.zeros(3))
    rotations = Rotation.random(3, random_state=np.random.default_rng(3))  # own stream: the shared one stays as it was
    q = np.vstack([rotations.as_quat(), [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, -1.0]])
    expected = np.vstack([rotations.as_rotvec(), np.zeros((2, 3))])
    np.testing.assert_allclose(rotation_vector(q), expected, atol=1e-12)


# ---- Drake order [w, x, y, z] ----------------------------------------------------------------


# pydrake filters numpy's "invalid value" warnings from symbolic object arrays when imported;
# pytest resets warning filters per test, so restore that one where symbols are used.
SYMBOLIC = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


def wxyz(paper):
    """Drake's [w, x, y, z] of (..., 4) scalar-last quaternions."""
    return paper[..., [3, 0, 1, 2]]


@pytest.mark.parametrize("a, b", PAIRS)
def test_quat_multiply_and_conjugate_match_drake(a, b):
    qa, qb = Quaternion(wxyz(a)), Quaternion(wxyz(b))
    np.testing.assert_allclose(quat_multiply(wxyz(a), wxyz(b)), qa.multiply(qb).wxyz(), atol=1e-15)
    np.testing.assert_allclose(quat_conjugate(wxyz(a)), qa.conjugate().wxyz())
    np.testing.assert_allclose(quat_multiply(wxyz(a), quat_conjugate(wxyz(a))), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(odot(a, b), quat_multiply(wxyz(a), wxyz(b))[[1, 2, 3, 0]], atol=1e-15)


@pytest.mark.parametrize("a, b", PAIRS)
def test_rotation_from_quaternion_matches_drake_and_scipy(a, b):
    R = RotationMatrix(Quaternion(wxyz(a))).matrix()
    np.testing.assert_allclose(rotation_from_quaternion(wxyz(a)), R, atol=1e-15)
    np.testing.assert_allclose(rotation_from_quaternion(list(wxyz(a))), R, atol=1e-15)  # a list of floats
    np.testing.assert_allclose(rotation_from_quaternion(wxyz(a)), Rotation.from_quat(a).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(rotation_from_quaternion(wxyz(a)), dcm(a).T, atol=1e-15)  # R_AB = (D^{B/A})^T
    np.testing.assert_allclose(rotation_from_quaternion(quat_multiply(wxyz(a), wxyz(b))),
                               R @ RotationMatrix(Quaternion(wxyz(b))).matrix(), atol=1e-14)


def test_rotation_from_quaternion_scales_out_the_norm():
    a = PAIRS[0][0]
    R = Rotation.from_quat(a).as_matrix()
    for scale in (1e-3, 0.7, 2.5, -4.0):
        np.testing.assert_allclose(rotation_from_quaternion(scale * wxyz(a)), R, atol=1e-14)
    # SciPy normalises a non-unit quaternion the same way
    np.testing.assert_allclose(rotation_from_quaternion(3.0 * wxyz(a)), Rotation.from_quat(3.0 * a).as_matrix(),
                               atol=1e-14)


def test_rotation_from_quaternion_and_quat_multiply_vectorise():
    rotations = Rotation.random(12, random_state=rng)
    q = wxyz(rotations.as_quat()).reshape(3, 4, 4) * rng.uniform(0.5, 2.0, (3, 4, 1))  # (3, 4) non-unit quaternions
    R = rotation_from_quaternion(q)
    assert R.shape == (3, 4, 3, 3)
    np.testing.assert_allclose(R.reshape(12, 3, 3), rotations.as_matrix(), atol=1e-14)
    for i, j in np.ndindex(3, 4):
        np.testing.assert_array_equal(R[i, j], rotation_from_quaternion(q[i, j]))  # one at a time: the same numbers
    b = wxyz(Rotation.random(random_state=rng).as_quat())
    products = quat_multiply(q, b)  # (3, 4, 4) times (4,): broadcast
    assert products.shape == (3, 4, 4)
    for i, j in np.ndindex(3, 4):
        np.testing.assert_allclose(products[i, j], Quaternion(q[i, j] / np.linalg.norm(q[i, j])).multiply(
            Quaternion(b)).wxyz() * np.linalg.norm(q[i, j]), atol=1e-14)
    np.testing.assert_allclose(quat_conjugate(q)[..., 1:], -q[..., 1:])


@SYMBOLIC
def test_rotation_from_quaternion_of_symbolic_variables():
    q = MakeVectorVariable(4, "q")
    R = rotation_from_quaternion(q)
    assert R.shape == (3, 3)
    values = 1.7 * wxyz(PAIRS[1][0])  # non-unit
    R_value = Evaluate(R, dict(zip(q, values)))
    np.testing.assert_allclose(R_value, rotation_from_quaternion(values), atol=1e-15)
    np.testing.assert_allclose(R_value, Rotation.from_quat(PAIRS[1][0]).as_matrix(), atol=1e-14)


@SYMBOLIC
def test_quaternion_rate_is_body_rate_kinematics():
    a = PAIRS[2][0]
    q, w_B = wxyz(a), np.array([0.3, -0.2, 0.9])  # rad/s, in B
    np.testing.assert_allclose(quaternion_rate(q, w_B), quat_multiply(q, np.r_[0.0, w_B]) / 2, atol=1e-15)
    np.testing.assert_allclose(quaternion_rate(q, w_B), wxyz(xi(a) @ w_B / 2), atol=1e-15)  # Eq. (11), reordered
    dt = 1e-6
    R_next = Rotation.from_quat(a) * Rotation.from_rotvec(w_B * dt)  # R_AB(t + dt) = R_AB Exp(w_B dt)
    q_next = wxyz(R_next.as_quat() * np.sign(R_next.as_quat() @ a))
    np.testing.assert_allclose((q_next - q) / dt, quaternion_rate(q, w_B), atol=1e-5)
    many = np.stack([q, 2 * q])
    np.testing.assert_array_equal(quaternion_rate(many, w_B), [quaternion_rate(q, w_B), quaternion_rate(2 * q, w_B)])
    variables = MakeVectorVariable(4, "q")
    symbolic = quaternion_rate(variables, w_B)
    assert symbolic.shape == (4,)
    np.testing.assert_allclose(Evaluate(symbolic, dict(zip(variables, q)))[:, 0], quaternion_rate(q, w_B), atol=1e-15)


def test_toward_puts_a_stack_of_quaternions_on_the_references_side():
    q = np.array([[0.1, 0.2, 0.3, 0.9], [-0.1, -0.2, -0.3, -0.9], [0.9, 0.0, 0.0, -0.5]])
    np.testing.assert_array_equal(toward(q, q[0]), [q[0], q[0], -q[2]])  # q and -q: one attitude
    stacked = toward(np.broadcast_to(q, (2, 3, 4)), np.array([q[0], -q[0]])[:, None])  # one reference per row
    np.testing.assert_array_equal(stacked[1], -toward(q, q[0]))
    # a quaternion at right angles to the reference (dot 0: attitudes 180 degrees apart) points away no more than -q
    # does: it is left as it is
    np.testing.assert_array_equal(toward(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])),
                                  [1.0, 0.0, 0.0, 0.0])
