"""Seed 003's tracking-by-detection (systems/perception/box_tracker.py): Eq. 2-6 on known boxes and
patches, the box Kalman filter against OpenCV's, and synthetic sequences (a target at constant velocity, a
distractor crossing it, missed detections, a 1 s gap, false alarms) with the target's identity and the
switches counted."""

from dataclasses import dataclass, replace

import cv2
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

from systems.config import ConfigError
from systems.estimators.track_filter import constant_velocity_model
from systems.noise import sample_rng
from systems.perception.box_tracker import (
    HISTOGRAM_SIZE,
    BoxTrack,
    BoxTracker,
    BoxTrackerConfig,
    Detection,
    TrackerState,
    _filter_params,
    associate,
    box_centre_pixel,
    box_corners,
    box_pixels,
    centre_form,
    colour_cost_matrix,
    colour_histogram,
    combined_cost,
    corner_form,
    count_identity_switches,
    histogram_similarity,
    initial_state,
    iou,
    iou_matrix,
    locked_truth_id,
    predict_track,
    recover,
    step_tracker,
    target_box,
)
from systems.perception.box_tracker_system import BoxTrackerSystem

RED, BLUE, GREEN = (200, 40, 40), (40, 60, 200), (40, 190, 60)
WIDTH, HEIGHT = 320, 240
TARGET, DISTRACTOR = 1, 2  # true object ids


# ----------------------------------------------------------------------------------------------
# Eq. 2-5


def test_iou_of_known_boxes():
    a = [0.0, 0.0, 10.0, 10.0]  # [x, y, w, h], (x, y) the top-left corner
    assert iou(a, a) == pytest.approx(1.0)
    assert iou(a, [5.0, 0.0, 10.0, 10.0]) == pytest.approx(50 / 150)  # half overlap: 50 / (100 + 100 - 50)
    assert iou(a, [2.0, 2.0, 5.0, 5.0]) == pytest.approx(25 / 100)  # contained
    assert iou(a, [5.0, 5.0, 10.0, 10.0]) == pytest.approx(25 / 175)
    assert iou(a, [10.0, 0.0, 10.0, 10.0]) == 0.0  # touching edges
    assert iou(a, [30.0, 30.0, 5.0, 5.0]) == 0.0
    assert iou(a, [0.0, 0.0, 0.0, 0.0]) == 0.0  # an empty box
    M = iou_matrix([a, [5.0, 5.0, 10.0, 10.0]], [a, [2.0, 2.0, 5.0, 5.0], [50.0, 0.0, 1.0, 1.0]])
    assert M.shape == (2, 3)
    np.testing.assert_allclose(M, [[1.0, 0.25, 0.0], [25 / 175, 4 / 121, 0.0]])


def test_centre_and_corner_forms():
    box = np.array([10.0, 20.0, 6.0, 4.0])
    np.testing.assert_allclose(centre_form(box), [13.0, 22.0, 6.0, 4.0])
    np.testing.assert_allclose(corner_form(centre_form(box)), box)


def test_box_centre_is_opencv_pixel():
    """A box covering pixels 10-13 and 20-25 (index space) is centred between pixels 11 and 12, 22 and 23."""
    assert np.allclose(box_centre_pixel([10.0, 20.0, 4.0, 6.0]), [11.5, 22.5])


