"""Seed 003's velocity observer (Eq. 15-19) and frame transforms (Eq. 20-22),
systems/estimators/velocity_observer.py: hand-computed transforms, Drake's rotations, the NED boundary,
constant and turning velocities from seeded noisy positions, the lag on a step, validity, the LeafSystem."""

import math

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator

from systems.config import ConfigError
from systems.estimators import velocity_observer
from systems.estimators.velocity_observer import (
    R_B_FRD,
    R_NW,
    ObserverState,
    VelocityObserverConfig,
    VelocityObserverSystem,
    camera_to_world,
    gaussian_weights,
    linear_fit_now,
    ned_to_world,
    observe_velocities,
    paper_rotation_matrix,
    paper_velocity_to_world,
    pixel_displacement_to_camera,
    pixel_to_ground_W,
    rotation_ned_frd,
    speed_and_heading,
    step_observer,
    weighted_velocity,
    world_to_ned,
)
from systems.geometry import ray_to_plane
from systems.noise import sample_rng

K = np.array([[200.0, 0.0, 255.5], [0.0, 210.0, 250.0], [0.0, 0.0, 1.0]])  # fx != fy to tell the axes apart
X_BC = RigidTransform(RotationMatrix.MakeXRotation(math.pi), [0.0, 0.0, -0.04])  # the project's camera mount
T = 0.1  # the default 10 Hz


# ----------------------------------------------------------------------------------------------
# Frame transforms


def test_eq15_pixel_displacement_to_metres():
    d_C = pixel_displacement_to_camera([10.0, -21.0], 7.5, K)
    np.testing.assert_allclose(d_C, [10.0 * 7.5 / 200.0, -21.0 * 7.5 / 210.0, 0.0])
    square = np.diag([200.0, 200.0, 1.0])  # equal focal lengths: Eq. 15's length s_ugv = f_pd Z / f
    assert np.linalg.norm(pixel_displacement_to_camera([3.0, 4.0], 6.0, square)) == pytest.approx(5.0 * 6.0 / 200.0)


