"""The UGV detector's scores (diagrams/hybrid_metrics.detection_scores) on constructed boxes, logged as the loop
logs them (DetectionsToTracker's detection_vector); the tracker's identity switches from the lock's log; the
true stereo window depth, and hybrid_metrics' position and altitude errors on a constructed log."""

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from scipy.spatial.transform import Rotation

from diagrams.hybrid_metrics import (
    CLIMBED_FRACTION,
    axis_stats,
    climb_end_index,
    detection_scores,
    hybrid_metrics,
    identity_switches,
    ray_box_entry,
    true_ugv_boxes,
    true_window_depth,
)
from diagrams.hybrid_perception import GROUND_LIFT_M
from diagrams.runner import load_scenario
from diagrams.ugv_detection_scenes import box_surface_points, ugv_bounds_V
from systems.perception.box_tracker import BoxTrack
from systems.perception.hybrid_pad import (
    HYBRID_VECTOR_SIZE,
    DetectionsToTracker,
    LockedTrackVector,
)
from systems.perception.seam import P_BP_W, RELATIVE_STATE_SIZE, V_WP
from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE

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


def test_the_detection_log_keeps_the_best_by_score_whatever_the_order_given():
    """Twelve detections, the UGV's given last but the fourth by score: the log's ten rows are the ten best,
    highest score first, the UGV's the fourth."""
    false_alarms = [([20.0 * k, 400.0, 30.0, 30.0], 0.95 - 0.01 * k) for k in range(11)]
    row = logged([false_alarms + [(TRUE_BOX.tolist(), 0.925)]])[0]
    assert row[0] == 12
    best = [box for box, _ in false_alarms[:3]] + [TRUE_BOX.tolist()] + [box for box, _ in false_alarms[3:9]]
    np.testing.assert_array_equal(row[1:].reshape(10, 5), [[1.0, *box] for box in best])


def test_f1_is_the_harmonic_mean_of_precision_and_recall():
    """Found with a false alarm beside it, missed (a box elsewhere instead), found: 2 true positives, 2 false, 1
    miss; precision 1/2, recall 2/3, F1 2 (1/2)(2/3) / (1/2 + 2/3) = 4/7."""
    elsewhere = [400.0, 300.0, 40.0, 30.0]
    frames = [[(TRUE_BOX.tolist(), 0.9), (elsewhere, 0.5)], [(elsewhere, 0.8)], [(TRUE_BOX.tolist(), 0.9)]]
    scores = detection_scores(logged(frames), [TRUE_BOX] * 3)
    assert (scores["true_positives"], scores["false_positives"], scores["false_negatives"]) == (2, 2, 1)
    assert scores["precision"] == pytest.approx(1 / 2) and scores["recall"] == pytest.approx(2 / 3)
    assert scores["f1"] == pytest.approx(4 / 7)


def test_a_detection_at_exactly_the_match_iou_is_a_true_positive():
    """A box of half the true box's width inside it: IOU 600 / 1200 px^2 = 0.5, seed 003 Table 3's match (IOU >=
    0.5), so a true positive and no miss."""
    scores = detection_scores(logged([[([100.0, 100.0, 20.0, 30.0], 0.9)]]), [TRUE_BOX])
    assert (scores["true_positives"], scores["false_positives"], scores["false_negatives"]) == (1, 0, 0)


@pytest.mark.parametrize("ids, expected", [
    ([-1, 3, 3, -1, 3, 7, 7, -1, -1, 3], (2, 6, 2)),  # 3 -> 7 and 7 -> 3 switches, a gap under one id not
    ([-1, 3, 3], (0, 2, 1)),
    ([0, 0, 1, -1], (1, 3, 2)),  # track ids start at 0: 0 is a lock
])
def test_identity_switches_count_changes_of_the_locked_id_across_frames_without_a_lock(ids, expected):
    """LockedTrackVector's log [id, matched]: id -1 without a lock. expected: (switches, frames locked, tracks)."""
    lock = np.column_stack([ids, np.greater_equal(ids, 0)]).astype(float)  # matched while locked
    assert identity_switches(lock) == dict(zip(("identity_switches", "frames_locked", "tracks_locked"), expected))