def patch(colours, size=(20, 30)) -> np.ndarray:
    """An RGBA image of vertical stripes of the given colours, equal widths."""
    image = np.zeros((size[0], size[1], 4), np.uint8)
    image[..., 3] = 255
    for k, colour in enumerate(colours):
        image[:, k * size[1] // len(colours):(k + 1) * size[1] // len(colours), :3] = colour
    return image


def test_box_pixels_are_those_the_box_covers_more_than_half_of():
    """A box from 10.6 to 15.6 px covers 0.4 of column 10 and 0.6 of column 15: its pixels are columns 11-15 (its
    corners rounded, as np.rint does away from halves), not 10-14; likewise rows; clipped to the image."""
    box = np.array([10.6, 20.4, 5.0, 5.0])
    assert box_pixels(box, 100, 100) == (11, 20, 16, 25)
    assert box_pixels(box, 100, 100) == tuple(int(c) for c in np.rint(box_corners(box)))
    assert box_pixels(np.array([-3.7, 96.6, 10.0, 10.0]), 100, 100) == (0, 97, 6, 100)
    # the histogram reads those pixels: a one-column red stripe at column 10 lies outside the box
    image = patch([BLUE], size=(40, 30))
    image[:, 10, :3] = RED
    assert histogram_similarity(colour_histogram(image, box), colour_histogram(patch([BLUE]), [0, 0, 5, 5])) == \
        pytest.approx(1.0)


def test_histogram_has_75_bins_of_25_per_channel():
    image = patch([RED])
    h = colour_histogram(image, [0, 0, 30, 20])
    assert h.shape == (HISTOGRAM_SIZE,) == (75,)
    assert h.sum() == pytest.approx(1.0)  # L1-normalised
    # 25 bins of 10.24 levels over [0, 256): R = 200 -> bin 19, G = 40 -> bin 3 (+25), B = 40 -> bin 3 (+50)
    assert set(np.flatnonzero(h)) == {19, 28, 53}
    np.testing.assert_allclose(h[[19, 28, 53]], 1 / 3)
    edge = patch([(10, 11, 255)])
    assert set(np.flatnonzero(colour_histogram(edge, [0, 0, 30, 20]))) == {0, 25 + 1, 50 + 24}
    assert not colour_histogram(image, [100, 100, 10, 10]).any()  # outside the image: no pixels


def test_histogram_similarity_of_identical_and_different_patches():
    red, blue = colour_histogram(patch([RED]), [0, 0, 30, 20]), colour_histogram(patch([BLUE]), [0, 0, 30, 20])
    half = colour_histogram(patch([RED, BLUE]), [0, 0, 30, 20])
    assert histogram_similarity(red, red) == pytest.approx(1.0)
    assert histogram_similarity(red, blue) == pytest.approx(0.0)  # no bin in common
    assert histogram_similarity(red, half) == pytest.approx(0.5)  # half its pixels red
    # Eq. 4's cost matrix (vectorised) is 1 - cv2.compareHist's intersection, pair by pair
    C = colour_cost_matrix(np.array([red, blue]), np.array([red, blue, half]))
    for i, a in enumerate((red, blue)):
        for j, b in enumerate((red, blue, half)):
            assert C[i, j] == pytest.approx(1.0 - cv2.compareHist(a, b, cv2.HISTCMP_INTERSECT), abs=1e-6)
    np.testing.assert_allclose(C, [[0.0, 1.0, 0.5], [1.0, 0.0, 0.5]], atol=1e-6)


def test_combined_cost_is_eq5_with_equal_weights():
    config = BoxTrackerConfig()
    assert (config.iou_weight, config.colour_weight) == (0.5, 0.5)
    cost = combined_cost(np.array([[1.0, 0.5, 0.0]]), np.array([[0.0, 0.2, 1.0]]), config)
    np.testing.assert_allclose(cost, [[0.0, 0.5 * 0.5 + 0.5 * 0.2, 1.0]])


# ----------------------------------------------------------------------------------------------
# The box Kalman filter


def test_kalman_prediction_through_missed_frames():
    config = BoxTrackerConfig(measurement_std_px=2.0)
    velocity = np.array([30.0, -12.0])  # px/s
    dt = config.period_s

    def true_box(t):
        return np.array([50.0 + velocity[0] * t, 120.0 + velocity[1] * t, 24.0, 16.0])

    state = TrackerState()
    for k in range(10):  # ten frames seen (noise-free), then ten missed: a 1 s gap at 10 Hz
        state = step_tracker(state, [Detection(true_box(k * dt), 0.9, 1)], None, k * dt, config)
    track = state.tracks[0]
    assert track.confirmed and track.hits == 10
    traces = [np.trace(track.P[:2, :2])]
    for k in range(10, 20):
        state = step_tracker(state, [], None, k * dt, config)
        track = state.tracks[0]
        assert track.misses == k - 9 and track.detection is None
        traces.append(np.trace(track.P[:2, :2]))
        # constant-velocity extrapolation: within 1.5 px of the truth after up to a second of coasting
        np.testing.assert_allclose(track.box, true_box(k * dt), atol=1.5)
    assert np.all(np.diff(traces) > 0)  # the uncertainty grows while coasting
    np.testing.assert_allclose(track.velocity, velocity, atol=1.0)
    # the box is the target's output while it coasts, and the track dies after max_misses (15) misses
    for k in range(20, 26):
        state = step_tracker(state, [], None, k * dt, config)
    assert len(state.tracks) == 0


def test_box_filter_matches_opencv_kalman_filter():
    """The track's predict and update steps against cv2.KalmanFilter with the same model."""
    config = BoxTrackerConfig()
    dt = config.period_s
    F, Q, H, R = constant_velocity_model(_filter_params(config, dt), 4)
    kf = cv2.KalmanFilter(8, 4, 0, cv2.CV_64F)
    kf.transitionMatrix, kf.processNoiseCov = F.copy(), Q.copy()
    kf.measurementMatrix, kf.measurementNoiseCov = H.copy(), R.copy()
    rng = np.random.default_rng(3)
    boxes = [np.array([40.0 + 3 * k, 60.0 - k, 20.0 + 0.2 * k, 12.0]) + rng.normal(0, 1.5, 4) for k in range(8)]
    state = step_tracker(TrackerState(), [Detection(boxes[0])], None, 0.0, config)
    kf.statePost, kf.errorCovPost = state.tracks[0].x.reshape(8, 1).copy(), state.tracks[0].P.copy()
    for k in range(1, 8):
        missed = k in (3, 4)
        state = step_tracker(state, [] if missed else [Detection(boxes[k])], None, k * dt, config)
        kf.predict()
        if not missed:
            kf.correct(centre_form(boxes[k]).reshape(4, 1))
            x, P = kf.statePost.ravel(), kf.errorCovPost
        else:
            x, P = kf.statePre.ravel(), kf.errorCovPre
        np.testing.assert_allclose(state.tracks[0].x, x, atol=1e-9)
        np.testing.assert_allclose(state.tracks[0].P, P, atol=1e-9)


def test_predict_keeps_box_sizes_positive():
    config = BoxTrackerConfig()
    state = step_tracker(TrackerState(), [Detection(np.array([10.0, 10.0, 4.0, 4.0]))], None, 0.0, config)
    track = replace(state.tracks[0], x=np.r_[state.tracks[0].x[:4], 0.0, 0.0, -100.0, -100.0])
    assert np.all(predict_track(track, 1.0, config).box[2:] >= 1.0)


# ----------------------------------------------------------------------------------------------
# Synthetic sequences


@dataclass
class Sequence:
    """A synthetic run: per frame the detections (truth ids set), the image and the time."""

    times: np.ndarray
    detections: list[list[Detection]]
    images: list[np.ndarray]


def true_boxes(t: float, distractor_colour, lane_offset: float = 8.0) -> dict[int, np.ndarray]:
    """Top-left boxes of the target (left to right at 25 px/s) and a distractor crossing it (right to left,
    `lane_offset` px lower), crossing at t = 4 s; no distractor when its colour is None."""
    boxes = {TARGET: np.array([45.0 + 25.0 * t, 110.0, 30.0, 20.0])}
    if distractor_colour is not None:
        boxes[DISTRACTOR] = np.array([245.0 - 25.0 * t, 110.0 + lane_offset, 30.0, 20.0])
    return boxes


def make_sequence(seed: int, distractor_colour=BLUE, duration_s: float = 8.0, gap_s=(5.5, 6.5),
                  miss_probability: float = 0.1, target_colour=RED, lane_offset: float = 8.0,
                  occlusion_iou: float = 0.3) -> Sequence:
    """10 Hz frames of a textured grey ground with the target (drawn behind) and the distractor; the detector
    (box noise 1 px) misses the target with `miss_probability`, throughout `gap_s` and whenever the
    distractor covers it (IOU > occlusion_iou), and adds a one-frame false alarm every 1.3 s.
    Seeded: frame k draws from sample_rng(seed, "box_detections", k)."""
    ground = np.random.default_rng(seed).integers(90, 150, (HEIGHT, WIDTH), dtype=np.uint8)
    times = np.arange(0.0, duration_s, 0.1)
    detections, images = [], []
    for k, t in enumerate(times):
        rng = sample_rng(seed, "box_detections", k)
        boxes = true_boxes(t, distractor_colour, lane_offset)
        image = np.dstack([ground, ground, ground, np.full_like(ground, 255)])
        for object_id, colour in ((TARGET, target_colour), (DISTRACTOR, distractor_colour)):
            if object_id in boxes:
                x, y, w, h = np.round(boxes[object_id]).astype(int)
                image[y:y + h, x:x + w, :3] = colour
        frame = []
        occluded = DISTRACTOR in boxes and iou(boxes[TARGET], boxes[DISTRACTOR]) > occlusion_iou
        missed = rng.random() < miss_probability or gap_s[0] <= t < gap_s[1] or occluded
        for object_id, box in boxes.items():
            if object_id == TARGET and missed:
                continue
            frame.append(Detection(box + rng.normal(0.0, 1.0, 4), 0.8 + 0.2 * rng.random(), object_id))
        if k % 13 == 5:  # a false alarm somewhere on the ground
            frame.append(Detection(np.array([rng.uniform(0, WIDTH - 30), rng.uniform(0, 60), 30.0, 20.0]), 0.6, -1))
        rng.shuffle(frame)
        detections.append(frame)
        images.append(image)
    return Sequence(times, detections, images)


def run(sequence: Sequence, config: BoxTrackerConfig, use_images: bool = True):
    """(locked ids, locked truth ids, final state) of the tracker over a sequence."""
    tracker = BoxTracker(config)
    locked, truth = [], []
    for t, frame, image in zip(sequence.times, sequence.detections, sequence.images):
        state = tracker.step(frame, image if use_images else None, float(t))
        locked.append(state.lock.track_id)
        truth.append(locked_truth_id(state, [d.truth_id for d in frame]))
    return locked, truth, tracker.state


CUE = [60.0, 120.0]  # near the target's first box: the initial cue


@pytest.mark.parametrize("seed", [0, 1, 2, 5])
def test_target_kept_through_crossing_misses_and_gap(seed):
    """A red target behind a blue distractor crossing it, 10 % missed detections, a 1 s gap and false
    alarms: the lock stays on one track, on the target, from its confirmation to the end. (Seed 5 misses the
    target's second frame: its tentative track dies, the distractor is confirmed first and is not taken, as
    it is beyond cue_radius_px.)"""
    sequence = make_sequence(seed)
    locked, truth, state = run(sequence, BoxTrackerConfig(cue_px=CUE))
    switches = count_identity_switches(locked, truth, TARGET)
    assert switches.total == 0, switches
    assert switches.frames_off_target == 0
    first = next(k for k, i in enumerate(locked) if i is not None)
    assert 2 <= first <= 6  # at the third hit (min_hits = 3)
    assert len(set(locked[first:])) == 1  # never lost: the gap (10 frames) is within max_misses (15)
    assert switches.frames_on_target >= 45  # of 80 frames: less the missed ones, the gap and those before the lock
    # at the end the target's box follows the truth
    np.testing.assert_allclose(state.target.box, true_boxes(sequence.times[-1], BLUE)[TARGET], atol=3.0)


def make_sequence_with_newcomer(seed: int, colour, start_s: float = 3.0) -> Sequence:
    """No crossing: the target is missed for 1 s from `start_s` (under a tree, say), and a newcomer of the
    given colour appears then beside its path (6 px ahead, 8 px lower) and drives off diagonally
    (25, 15) px/s. The newcomer has no track yet: nothing competes with the target's coasting track for it."""
    sequence = make_sequence(seed, distractor_colour=None, gap_s=(start_s, start_s + 1.0), miss_probability=0.0)
    for k, t in enumerate(sequence.times):
        if t < start_s - 1e-9:
            continue
        box = true_boxes(start_s, None)[TARGET] + np.array([6.0 + 25.0 * (t - start_s), 8.0 + 15.0 * (t - start_s),
                                                             0.0, 0.0])
        noise = sample_rng(seed, "newcomer", k).normal(0.0, 1.0, 4)
        sequence.detections[k].append(Detection(box + noise, 0.9, DISTRACTOR))
        x, y, w, h = np.round(box).astype(int)
        sequence.images[k][y:y + h, x:x + w, :3] = colour
    return sequence


@pytest.mark.parametrize("seed", [0, 1])
def test_colour_keeps_a_newcomer_from_taking_the_coasting_target(seed):
    """The newcomer's box passes the coasting track's chi-square gate and, on geometry alone, its cost gate; a
    differently coloured one has a colour cost near 1, which fails the colour gate (0.5) and lifts Eq. 5's
    cost above max_cost (0.75) too, and the lock stays on the target.
    Of the target's own colour, or on boxes alone, it takes the track: one object change, the lock then on
    the newcomer to the end (over 20 seeds: 0/20 runs switch with blue or green, 20/20 with red or boxes
    alone)."""
    config = BoxTrackerConfig(cue_px=CUE)
    for colour in (BLUE, GREEN):
        locked, truth, _ = run(make_sequence_with_newcomer(seed, colour), config)
        switches = count_identity_switches(locked, truth, TARGET)
        assert (switches.total, switches.frames_off_target) == (0, 0), colour
    for colour, use_images in ((RED, True), (BLUE, False)):
        locked, truth, _ = run(make_sequence_with_newcomer(seed, colour), config, use_images)
        switches = count_identity_switches(locked, truth, TARGET)
        assert (switches.id_changes, switches.object_changes) == (0, 1), (colour, use_images)
        assert switches.frames_off_target >= 40  # from the gap's end (4 s) to the end (8 s)


def test_a_colour_weight_of_zero_tracks_on_boxes_alone():
    """With colour_weight 0 the images change nothing (no colour cost, no colour gate): the blue newcomer takes
    the coasting target's track as it does on boxes alone, frame for frame. (max_cost 1: no cost gate, as there
    is none on boxes alone with the default weights, whose cost a1 (1 - IOU) is at most 0.5.)"""
    config = BoxTrackerConfig(cue_px=CUE, iou_weight=1.0, colour_weight=0.0, max_cost=1.0)
    sequence = make_sequence_with_newcomer(0, BLUE)
    locked, truth, state = run(sequence, config)
    assert (locked, truth) == run(sequence, config, use_images=False)[:2]
    switches = count_identity_switches(locked, truth, TARGET)
    assert (switches.id_changes, switches.object_changes) == (0, 1)
    assert not any(t.histogram.any() for t in state.tracks)  # no appearance kept


def make_sequence_same_lane(seed: int, distractor_colour) -> Sequence:
    """The distractor drives in the target's lane and the detector misses the target while they overlap at
    all: the distractor's box sits on the target's predicted box."""
    return make_sequence(seed, distractor_colour, miss_probability=0.0, gap_s=(0.0, 0.0), lane_offset=0.0,
                         occlusion_iou=0.0)


def test_same_colour_crossing():
    """The crossing with a distractor of the target's own colour, where the colour term cannot tell them
    apart. Recorded behaviour: in the offset lane the Kalman prediction and the Hungarian assignment keep
    the target (0 switches over 20 seeds, as with a blue distractor or boxes alone). In the target's own
    lane, with the target unseen while they overlap, the pair's costs tie at the crossing: seed 2 jumps to
    the distractor for one frame and back (two object changes; 5 of 20 seeds switch, 0 of 20 with a blue
    distractor)."""
    config = BoxTrackerConfig(cue_px=CUE)
    for seed in (0, 1, 2):
        locked, truth, _ = run(make_sequence(seed, distractor_colour=RED), config)
        assert count_identity_switches(locked, truth, TARGET).total == 0
    locked, truth, _ = run(make_sequence_same_lane(2, RED), config)
    switches = count_identity_switches(locked, truth, TARGET)
    assert (switches.id_changes, switches.object_changes, switches.frames_off_target) == (0, 2, 1)
    locked, truth, _ = run(make_sequence_same_lane(2, BLUE), config)
    assert count_identity_switches(locked, truth, TARGET).total == 0


def test_lost_target_reacquired_under_a_new_id_counts_one_switch():
    """A 3 s gap (past max_misses = 1.5 s): the target's track dies, a new one is confirmed when it is seen
    again and the lock passes to it: one id change, no object change, back on the target."""
    sequence = make_sequence(4, distractor_colour=None, gap_s=(2.0, 5.0), miss_probability=0.0)
    locked, truth, _ = run(sequence, BoxTrackerConfig(cue_px=CUE))
    switches = count_identity_switches(locked, truth, TARGET)
    assert (switches.id_changes, switches.object_changes, switches.frames_off_target) == (1, 0, 0)
    k_lost = next(k for k, t in enumerate(sequence.times) if t >= 2.0) + 15  # its 16th miss: dead
    assert locked[k_lost - 1] is not None and locked[k_lost] is None
    assert len({i for i in locked if i is not None}) == 2


@pytest.mark.parametrize("fragment", [(16.0, 30.0), (40.0, 12.0)], ids=["narrower", "shorter"])
def test_partial_view_is_not_measured_and_starts_no_track(fragment):
    """A target boxed at 40 % of its width, or of its height, for 1 s (half under a bridge): the fragments are not
    associated and start no track; the target's track coasts at its own velocity as if unseen (not pulled to the
    fragments' centre) and, inside max_misses, matches the whole target's box again under its id."""
    tracker, v = BoxTracker(BoxTrackerConfig()), np.array([20.0, 0.0])  # px/s

    def box(t, width=40.0, height=30.0):
        return np.array([*(np.array([200.0, 250.0]) + v * t), width, height])

    for k in range(10):
        state = tracker.step([Detection(box(0.1 * k))], None, 0.1 * k)
    target_id = state.target.id
    for k in range(10, 20):
        state = tracker.step([Detection(box(0.1 * k, *fragment))], None, 0.1 * k)
        target = state.target
        assert target.id == target_id and target.detection is None and target.misses == k - 9
        assert np.allclose(target.box, box(0.1 * k), atol=1.5)  # the whole box, predicted
        assert [t.id for t in state.tracks] == [target_id]
    state = tracker.step([Detection(box(2.0))], None, 2.0)
    assert state.target.id == target_id and state.target.detection == 0 and state.target.misses == 0


def test_a_box_smaller_both_ways_is_the_targets_whole_view_not_a_fragment():
    """A still target boxed 100 x 110 px for 8 frames (the learned detector's oversized first boxes near the ground),
    then 50 x 70 px inside it (half the width, under two thirds of the height: no cut leaves that): the locked track
    measures it under its id and takes its size, and no other track starts."""
    tracker, big, true = BoxTracker(BoxTrackerConfig()), np.array([100.0, 100.0, 100.0, 110.0]), \
        np.array([125.0, 120.0, 50.0, 70.0])
    for k in range(8):
        state = tracker.step([Detection(big)], None, 0.1 * k)
    target_id = state.target.id
    for k in range(8, 12):
        state = tracker.step([Detection(true)], None, 0.1 * k)
        assert [t.id for t in state.tracks] == [target_id] and state.target.detection == 0
    assert iou(state.target.box, true) > 0.9


def test_a_partial_view_in_an_image_leaves_the_other_detections_to_their_tracks():
    """With images, a red target's fragment listed before a distant blue vehicle: the target coasts, and the
    vehicle's track is matched with the vehicle's own detection and keeps a blue appearance, 1/3 in each of
    the bins of (40, 60, 200) (25 bins of 10.24 levels: R bin 3, G bin 5, B bin 19)."""
    target, vehicle = np.array([200.0, 250.0, 40.0, 30.0]), np.array([40.0, 40.0, 50.0, 40.0])
    image = np.zeros((512, 512, 4), np.uint8)
    image[250:280, 200:240, :3], image[40:80, 40:90, :3] = RED, BLUE
    tracker = BoxTracker(BoxTrackerConfig(cue_px=[220.0, 265.0]))
    for k in range(10):
        state = tracker.step([Detection(target), Detection(vehicle)], image, 0.1 * k)
    target_id, vehicle_id = state.target.id, next(t.id for t in state.tracks if t.id != state.target.id)
    image[250:280, 216:240, :3] = 128  # the target's right 60 % under a grey bridge
    for k in range(10, 15):
        state = tracker.step([Detection(np.array([200.0, 250.0, 16.0, 30.0])), Detection(vehicle)], image, 0.1 * k)
        assert [t.id for t in state.tracks] == [target_id, vehicle_id]
        assert (state.target.detection, state.target.misses) == (None, k - 9)
        blue = state.track(vehicle_id)
        assert (blue.detection, blue.misses) == (1, 0)
        np.testing.assert_allclose(blue.histogram[[3, 25 + 5, 50 + 19]], 1 / 3, atol=1e-6)


def test_a_smaller_object_over_a_larger_track_keeps_its_own_track():
    """A red 40 px target seen over a grey 140 px vehicle (inside its box, under 0.6 of its size) from the
    first frame: both confirmed, the target's whole box is its own track's view, not the vehicle's fragment,
    so it is matched in every frame and the lock on it holds."""
    image = np.zeros((512, 512, 4), np.uint8)
    image[200:340, 200:340, :3], image[290:330, 290:330, :3] = (128, 128, 128), (220, 30, 30)
    vehicle, target = np.array([200.0, 200.0, 140.0, 140.0]), np.array([290.0, 290.0, 40.0, 40.0])
    tracker = BoxTracker(BoxTrackerConfig(cue_px=[310.0, 310.0]))
    for k in range(25):
        state = tracker.step([Detection(vehicle, 0.9), Detection(target, 0.9)], image, 0.1 * k)
        if k >= 2:
            assert [(t.confirmed, t.misses, t.detection) for t in state.tracks] == [(True, 0, 0), (True, 0, 1)]
            assert state.lock.track_id == state.tracks[1].id
    assert np.allclose(target_box(state)[0], target) and target_box(state)[1]


@pytest.mark.parametrize("rows_cols, nearer, farther", [
    # 512 px: the centre (256, 256) in the boxes' centre form (x + w / 2); the box centred 7 px down and right of it
    # (9.90 px away) is nearer than one 7.2 px up and left (10.18 px); OpenCV's (255.5, 255.5) would take the other
    # (10.61 against 9.48 px)
    ((512, 512), [258.0, 258.0, 10.0, 10.0], [243.8, 243.8, 10.0, 10.0]),
    # 640 x 480: the centre (320, 240), u across the 640 columns, v down the 480 rows; the other box centred at
    # (240, 320), 113 px off, within cue_radius_px
    ((480, 640), [310.0, 230.0, 20.0, 20.0], [230.0, 310.0, 20.0, 20.0]),
], ids=["square", "wide"])
def test_the_default_cue_is_the_image_centre_in_the_boxes_pixel_index_space(rows_cols, nearer, farther):
    """Without a cue the lock takes the track nearest the image's centre, (width / 2, height / 2) in the boxes'
    pixel-index space."""
    image = np.zeros((*rows_cols, 4), np.uint8)
    tracker = BoxTracker(BoxTrackerConfig())
    for k in range(3):
        state = tracker.step([Detection(np.array(farther), 0.9), Detection(np.array(nearer), 0.9)], image, 0.1 * k)
    assert np.allclose(target_box(state)[0], nearer)


def test_lock_takes_only_a_confident_track():
    """Two steady tracks, the one nearer the cue scoring 0.6 (a marginal box), the other 0.95: with
    lock_min_score 0.8 the lock takes the confident one; without, the nearer."""
    marginal, confident = np.array([250.0, 250.0, 30.0, 30.0]), np.array([350.0, 300.0, 30.0, 30.0])
    for min_score, expected in ((0.8, confident), (0.0, marginal)):
        tracker = BoxTracker(BoxTrackerConfig(cue_px=[256.0, 256.0], cue_radius_px=300.0, lock_min_score=min_score))
        for k in range(5):
            state = tracker.step([Detection(marginal, 0.6), Detection(confident, 0.95)], None, 0.1 * k)
        assert np.allclose(state.target.box, expected, atol=1e-6)
        assert state.target.score == (0.95 if min_score else 0.6)


def test_a_tracks_score_is_its_best_detections():
    """A track first boxed at 0.95, then at 0.6: its score stays 0.95 (the best of its detections), so with
    lock_min_score 0.8 the lock takes it once it is confirmed, though its latest boxes are marginal."""
    box = np.array([250.0, 250.0, 30.0, 30.0])
    tracker = BoxTracker(BoxTrackerConfig(cue_px=[256.0, 256.0], lock_min_score=0.8))
    for k, score in enumerate((0.95, 0.6, 0.6, 0.6)):
        state = tracker.step([Detection(box, score)], None, 0.1 * k)
    assert [t.score for t in state.tracks] == [0.95]
    assert state.target is not None and state.target.id == state.tracks[0].id


def test_reacquire_skips_a_nearer_tentative_track_for_a_confirmed_one():
    """The locked target's track dies (max_misses 0) in the frame where a new, tentative track starts right on
    its last box (a box three times its size, outside its gate): the lock passes at once to the confirmed
    track 80 px away (within reacquire_radius_px), the nearest confirmed one, not held back by the nearer
    tentative one."""
    target, other = np.array([100.0, 100.0, 20.0, 20.0]), np.array([180.0, 100.0, 20.0, 20.0])
    config = BoxTrackerConfig(cue_px=[110.0, 110.0], cue_radius_px=30.0, max_misses=0)
    tracker = BoxTracker(config)
    for k in range(4):
        state = tracker.step([Detection(target), Detection(other)], None, 0.1 * k)
    target_id = state.target.id
    other_id = next(t.id for t in state.tracks if t.id != target_id)
    assert target_id != other_id and all(t.confirmed for t in state.tracks)
    state = tracker.step([Detection(np.array([80.0, 80.0, 60.0, 60.0])), Detection(other)], None, 0.4)
    newcomer = next(t for t in state.tracks if t.id not in (target_id, other_id))
    assert state.track(target_id) is None and not newcomer.confirmed
    last = centre_form(target)[:2]
    assert np.linalg.norm(newcomer.centre - last) < np.linalg.norm(state.track(other_id).centre - last)
    assert state.lock.track_id == other_id


def lost_and_reacquired(target, others, config, image=None):
    """The state after the target, locked over three frames among `others`, goes unseen for a frame (its track
    dropped: config's max_misses 0) and the lock passes to another track."""
    tracker = BoxTracker(config)
    for k in range(3):
        state = tracker.step([Detection(target), *map(Detection, others)], image, 0.1 * k)
    target_id = state.target.id
    state = tracker.step(list(map(Detection, others)), image, 0.3)
    assert state.track(target_id) is None
    return state


def test_reacquire_measures_from_the_last_boxs_centre():
    """A lost 60 px target's last box has its centre at (130, 130): the lock passes to the track centred 40 px
    from it (at (170, 130)), not to the one 71 px away at (80, 80), though that one is nearer the box's
    top-left corner (28 px against 76 px)."""
    target = np.array([100.0, 100.0, 60.0, 60.0])
    right, corner = np.array([160.0, 120.0, 20.0, 20.0]), np.array([70.0, 70.0, 20.0, 20.0])
    state = lost_and_reacquired(target, [right, corner],
                                BoxTrackerConfig(cue_px=[130.0, 130.0], cue_radius_px=30.0, max_misses=0))
    assert np.allclose(state.target.box, right)


def test_reacquire_takes_a_track_of_the_targets_colour():
    """A red target's track dies; a blue confirmed track lies 40 px from its last box and a red one 90 px: with
    images the lock passes to the red one (the blue one's colour cost, 1, is over max_colour_cost); on boxes
    alone to the nearer blue one."""
    target, blue, red = (np.array([100.0, 100.0, 30.0, 20.0]), np.array([140.0, 100.0, 30.0, 20.0]),
                         np.array([100.0, 190.0, 30.0, 20.0]))
    image = np.zeros((240, 320, 4), np.uint8)
    image[100:120, 100:130, :3], image[100:120, 140:170, :3], image[190:210, 100:130, :3] = RED, BLUE, RED
    config = BoxTrackerConfig(cue_px=[115.0, 110.0], cue_radius_px=20.0, max_misses=0)
    for use_image, expected in ((True, red), (False, blue)):
        state = lost_and_reacquired(target, [blue, red], config, image if use_image else None)
        assert np.allclose(state.target.box, expected), use_image


def test_false_alarms_are_never_locked_or_confirmed():
    """One-frame false alarms (truth id -1) start tentative tracks that die unconfirmed."""
    sequence = make_sequence(5)
    tracker = BoxTracker(BoxTrackerConfig(cue_px=CUE))
    for t, frame, image in zip(sequence.times, sequence.detections, sequence.images):
        state = tracker.step(frame, image, float(t))
        for track in state.tracks:
            if track.detection is not None and frame[track.detection].truth_id == -1:
                assert not track.confirmed and track.hits == 1


def test_identity_switch_counter_on_hand_made_histories():
    none = None
    # kept, lost (coasting, no lock) and back under the same id: no switch
    assert count_identity_switches([none, 3, 3, none, 3], [none, 1, none, none, 1]).total == 0
    # re-acquired under another id: one id change (even on the same object)
    s = count_identity_switches([3, 3, none, 7, 7], [1, 1, none, 1, 1], target_truth_id=1)
    assert (s.id_changes, s.object_changes, s.frames_on_target, s.frames_off_target) == (1, 0, 4, 0)
    # the same id jumps to another object and back: two object changes
    s = count_identity_switches([3, 3, 3, 3, 3], [1, 1, 2, none, 1], target_truth_id=1)
    assert (s.id_changes, s.object_changes, s.frames_off_target) == (0, 2, 1)
    # an id change onto another object counts once
    assert count_identity_switches([3, 4], [1, 2]).total == 1
    # re-acquired under another id that is coasting at first: its first matched object is no object change
    s = count_identity_switches([3, 3, 7, 7], [1, 1, none, 2])
    assert (s.id_changes, s.object_changes) == (1, 0)
    with pytest.raises(ConfigError, match="one entry per frame"):
        count_identity_switches([1, 2], [1])


def test_lock_takes_the_confirmed_track_nearest_the_cue():
    config = BoxTrackerConfig(cue_px=[200.0, 50.0])
    far, near = Detection(np.array([10.0, 10.0, 20.0, 20.0])), Detection(np.array([180.0, 40.0, 20.0, 20.0]))
    state = TrackerState()
    for k in range(3):
        state = step_tracker(state, [far, near], None, 0.1 * k, config)
    assert state.target is not None and state.target.detection == 1
    none_near = replace(config, cue_radius_px=5.0)
    state = TrackerState()
    for k in range(3):
        state = step_tracker(state, [far, near], None, 0.1 * k, none_near)
    assert state.target is None and len(state.tracks) == 2


def test_low_scores_and_bad_boxes_are_not_used():
    config = BoxTrackerConfig()
    detections = [Detection(np.array([0.0, 0.0, 10.0, 10.0]), 0.2), Detection(np.array([5.0, 5.0, 0.0, 4.0])),
                  Detection(np.array([np.nan, 0.0, 10.0, 10.0]))]
    assert step_tracker(TrackerState(), detections, None, 0.0, config).tracks == ()
    # A score of exactly min_score is used: ColourPadDetector scores 0.5 at its acceptance limits.
    assert config.min_score == 0.5
    at_limit = [Detection(np.array([0.0, 0.0, 10.0, 10.0]), 0.5)]
    assert len(step_tracker(TrackerState(), at_limit, None, 0.0, replace(config, min_hits=1)).tracks) == 1


def test_a_tracks_detection_indexes_the_frames_own_list():
    """BoxTrack.detection counts the frame's dropped detections (a low score, a NaN box) too: the target listed
    third is detection 2, at its track's birth and in later frames, and locked_truth_id finds its truth id."""
    frame = [Detection(np.array([300.0, 50.0, 20.0, 20.0]), 0.2, truth_id=9),
             Detection(np.array([np.nan, 0.0, 10.0, 10.0]), 0.9, truth_id=8),
             Detection(np.array([100.0, 100.0, 20.0, 20.0]), 0.9, truth_id=TARGET)]
    state = TrackerState()
    for k in range(3):
        state = step_tracker(state, frame, None, 0.1 * k, BoxTrackerConfig(min_hits=1))
        assert [t.detection for t in state.tracks] == [2] and state.target.hits == k + 1
        assert locked_truth_id(state, [d.truth_id for d in frame]) == TARGET


def test_a_box_of_no_height_or_width_is_not_used():
    """A box with a zero or negative height (or width) covers no pixel: it starts no track, whatever its score."""
    for box in ([5.0, 5.0, 4.0, 0.0], [5.0, 5.0, 4.0, -3.0], [5.0, 5.0, 0.0, 4.0], [5.0, 5.0, -3.0, 4.0]):
        state = step_tracker(TrackerState(), [Detection(np.array(box), 0.9)], None, 0.0, BoxTrackerConfig(min_hits=1))
        assert state.tracks == (), box


def ground_with(box, colour) -> np.ndarray:
    """A (200, 300, 3) grey image (110) with the integer box [x, y, w, h] painted in `colour`."""
    image = np.full((200, 300, 3), 110, np.uint8)
    x, y, w, h = (int(v) for v in box)
    image[y:y + h, x:x + w] = colour
    return image


def test_a_differently_coloured_box_in_the_same_place_is_gated_by_colour_alone():
    """The same box red (255, 0, 0), then blue (0, 0, 255): their histograms share only G's bin 0 (1/3 of each),
    a colour cost of 2/3 over max_colour_cost 0.5, while IOU 1 makes the combined cost 0.5 * 2/3 = 1/3, under
    max_cost 0.75: the colour gate alone keeps the blue box from the red track, which coasts."""
    box = np.array([100.0, 100.0, 20.0, 20.0])
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1))
    tracker.step([Detection(box)], ground_with(box, (255, 0, 0)), 0.0)
    state = tracker.step([Detection(box)], ground_with(box, (0, 0, 255)), 0.1)
    assert [t.id for t in state.tracks] == [0, 1]
    assert (state.track(0).detection, state.track(0).misses) == (None, 1)
    assert state.track(1).detection == 0