def test_eq22_camera_to_world_by_hand_and_against_drake():
    # level UAV yawed 90 deg: image +x (C) is body forward (B +x), which points along W +y; image +y is
    # the body's right (-y_B), which points along W +x
    R_WB = RotationMatrix.MakeZRotation(math.pi / 2)
    np.testing.assert_allclose(camera_to_world([1.0, 0.0, 0.0], R_WB, X_BC.rotation()), [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(camera_to_world([0.0, 1.0, 0.0], R_WB, X_BC.rotation()), [1.0, 0.0, 0.0], atol=1e-12)
    rng = np.random.default_rng(7)
    for _ in range(5):
        X_WB = RigidTransform(RollPitchYaw(rng.uniform(-0.4, 0.4, 3) * [1, 1, 8]), rng.normal(0, 5, 3))
        v_C = rng.normal(0, 1, 3)
        expected = X_WB.multiply(X_BC).rotation().multiply(v_C)  # a free vector: rotation only (Eq. 22)
        np.testing.assert_allclose(camera_to_world(v_C, X_WB.rotation(), X_BC.rotation().matrix()), expected,
                                   atol=1e-12)


def test_pixel_to_ground_level_camera_by_hand():
    X_WB = RigidTransform([1.0, 2.0, 7.54])  # level; the camera 7.5 m above the ground z = 0
    X_WC = X_WB.multiply(X_BC)
    p = pixel_to_ground_W([255.5 + 40.0, 250.0 - 42.0], 7.5, K, X_WC)
    # Eq. 15 in C: [40 * 7.5 / 200, -42 * 7.5 / 210, 7.5] = [1.5, -1.5, 7.5]; C -> W (a half turn about x): [x, -y, -z]
    np.testing.assert_allclose(p, [1.0 + 1.5, 2.0 + 1.5, 0.0], atol=1e-12)
    # between two pixels under a still, level camera: Eq. 15 and Eq. 22 on the displacement
    q = pixel_to_ground_W([255.5 + 33.0, 250.0 - 2.0], 7.5, K, X_WC)
    d_W = camera_to_world(pixel_displacement_to_camera([33.0 - 40.0, -2.0 + 42.0], 7.5, K), X_WB.rotation(),
                          X_BC.rotation())
    np.testing.assert_allclose(q - p, d_W, atol=1e-12)


def test_pixel_to_ground_tilted_camera_reprojects():
    X_WB = RigidTransform(RollPitchYaw(0.15, -0.2, 1.0), [3.0, -1.0, 6.0])
    X_WC = X_WB.multiply(X_BC)
    h = X_WC.translation()[2]  # the ground z = 0
    for uv in ([100.0, 60.0], [255.5, 250.0], [400.0, 420.0]):
        p = pixel_to_ground_W(uv, h, K, X_WC)
        assert p[2] == pytest.approx(0.0, abs=1e-12)
        p_C = X_WC.inverse().multiply(p)
        np.testing.assert_allclose((K @ p_C)[:2] / p_C[2], uv, atol=1e-9)
    upside_down = RigidTransform(RotationMatrix(), [0.0, 0.0, 5.0])  # optical axis up: no ground in view
    assert pixel_to_ground_W([255.5, 250.0], 5.0, K, upside_down) is None
    assert pixel_to_ground_W([255.5, 250.0], 0.0, K, X_WC) is None


def test_pixel_to_ground_is_ray_to_plane_with_any_downward_ray(monkeypatch):
    """pixel_to_ground_W cuts the pixel's ray with the plane by the hybrid estimate's one routine, ray_to_plane,
    refusing only rays that do not point down (the hybrid estimate refuses oblique ones too): the same points as
    before for rays that do (p_C + height / -r_z r), and a 80 deg ray, which the hybrid estimate's default refuses."""
    X_WC = RigidTransform(RollPitchYaw(0.15, -0.2, 1.0), [3.0, -1.0, 6.0]).multiply(X_BC)
    p_WC = X_WC.translation()
    for uv in ([100.0, 60.0], [255.5, 250.0], [400.0, 420.0]):
        ray_W = X_WC.rotation().multiply(np.linalg.solve(K, [uv[0], uv[1], 1.0]))
        before = p_WC + (5.5 / -ray_W[2]) * ray_W
        p = pixel_to_ground_W(uv, 5.5, K, X_WC)
        assert np.array_equal(p[:2], before[:2]) and p[2] == pytest.approx(before[2], abs=1e-12)
    level = RigidTransform(RotationMatrix.MakeXRotation(math.pi), [0.0, 0.0, 5.0])  # looking straight down
    u = 255.5 + 200.0 * math.tan(math.radians(80))
    ray_W = level.rotation().multiply(np.linalg.solve(K, [u, 250.0, 1.0]))
    assert ray_to_plane(level.translation(), ray_W / np.linalg.norm(ray_W), 4.5, 0.5) is None
    np.testing.assert_allclose(pixel_to_ground_W([u, 250.0], 4.5, K, level),
                               [4.5 * math.tan(math.radians(80)), 0.0, 0.5], atol=1e-9)
    calls = []
    monkeypatch.setattr(velocity_observer, "ray_to_plane", lambda *a, **kw: calls.append(kw) or ray_to_plane(*a, **kw))
    pixel_to_ground_W([255.5, 250.0], 4.5, K, level)
    assert len(calls) == 1


def test_ned_boundary():
    # W read as ENU at the boundary: east (x_W) is NED's second axis, north (y_W) its first, up is -down
    np.testing.assert_allclose(world_to_ned([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0])
    np.testing.assert_allclose(world_to_ned([0.0, 1.0, 0.0]), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(world_to_ned([0.0, 0.0, 1.0]), [0.0, 0.0, -1.0])
    np.testing.assert_allclose(ned_to_world(world_to_ned([0.3, -2.0, 0.7])), [0.3, -2.0, 0.7])
    for R in (R_NW, R_B_FRD):
        assert np.linalg.det(R) == pytest.approx(1.0)  # proper rotations
    # a level UAV heading north (yaw 90 deg in W) is the FRD body aligned with NED: q = identity
    R_N_FRD = R_NW @ RotationMatrix.MakeZRotation(math.pi / 2).matrix() @ R_B_FRD
    np.testing.assert_allclose(R_N_FRD, np.eye(3), atol=1e-12)


def test_eq21_is_the_transpose_of_the_hamilton_rotation():
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = rng.normal(0, 1, 4)
        q /= np.linalg.norm(q)
        R_drake = RotationMatrix(Quaternion(q)).matrix()  # Drake: [w, x, y, z], Hamilton
        np.testing.assert_allclose(paper_rotation_matrix(q), R_drake.T, atol=1e-12)
        assert not np.allclose(paper_rotation_matrix(q), R_drake, atol=1e-3)  # as printed, it is not R itself


def test_eq22_end_to_end_from_the_papers_frames():
    """A velocity given as the paper would (FRD body, attitude quaternion of FRD in NED) reaches W as Drake's
    R_WB does it in our frames."""
    rng = np.random.default_rng(5)
    for _ in range(5):
        R_WB = RotationMatrix(RollPitchYaw(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-3, 3)))
        v_B = rng.normal(0, 1, 3)
        q = RotationMatrix(R_NW @ R_WB.matrix() @ R_B_FRD).ToQuaternion().wxyz()
        np.testing.assert_allclose(rotation_ned_frd(q), R_NW @ R_WB.matrix() @ R_B_FRD, atol=1e-12)
        np.testing.assert_allclose(paper_velocity_to_world(R_B_FRD.T @ v_B, q), R_WB.multiply(v_B), atol=1e-12)


# ----------------------------------------------------------------------------------------------
# Eq. 16-19


def noisy_track(positions: np.ndarray, std: float, seed: int) -> np.ndarray:
    """Positions with seeded Gaussian noise of `std` [m] on x and y, sample k from sample_rng(seed, ...)."""
    noise = np.array([sample_rng(seed, "target_position", k).normal(0.0, std, 2) for k in range(len(positions))])
    return positions + np.c_[noise, np.zeros(len(positions))]


def noise_gain(config: VelocityObserverConfig) -> float:
    """The estimate's noise std per axis [m/s] per metre of position noise: the weighted sum of differences
    is (1/T) sum_k (w_k - w_{k-1}) n_k over the window's positions, w normalised."""
    w = gaussian_weights(np.arange(round(config.window_s / T) + 1) * T, config.sigma_s)
    return math.sqrt(w[0] ** 2 + np.sum(np.diff(w) ** 2) + w[-1] ** 2) / T


def test_weights_peak_at_the_current_frame_and_sum_to_one():
    w = gaussian_weights([0.0, 0.1, 0.5, 1.0], 0.5)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(np.diff(w) < 0)
    assert w[2] / w[0] == pytest.approx(math.exp(-0.5))  # one sigma old: e^-1/2 of the peak


def test_weights_of_samples_many_sigma_old_do_not_underflow():
    """Ages of 40, 45 and 50 sigma (0.8-1.0 s at sigma 0.02 s): exp(-x^2 / 2) underflows to 0 for each, yet
    the normalised weights keep Eq. 18-19's ratios to the youngest, e^-((45^2 - 40^2) / 2) and
    e^-((50^2 - 40^2) / 2) (their logs compared), the youngest's weight 1 to rounding."""
    assert math.exp(-0.5 * 40**2) == 0.0
    w = gaussian_weights([0.8, 0.9, 1.0], 0.02)
    assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0) and w[0] == pytest.approx(1.0)
    assert math.log(w[1]) == pytest.approx(-(45**2 - 40**2) / 2)
    assert math.log(w[2]) == pytest.approx(-(50**2 - 40**2) / 2)


def test_weights_of_a_young_and_a_many_sigma_old_sample_are_taken_relative_to_the_youngest():
    """Ages 0 and 50 sigma (1 s at sigma 0.02 s): relative to the youngest (x^2 = 0) the weights are e^0 and
    e^-1250, which underflows to 0, so the youngest takes all the weight. Relative to the oldest (x^2 = 2500)
    the youngest's would overflow, e^1250, and the normalisation give inf / inf."""
    assert math.exp(-0.5 * 50**2) == 0.0
    w = gaussian_weights([0.0, 1.0], 0.02)
    assert np.all(np.isfinite(w))
    np.testing.assert_array_equal(w, [1.0, 0.0])


def test_constant_velocity_from_noisy_positions():
    """1.3 m/s (x 1.2, y -0.5) with 3 cm of position noise, 60 s at 10 Hz: unbiased, and the scatter is the
    weights' noise gain (1.54 per metre: 4.6 cm/s per axis), with Eq. 18-19's weighted mean."""
    config = VelocityObserverConfig(fit="mean")
    t = np.arange(0.0, 60.0, T)
    v = np.array([1.2, -0.5, 0.0])
    estimates, valid = observe_velocities(t, noisy_track(t[:, None] * v + [3.0, 4.0, 0.0], 0.03, seed=1), config)
    assert not valid[:3].any() and valid[3:].all()  # three instant velocities need four sightings
    assert np.all(np.isnan(estimates[:3]))
    error = estimates[20:, :2] - v[:2]  # past the first window
    assert np.all(np.abs(error.mean(axis=0)) < 0.01)
    expected = 0.03 * noise_gain(config)
    assert noise_gain(config) == pytest.approx(1.544, abs=1e-3)
    np.testing.assert_allclose(error.std(axis=0), expected, rtol=0.2)
    np.testing.assert_allclose(estimates[20:, 2], 0.0, atol=1e-12)


def test_turning_velocity_lags_by_the_weights_mean_age():
    """A circle of 5 m at 1 m/s (0.2 rad/s) with 3 cm of noise: the estimate's heading lags the truth by
    omega times the weights' mean delay (0.416 s: sigma sqrt(2/pi) on the ages, plus half a frame for each
    difference's midpoint), 0.083 rad; its speed is the truth's within 2 %, its error under 0.12 m/s RMS.
    Eq. 18-19's weighted mean (`fit="mean"`)."""
    config = VelocityObserverConfig(fit="mean")
    radius, omega = 5.0, 0.2
    t = np.arange(0.0, 60.0, T)
    p = np.c_[radius * np.cos(omega * t), radius * np.sin(omega * t), np.zeros_like(t)]
    v_true = np.c_[-radius * omega * np.sin(omega * t), radius * omega * np.cos(omega * t)]
    estimates, _ = observe_velocities(t, noisy_track(p, 0.03, seed=2), config)
    speed, heading = speed_and_heading(estimates[20:])
    lag = np.remainder(np.arctan2(v_true[20:, 1], v_true[20:, 0]) - heading + np.pi, 2 * np.pi) - np.pi
    ages = np.arange(16) * T
    delay = gaussian_weights(ages, config.sigma_s) @ (ages + T / 2)
    assert delay == pytest.approx(0.416, abs=1e-3)
    assert lag.mean() == pytest.approx(omega * delay, rel=0.15)
    assert speed.mean() == pytest.approx(radius * omega, rel=0.02)
    assert np.sqrt(np.mean(np.sum((estimates[20:, :2] - v_true[20:]) ** 2, axis=1))) < 0.12


def test_lag_on_a_velocity_step():
    """Standing, then 1 m/s along x from t0 = 3 s (noise-free): k frames after the step the estimate is the
    weight of the k newest instant velocities: 15 % after one frame, over half after 0.4 s, 92 % after
    0.9 s, all of it after the 1.5 s window. Eq. 18-19's weighted mean (`fit="mean"`)."""
    config = VelocityObserverConfig(fit="mean")
    t = np.arange(0.0, 8.0, T)
    estimates, _ = observe_velocities(t, np.c_[np.maximum(t - 3.0, 0.0), np.zeros((len(t), 2))], config)
    k0 = 30
    w = gaussian_weights(np.arange(16) * T, config.sigma_s)
    np.testing.assert_allclose(estimates[k0 + 1:k0 + 17, 0], np.cumsum(w), atol=1e-12)
    np.testing.assert_allclose(estimates[k0 - 10:k0 + 1, 0], 0.0, atol=1e-12)
    assert estimates[k0 + 3, 0] < 0.5 < estimates[k0 + 4, 0]  # the half-way delay: 0.4 s
    assert estimates[k0 + 8, 0] < 0.9 < estimates[k0 + 9, 0]  # 90 %: 0.9 s


def linear_noise_gain(config: VelocityObserverConfig) -> float:
    """The linear fit's noise std per axis [m/s] per metre of position noise: its value now is sum_j c_j v_j
    over the instant velocities, c_j = w_j (1 + (a_j - m)(0 - m) / s) (m, s the weights' mean age and its
    spread), so, as for the mean, a weighted sum of differences of the window's positions."""
    ages = np.arange(round(config.window_s / T) + 1) * T
    w = gaussian_weights(ages, config.sigma_s)
    m = w @ ages
    c = w * (1 - (ages - m) * m / (w @ (ages - m) ** 2))
    return math.sqrt(c[0] ** 2 + np.sum(np.diff(c) ** 2) + c[-1] ** 2) / T


def test_linear_fit_reads_a_constant_velocity_with_more_noise_than_the_mean():
    """`fit="linear"` (a weighted line through the instant velocities, taken now) on the constant 1.3 m/s of
    the test above: unbiased, its scatter the line's noise gain (3.92 per metre against the mean's 1.54: 11.7
    against 4.6 cm/s per axis), the price of reading the velocity now rather than 0.4 s ago."""
    config = VelocityObserverConfig(fit="linear")
    t = np.arange(0.0, 60.0, T)
    v = np.array([1.2, -0.5, 0.0])
    estimates, valid = observe_velocities(t, noisy_track(t[:, None] * v + [3.0, 4.0, 0.0], 0.03, seed=1), config)
    assert valid[3:].all()
    error = estimates[20:, :2] - v[:2]
    assert np.all(np.abs(error.mean(axis=0)) < 0.015)
    assert linear_noise_gain(config) == pytest.approx(3.915, abs=1e-3)
    np.testing.assert_allclose(error.std(axis=0), 0.03 * linear_noise_gain(config), rtol=0.2)


def test_linear_fit_does_not_lag_on_a_turn():
    """The 5 m circle at 1 m/s of the lag test, noise-free: the mean's heading lags 0.083 rad; the line's only
    by the newest difference's half frame (it stands for the velocity at its interval's midpoint), omega T / 2
    = 0.010 rad, within 5 % (a constant turn is a constant acceleration but for its third-order change)."""
    radius, omega = 5.0, 0.2
    t = np.arange(0.0, 60.0, T)
    p = np.c_[radius * np.cos(omega * t), radius * np.sin(omega * t), np.zeros_like(t)]
    truth = np.arctan2(np.cos(omega * t[20:]), -np.sin(omega * t[20:]))
    lags = {}
    for fit in ("mean", "linear"):
        estimates, _ = observe_velocities(t, p, VelocityObserverConfig(fit=fit))
        _, heading = speed_and_heading(estimates[20:])
        lags[fit] = np.abs(np.remainder(truth - heading + np.pi, 2 * np.pi) - np.pi).mean()
    assert lags["mean"] == pytest.approx(0.083, abs=0.005)
    assert lags["linear"] == pytest.approx(omega * T / 2, rel=0.05)


def test_linear_fit_is_exact_on_a_constant_acceleration():
    """x = 0.3 t^2 (noise-free): the instant velocities lie on a line, so the fit's value now is the
    acceleration's line at the newest difference's midpoint, 0.6 (t - T/2), to rounding."""
    t = np.arange(0.0, 6.0, T)
    track = np.c_[0.3 * t ** 2, np.zeros((len(t), 2))]
    estimates, _ = observe_velocities(t, track, VelocityObserverConfig(fit="linear"))
    np.testing.assert_allclose(estimates[20:, 0], 0.6 * (t[20:] - T / 2), atol=1e-9)


def test_linear_fit_only_on_a_window_of_precise_sightings():
    """The circle above, each sighting flagged precise or not: the line is taken only where every instant
    velocity in the window joins two precise sightings; one imprecise sighting gives the mean (exactly) until
    the window has passed it, then the line again."""
    radius, omega = 5.0, 0.2
    t = np.arange(0.0, 12.0, T)
    p = np.c_[radius * np.cos(omega * t), radius * np.sin(omega * t), np.zeros_like(t)]
    linear, mean = VelocityObserverConfig(fit="linear"), VelocityObserverConfig(fit="mean")
    lined, _ = observe_velocities(t, p, linear)
    averaged, _ = observe_velocities(t, p, mean)
    flagged, state = [], ObserverState()
    for k, (tk, pk) in enumerate(zip(t, p)):
        state = step_observer(state, float(tk), linear, p_W=pk, precise=k != 60)
        flagged.append(state.estimate)
    flagged = np.array(flagged)
    # Sighting 60 is imprecise: the differences ending at 60 and 61 are too, for the 1.5 s window after each.
    np.testing.assert_allclose(flagged[20:60], lined[20:60], atol=1e-12)
    np.testing.assert_allclose(flagged[60:77], averaged[60:77], atol=1e-12)
    np.testing.assert_allclose(flagged[77:], lined[77:], atol=1e-12)
    assert np.abs(lined[70] - averaged[70]).max() > 0.01  # the two fits differ here


def test_imprecise_instant_velocities_do_not_feed_the_line():
    """Source displacement (instant velocities given, step_observer's v_W) on a constant acceleration,
    v = 0.5 t, every frame flagged imprecise: the line is taken only where every instant velocity in the
    window is precise (module docstring), so fit linear gives the weighted mean, exactly; the line's value
    now, 0.5 x 1.9 = 0.95 m/s at t = 1.9 s, comes only from the same frames flagged precise."""
    def run(config, precise):
        state = ObserverState()
        for k in range(20):
            state = step_observer(state, k * T, config, v_W=[0.5 * k * T, 0.0, 0.0], precise=precise)
        assert state.valid
        return state.estimate

    linear, mean = VelocityObserverConfig(fit="linear"), VelocityObserverConfig(fit="mean")
    imprecise = run(linear, False)
    np.testing.assert_allclose(imprecise, run(mean, False), atol=1e-12)
    np.testing.assert_allclose(run(linear, True), [0.5 * 19 * T, 0.0, 0.0], atol=1e-9)  # the line, precise
    assert abs(imprecise[0] - 0.5 * 19 * T) > 0.1  # the mean lags the line


def test_linear_fit_needs_linear_min_samples():
    """Precise sightings from frame 0 on: the first instant velocities give the mean until linear_min_samples (8)
    of them are in the window, then the line."""
    t = np.arange(0.0, 3.0, T)
    p = np.c_[0.5 * t ** 2, np.zeros((len(t), 2))]
    config = VelocityObserverConfig(fit="linear")
    lined, _ = observe_velocities(t, p, config)
    averaged, _ = observe_velocities(t, p, VelocityObserverConfig(fit="mean"))
    first = config.linear_min_samples  # frame k holds k instant velocities
    np.testing.assert_allclose(lined[config.min_samples:first], averaged[config.min_samples:first], atol=1e-12)
    np.testing.assert_allclose(lined[first:, 0], 1.0 * (t[first:] - T / 2), atol=1e-9)  # exact: a = 1 m/s^2
    assert np.all(np.abs(lined[first:, 0] - averaged[first:, 0]) > 0.1)
    with pytest.raises(ConfigError, match="linear_min_samples"):
        VelocityObserverConfig(linear_min_samples=1).validate()


@pytest.mark.parametrize("ages, velocities, w, expected", [
    ([0.3], [[1.0, 2.0, 3.0]], [1.0], [1.0, 2.0, 3.0]),
    ([0.2, 0.2], [[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]], [0.5, 0.5], [2.0, 2.0, 2.0]),
], ids=["one_sample", "two_of_one_age"])
def test_linear_fit_without_a_spread_of_ages_is_the_weighted_mean(ages, velocities, w, expected):
    """No line runs through one age (its slope would be 0 / 0): the fit is the weighted mean then, the one
    velocity, or (1 + 3) / 2 = 2 on each axis of two equally weighted ones of the same age, not NaN."""
    v = linear_fit_now(np.array(ages), np.array(velocities), np.array(w))
    np.testing.assert_allclose(v, expected, atol=1e-12)


def test_speed_heading_mode_reads_noise_as_speed():
    """Eq. 18-19 as printed (speed and direction averaged apart) agree with the vector mean on a straight
    run and read a noisy westbound one (headings across +-180 deg) right, but on a standing target with 3 cm of
    noise every instant speed is positive: it reads about 0.5 m/s where the vector mean reads a few cm/s."""
    t = np.arange(0.0, 30.0, T)
    straight = np.c_[0.8 * t, 0.3 * t, np.zeros_like(t)]
    vector, _ = observe_velocities(t, straight, VelocityObserverConfig(fit="mean"))
    printed, _ = observe_velocities(t, straight, VelocityObserverConfig(combine="speed_heading"))
    np.testing.assert_allclose(printed[3:], vector[3:], atol=1e-12)
    np.testing.assert_allclose(vector[3:, :2], np.tile([0.8, 0.3], (len(t) - 3, 1)), atol=1e-12)
    standing = noisy_track(np.zeros((len(t), 3)), 0.03, seed=3)
    vector, _ = observe_velocities(t, standing, VelocityObserverConfig(fit="mean"))
    printed, _ = observe_velocities(t, standing, VelocityObserverConfig(combine="speed_heading"))
    assert np.mean(np.linalg.norm(vector[20:], axis=1)) < 0.08
    assert np.mean(np.linalg.norm(printed[20:], axis=1)) > 0.35
    # Due west (heading +-180 deg) with 1 cm of noise the headings straddle the +-pi cut: unwrapped next to the
    # newest, they average to west (a plain mean of +-pi would point east).
    west = noisy_track(np.c_[-0.8 * t, np.zeros((len(t), 2))], 0.01, seed=4)
    printed, valid = observe_velocities(t, west, VelocityObserverConfig(combine="speed_heading"))
    assert valid[20:].all()
    np.testing.assert_allclose(printed[20:, :2].mean(axis=0), [-0.8, 0.0], atol=0.03)
    assert np.abs(printed[20:, 0] + 0.8).max() < 0.1


def test_speed_heading_mode_unwraps_the_headings_next_to_the_newest():
    """Eq. 19 on three unit instant velocities heading -120 deg (oldest), +120 deg and 0 deg (newest): each
    heading is taken within 180 deg of the newest's, so they average as [0, 120, -120] deg with the weights
    exp(-age^2 / 2 sigma^2) normalised (by hand), not as unwrapped next to any other."""
    config = VelocityObserverConfig(combine="speed_heading")
    headings = np.radians([-120.0, 120.0, 0.0])
    velocities = np.c_[np.cos(headings), np.sin(headings), np.zeros(3)]
    v, valid = weighted_velocity(np.array([0.8, 0.9, 1.0]), velocities, 1.0, config)
    ages = np.array([0.0, 0.1, 0.2])  # newest first
    w = np.exp(-ages**2 / (2 * config.sigma_s**2))
    heading = (w / w.sum()) @ np.radians([0.0, 120.0, -120.0])
    assert valid
    np.testing.assert_allclose(v, [math.cos(heading), math.sin(heading), 0.0], atol=1e-12)


def test_speed_heading_mode_reads_the_vertical_velocity():
    """Eq. 18-19 average the horizontal speed and heading; the vertical velocity is averaged beside them: on a
    track climbing at 0.2 m/s both modes read the true [0.8, 0.3, 0.2] m/s."""
    t = np.arange(0.0, 3.0, T)
    climbing = np.c_[0.8 * t, 0.3 * t, 0.2 * t]
    printed, valid = observe_velocities(t, climbing, VelocityObserverConfig(combine="speed_heading"))
    vector, _ = observe_velocities(t, climbing, VelocityObserverConfig(fit="mean"))
    assert valid[3:].all()
    np.testing.assert_allclose(printed[3:], np.tile([0.8, 0.3, 0.2], (len(t) - 3, 1)), atol=1e-12)
    np.testing.assert_allclose(printed[3:], vector[3:], atol=1e-12)


@pytest.mark.parametrize("gap_s, joined", [(0.5, True), (0.6, False), (1.0, False)])
def test_a_gap_longer_than_max_gap_s_gives_no_instant_velocity(gap_s, joined):
    """A sighting max_gap_s (0.5 s) after the last is differenced with it (an instant velocity of 5 m over the
    gap); one any later (0.6 s, twice max_gap_s) restarts the differences."""
    config = VelocityObserverConfig()
    assert config.max_gap_s == 0.5
    state = step_observer(ObserverState(), 1.0, config, p_W=np.zeros(3))
    state = step_observer(state, 1.0 + gap_s, config, p_W=np.array([5.0, 0.0, 0.0]))
    assert len(state.times) == (1 if joined else 0)
    if joined:
        np.testing.assert_allclose(state.velocities[0], [5.0 / gap_s, 0.0, 0.0])
    assert state.last_time == 1.0 + gap_s  # the new sighting is the next difference's start either way


def test_validity_history_and_gaps():
    config = VelocityObserverConfig()
    state = ObserverState()
    v = np.array([0.5, 0.0, 0.0])
    for k in range(10):
        state = step_observer(state, k * T, config, p_W=v * k * T)
    assert state.valid and np.allclose(state.estimate, v)
    # lost: the estimate holds on the window's old velocities, then turns invalid (NaN) once fewer than
    # three instant velocities are at most 1.5 s old
    for k in range(10, 40):
        state = step_observer(state, k * T, config, p_W=np.full(3, np.nan))
        if k * T <= 0.7 + 1.5 + 1e-9:  # the third newest instant velocity, at 0.7 s, is 1.5 s old at 2.2 s
            assert state.valid and np.allclose(state.estimate, v)
        else:
            assert not state.valid and np.all(np.isnan(state.estimate))
    # seen again 5 m away after 3 s: no instant velocity across the gap (max_gap_s), valid after four sightings
    for k in range(40, 44):
        state = step_observer(state, k * T, config, p_W=np.array([5.0, 0.0, 0.0]) + v * (k - 40) * T)
        assert state.valid == (k == 43)
    np.testing.assert_allclose(state.estimate, v)
    # one frame missed: the difference over two frames is still an instant velocity
    state = step_observer(state, 45 * T, config, p_W=np.array([5.0, 0.0, 0.0]) + v * 5 * T)
    np.testing.assert_allclose(state.times[-1], 45 * T)
    np.testing.assert_allclose(state.velocities[-1], v)
    estimate, valid = weighted_velocity(np.array([0.0]), np.array([[1.0, 0.0, 0.0]]), 0.0, config)
    assert not valid and np.all(np.isnan(estimate))


def test_instant_velocities_stamped_after_now_do_not_count():
    """Three [1, 0, 0] m/s of ages 0.2, 0.1 and 0 s at now = 1.0 s and one [100, 0, 0] stamped 0.1 s after now:
    that one is not in the window (ages 0 to window_s), so the estimate is the three's mean, [1, 0, 0], and with
    min_samples 4 there are too few for a valid one."""
    times = np.array([0.8, 0.9, 1.0, 1.1])
    velocities = np.array([[1.0, 0.0, 0.0]] * 3 + [[100.0, 0.0, 0.0]])
    estimate, valid = weighted_velocity(times, velocities, 1.0, VelocityObserverConfig())
    assert valid
    np.testing.assert_allclose(estimate, [1.0, 0.0, 0.0], atol=1e-12)
    estimate, valid = weighted_velocity(times, velocities, 1.0, VelocityObserverConfig(min_samples=4))
    assert not valid and np.all(np.isnan(estimate))


def nan_y_at_frame_5():
    t = np.arange(10) * T
    p = np.c_[t, np.zeros((len(t), 2))]
    p[5, 1] = np.nan
    return t, p


def repeated_time():
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.3, 0.4, 0.5])
    return t, np.c_[t, np.zeros((len(t), 2))]


