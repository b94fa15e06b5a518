"""Tests of the tracking Kalman filter (seed 000, Eq. 28-35), on a tag-corner track."""

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from systems.estimators.track_filter import (
    Track,
    TrackFilterParams,
    constant_velocity_model,
    innovation_distance,
    kalman_update,
    step_track,
)

PARAMS = TrackFilterParams()
START = np.array([[200.0, 200.0], [280.0, 205.0], [275.0, 285.0], [195.0, 280.0]])
VELOCITY = np.array([40.0, -25.0])  # px/s, every corner alike


def corners(track):
    """The track's (4, 2) corner pixels."""
    return track.position.reshape(4, 2)


def truth(k):
    return START + VELOCITY * k * PARAMS.dt_s


def run(track, frames, rng, dropped=()):
    """Step the filter over frame indices; returns the track after each frame."""
    tracks = []
    for k in frames:
        noise = PARAMS.measurement_std * rng.standard_normal((4, 2))
        z = None if k in dropped else truth(k) + noise
        track = step_track(track, z, PARAMS)
        tracks.append(track)
    return tracks


def errors(tracks, frames):
    """Largest corner error of each track, px."""
    return np.array([np.abs(corners(t) - truth(k)).max() for t, k in zip(tracks, frames)])


def test_scalar_update_matches_hand_computation():
    x, P = kalman_update(np.array([0.0]), np.array([[4.0]]), np.array([10.0]), np.eye(1), np.eye(1))
    # K = 4 / (4 + 1) = 0.8
    np.testing.assert_allclose(x, [8.0])
    np.testing.assert_allclose(P, [[0.8]])


def test_no_track_before_the_first_detection():
    track = step_track(Track(), None, PARAMS)
    assert not track.valid
    assert track.position is None
    track = step_track(track, START, PARAMS)
    assert track.valid and track.coasted_steps == 0
    np.testing.assert_array_equal(corners(track), START)


def test_converges_on_a_constant_velocity_track_to_the_riccati_covariance():
    rng = np.random.default_rng(0)
    tracks = run(Track(), range(300), rng)
    # Filtered corners beat the raw 1 px detections, and the velocity estimate is unbiased.
    residuals = [corners(t) - truth(k) for t, k in zip(tracks[100:], range(100, 300))]
    rms = np.sqrt(np.mean(np.square(residuals)))
    assert rms < 0.9 * PARAMS.measurement_std
    mean_velocity = np.mean([t.x[8:].reshape(4, 2) for t in tracks[-200:]], axis=0)
    np.testing.assert_allclose(mean_velocity, np.broadcast_to(VELOCITY, (4, 2)), atol=0.5)  # measured: 0.15 px/s
    # Steady state: the posterior covariance is the one implied by SciPy's Riccati solution.
    F, Q, H, R = constant_velocity_model(PARAMS, 8)
    P_prior = solve_discrete_are(F.T, H.T, Q, R)
    P_post = P_prior - P_prior @ H.T @ np.linalg.solve(H @ P_prior @ H.T + R, H @ P_prior)
    np.testing.assert_allclose(tracks[-1].P, P_post, rtol=1e-6, atol=1e-9)
    # Eq. 35 symmetrised: every update's P is exactly symmetric, round-off and all.
    for track in tracks:
        np.testing.assert_array_equal(track.P, track.P.T)


def test_the_process_noise_is_a_white_acceleration_held_over_the_step():
    """Q is acceleration_std^2 G G^T per coordinate, G = [dt^2 / 2, dt] the position and rate a unit
    acceleration held over the step adds (the position's and rate's noise fully correlated), F the
    constant-velocity step; coordinates independent."""
    params = TrackFilterParams(dt_s=0.05, acceleration_std=3.0)
    F, Q, H, R = constant_velocity_model(params, 2)
    dt = params.dt_s
    G = np.array([dt**2 / 2, dt])
    np.testing.assert_allclose(Q, 9.0 * np.kron(np.outer(G, G), np.eye(2)), rtol=1e-12)
    np.testing.assert_array_equal(F, [[1.0, 0.0, dt, 0.0], [0.0, 1.0, 0.0, dt], [0.0, 0.0, 1.0, 0.0],
                                      [0.0, 0.0, 0.0, 1.0]])


def test_coasts_through_a_three_frame_dropout_with_bounded_error():
    rng = np.random.default_rng(1)
    track = run(Track(), range(100), rng)[-1]
    dropout = [100, 101, 102]
    tracks = run(track, dropout, rng, dropped=set(dropout))
    assert [t.coasted_steps for t in tracks] == [1, 2, 3] and tracks[-1].valid
    # Within the filter's own 3-sigma, which grows while coasting, and a few pixels at most.
    stds = np.array([np.sqrt(np.diag(t.P)[:8].max()) for t in tracks])
    assert np.all(np.diff(stds) > 0)
    assert np.all(errors(tracks, dropout) < 3 * stds) and stds[-1] < 3.0
    track = run(tracks[-1], [103], rng)[-1]
    assert track.coasted_steps == 0 and errors([track], [103])[0] < 3.0