@pytest.mark.parametrize("detection, matched", [(None, 0.0), (0, 1.0)])
def test_the_lock_log_says_whether_the_locked_track_was_matched_this_frame(detection, matched):
    """LockedTrackVector: the id of the track whose box is the target's, and 1 when it was matched with a detection
    this frame (that of index 0 too), 0 when it coasts; [-1, 0] for a target box no track has."""
    system = LockedTrackVector()
    context = system.CreateDefaultContext()
    centre_form = [TRUE_BOX[0] + TRUE_BOX[2] / 2, TRUE_BOX[1] + TRUE_BOX[3] / 2, *TRUE_BOX[2:]]
    tracks = [BoxTrack(4, np.r_[400.0, 300.0, 40.0, 30.0, np.zeros(4)], np.eye(8), detection=1),
              BoxTrack(7, np.r_[centre_form, np.zeros(4)], np.eye(8), detection=detection)]
    system.GetInputPort("tracks").FixValue(context, tracks)
    system.GetInputPort("target_box").FixValue(context, TRUE_BOX)
    np.testing.assert_array_equal(system.get_output_port().Eval(context), [7.0, matched])
    system.GetInputPort("target_box").FixValue(context, [10.0, 10.0, 40.0, 30.0])
    np.testing.assert_array_equal(system.get_output_port().Eval(context), [-1.0, 0.0])


def _hover(p_WB, rpy, ugv_yaw, n=1):
    """n frames of the UAV at p_WB with attitude rpy over the UGV at the origin headed ugv_yaw."""

    quadrotor = np.zeros((n, STATE_SIZE))
    quadrotor[:, P_WB], quadrotor[:, Q_WB] = p_WB, RollPitchYaw(*rpy).ToQuaternion().wxyz()
    return quadrotor, np.tile([0.0, 0.0, ugv_yaw, 0.0], (n, 1))


def _ugv_hybrid():
    config = load_scenario("ugv-hybrid")[1]
    return config, ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)[1][2]


def _hybrid_log(quadrotor, vehicle, hybrid, truth=None, **channels) -> dict:
    """hybrid_metrics' log of frames 0.1 s apart: the UAV's and UGV's states, the hybrid vectors, the true relative
    state (zero if None); the pad velocity valid and zero, the stereo and altitude channels valid and reading 1 m (or
    as `channels` give them), no detection, no lock."""
    n = len(quadrotor)
    ones = np.ones((n, 1))
    return {"t": np.arange(n) * 0.1, "hybrid": hybrid,
            "true_relative_state": np.zeros((n, RELATIVE_STATE_SIZE)) if truth is None else truth,
            "quadrotor_state": quadrotor, "vehicle_state": vehicle, "v_valid": ones, "v_WP": np.zeros((n, 3)),
            "detections": np.zeros((n, 6)), "lock": np.tile([-1.0, 0.0], (n, 1)), "stereo_altitude": ones,
            "stereo_valid": ones, "altitude": ones, "altitude_valid": ones, **channels}


def test_the_true_window_depth_follows_the_ugvs_heading_and_ignores_a_box_behind_the_eye():
    """The left eye (X_BL) looking straight down on the UGV's box top: the eye's height minus the box's, the
    same over the box's centre line with the UGV headed 0 or 90 deg (its frame turned); NaN looking up, the box
    then behind the eye and no ground ahead."""
    config, top = _ugv_hybrid()
    eye_height = 3.0 + config.hybrid.stereo.X_BL.translation()[2]
    straight = true_window_depth(*_hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0), config)[0]
    turned = true_window_depth(*_hover([0.0, 0.45, 3.0], (0, 0, 0), np.pi / 2), config)[0]
    assert straight == pytest.approx(eye_height - top) and turned == pytest.approx(eye_height - top)
    assert np.isnan(true_window_depth(*_hover([0.45, 0.0, 3.0], (np.pi, 0, 0), 0.0), config)[0])


def test_the_true_window_depth_along_a_slanted_axis_meets_the_turned_ugvs_box():
    """The UAV pitched 20 deg, its left eye's axis slanting towards the UGV headed 90 deg: the depth is where a fine
    march along that axis first enters the box (tested in the UGV's frame) or the ground, here the box's top."""

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
    low, high = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 0.5])
    for d in ([0.0, 0.0, -1.0], [0.6, -0.8, 0.0], [0.3, 0.4, 0.866]):
        assert ray_box_entry(np.array([0.2, -0.3, 0.25]), np.array(d), low, high) == 0.0


