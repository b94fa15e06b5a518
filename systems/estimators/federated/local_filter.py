"""A local filter of seed 001's federated EKF (Sec. 4.2): the UAV's pose relative to the pattern,
predicted by the IMU and updated by one vision node.

The state is Eq. (4)'s pose of the body B in the pattern frame P, p_PB and R_PB, plus the velocity
v_PB (in P) that integrating the IMU's accelerations needs (Eq. 4 lists the pose alone). Error
state (9): [dp, dv, dtheta], dtheta a rotation vector in P (R = Exp(dtheta) R_nominal). Prediction
(strapdown, P level and still): R <- R Exp(w_B dt), a = R f_B + g_P, p <- p + v dt + a dt^2 / 2,
v <- v + a dt. Measurements: a full pose, as Eq. (5)'s Z (the adjustment and touchdown nodes'),
either of B in P or as the nodes give it, the pattern's pose in the camera (Eq. 2's R and t); or
the pattern's centre in the camera (the approaching node's rough position). Each is gated by its
innovation's chi-square quantile. Units: m, s, rad.
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from systems.config import require, require_positive
from systems.quaternion import skew


@dataclass
class LocalFilterConfig:
    """Process noise of the IMU prediction (ours: the IMU's densities plus what the model leaves out)
    and the initial uncertainty."""

    # (m/s^2)^2/Hz: the accelerometer's 6e-7 (Table 1's 80 ug/sqrt(Hz)) and what the model leaves out
    # (the pattern is taken to be still; a moving one's accelerations, the body's unmodelled motion).
    accel_noise_psd: float = 1e-3
    gyro_noise_psd: float = 3e-8  # (rad/s)^2/Hz: Table 1's 0.01 deg/s/sqrt(Hz), squared
    # v_PB at the start, horizontal: the pattern may ride a carrier (open-landing's moving variant: 1 m/s)
    initial_velocity_std_mps: float = 1.0
    # and vertical: the UAV starts in hover over a carrier on the ground. Not looser: from 20 m the
    # approaching node's heights scatter by 0.3 m, and a loose prior fits a climb to the first few
    # (1 m/s: 1.7 m/s estimated on a UAV sinking at 0.4 m/s, open-landing seed 4).
    initial_vertical_velocity_std_mps: float = 0.2
    # Roll and pitch from the first accelerometer sample, whose direction is the vertical while the UAV
    # hovers (a horizontal acceleration of 0.09 m/s^2 tilts it 0.5 deg). Not looser: the approaching
    # node's centre alone leaves the tilt and the horizontal position a 20 m lever arm apart, and a
    # loose prior lets its pixel errors tilt the filter (3 deg: the fused height RMSE of open-landing
    # 0.040 m instead of 0.025 m).
    initial_tilt_std_deg: float = 0.5
    # The heading of P before a full pose: the approaching node's centre cannot tell it, and nothing
    # the landing needs depends on it (a gauge: P is taken turned with the body; the first full pose
    # restarts the filter in the pattern's own frame, engine.py). Small, so that the filter stays linear.
    initial_yaw_std_deg: float = 1.0
    gate_probability: float = 0.9999

    def validate(self, prefix: str = "federated") -> None:
        for name in ("accel_noise_psd", "gyro_noise_psd", "initial_velocity_std_mps",
                     "initial_vertical_velocity_std_mps", "initial_tilt_std_deg", "initial_yaw_std_deg"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(0 < self.gate_probability < 1, f"{prefix}.gate_probability must be in (0, 1)")


@dataclass(frozen=True)
class LocalState:
    """The nominal state and the error covariance (9x9) of one local filter; `q_scale` is 1/beta,
    the share of the process noise it carries (fusion.py). Immutable."""

    p: np.ndarray  # p_PB [m]
    v: np.ndarray  # v_PB in P [m/s]
    R: np.ndarray  # R_PB
    P: np.ndarray  # covariance of [dp, dv, dtheta]
    q_scale: float = 1.0
    accepted: int = 0
    gated: int = 0
    stats: dict = field(default_factory=dict)


def exp_so3(theta: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(theta).as_matrix()


def log_so3(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


def initial_velocity_covariance(config: LocalFilterConfig) -> np.ndarray:
    """(3x3) of v_PB at the start, in P (z up) [m^2/s^2]."""
    return np.diag([config.initial_velocity_std_mps**2, config.initial_velocity_std_mps**2,
                    config.initial_vertical_velocity_std_mps**2])


def initial_state(p_BP_B: np.ndarray, covariance_B: np.ndarray, f_B: np.ndarray,
                  config: LocalFilterConfig) -> LocalState:
    """The state from a first position of the pattern seen from the body (p_BP_B, m, in B; its
    covariance `covariance_B`, 3x3, m^2, in B) and the accelerometer's specific force f_B (its direction is up): roll
    and pitch level the body with it, the heading 0 with `initial_yaw_std_deg`. The position
    p = -R p_BP_B turns with the attitude, dp = -[p]x dtheta: the covariance says so, so that the
    relative position (what the landing needs) is as certain as measured whatever the heading."""
    up_B = np.asarray(f_B, dtype=float) / np.linalg.norm(f_B)
    R = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up_B])[0].as_matrix()  # R_PB: up_B -> z_P
    p = -R @ np.asarray(p_BP_B, dtype=float)
    tilt, yaw = np.radians(config.initial_tilt_std_deg), np.radians(config.initial_yaw_std_deg)
    P_theta = np.diag([tilt**2, tilt**2, yaw**2])
    S = skew(p)
    P = np.zeros((9, 9))
    P[0:3, 0:3] = R @ np.asarray(covariance_B) @ R.T + S @ P_theta @ S.T
    P[0:3, 6:9] = -S @ P_theta
    P[6:9, 0:3] = P[0:3, 6:9].T
    P[3:6, 3:6] = initial_velocity_covariance(config)
    P[6:9, 6:9] = P_theta
    return LocalState(p, np.zeros(3), R, P)


def predict(state: LocalState, f_B: np.ndarray, w_B: np.ndarray, dt: float, config: LocalFilterConfig,
            gravity_m_s2: float) -> LocalState:
    """One IMU step of dt seconds with specific force f_B [m/s^2] and angular velocity w_B [rad/s]."""
    R = state.R
    a = R @ f_B - [0.0, 0.0, gravity_m_s2]
    F = np.eye(9)
    F[0:3, 3:6] = dt * np.eye(3)
    F[3:6, 6:9] = -dt * skew(R @ f_B)  # d(a)/d(dtheta): Exp(dtheta) R f = R f + dtheta x R f
    F[0:3, 6:9] = -dt**2 / 2 * skew(R @ f_B)  # the same through p's a dt^2 / 2
    q_a, q_w = config.accel_noise_psd * state.q_scale, config.gyro_noise_psd * state.q_scale
    Q = np.zeros((9, 9))
    Q[0:3, 0:3] = q_a * dt**3 / 3 * np.eye(3)
    Q[0:3, 3:6] = Q[3:6, 0:3] = q_a * dt**2 / 2 * np.eye(3)
    Q[3:6, 3:6] = q_a * dt * np.eye(3)
    Q[6:9, 6:9] = q_w * dt * np.eye(3)
    P = F @ state.P @ F.T + Q
    return replace(state, p=state.p + state.v * dt + a * dt**2 / 2, v=state.v + a * dt, R=R @ exp_so3(w_B * dt),
                   P=(P + P.T) / 2)


def _update(state: LocalState, innovation: np.ndarray, H: np.ndarray, noise: np.ndarray,
            config: LocalFilterConfig) -> LocalState:
    S = H @ state.P @ H.T + noise
    nis = float(innovation @ np.linalg.solve(S, innovation))
    if not np.isfinite(nis) or nis > chi2.ppf(config.gate_probability, len(innovation)):
        return replace(state, gated=state.gated + 1)
    K = np.linalg.solve(S, H @ state.P).T
    dx = K @ innovation
    I_KH = np.eye(9) - K @ H
    P = I_KH @ state.P @ I_KH.T + K @ noise @ K.T  # Joseph form
    return replace(state, p=state.p + dx[0:3], v=state.v + dx[3:6], R=exp_so3(dx[6:9]) @ state.R, P=(P + P.T) / 2,
                   accepted=state.accepted + 1)


def update_pose(state: LocalState, p_PB: np.ndarray, R_PB: np.ndarray, covariance: np.ndarray,
                config: LocalFilterConfig) -> LocalState:
    """A full pose of B in P; covariance (6x6) over [dtheta (in P), dp]."""
    innovation = np.r_[np.asarray(p_PB) - state.p, log_so3(R_PB @ state.R.T)]
    H = np.zeros((6, 9))
    H[0:3, 0:3] = np.eye(3)
    H[3:6, 6:9] = np.eye(3)
    return _update(state, innovation, H, position_first(covariance), config)


def update_pattern_in_camera(state: LocalState, p_CP: np.ndarray, R_CP: np.ndarray, covariance: np.ndarray,
                             R_BC: np.ndarray, p_BC: np.ndarray, config: LocalFilterConfig) -> LocalState:
    """The pattern's pose seen from the camera, Eq. (2)'s t and R (p_CP, R_CP; covariance 6x6 over
    [dtheta (in C), dp (in C)]), the camera at (R_BC, p_BC) in B: h = (R_BC^T (R_PB^T (-p_PB) - p_BC),
    R_BC^T R_PB^T). Far off, a pose errs mostly along the orbit about the pattern, which moves R_CP
    and leaves p_CP: in these coordinates that error is linear, where in p_PB it drops the height by
    the orbit's squared angle (tests/test_federated_filter.py)."""
    predicted, H_centre = _centre_in_camera(state, R_BC, p_BC)
    R_CP_predicted = R_BC.T @ state.R.T
    innovation = np.r_[np.asarray(p_CP) - predicted, log_so3(np.asarray(R_CP) @ R_CP_predicted.T)]
    H = np.zeros((6, 9))
    H[0:3] = H_centre
    H[3:6, 6:9] = -R_CP_predicted  # R_BC^T R^T Exp(-dtheta) = Exp(-R_CP dtheta) R_CP
    return _update(state, innovation, H, position_first(covariance), config)


def update_centre_in_camera(state: LocalState, p_CP: np.ndarray, covariance: np.ndarray, R_BC: np.ndarray,
                            p_BC: np.ndarray, config: LocalFilterConfig) -> LocalState:
    """The pattern's centre seen from the camera (p_CP in C, m; covariance 3x3), the camera at (R_BC,
    p_BC) in B: h = R_BC^T (R_PB^T (-p_PB) - p_BC)."""
    predicted, H = _centre_in_camera(state, R_BC, p_BC)
    return _update(state, np.asarray(p_CP) - predicted, H, np.asarray(covariance), config)


def centre_in_body(state: LocalState) -> tuple[np.ndarray, np.ndarray]:
    """The pattern's centre seen from the body that the state predicts, p_BP_B = R_PB^T (-p_PB) (m, in B),
    and its Jacobian over the error state (3x9)."""
    R_BP = state.R.T
    H = np.zeros((3, 9))
    H[:, 0:3] = -R_BP
    H[:, 6:9] = -R_BP @ skew(state.p)  # R_PB^T = R^T Exp(-dtheta): d/d(dtheta) of -R^T (p - dtheta x p)
    return R_BP @ (-state.p), H


def _centre_in_camera(state: LocalState, R_BC: np.ndarray, p_BC: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pattern's centre in the camera that the state predicts, R_BC^T (p_BP_B - p_BC) (m), and its
    Jacobian over the error state (3x9)."""
    p_BP_B, H = centre_in_body(state)
    return R_BC.T @ (p_BP_B - p_BC), R_BC.T @ H


def position_first(covariance: np.ndarray) -> np.ndarray:
    """A pose's covariance over [dtheta, dp] reordered to the error state's [dp, dtheta]."""
    order = [3, 4, 5, 0, 1, 2]
    return np.asarray(covariance)[np.ix_(order, order)]
