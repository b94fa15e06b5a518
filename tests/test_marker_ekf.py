"""Seed 002 marker EKF (Eq. 11-12) and the constant-turn EKF beside it: models against Drake's
geometry and finite differences, convergence on analytic drives, drop-outs, bad and late
measurements, any subset of markers, and the Drake system."""

import copy

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource
from scipy.linalg import expm
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from systems.config import ConfigError
from systems.estimators.marker_ekf import FILTERS, ConstantTurnEkf, MarkerEkfConfig, MarkerFilterSystem, PaperMarkerEkf
from systems.estimators.marker_ekf.engine import (
    EST_LAST_MEASUREMENT,
    EST_P_WP,
    EST_POSITION_STD,
    EST_V_WP,
    EST_VALID,
    EST_YAW,
    FilterStats,
)
from systems.perception.latency import MeasurementLatency
from systems.perception.markers import MarkerLayout, MarkerMeasurement
from systems.perception.synthetic_markers import (
    SyntheticMarkerSource,
    synthetic_marker_measurements,
)
from systems.quaternion import drake_to_paper, xi
from systems.sensors.camera import CameraConfig
from tests.conftest import pose

LAYOUT = MarkerLayout()
X_BC = CameraConfig().X_BC
TS = 0.035
BOTH = [PaperMarkerEkf, ConstantTurnEkf]
PAD_AHEAD_OF_REAR_AXLE_M = 1.75


# ---- truth, built here with Drake's RigidTransform, independently of the filters' algebra ------


def straight(speed: float, heading: float = np.radians(30.0)):
    """X_WP(t) of a pad driven straight at constant speed."""
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    return lambda t: RigidTransform(RotationMatrix.MakeZRotation(heading), [5.0, -3.0, 1.6] + speed * t * direction)


def circle(speed: float, radius: float):
    """X_WP(t) of a pad PAD_AHEAD_OF_REAR_AXLE_M ahead of the rear axle of a car on a circle
    (the pad is not on the circle: it slips sideways, as on a real car)."""
    def X_WP(t):
        heading = speed / radius * t
        rear = np.array([radius * np.sin(heading), radius * (1 - np.cos(heading)), 1.6])
        R_WP = RotationMatrix.MakeZRotation(heading)
        return RigidTransform(R_WP, rear + R_WP.matrix()[:, 0] * PAD_AHEAD_OF_REAR_AXLE_M)
    return X_WP


def uav_over(X_WP: RigidTransform, t: float) -> RigidTransform:
    """The UAV 3 m above the pad, off centre, tilted and yawed, wandering slowly."""
    rpy = RollPitchYaw(0.04 * np.sin(t), -0.03, 0.3 + 0.1 * np.cos(0.5 * t))
    return RigidTransform(rpy, X_WP.translation() + [0.3 * np.sin(0.7 * t), -0.2, 3.0])


def measure(truth, t: float, rng, ids=None, time=None) -> list[MarkerMeasurement]:
    """Seed 002 Sec. 4 measurements of the markers `ids` (default: all) at time t."""
    X_WP = truth(t)
    X_CP = uav_over(X_WP, t).multiply(X_BC).InvertAndCompose(X_WP)
    measurements = synthetic_marker_measurements(X_CP, LAYOUT, rng, time=t if time is None else time)
    return [m for m in measurements if ids is None or m.marker_id in ids]


def drive(marker_filter, truth, steps, seed=0, visible=lambda k: LAYOUT.ids, first=0):
    """Steps the filter at k TS for k in first..first + steps - 1; returns per step: pad position
    error norm [m], yaw error [rad], marker position errors (5,) [m], and the estimated velocity
    (3,) [m/s] of marker 0 (paper) or the pad (ct)."""
    rng = np.random.default_rng(seed)
    errors = []
    for k in range(first, first + steps):
        t = k * TS
        marker_filter.step(t, uav_over(truth(t), t), measure(truth, t, rng, visible(k)))
        errors.append(estimate_errors(marker_filter, truth(t)) + (marker_filter.belief[1][3:6],))
    return [np.array(e) for e in zip(*errors)]


def estimate_errors(marker_filter, X_WP: RigidTransform):
    estimate = marker_filter.estimate()
    yaw = RollPitchYaw(X_WP.rotation()).yaw_angle()
    p_WM = X_WP.multiply(LAYOUT.p_PM.T).T
    return (np.linalg.norm(estimate.X_WP.X_RT.translation() - X_WP.translation()),
            np.angle(np.exp(1j * (estimate.vector[EST_YAW] - yaw))), np.linalg.norm(estimate.p_WM - p_WM, axis=1))


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def state_from_truth(cls, X_WP: RigidTransform, v_WP=(3.0, -1.0, 0.1), omega_z=0.2) -> np.ndarray:
    """A filter state for the pad at X_WP moving at v_WP (every marker alike) turning at omega_z."""
    if cls is ConstantTurnEkf:
        return np.r_[X_WP.translation(), v_WP, RollPitchYaw(X_WP.rotation()).yaw_angle(), omega_z]
    markers = [np.r_[X_WP.multiply(p), v_WP] for p in LAYOUT.p_PM]
    return np.r_[np.concatenate(markers), drake_to_paper(X_WP.rotation()), 0.01, -0.02, omega_z]


def make(cls, **config):
    return cls(LAYOUT, X_BC, MarkerEkfConfig(**config))


# ---- models ------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls, X_WP", [(PaperMarkerEkf, pose([12, -4, 1.6], [0, 0, 35])),
                                       (PaperMarkerEkf, pose([12, -4, 1.6], [6, -4, 150])),  # a tilted pad
                                       (ConstantTurnEkf, pose([12, -4, 1.6], [0, 0, 35])),
                                       (ConstantTurnEkf, pose([-2, 7, 1.6], [0, 0, -120]))])
def test_measurement_model_is_the_true_geometry(cls, X_WP):
    marker_filter = make(cls)
    X_WB = pose([12.5, -3.8, 4.5], [5, -3, 100])
    slots = np.arange(5)
    p_CM, q_MC = marker_filter.predict_measurements(state_from_truth(cls, X_WP), slots,
                                                    marker_filter.camera_at(X_WB))
    X_WC = X_WB.multiply(X_BC)
    for i in slots:
        X_CM = X_WC.InvertAndCompose(X_WP.multiply(RigidTransform(LAYOUT.p_PM[i])))
        np.testing.assert_allclose(p_CM[i], X_CM.translation(), atol=1e-12)
        q_true = drake_to_paper(X_CM.rotation())
        np.testing.assert_allclose(q_MC * np.sign(q_MC @ q_true), q_true, atol=1e-12)


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("slots", [[0, 2, 4], [3], [0, 1, 2, 3, 4]])
def test_measurement_jacobian_matches_finite_differences(cls, slots):
    marker_filter = make(cls)
    camera = marker_filter.camera_at(pose([12.5, -3.8, 4.5], [5, -3, 100]))
    x0 = state_from_truth(cls, pose([12, -4, 1.6], [0, 0, 35]))
    slots = np.array(slots)
    p_CM, q_MC = marker_filter.predict_measurements(x0, slots, camera)
    q_MC = np.tile(q_MC, (len(slots), 1))

    def innovation(x):
        return marker_filter.innovations(x, slots, camera, p_CM, q_MC).ravel()

    eps = 1e-6
    numeric = np.column_stack([-(innovation(x0 + eps * e) - innovation(x0 - eps * e)) / (2 * eps)
                               for e in np.eye(len(x0))])
    np.testing.assert_allclose(marker_filter.measurement_jacobian(x0, slots, camera), numeric, atol=1e-7)


@pytest.mark.parametrize("cls, omega_z", [(PaperMarkerEkf, 0.3), (ConstantTurnEkf, 0.4), (ConstantTurnEkf, 1e-7),
                                          (ConstantTurnEkf, 0.0)])