@pytest.mark.parametrize("p, d, low, high, expected", [
    # straight down beside the box: parallel to its x and y slabs, outside x's (x = 5, not in [-1, 1])
    ([5.0, 0.0, 3.0], [0.0, 0.0, -1.0], [-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], np.inf),
    # grazing the edge x = 1, y = 0: in x's slab for s in [1, 2], in y's for s in [0, 1]; they meet at s = 1
    ([2.0, 1.0, 0.5], [-1.0, -1.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 1.0),
])
def test_a_ray_parallel_to_a_slab_outside_it_misses_and_a_grazing_ray_hits(p, d, low, high, expected):
    assert ray_box_entry(*map(np.array, (p, d, low, high))) == expected


def test_the_true_window_depth_is_zero_with_the_eye_inside_the_ugvs_box():
    """The level UAV placed so that its left eye (X_BL) is at the centre of the UGV's box: the box is met at once."""
    config, _ = _ugv_hybrid()
    low, high = ugv_bounds_V(config.platform, config.vehicle.wheelbase_m)
    p_WB = (low + high) / 2 - config.hybrid.stereo.X_BL.translation()
    assert true_window_depth(*_hover(p_WB, (0, 0, 0), 0.0), config)[0] == 0.0


def test_hybrid_metrics_on_a_constructed_log():
    """The estimate off in z alone (0.2 m): no horizontal error; an invalid frame's far-off estimate left out;
    the stereo altitude's bias is its reading minus the true depth (raw 0.1 m over, filtered 0.05 m under)."""
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
    column = np.ones((n, 1)) * depth
    log = _hybrid_log(quadrotor, vehicle, hybrid, truth, stereo_altitude=column + 0.1, altitude=column - 0.05)
    out = hybrid_metrics(log, config, None)
    position = out["hybrid"]["position_m"]
    assert position["samples"] == 3 and position["rmse_horizontal"] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(position["rmse_xyz"], [0.0, 0.0, 0.2], atol=1e-12)
    assert out["hybrid_stereo_altitude"]["raw"]["bias_m"] == pytest.approx(0.1)
    assert out["hybrid_stereo_altitude"]["filtered"]["bias_m"] == pytest.approx(-0.05)


def test_the_valid_fraction_in_view_counts_only_frames_that_see_the_ugv():
    """Two frames 30 m off (the UGV about 85 deg off the fisheye's axis, outside its 150 deg view) with the estimate
    invalid, then two over it with the estimate valid: valid in half the frames, in every frame in view."""
    config, _ = _ugv_hybrid()
    away, over = _hover([30.0, 0.0, 3.0], (0, 0, 0), 0.0, 2), _hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0, 2)
    quadrotor, vehicle = np.vstack([away[0], over[0]]), np.vstack([away[1], over[1]])
    assert [box is None for box in true_ugv_boxes(quadrotor, vehicle, config)] == [True, True, False, False]
    n = 4
    hybrid = np.zeros((n, HYBRID_VECTOR_SIZE))
    hybrid[2:, 0] = hybrid[2:, 4] = 1.0
    out = hybrid_metrics(_hybrid_log(quadrotor, vehicle, hybrid), config, None)["hybrid"]
    assert out["valid_fraction"] == 0.5 and out["valid_fraction_in_view"] == 1.0


def test_the_horizontal_rmse_is_the_rms_of_the_horizontal_distance():
    """Horizontal errors (0.03, 0.04) and (-0.06, 0.08) m, 0.05 and 0.1 m off, a NaN row left out: rmse_horizontal is
    sqrt((0.05^2 + 0.1^2) / 2) m, the RMS of the distance (not of the two axes' errors together)."""
    stats = axis_stats(np.array([[0.03, 0.04, 0.5], [-0.06, 0.08, -0.5], [np.nan, np.nan, np.nan]]))
    assert stats["samples"] == 2
    assert stats["rmse_horizontal"] == pytest.approx(np.sqrt((0.05**2 + 0.1**2) / 2))
    np.testing.assert_allclose(stats["mae_xyz"], [0.045, 0.06, 0.5])