@pytest.mark.parametrize("track", [nan_y_at_frame_5, repeated_time])
def test_a_sighting_that_makes_no_instant_velocity(track):
    """A target at [t, 0, 0] m (1 m/s along x) with a position NaN in one coordinate only (no sighting: the
    next frame is differenced with the one before), or seen twice at the same time (no difference over 0 s): no
    NaN instant velocity enters the window, so the last estimate is a valid [1, 0, 0] and every valid one is
    finite."""
    estimates, valid = observe_velocities(*track(), VelocityObserverConfig())
    assert valid[-1]
    np.testing.assert_allclose(estimates[-1], [1.0, 0.0, 0.0], atol=1e-12)
    assert np.all(np.isfinite(estimates[valid]))


def test_an_instant_velocity_with_a_nan_coordinate_is_dropped():
    """Source displacement: four instant velocities [1, 0, 0] m/s, then one [1, NaN, 0] (not known): it is no
    sample, and the estimate stays a valid [1, 0, 0]."""
    config, state = VelocityObserverConfig(), ObserverState()
    for k, v in enumerate([[1.0, 0.0, 0.0]] * 4 + [[1.0, np.nan, 0.0]]):
        state = step_observer(state, k * T, config, v_W=np.array(v))
    assert state.valid and len(state.times) == 4
    np.testing.assert_allclose(state.estimate, [1.0, 0.0, 0.0], atol=1e-12)