def test_drops_the_track_after_coasting_too_long_and_restarts():
    rng = np.random.default_rng(2)
    track = run(Track(), range(50), rng)[-1]
    dropout = range(50, 50 + PARAMS.max_coast_steps + 1)
    tracks = run(track, dropout, rng, dropped=set(dropout))
    assert [t.valid for t in tracks] == [True] * PARAMS.max_coast_steps + [False]
    restart = truth(60)
    track = step_track(tracks[-1], restart, PARAMS)
    assert track.valid
    np.testing.assert_array_equal(corners(track), restart)


@pytest.mark.parametrize("bad", [np.full((4, 2), np.nan), None])
def test_missing_or_nan_detections_only_predict(bad):
    rng = np.random.default_rng(3)
    track = run(Track(), range(20), rng)[-1]
    coasted = step_track(track, bad, PARAMS)
    assert coasted.valid and coasted.coasted_steps == 1
    assert np.all(np.isfinite(corners(coasted)))


def test_a_known_shift_removes_the_lag_of_the_drones_own_motion():
    # Four ranges to a still deck from a drone that hovers, then descends at 0.4 m/s: with its own motion
    # as Eq. 28's B u the slow range filter follows; without it, it lags by centimetres.
    params = TrackFilterParams(dt_s=0.05, measurement_std=0.005, acceleration_std=0.05, initial_velocity_std=0.2)
    rng = np.random.default_rng(2)
    speed = np.r_[np.zeros(40), np.full(40, 0.4)]  # m/s towards the deck, per frame
    ranges = 2.0 - np.cumsum(np.r_[0.0, speed[:-1]]) * params.dt_s
    told = blind = Track()
    worst_told = worst_blind = 0.0
    for k, r in enumerate(ranges):
        z = r + params.measurement_std * rng.standard_normal(4)
        shift = None if k == 0 else np.full(4, -speed[k - 1] * params.dt_s)
        told, blind = step_track(told, z, params, shift), step_track(blind, z, params)
        if k >= 40:
            worst_told = max(worst_told, np.abs(told.position - r).max())
            worst_blind = max(worst_blind, np.abs(blind.position - r).max())
    assert worst_told < 0.01 < worst_blind


def test_an_unknown_shift_adds_nothing():
    """A shift with a NaN (the navigation's velocity unknown for a frame) is no shift: the step equals the one
    without it, and the track stays finite and follows the next measurements."""
    rng = np.random.default_rng(4)
    track = run(Track(), range(20), rng)[-1]
    z = truth(20) + PARAMS.measurement_std * rng.standard_normal((4, 2))
    unknown = step_track(track, z, PARAMS, np.r_[np.nan, np.zeros(7)])
    none = step_track(track, z, PARAMS)
    np.testing.assert_array_equal(unknown.x, none.x)
    np.testing.assert_array_equal(unknown.P, none.P)
    assert np.all(np.isfinite(run(unknown, range(21, 30), rng)[-1].x))


def test_innovation_distance_is_the_residual_over_its_covariance():
    params = TrackFilterParams(dt_s=0.05, measurement_std=0.01, acceleration_std=0.1, initial_velocity_std=0.2)
    track = step_track(Track(), [1.0, 2.0], params)
    F, Q, H, R = constant_velocity_model(params, 2)
    P = F @ track.P @ F.T + Q
    S = R + H @ P @ H.T  # diagonal here: one coordinate's variance each
    z = np.array([1.03, 1.98])
    expected = (0.03**2) / S[0, 0] + (0.02**2) / S[1, 1]
    assert innovation_distance(track, z, params) == pytest.approx(expected)


def test_a_new_track_knows_its_position_to_the_measurement_and_its_rate_to_initial_velocity_std():
    """The first measurement starts the track at it with zero rate, the position's variance the measurement's
    and the rate's initial_velocity_std^2 (unknown, not a pixel's 1 px/s): so the second measurement, 2 px on,
    gives nearly the finite-difference rate, 2 px / dt, as the Kalman gain for a nearly unknown rate does."""
    params = TrackFilterParams(measurement_std=1.0, initial_velocity_std=200.0)
    track = step_track(Track(), [10.0, 20.0], params)
    np.testing.assert_array_equal(track.x, [10.0, 20.0, 0.0, 0.0])
    np.testing.assert_allclose(np.diag(track.P), [1.0, 1.0, 200.0**2, 200.0**2])
    track = step_track(track, [12.0, 20.0], params)
    np.testing.assert_allclose(track.x[2:], [2.0 / params.dt_s, 0.0], rtol=0.05, atol=1e-9)