def _pad_frames(n, offsets, z=3.0):
    """n frames of the UAV at (0.45, 0, z) over the UGV headed 0, the pad 2.5 m under it, and hybrid estimates of
    it, valid and measured, off by `offsets` (n, 3) [m]: (quadrotor, vehicle, hybrid, truth)."""
    quadrotor, vehicle = _hover([0.45, 0.0, 0.0], (0, 0, 0), 0.0, n)
    quadrotor[:, P_WB.start + 2] = z
    truth = np.zeros((n, RELATIVE_STATE_SIZE))
    truth[:, P_BP_W] = [0.1, -0.2, -2.5]
    hybrid = np.zeros((n, HYBRID_VECTOR_SIZE))
    hybrid[:, 0] = hybrid[:, 4] = 1.0
    hybrid[:, 1:4] = quadrotor[:, P_WB] + truth[:, P_BP_W] + offsets
    return quadrotor, vehicle, hybrid, truth


def test_a_row_with_any_nan_is_left_out_of_the_axis_stats():
    """[0.1, -0.2, 0.3] and a row NaN in x alone: one sample, the first row's |error| its MAE."""
    stats = axis_stats(np.array([[0.1, -0.2, 0.3], [np.nan, 1.0, 1.0]]))
    assert stats["samples"] == 1
    np.testing.assert_allclose(stats["mae_xyz"], [0.1, 0.2, 0.3])


def test_the_climb_ends_at_the_first_frame_at_exactly_the_climbed_fraction():
    ih = 10.0
    assert climb_end_index([0.0, CLIMBED_FRACTION * ih, ih], ih) == 1