def test_process_jacobian_matches_finite_differences(cls, omega_z):
    marker_filter = make(cls)
    x0 = state_from_truth(cls, pose([12, -4, 1.6], [2, -1, 35]), omega_z=omega_z)
    eps = 1e-6
    numeric = np.column_stack([(marker_filter.process(x0 + eps * e, TS)[0] - marker_filter.process(x0 - eps * e, TS)[0])
                               / (2 * eps) for e in np.eye(len(x0))])
    np.testing.assert_allclose(marker_filter.process(x0, TS)[1], numeric, atol=1e-8)


def test_constant_turn_model_is_exact_for_a_pad_off_the_rear_axle_in_a_steady_turn():
    truth, marker_filter = circle(12.0, 41.0), make(ConstantTurnEkf)

    def state(t, dt=1e-6):  # the pad's velocity by central differences of the truth
        v = (truth(t + dt).translation() - truth(t - dt).translation()) / (2 * dt)
        return state_from_truth(ConstantTurnEkf, truth(t), v, 12.0 / 41.0)

    predicted = marker_filter.process(state(1.0), TS)[0]
    np.testing.assert_allclose(predicted, state(1.0 + TS), atol=1e-7)
    v = state(1.0)[3:5]
    assert abs(v[1] / np.linalg.norm(v) - np.sin(12.0 / 41.0)) > 0.02  # its velocity is not along its heading


def test_the_platform_attitude_covariance_is_that_of_twice_the_quaternions_vector():
    """Near the identity a small rotation is dtheta = 2 dq_vec (Markley & Crassidis): a quaternion-vector std of
    0.01 is an attitude std of 0.02 rad on each axis, what the seam is given."""
    ekf = PaperMarkerEkf(MarkerLayout(), CameraConfig().X_BC)
    x, P = np.zeros(ekf.n), np.zeros((ekf.n, ekf.n))
    x[ekf._q] = [0.0, 0.0, 0.0, 1.0]
    P[ekf._q, ekf._q] = np.diag([1e-4, 1e-4, 1e-4, 0.0])
    np.testing.assert_allclose(np.diag(ekf.platform_covariance(x, P))[:3], (2 * 0.01) ** 2, rtol=1e-12)


def test_the_paper_filters_platform_covariance_is_marker_0s_position_and_the_attitudes():
    """A full random P and a pad yawed 0.5 rad: the position block of [roll, pitch, yaw, x, y, z] is marker 0's
    (the pad frame's origin, x[:3]), and the attitude's blocks are those of the small rotation in P, whose Jacobian
    in q is taken here by central differences of SciPy's rotation vector of R(q0)^T R(q) (q normalised)."""
    ekf = make(PaperMarkerEkf)
    A = np.random.default_rng(1).standard_normal((ekf.n, ekf.n))
    P = A @ A.T
    x = np.zeros(ekf.n)
    q0 = drake_to_paper(RotationMatrix.MakeZRotation(0.5))
    x[30:34] = q0
    eps = 1e-6

    def rotation_in_p(q):  # SciPy's quaternions are [x, y, z, w] of R_WP, as the paper's q^{P/R} is
        return (Rotation.from_quat(q0).inv() * Rotation.from_quat(q)).as_rotvec()

    J = np.column_stack([(rotation_in_p(q0 + eps * e) - rotation_in_p(q0 - eps * e)) / (2 * eps) for e in np.eye(4)])
    covariance = ekf.platform_covariance(x, P)
    np.testing.assert_allclose(covariance[3:, 3:], P[:3, :3], rtol=1e-12)
    np.testing.assert_allclose(covariance[:3, 3:], J @ P[30:34, :3], atol=1e-7)
    np.testing.assert_allclose(covariance[3:, :3], covariance[:3, 3:].T, rtol=1e-12)
    np.testing.assert_allclose(covariance[:3, :3], J @ P[30:34, 30:34] @ J.T, atol=1e-7)


def started_from_markers_1_and_2(cls, moved=(0.0, 0.0, 0.0)):
    """(filter, its first state, p_WP, R_WP): `cls` started from markers 1 and 2 alone, seen exactly on a pad at
    p_WP yawed 30 deg, but for marker 2 seen `moved` [m] (in W) from there."""
    ekf = cls(MarkerLayout(), CameraConfig().X_BC)
    R_WP = RotationMatrix.MakeZRotation(np.radians(30.0))
    p_WP = np.array([5.0, 2.0, 1.6])
    slots = np.array([1, 2])
    q_MR = np.tile(drake_to_paper(R_WP.ToQuaternion()), (2, 1))
    x, _ = ekf.initial_state(slots, p_WP + ekf.p_PM[slots] @ R_WP.matrix().T + [[0.0, 0.0, 0.0], moved], q_MR)
    return ekf, x, p_WP, R_WP


def test_markers_not_seen_at_the_start_begin_where_the_layout_puts_them():
    """The paper filter started from markers 1 and 2 alone: markers 0, 3 and 4 begin at the pad's pose applied to
    the layout (the seen markers' mean less their offsets, turned into W)."""
    ekf, x, p_WP, R_WP = started_from_markers_1_and_2(PaperMarkerEkf)
    m = len(ekf.p_PM)
    np.testing.assert_allclose(x[:6 * m].reshape(m, 6)[:, :3], p_WP + ekf.p_PM @ R_WP.matrix().T, atol=1e-12)


def test_markers_seen_at_the_start_begin_where_they_were_seen():
    """The paper filter started from markers 1 and 2, marker 2 seen 0.1 m along x from where the layout puts it:
    markers 1 and 2 begin exactly where seen; markers 0, 3 and 4 where the layout puts them from the pad's origin
    the seen markers give, their mean less their offsets: p_WP moved 0.05 m along x."""
    ekf, x, p_WP, R_WP = started_from_markers_1_and_2(PaperMarkerEkf, moved=(0.1, 0.0, 0.0))
    X_WP = RigidTransform(R_WP, p_WP)
    p_WM = x[:6 * len(LAYOUT.p_PM)].reshape(-1, 6)[:, :3]
    np.testing.assert_allclose(p_WM[1], X_WP.multiply(LAYOUT.p_PM[1]), atol=1e-12)
    np.testing.assert_allclose(p_WM[2], X_WP.multiply(LAYOUT.p_PM[2]) + [0.1, 0.0, 0.0], atol=1e-12)
    origin = RigidTransform(R_WP, p_WP + [0.05, 0.0, 0.0])
    np.testing.assert_allclose(p_WM[[0, 3, 4]], origin.multiply(LAYOUT.p_PM[[0, 3, 4]].T).T, atol=1e-12)


def test_the_constant_turn_filter_starts_at_the_pads_origin_from_any_markers():
    """The constant-turn filter started from markers 1 and 2 alone: its p_WP is the pad's origin (the seen markers
    less their layout offsets turned into W) and its yaw 30 deg."""
    _, x, p_WP, _ = started_from_markers_1_and_2(ConstantTurnEkf)
    np.testing.assert_allclose(x[:3], p_WP, atol=1e-12)
    assert x[ConstantTurnEkf.PSI] == pytest.approx(np.radians(30.0), abs=1e-12)


def test_markers_seen_as_q_and_minus_q_start_the_filter_at_the_pads_attitude():
    """Two markers whose measured quaternions differ only in sign (the same attitude): the filter starts at that
    attitude, not at the zero their plain sum would give."""
    ekf = PaperMarkerEkf(MarkerLayout(), CameraConfig().X_BC)
    q = drake_to_paper(RotationMatrix(RollPitchYaw(0.1, -0.05, 0.7)).ToQuaternion())
    x, _ = ekf.initial_state(np.array([0, 1]), np.array([[1.0, 2.0, 0.5], [1.3, 2.1, 0.5]]), np.array([q, -q]))
    assert abs(x[ekf._q] @ q) == pytest.approx(1.0, abs=1e-12)


