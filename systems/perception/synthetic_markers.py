"""Seed 002's synthetic marker measurements (Sec. 4): every marker's true pose in the camera frame
plus zero-mean Gaussian noise, 0.1 m on each position axis and 5 deg on each axis of a rotation
vector that perturbs the attitude (the paper's "+-5 deg for q^{i/C}").

The noise of sample k comes from systems.noise.sample_rng(seed, STREAM, k): a pure function of the
scenario's seed and the sample, so a run repeats bit for bit, and `synthetic_marker_sample` (used by
the system here and by diagrams/marker_batch.py) gives the same stream wherever it is called.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.noise import sample_index, sample_rng
from systems.perception.markers import MarkerLayout, MarkerMeasurement
from systems.quaternion import drake_to_paper, odot_matrix

STREAM = "marker_measurements"


def noisy_marker_poses(p_CM: np.ndarray, q_CP: np.ndarray, dp: np.ndarray,
                       dtheta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The measured poses from the true ones, over any leading shape (...): marker centres p_CM
    (..., n, 3) [m] and the pad's attitude q_CP (..., 4, the paper's scalar-last q^{P/C}), plus
    position noise dp (..., n, 3) [m] and attitude noise dtheta (..., n, 3) [rad], a rotation vector in
    the marker frame: (p_CM + dp, q^{M/C} (..., n, 4)) with R_CM = R_CP Exp(dtheta)."""
    angle = np.linalg.norm(dtheta, axis=-1, keepdims=True)
    # [sin(a/2) axis, cos(a/2)]
    dq = np.concatenate([np.sinc(angle / (2 * np.pi)) * dtheta / 2, np.cos(angle / 2)], axis=-1)
    return p_CM + dp, np.einsum("...ij,...mj->...mi", odot_matrix(q_CP) if q_CP.ndim == 1 else
                                np.array([odot_matrix(q) for q in q_CP]), dq)  # q_CP (.) dq


def draw_noise(rng: np.random.Generator, n: int, sigma_p: float, sigma_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(dp (n, 3) [m], dtheta (n, 3) [rad]) of one sample: positions first, then angles."""
    return rng.normal(0.0, sigma_p, (n, 3)), rng.normal(0.0, np.radians(sigma_deg), (n, 3))


def synthetic_marker_measurements(X_CP: RigidTransform, layout: MarkerLayout, rng: np.random.Generator,
                                  sigma_p: float = 0.1, sigma_deg: float = 5.0,
                                  time: float = 0.0) -> list[MarkerMeasurement]:
    """Every marker's true pose in C (from the pad pose X_CP) plus noise drawn from `rng`
    (`noisy_marker_poses`, `draw_noise`), stamped `time` [s]."""
    p_CM, q_CM = noisy_marker_poses(X_CP.multiply(layout.p_PM.T).T, drake_to_paper(X_CP.rotation()),
                                    *draw_noise(rng, len(layout.ids), sigma_p, sigma_deg))
    return [MarkerMeasurement(time, marker_id, p, q) for marker_id, p, q in zip(layout.ids, p_CM, q_CM)]


def synthetic_marker_sample(time: float, X_WB: RigidTransform, X_WP: RigidTransform, X_BC: RigidTransform,
                            layout: MarkerLayout, seed: int, period_s: float, sigma_p: float,
                            sigma_deg: float) -> list[MarkerMeasurement]:
    """The measurements acquired at `time` [s] (a sample time k period_s) by a camera at X_BC on
    the UAV body at X_WB, of the pad at X_WP, with the noise of sample k under `seed`."""
    X_CP = X_WB.multiply(X_BC).InvertAndCompose(X_WP)
    rng = sample_rng(seed, STREAM, sample_index(time, period_s))
    return synthetic_marker_measurements(X_CP, layout, rng, sigma_p, sigma_deg, time)


class SyntheticMarkerSource(LeafSystem):
    """The paper's measurement source as a system. Inputs `X_WB` (RigidTransform, the UAV body) and
    `X_WP` (RigidTransform, the pad); output `marker_measurements` (list of MarkerMeasurement):
    `synthetic_marker_sample` at the context's time. Evaluate it at the sample times (the latency
    system does, in its periodic update)."""

    def __init__(self, layout: MarkerLayout, X_BC: RigidTransform, period_s: float = 0.035, seed: int = 0,
                 sigma_p: float = 0.1, sigma_deg: float = 5.0):
        super().__init__()
        layout.validate()
        require_positive(period_s, "period_s")
        require(sigma_p >= 0 and sigma_deg >= 0, "marker measurement noise must not be negative")
        self._settings = X_BC, layout, seed, period_s, sigma_p, sigma_deg
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._X_WP = self.DeclareAbstractInputPort("X_WP", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractOutputPort("marker_measurements", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        output.set_value(synthetic_marker_sample(context.get_time(), self._X_WB.Eval(context),
                                                 self._X_WP.Eval(context), *self._settings))
