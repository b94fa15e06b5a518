"""The estimate that every pose estimator emits, so metrics, plots and fusion treat them alike."""

from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RigidTransform


@dataclass(frozen=True)
class PoseEstimate:
    """A pose estimate of a target frame T in a reference frame R (e.g. X_CT: tag in camera).

    time: seconds of simulation time the estimate refers to.
    X_RT: the estimated pose; meaningful only when `valid` is True.
    valid: False when the estimator could not produce an estimate (then X_RT is identity).
    covariance: 6x6 covariance of [roll, pitch, yaw (rad); x, y, z (m)], or None if unknown.
    """

    time: float = 0.0
    X_RT: RigidTransform = field(default_factory=RigidTransform)
    valid: bool = False
    covariance: np.ndarray | None = None

    @staticmethod
    def invalid(time: float) -> "PoseEstimate":
        return PoseEstimate(time=time)