def test_a_pair_over_max_cost_is_not_assigned():
    """Without images, a 10 px box moved 5 px: IOU 50 / 150 = 1/3, combined cost 0.5 (1 - 1/3) = 1/3, over
    max_cost 0.3 (the innovation gate passes, chi-square about 0.23): not assigned, a new track starts."""
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1, max_cost=0.3))
    tracker.step([Detection(np.array([100.0, 100.0, 10.0, 10.0]))], None, 0.0)
    state = tracker.step([Detection(np.array([105.0, 100.0, 10.0, 10.0]))], None, 0.1)
    assert [t.id for t in state.tracks] == [0, 1]
    assert state.track(0).detection is None


def test_lock_takes_a_track_scoring_exactly_lock_min_score():
    state = BoxTracker(BoxTrackerConfig(min_hits=1, lock_min_score=0.8)).step(
        [Detection(np.array([250.0, 250.0, 10.0, 10.0]), 0.8)], None, 0.0)
    assert state.lock.track_id == 0


def test_a_narrower_box_mostly_outside_the_track_is_matched_not_a_partial_view():
    """A 40 x 30 px track, then a 16 px wide box (under 0.6 of 40) overlapping it by 10 columns: 300 / 480 = 0.625
    of it inside the predicted box, under PARTIAL_INSIDE 0.8, so it is a whole view: matched (IOU 300 / 1380,
    combined cost 0.39), the track does not coast."""
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1))
    tracker.step([Detection(np.array([100.0, 100.0, 40.0, 30.0]))], None, 0.0)
    state = tracker.step([Detection(np.array([130.0, 100.0, 16.0, 30.0]))], None, 0.1)
    assert [t.id for t in state.tracks] == [0]
    assert (state.track(0).detection, state.track(0).misses) == (0, 0)


