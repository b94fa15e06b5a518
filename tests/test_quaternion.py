"""Seed 002 quaternion algebra (Eq. 1-3, scalar last) against Drake's Quaternion and SciPy's Rotation."""

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix
from scipy.spatial.transform import Rotation

from systems.estimators.quaternion import (dcm, drake_to_paper, inverse, odot, odot_matrix, omega_matrix, otimes,
                                           otimes_matrix, paper_to_drake, rotation_vector, skew, xi)

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