def test_the_error_after_the_climb_counts_the_frame_that_ends_it():
    """Initial height IH: the UAV at 0.4 and 0.8 IH, then at IH from frame 2 (the climb's end, at or above 0.95 IH)
    on; x errors 1 m in the climb, 0.3 and -0.1 m after it: after the climb 2 samples, MAE 0.2 m, RMSE sqrt(0.05)."""
    config, _ = _ugv_hybrid()
    ih = config.landing.initial_height_m
    offsets = np.column_stack([[1.0, 1.0, 0.3, -0.1], np.zeros(4), np.zeros(4)])
    quadrotor, vehicle, hybrid, truth = _pad_frames(4, offsets, np.array([0.4, 0.8, 1.0, 1.0]) * ih)
    out = hybrid_metrics(_hybrid_log(quadrotor, vehicle, hybrid, truth), config, None)["hybrid"]
    after = out["position_m_after_climb"]
    assert after["samples"] == 2
    np.testing.assert_allclose(after["mae_xyz"], [0.2, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(after["rmse_xyz"], [np.sqrt((0.3**2 + 0.1**2) / 2), 0.0, 0.0], atol=1e-12)


def test_the_frames_up_to_the_end_time_are_scored_the_last_included():
    """end_s the third frame's time: frames 0-2 scored (0.1 m off in y), the later ones 50 m off left out."""
    config, _ = _ugv_hybrid()
    offsets = np.array([[0.0, 0.1, 0.0]] * 3 + [[50.0, 50.0, 50.0]] * 2)
    log = _hybrid_log(*_pad_frames(5, offsets))
    out = hybrid_metrics(log, config, end_s=log["t"][2])["hybrid"]
    assert out["frames"] == 3 and out["position_m"]["samples"] == 3
    np.testing.assert_allclose(out["mae_xyz_m"], [0.0, 0.1, 0.0], atol=1e-12)


def test_the_velocity_error_is_the_estimate_minus_the_truth():
    """The pad moving at (1, 0, 0) m/s, its velocity estimated at (1.1, 0, 0) m/s: an error of 0.1 m/s in x."""
    config, _ = _ugv_hybrid()
    quadrotor, vehicle, hybrid, truth = _pad_frames(3, np.zeros(3))
    truth[:, V_WP] = [1.0, 0.0, 0.0]
    log = _hybrid_log(quadrotor, vehicle, hybrid, truth, v_WP=np.tile([1.1, 0.0, 0.0], (3, 1)))
    velocity = hybrid_metrics(log, config, None)["hybrid"]["velocity_mps"]
    assert velocity["samples"] == 3
    np.testing.assert_allclose(velocity["mae_xyz"], [0.1, 0.0, 0.0], atol=1e-12)


def test_a_frame_measured_by_the_box_or_the_stereo_fix_counts_as_measured():
    """The hybrid vector's `measured` (0 no, 1 by the box, 2 by the stereo eye's pad fix) 0, 1, 2, 2: measured in
    3 of 4 frames, by the stereo fix in 2."""
    config, _ = _ugv_hybrid()
    quadrotor, vehicle, hybrid, truth = _pad_frames(4, np.zeros(3))
    hybrid[:, 4] = [0.0, 1.0, 2.0, 2.0]
    out = hybrid_metrics(_hybrid_log(quadrotor, vehicle, hybrid, truth), config, None)["hybrid"]
    assert out["measured_fraction"] == 0.75 and out["stereo_pad_fraction"] == 0.5


def test_the_true_ugv_box_follows_the_ugvs_heading():
    """The UGV headed 0.6 rad, the UAV off its centre and yawed: its box is the enclosing box (pixel-index space,
    +0.5 px) of its surface points placed by SciPy's yaw and seen through Drake's X_WC, projected by OpenCV's fisheye
    model, the whole UGV inside the view and the image."""

    config, _ = _ugv_hybrid()
    fisheye = config.hybrid.fisheye
    p_WV, yaw = np.array([0.5, -0.3, 0.0]), 0.6
    X_WB = RigidTransform(RollPitchYaw(0.05, -0.1, 0.3), [1.5, 1.0, 4.0])
    quadrotor = np.zeros((1, STATE_SIZE))
    quadrotor[0, P_WB], quadrotor[0, Q_WB] = X_WB.translation(), X_WB.rotation().ToQuaternion().wxyz()
    points_W = Rotation.from_rotvec([0.0, 0.0, yaw]).apply(box_surface_points(*ugv_bounds_V(
        config.platform, config.vehicle.wheelbase_m), 9)) + p_WV
    p_C = X_WB.multiply(fisheye.X_BC).inverse().multiply(points_W.T).T
    assert np.all(np.arctan2(np.hypot(p_C[:, 0], p_C[:, 1]), p_C[:, 2]) < fisheye.theta_max)
    uv = cv2.fisheye.projectPoints(p_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), fisheye.K, fisheye.D)[0]
    uv = uv.reshape(-1, 2) + 0.5
    assert np.all((uv > 0) & (uv < [fisheye.width, fisheye.height]))  # not clipped
    box = true_ugv_boxes(quadrotor, np.array([[*p_WV[:2], yaw, 0.0]]), config)[0]
    np.testing.assert_allclose(box, [*uv.min(axis=0), *(uv.max(axis=0) - uv.min(axis=0))], atol=1e-9)


def test_a_frame_without_a_true_depth_is_left_out_of_the_stereo_errors():
    """Three frames over the UGV's box top with the stereo reading 0.1 m over the true depth (the eye's height minus
    the box's), then one looking up (nothing ahead: no true depth) with a valid reading: its error is left out, the
    raw stereo's MAE, RMSE and bias 0.1 m; it still counts in the valid fraction."""
    config, top = _ugv_hybrid()
    over, up = _hover([0.45, 0.0, 3.0], (0, 0, 0), 0.0, 3), _hover([0.45, 0.0, 3.0], (np.pi, 0, 0), 0.0, 1)
    quadrotor, vehicle = np.vstack([over[0], up[0]]), np.vstack([over[1], up[1]])
    assert np.isnan(true_window_depth(quadrotor, vehicle, config)[3])
    depth = 3.0 + config.hybrid.stereo.X_BL.translation()[2] - top
    reading = np.array([[depth + 0.1]] * 3 + [[2.0]])
    log = _hybrid_log(quadrotor, vehicle, np.zeros((4, HYBRID_VECTOR_SIZE)), stereo_altitude=reading)
    raw = hybrid_metrics(log, config, None)["hybrid_stereo_altitude"]["raw"]
    assert raw["valid_fraction"] == 1.0
    assert raw["mae_m"] == pytest.approx(0.1) and raw["rmse_m"] == pytest.approx(0.1)
    assert raw["bias_m"] == pytest.approx(0.1)
