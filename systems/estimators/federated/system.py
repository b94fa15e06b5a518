"""`FederatedFilterSystem`: seed 001's federated EKF (engine.py) stepped in a Drake diagram."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require
from systems.estimators.estimate import PoseEstimate
from systems.estimators.federated.engine import (
    NODES,
    X_PB,
    FederatedConfig,
    FederatedState,
    is_valid,
    relative_jacobian,
    relative_std_m,
    step,
)
from systems.estimators.federated.fusion import POSITION
from systems.estimators.federated.local_filter import log_so3
from systems.perception.rqrlp.node_systems import first
from systems.stepped import SteppedValue, is_step_time

# `federated_vector`, for logs: the fused estimate, its validity, the betas and every local filter.
FED_VALID = 0
FED_P_PB = slice(1, 4)  # m, in P
FED_Q_PB = slice(4, 8)  # wxyz
FED_V_PB = slice(8, 11)  # m/s, in P
FED_RELATIVE_STD = 11  # m: sqrt(trace) of p_BP_B's covariance
FED_BETAS = slice(12, 15)  # Eq. (9), in NODES' order
FED_LOCAL_TRACES = slice(15, 18)  # trace of each local filter's position covariance after its update [m^2]
FED_LOCAL_P = slice(18, 27)  # each local filter's p_PB after its update (3 per node)
FED_LOCAL_THETA = slice(27, 36)  # each one's R_PB as a rotation vector (3 per node)
FED_STARTED = 36
FEDERATED_VECTOR_SIZE = 37


def federated_vector(state: FederatedState, valid: bool) -> np.ndarray:
    """The FED_* layout (NaN where there is nothing yet)."""
    out = np.full(FEDERATED_VECTOR_SIZE, np.nan)
    out[FED_VALID], out[FED_STARTED] = float(valid), float(state.started)
    if not state.started:
        return out
    fused = state.fused
    out[FED_P_PB], out[FED_V_PB] = fused.p, fused.v
    out[FED_Q_PB] = RotationMatrix.ProjectToRotationMatrix(fused.R).ToQuaternion().wxyz()
    out[FED_RELATIVE_STD] = relative_std_m(fused)
    out[FED_BETAS] = state.betas
    if state.local_estimates:
        out[FED_LOCAL_TRACES] = [np.trace(s.P[POSITION, POSITION]) for s in state.local_estimates]
        out[FED_LOCAL_P] = np.concatenate([s.p for s in state.local_estimates])
        out[FED_LOCAL_THETA] = np.concatenate([log_so3(s.R) for s in state.local_estimates])
    return out


def with_heading_gauge(covariance: np.ndarray, p: np.ndarray, z_P: np.ndarray) -> np.ndarray:
    """`covariance` (6x6 over [dtheta (rad); dp (m)], in a frame F) with the pattern's heading unknown:
    a turn psi of P about its own z axis (z_P, a unit vector in F) at its origin turns the attitude by
    z_P psi and moves a point at p (m, in F, from P's origin) by z_P x p psi, so the covariance gains
    pi^2 g g^T with g = [z_P; z_P x p]."""
    g = np.concatenate([z_P, np.cross(z_P, p)])
    return covariance + np.pi**2 * np.outer(g, g)


def require_camera_steps(config: FederatedConfig, imu_period_s: float, camera_period_s: float,
                         prefix: str = "federated") -> None:
    """The filter steps with the IMU and reads a frame every few steps: the camera's period [s] a whole
    number of IMU periods, and config.max_coast_s over it (at or below it every frame restarts the local
    filters); else ConfigError naming `{prefix}.camera.rate_hz` or `{prefix}.filter.max_coast_s`."""
    ratio = camera_period_s / imu_period_s
    require(abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1,
            f"{prefix}.camera.rate_hz ({1 / camera_period_s:g}) must divide {prefix}.imu.rate_hz "
            f"({1 / imu_period_s:g}): the filter reads a frame every few IMU samples")
    require(config.max_coast_s > camera_period_s,
            f"{prefix}.filter.max_coast_s ({config.max_coast_s:g} s) must exceed the camera's period "
            f"({camera_period_s:g} s): at or below it every frame restarts the local filters")


class FederatedFilterSystem(LeafSystem):
    """The federated filter stepped at the IMU's rate, its nodes read at the camera's.

    Inputs: `imu` (6: f_B m/s^2, w_B rad/s, systems/sensors/imu.py), one input per node in NODES
    (`approach`, `adjustment`, `touchdown`: a list of 0 or 1 NodeMeasurement,
    systems/perception/rqrlp/node_systems.py), and the UAV's own navigation `X_WB` (RigidTransform) and
    `V_WB` (6, [w; v] in W) that put the pattern in the world.
    Outputs at t, with the step at t included (systems/stepped.py):
    `X_PB_estimate` (PoseEstimate of B in P, covariance [dtheta; dp] in P, with the heading's pi^2 and the
    horizontal position it turns before the first full pose), `X_WP_estimate` (PoseEstimate of the
    pattern in W: X_WB X_PB^-1, its position covariance the relative position's, its heading's pi^2 about
    P's z before the first full pose, valid by engine.is_valid), `v_WP_estimate` (3, m/s in W: the
    pattern's velocity, v_WB minus the body's velocity relative to P) and `federated_vector` (FED_* layout).
    """

    def __init__(self, config: FederatedConfig, X_BC: RigidTransform, imu_period_s: float, camera_period_s: float):
        super().__init__()
        config.validate()
        require_camera_steps(config, imu_period_s, camera_period_s)
        self._config, self._X_BC, self._camera_period = config, X_BC, camera_period_s
        self._imu = self.DeclareVectorInputPort("imu", 6)
        self._nodes = {node: self.DeclareAbstractInputPort(node, AbstractValue.Make([])) for node in NODES}
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._V_WB = self.DeclareVectorInputPort("V_WB", 6)
        self._now = SteppedValue(self, "federated", FederatedState(), imu_period_s, self._step, lambda s: s.time).now
        now = {self._now.ticket()}
        self.DeclareAbstractOutputPort("X_PB_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._X_PB(c)), now)
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._X_WP(c)), {self.all_input_ports_ticket(),
                                                                                  self._now.ticket()})
        self.DeclareVectorOutputPort("v_WP_estimate", 3, self._v_WP)
        self.DeclareVectorOutputPort("federated_vector", FEDERATED_VECTOR_SIZE, lambda c, o: o.SetFromVector(
            federated_vector(self._now.Eval(c), is_valid(self._now.Eval(c), self._config))), now)

    def _step(self, context, state: FederatedState) -> FederatedState:
        t = context.get_time()
        measurements = ({node: first(port.Eval(context)) for node, port in self._nodes.items()}
                        if is_step_time(t, self._camera_period) else None)
        return step(state, t, self._imu.Eval(context), measurements, self._config, self._X_BC)

    def _X_PB(self, context) -> PoseEstimate:
        state = self._now.Eval(context)
        if not state.started:
            return PoseEstimate.invalid(context.get_time(), "P", "B")
        P = state.fused.P
        covariance = np.block([[P[6:9, 6:9], P[6:9, 0:3]], [P[0:3, 6:9], P[0:3, 0:3]]])
        if not state.heading_known:  # P's heading is a gauge until a full pose (engine.py): it turns p_PB too
            covariance = with_heading_gauge(covariance, state.fused.p, np.array([0.0, 0.0, 1.0]))
        return PoseEstimate(context.get_time(), X_PB(state.fused), is_valid(state, self._config), covariance, "P", "B")

    def _X_WP(self, context) -> PoseEstimate:
        """X_WP = X_WB X_BP; covariance: the attitude's and the relative position's, in W."""
        state = self._now.Eval(context)
        if not state.started:
            return PoseEstimate.invalid(context.get_time(), "W", "P")
        X_WB = self._X_WB.Eval(context)
        X_WP = X_WB.multiply(X_PB(state.fused).inverse())
        R_WB, R_WP = X_WB.rotation().matrix(), X_WP.rotation().matrix()
        J = np.zeros((6, 9))
        J[0:3, 6:9] = -R_WP  # R_WP = R_WB R_PB^T: an attitude error dtheta (in P) turns it by -R_WP dtheta in W
        J[3:6] = R_WB @ relative_jacobian(state.fused)
        covariance = J @ state.fused.P @ J.T
        if not state.heading_known:  # the pattern's heading is a gauge until a full pose (engine.py)
            covariance = with_heading_gauge(covariance, np.zeros(3), R_WP[:, 2])  # P turns about p_WP: it stays
        return PoseEstimate(context.get_time(), X_WP, is_valid(state, self._config), (covariance + covariance.T) / 2,
                            "W", "P")

    def _v_WP(self, context, output):
        """v_WP = v_WB - R_WP v_PB (P level and not turning: the pattern translates)."""
        state = self._now.Eval(context)
        if not state.started:
            output.SetFromVector(np.zeros(3))
            return
        X_WP = self._X_WB.Eval(context).multiply(X_PB(state.fused).inverse())
        output.SetFromVector(self._V_WB.Eval(context)[3:] - X_WP.rotation().matrix() @ state.fused.v)