# ages 0 to window_s a period apart
@pytest.mark.parametrize("rate_hz, window_s, held", [(10.0, 1.5, 16), (10.0, 0.3, 4), (100.0, 0.29, 30)])
def test_min_samples_beyond_what_the_window_holds_is_refused(rate_hz, window_s, held):
    """Before: accepted, and the estimate was never valid (or never linear), silently."""
    t = np.arange(300) / rate_hz
    p = np.c_[t, np.zeros_like(t), np.zeros_like(t)]  # 1 m/s along x, seen every frame
    full = VelocityObserverConfig(rate_hz=rate_hz, window_s=window_s, min_samples=held)
    assert full.window_capacity == held
    full.validate()
    estimates, valid = observe_velocities(t, p, full)
    # valid once the window holds `held` (0.29 s at 100 Hz: 30, despite 0.29 * 100 < 29 in floats)
    assert valid.sum() == len(t) - held
    np.testing.assert_allclose(estimates[valid], np.tile([1.0, 0.0, 0.0], (valid.sum(), 1)), atol=1e-9)
    with pytest.raises(ConfigError, match=rf"velocity_observer\.min_samples \({held + 1}\) is more than the window "
                                          rf"holds: {held} instant velocities"):
        VelocityObserverConfig(rate_hz=rate_hz, window_s=window_s, min_samples=held + 1).validate()
    with pytest.raises(ConfigError, match=rf"hybrid\.velocity_observer\.linear_min_samples \({held + 1}\)"):
        VelocityObserverConfig(rate_hz=rate_hz, window_s=window_s, fit="linear",
                               linear_min_samples=held + 1).validate("hybrid.velocity_observer")
    VelocityObserverConfig(rate_hz=rate_hz, window_s=window_s, fit="mean", linear_min_samples=held + 1).validate()


