"""The coordinated-turn marker EKF: `ConstantTurnEkf` ("ct_ekf").

The paper's filter degrades with speed (its Sec. 4 and 5): its model says every marker moves in a
straight line at constant velocity, but the vehicle turns, so the error in each 35 ms prediction is
the centripetal acceleration v^2 kappa (3.5 m/s^2 at 12 m/s on Eq. 13's path against 0.2 m/s^2 at
3 m/s) and the filter lags on every bend. This filter models the pad as the rigid body it is,
turning at a constant rate (the coordinated-turn model, Bar-Shalom et al. [10]): state [p_WP (3),
v_WP (3), yaw psi, yaw rate omega], the horizontal velocity rotating at omega (exact for any point
of a car in a steady turn, wherever the pad sits on it), the pad level; each marker is
p_WP + R_z(psi) p_PM_i with the layout's known offsets, so all five markers and their attitudes
inform one 8-state pose. The attitude innovation is the rotation vector of q_meas (x) q_pred^-1
(both W-relative, Eq. 5).
"""

import math

import numpy as np

from systems.estimators.marker_ekf.engine import MarkerFilter, cv_noise
from systems.geometry import wrap_angle
from systems.quaternion import dcm, inverse, odot_matrix, rotation_vector


def _rot_z(psi) -> np.ndarray:
    """R_z(psi), a rotation by psi [rad] about z: (3, 3), or (..., 3, 3) for angles (...)."""
    if isinstance(psi, float):  # a Python float or a numpy float64
        c, s = math.cos(psi), math.sin(psi)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    c, s = np.cos(psi), np.sin(psi)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.moveaxis(np.array([[c, -s, zero], [s, c, zero], [zero, zero, one]]), (0, 1), (-2, -1))


def _yaw_quaternion(psi) -> np.ndarray:
    """q^{P/R} of a level pad yawed by psi [rad] about W's z: (4,), or (..., 4) for angles (...)."""
    if isinstance(psi, float):  # a Python float or a numpy float64
        return np.array([0.0, 0.0, math.sin(psi / 2), math.cos(psi / 2)])
    zero = np.zeros_like(psi)
    return np.stack([zero, zero, np.sin(psi / 2), np.cos(psi / 2)], axis=-1)


def _turn_terms(theta: float) -> tuple[float, float, float, float]:
    """sin(th)/th, (1 - cos(th))/th and their derivatives in th, with series near th = 0."""
    if abs(theta) < 1e-4:
        return 1 - theta**2 / 6, theta / 2 - theta**3 / 24, -theta / 3, 0.5 - theta**2 / 8
    s, c = math.sin(theta), math.cos(theta)
    return s / theta, (1 - c) / theta, (theta * c - s) / theta**2, (theta * s - (1 - c)) / theta**2


