"""The estimate that every pose estimator emits, so metrics, plots and fusion treat them alike."""

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem


@dataclass(frozen=True)
class PoseEstimate:
    """A pose estimate of a target frame T in a reference frame R (e.g. X_CT: tag in camera).

    time: seconds of simulation time the estimate refers to.
    X_RT: the estimated pose; meaningful only when `valid` is True.
    valid: False when the estimator has no trustworthy estimate (none at all, or one it coasted too
      long to trust); X_RT is then identity or that untrusted estimate.
    covariance: 6x6 covariance of [roll, pitch, yaw (rad); x, y, z (m)], or None if unknown.
    """

    time: float = 0.0
    X_RT: RigidTransform = field(default_factory=RigidTransform)
    valid: bool = False
    covariance: np.ndarray | None = None

    @staticmethod
    def invalid(time: float) -> "PoseEstimate":
        return PoseEstimate(time=time)


def estimate_vector(estimate: PoseEstimate) -> np.ndarray:
    """[valid, x, y, z, qw, qx, qy, qz] for logging; NaN pose entries when not valid."""
    if not estimate.valid:
        return np.concatenate([[0.0], np.full(7, np.nan)])
    return np.concatenate([[1.0], estimate.X_RT.translation(), estimate.X_RT.rotation().ToQuaternion().wxyz()])


class PoseEstimateToVector(LeafSystem):
    """Input `estimate` (PoseEstimate); output `estimate_vector` (see `estimate_vector`), for
    Drake's vector loggers."""

    def __init__(self):
        super().__init__()
        self.DeclareAbstractInputPort("estimate", AbstractValue.Make(PoseEstimate()))
        self.DeclareVectorOutputPort("estimate_vector", 8,
                                     lambda c, o: o.SetFromVector(estimate_vector(self.get_input_port().Eval(c))))