def test_a_window_of_exactly_one_period_is_accepted():
    """window_s = 1 / rate_hz (0.1 s at 10 Hz) holds one period: it validates, holding two instant velocities
    (ages 0 and 0.1 s), enough for min_samples 1."""
    config = VelocityObserverConfig(rate_hz=10.0, window_s=0.1, min_samples=1)
    config.validate()
    assert config.window_capacity == 2


def test_bad_configs_name_the_field():
    for kwargs, name in (({"sigma_s": 0.0}, "velocity_observer.sigma_s"),
                         ({"window_s": -1.0}, "velocity_observer.window_s"),
                         ({"window_s": 0.05}, "velocity_observer.window_s"),
                         ({"min_samples": 0}, "velocity_observer.min_samples"),
                         ({"combine": "median"}, "velocity_observer.combine"),
                         ({"fit": "quadratic"}, "velocity_observer.fit"),
                         ({"combine": "speed_heading", "fit": "linear"}, "velocity_observer.fit"),
                         ({"source": "gps"}, "velocity_observer.source"),
                         ({"rate_hz": -10.0}, "velocity_observer.rate_hz")):
        with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
            VelocityObserverConfig(**kwargs).validate()
    with pytest.raises(ConfigError, match=r"observer\.max_gap_s"):
        VelocityObserverConfig(max_gap_s=0.0).validate("observer")
    with pytest.raises(ConfigError, match="needs the camera's 3x3 intrinsics K"):
        VelocityObserverSystem(VelocityObserverConfig(source="pixel"))
    with pytest.raises(ConfigError, match="needs the camera's pose X_BC"):
        VelocityObserverSystem(VelocityObserverConfig(source="displacement"), K=K)


