"""The perception seam: the one vector the landing controller reads, and the adapter that makes it
from any pose estimator's output.

The seam (`relative_state`, RELATIVE_STATE_SIZE) is the landing target as the UAV believes it, in
SI units, World W z up: the pad centre P relative to the UAV body origin B in W and in B, the pad's
velocity and acceleration in W, the UAV's height above the pad's top surface, and a valid flag.
A perception source is any system with that output; `SeamSplit` cuts it into the named ports that
`TrackingPid` and `LandingSupervisor` read. The truth's source is
systems/perception/truth.py; every estimator reaches the seam through `EstimateToSeam`.

Validity is the estimator's own: its `PoseEstimate.valid`, its covariance (position standard
deviation within `SeamConfig.max_position_std_m`) and its age (context time minus the estimate's
time, within `max_age_s`); never the truth. A predicting filter (the marker EKFs, the federated
filter) stamps its estimate with the time it is predicted to, so the age guards a held or late
estimate, not how long a filter has coasted: a coasting marker filter turns invalid by its position
covariance (MarkerEkfConfig.max_valid_position_std_m). An invalid seam still carries the
estimate's finite numbers (zeros where it has none), never NaN.
"""

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import Demultiplexer

from systems.config import ConfigError, require_positive
from systems.estimators.estimate import PoseEstimate

P_BP_W = slice(0, 3)  # pad centre minus UAV (body origin), in W [m]
P_BP_B = slice(3, 6)  # the same, in the UAV body frame B [m]
V_WP = slice(6, 9)  # velocity of the pad centre in W [m/s]
HEIGHT = 9  # UAV above the pad's top surface [m]
VALID = 10  # 1 when the estimate may be steered on, else 0
A_WP = slice(11, 14)  # acceleration of the pad centre in W [m/s^2]
RELATIVE_STATE_SIZE = 14
FUTURE_TOLERANCE_S = 1e-9  # an estimate stamped later than the context's time by more is invalid
NEGATIVE_VARIANCE_TOLERANCE_M2 = 1e-12  # round-off in a filter's covariance; a variance more negative is invalid


@dataclass
class SeamConfig:
    """When an estimate is valid enough to steer on (not from the papers)."""

    max_position_std_m: float = 1.0  # sqrt(trace) of the estimate's position covariance
    max_age_s: float = 0.5  # context time minus the estimate's time

    def validate(self, prefix: str = "perception") -> None:
        require_positive(self.max_position_std_m, f"{prefix}.max_position_std_m")
        require_positive(self.max_age_s, f"{prefix}.max_age_s")


def estimate_is_valid(estimate: PoseEstimate, time: float, config: SeamConfig) -> bool:
    """The estimate's own flag, a finite pose, its position std (when it has a covariance) within
    config.max_position_std_m, and no older than config.max_age_s at `time` [s] nor stamped after it.
    A position variance below -NEGATIVE_VARIANCE_TOLERANCE_M2 (a diverged filter's P) is not a std at all:
    invalid, not the most certain estimate there is."""
    if not estimate.valid or not math.isfinite(estimate.time):
        return False
    if time - estimate.time > config.max_age_s or estimate.time > time + FUTURE_TOLERANCE_S:
        return False
    if not np.all(np.isfinite(estimate.X_RT.GetAsMatrix34())):
        return False
    if estimate.covariance is not None:
        variances = np.diag(np.asarray(estimate.covariance)[3:, 3:])
        if not np.all(np.isfinite(variances)) or np.any(variances < -NEGATIVE_VARIANCE_TOLERANCE_M2):
            return False
        if math.sqrt(max(float(variances.sum()), 0.0)) > config.max_position_std_m:
            return False
    return True