def test_a_frame_earlier_than_the_last_predicts_nothing():
    """A frame whose time goes back to an earlier one is taken as dt = 0, not |dt|: a moving track (over
    10 px/s) coasts in place, its box exactly the last frame's."""
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1))
    tracker.step([Detection(np.array([100.0, 100.0, 10.0, 10.0]))], None, 1.0)
    last = tracker.step([Detection(np.array([110.0, 100.0, 10.0, 10.0]))], None, 1.1)
    assert last.track(0).detection == 0 and last.track(0).velocity[0] > 10.0
    state = tracker.step([], None, 1.0)
    assert state.track(0).detection is None
    np.testing.assert_array_equal(state.track(0).box, last.track(0).box)


def image_with(box: np.ndarray, colour) -> np.ndarray:
    """A WIDTH x HEIGHT RGBA frame, black but for `box` [x, y, w, h] (integers) painted `colour`."""
    image = np.zeros((HEIGHT, WIDTH, 4), np.uint8)
    x, y, w, h = (int(v) for v in box)
    image[y:y + h, x:x + w, :3] = colour
    return image


@pytest.mark.parametrize("shift_px, colour, recovered", [(0.0, RED, True), (-10.0, RED, True),
                                                         (-11.0, RED, False), (0.0, BLUE, False)],
                         ids=["where-last-seen", "iou-0.33", "iou-0.29", "other-colour"])
