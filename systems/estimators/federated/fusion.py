"""The federated fusion of seed 001 (Sec. 4.2, Eq. 6-9) over local filters (local_filter.py).

Every local filter's estimate is expressed as an error about a common reference (the first
filter's nominal state: positions and velocities as differences, attitudes as rotation vectors in
P), so that Eq. (7)-(8) weigh them in one vector space:
    P_g = (sum_i P_i^-1)^-1,    X_g = P_g sum_i P_i^-1 X_i.
Eq. (9)'s dynamic weight beta_i = trace(P_i^-1) / sum_j trace(P_j^-1), over the marginal position
block P_i,pp (the paper's 7x7 P_i mixes metres with the quaternion's units: a bearing seen from
20 m puts a lever arm's worth of attitude information in a full block's trace), shares the process noise out (Eq. 6: Q_i = Q / beta_i,
so that sum_i Q_i^-1 = Q^-1) and the global covariance back (P_i = P_g / beta_i). Carlson's fusion-reset
also restarts every local filter from X_g (then the fusion equals the centralised filter); seed 001
shares only P_i and Q_i, and a local filter keeps its own state while its node measures (engine.py).
"""

from dataclasses import replace

import numpy as np

from systems.estimators.federated.local_filter import LocalState, exp_so3, log_so3

POSITION = slice(0, 3)  # the position block of the 9 error states
MIN_BETA = 1e-3  # a filter's share never vanishes, so its process noise stays finite


def errors_about(reference: LocalState, state: LocalState) -> np.ndarray:
    """The state as an error vector [dp, dv, dtheta] about the reference's nominal state."""
    return np.r_[state.p - reference.p, state.v - reference.v, log_so3(state.R @ reference.R.T)]


def fuse(states: list[LocalState]) -> tuple[LocalState, np.ndarray]:
    """(the global estimate, the betas) of Eq. (7)-(9) over the local filters' states."""
    reference = states[0]
    information = [np.linalg.inv(s.P) for s in states]
    P_g = np.linalg.inv(sum(information))
    x_g = P_g @ sum(I @ errors_about(reference, s) for I, s in zip(information, states))
    traces = np.array([np.trace(np.linalg.inv(s.P[POSITION, POSITION])) for s in states])
    betas = np.maximum(traces / traces.sum(), MIN_BETA)
    betas /= betas.sum()
    fused = LocalState(reference.p + x_g[0:3], reference.v + x_g[3:6], exp_so3(x_g[6:9]) @ reference.R,
                       (P_g + P_g.T) / 2)
    return fused, betas


def reset(states: list[LocalState], fused: LocalState, betas: np.ndarray, kept=()) -> list[LocalState]:
    """The information sharing: every filter gets P_i = P_g / beta_i and a process-noise share of
    1 / beta_i, and restarts from the global estimate, except those listed in `kept` (indices), which
    keep their own state."""
    shared = [replace(s, P=fused.P / b, q_scale=1.0 / b) for s, b in zip(states, betas)]
    return [s if i in kept else replace(s, p=fused.p.copy(), v=fused.v.copy(), R=fused.R.copy())
            for i, s in enumerate(shared)]