def seam_vector(X_WB: RigidTransform, p_WP: np.ndarray, v_WP: np.ndarray, a_WP: np.ndarray,
                valid: bool) -> np.ndarray:
    """The seam from the UAV's pose X_WB and the pad's position p_WP [m], velocity v_WP [m/s] and
    acceleration a_WP [m/s^2] in W; non-finite entries become 0 and make it invalid."""
    p_BP_W = np.asarray(p_WP, dtype=float) - X_WB.translation()
    values = np.zeros(RELATIVE_STATE_SIZE)
    values[P_BP_W] = p_BP_W
    values[P_BP_B] = X_WB.rotation().inverse().multiply(p_BP_W)
    values[V_WP] = v_WP
    values[HEIGHT] = -p_BP_W[2]
    values[A_WP] = a_WP
    finite = np.isfinite(values)
    values[~finite] = 0.0
    values[VALID] = 1.0 if valid and finite.all() else 0.0
    return values


class EstimateToSeam(LeafSystem):
    """The adapter from a pad estimate to the seam.

    Inputs: `X_WB` (RigidTransform, the UAV's own pose: its navigation), `X_WP_estimate`
    (PoseEstimate of the pad frame P in W, its frames named "W" and "P": a valid estimate of any other
    pose is a ConfigError), and optionally `v_WP_estimate` and `a_WP_estimate` (3
    each, W, m/s and m/s^2; zero when not connected). Output `relative_state` (RELATIVE_STATE_SIZE),
    valid by `estimate_is_valid`.
    """

    def __init__(self, config: SeamConfig | None = None):
        super().__init__()
        self._config = config or SeamConfig()
        self._config.validate()
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._estimate = self.DeclareAbstractInputPort("X_WP_estimate", AbstractValue.Make(PoseEstimate()))
        self._v_WP = self.DeclareVectorInputPort("v_WP_estimate", 3)
        self._a_WP = self.DeclareVectorInputPort("a_WP_estimate", 3)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _rate(self, port, context) -> np.ndarray:
        return port.Eval(context) if port.HasValue(context) else np.zeros(3)

    def _calc(self, context, output):
        estimate = self._estimate.Eval(context)
        if estimate.valid and estimate.frames != "X_WP":
            raise ConfigError(f"the perception seam needs an estimate of the pad in the world, X_WP; "
                              f"it got {estimate.frames}")
        valid = estimate_is_valid(estimate, context.get_time(), self._config)
        output.SetFromVector(seam_vector(self._X_WB.Eval(context), estimate.X_RT.translation(),
                                         self._rate(self._v_WP, context), self._rate(self._a_WP, context), valid))


class SeamSplit(Diagram):
    """The seam cut into the ports the controller reads (a C++ demultiplexer, no Python per step).

    Input `relative_state`. Outputs: `target_offset` (2, pad minus UAV, World x-y, m),
    `target_velocity` (2, m/s), `target_acceleration` (2, m/s^2), `height_above_target` (1, m),
    `target_valid` (1), `p_BP_W` (3), `p_BP_B` (3)."""

    def __init__(self):
        super().__init__()
        builder = DiagramBuilder()
        # RELATIVE_STATE_SIZE in pieces: p_BP_W xy, z, p_BP_B, v_WP xy, z, height, valid, a_WP xy, z.
        split = builder.AddNamedSystem("split", Demultiplexer([2, 1, 3, 2, 1, 1, 1, 2, 1]))
        in_w = builder.AddNamedSystem("in_world", Demultiplexer([3, RELATIVE_STATE_SIZE - 3]))
        builder.ExportInput(split.get_input_port(), "relative_state")
        builder.ConnectInput("relative_state", in_w.get_input_port())
        for index, name in ((0, "target_offset"), (2, "p_BP_B"), (3, "target_velocity"), (5, "height_above_target"),
                            (6, "target_valid"), (7, "target_acceleration")):
            builder.ExportOutput(split.get_output_port(index), name)
        builder.ExportOutput(in_w.get_output_port(0), "p_BP_W")
        builder.BuildInto(self)
        self.set_name("seam")