def test_a_target_that_stops_dead_is_recovered_from_its_last_observed_box(shift_px, colour, recovered):
    """A red 20 px target crosses at 200 px/s for 8 frames, then stops dead. Its constant-velocity prediction runs
    20 px on, outside the innovation gate (asserted: the first association refuses the detection). Recovery pairs
    the track with a detection of its colour whose IOU with its last observed box (x = 240) is at least 0.3: one
    where it was last seen, or 10 px back (IOU 10/30 = 0.33); its state restarts there, velocity 0. 11 px back
    (IOU 9/31 = 0.29), or blue where it was last seen, starts a new track and the target's coasts."""
    config = BoxTrackerConfig(cue_px=[110.0, 110.0])
    tracker, dt = BoxTracker(config), 0.1
    for k in range(8):
        box = np.array([100.0 + 20.0 * k, 100.0, 20.0, 20.0])
        state = tracker.step([Detection(box)], image_with(box, RED), dt * k)
    target = state.target
    assert target is not None and np.allclose(target.velocity, [200.0, 0.0], atol=5.0)
    stopped = np.array([240.0 + shift_px, 100.0, 20.0, 20.0])
    predicted = predict_track(target, dt, config)
    assert associate([predicted], stopped[None], None, None, config) == []
    state = tracker.step([Detection(stopped)], image_with(stopped, colour), dt * 8)
    track = state.track(target.id)
    assert state.target is track and (track.detection == 0) == recovered
    if recovered:
        x, P = initial_state(stopped, config)
        np.testing.assert_array_equal(track.x, x)
        np.testing.assert_array_equal(track.P, P)
        np.testing.assert_array_equal(track.observed, stopped)
        assert len(state.tracks) == 1
    else:
        assert track.misses == 1 and track.velocity[0] > 150.0
        np.testing.assert_array_equal(track.observed, target.observed)
        assert [t.detection for t in state.tracks if t.id != target.id] == [0]