# ----------------------------------------------------------------------------------------------
# The LeafSystem


def drive(system, inputs, times):
    """Steps a system through frames: inputs(k, t) fixes the ports for frame k; returns per frame (v_WT,
    valid) read at the frame time (which includes that frame's step)."""
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    out = []
    for k, t in enumerate(times):
        inputs(context, k, t)
        simulator.AdvanceTo(t)
        out.append((system.GetOutputPort("v_WT").Eval(context).copy(), system.GetOutputPort("valid").Eval(context)[0]))
        simulator.AdvanceTo(t + T / 2)  # the update at t stores the step with frame k's inputs
    return out


def test_system_world_source_matches_the_batch_observer():
    config = VelocityObserverConfig()
    system = VelocityObserverSystem(config)
    t = np.arange(0.0, 3.0, T)
    p = noisy_track(np.c_[0.7 * t, -0.2 * t, 0.1 * t], 0.02, seed=4)
    out = drive(system, lambda c, k, _: system.GetInputPort("p_WT").FixValue(c, p[k]), t)
    expected, valid = observe_velocities(t, p, config)
    assert [o[1] for o in out] == [float(v) for v in valid]
    np.testing.assert_allclose(np.array([o[0] for o in out]), expected, atol=1e-12)  # NaN where invalid


