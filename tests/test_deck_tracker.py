"""The deck tracker (systems/estimators/deck_tracker.py): its attitude coordinates against Drake's
rotations, and its tracks against a moving deck's truth, with the tag seen and lost."""

import math
from dataclasses import replace

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from systems.config import ConfigError
from systems.estimators.deck_tracker import (
    DeckTrack,
    DeckTracker,
    DeckTrackerConfig,
    attitude_coordinates,
    attitude_rotation,
    deck_estimate,
    predicted,
    step_deck_track,
    tilt_deg,
)
from systems.estimators.estimate import PoseEstimate
from systems.estimators.track_filter import Track

PERIOD = 0.05
CONFIG = DeckTrackerConfig()


def deck_pose(t: float) -> RigidTransform:
    """A deck heaving 6 cm at 0.04 Hz and rolling and pitching 8 deg, yawed 10 deg, 0.69 m up."""
    roll = math.radians(8.0) * math.sin(2 * math.pi * 0.05 * t)
    pitch = math.radians(8.0) * math.sin(2 * math.pi * 0.037 * t + 1.2)
    z = 0.69 + 0.06 * math.sin(2 * math.pi * 0.041 * t)
    return RigidTransform(RollPitchYaw(roll, pitch, math.radians(10.0)), [0.02, -0.01, z])


def test_attitude_coordinates_round_trip_drake_rotations():
    rng = np.random.default_rng(3)
    for _ in range(50):
        rpy = rng.uniform([-0.5, -0.5, -math.pi], [0.5, 0.5, math.pi])
        R = RotationMatrix(RollPitchYaw(rpy))
        coordinates = attitude_coordinates(R)
        np.testing.assert_allclose(coordinates[:2], R.col(2)[:2], atol=1e-12)  # the normal's tilt
        np.testing.assert_allclose(attitude_rotation(coordinates).matrix(), R.matrix(), atol=1e-12)
    # A level deck: the heading alone.
    np.testing.assert_allclose(attitude_coordinates(RotationMatrix.MakeZRotation(0.7)), [0.0, 0.0, 0.7], atol=1e-12)


@pytest.mark.filterwarnings("error")  # arcsin of more than 1 warns (and is NaN)
@pytest.mark.parametrize("n_xy, expected", [
    ([0.8, 0.7], 90.0),  # |n_xy| = sqrt(1.13) > 1: noise past the horizontal
    ([[0.6, 0.0], [1.2, 0.0]], [math.degrees(math.asin(0.6)), 90.0]),  # along the last axis
])
def test_the_tilt_of_a_normal_whose_xy_exceeds_one_is_90_deg(n_xy, expected):
    """|n_xy| = sin(tilt) is at most 1 for a unit normal; a predicted one may pass it, and is read as 90 deg."""
    assert tilt_deg(np.array(n_xy)) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("rpy", [(5e-4, 0.0, 0.3), (0.0, -5e-4, -2.0), (1e-6, 1e-6, 1.0)])
def test_a_deck_tilted_by_under_a_milliradian_is_not_taken_for_level(rpy):
    """Tilts of a milliradian and less round-trip through the attitude coordinates to 1e-12 like larger ones:
    only an exactly level normal (|n_xy| under 1e-12) skips the tilt rotation."""
    R = RotationMatrix(RollPitchYaw(rpy))
    coordinates = attitude_coordinates(R)
    np.testing.assert_allclose(coordinates[:2], R.col(2)[:2], atol=1e-15)
    np.testing.assert_allclose(attitude_rotation(coordinates).matrix(), R.matrix(), atol=1e-12)