def test_recovery_pairs_only_tracks_with_an_observed_box():
    """`recover` on two tracks whose predictions lie far off, one detection on each's last observed box: both
    paired; a track built without an observed box (by hand, as BoxTrack allows) takes none."""
    config = BoxTrackerConfig()
    seen = [np.array([10.0, 10.0, 20.0, 20.0]), np.array([200.0, 10.0, 20.0, 20.0])]
    tracks = [BoxTrack(k, np.r_[500.0, 500.0, 20.0, 20.0, np.zeros(4)], np.eye(8), observed=box)
              for k, box in enumerate(seen)]
    boxes = np.array(seen[::-1])
    assert sorted(recover(tracks, boxes, None, None, config)) == [(0, 1), (1, 0)]
    assert recover([tracks[0], replace(tracks[1], observed=None)], boxes, None, None, config) == [(0, 1)]
    assert recover(tracks, np.zeros((0, 4)), None, None, config) == []


def test_bad_configs_name_the_field():
    for kwargs, field_name in (({"iou_weight": 0.7}, "box_tracker.iou_weight + box_tracker.colour_weight"),
                               ({"min_hits": 0}, "box_tracker.min_hits"),
                               ({"max_misses": -1}, "box_tracker.max_misses"),
                               ({"rate_hz": 0.0}, "box_tracker.rate_hz"),
                               ({"gate_chi2": -1.0}, "box_tracker.gate_chi2"),
                               ({"appearance_update": 0.0}, "box_tracker.appearance_update"),
                               ({"recovery_min_iou": 0.0}, "box_tracker.recovery_min_iou"),
                               ({"recovery_min_iou": 1.5}, "box_tracker.recovery_min_iou"),
                               ({"cue_px": [1.0, 2.0, 3.0]}, "box_tracker.cue_px")):
        with pytest.raises(ConfigError, match=field_name.replace(".", r"\.").replace("+", r"\+")):
            BoxTrackerConfig(**kwargs).validate()
    with pytest.raises(ConfigError, match=r"tracker\.min_score"):
        BoxTrackerConfig(min_score=-0.1).validate("tracker")
    BoxTrackerConfig(recovery_min_iou=1.0).validate()  # (0, 1]: an IOU of 1, the same box, is a valid demand


