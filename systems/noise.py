"""Seeded randomness that is a pure function of (seed, stream, sample index), and the exact discrete
form of the linear processes driven by it.

Every noise source draws from `sample_rng(seed, stream, k)` for its k-th sample, so the same seed
gives the same run bit for bit, whatever order systems are evaluated in and however often a
context is cloned or re-simulated.
"""

import zlib

import numpy as np
from scipy.linalg import cholesky, expm, solve_continuous_lyapunov


def stream_id(name: str) -> int:
    """A stable integer for a noise stream's name (Python's hash() is salted per process)."""
    return zlib.crc32(name.encode())


def sample_rng(seed: int, stream: str, k: int) -> np.random.Generator:
    """The generator for sample k of the named stream under the scenario seed."""
    return np.random.default_rng([int(seed), stream_id(stream), int(k)])


def sample_index(time: float, period: float) -> int:
    """Index of the periodic sample at `time` for a sampler of the given period (s)."""
    return int(round(time / period))


def van_loan_discretisation(A_step: np.ndarray, BBt_step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The exact step of x' = A x + B n (n unit white noise): (Phi, G) with x_next = Phi x + G m, m ~ N(0, I).

    Takes A and B B^T times the step (each row's own step where the states step differently, as the wind's do).
    Van Loan's method (1978): expm of [[-A h, B B^T h], [0, A^T h]] holds Phi^T in its lower-right block and
    Phi^-1 Q in its upper right, Q = integral over [0, h] of e^(A r) B B^T e^(A^T r) dr; G is Q's Cholesky factor."""
    n = len(A_step)
    van_loan = np.zeros((2 * n, 2 * n))
    van_loan[:n, :n], van_loan[:n, n:], van_loan[n:, n:] = -A_step, BBt_step, A_step.T
    exp = expm(van_loan)
    phi = exp[n:, n:].T
    q = phi @ exp[:n, n:]
    return phi, cholesky((q + q.T) / 2, lower=True)


def stationary_factor(A: np.ndarray, BBt: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor of x' = A x + B n's stationary covariance P, A P + P A^T + B B^T = 0 (A stable):
    L m, m ~ N(0, I), is a draw from the stationary distribution."""
    return cholesky(solve_continuous_lyapunov(A, -BBt), lower=True)
