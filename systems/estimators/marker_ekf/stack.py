"""Many runs of one marker filter stepped together on one flight: `run_stack`.

On a stream that gives every marker at every filter step, `latency` steps late (the open-loop
campaign's synthetic stream, diagrams/marker_batch.py), `MarkerFilter.step` at step k amounts to:
the posterior of step j = k - latency (the previous one's predicted to t_j, then updated with the
markers taken at t_j, gated and reset as engine.py's module docstring says), predicted step by step
to t_k. `run_stack` does that for S runs at once: states (S, n), covariances (S, n, n), numpy's
batched matmul and solve, through the model's stack hooks (`process_stack`, `process_noise_stack`,
`innovations_stack`, `jacobian_stack`, `normalized_stack`). A gated marker's rows get zero H rows
and a zero innovation, which leaves the update's arithmetic as if they were dropped; a run whose
markers are all gated keeps its prior. The start and each reset go through the filter's own
`_start`, one run at a time (they are few). tests/test_marker_stack.py checks it gives `step`'s
records to 1e-9.
"""

from typing import NamedTuple

import numpy as np

from systems.config import require
from systems.estimators.marker_ekf.engine import Camera, FilterStats, MarkerFilter
from systems.perception.markers import MarkerMeasurement
from systems.stepped import TIME_TOLERANCE_S


class StackRecords(NamedTuple):
    """What `MarkerFilter.record` gives at each of N steps, for S runs (NaN, -inf before the start)."""

    x: np.ndarray  # (S, N, n) state
    position_variance: np.ndarray  # (S, N) trace of the pad position's covariance [m^2]
    last_measurement_s: np.ndarray  # (S, N) acquisition time of the newest fused measurement [s]
    started: np.ndarray  # (N,) whether the filters have started (the same step in every run)
    stats: list[FilterStats]  # per run


def run_stack(marker_filter: MarkerFilter, t: np.ndarray, cameras: Camera, p_CM: np.ndarray, q_CM: np.ndarray,
              latency: int) -> StackRecords:
    """S runs of `marker_filter`'s model (a fresh filter: only its model, constants and `_start` are
    used) at the steps t (N,) [s], with the camera of every step (`MarkerFilter.camera` on stacks) and
    the markers measured at every step, in layout order: p_CM (S, N, m, 3) [m] and q^{M/C} (S, N, m, 4),
    arriving `latency` steps late."""
    f = marker_filter
    S, N, m = p_CM.shape[:3]
    require(m == len(f.layout.ids), "the stacked stream must hold every marker of the layout")
    require(latency < N and t[latency] - t[0] <= f.config.history_s + TIME_TOLERANCE_S,
            "the stacked stream must arrive within the filter's history")
    norm_error = np.abs(np.linalg.norm(q_CM, axis=-1) - 1.0)
    require(bool(np.all(np.isfinite(p_CM)) and np.all(norm_error <= f.config.max_quaternion_norm_error)),
            "the stacked stream must hold only usable measurements")
    camera = [Camera(*(part[k] for part in cameras)) for k in range(N)]
    R, r, _ = f._stacked_noise(m)
    x_out = np.full((S, N, f.n), np.nan)
    variance_out = np.full((S, N), np.nan)
    last_out = np.full((S, N), -np.inf)
    started = np.zeros(N, dtype=bool)
    accepted = np.full(S, m)  # the start uses every marker of step 0
    gated, resets, streak = np.zeros(S, dtype=int), np.zeros(S, dtype=int), np.zeros(S, dtype=int)
    last = np.full(S, t[0])
    x, P = np.empty((S, f.n)), np.empty((S, f.n, f.n))
    for s in range(S):
        x[s], P[s] = _start(f, t[0], camera[0], p_CM[s, 0], q_CM[s, 0])
    for j in range(N - latency):
        if j > 0:  # the prior, predicted from step j - 1 below; now the update with the markers of t_j
            x, P, fused = _update(f, x, P, camera[j], p_CM[:, j], q_CM[:, j], R, r)
            accepted += fused
            gated += m - fused
            last = np.where(fused > 0, t[j], last)
            streak = np.where(fused == 0, streak + 1, 0)
            for s in np.flatnonzero(streak >= f.config.reset_after_rejected_steps):
                x[s], P[s] = _start(f, t[j], camera[j], p_CM[s, j], q_CM[s, j])
                streak[s], resets[s] = 0, resets[s] + 1
                accepted[s], gated[s], last[s] = accepted[s] + m, gated[s] - m, t[j]  # the restart used them
        x_k, P_k, prior = x, P, None
        for k in range(j + 1, j + latency + 1):  # to the step the measurements of t_j arrive in
            x_k, P_k = _predict(f, x_k, P_k, t[k] - t[k - 1])
            prior = prior or (x_k, P_k)
        k = j + latency
        x_out[:, k], variance_out[:, k], last_out[:, k], started[k] = x_k, _position_variance(P_k), last, True
        if j + 1 < N - latency:
            x, P = prior or _predict(f, x, P, t[j + 1] - t[j])
    stats = [FilterStats(int(a), int(g), 0, 0, int(n)) for a, g, n in zip(accepted, gated, resets)]
    return StackRecords(x_out, variance_out, last_out, started, stats)