def test_a_deck_heading_across_plus_minus_180_deg_is_tracked():
    """Headings 179.9 deg and -179.9 deg in turn are 0.2 deg apart, not 359.8: each frame's yaw is unwrapped
    next to the track's, so none is gated, every frame counts and the estimate heads 180 deg."""
    track = DeckTrack()
    for k in range(40):
        yaw = math.pi - 0.002 if k % 2 else -math.pi + 0.002
        track = step_deck_track(track, RigidTransform(RotationMatrix.MakeZRotation(yaw), [0.0, 0.0, 1.0]),
                                k * PERIOD, CONFIG, PERIOD)
    estimate, _, _ = deck_estimate(track, 39 * PERIOD, CONFIG)
    assert track.frames_used == 40 and track.coasted_steps == 0 and estimate.valid
    heading = estimate.X_WP.rotation().multiply(RotationMatrix.MakeZRotation(-math.pi))  # 180 deg off it
    assert heading.ToAngleAxis().angle() < math.radians(0.5)


def test_the_estimates_covariance_puts_roll_and_pitch_on_the_normals_y_and_x():
    """[roll, pitch, yaw] variances of a level deck from the attitude track's [n_x, n_y, yaw]: through the
    Jacobian of attitude_coordinates in Drake's roll-pitch-yaw (roll moves n_y, pitch n_x), with var(n_x),
    var(n_y) and var(yaw) all different so that no two may swap; and x, y, z the position track's."""
    P_attitude = np.diag([1e-4, 4e-4, 9e-4, 0.0, 0.0, 0.0])
    P_position = np.diag([1e-6, 2e-6, 3e-6, 0.0, 0.0, 0.0])
    track = DeckTrack(1.0, Track(np.zeros(6), P_position), Track(np.zeros(6), P_attitude), frames_used=5)
    covariance = deck_estimate(track, 1.0, CONFIG)[0].covariance
    h = 1e-6
    J = np.column_stack([(attitude_coordinates(RotationMatrix(RollPitchYaw(h * e)))
                          - attitude_coordinates(RotationMatrix(RollPitchYaw(-h * e)))) / (2 * h) for e in np.eye(3)])
    J_inverse = np.linalg.inv(J)  # d[roll, pitch, yaw] / d[n_x, n_y, yaw]
    np.testing.assert_allclose(np.diag(covariance)[:3], np.diag(J_inverse @ P_attitude[:3, :3] @ J_inverse.T),
                               rtol=1e-6)
    np.testing.assert_allclose(np.diag(covariance)[3:], [1e-6, 2e-6, 3e-6], rtol=1e-12)