def test_a_cue_outside_the_image_or_nan_is_refused():
    """A cue far from every track never locks the target: NaN always, outside the image where its size is known
    (the LeafSystem's, the scenario's fisheye)."""
    with pytest.raises(ConfigError, match=r"box_tracker\.cue_px must be finite"):
        BoxTrackerConfig(cue_px=[np.nan, 100.0]).validate()
    for cue in ([512.0, 100.0], [100.0, 512.0], [-0.5, 100.0], [1e9, 1e9]):
        with pytest.raises(ConfigError, match=r"box_tracker\.cue_px .* must lie in the 512 x 512 px image"):
            BoxTrackerSystem(BoxTrackerConfig(cue_px=cue), 512, 512)
    BoxTrackerSystem(BoxTrackerConfig(cue_px=[0.0, 511.9]), 512, 512)  # the image's edges are in it
    BoxTrackerConfig(cue_px=[1e9, 1e9]).validate()  # the script tracker knows no image size


# ----------------------------------------------------------------------------------------------
# The LeafSystem


def to_drake_image(rgba: np.ndarray) -> ImageRgba8U:
    image = ImageRgba8U(rgba.shape[1], rgba.shape[0])
    image.mutable_data[:] = rgba
    return image


def test_box_tracker_system_outputs_the_locked_box():
    """The system against the BoxTracker stepped by hand on the same frames: the same target box, the same
    tracks, each with the same colour histogram (read from its color_image input)."""
    config = BoxTrackerConfig(cue_px=CUE)
    system = BoxTrackerSystem(config, WIDTH, HEIGHT)
    sequence = make_sequence(0)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    detections, image = system.GetInputPort("detections"), system.GetInputPort("color_image")
    box_out, valid_out = system.GetOutputPort("target_box"), system.GetOutputPort("target_valid")
    reference = BoxTracker(config)
    for k in range(30):
        t = float(sequence.times[k])
        detections.FixValue(context, sequence.detections[k])
        image.FixValue(context, to_drake_image(sequence.images[k]))
        simulator.AdvanceTo(t)  # outputs at a frame time include that frame
        state = reference.step(sequence.detections[k], sequence.images[k], t)
        box, valid = box_out.Eval(context), valid_out.Eval(context)[0]
        if state.target is None:
            assert valid == 0.0 and np.all(np.isnan(box))
        else:
            assert valid == 1.0
            np.testing.assert_allclose(box, state.target.box)
        tracks = system.GetOutputPort("tracks").Eval(context)
        assert [tr.id for tr in tracks] == [tr.id for tr in state.tracks]
        for ours, theirs in zip(tracks, state.tracks):  # the appearance is read from the color_image input
            np.testing.assert_allclose(ours.histogram, theirs.histogram)
            assert ours.histogram.sum() == pytest.approx(1.0, abs=1e-5)  # L1-normalised, not the imageless zeros
        simulator.AdvanceTo(t + 0.05)  # the update at t stores the frame's step with the inputs of t
    assert valid == 1.0
    np.testing.assert_allclose(box, true_boxes(sequence.times[29], BLUE)[TARGET], atol=3.0)