def _start(f: MarkerFilter, time: float, camera: Camera, p_CM: np.ndarray, q_CM: np.ndarray):
    """(x, P) of the filter's start from every marker of one step (p_CM (m, 3), q_CM (m, 4))."""
    belief = f._start(time, [MarkerMeasurement(time, i, p, q) for i, p, q in zip(f.layout.ids, p_CM, q_CM)],
                      camera)
    return belief.x, belief.P


def _predict(f: MarkerFilter, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """`MarkerFilter.predict` on stacks: x (S, n), P (S, n, n) over dt [s]."""
    x_next, F = f.process_stack(x, dt)
    return x_next, F @ P @ np.swapaxes(F, -1, -2) + f.process_noise_stack(x, dt)


def _update(f: MarkerFilter, x, P, camera: Camera, p_CM, q_CM, R, r):
    """`MarkerFilter._update` on stacks (module docstring): (x, P, markers fused (S,))."""
    nu = f.innovations_stack(x, camera, p_CM, q_CM)  # (S, m, d)
    S, m, d = nu.shape
    H = np.broadcast_to(f.jacobian_stack(x, camera), (S, m * d, f.n))
    Ht = np.swapaxes(H, -1, -2)
    PHt = P @ Ht
    S_y = H @ PHt + R
    blocks = S_y.reshape(S, m, d, m, d)[:, np.arange(m), :, np.arange(m), :]  # (m, S, d, d)
    nu_blocks = np.swapaxes(nu, 0, 1)[..., None]  # (m, S, d, 1)
    nis = np.sum(nu_blocks * np.linalg.solve(blocks, nu_blocks), axis=(-2, -1)).T  # (S, m)
    keep = nis <= f._gate
    fused = keep.sum(axis=1)
    if not keep.all():
        rows = np.repeat(keep, d, axis=1)[..., None]  # (S, m d, 1)
        H = H * rows
        Ht = np.swapaxes(H, -1, -2)
        PHt = P @ Ht
        S_y = H @ PHt + R
        nu = nu * keep[..., None]
    K = np.swapaxes(np.linalg.solve(S_y, np.swapaxes(PHt, -1, -2)), -1, -2)  # (S, n, m d)
    x_new = f.normalized_stack(x + (K @ nu.reshape(S, m * d, 1))[..., 0])
    I_KH = np.eye(f.n) - K @ H
    P_new = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + (K * r) @ np.swapaxes(K, -1, -2)
    P_new = (P_new + np.swapaxes(P_new, -1, -2)) / 2
    any_fused = fused > 0
    return (np.where(any_fused[:, None], x_new, x), np.where(any_fused[:, None, None], P_new, P), fused)


def _position_variance(P: np.ndarray) -> np.ndarray:
    """trace of the covariance of p_WP = x[..., :3] [m^2], (S,)."""
    return P[:, 0, 0] + P[:, 1, 1] + P[:, 2, 2]