@pytest.mark.parametrize("precise", [None, 1.0, 0.0])
def test_system_precise_input_selects_the_fit(precise):
    """fit linear: unconnected or 1.0, the system gives the batch observer's line; 0.0, Eq. 18-19's mean."""
    system = VelocityObserverSystem(VelocityObserverConfig(fit="linear"))
    t = np.arange(0.0, 3.0, T)
    p = np.c_[0.5 * t ** 2, -0.2 * t, np.zeros_like(t)]

    def inputs(c, k, _):
        system.GetInputPort("p_WT").FixValue(c, p[k])
        if precise is not None:
            system.GetInputPort("precise").FixValue(c, [precise])

    out = np.array([o[0] for o in drive(system, inputs, t)])
    expected, _ = observe_velocities(t, p, VelocityObserverConfig(fit="mean" if precise == 0.0 else "linear"))
    np.testing.assert_allclose(out, expected, atol=1e-12)


def ground_pixel(p_W: np.ndarray, X_WC: RigidTransform) -> np.ndarray:
    p_C = X_WC.inverse().multiply(p_W)
    return (K @ p_C)[:2] / p_C[2]


@pytest.mark.parametrize("source", ["pixel", "displacement"])
def test_system_from_pixels_recovers_the_ground_velocity(source):
    """A level UAV yawed 30 deg, flying at (2, -1) m/s at 7.5 m while the target drives at (0.8, 0.3) m/s:
    from its pixel (through the UAV's pose) or from its motion-compensated displacement (Eq. 15, Eq. 22),
    the observer reads the target's own velocity exactly (noise-free)."""
    config = VelocityObserverConfig(source=source)
    system = VelocityObserverSystem(config, K=K, X_BC=X_BC)
    v_target, v_uav = np.array([0.8, 0.3, 0.0]), np.array([2.0, -1.0, 0.0])
    t = np.arange(0.0, 2.0, T)

    def X_WC(tk):
        return RigidTransform(RotationMatrix.MakeZRotation(math.radians(30)), [1.0, 1.0, 7.54] + v_uav * tk).multiply(
            X_BC)

    def inputs(context, k, tk):
        X_WB = X_WC(tk).multiply(X_BC.inverse())
        target = [2.0, 0.5, 0.0] + v_target * tk
        if source == "pixel":
            value = ground_pixel(target, X_WC(tk))
        else:  # the homography of the ground maps the previous pixel into this frame: the current pose
            value = ground_pixel(target, X_WC(tk)) - ground_pixel(target - v_target * T, X_WC(tk))
        system.GetInputPort(f"target_{source}").FixValue(context, value)
        system.GetInputPort("altitude").FixValue(context, [7.5])
        system.GetInputPort("X_WB").FixValue(context, X_WB)

    out = drive(system, inputs, t)
    first_valid = 3 if source == "pixel" else 2  # positions need one more frame than displacements
    assert [o[1] for o in out[:first_valid + 1]] == [0.0] * first_valid + [1.0]
    for v, valid in out[first_valid:]:
        assert valid == 1.0
        np.testing.assert_allclose(v, v_target, atol=1e-9)


