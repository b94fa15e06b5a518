"""systems/noise.py's exact discretisation of linear processes driven by white noise, which the wind's
turbulence and the navigation's errors share: against closed forms, and used by both as it is."""

import math

import numpy as np
import pytest

from systems.environment.wind import _A, _B, _COMPONENT_OF_STATE, _STATIONARY_FACTOR, turbulence_discrete
from systems.noise import stationary_factor, van_loan_discretisation
from systems.sensors.navigation import second_order_model


@pytest.mark.parametrize("steps", [[0.01, 0.01], [0.1, 0.5], [3.0, 0.002]])
def test_van_loan_steps_ornstein_uhlenbeck_processes_exactly(steps):
    """x' = -x + sqrt(2) n per state (unit stationary variance), each row at its own step h:
    Phi = e^-h, G = sqrt(1 - e^-2h), the states independent."""
    h = np.array(steps)
    phi, g = van_loan_discretisation(-np.diag(h), 2.0 * np.diag(h))
    np.testing.assert_allclose(phi, np.diag(np.exp(-h)), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(g, np.diag(np.sqrt(1.0 - np.exp(-2.0 * h))), rtol=1e-12, atol=1e-15)


def test_van_loan_of_a_double_integrator_has_its_closed_form():
    """x = [p, v], v' = q n over h: Phi = [[1, h], [0, 1]], Q = q^2 [[h^3 / 3, h^2 / 2], [h^2 / 2, h]]."""
    h, q = 0.3, 2.0
    A, B = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [q]])
    phi, g = van_loan_discretisation(A * h, B @ B.T * h)
    np.testing.assert_allclose(phi, [[1.0, h], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(g @ g.T, q**2 * np.array([[h**3 / 3, h**2 / 2], [h**2 / 2, h]]), rtol=1e-12)
    assert g[0, 1] == 0.0  # lower triangular


def test_stationary_factor_is_the_lyapunov_solutions_cholesky_factor():
    tau = 4.0  # the navigation's second-order process: var(e) = 1, var(e') = 1 / tau^2
    A, B = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]]), np.array([[0.0], [2.0 / math.sqrt(tau**3)]])
    L = stationary_factor(A, B @ B.T)
    np.testing.assert_allclose(L @ L.T, np.diag([1.0, 1.0 / tau**2]), atol=1e-13)
    assert L[0, 1] == 0.0


def test_the_wind_and_the_navigation_step_with_the_shared_helpers():
    """Both models are the helpers' output bit for bit (their seeded draws unchanged by the sharing)."""
    tau, period = 60.0, 0.005
    A, B = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]]), np.array([[0.0], [2.0 / math.sqrt(tau**3)]])
    phi, g, stationary = second_order_model(tau, period)
    shared = (*van_loan_discretisation(A * period, B @ B.T * period), stationary_factor(A, B @ B.T))
    for mine, theirs in zip((phi, g, stationary), shared):
        np.testing.assert_array_equal(mine, theirs)
    length, airspeed, dt = np.array([67.0, 67.0, 10.0]), 5.0, 0.01
    h = (airspeed * dt / length)[_COMPONENT_OF_STATE]
    B_h = np.sqrt(h)[:, None] * _B
    shared = van_loan_discretisation(h[:, None] * _A, B_h @ B_h.T)
    for mine, theirs in zip(turbulence_discrete(length, airspeed, dt), shared):
        np.testing.assert_array_equal(mine, theirs)
    np.testing.assert_array_equal(_STATIONARY_FACTOR, stationary_factor(_A, _B @ _B.T))


def test_each_stream_draws_its_own_numbers():
    """The same seed and sample index in two streams (the IMU's, the camera's) are independent draws."""
    from systems.noise import sample_rng
    imu, camera = sample_rng(7, "imu", 3).standard_normal(4), sample_rng(7, "camera", 3).standard_normal(4)
    assert not np.allclose(imu, camera)
    np.testing.assert_array_equal(imu, sample_rng(7, "imu", 3).standard_normal(4))  # and each repeats