def test_the_estimates_yaw_is_the_heading_of_a_pitched_pads_x_axis():
    """The paper filter estimates the pad's whole attitude: pitched 60 deg and yawed 45 deg, its x axis points at
    45 deg in W's xy plane, the yaw Drake's RollPitchYaw gives, not atan(cos 60) = 26.6 deg."""
    marker_filter = make(PaperMarkerEkf)
    X_WP = RigidTransform(RollPitchYaw(0.0, np.radians(60.0), np.radians(45.0)), [5.0, -3.0, 1.6])
    assert RollPitchYaw(X_WP.rotation()).yaw_angle() == pytest.approx(np.radians(45.0), abs=1e-12)
    vector, _, _ = marker_filter.estimate_vectors(state_from_truth(PaperMarkerEkf, X_WP), 0.01, 0.0)
    assert vector[EST_YAW] == pytest.approx(np.radians(45.0), abs=1e-12)


@pytest.mark.parametrize("cls", BOTH)
def test_a_filter_started_under_a_tilted_uav_starts_at_the_pads_attitude(cls):
    """Exact measurements of a pad yawed 30 deg from a UAV rolled, pitched and yawed (the camera's attitude in W not
    a half-turn about one axis, as it nearly is under a level UAV): the first estimate's attitude is the pad's, and
    so are its position and the markers' (the camera's 4 cm offset from B, turned into W, included)."""
    marker_filter = make(cls)
    X_WP = RigidTransform(RotationMatrix.MakeZRotation(np.radians(30.0)), [5.0, -3.0, 1.6])
    X_WB = RigidTransform(RollPitchYaw(0.4, -0.3, 1.0), [5.5, -3.2, 4.6])
    X_CP = X_WB.multiply(X_BC).InvertAndCompose(X_WP)
    marker_filter.step(0.0, X_WB, synthetic_marker_measurements(X_CP, LAYOUT, np.random.default_rng(0), 0.0, 0.0))
    estimate = marker_filter.estimate()
    assert estimate.vector[EST_YAW] == pytest.approx(np.radians(30.0), abs=1e-9)
    np.testing.assert_allclose(estimate.X_WP.X_RT.rotation().matrix(), X_WP.rotation().matrix(), atol=1e-9)
    np.testing.assert_allclose(estimate.X_WP.X_RT.translation(), X_WP.translation(), atol=1e-9)
    np.testing.assert_allclose(estimate.p_WM, X_WP.multiply(LAYOUT.p_PM.T).T, atol=1e-9)


@pytest.mark.parametrize("cls", BOTH)
def test_an_unstarted_filters_estimate_is_invalid_at_the_time_asked(cls):
    """Before its start a filter has no pose, but its invalid estimate is stamped at the time asked for (the Drake
    system reads it at the context's time), 0 when none is."""
    marker_filter = make(cls)
    estimate = marker_filter.estimate(2.5)
    assert not estimate.X_WP.valid and estimate.X_WP.time == 2.5
    assert marker_filter.estimate().X_WP.time == 0.0


def test_the_stacked_innovations_take_q_and_minus_q_as_one_attitude():
    """The batch path's innovations equal a single filter's when every measured quaternion is the negative of the
    predicted one: the same attitude, so a zero attitude innovation."""
    ekf = PaperMarkerEkf(MarkerLayout(), CameraConfig().X_BC)
    m = len(ekf.p_PM)
    x = np.zeros(ekf.n)
    x[ekf._q] = np.array([0.1, 0.0, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 0.0, 1.0])
    camera = type("Camera", (), {"p_WC": np.array([0.0, 0.0, 5.0]), "R_CW": np.diag([1.0, -1.0, -1.0]),
                                 "Q_RC": np.eye(4)})()
    p_CM, q_MC = np.ones((m, 3)), np.tile(-x[ekf._q], (m, 1))
    single = ekf.innovations(x, np.arange(m), camera, p_CM, q_MC)
    stacked = ekf.innovations_stack(x[None], camera, p_CM, q_MC)[0]
    np.testing.assert_allclose(stacked, single, atol=1e-12)
    np.testing.assert_allclose(stacked[:, 3:], 0.0, atol=1e-12)


def test_the_constant_turn_process_noise_is_white_acceleration_on_each_axis():
    """Q over dt against Van Loan's discretisation (SciPy's expm) of p' = v, psi' = omega with white accelerations:
    x and y under acceleration_psd, z under vertical_acceleration_psd (a different value), omega under
    angular_acceleration_psd; nothing across axes."""
    marker_filter = make(ConstantTurnEkf, acceleration_psd=0.5, vertical_acceleration_psd=0.01,
                         angular_acceleration_psd=0.002)
    dt = 0.1
    A, W = np.zeros((8, 8)), np.diag([0.0, 0.0, 0.0, 0.5, 0.5, 0.01, 0.0, 0.002])
    A[0, 3] = A[1, 4] = A[2, 5] = A[6, 7] = 1.0
    E = expm(np.block([[-A, W], [np.zeros((8, 8)), A.T]]) * dt)
    Q = E[8:, 8:].T @ E[:8, 8:]
    x = state_from_truth(ConstantTurnEkf, pose([1, 2, 1.6], [0, 0, 20]))
    np.testing.assert_allclose(marker_filter.process_noise(x, dt), Q, rtol=1e-9, atol=1e-15)


def van_loan(A: np.ndarray, W: np.ndarray, dt: float) -> np.ndarray:
    """Van Loan's discretisation (SciPy's expm) of x' = A x + w, w white with spectral density W: Q over dt."""
    n = len(A)
    E = expm(np.block([[-A, W], [np.zeros((n, n)), A.T]]) * dt)
    return E[n:, n:].T @ E[:n, n:]


