"""The estimate that every pose estimator emits, so metrics, plots and fusion treat them alike."""

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.config import ConfigError


class RunningMean(NamedTuple):
    """A mean accumulated over frames: total of the weighted samples and the total weight."""

    total: np.ndarray | float = 0.0
    weight: float = 0.0

    def add(self, sample, weight: float = 1.0) -> "RunningMean":
        return RunningMean(self.total + weight * np.asarray(sample, dtype=float), self.weight + weight)

    @property
    def mean(self):
        """The mean, or None before the first sample."""
        return self.total / self.weight if self.weight > 0 else None


@dataclass(frozen=True)
class PoseEstimate:
    """A pose estimate of a target frame in a reference frame, both named by their monogram letters:
    `reference` "C" and `target` "T" make X_RT the tag in the camera, readable as `estimate.X_CT`.

    time: seconds of simulation time the estimate refers to.
    X_RT: the estimated pose; meaningful only when `valid` is True.
    valid: False when the estimator has no trustworthy estimate (none at all, or one it coasted too
      long to trust); X_RT is then identity or that untrusted estimate.
    covariance: 6x6 covariance of [roll, pitch, yaw (rad); x, y, z (m)], or None if unknown; any
      other shape is a ConfigError naming the frames.
    reference, target: the frames' names ("R" and "T" when not named).
    """

    time: float = 0.0
    X_RT: RigidTransform = field(default_factory=RigidTransform)
    valid: bool = False
    covariance: np.ndarray | None = None
    reference: str = "R"
    target: str = "T"

    def __post_init__(self):
        if self.covariance is not None and np.shape(self.covariance) != (6, 6):
            raise ConfigError(f"the {self.frames} estimate's covariance must be 6x6 ([roll, pitch, yaw; x, y, z]), "
                              f"got shape {np.shape(self.covariance)}")

    @property
    def frames(self) -> str:
        """The pose's monogram name: "X_" + reference + target, e.g. "X_WP"."""
        return f"X_{self.reference}{self.target}"

    def __getattr__(self, name: str):
        if not name.startswith("_") and name not in ("reference", "target") and name == self.frames:
            return self.X_RT
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    @staticmethod
    def invalid(time: float, reference: str = "R", target: str = "T") -> "PoseEstimate":
        return PoseEstimate(time=time, reference=reference, target=target)


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
