"""The UGV detector's scores (diagrams/hybrid_metrics.detection_scores) on constructed boxes, logged as the loop
logs them (DetectionsToTracker's detection_vector); the tracker's identity switches from the lock's log."""

import numpy as np
import pytest

from diagrams.hybrid_metrics import detection_scores, identity_switches
from systems.perception.hybrid_pad import DetectionsToTracker

TRUE_BOX = np.array([100.0, 100.0, 40.0, 30.0])  # [x, y, w, h] px


def logged(frames: list[list[tuple[list[float], float]]]) -> np.ndarray:
    """The loop's log rows of each frame's (box, score) detections."""
    system = DetectionsToTracker()
    context = system.CreateDefaultContext()
    rows = []
    for detections in frames:
        system.get_input_port().FixValue(context, [(np.array(box), score) for box, score in detections])
        rows.append(system.GetOutputPort("detection_vector").Eval(context).copy())
    return np.array(rows)


@pytest.mark.parametrize("found, expected", [([400.0, 300.0, 40.0, 30.0], 0.0), (TRUE_BOX.tolist(), 1.0)])
def test_f1_is_zero_when_no_box_matches_and_one_when_every_box_does(found, expected):
    scores = detection_scores(logged([[(found, 0.9)]] * 20), [TRUE_BOX] * 20)
    assert scores["precision"] == scores["recall"] == scores["f1"] == expected


def test_every_detection_counts_however_many_a_frame_has():
    """Twelve detections in a frame, the UGV's the fourth by score; then a frame without the UGV in view and
    two false alarms (before: the best three logged and scored, precision 1/3, and the UGV a miss)."""
    false_alarms = [([20.0 * k, 400.0, 30.0, 30.0], 0.95 - 0.01 * k) for k in range(11)]
    frames = [false_alarms[:3] + [(TRUE_BOX.tolist(), 0.925)] + false_alarms[3:], false_alarms[:2]]
    scores = detection_scores(logged(frames), [TRUE_BOX, None])
    assert (scores["true_positives"], scores["false_positives"], scores["false_negatives"]) == (1, 13, 0)
    assert scores["precision"] == pytest.approx(1 / 14) and scores["recall"] == 1.0
    assert scores["f1"] == pytest.approx(2 / 15)  # 2 P R / (P + R) = (2 / 14) / (15 / 14)


def test_f1_is_the_harmonic_mean_of_precision_and_recall():
    """Found with a false alarm beside it, missed (a box elsewhere instead), found: 2 true positives, 2 false, 1
    miss; precision 1/2, recall 2/3, F1 2 (1/2)(2/3) / (1/2 + 2/3) = 4/7."""
    elsewhere = [400.0, 300.0, 40.0, 30.0]
    frames = [[(TRUE_BOX.tolist(), 0.9), (elsewhere, 0.5)], [(elsewhere, 0.8)], [(TRUE_BOX.tolist(), 0.9)]]
    scores = detection_scores(logged(frames), [TRUE_BOX] * 3)
    assert (scores["true_positives"], scores["false_positives"], scores["false_negatives"]) == (2, 2, 1)
    assert scores["precision"] == pytest.approx(1 / 2) and scores["recall"] == pytest.approx(2 / 3)
    assert scores["f1"] == pytest.approx(4 / 7)


def test_identity_switches_count_changes_of_the_locked_id_across_frames_without_a_lock():
    """LockedTrackVector's log: id -1 without a lock. 3 -> 7 and 7 -> 3 are switches, a gap under one id is not."""
    ids = [-1, 3, 3, -1, 3, 7, 7, -1, -1, 3]
    lock = np.column_stack([ids, np.zeros(len(ids))]).astype(float)
    assert identity_switches(lock) == {"identity_switches": 2, "frames_locked": 6, "tracks_locked": 2}
    assert identity_switches(lock[:3]) == {"identity_switches": 0, "frames_locked": 2, "tracks_locked": 1}