def test_the_paper_filters_marker_process_noise_is_white_acceleration_on_each_axis():
    """Each marker's [p, v] block of the paper filter's Q against Van Loan's discretisation of p' = v with white
    acceleration, x and y under acceleration_psd, z under vertical_acceleration_psd (a different value); nothing
    between markers or between a marker and the attitude."""
    marker_filter = make(PaperMarkerEkf, acceleration_psd=0.5, vertical_acceleration_psd=0.01)
    dt = 0.1
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    marker = van_loan(A, np.diag([0.0, 0.0, 0.0, 0.5, 0.5, 0.01]), dt)
    m = len(LAYOUT.p_PM)
    Q = marker_filter.process_noise(state_from_truth(PaperMarkerEkf, pose([1, 2, 1.6], [0, 0, 20])), dt)
    np.testing.assert_allclose(Q[:6 * m, :6 * m], np.kron(np.eye(m), marker), rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(Q[:6 * m, 6 * m:], 0.0)


def test_the_paper_filters_attitude_process_noise_is_white_angular_acceleration_through_xi():
    """The [q, omega] block of the paper filter's Q (single and stacked) against Van Loan's discretisation of
    q' = G omega, omega' = white angular acceleration, G = Xi(q)/2 held at the state's q: the q-omega cross term
    included, and G G^T (not a quarter of it) on q."""
    psd, dt = 0.002, 0.1
    marker_filter = make(PaperMarkerEkf, angular_acceleration_psd=psd)
    x = state_from_truth(PaperMarkerEkf, pose([1, 2, 1.6], [6, -4, 150]))
    A = np.zeros((7, 7))
    A[:4, 4:] = xi(x[30:34]) / 2
    expected = van_loan(A, np.diag([0.0, 0.0, 0.0, 0.0, psd, psd, psd]), dt)
    np.testing.assert_allclose(marker_filter.process_noise(x, dt)[30:, 30:], expected, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(marker_filter.process_noise_stack(x[None], dt)[0, 30:, 30:], expected,
                               rtol=1e-9, atol=1e-15)


def test_the_paper_filters_platform_velocity_is_marker_0s():
    """The paper filter's platform velocity is marker 0's (the pad frame's origin), with every marker given a
    different velocity, and its acceleration zero (constant velocity)."""
    marker_filter = make(PaperMarkerEkf)
    x = state_from_truth(PaperMarkerEkf, pose([1, 2, 1.6], [0, 0, 20]))
    m = len(LAYOUT.p_PM)
    velocities = np.array([[1.0 + i, -0.5 * i, 0.1 * i] for i in range(m)])
    x[:6 * m].reshape(m, 6)[:, 3:] = velocities
    v, a = marker_filter.platform_rates(x)
    np.testing.assert_array_equal(v, velocities[0])
    np.testing.assert_array_equal(a, 0.0)


@pytest.mark.parametrize("v_WP, omega_z, a_WP", [
    ((3.0, 0.0, 0.0), 0.2, (0.0, 0.6, 0.0)),  # heading +x, turning left: toward +y
    ((3.0, -1.0, 0.1), 0.2, (0.2, 0.6, 0.0)),
    ((0.0, 2.0, 0.0), -0.5, (1.0, 0.0, 0.0)),  # heading +y, turning right: toward +x
])
def test_the_constant_turn_filters_platform_acceleration_turns_its_velocity_at_the_yaw_rate(v_WP, omega_z, a_WP):
    """v_xy(t) = R_z(omega t) v_xy(0): a = d/dt at t = 0 = omega [-v_y, v_x], the z velocity constant; the
    velocity is the state's."""
    x = state_from_truth(ConstantTurnEkf, pose([1, 2, 1.6], [0, 0, 20]), v_WP, omega_z)
    v, a = make(ConstantTurnEkf).platform_rates(x)
    np.testing.assert_array_equal(v, v_WP)
    np.testing.assert_allclose(a, a_WP, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("cls", BOTH)
def test_the_initial_covariance_is_the_configured_variances(cls):
    """The starting P is diagonal with the configuration's variances: position_std_m^2 on positions,
    initial_velocity_std_mps^2 on velocities, the attitude's (attitude_std_deg in rad, halved on each quaternion
    component for the paper filter), initial_angular_velocity_std_radps^2 on the angular velocity."""
    c = MarkerEkfConfig(position_std_m=0.2, attitude_std_deg=4.0, initial_velocity_std_mps=7.0,
                        initial_angular_velocity_std_radps=0.3)
    marker_filter = cls(LAYOUT, X_BC, c)
    q = np.tile(drake_to_paper(RotationMatrix.MakeZRotation(0.5).ToQuaternion()), (2, 1))
    _, P = marker_filter.initial_state(np.array([0, 1]), np.array([[1.0, 2.0, 1.6], [1.3, 2.1, 1.6]]), q)
    sigma_q = np.radians(c.attitude_std_deg)
    if cls is ConstantTurnEkf:
        expected = np.r_[np.full(3, 0.2**2), np.full(3, 7.0**2), sigma_q**2, 0.3**2]
    else:
        expected = np.r_[np.tile(np.r_[np.full(3, 0.2**2), np.full(3, 7.0**2)], len(LAYOUT.p_PM)),
                         np.full(4, (sigma_q / 2) ** 2), np.full(3, 0.3**2)]
    np.testing.assert_allclose(P, np.diag(expected), rtol=1e-12, atol=0.0)


def test_the_constant_turn_platform_covariance_is_its_yaw_and_position():
    """[roll, pitch, yaw, x, y, z] of the pad: roll and pitch level by assumption (zero variance), the yaw's
    (co)variances those of the state's psi, the position's those of p_WP."""
    marker_filter = make(ConstantTurnEkf)
    A = np.random.default_rng(1).standard_normal((8, 8))
    P = A @ A.T
    x = state_from_truth(ConstantTurnEkf, pose([1, 2, 1.6], [0, 0, 20]))
    covariance = marker_filter.platform_covariance(x, P)
    kept = [ConstantTurnEkf.PSI, 0, 1, 2]
    np.testing.assert_array_equal(covariance[:2], 0.0)
    np.testing.assert_array_equal(covariance[:, :2], 0.0)
    np.testing.assert_allclose(covariance[2:, 2:], P[np.ix_(kept, kept)], rtol=1e-12)


@pytest.mark.parametrize("cls", BOTH)
def test_a_prediction_over_a_period_0_4_ms_longer_uses_its_own_dt(cls):
    """A filter stepped at T_s (its constants for dt = T_s made) then predicting over dt = T_s + 0.4 ms predicts as a
    fresh filter does. Marker 0 (the pad's origin) at constant velocity along x (v_y = 0 and omega = 0: the turn's
    terms vanish), from P = I: P[0, 0] = 1 + dt^2 + acceleration_psd dt^3 / 3 (white acceleration's dt^3 / 3)."""
    marker_filter, truth = make(cls), straight(6.0)
    rng = np.random.default_rng(0)
    for t in (0.0, TS):
        marker_filter.step(t, uav_over(truth(t), t), measure(truth, t, rng))
    dt = TS + 0.0004
    x = state_from_truth(cls, pose([1, 2, 1.6], [0, 0, 0]), v_WP=(3.0, 0.0, 0.0), omega_z=0.0)
    P = np.eye(marker_filter.n)
    x_fresh, P_fresh = make(cls).predict(x, P, dt)
    x_warm, P_warm = marker_filter.predict(x, P, dt)
    np.testing.assert_allclose(x_warm, x_fresh, atol=1e-12, rtol=0)
    np.testing.assert_allclose(P_warm, P_fresh, atol=1e-12, rtol=0)
    assert P_warm[0, 0] == pytest.approx(1.0 + dt**2 + marker_filter.config.acceleration_psd * dt**3 / 3, abs=1e-12)


def test_paper_process_is_eq_11():
    marker_filter = make(PaperMarkerEkf)
    x = state_from_truth(PaperMarkerEkf, pose([1, 2, 1.6], [0, 0, 20]))
    f = marker_filter.process(x, TS)[0]
    np.testing.assert_allclose(f[0:3], x[0:3] + TS * x[3:6])
    np.testing.assert_allclose(f[3:6], x[3:6])
    q, omega = x[30:34], x[34:37]
    np.testing.assert_allclose(f[30:34], q + TS / 2 * xi(q) @ omega)
    np.testing.assert_allclose(f[34:37], omega)
    assert marker_filter.n == 37


# ---- convergence -------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", BOTH)
def test_converges_on_a_straight_constant_speed_drive(cls):
    marker_filter = make(cls)
    truth = straight(6.0)
    position, yaw, markers, velocity = drive(marker_filter, truth, steps=400)
    settled = slice(150, None)  # after 5 s
    assert rms(position[settled]) < 0.08  # a single marker measurement is off by 0.17 m (3D, rms)
    assert np.degrees(rms(yaw[settled])) < 1.5
    assert markers[settled].max() < 0.25
    estimate = marker_filter.estimate()
    assert estimate.X_WP.valid and estimate.X_WP.covariance.shape == (6, 6)
    np.testing.assert_allclose(velocity[settled].mean(axis=0),
                               6.0 * np.array([np.cos(np.radians(30)), np.sin(np.radians(30)), 0]), atol=0.1)


def test_constant_turn_filter_converges_on_a_circle_and_beats_the_papers():
    truth = circle(12.0, 41.0)  # Eq. (13)'s tightest bend, at case C3's speed
    paper, ct = make(PaperMarkerEkf), make(ConstantTurnEkf)
    paper_errors = drive(paper, truth, steps=500)
    ct_errors = drive(ct, truth, steps=500)
    settled = slice(150, None)
    assert rms(ct_errors[0][settled]) < 0.05
    assert rms(paper_errors[0][settled]) > 1.5 * rms(ct_errors[0][settled])
    assert rms(ct_errors[2][settled]) < rms(paper_errors[2][settled])
    assert ct.belief[1][ConstantTurnEkf.OMEGA] == pytest.approx(12.0 / 41.0, rel=0.1)
    # The pad's rates against the truth's (central differences), RMS over 100 more steps: the
    # constant-turn filter's acceleration is the centripetal one (v^2 / r ~ 3.5 m/s^2); the paper's
    # model has none.
    h, rng = 1e-4, np.random.default_rng(5)
    errors = {ct: [], paper: []}
    for k in range(500, 600):
        t = k * TS
        p = [truth(t + d).translation() for d in (-h, 0.0, h)]
        v_true, a_true = (p[2] - p[0]) / (2 * h), (p[2] - 2 * p[1] + p[0]) / h**2
        measurements = measure(truth, t, rng)
        for marker_filter in errors:
            marker_filter.step(t, uav_over(truth(t), t), measurements)
            estimate = marker_filter.estimate()
            errors[marker_filter].append(np.r_[estimate.v_WP - v_true, estimate.a_WP - a_true])
    ct_v, ct_a = np.split(np.array(errors[ct]), 2, axis=1)
    paper_a = np.array(errors[paper])[:, 3:]
    assert rms(np.linalg.norm(ct_v, axis=1)) < 0.5 and rms(np.linalg.norm(ct_a, axis=1)) < 0.5
    assert rms(np.linalg.norm(paper_a, axis=1)) == pytest.approx(12.0**2 / 41.0, rel=0.1)  # all of it


@pytest.mark.parametrize("cls", BOTH)
def test_without_markers_the_filter_predicts_and_then_reconverges(cls):
    marker_filter = make(cls)
    truth = straight(6.0)
    drive(marker_filter, truth, steps=150)
    traces = []
    for k in range(150, 250):  # 3.5 s without markers
        t = k * TS
        marker_filter.step(t, uav_over(truth(t), t), [])
        traces.append(np.trace(marker_filter.belief[2]))
    assert np.all(np.diff(traces) > 0)
    coasted = marker_filter.estimate()
    assert not coasted.X_WP.valid  # its position is too uncertain
    assert np.linalg.norm(coasted.X_WP.X_RT.translation() - truth(249 * TS).translation()) < 2.0  # but predicted
    position = drive(marker_filter, truth, steps=100, first=250)[0]
    assert position[-30:].max() < 0.15
    assert marker_filter.estimate().X_WP.valid
    assert marker_filter.stats.gated == 0 and marker_filter.stats.resets == 0


# ---- bad, outlying and late measurements -------------------------------------------------------


def converged(cls, truth=straight(6.0), steps=60):
    marker_filter = make(cls)
    drive(marker_filter, truth, steps=steps)
    return marker_filter


def twins(cls):
    """Two identical filters (copied as Drake copies state) after the same 60 steps."""
    a = converged(cls)
    return a, copy.deepcopy(a)


def assert_same_belief(a, b, atol=0.0):
    (ta, xa, Pa), (tb, xb, Pb) = a.belief, b.belief
    assert ta == tb
    np.testing.assert_allclose(xa, xb, atol=atol, rtol=0)
    np.testing.assert_allclose(Pa, Pb, atol=atol, rtol=0)


@pytest.mark.parametrize("cls", BOTH)
def test_nan_and_non_unit_measurements_are_rejected_and_counted(cls):
    a, b = twins(cls)
    truth, t = straight(6.0), 60 * TS
    good = measure(truth, t, np.random.default_rng(5))
    m = good[1]
    bad = [MarkerMeasurement(t, m.marker_id, [np.nan, 0, 1], m.q_CM),
           MarkerMeasurement(t, m.marker_id, m.p_CM, [0, np.nan, 0, 1]),
           MarkerMeasurement(t, m.marker_id, m.p_CM, 1.2 * m.q_CM),  # |q| = 1.2
           MarkerMeasurement(t, 42, m.p_CM, m.q_CM),  # not a layout marker
           MarkerMeasurement(t + 1.0, m.marker_id, m.p_CM, m.q_CM),  # from the future
           "not a measurement"]
    a.step(t, uav_over(truth(t), t), good + bad)
    b.step(t, uav_over(truth(t), t), good)
    assert_same_belief(a, b)
    assert a.stats.invalid == 6 and b.stats.invalid == 0
    assert a.stats.accepted == b.stats.accepted


@pytest.mark.parametrize("error", [1.0, 2.0])
def test_a_quaternion_norm_tolerance_of_one_or_more_is_refused(error):
    """At 1 a zero quaternion, | |q| - 1 | = 1, would pass the screening."""
    with pytest.raises(ConfigError, match=r"estimation\.ekf\.max_quaternion_norm_error must be in \(0, 1\)"):
        MarkerEkfConfig(max_quaternion_norm_error=error).validate("estimation.ekf")


@pytest.mark.parametrize("field, value, message", [
    ("reset_after_rejected_steps", 0, r"estimation\.ekf\.reset_after_rejected_steps must be at least 1"),
    ("history_s", -0.01, r"estimation\.ekf\.history_s must not be negative"),
])
def test_a_config_out_of_range_is_refused_by_name(field, value, message):
    with pytest.raises(ConfigError, match=message):
        MarkerEkfConfig(**{field: value}).validate("estimation.ekf")


@pytest.mark.parametrize("field, value", [("reset_after_rejected_steps", 1), ("history_s", 0.0)])
def test_the_configs_bounds_themselves_are_accepted(field, value):
    """A restart after a single fully gated step, and no history (late measurements all too late), are legitimate."""
    MarkerEkfConfig(**{field: value}).validate("estimation.ekf")


@pytest.mark.parametrize("cls", BOTH)
def test_a_quaternion_without_a_direction_is_rejected_at_any_tolerance(cls):
    """Norm 5e-7: within a tolerance just below 1 of unit length, but no attitude; counted invalid, the filter
    not started on it."""
    marker_filter = make(cls, max_quaternion_norm_error=1 - 1e-7)
    truth = straight(6.0)
    frame = measure(truth, 0.0, np.random.default_rng(5))
    tiny = [MarkerMeasurement(0.0, m.marker_id, m.p_CM, 5e-7 * m.q_CM) for m in frame]
    marker_filter.step(0.0, uav_over(truth(0.0), 0.0), tiny)
    assert marker_filter.stats.invalid == 5 and marker_filter.stats.accepted == 0 and not marker_filter.started


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("cls", BOTH)
def test_an_estimate_with_a_figure_not_finite_is_invalid(cls):
    """A state whose attitude is lost (a zero quaternion, or a NaN yaw): its position std is small, and the
    estimate is still invalid, for every step of a stack alike."""
    marker_filter = make(cls)
    x = state_from_truth(cls, pose([12, -4, 1.6], [0, 0, 35]))
    broken = x.copy()
    if cls is PaperMarkerEkf:
        broken[marker_filter._q] = 0.0
    else:
        broken[ConstantTurnEkf.PSI] = np.nan
    vectors, _, _ = marker_filter.estimate_vectors(np.stack([x, broken]), np.array([0.01, 0.01]), np.array([1.0, 1.0]))
    assert vectors[:, EST_VALID].tolist() == [1.0, 0.0]
    assert not np.isfinite(vectors[1]).all()


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("variance, std, valid", [(0.36, 0.6, 0.0), (0.25, 0.5, 1.0), (0.16, 0.4, 1.0)])
def test_the_estimates_position_std_is_the_square_root_of_its_variance(cls, variance, std, valid):
    """The pad position's variance 0.36 m^2 is a std of 0.6 m: reported so, and over a 0.5 m limit invalid; 0.25 m^2
    is exactly the limit (sqrt(0.25) = 0.5 in floating point), at most it, so valid, as 0.4 m is."""
    marker_filter = make(cls, max_valid_position_std_m=0.5)
    x = state_from_truth(cls, pose([12, -4, 1.6], [0, 0, 35]))
    vector, _, _ = marker_filter.estimate_vectors(x, variance, 1.0)
    assert vector[EST_POSITION_STD] == pytest.approx(std, abs=1e-12) and vector[EST_VALID] == valid


@pytest.mark.parametrize("cls", BOTH)
def test_no_measurement_fused_yet_is_a_nan_time_in_the_estimate(cls):
    """A newest-measurement time of -inf (none yet, as a stack's records hold before the start) is reported NaN,
    beside a finite one, and the estimate stays valid (the time is not one of its figures)."""
    marker_filter = make(cls)
    x = state_from_truth(cls, pose([12, -4, 1.6], [0, 0, 35]))
    vectors, _, _ = marker_filter.estimate_vectors(np.stack([x, x]), np.array([0.01, 0.01]), np.array([-np.inf, 1.0]))
    assert np.isnan(vectors[0, EST_LAST_MEASUREMENT]) and vectors[1, EST_LAST_MEASUREMENT] == 1.0
    assert vectors[:, EST_VALID].tolist() == [1.0, 1.0]


def test_an_estimate_with_a_marker_position_not_finite_is_invalid():
    """The paper filter estimates each marker apart: marker 2's position NaN leaves the pad's own figures (marker
    0's) finite, and the estimate, whose p_WM carries it, is invalid all the same."""
    marker_filter = make(PaperMarkerEkf)
    x = state_from_truth(PaperMarkerEkf, pose([12, -4, 1.6], [0, 0, 35]))
    broken = x.copy()
    broken[12:15] = np.nan  # marker 2's position: six states per marker
    vectors, p_WM, _ = marker_filter.estimate_vectors(np.stack([x, broken]), np.array([0.01, 0.01]),
                                                      np.array([1.0, 1.0]))
    assert np.isfinite(np.delete(vectors, EST_VALID, axis=1)).all() and np.isnan(p_WM[1, 2]).all()
    assert vectors[:, EST_VALID].tolist() == [1.0, 0.0]


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("outlier", ["moved 1 m", "flipped"])
def test_the_chi_square_gate_rejects_a_gross_outlier(cls, outlier):
    a, b = twins(cls)
    truth, t = straight(6.0), 60 * TS
    measurements = measure(truth, t, np.random.default_rng(5))
    m = measurements[2]
    if outlier == "moved 1 m":
        wrong = MarkerMeasurement(t, m.marker_id, m.p_CM + [0.6, -0.8, 0.0], m.q_CM)
    else:  # the attitude upside down, as a planar marker's pose ambiguity can give
        wrong = MarkerMeasurement(t, m.marker_id, m.p_CM, drake_to_paper(
            m.X_CM.rotation().multiply(RotationMatrix.MakeXRotation(np.pi))))
    a.step(t, uav_over(truth(t), t), measurements[:2] + [wrong] + measurements[3:])
    b.step(t, uav_over(truth(t), t), measurements[:2] + measurements[3:])
    assert_same_belief(a, b, atol=1e-12)
    assert a.stats.gated == 1 and b.stats.gated == 0


@pytest.mark.parametrize("cls", BOTH)
def test_the_newest_measurement_fused_is_not_a_later_gated_one(cls):
    """One step brings a frame taken half a step before it (fused) and one at the step, every marker 5 m off
    (gated): the estimate's newest fused measurement is the first frame's."""
    marker_filter = converged(cls)
    truth, t = straight(6.0), 60 * TS
    rng = np.random.default_rng(5)
    good = measure(truth, t - TS / 2, rng)
    bad = [MarkerMeasurement(t, m.marker_id, m.p_CM + 5.0, m.q_CM) for m in measure(truth, t, rng)]
    before = marker_filter.stats
    marker_filter.step(t, uav_over(truth(t), t), good + bad)
    after = marker_filter.stats
    assert (after.accepted - before.accepted, after.gated - before.gated) == (5, 5)
    assert marker_filter.estimate_vector()[0][EST_LAST_MEASUREMENT] == pytest.approx(t - TS / 2, abs=1e-12)
    assert marker_filter.estimate().vector[EST_LAST_MEASUREMENT] == pytest.approx(t - TS / 2, abs=1e-12)


@pytest.mark.parametrize("offset, fused", [(0.65, 5), (0.75, 4)])
def test_the_gate_weighs_each_marker_by_its_own_innovation_covariance(offset, fused):
    """A still pad seen exactly, the filter started on it (velocities, yaw rate and process noise made negligible):
    at the next step its position covariance is 0.1^2 I, so marker 0's (at P's origin: no yaw in its position)
    innovation covariance in p_CM is 0.01 + 0.1^2 = 0.02 on each axis. Marker 0 alone moved `offset` along the
    camera's x: its NIS offset^2 / 0.02 is 21.1 at 0.65 m, under the gate chi2.ppf(0.9999, 6) = 27.9, fused;
    28.1 at 0.75 m, gated. Weighed with the other markers' rows, which share the pad's position, it would not be
    its own NIS: (100 (I - 1 1^T / 6))_00 0.65^2 = 35.2 at 0.65 m, gated."""
    marker_filter = make(ConstantTurnEkf, initial_velocity_std_mps=1e-6, initial_angular_velocity_std_radps=1e-6,
                         acceleration_psd=1e-9, vertical_acceleration_psd=1e-9, angular_acceleration_psd=1e-9)
    assert marker_filter._gate == pytest.approx(chi2.ppf(0.9999, 6))
    assert 0.65**2 / 0.02 < chi2.ppf(0.9999, 6) < 0.75**2 / 0.02
    np.testing.assert_array_equal(LAYOUT.p_PM[0], 0.0)
    X_WP = RigidTransform(RotationMatrix.MakeZRotation(np.radians(30.0)), [5.0, -3.0, 1.6])
    X_WB = uav_over(X_WP, 0.0)
    X_CP = X_WB.multiply(X_BC).InvertAndCompose(X_WP)
    rng = np.random.default_rng(0)
    marker_filter.step(0.0, X_WB, synthetic_marker_measurements(X_CP, LAYOUT, rng, 0.0, 0.0, 0.0))
    exact = synthetic_marker_measurements(X_CP, LAYOUT, rng, 0.0, 0.0, TS)
    moved = MarkerMeasurement(TS, exact[0].marker_id, exact[0].p_CM + [offset, 0.0, 0.0], exact[0].q_CM)
    marker_filter.step(TS, X_WB, [moved] + exact[1:])
    assert marker_filter.stats == FilterStats(accepted=5 + fused, gated=5 - fused)


def test_the_paper_filters_gate_has_the_six_degrees_of_freedom_of_a_pose():
    """Its measurement has 7 rows, but the unit quaternion's 4 components carry 3 degrees of freedom."""
    assert make(PaperMarkerEkf, gate_probability=0.99)._gate == pytest.approx(chi2.ppf(0.99, 6), rel=1e-12)
    assert make(ConstantTurnEkf, gate_probability=0.99)._gate == pytest.approx(chi2.ppf(0.99, 6), rel=1e-12)


@pytest.mark.parametrize("cls", BOTH)
def test_the_gate_rejects_correct_measurements_at_its_probabilitys_rate(cls):
    """gate_probability 0.9 on the measurements of the model (after a 60-step settle): 10 % of 3000 gated,
    to 4 binomial standard deviations (0.022). A gate of the paper filter's 7 rows rejects 5 %."""
    marker_filter = make(cls, gate_probability=0.9)
    drive(marker_filter, straight(6.0), steps=60, seed=0)
    before = marker_filter.stats
    drive(marker_filter, straight(6.0), steps=600, seed=10, first=60)
    gated, accepted = marker_filter.stats.gated - before.gated, marker_filter.stats.accepted - before.accepted
    assert gated + accepted == 3000 and marker_filter.stats.resets == 0
    assert gated / 3000 == pytest.approx(0.1, abs=4 * np.sqrt(0.1 * 0.9 / 3000))


@pytest.mark.parametrize("cls", BOTH)
def test_measurements_rejected_for_many_steps_restart_the_filter(cls):
    marker_filter = converged(cls)
    moved = lambda t: straight(6.0)(t).multiply(RigidTransform([0.0, 4.0, 0.0]))  # the pad is elsewhere now
    steps = marker_filter.config.reset_after_rejected_steps
    accepted = marker_filter.stats.accepted
    drive(marker_filter, moved, steps=steps, first=60)
    # The restart uses the last step's five markers: they count as accepted, the steps before as gated, and
    # the estimate's newest measurement is that step's.
    stats = marker_filter.stats
    assert (stats.resets, stats.gated, stats.accepted) == (1, 5 * (steps - 1), accepted + 5)
    assert marker_filter.estimate_vector()[0][EST_LAST_MEASUREMENT] == pytest.approx((60 + steps - 1) * TS)
    position = drive(marker_filter, moved, steps=60, first=60 + steps)[0]
    assert position[-1] < 0.15


@pytest.mark.parametrize("cls", BOTH)
def test_steps_with_only_some_measurements_gated_do_not_restart_the_filter(cls):
    """reset_after_rejected_steps steps in a row in which marker 2 is seen 5 m off and the other four right: every
    step fused some, so none counts toward a restart; marker 2 gated each time, the others accepted."""
    marker_filter = converged(cls, steps=30)
    truth, rng = straight(6.0), np.random.default_rng(1)
    steps = marker_filter.config.reset_after_rejected_steps
    before = marker_filter.stats
    for k in range(30, 30 + steps):
        t = k * TS
        frame = measure(truth, t, rng)
        frame[2] = MarkerMeasurement(t, frame[2].marker_id, frame[2].p_CM + [5.0, 0.0, 0.0], frame[2].q_CM)
        marker_filter.step(t, uav_over(truth(t), t), frame)
    after = marker_filter.stats
    assert (after.resets, after.gated - before.gated, after.accepted - before.accepted) == (0, steps, 4 * steps)


@pytest.mark.parametrize("cls", BOTH)
def test_late_measurements_are_fused_as_if_they_had_arrived_on_time(cls):
    truth = circle(6.0, 41.0)
    on_time, late = make(cls), make(cls)
    rng, delays = np.random.default_rng(2), np.random.default_rng(3)
    arriving = {}  # step -> measurements arriving then
    for k in range(80):
        t = k * TS
        measurements = measure(truth, t, rng)
        on_time.step(t, uav_over(truth(t), t), measurements)
        for m in measurements:  # 0 to 3 steps late (the paper's 35 ms budget is one), in any order
            arriving.setdefault(k + int(delays.integers(0, 4)), []).append(m)
    for k in range(80):
        t = k * TS
        late.step(t, uav_over(truth(t), t), arriving.get(k, [])[::-1])
    for k in range(80, 84):  # the last ones arrive after the drive; the on-time filter just predicts
        t = k * TS
        on_time.step(t, uav_over(truth(t), t), [])
        late.step(t, uav_over(truth(t), t), arriving.get(k, []))
    assert_same_belief(on_time, late, atol=1e-9)
    assert late.stats == on_time.stats


@pytest.mark.parametrize("cls", BOTH)
def test_a_steps_measurements_in_any_order_give_the_same_belief(cls):
    """One step brings a frame taken half a step before it and one taken at it: handed over in either order, the
    filter fuses them in time order, the same belief."""
    truth, rng = straight(6.0), np.random.default_rng(0)
    a, b = make(cls), make(cls)
    first = measure(truth, 0.0, rng)
    for marker_filter in (a, b):
        marker_filter.step(0.0, uav_over(truth(0.0), 0.0), first)
    mid, now = measure(truth, TS / 2, rng, time=TS / 2), measure(truth, TS, rng)
    a.step(TS, uav_over(truth(TS), TS), mid + now)
    b.step(TS, uav_over(truth(TS), TS), now + mid)
    assert_same_belief(a, b)
    assert a.stats == b.stats == FilterStats(accepted=15)


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("before", [0.5, 0.25])
def test_a_measurement_between_steps_is_fused_at_its_own_time(cls, before):
    """Taken half (or a quarter of) a step before the step it arrives at, with the UAV moving: the filter
    interpolates the UAV's pose (exact here: constant velocity and attitude) and fuses it at its own time, as a
    filter stepped at that time does (a quarter step early: three quarters of the way from the previous step)."""
    truth = straight(6.0)
    uav = lambda t: RigidTransform(RollPitchYaw(0.02, -0.01, 0.3), truth(t).translation() + [0.2, 0.1, 3.0])
    stepped_there, on_grid = make(cls), make(cls)
    rng = np.random.default_rng(4)
    for k in range(40):
        t, t_m = k * TS, (k - before) * TS
        measurements = []
        if k:
            X_CP = uav(t_m).multiply(X_BC).InvertAndCompose(truth(t_m))
            measurements = synthetic_marker_measurements(X_CP, LAYOUT, rng, time=t_m)
            stepped_there.step(t_m, uav(t_m), measurements)
        stepped_there.step(t, uav(t), [])
        on_grid.step(t, uav(t), measurements)
    assert_same_belief(stepped_there, on_grid, atol=1e-9)


@pytest.mark.parametrize("cls", BOTH)
def test_a_measurement_exactly_history_s_late_is_fused(cls):
    """history_s = 3 T_s: frame 8 held back and handed in at step 11 with frame 11, exactly history_s late. The
    step it was taken in is still kept, so it is fused as if it had arrived on time: the belief of a filter given
    every frame on time, all 12 frames' 60 marker measurements accepted, none too late."""
    truth, rng = straight(6.0), np.random.default_rng(0)
    on_time, late = make(cls, history_s=3 * TS), make(cls, history_s=3 * TS)
    held = []
    for k in range(12):
        t = k * TS
        frame = measure(truth, t, rng)
        on_time.step(t, uav_over(truth(t), t), frame)
        if k == 8:
            held, frame = frame, []
        late.step(t, uav_over(truth(t), t), held + frame if k == 11 else frame)
    assert late.stats == on_time.stats == FilterStats(accepted=60)
    assert_same_belief(on_time, late, atol=1e-9)


@pytest.mark.parametrize("cls", BOTH)
def test_measurements_older_than_the_history_are_counted_too_late(cls):
    a, b = twins(cls)
    truth, t = straight(6.0), 60 * TS
    stale = measure(truth, t - 1.0, np.random.default_rng(6))  # 1 s old; the history keeps 0.5 s
    a.step(t, uav_over(truth(t), t), stale)
    b.step(t, uav_over(truth(t), t), [])
    assert_same_belief(a, b)
    assert a.stats.too_late == 5


@pytest.mark.parametrize("cls", BOTH)
def test_measurements_older_than_the_first_step_are_too_late_and_do_not_start_the_filter(cls):
    """A fresh filter's first step, at 2 s, given a frame of 1 s before it: there is no step of that time to fuse
    it in, so its five markers count as too late and the filter has not started."""
    marker_filter, truth, t = make(cls), straight(6.0), 2.0
    marker_filter.step(t, uav_over(truth(t), t), measure(truth, t - 1.0, np.random.default_rng(6)))
    assert not marker_filter.started
    assert marker_filter.stats.too_late == len(LAYOUT.ids) == 5


@pytest.mark.parametrize("cls", BOTH)
def test_a_step_must_come_after_the_previous_one(cls):
    """A second step at the previous step's time (or before it) is refused, not taken as a new step."""
    marker_filter, truth = make(cls), straight(6.0)
    marker_filter.step(1.0, uav_over(truth(1.0), 1.0), [])
    for t in (1.0, 0.9):
        with pytest.raises(ValueError, match="does not follow the previous step"):
            marker_filter.step(t, uav_over(truth(t), t), [])


@pytest.mark.parametrize("cls", BOTH)
def test_a_late_measurement_at_the_oldest_kept_steps_time_is_too_late(cls):
    """Once the history has dropped its first steps, the oldest step kept has lost the posterior it was run
    from: a measurement taken at its time cannot be re-run into it. It counts as too late and leaves the
    belief as it was (it must not restart the filter from that frame alone)."""
    a, b = twins(cls)
    truth, t = straight(6.0), 60 * TS
    oldest = a._history[0].time
    assert oldest > 0 and t - oldest > a.config.history_s  # the first steps were dropped
    a.step(t, uav_over(truth(t), t), measure(truth, oldest, np.random.default_rng(6)))
    b.step(t, uav_over(truth(t), t), [])
    assert_same_belief(a, b)
    assert a.stats.too_late == 5 and a.stats.resets == b.stats.resets == 0


def test_the_camera_between_two_steps_across_a_yaw_of_180_degrees_is_halfway():
    """The UAV yawed 179 deg at one step and 181 deg at the next: Drake's quaternions of the two (w >= 0) have
    opposite signs, the same attitudes as q and -q. Halfway between them the camera is that of the UAV at
    180 deg and the mid position (Drake's X_WB X_BC), not turned back through 0 deg."""
    marker_filter = make(ConstantTurnEkf)
    X_WB = [RigidTransform(RollPitchYaw(0.04, -0.03, np.radians(yaw)), p)
            for yaw, p in ((179.0, [1.0, 2.0, 4.0]), (181.0, [1.4, 1.8, 4.2]))]
    a, b = (marker_filter.camera_at(X) for X in X_WB)
    assert a.q_BR @ b.q_BR < 0
    halfway = marker_filter._interpolate(a, b, 0.5)
    X_WC = RigidTransform(RollPitchYaw(0.04, -0.03, np.pi), [1.2, 1.9, 4.1]).multiply(X_BC)
    np.testing.assert_allclose(halfway.R_CW, X_WC.rotation().inverse().matrix(), atol=1e-12)
    np.testing.assert_allclose(halfway.p_WC, X_WC.translation(), atol=1e-12)


# ---- any subset of markers ---------------------------------------------------------------------


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("ids", [[0], [3], [1, 2], [0, 2, 4]])
def test_any_subset_of_markers(cls, ids):
    marker_filter = make(cls)
    position, _, markers, _ = drive(marker_filter, straight(6.0), steps=200, visible=lambda k: ids)
    seen = [LAYOUT.index(i) for i in ids]
    assert markers[-50:, seen].max() < 0.25
    if cls is ConstantTurnEkf or 0 in ids:
        assert position[-50:].max() < 0.25 and marker_filter.estimate().X_WP.valid
    else:  # the paper's markers are independent: the pad (marker 0) is only predicted, and invalid
        assert not marker_filter.estimate().X_WP.valid


@pytest.mark.parametrize("cls", BOTH)
def test_a_different_random_subset_each_step(cls):
    marker_filter = make(cls)
    rng = np.random.default_rng(8)
    visible = lambda k: list(rng.choice(LAYOUT.ids, size=rng.integers(0, 6), replace=False))
    position, _, markers, _ = drive(marker_filter, straight(6.0), steps=250, visible=visible)
    assert position[-50:].max() < 0.25 and markers[-50:].max() < 0.3


# ---- the Drake system --------------------------------------------------------------------------


def filter_diagram(cls, X_WB, X_WP, delay_steps=0):
    builder = DiagramBuilder()
    uav = builder.AddSystem(ConstantValueSource(AbstractValue.Make(X_WB)))
    pad = builder.AddSystem(ConstantValueSource(AbstractValue.Make(X_WP)))
    source = builder.AddSystem(SyntheticMarkerSource(LAYOUT, X_BC, TS, seed=1))
    latency = builder.AddSystem(MeasurementLatency(TS, delay_steps))
    estimator = builder.AddSystem(MarkerFilterSystem(make(cls)))
    builder.Connect(uav.get_output_port(), source.GetInputPort("X_WB"))
    builder.Connect(pad.get_output_port(), source.GetInputPort("X_WP"))
    builder.Connect(source.get_output_port(), latency.get_input_port())
    builder.Connect(uav.get_output_port(), estimator.GetInputPort("X_WB"))
    builder.Connect(latency.get_output_port(), estimator.GetInputPort("marker_measurements"))
    return builder.Build(), estimator


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize("delay_steps", [0, 1])
def test_filter_system_estimates_a_still_pad(cls, delay_steps):
    X_WB, X_WP = pose([3.2, 1.1, 4.6], [2, -1, 80]), pose([3.0, 1.0, 1.6], [0, 0, 70])
    diagram, estimator = filter_diagram(cls, X_WB, X_WP, delay_steps)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(60 * TS)
    context = estimator.GetMyContextFromRoot(simulator.get_context())
    estimate = estimator.GetOutputPort("X_WP_estimate").Eval(context)
    assert estimate.valid and estimate.time == pytest.approx(60 * TS)
    assert np.linalg.norm(estimate.X_RT.translation() - X_WP.translation()) < 0.1
    assert X_WP.rotation().InvertAndCompose(estimate.X_RT.rotation()).ToAngleAxis().angle() < np.radians(3)
    p_WM = estimator.GetOutputPort("p_WM_estimate").Eval(context).reshape(5, 3)
    np.testing.assert_allclose(p_WM, X_WP.multiply(LAYOUT.p_PM.T).T, atol=0.2)  # the paper's: 0.06 m std
    stats = estimator.GetOutputPort("filter_stats").Eval(context)
    # 61 steps (t = 0 to 60 TS: the outputs at a step time include that step); with latency, the
    # first step has nothing yet
    assert stats.accepted == 5 * (61 - delay_steps) and stats.too_late == 0 and stats.invalid == 0
    vector = estimator.GetOutputPort("estimate_vector").Eval(context)
    assert vector[EST_LAST_MEASUREMENT] == pytest.approx((60 - delay_steps) * TS)
    np.testing.assert_allclose(vector[EST_P_WP], estimate.X_RT.translation())
    assert np.linalg.norm(estimator.GetOutputPort("v_WP_estimate").Eval(context)) < 1.0  # still (noise: ~0.3)
    np.testing.assert_allclose(vector[EST_V_WP], estimator.GetOutputPort("v_WP_estimate").Eval(context))
    simulator.AdvanceTo(60.5 * TS)  # between updates: the outputs are predicted to the context's time
    assert estimator.GetOutputPort("X_WP_estimate").Eval(context).time == pytest.approx(60.5 * TS)


def test_filter_system_contexts_do_not_share_the_filter():
    X_WB, X_WP = pose([0, 0, 4.6], [0, 0, 0]), pose([0, 0, 1.6], [0, 0, 0])
    diagram, estimator = filter_diagram(ConstantTurnEkf, X_WB, X_WP)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(10 * TS)
    clone = simulator.get_context().Clone()
    simulator.AdvanceTo(20 * TS)
    stats = lambda c: estimator.GetOutputPort("filter_stats").Eval(estimator.GetMyContextFromRoot(c))
    assert stats(clone).accepted == 55 and stats(simulator.get_context()).accepted == 105


def test_reading_the_filter_system_leaves_its_stored_filter_as_it_was():
    """An output read at a step time steps a copy of the stored filter: the context's filter is stored only by the
    update. Read at t = 0 with no measurements yet, the stored filter is still unstarted; the measurements of
    t = 0 then arriving (another system's update at the same time) are in the step the next read and the
    update take, all five accepted."""
    X_WB, X_WP = pose([0, 0, 4.6], [0, 0, 0]), pose([0, 0, 1.6], [0, 0, 30])
    estimator = MarkerFilterSystem(make(ConstantTurnEkf))
    context = estimator.CreateDefaultContext()
    estimator.GetInputPort("X_WB").FixValue(context, X_WB)
    estimator.GetInputPort("marker_measurements").FixValue(context, [])
    assert not estimator.GetOutputPort("X_WP_estimate").Eval(context).valid
    stored = context.get_abstract_state(0).get_value()
    assert stored.time is None and stored.stats.accepted == 0
    X_CP = X_BC.inverse().multiply(X_WB.inverse()).multiply(X_WP)
    measurements = synthetic_marker_measurements(X_CP, LAYOUT, np.random.default_rng(1), time=0.0)
    estimator.GetInputPort("marker_measurements").FixValue(context, measurements)
    assert estimator.GetOutputPort("filter_stats").Eval(context).accepted == 5
    assert estimator.GetOutputPort("X_WP_estimate").Eval(context).valid


def test_filters_are_registered_by_name():
    assert FILTERS == {"paper_ekf": PaperMarkerEkf, "ct_ekf": ConstantTurnEkf}