@pytest.mark.parametrize("time, expected", [
    (1.0, [0.01, 0.02, 0.001, 0.002, 0.69, 0.3, 1.0, 0.0]),  # at the frame: the tracks' own values
    (1.5, [0.0105, 0.021, 0.001, 0.002, 0.84, 0.3, 1.0, 0.0]),  # 0.5 s on: each value moved by its rate
])
def test_the_deck_motion_is_the_normals_tilt_and_the_centres_heave_with_their_rates(time, expected):
    """deck_motion [n_x, n_y, dn_x/dt, dn_y/dt, z, dz/dt, valid, coasted steps] from tracks whose every
    coordinate and rate differ (p = [0, 0, 0.69], v = [0.1, 0.2, 0.3]; [n_x, n_y, yaw] = [0.01, 0.02, 0.3]
    at rates [0.001, 0.002, 0.003]): the heave rate is the centre's z rate, not its x or y rate."""
    track = DeckTrack(1.0, Track(np.array([0.0, 0.0, 0.69, 0.1, 0.2, 0.3]), 1e-6 * np.eye(6)),
                      Track(np.array([0.01, 0.02, 0.3, 0.001, 0.002, 0.003]), 1e-6 * np.eye(6)), frames_used=3)
    estimate, v_WP, motion = deck_estimate(track, time, CONFIG)
    assert estimate.valid
    np.testing.assert_allclose(motion, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(v_WP, [0.1, 0.2, 0.3], rtol=0, atol=1e-15)


def test_predicted_variances_are_those_of_the_constant_velocity_step():
    """predicted()'s variances are diag(F P F^T) for F = [[I, dt I], [0, I]] (numpy as the truth), the values'
    and rates' cross-covariance included."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    P = A @ A.T
    dt = 0.3
    F = np.kron([[1.0, dt], [0.0, 1.0]], np.eye(3))
    x = rng.normal(size=6)
    values, rates, variances = predicted(Track(x, P), dt)
    np.testing.assert_allclose(values, (F @ x)[:3], rtol=1e-12)
    np.testing.assert_allclose(rates, x[3:], rtol=1e-12)
    np.testing.assert_allclose(variances, np.diag(F @ P @ F.T)[:3], rtol=1e-12)


def track_run(frames, measured=lambda k: True, noise_m=0.002, noise_rad=0.002, seed=0):
    """Steps a tracker over camera frames of the moving deck with noisy poses (where `measured`)."""
    rng = np.random.default_rng(seed)
    track = DeckTrack()
    for k in frames:
        t = k * PERIOD
        X = None
        if measured(k):
            true = deck_pose(t)
            noise = RotationMatrix(RollPitchYaw(noise_rad * rng.standard_normal(3)))
            X = RigidTransform(true.rotation().multiply(noise), true.translation() + noise_m * rng.standard_normal(3))
        track = step_deck_track(track, X, t, CONFIG, PERIOD)
    return track


def errors(track, t):
    estimate, v_WP, motion = deck_estimate(track, t, CONFIG)
    true = deck_pose(t)
    h = 1e-4
    true_rate = (deck_pose(t + h).translation() - deck_pose(t - h).translation()) / (2 * h)
    n_rate = (deck_pose(t + h).rotation().col(2) - deck_pose(t - h).rotation().col(2))[:2] / (2 * h)
    return (estimate, np.linalg.norm(estimate.X_WP.translation() - true.translation()),
            math.degrees(estimate.X_WP.rotation().InvertAndCompose(true.rotation()).ToAngleAxis().angle()),
            abs(v_WP[2] - true_rate[2]), np.abs(motion[2:4] - n_rate).max())


def test_tracks_a_moving_deck_from_noisy_frames():
    frames = range(400)
    track = track_run(frames)
    estimate, position, angle, heave_rate, tilt_rate = errors(track, 399 * PERIOD)
    assert estimate.valid and estimate.frames == "X_WP"
    assert position < 0.005 and angle < 0.3
    assert heave_rate < 0.01  # m/s; the deck heaves at up to 0.015 m/s
    assert tilt_rate < 0.01  # 1/s; the normal tilts at up to 0.025 per s
    # Predicted between frames: the estimate at t + 0.02 s is the track moved by its rates.
    later, _, _, _, _ = errors(track, 399 * PERIOD + 0.02)
    step = later.X_WP.translation() - estimate.X_WP.translation()
    np.testing.assert_allclose(step, 0.02 * deck_estimate(track, 399 * PERIOD, CONFIG)[1], atol=1e-12)


def test_coasts_then_turns_invalid_without_measurements():
    seen = 200
    track = track_run(range(seen + CONFIG.position.max_coast_steps), measured=lambda k: k < seen)
    assert track.tracking and track.coasted_steps == CONFIG.position.max_coast_steps
    last = (seen + CONFIG.position.max_coast_steps - 1) * PERIOD  # the last frame: still valid, its motion counts
    estimate, _, motion = deck_estimate(track, last, CONFIG)  # the frames it coasted through, all unseen
    assert estimate.valid and motion[6] == 1.0 and motion[7] == CONFIG.position.max_coast_steps
    track = step_deck_track(track, None, (seen + 40) * PERIOD, CONFIG, PERIOD)
    estimate, v_WP, motion = deck_estimate(track, (seen + 40) * PERIOD, CONFIG)
    assert not estimate.valid and motion[6] == 0.0 and not np.any(v_WP)


def test_tracks_lost_by_coasting_are_confirmed_afresh_on_reacquisition():
    """Tracks dropped after max_coast_steps start again from the next frame as new tracks: the frames used
    before the loss do not count, so the estimate is invalid on the first two re-acquired frames and valid
    on the third (confirm_frames, 3, in a row)."""
    seen, lost = 200, CONFIG.position.max_coast_steps + 1
    track = track_run(range(seen + lost), measured=lambda k: k < seen)
    assert not track.tracking
    valid = []
    for k in range(seen + lost, seen + lost + 4):
        track = step_deck_track(track, deck_pose(k * PERIOD), k * PERIOD, CONFIG, PERIOD)
        valid.append(deck_estimate(track, k * PERIOD, CONFIG)[0].valid)
    assert valid == [False, False, True, True]


@pytest.mark.parametrize("short", ["position", "attitude"])
def test_one_track_lost_ends_the_tracking_though_the_other_coasts_on(short):
    """One track's max_coast_steps 2, the other's 30: three frames, then three without a pose drop the
    short one alone; the deck is tracked by both tracks or not at all, so the estimate is invalid."""
    config = replace(CONFIG, **{short: replace(getattr(CONFIG, short), max_coast_steps=2)})
    track = DeckTrack()
    for k in range(6):
        track = step_deck_track(track, deck_pose(k * PERIOD) if k < 3 else None, k * PERIOD, config, PERIOD)
        if k == 2:
            assert track.confirmed(config)
    long = "attitude" if short == "position" else "position"
    assert not getattr(track, short).valid and getattr(track, long).valid
    assert not track.tracking and not track.confirmed(config)
    estimate, v_WP, motion = deck_estimate(track, 5 * PERIOD, config)
    assert not estimate.valid and motion[6] == 0.0 and not np.any(v_WP)


def test_an_attitude_track_lost_alone_restarts_on_the_next_frame():
    """Attitude max_coast_steps 2, position 30: three frames, three without a pose drop the attitude track
    alone; the next frame starts it afresh beside the coasting position track (no heading to unwrap next to),
    and both track again."""
    config = replace(CONFIG, attitude=replace(CONFIG.attitude, max_coast_steps=2))
    X = RigidTransform(RotationMatrix.MakeZRotation(0.17), [0.0, 0.0, 1.0])
    track = DeckTrack()
    for k in range(7):
        track = step_deck_track(track, None if 3 <= k <= 5 else X, k * PERIOD, config, PERIOD)
        if k == 5:
            assert track.position.valid and not track.attitude.valid
    assert track.tracking and track.attitude.coasted_steps == 0
    np.testing.assert_allclose(track.attitude.x[:3], [0.0, 0.0, 0.17], atol=1e-12)  # the frame's own


def test_a_position_track_lost_alone_leaves_the_heading_unwrapped_next_to_the_attitude_tracks():
    """Position max_coast_steps 2, attitude 30: three frames heading 179.9 deg, three without a pose drop the
    position track alone, then three heading -179.9 deg (0.2 deg on, across +-180): each is unwrapped next to
    the coasting attitude track's heading, so the restarted tracks confirm on them (confirm_frames, 3) and the
    estimate heads 180 deg."""
    config = replace(CONFIG, position=replace(CONFIG.position, max_coast_steps=2))
    track = DeckTrack()
    for k in range(9):
        yaw = math.pi - 0.002 if k < 3 else -math.pi + 0.002
        X = None if 3 <= k <= 5 else RigidTransform(RotationMatrix.MakeZRotation(yaw), [0.0, 0.0, 1.0])
        track = step_deck_track(track, X, k * PERIOD, config, PERIOD)
        if k == 5:
            assert not track.position.valid and track.attitude.valid
    estimate, _, _ = deck_estimate(track, 8 * PERIOD, config)
    assert estimate.valid
    heading = estimate.X_WP.rotation().multiply(RotationMatrix.MakeZRotation(-math.pi))  # 180 deg off it
    assert heading.ToAngleAxis().angle() < math.radians(0.5)


@pytest.mark.parametrize("nan_in", ["translation", "rotation"])
def test_a_frame_with_a_nan_is_coasted_and_does_not_count(nan_in):
    """One good frame, then two with a NaN in the translation or the rotation: both tracks coast on them
    alike, and they do not count towards confirm_frames (3), so the estimate is not yet valid."""
    good = deck_pose(0.0)
    bad = (RigidTransform(good.rotation(), [np.nan, 0.0, 0.69]) if nan_in == "translation"
           else RigidTransform(RotationMatrix(np.full((3, 3), np.nan)), good.translation()))
    track = step_deck_track(DeckTrack(), good, 0.0, CONFIG, PERIOD)
    for k in (1, 2):
        track = step_deck_track(track, bad, k * PERIOD, CONFIG, PERIOD)
    assert track.frames_used == 1
    assert track.position.coasted_steps == track.attitude.coasted_steps == 2
    estimate, _, motion = deck_estimate(track, 2 * PERIOD, CONFIG)
    assert not estimate.valid and np.all(np.isfinite(motion))


@pytest.mark.parametrize("latency_s", [0.0, 0.2])
def test_the_system_measures_the_deck_through_the_uav_pose(latency_s):
    """Each frame is X_WP = X_WB X_BC X_CT X_TP: the deck pose an X_CT was composed from by Drake comes back, with
    a tag pose on the pad X_PT that is not its own inverse (turned over, tilted, yawed, off centre), so that X_PT
    taken for X_TP = X_PT^-1 would show, and a camera mount X_BC that is not its own inverse either (tilted and
    yawed off looking straight down, off centre), so that X_BC^-1 taken for it would show. Told a latency, the
    system predicts its one frame latency_s on from the exposure: at rate zero the pose stays, and each variance
    grows by (latency_s initial_velocity_std)^2."""
    X_BC = RigidTransform(RollPitchYaw(math.pi, 0.05, 0.1), [0.05, 0.0, -0.04])
    X_PT = RigidTransform(RollPitchYaw(math.pi, 0.1, 0.4), [0.03, -0.02, 0.0005])
    assert not X_BC.IsNearlyEqualTo(X_BC.inverse(), 1e-3) and not X_PT.IsNearlyEqualTo(X_PT.inverse(), 1e-3)
    tracker = DeckTracker(replace(CONFIG, confirm_frames=1), X_BC, X_PT.inverse(), PERIOD,  # one frame steers
                          latency_s)
    context = tracker.CreateDefaultContext()
    X_WB = RigidTransform(RollPitchYaw(0.05, -0.03, 0.4), [0.1, -0.2, 2.7])
    X_WP = deck_pose(0.0)
    X_CT = X_WB.multiply(X_BC).InvertAndCompose(X_WP.multiply(X_PT))
    tracker.GetInputPort("X_WB").FixValue(context, X_WB)
    tracker.GetInputPort("X_CT_estimate").FixValue(context, PoseEstimate(0.0, X_CT, True, reference="C", target="T"))
    estimate = tracker.GetOutputPort("X_WP_estimate").Eval(context)
    assert estimate.valid and estimate.frames == "X_WP"
    np.testing.assert_allclose(estimate.X_WP.GetAsMatrix4(), X_WP.GetAsMatrix4(), atol=1e-12)
    motion = tracker.GetOutputPort("deck_motion").Eval(context)
    assert motion[4] == pytest.approx(X_WP.translation()[2]) and motion[6] == 1.0
    # One frame: each track's variance its measurement's, its rate's initial_velocity_std^2, uncorrelated.
    variances = [params.measurement_std**2 + (latency_s * params.initial_velocity_std)**2
                 for params in (CONFIG.attitude, CONFIG.position)]
    np.testing.assert_allclose(np.diag(estimate.covariance), np.repeat(variances, 3), rtol=1e-12)


@pytest.mark.parametrize("confirm_frames, takeover_frames", [(1, 1), (3, 2)])
def test_a_challenger_must_take_over_confirmed_on_two_frames_or_more(confirm_frames, takeover_frames):
    with pytest.raises(ConfigError, match=rf"deck_tracker.takeover_frames must be at least 2 and at least "
                                          rf"deck_tracker.confirm_frames \({confirm_frames}\), got {takeover_frames}"):
        DeckTrackerConfig(confirm_frames=confirm_frames, takeover_frames=takeover_frames).validate()


def test_a_wrong_frame_is_gated_and_the_tracks_keep_the_deck():
    track = track_run(range(200))
    t = 200 * PERIOD
    true = deck_pose(t)
    wrong = RigidTransform(true.rotation(), true.translation() + [0.1, -0.1, -0.6])  # a sensor off the edge
    gated = step_deck_track(track, wrong, t, CONFIG, PERIOD)
    assert gated.coasted_steps == 1  # not used: coasted
    estimate, _, _ = deck_estimate(gated, t, CONFIG)
    assert np.linalg.norm(estimate.X_WP.translation() - true.translation()) < 0.005
    assert step_deck_track(track, true, t, CONFIG, PERIOD).coasted_steps == 0  # the right one is used


def late_frames_heave_rms(lag_s: float, tracker_lag_s: float) -> tuple[DeckTrack, float]:
    """Frames of the deck exposed lag_s before they arrive (0.5 mm noise), estimated as tracker_lag_s late:
    (the last track, the rms of its heave estimate's error now over the last 20 s of 40) [m]."""
    rng = np.random.default_rng(1)
    track, errors = DeckTrack(), []
    for k in range(4, 800):
        t = k * PERIOD
        exposed = deck_pose(t - lag_s)
        X = RigidTransform(exposed.rotation(), exposed.translation() + 0.0005 * rng.standard_normal(3))
        track = step_deck_track(track, X, t, CONFIG, PERIOD)
        if k >= 400:
            errors.append(deck_estimate(track, t, CONFIG, tracker_lag_s)[0].X_WP.translation()[2]
                          - deck_pose(t).translation()[2])
    return track, float(np.sqrt(np.mean(np.square(errors))))


def test_late_frames_are_predicted_from_their_exposure_to_now():
    """Frames arriving four frames after their exposure (0.2 s): the estimate told the lag gives the deck's
    heave now about as well as on frames without latency; untold, it is behind by the deck's motion."""
    lag = 4 * PERIOD
    track, told_rms = late_frames_heave_rms(lag, lag)
    _, untold_rms = late_frames_heave_rms(lag, 0.0)
    _, prompt_rms = late_frames_heave_rms(0.0, 0.0)
    # The same tracks: told the lag, its estimate now is the untold one's a lag later.
    np.testing.assert_allclose(deck_estimate(track, track.time, CONFIG, lag)[0].X_WP.translation(),
                               deck_estimate(track, track.time + lag, CONFIG)[0].X_WP.translation(), atol=1e-12)
    assert untold_rms > 2e-3  # the deck heaves up to 3 mm in 0.2 s
    assert told_rms < 0.4 * untold_rms and told_rms < 2.0 * prompt_rms


def test_a_track_started_on_a_wrong_frame_restarts_on_the_right_ones():
    """The first frame 9 deg and 5 cm off (CRHF's first frame with stewart-hardware's sensors), the rest
    right: the track restarts on the second, steers from the fourth and holds the deck."""
    rng = np.random.default_rng(2)
    tilt = RotationMatrix(RollPitchYaw(math.radians(9.0), 0.0, 0.0))

    def run(config):
        track, errors = DeckTrack(), []
        for k in range(30):
            t = k * PERIOD
            true = deck_pose(t)
            X = RigidTransform(true.rotation(), true.translation() + 0.001 * rng.standard_normal(3))
            if k == 0:
                X = RigidTransform(tilt.multiply(true.rotation()), true.translation() + [0.05, 0.0, 0.0])
            track = step_deck_track(track, X, t, config, PERIOD)
            estimate = deck_estimate(track, t, config)[0]
            errors.append(math.degrees(estimate.X_WP.rotation().InvertAndCompose(true.rotation()).ToAngleAxis().angle())
                          if estimate.valid else None)
        return errors

    confirmed = run(CONFIG)
    assert confirmed[:3] == [None, None, None] and None not in confirmed[3:]  # the 2nd, 3rd, 4th frames agree
    assert max(confirmed[3:]) < 0.5
    # Confirmed on one frame, it steers on the wrong one; the three right frames it then gates take over.
    at_once = run(replace(CONFIG, confirm_frames=1))
    assert None not in at_once and at_once[0] > 8.0 and max(at_once[7:]) < 0.5
    # With neither, a rate fitted to the jump: the right frames gated, the tracks coasting away.
    unchallenged = run(replace(CONFIG, confirm_frames=1, takeover_frames=1000))
    assert max(unchallenged) > 20.0


def test_frames_that_confirmed_tracks_gate_replace_them_when_they_agree():
    """A confirmed track, then the deck 6 deg and 5 cm from where it was (the tracks gone wrong: on
    re-acquisition they fitted a rate to the first frames' drift): the tracks gate the frames, the frames
    agree with each other, and after takeover_frames of them they are the tracks. Wrong frames that do not
    agree with each other never take over."""
    track = track_run(range(200))
    shift = RigidTransform(RollPitchYaw(0.0, math.radians(6.0), 0.0), [0.05, 0.0, 0.0])
    for k in range(200, 200 + CONFIG.takeover_frames):
        true = shift.multiply(deck_pose(k * PERIOD))
        track = step_deck_track(track, true, k * PERIOD, CONFIG, PERIOD)
        estimate = deck_estimate(track, k * PERIOD, CONFIG)[0]
        angle = math.degrees(estimate.X_WP.rotation().InvertAndCompose(true.rotation()).ToAngleAxis().angle())
        if k < 200 + CONFIG.takeover_frames - 1:
            assert track.coasted_steps == k - 199 and angle > 5.0  # gated, the challenger growing
            assert track.challenger.frames_used == k - 199
        else:
            assert track.coasted_steps == 0 and track.challenger is None and angle < 0.5  # taken over
            assert estimate.valid and np.linalg.norm(estimate.X_WP.translation() - true.translation()) < 0.005
    rng = np.random.default_rng(5)
    track = track_run(range(200))
    for k in range(200, 230):  # outliers scattered 0.3 m around the deck: each starts the challenger afresh
        true = deck_pose(k * PERIOD)
        wrong = RigidTransform(true.rotation(), true.translation() + 0.3 * rng.standard_normal(3))
        track = step_deck_track(track, wrong, k * PERIOD, CONFIG, PERIOD)
        estimate = deck_estimate(track, k * PERIOD, CONFIG)[0]
        assert np.linalg.norm(estimate.X_WP.translation() - true.translation()) < 0.01
        assert track.challenger.frames_used < CONFIG.takeover_frames
    assert track.coasted_steps == 30


def test_a_challenger_does_not_outlive_an_accepted_frame():
    """takeover_frames gated frames must come in a row: a frame the tracks accept ends the challenger. Three
    times one frame 6 deg and 5 cm off (gated: it starts a challenger) then two right ones: the challenger is
    gone after each right frame and the shifted frames never take over."""
    track = track_run(range(200))
    shift = RigidTransform(RollPitchYaw(0.0, math.radians(6.0), 0.0), [0.05, 0.0, 0.0])
    for k in range(200, 209):
        true = deck_pose(k * PERIOD)
        shifted = k % 3 == 2
        track = step_deck_track(track, shift.multiply(true) if shifted else true, k * PERIOD, CONFIG, PERIOD)
        estimate = deck_estimate(track, k * PERIOD, CONFIG)[0]
        assert estimate.valid
        assert math.degrees(estimate.X_WP.rotation().InvertAndCompose(true.rotation()).ToAngleAxis().angle()) < 0.5
        if shifted:
            assert track.coasted_steps == 1 and track.challenger.frames_used == 1
        else:
            assert track.coasted_steps == 0 and track.challenger is None