def _turn_terms_stack(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_turn_terms` of angles theta (S,) [rad]."""
    small = np.abs(theta) < 1e-4
    th = np.where(small, 1.0, theta)
    s, c = np.sin(th), np.cos(th)
    return (np.where(small, 1 - theta**2 / 6, s / th), np.where(small, theta / 2 - theta**3 / 24, (1 - c) / th),
            np.where(small, -theta / 3, (th * c - s) / th**2),
            np.where(small, 0.5 - theta**2 / 8, (th * s - (1 - c)) / th**2))


class ConstantTurnEkf(MarkerFilter):
    """The coordinated-turn EKF (module docstring). State x (8): [p_WP (3, m), v_WP (3, m/s), psi
    (rad), omega (rad/s)]: the pad frame's origin (marker 0) and velocity in W, its yaw and yaw rate."""

    name = "ct_ekf"
    n = 8
    rows = 6  # p_CM (3), attitude rotation vector (3)
    gate_dof = rows
    attitude_axes = ("yaw",)  # the pad level by assumption
    PSI, OMEGA = 6, 7

    def marker_noise(self, sigma_p, sigma_q):
        return np.diag(np.r_[np.full(3, sigma_p**2), np.full(3, sigma_q**2)])

    def initial_state(self, slots, p_WM, q_MR):
        c = self.config
        R = np.array([dcm(q).T for q in q_MR])  # R_WM of each marker
        psi = np.arctan2(np.sum(R[:, 1, 0]), np.sum(R[:, 0, 0]))  # mean heading
        p = np.mean(p_WM - self.p_PM[slots] @ _rot_z(psi).T, axis=0)
        x = np.r_[p, 0.0, 0.0, 0.0, psi, 0.0]
        return x, np.diag(np.r_[np.full(3, c.position_std_m**2), np.full(3, c.initial_velocity_std_mps**2),
                                self._sigma_q**2, c.initial_angular_velocity_std_radps**2])

    def process(self, x, dt):
        """Exact coordinated turn over dt: the horizontal velocity turns by omega dt, the position
        follows the arc, p_xy += dt [[f1, -f2], [f2, f1]] v_xy with f1 = sin(omega dt)/(omega dt),
        f2 = (1 - cos(omega dt))/(omega dt); z at constant velocity; psi += omega dt; omega constant."""
        _, _, _, vx, vy, vz, _, omega = x.tolist()
        f1, f2, d1, d2 = _turn_terms(omega * dt)
        c, s = math.cos(omega * dt), math.sin(omega * dt)
        a, b = dt * f1, dt * f2
        f = x.copy()
        f[0] += a * vx - b * vy
        f[1] += b * vx + a * vy
        f[2] += dt * vz
        f[3], f[4] = c * vx - s * vy, s * vx + c * vy
        f[self.PSI] += omega * dt
        F = np.eye(8)
        F[0, 3], F[0, 4], F[1, 3], F[1, 4] = a, -b, b, a
        F[0, 7], F[1, 7] = dt * dt * (d1 * vx - d2 * vy), dt * dt * (d2 * vx + d1 * vy)
        F[3, 3], F[3, 4], F[4, 3], F[4, 4] = c, -s, s, c
        F[3, 7], F[4, 7] = -dt * (s * vx + c * vy), dt * (c * vx - s * vy)
        F[2, 5] = F[self.PSI, self.OMEGA] = dt
        return f, F

    def process_noise(self, x, dt):
        return self.constants(dt)

    def constant_parts(self, dt):
        """Q: white acceleration on each axis of the pad (as the paper's filter has on each marker),
        white angular acceleration on the yaw rate."""
        c = self.config
        Q = np.zeros((8, 8))
        for axis, psd in enumerate((c.acceleration_psd, c.acceleration_psd, c.vertical_acceleration_psd)):
            Q[axis::3, axis::3][:2, :2] = cv_noise(psd, dt)
        Q[6:, 6:] = cv_noise(c.angular_acceleration_psd, dt)
        return Q

    def predict_measurements(self, x, slots, camera):
        return self._predict_positions(x, slots, camera), camera.Q_RC @ _yaw_quaternion(float(x[self.PSI]))  # Eq. (12)

    def _predict_positions(self, x, slots, camera):
        p_WM = x[:3] + self.p_PM[slots] @ _rot_z(float(x[self.PSI])).T
        return (p_WM - camera.p_WC) @ camera.R_CW.T

    def measurement_jacobian(self, x, slots, camera):
        k = len(slots)
        psi = float(x[self.PSI])
        c, s = math.cos(psi), math.sin(psi)
        dR_WP = np.array([[-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])  # d R_z(psi) / d psi
        H = np.zeros((k, 6, 8))
        H[:, :3, :3] = camera.R_CW
        H[:, :3, self.PSI] = self.p_PM[slots] @ (camera.R_CW @ dR_WP).T
        H[:, 5, self.PSI] = 1.0  # the attitude error is a rotation about z by the yaw error
        return H.reshape(6 * k, 8)

    def innovations(self, x, slots, camera, p_CM, q_MC):
        # q^{M/R} = [q^{C/R} (.)] q^{M/C} (Eq. 5) = dq (x) q_pred: dq = [q_pred^-1 (.)] q^{M/R}
        to_error = odot_matrix(inverse(_yaw_quaternion(float(x[self.PSI])))) @ camera.M_CR
        return np.concatenate([p_CM - self._predict_positions(x, slots, camera), rotation_vector(q_MC @ to_error.T)],
                              axis=1)

    def process_stack(self, x, dt):
        vx, vy, vz, omega = x[:, 3], x[:, 4], x[:, 5], x[:, self.OMEGA]
        f1, f2, d1, d2 = _turn_terms_stack(omega * dt)
        c, s = np.cos(omega * dt), np.sin(omega * dt)
        a, b = dt * f1, dt * f2
        f = x.copy()
        f[:, 0] += a * vx - b * vy
        f[:, 1] += b * vx + a * vy
        f[:, 2] += dt * vz
        f[:, 3], f[:, 4] = c * vx - s * vy, s * vx + c * vy
        f[:, self.PSI] += omega * dt
        F = np.repeat(np.eye(8)[None], len(x), axis=0)
        F[:, 0, 3], F[:, 0, 4], F[:, 1, 3], F[:, 1, 4] = a, -b, b, a
        F[:, 0, 7], F[:, 1, 7] = dt * dt * (d1 * vx - d2 * vy), dt * dt * (d2 * vx + d1 * vy)
        F[:, 3, 3], F[:, 3, 4], F[:, 4, 3], F[:, 4, 4] = c, -s, s, c
        F[:, 3, 7], F[:, 4, 7] = -dt * (s * vx + c * vy), dt * (c * vx - s * vy)
        F[:, 2, 5] = F[:, self.PSI, self.OMEGA] = dt
        return f, F

    def process_noise_stack(self, x, dt):
        return self.constants(dt)

    def _predict_positions_stack(self, x, camera):
        p_WM = x[:, None, :3] + self.p_PM @ np.swapaxes(_rot_z(x[:, self.PSI]), -1, -2)
        return (p_WM - camera.p_WC) @ camera.R_CW.T

    def innovations_stack(self, x, camera, p_CM, q_MC):
        to_error = odot_matrix(inverse(_yaw_quaternion(x[:, self.PSI]))) @ camera.M_CR  # (S, 4, 4)
        return np.concatenate([p_CM - self._predict_positions_stack(x, camera),
                               rotation_vector(q_MC @ np.swapaxes(to_error, -1, -2))], axis=-1)

    def jacobian_stack(self, x, camera):
        psi = x[:, self.PSI]
        c, s, zero = np.cos(psi), np.sin(psi), np.zeros_like(psi)
        dR_WP = np.moveaxis(np.array([[-s, -c, zero], [c, -s, zero], [zero, zero, zero]]), (0, 1), (-2, -1))
        m = len(self.p_PM)
        H = np.zeros((len(x), m, 6, 8))
        H[:, :, :3, :3] = camera.R_CW
        H[:, :, :3, self.PSI] = self.p_PM @ np.swapaxes(camera.R_CW @ dR_WP, -1, -2)
        H[:, :, 5, self.PSI] = 1.0
        return H.reshape(len(x), 6 * m, 8)

    def normalized_stack(self, x):
        x[:, self.PSI] = wrap_angle(x[:, self.PSI])
        return x

    def normalized(self, x):
        x[self.PSI] = wrap_angle(float(x[self.PSI]))
        return x

    def platform(self, x):
        psi = x[..., self.PSI]
        p_WM = x[..., None, :3] + self.p_PM @ np.swapaxes(_rot_z(psi), -1, -2)
        return x[..., :3].copy(), _yaw_quaternion(psi), p_WM

    def platform_covariance(self, x, P):
        J = np.zeros((6, 8))
        J[2, self.PSI] = 1.0  # roll and pitch: level by assumption, zero variance
        J[3:, :3] = np.eye(3)
        return J @ P @ J.T

    def platform_rates(self, x):
        """v_WP, and the coordinated turn's acceleration: the horizontal velocity turning at omega."""
        vx, vy, omega = x[..., 3], x[..., 4], x[..., self.OMEGA]
        return x[..., 3:6].copy(), np.stack([-omega * vy, omega * vx, np.zeros_like(vx)], axis=-1)
