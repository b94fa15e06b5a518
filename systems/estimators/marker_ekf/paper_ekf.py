"""Seed 002's marker EKF, Eq. (11)-(12): `PaperMarkerEkf` ("paper_ekf").

Each of the n markers has its own constant-velocity position (6 states each, in W, the paper's S_R),
plus the pad attitude q^{P/R} (scalar last) and angular velocity omega (in P) under constant angular
velocity: 6 n + 7 states, 37 for five markers. The markers are not tied to each other or to the
attitude. A measured quaternion is sign-aligned with the prediction (q and -q are the same attitude)
before the paper's additive innovation; its noise is (sigma/2)^2 on each quaternion component for
`attitude_std_deg` sigma per axis of a rotation vector.

Reading the paper: Eq. (11)'s omega is written like Eq. (7)'s omega_R, but Xi(q) omega / 2 is the
kinematics of a body-frame rate, so omega here is in P (the same for a pad turning about the
vertical).
"""

import math

import numpy as np
from pydrake.math import RigidTransform

from systems.estimators.marker_ekf.engine import MarkerEkfConfig, MarkerFilter, cv_noise
from systems.perception.markers import MarkerLayout
from systems.quaternion import dcm, omega_matrix, toward, xi


def attitude_noise(q: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Q's [q, omega] block (7x7; (..., 7, 7) for quaternions q (..., 4)): white angular acceleration on omega,
    `rotation` = psd [[dt^3/3, dt^2/2], [dt^2/2, dt]], reaching q through dq/dt = G omega with G = Xi(q)/2
    held over dt: [[r00 G G^T, r01 G], [r01 G^T, r11 I3]]."""
    G = xi(q) / 2
    G_T = np.swapaxes(G, -1, -2)
    block = np.zeros(G.shape[:-2] + (7, 7))
    block[..., :4, :4] = rotation[0, 0] * G @ G_T
    block[..., :4, 4:] = rotation[0, 1] * G
    block[..., 4:, :4] = rotation[0, 1] * G_T
    block[..., 4:, 4:] = rotation[1, 1] * np.eye(3)
    return block


class PaperMarkerEkf(MarkerFilter):
    """Seed 002's EKF, Eq. (11)-(12). State x (6 n + 7; 37 for five markers):
    [p_WM_1, v_WM_1, ..., p_WM_n, v_WM_n (m, m/s, in W), q^{P/R} (scalar last), omega (rad/s, in P)]."""

    name = "paper_ekf"
    rows = 7  # p_CM (3), q^{M/C} (4)
    gate_dof = 6  # p_CM (3), and the unit quaternion's 3: its 4 components' innovation has 3 degrees of freedom
    attitude_axes = ("roll", "pitch", "yaw")

    def __init__(self, layout: MarkerLayout, X_BC: RigidTransform, config: MarkerEkfConfig | None = None):
        self.n = 6 * len(layout.ids) + 7
        self._q = slice(self.n - 7, self.n - 3)
        self._w = slice(self.n - 3, self.n)
        self._attitude = slice(self.n - 7, self.n)  # [q, omega]
        super().__init__(layout, X_BC, config)

    def marker_noise(self, sigma_p, sigma_q):
        # A rotation vector dtheta ~ N(0, sigma^2 I3) moves q by about [dtheta / 2, 0]: (sigma/2)^2 per
        # component (the scalar's share is second order; giving it the same is conservative).
        return np.diag(np.r_[np.full(3, sigma_p**2), np.full(4, (sigma_q / 2) ** 2)])

    def initial_state(self, slots, p_WM, q_MR):
        c = self.config
        q = np.sum(toward(q_MR, q_MR[0]), axis=0)  # every marker's attitude is the pad's
        q /= np.linalg.norm(q)
        R_WP = dcm(q).T
        # markers not seen start where the layout puts them, from the mean of the seen ones
        origin = np.mean(p_WM - self.p_PM[slots] @ R_WP.T, axis=0)
        p = origin + self.p_PM @ R_WP.T
        p[slots] = p_WM
        m = len(self.p_PM)
        x = np.zeros(self.n)
        x[:6 * m].reshape(m, 6)[:, :3] = p
        x[self._q] = q
        variances = np.tile(np.r_[np.full(3, c.position_std_m**2), np.full(3, c.initial_velocity_std_mps**2)], m)
        return x, np.diag(np.r_[variances, np.full(4, (self._sigma_q / 2) ** 2),
                                np.full(3, c.initial_angular_velocity_std_radps**2)])

    def process(self, x, dt):
        """Eq. (11): markers at constant velocity, q_{k+1} = q_k + (T_s/2) Xi(q_k) omega_k, omega constant."""
        m = len(self.p_PM)
        f = x.copy()
        markers = f[:6 * m].reshape(m, 6)
        markers[:, :3] += dt * markers[:, 3:]
        q, omega = x[self._q], x[self._w]
        Xi_dt = dt / 2 * xi(q)
        f[self._q] = q + Xi_dt @ omega
        F = self.constants(dt)[0].copy()
        F[self._q, self._q] += dt / 2 * omega_matrix(omega)
        F[self._q, self._w] = Xi_dt
        return f, F

    def process_noise(self, x, dt):
        """Q: white acceleration on each marker axis; white angular acceleration on omega, reaching
        q through Xi(q)/2 (the same [[dt^3/3, dt^2/2], [dt^2/2, dt]] shape)."""
        _, Q, rotation = self.constants(dt)
        Q = Q.copy()
        Q[self._attitude, self._attitude] = attitude_noise(x[self._q], rotation)
        return Q

    def constant_parts(self, dt):
        """F and Q of Eq. (11) without the attitude's blocks ([q, omega] of Q, q's of F), which depend on the
        state, and the angular velocity's [[dt^3/3, dt^2/2], [dt^2/2, dt]] psd they are made of (attitude_noise)."""
        c, m = self.config, len(self.p_PM)
        F = np.eye(self.n)
        F[:6 * m, :6 * m] = np.kron(np.eye(m), np.kron([[1.0, dt], [0.0, 1.0]], np.eye(3)))
        psd = np.diag([c.acceleration_psd, c.acceleration_psd, c.vertical_acceleration_psd])
        Q = np.zeros((self.n, self.n))
        Q[:6 * m, :6 * m] = np.kron(np.eye(m), np.kron(cv_noise(1.0, dt), psd))
        return F, Q, cv_noise(c.angular_acceleration_psd, dt)

    def predict_measurements(self, x, slots, camera):
        m = len(self.p_PM)
        p_WM = x[:6 * m].reshape(m, 6)[slots, :3]
        return (p_WM - camera.p_WC) @ camera.R_CW.T, camera.Q_RC @ x[self._q]  # Eq. (12)

    def measurement_jacobian(self, x, slots, camera):
        k = len(slots)
        H = np.zeros((k, 7, self.n))
        H[np.arange(k)[:, None, None], np.arange(3)[None, :, None],
          6 * np.asarray(slots)[:, None, None] + np.arange(3)[None, None, :]] = camera.R_CW
        H[:, 3:, self._q] = camera.Q_RC
        return H.reshape(7 * k, self.n)

    def innovations(self, x, slots, camera, p_CM, q_MC):
        p_hat, q_hat = self.predict_measurements(x, slots, camera)
        q_MC = toward(q_MC, q_hat)
        return np.concatenate([p_CM - p_hat, q_MC - q_hat], axis=1)

    def process_stack(self, x, dt):
        m = len(self.p_PM)
        f = x.copy()
        markers = f[:, :6 * m].reshape(len(x), m, 6)
        markers[..., :3] += dt * markers[..., 3:]
        q, omega = x[:, self._q], x[:, self._w]
        Xi_dt = dt / 2 * xi(q)
        f[:, self._q] = q + (Xi_dt @ omega[..., None])[..., 0]
        F = np.repeat(self.constants(dt)[0][None], len(x), axis=0)
        F[:, self._q, self._q] += dt / 2 * omega_matrix(omega)
        F[:, self._q, self._w] = Xi_dt
        return f, F

    def process_noise_stack(self, x, dt):
        _, Q, rotation = self.constants(dt)
        Q = np.repeat(Q[None], len(x), axis=0)
        Q[:, self._attitude, self._attitude] = attitude_noise(x[:, self._q], rotation)
        return Q

    def innovations_stack(self, x, camera, p_CM, q_MC):
        m = len(self.p_PM)
        p_hat = (x[:, :6 * m].reshape(len(x), m, 6)[..., :3] - camera.p_WC) @ camera.R_CW.T
        q_hat = x[:, self._q] @ camera.Q_RC.T
        q_MC = toward(q_MC, q_hat[:, None])
        return np.concatenate([p_CM - p_hat, q_MC - q_hat[:, None]], axis=-1)

    def jacobian_stack(self, x, camera):
        return self.measurement_jacobian(x[0], np.arange(len(self.p_PM)), camera)  # H does not depend on x

    def normalized_stack(self, x):
        q = x[:, self._q]
        x[:, self._q] = q / np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
        return x

    def normalized(self, x):
        q = x[self._q]
        q /= math.sqrt(q @ q)  # |q|, as np.linalg.norm computes it
        return x

    def platform(self, x):
        m = len(self.p_PM)
        return x[..., :3].copy(), x[..., self._q].copy(), x[..., :6 * m].reshape(x.shape[:-1] + (m, 6))[..., :3].copy()

    def platform_covariance(self, x, P):
        J = np.zeros((6, self.n))  # [small rotation in P; position of marker 0] from x
        J[:3, self._q] = 2 * xi(x[self._q]).T  # dtheta = 2 Xi(q)^T dq (Markley & Crassidis)
        J[3:, :3] = np.eye(3)
        return J @ P @ J.T

    def platform_rates(self, x):
        """Marker 0's velocity; Eq. (11) moves each marker at constant velocity: no acceleration."""
        return x[..., 3:6].copy(), np.zeros(x.shape[:-1] + (3,))
