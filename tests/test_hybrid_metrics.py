"""The UGV detector's scores (diagrams/hybrid_metrics.detection_scores) on constructed boxes, logged as the loop
logs them (DetectionsToTracker's detection_vector); the tracker's identity switches from the lock's log; the
true stereo window depth, and hybrid_metrics' position and altitude errors on a constructed log."""

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


def _hover(p_WB, rpy, ugv_yaw, n=1):
    """n frames of the UAV at p_WB with attitude rpy over the UGV at the origin headed ugv_yaw."""
    from pydrake.math import RollPitchYaw

    from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE
    quadrotor = np.zeros((n, STATE_SIZE))
    quadrotor[:, P_WB], quadrotor[:, Q_WB] = p_WB, RollPitchYaw(*rpy).ToQuaternion().wxyz()
    return quadrotor, np.tile([0.0, 0.0, ugv_yaw, 0.0], (n, 1))


def _ugv_hybrid():
    from diagrams.runner import load_scenario
    from diagrams.ugv_detection_scenes import ugv_bounds_V
    config = load_scenario("ugv-hybrid")[1]
    return config, ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)[1][2]


def test_the_true_window_depth_follows_the_ugvs_heading_and_ignores_a_box_behind_the_eye():
    """The left eye (X_BL) looking straight down on the UGV's box top: the eye's height minus the box's, the
    same over the box's centre line with the UGV headed 0 or 90 deg (its frame turned); NaN looking up, the box
    then behind the eye and no ground ahead."""
    from diagrams.hybrid_metrics import true_window_depth
    config, top = _ugv_hybrid()
    eye_height = 3.0 + config.hybrid.stereo.X_BL.translation()[2]
    straight = true_window_depth(*_hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0), config)[0]
    turned = true_window_depth(*_hover([0.0, 0.45, 3.0], (0, 0, 0), np.pi / 2), config)[0]
    assert straight == pytest.approx(eye_height - top) and turned == pytest.approx(eye_height - top)
    assert np.isnan(true_window_depth(*_hover([0.45, 0.0, 3.0], (np.pi, 0, 0), 0.0), config)[0])