def test_box_tracker_system_without_image_tracks_boxes():
    system = BoxTrackerSystem(BoxTrackerConfig(min_hits=1))
    context = system.CreateDefaultContext()
    system.GetInputPort("detections").FixValue(context, [Detection(np.array([250.0, 250.0, 10.0, 10.0]))])
    np.testing.assert_allclose(system.GetOutputPort("target_box").Eval(context), [250.0, 250.0, 10.0, 10.0])
    with pytest.raises(ConfigError, match=r"box_tracker\.rate_hz"):
        BoxTrackerSystem(BoxTrackerConfig(rate_hz=-1.0))


def test_a_track_started_without_an_image_takes_its_appearance_when_images_arrive():
    """A track and lock born on a frame without an image have no appearance (all zeros). When images
    arrive the track is matched on its box (colour cost 0 for an unseen appearance), takes the first
    histogram and keeps the lock; it is not gated out, coasted to death and replaced by a new id."""
    box = np.array([100.0, 100.0, 20.0, 20.0])
    image = ground_with(box, RED)
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1))
    assert tracker.step([Detection(box)], None, 0.0).lock.track_id == 0
    for k in range(1, 21):
        state = tracker.step([Detection(box)], image, 0.1 * k)
    assert [t.id for t in state.tracks] == [0]
    assert state.lock.track_id == 0
    np.testing.assert_allclose(state.track(0).histogram, colour_histogram(image, box), atol=1e-6)
    unseen = np.zeros(HISTOGRAM_SIZE, np.float32)
    red, blue = colour_histogram(image, box), colour_histogram(patch([BLUE]), [0, 0, 30, 20])
    np.testing.assert_allclose(colour_cost_matrix(np.array([unseen, red]), np.array([blue, unseen])),
                               [[0.0, 0.0], [1.0, 0.0]], atol=1e-6)


def test_reacquire_measures_from_where_the_target_was_last_seen_not_where_its_track_coasted():
    """A target locked while moving right at 100 px/s vanishes; its track coasts on at that rate for max_misses
    (20) frames and dies over 200 px on. A confirmed track (a box twice the target's, outside its gate) sits
    where the target was last seen: the lock passes to it, though the dead track's coasted box lies farther from
    it than reacquire_radius_px (150 px)."""
    config = BoxTrackerConfig(max_misses=20)
    tracker, dt = BoxTracker(config), 0.1
    for k in range(8):
        state = tracker.step([Detection(np.array([100.0 + 10.0 * k, 100.0, 20.0, 20.0]))], None, dt * k)
    target_id, last_seen = state.target.id, state.target.box.copy()
    stand_in = np.array([last_seen[0] - 10.0, last_seen[1] - 10.0, 40.0, 40.0])  # centred on the last seen box
    k = 8
    while state.track(target_id) is not None:
        coasted = state.track(target_id).box
        state = tracker.step([Detection(stand_in)], None, dt * k)
        k += 1
    assert np.linalg.norm(centre_form(coasted)[:2] - centre_form(stand_in)[:2]) > config.reacquire_radius_px
    assert state.target is not None and state.target.id != target_id
    np.testing.assert_allclose(centre_form(state.target.box)[:2], centre_form(stand_in)[:2], atol=1.0)


@pytest.mark.parametrize("shift_px, pairs", [(7.0, [(0, 0)]), (8.0, [])], ids=["iou-exactly-0.3", "iou-0.24"])
def test_recovery_takes_an_iou_of_exactly_recovery_min_iou(shift_px, pairs):
    """A 13 x 20 px last observed box and a detection 7 px along: 6 of 13 columns shared, IOU 120 / (260 + 260 - 120)
    = 0.3, exactly recovery_min_iou: paired. 8 px along: 100 / 420 = 0.24, not."""
    config = BoxTrackerConfig()
    observed = np.array([100.0, 100.0, 13.0, 20.0])
    track = BoxTrack(0, np.r_[500.0, 500.0, 13.0, 20.0, np.zeros(4)], np.eye(8), observed=observed)
    detection = observed + [shift_px, 0.0, 0.0, 0.0]
    assert recover([track], detection[None], None, None, config) == pairs


def test_recovery_maps_its_pairs_back_to_the_frames_tracks_and_detections():
    """Track 0 at rest on its detection (d0), track 1 whose prediction ran 100 px off its last observed box (outside
    the innovation gate) with a detection there (d1), and d2 10 px along from track 0 (IOU 1/3 with its box). The first
    association gives track 0 d0; recovery, among the tracks and detections it left (track 1; d1, d2), gives
    track 1 d1, its state restarted there; d2 starts track 2. A matched track is not offered to recovery again."""
    config = BoxTrackerConfig(min_hits=1)
    a, b = np.array([100.0, 100.0, 20.0, 20.0]), np.array([200.0, 100.0, 20.0, 20.0])
    x_a, P_a = initial_state(a, config)
    x_b, P_b = initial_state(b + [100.0, 0.0, 0.0, 0.0], config)
    tracks = (BoxTrack(0, x_a, P_a, confirmed=True, observed=a), BoxTrack(1, x_b, P_b, confirmed=True, observed=b))
    d2 = a + [10.0, 0.0, 0.0, 0.0]
    state = step_tracker(TrackerState(0.0, tracks, 2), [Detection(a), Detection(b), Detection(d2)], None, 0.1, config)
    assert [(t.id, t.detection, t.misses) for t in state.tracks] == [(0, 0, 0), (1, 1, 0), (2, 2, 0)]
    np.testing.assert_array_equal(state.track(1).x, initial_state(b, config)[0])
    np.testing.assert_array_equal(state.track(0).observed, a)


@pytest.mark.parametrize("box, partial", [
    ([100.0, 103.0, 16.0, 24.0], True),  # 0.4 of the width, 24 / 30 = exactly PARTIAL_WHOLE_EXTENT of the height
    ([104.0, 100.0, 32.0, 12.0], True),  # 0.4 of the height, 32 / 40 = exactly PARTIAL_WHOLE_EXTENT of the width
    ([100.0, 100.0, 24.0, 30.0], False),  # 24 / 40 = exactly min_size_ratio of the width: not narrower
    ([100.0, 100.0, 40.0, 18.0], False),  # 18 / 30 = exactly min_size_ratio of the height: not shorter
], ids=["narrower-keeping-0.8", "shorter-keeping-0.8", "width-0.6", "height-0.6"])
def test_partial_view_bounds_are_inclusive_of_the_whole_extent_and_exclusive_of_the_size_ratio(box, partial):
    """A still 40 x 30 px confirmed track (its predicted box exactly its last), then a box inside it: a fragment keeping
    exactly 0.8 of one extent and under 0.6 of the other is a partial view (the track coasts); one exactly 0.6 of an
    extent is a whole view, measured (IOU 0.6, within the innovation gate)."""
    tracker = BoxTracker(BoxTrackerConfig(min_hits=1))
    tracker.step([Detection(np.array([100.0, 100.0, 40.0, 30.0]))], None, 0.0)
    state = tracker.step([Detection(np.array(box))], None, 0.1)
    assert [t.id for t in state.tracks] == [0]
    assert (state.track(0).detection, state.track(0).misses) == ((None, 1) if partial else (0, 0))