def test_system_displacement_source_takes_the_linear_fit():
    """fit linear from motion-compensated displacements (each frame's, unflagged: precise): a target accelerating
    at 0.5 m/s^2 under a still, level UAV yawed 30 deg at 7.5 m; each instant velocity is the displacement over
    the last period, a (t - T/2), so once linear_min_samples are in the window the estimate is that line now,
    where Eq. 18-19's mean would lag it by about 0.4 s."""
    config = VelocityObserverConfig(source="displacement", fit="linear")
    system = VelocityObserverSystem(config, K=K, X_BC=X_BC)
    a = np.array([0.5, 0.0, 0.0])
    X_WB = RigidTransform(RotationMatrix.MakeZRotation(math.radians(30)), [1.0, 1.0, 7.54])
    X_WC = X_WB.multiply(X_BC)
    t = np.arange(0.0, 2.0, T)

    def target(tk):
        return np.array([2.0, 0.5, 0.0]) + 0.5 * a * tk**2

    def inputs(context, k, tk):
        system.GetInputPort("target_displacement").FixValue(
            context, ground_pixel(target(tk), X_WC) - ground_pixel(target(tk - T), X_WC))
        system.GetInputPort("altitude").FixValue(context, [7.5])
        system.GetInputPort("X_WB").FixValue(context, X_WB)

    out = drive(system, inputs, t)
    first = config.linear_min_samples - 1  # a displacement gives an instant velocity from frame 0
    for (v, valid), tk in zip(out[first:], t[first:]):
        assert valid == 1.0
        np.testing.assert_allclose(v, a * (tk - T / 2), atol=1e-9)


@pytest.mark.parametrize("invalid_flag", [0.0, np.nan], ids=["zero", "nan"])
def test_system_invalid_altitude_is_no_sighting(invalid_flag):
    """altitude_valid 0, or NaN (no valid flag raised), from frame 10 on: no sighting from there."""
    config = VelocityObserverConfig(source="pixel")
    system = VelocityObserverSystem(config, K=K, X_BC=X_BC)
    X_WB = RigidTransform([0.0, 0.0, 7.54])

    def inputs(context, k, tk):
        system.GetInputPort("target_pixel").FixValue(context, ground_pixel([0.1 * tk, 0.0, 0.0], X_WB.multiply(X_BC)))
        system.GetInputPort("altitude").FixValue(context, [7.5 if k % 2 == 0 else np.nan])
        system.GetInputPort("altitude_valid").FixValue(context, [1.0 if k < 10 else invalid_flag])
        system.GetInputPort("X_WB").FixValue(context, X_WB)

    out = drive(system, inputs, np.arange(0.0, 4.0, T))
    # every other altitude unknown: sightings at even frames (0.2 s apart); valid from the fourth (k = 6)
    assert [o[1] for o in out[:8]] == [0.0] * 6 + [1.0, 1.0]
    np.testing.assert_allclose(out[8][0], [0.1, 0.0, 0.0], atol=1e-9)
    # altitude flagged invalid from k = 10: the window empties and the estimate turns invalid, never NaN-as-valid
    assert out[-1][1] == 0.0 and np.all(np.isnan(out[-1][0]))
    assert all(np.all(np.isfinite(v)) for v, valid in out if valid == 1.0)


@pytest.mark.parametrize("altitude_m", [-3.0, 0.0])
def test_system_an_altitude_at_or_below_zero_is_no_sighting(altitude_m):
    """A displacement read at a non-positive altitude (flagged valid) would give a reversed or zero velocity:
    it is no sighting, and the observer never turns valid."""
    system = VelocityObserverSystem(VelocityObserverConfig(source="displacement"), K=K, X_BC=X_BC)

    def inputs(context, k, tk):
        system.GetInputPort("target_displacement").FixValue(context, [10.0, 0.0])
        system.GetInputPort("altitude").FixValue(context, [altitude_m])
        system.GetInputPort("X_WB").FixValue(context, RigidTransform([0.0, 0.0, 7.54]))

    assert all(valid == 0.0 for _, valid in drive(system, inputs, np.arange(0.0, 1.0, T)))