def test_the_true_window_depth_along_a_slanted_axis_meets_the_turned_ugvs_box():
    """The UAV pitched 20 deg, its left eye's axis slanting towards the UGV headed 90 deg: the depth is where a fine
    march along that axis first enters the box (tested in the UGV's frame) or the ground, here the box's top."""
    from pydrake.math import RigidTransform, RollPitchYaw

    from diagrams.hybrid_metrics import true_window_depth
    from diagrams.hybrid_perception import GROUND_LIFT_M
    from diagrams.ugv_detection_scenes import ugv_bounds_V
    config, top = _ugv_hybrid()
    low, high = ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)
    p_WB, rpy, yaw = [1.0, 0.45, 3.0], (0.0, np.radians(20.0), 0.0), np.pi / 2
    X_WL = RigidTransform(RollPitchYaw(*rpy), p_WB).multiply(config.hybrid.stereo.X_BL)
    s = np.arange(0.0, 10.0, 1e-4)
    p_W = X_WL.translation() + np.outer(s, X_WL.rotation().col(2))
    R_VW = np.array([[np.cos(yaw), np.sin(yaw), 0.0], [-np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    p_V = p_W @ R_VW.T  # the UGV at the World's origin
    hit = np.all((p_V >= low) & (p_V <= high), axis=1) | (p_W[:, 2] <= GROUND_LIFT_M)
    expected = s[np.argmax(hit)]
    assert p_W[np.argmax(hit), 2] == pytest.approx(top, abs=1e-3)  # on the box's top, not the ground
    assert true_window_depth(*_hover(p_WB, rpy, yaw), config)[0] == pytest.approx(expected, abs=2e-4)


def test_a_ray_from_inside_the_box_enters_it_at_once():
    """ray_box_entry from a point inside the box is 0, whichever way the ray goes."""
    from diagrams.hybrid_metrics import ray_box_entry
    low, high = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 0.5])
    for d in ([0.0, 0.0, -1.0], [0.6, -0.8, 0.0], [0.3, 0.4, 0.866]):
        assert ray_box_entry(np.array([0.2, -0.3, 0.25]), np.array(d), low, high) == 0.0


def test_hybrid_metrics_on_a_constructed_log():
    """The estimate off in z alone (0.2 m): no horizontal error; an invalid frame's far-off estimate left out;
    the stereo altitude's bias is its reading minus the true depth (raw 0.1 m over, filtered 0.05 m under)."""
    from diagrams.hybrid_metrics import hybrid_metrics
    from systems.perception.hybrid_pad import HYBRID_VECTOR_SIZE
    from systems.perception.seam import P_BP_W, RELATIVE_STATE_SIZE
    from systems.vehicles.quadrotor import P_WB
    config, top = _ugv_hybrid()
    n = 4
    quadrotor, vehicle = _hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0, n)
    truth = np.zeros((n, RELATIVE_STATE_SIZE))
    truth[:, P_BP_W] = [0.1, -0.2, -2.5]
    hybrid = np.zeros((n, HYBRID_VECTOR_SIZE))
    hybrid[:, 0] = hybrid[:, 4] = 1.0
    hybrid[:, 1:4] = quadrotor[:, P_WB] + truth[:, P_BP_W] + [0.0, 0.0, 0.2]
    hybrid[-1, 0], hybrid[-1, 1:4] = 0.0, 50.0  # invalid: not scored
    depth = 3.0 + config.hybrid.stereo.X_BL.translation()[2] - top
    ones, column = np.ones((n, 1)), np.ones((n, 1)) * depth
    log = {"t": np.arange(n) * 0.1, "hybrid": hybrid, "true_relative_state": truth, "quadrotor_state": quadrotor,
           "vehicle_state": vehicle, "v_valid": ones, "v_WP": np.zeros((n, 3)), "detections": np.zeros((n, 6)),
           "lock": np.tile([-1.0, 0.0], (n, 1)), "stereo_altitude": column + 0.1, "stereo_valid": ones,
           "altitude": column - 0.05, "altitude_valid": ones}
    out = hybrid_metrics(log, config, None)
    position = out["hybrid"]["position_m"]
    assert position["samples"] == 3 and position["rmse_horizontal"] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(position["rmse_xyz"], [0.0, 0.0, 0.2], atol=1e-12)
    assert out["hybrid_stereo_altitude"]["raw"]["bias_m"] == pytest.approx(0.1)
    assert out["hybrid_stereo_altitude"]["filtered"]["bias_m"] == pytest.approx(-0.05)


def test_the_valid_fraction_in_view_counts_only_frames_that_see_the_ugv():
    """Two frames 30 m off (the UGV about 85 deg off the fisheye's axis, outside its 150 deg view) with the estimate
    invalid, then two over it with the estimate valid: valid in half the frames, in every frame in view."""
    from diagrams.hybrid_metrics import hybrid_metrics, true_ugv_boxes
    from systems.perception.hybrid_pad import HYBRID_VECTOR_SIZE
    from systems.perception.seam import RELATIVE_STATE_SIZE
    config, _ = _ugv_hybrid()
    away, over = _hover([30.0, 0.0, 3.0], (0, 0, 0), 0.0, 2), _hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0, 2)
    quadrotor, vehicle = np.vstack([away[0], over[0]]), np.vstack([away[1], over[1]])
    assert [box is None for box in true_ugv_boxes(quadrotor, vehicle, config)] == [True, True, False, False]
    n = 4
    hybrid = np.zeros((n, HYBRID_VECTOR_SIZE))
    hybrid[2:, 0] = hybrid[2:, 4] = 1.0
    ones = np.ones((n, 1))
    log = {"t": np.arange(n) * 0.1, "hybrid": hybrid, "true_relative_state": np.zeros((n, RELATIVE_STATE_SIZE)),
           "quadrotor_state": quadrotor, "vehicle_state": vehicle, "v_valid": ones, "v_WP": np.zeros((n, 3)),
           "detections": np.zeros((n, 6)), "lock": np.tile([-1.0, 0.0], (n, 1)), "stereo_altitude": ones,
           "stereo_valid": ones, "altitude": ones, "altitude_valid": ones}
    out = hybrid_metrics(log, config, None)["hybrid"]
    assert out["valid_fraction"] == 0.5 and out["valid_fraction_in_view"] == 1.0
