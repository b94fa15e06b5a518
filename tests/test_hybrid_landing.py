"""perception.source hybrid (seed 003's fisheye + stereo array in the loop) and the ugv-hybrid scenario:
the pad from a box's ray (analytic), the estimator's validity and coasting, the scenario's loading and
errors, and short rendered flights (marked slow): the estimate against the truth, and invalid out of view."""

import math
import re

import cv2
import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder

from diagrams import hybrid_perception
from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly, summary_lines
from diagrams.hybrid_metrics import climb_end_index, true_ugv_boxes, true_window_depth
from diagrams.hybrid_perception import GROUND_LIFT_M, HybridPerceptionConfig
from diagrams.runner import load_scenario
from diagrams.stereo_hover import add_textured_ground, ground_tiles
from systems.config import ConfigError
from systems.estimators.velocity_observer import VelocityObserverConfig
from systems.perception.box_tracker import iou
from systems.perception.hybrid_pad import (
    HybridPadConfig,
    HybridPadEstimator,
    HybridPadState,
    camera_height,
    hybrid_step,
    hybrid_vector,
    pad_from_box,
)
from systems.perception.seam import P_BP_W, VALID, SeamConfig, estimate_is_valid
from systems.perception.stereo_depth import StereoAltimeter
from systems.sensors.camera import add_renderer
from systems.sensors.fisheye import FisheyeConfig, project_points
from systems.sensors.stereo import add_stereo_pair
from systems.vehicles.airframe import AirframeGeometry
from systems.vehicles.quadrotor import P_WB, Q_WB
from tests.conftest import wiring

FISHEYE = FisheyeConfig()
Z_PAD = 0.5


def box_around(p_W: np.ndarray, X_WB: RigidTransform, half_px: float = 20.0) -> np.ndarray:
    """A box [x, y, w, h] (pixel-index space) centred on the fisheye pixel of p_W."""
    X_WC = X_WB.multiply(FISHEYE.X_BC)
    uv = project_points(X_WC.inverse().multiply(p_W).reshape(1, 3), FISHEYE)[0]
    return np.array([uv[0] + 0.5 - half_px, uv[1] + 0.5 - half_px, 2 * half_px, 2 * half_px])


@pytest.mark.parametrize("rpy_deg, p_WP", [((0, 0, 0), (1.0, -2.0, Z_PAD)), ((8, -5, 40), (3.0, 1.5, Z_PAD)),
                                           ((0, 10, -120), (-4.0, 2.0, Z_PAD))])
def test_pad_from_box_recovers_the_point(rpy_deg, p_WP):
    """The ray of the box's centre, rotated with the attitude and cut at the pad's plane with the true
    camera height, lands on the point the box was drawn around (to the undistortion's precision)."""
    X_WB = RigidTransform(RollPitchYaw(np.radians(rpy_deg)), [0.3, -0.2, 7.5])
    h = X_WB.multiply(FISHEYE.X_BC).translation()[2]
    p = pad_from_box(box_around(np.array(p_WP), X_WB), h, X_WB, FISHEYE, Z_PAD)
    assert p is not None
    assert np.allclose(p, p_WP, atol=1e-6)


def test_pad_from_box_rejects_oblique_and_outside():
    X_WB = RigidTransform([0.0, 0.0, 2.0])
    h = X_WB.multiply(FISHEYE.X_BC).translation()[2]
    # 70 deg from the vertical: inside the 150 deg fisheye but beyond min_ray_down's 60 deg.
    far = np.array([(h - Z_PAD) * math.tan(math.radians(70)), 0.0, Z_PAD])
    assert pad_from_box(box_around(far, X_WB), h, X_WB, FISHEYE, Z_PAD) is None
    assert pad_from_box(np.array([600.0, 600.0, 10.0, 10.0]), h, X_WB, FISHEYE, Z_PAD) is None  # outside the circle
    # 3 px outside the field of view's circle, inside the image, on the diagonal: the ray undistortion gives that
    # pixel (about 76 deg off the axis) still points down by more than a min_ray_down of 0.2, but it is out of view
    d = (FISHEYE.radius_px + 3.0) / math.sqrt(2)
    uv = np.array([FISHEYE.cx + d, FISHEYE.cy + d])
    assert np.all(uv < [FISHEYE.width, FISHEYE.height])
    ray = cv2.fisheye.undistortPoints(uv.reshape(1, 1, 2), FISHEYE.K, FISHEYE.D).reshape(2)
    assert 0.2 < 1 / math.hypot(*ray, 1.0) < math.cos(FISHEYE.theta_max)  # -r_W,z: the camera looks straight down
    box = np.array([uv[0] + 0.5 - 10.0, uv[1] + 0.5 - 10.0, 20.0, 20.0])
    assert pad_from_box(box, h, X_WB, FISHEYE, Z_PAD, min_ray_down=0.2) is None
    assert pad_from_box(box_around(np.zeros(3) + [0, 0, Z_PAD], X_WB), 0.3, X_WB, FISHEYE, Z_PAD) is None  # below


def _run(steps, config: HybridPadConfig | None = None, height_m=7.5):
    """hybrid_step over (time, seen, altitude valid, p_WP) frames at 10 Hz; the UAV over the origin at height_m
    (m, or a function of the time), the stereo altitude true."""
    config = config or HybridPadConfig()
    state, out = HybridPadState(), []
    for t, seen, alt_ok, p in steps:
        X_WB = RigidTransform([0.0, 0.0, height_m(t) if callable(height_m) else height_m])
        h = X_WB.multiply(FISHEYE.X_BC).translation()[2]
        box = box_around(np.array(p), X_WB) if seen else np.full(4, np.nan)
        state = hybrid_step(state, t, box, seen, h if alt_ok else math.nan, alt_ok, X_WB, FISHEYE, Z_PAD, config,
                            VelocityObserverConfig())
        out.append(state)
    return out


def test_estimator_valid_coasts_then_invalid():
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)]
    blind = [(0.1 * k, False, True, None) for k in range(10, 60)]
    states = _run(seen + blind, HybridPadConfig(max_coast_s=2.0, approach_max_coast_s=2.0))
    assert not states[0].estimate.valid or states[0].measured
    assert all(s.estimate.valid and s.measured for s in states[3:10])
    # Coasting at the observed velocity for max_coast_s, then invalid (never NaN as valid).
    coast = states[14]
    assert coast.estimate.valid and not coast.measured
    assert np.allclose(coast.estimate.X_RT.translation()[:2], [0.5 * 1.4, 0.0], atol=0.02)
    assert not states[31].estimate.valid
    for s in states:
        assert not s.estimate.valid or np.all(np.isfinite(s.estimate.X_RT.translation()))


def test_a_velocity_from_before_a_loss_is_not_coasted_on():
    """In the landing zone (2 m up): the target seen moving at 1.5 m/s for 1 s, lost for 5 s (invalid), seen once
    standing at x = 0.5 m, then unseen: that one frame is valid, and the frames after it are invalid, not coasted
    at the 1.5 m/s seen before the loss (for up to max_coast_s, 2 s: 3 m off the standing target)."""
    v = np.array([1.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(11)]
    lost = [(0.1 * k, False, True, None) for k in range(11, 61)]
    again = [(6.1, True, True, np.array([0.5, 0.0, Z_PAD]))] + [(0.1 * k, False, True, None) for k in range(62, 80)]
    states = _run(seen + lost + again, HybridPadConfig(max_coast_s=2.0), height_m=2.0)
    assert states[10].estimate.valid and not states[60].estimate.valid
    found = states[61]
    assert found.estimate.valid and found.measured
    assert np.allclose(found.estimate.X_RT.translation()[:2], [0.5, 0.0], atol=0.05)
    assert not any(s.estimate.valid for s in states[62:])


def test_sightings_with_lost_frames_between_still_build_the_approachs_velocity():
    """Above the landing zone (7.5 m up), the target moving at 1.5 m/s seen every third frame, the frames between
    invalid (no velocity yet to coast on): the observer's window joins the sightings across those frames into a
    velocity, so the estimate comes to coast between them. (An observer started afresh at each invalid frame never
    became valid here, and lost the UGV in 12 of ugv-hybrid's 16 flights at 1.5 m/s: benchmarks/hybrid.py, measured
    2026-12-06; so a target found again within window_s is coasted at the velocity its sightings give across the
    loss, docs/architecture.md.)"""
    v = np.array([1.5, 0.0, 0.0])
    steps = [(0.1 * k, k % 3 == 0, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k if k % 3 == 0 else None)
             for k in range(31)]
    states = _run(steps, HybridPadConfig())
    assert not states[1].estimate.valid  # lost between the first sightings: nothing to coast at yet
    assert states[30].observer.valid
    assert np.allclose(states[30].observer.estimate[:2], v[:2], atol=0.1)
    coasting = [s for s in states[20:] if s.estimate.valid and not s.measured]
    assert coasting, "no frame between sightings coasted"


@pytest.mark.parametrize("growth_m_s, refused_from_s", [(0.1, None), (0.2, 3.1)])
def test_the_seam_refuses_a_coast_by_its_std_only_past_its_growth(growth_m_s, refused_from_s):
    """In the landing zone, a coast of max_coast_s (4 s) after a measured 0.1 m: with the default growth, 0.1 m/s,
    the seam's max_position_std_m (1 m, sqrt(trace)) refuses none of it (0.71 m at 4 s); with 0.2 m/s, from 3.1 s
    on (HybridPadConfig's comment)."""
    v = np.array([0.3, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(11)]
    blind = [(0.1 * k, False, True, None) for k in range(11, 60)]
    states = _run(seen + blind, HybridPadConfig(coast_std_growth_m_s=growth_m_s), height_m=2.0)
    coasting = [s for s in states[11:] if s.estimate.valid]
    assert round(coasting[-1].time - 1.0, 6) == HybridPadConfig().max_coast_s
    refused = [round(s.time - 1.0, 6) for s in coasting if not estimate_is_valid(s.estimate, s.time, SeamConfig())]
    assert refused == ([] if refused_from_s is None else
                       [round(0.1 * k, 6) for k in range(round(refused_from_s * 10), 41)])
    if refused_from_s is None:
        assert math.sqrt(np.trace(coasting[-1].estimate.covariance[3:, 3:])) == pytest.approx(0.71, abs=0.01)


def test_the_landing_zone_ends_where_the_camera_climbs_out_of_it():
    """Taking off: the UGV measured below the UAV 1.8 m up (in the landing zone) for 1 s at 0.5 m/s, then, with the
    UAV at 6 m, seen 2.5 m off the coast's prediction (it turned): a measurement, as above the zone (before: the
    zone's rules stayed while the estimate was valid, and its gate refused every ray up to IH for a 4 s coast, 2.9 m
    off, in ugv-hybrid's circle at 0.2 m/s)."""
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(11)]
    turned = np.array([-1.0, 1.5, Z_PAD])
    climbed = [(0.1 * k, True, True, turned) for k in range(11, 14)]
    states = _run(seen + climbed, height_m=lambda t: 1.8 if t < 1.05 else 6.0)
    assert states[10].estimate.valid and states[10].measured
    for state in states[11:]:
        assert state.measured and state.gated == 0
        assert np.allclose(state.estimate.X_RT.translation(), turned, atol=0.02)


@pytest.mark.parametrize("height_m, approach_coast_s, valid_after_s", [(7.5, 0.3, 0.3), (7.5, 2.0, 1.3), (2.0, 0.3, 2.0)])
def test_coast_above_the_landing_zone_is_short(height_m, approach_coast_s, valid_after_s):
    """Above the landing zone the estimate coasts at most approach_max_coast_s (and only while the observer is
    valid: 1.3 s here, while the third-last sample, 0.2 s before the last, is in its 1.5 s window); in the
    landing zone, max_coast_s."""
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)]
    blind = [(0.1 * k, False, True, None) for k in range(10, 40)]
    states = _run(seen + blind, HybridPadConfig(max_coast_s=2.0, approach_max_coast_s=approach_coast_s), height_m)
    valid = [round(s.time - 0.9, 6) for s in states[10:] if s.estimate.valid]
    assert valid and max(valid) == pytest.approx(valid_after_s)


@pytest.mark.parametrize("over_pad_m, measures", [(1.2, True), (1.0, True), (0.8, False)])
def test_box_does_not_measure_close_over_the_pad(over_pad_m, measures):
    """Below box_min_height_m (1 m) of camera height over the pad's plane the fisheye's box is not a measurement;
    at exactly 1 m it is."""
    assert HybridPadConfig().box_min_height_m == 1.0
    height_m = Z_PAD + over_pad_m - FISHEYE.X_BC.translation()[2]
    assert RigidTransform([0.0, 0.0, height_m]).multiply(FISHEYE.X_BC).translation()[2] - Z_PAD == over_pad_m  # exactly
    p = np.array([0.05, 0.0, Z_PAD])
    states = _run([(0.1 * k, True, True, p) for k in range(3)], height_m=height_m)
    assert states[-1].estimate.valid == measures
    assert states[-1].measured == measures


@pytest.mark.parametrize("height_m, measures", [(7.5, True), (2.0, False)])
def test_oblique_ray_measures_only_above_the_landing_zone(height_m, measures):
    """A UGV 70 deg off the vertical: followed from IH (approach_min_ray_down's 78 deg) with its std grown by
    1 / cos 70 deg, but not measured within landing_zone_m over the pad (min_ray_down's 60 deg)."""
    h = RigidTransform([0.0, 0.0, height_m]).multiply(FISHEYE.X_BC).translation()[2]
    p = np.array([(h - Z_PAD) * math.tan(math.radians(70)), 0.0, Z_PAD])
    state = _run([(0.1 * k, True, True, p) for k in range(3)], height_m=height_m)[-1]
    assert state.estimate.valid == measures
    if measures:
        assert np.allclose(state.estimate.X_RT.translation(), p, atol=1e-6)
        config = HybridPadConfig()
        variances = np.diag(state.estimate.covariance)[3:]  # [roll, pitch, yaw; x, y, z]
        std = config.position_std_m / math.cos(math.radians(70))
        assert variances == pytest.approx([std**2, std**2, config.height_std_m**2], rel=1e-5)


@pytest.mark.parametrize("over_pad_m, measures", [(1.8, False), (2.1, True)])
def test_the_landing_zone_is_counted_from_the_pads_plane(over_pad_m, measures):
    """landing_zone_m (2 m) is the camera's height over the pad's plane (0.5 m up), not over the ground: a UGV 70 deg
    off the vertical is not measured from 1.8 m over the pad (2.3 m over the ground), and is from 2.1 m."""
    height_m = Z_PAD + over_pad_m - FISHEYE.X_BC.translation()[2]
    p = np.array([over_pad_m * math.tan(math.radians(70)), 0.0, Z_PAD])
    state = _run([(0.1 * k, True, True, p) for k in range(3)], height_m=height_m)[-1]
    assert state.estimate.valid == measures and state.measured == measures


def test_the_landing_zone_is_judged_by_the_navigations_height_not_the_stereos():
    """1.5 m over the pad by the navigation, in the landing zone, while the stereo height spikes to 5 m (valid): a
    UGV 70 deg off the vertical is beyond the landing zone's min_ray_down (60 deg) and not measured, though the
    spike puts the camera 4.5 m over the pad, above the zone."""
    X_WB = RigidTransform([0.0, 0.0, Z_PAD + 1.5 - FISHEYE.X_BC.translation()[2]])
    over_pad_m = X_WB.multiply(FISHEYE.X_BC).translation()[2] - Z_PAD
    config = HybridPadConfig()
    assert over_pad_m == pytest.approx(1.5) and config.box_min_height_m < 1.5 < config.landing_zone_m < 5.0 - Z_PAD
    assert config.approach_min_ray_down < math.cos(math.radians(70)) < config.min_ray_down
    p = np.array([over_pad_m * math.tan(math.radians(70)), 0.0, Z_PAD])
    state = hybrid_step(HybridPadState(), 0.0, box_around(p, X_WB), True, 5.0, True, X_WB, FISHEYE, Z_PAD, config,
                        VelocityObserverConfig())
    assert state.height_source == 1 and state.height_m == 5.0
    assert not state.estimate.valid and not state.measured


def test_the_box_floor_is_judged_by_the_navigations_height_not_the_stereos():
    """1.2 m over the pad by the navigation, above box_min_height_m (1 m), while the stereo window sees the UGV's roof
    (at the pad's plane) and its height reads z_P low, 0.7 m over the pad: the box still measures, its ray cut at
    the stereo's 0.7 m below the camera."""
    X_WB = RigidTransform([0.0, 0.0, Z_PAD + 1.2 - FISHEYE.X_BC.translation()[2]])
    p_WC = X_WB.multiply(FISHEYE.X_BC).translation()
    h = p_WC[2] - Z_PAD  # the camera's height over the roof
    config = HybridPadConfig()
    assert p_WC[2] - Z_PAD == pytest.approx(1.2) and h - Z_PAD < config.box_min_height_m < p_WC[2] - Z_PAD
    p = np.array([0.05, 0.0, Z_PAD])
    state = hybrid_step(HybridPadState(), 0.0, box_around(p, X_WB), True, h, True, X_WB, FISHEYE, Z_PAD, config,
                        VelocityObserverConfig())
    assert state.height_source == 1 and state.height_m == h
    assert state.estimate.valid and state.measured and not state.fixed
    xy = p_WC[:2] + (h - Z_PAD) / (p_WC[2] - Z_PAD) * (p - p_WC)[:2]  # the ray to p, 0.7 m down instead of 1.2 m
    assert np.allclose(state.estimate.X_RT.translation(), [*xy, Z_PAD], atol=1e-6)


def test_carried_altitude_follows_the_navigations_descent():
    """The stereo altitude valid at 6 m, then invalid while the UAV descends to 4 m: the camera's height is carried
    on from the last valid one by the navigation's change in height (source 2), so it stays the true height and an
    off-axis box still lands on its point (the last valid height kept would put it 1.6 times too far out at 4 m)."""
    p = np.array([1.0, 0.5, Z_PAD])
    steps = [(0.1 * k, True, k < 5, p) for k in range(15)]
    states = _run(steps, height_m=lambda t: 6.0 if t < 0.45 else 6.0 - 2.0 * (t - 0.4))
    for k, state in enumerate(states[5:], start=5):
        true_h = RigidTransform([0.0, 0.0, 6.0 - 2.0 * (0.1 * k - 0.4)]).multiply(FISHEYE.X_BC).translation()[2]
        assert state.height_source == 2 and state.height_m == pytest.approx(true_h, abs=1e-9)
        assert state.estimate.valid and state.measured
        assert np.allclose(state.estimate.X_RT.translation(), p, atol=1e-6)


def test_the_carried_height_expires_altitude_coast_s_after_the_last_valid_stereo_height():
    """One valid stereo height, then none at 30 Hz: the height is carried (source 2) for altitude_coast_s after
    that valid one, counted from it and not from the frame before, then there is none (source 0, NaN)."""
    coast_s = 0.5
    states = _run([(k / 30, False, k == 0, None) for k in range(25)], HybridPadConfig(altitude_coast_s=coast_s))
    assert states[0].height_source == 1
    for k, state in enumerate(states[1:], start=1):
        if k / 30 <= coast_s:
            assert state.height_source == 2 and math.isfinite(state.height_m)
        else:
            assert state.height_source == 0 and math.isnan(state.height_m)
    assert states[15].height_source == 2 and states[16].height_source == 0  # 0.5 s exactly, then past it


@pytest.mark.parametrize("camera_height_m, altitude_valid", [(-0.3, True), (0.0, True), (3.95, False)])
def test_a_stereo_height_not_above_the_ground_or_not_valid_is_not_a_height(camera_height_m, altitude_valid):
    """A stereo height at or below zero, flagged valid, or the true one (3.95 m: the camera 5 cm below the body)
    flagged not valid, is no camera height: none is used (source 0, NaN) and the estimate of a box in view is not
    valid."""
    X_WB = RigidTransform([0.0, 0.0, 4.0])
    box = box_around(np.array([0.0, 0.0, Z_PAD]), X_WB)
    state = hybrid_step(HybridPadState(), 0.0, box, True, camera_height_m, altitude_valid, X_WB, FISHEYE, Z_PAD,
                        HybridPadConfig(), VelocityObserverConfig())
    assert state.height_source == 0 and math.isnan(state.height_m) and state.anchor is None
    assert not state.estimate.valid


def test_estimator_without_altitude_is_invalid():
    states = _run([(0.1 * k, True, False, (0.0, 0.0, Z_PAD)) for k in range(5)])
    assert not any(s.estimate.valid for s in states)


@pytest.mark.parametrize("rpy_deg, mount_z_m", [((0, 0, 0), -0.05), ((20, 0, 30), -0.05), ((0, -20, -100), -0.05),
                                               ((12, 15, 200), -0.20)])
def test_camera_height_puts_the_left_eyes_depth_vertical(rpy_deg, mount_z_m):
    """The depth along the tilted left eye's axis to the level ground (true_window_depth) gives the fisheye's
    height above that ground, whatever the tilt and wherever the pair is mounted."""
    _, scenario = load_scenario("ugv-hybrid", overrides=[f"hybrid.stereo.mount_xyz_m=[-0.06, 0.0, {mount_z_m}]"])
    p_WB, rpy = [20.0, -30.0, 5.0], np.radians(rpy_deg)  # far from the UGV: the eye sees the ground
    quad, vehicle = _state_rows(p_WB, rpy)
    depth = true_window_depth(quad, vehicle, scenario)[0]
    X_WB = RigidTransform(RollPitchYaw(*rpy), p_WB)
    fisheye = scenario.hybrid.fisheye
    h = camera_height(depth, X_WB, scenario.hybrid.stereo.X_BL, fisheye.X_BC)
    assert h == pytest.approx(X_WB.multiply(fisheye.X_BC).translation()[2] - GROUND_LIFT_M, abs=1e-9)


def test_camera_height_is_nan_when_the_eye_looks_up():
    X_WB = RigidTransform(RollPitchYaw(math.pi, 0.0, 0.0), [0.0, 0.0, 5.0])
    assert math.isnan(camera_height(3.0, X_WB, HybridPerceptionConfig().stereo.X_BL, FISHEYE.X_BC))


def test_camera_height_is_nan_when_the_eye_looks_exactly_level():
    """A left eye whose axis is exactly horizontal (90 deg about x, exact: R_WL's z row has a 0 there) does not look
    down, so it gives no height (the offsets alone would say 5.1 - 4.95 = 0.15 m)."""
    X_WB = RigidTransform([0.0, 0.0, 5.0])
    X_BL = RigidTransform(RotationMatrix(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])), [0, 0, -0.05])
    assert X_WB.multiply(X_BL).rotation().matrix()[2, 2] == 0.0
    assert math.isnan(camera_height(2.0, X_WB, X_BL, RigidTransform([0.0, 0.0, 0.1])))


def test_the_estimator_takes_the_tilted_stereo_depth_to_the_pad():
    """The system fed the depth a UAV rolled 20 deg reads along its stereo axis, and a box on a point of the
    pad's plane, puts the pad on that point (before: the depth taken for the height, 0.1 m off)."""
    _, scenario = load_scenario("ugv-hybrid")
    p_WB, rpy = [20.0, -30.0, 5.0], np.radians([20.0, 0.0, 0.0])
    X_WB = RigidTransform(RollPitchYaw(*rpy), p_WB)
    depth = true_window_depth(*_state_rows(p_WB, rpy), scenario)[0]
    p_WP = np.array([20.0, -32.0, Z_PAD + GROUND_LIFT_M])  # the plane the stereo depth measures up from
    system = HybridPadEstimator(FISHEYE, scenario.hybrid.stereo.X_BL, Z_PAD)
    context = system.CreateDefaultContext()
    system.GetInputPort("target_box").FixValue(context, box_around(p_WP, X_WB))
    system.GetInputPort("target_valid").FixValue(context, [1.0])
    system.GetInputPort("altitude").FixValue(context, [depth])
    system.GetInputPort("altitude_valid").FixValue(context, [1.0])
    system.GetInputPort("X_WB").FixValue(context, X_WB)
    estimate = system.GetOutputPort("X_WP_estimate").Eval(context)
    assert estimate.valid
    assert np.allclose(estimate.X_RT.translation()[:2], p_WP[:2], atol=1e-6)


def test_estimator_system_builds():
    system = HybridPadEstimator(FISHEYE, HybridPerceptionConfig().stereo.X_BL, Z_PAD)
    context = system.CreateDefaultContext()
    system.GetInputPort("target_box").FixValue(context, np.full(4, np.nan))
    system.GetInputPort("target_valid").FixValue(context, [0.0])
    system.GetInputPort("altitude").FixValue(context, [7.4])
    system.GetInputPort("altitude_valid").FixValue(context, [1.0])
    system.GetInputPort("X_WB").FixValue(context, RigidTransform([0.0, 0.0, 7.5]))
    estimate = system.GetOutputPort("X_WP_estimate").Eval(context)
    assert not estimate.valid and estimate.frames == "X_WP"
    assert np.all(np.isnan(system.GetOutputPort("v_WP_observed").Eval(context)))
    assert system.GetOutputPort("v_valid").Eval(context)[0] == 0.0
    assert np.array_equal(system.GetOutputPort("v_WP").Eval(context), np.zeros(3))  # never NaN to the seam


def test_the_seams_velocity_past_the_observers_window_is_the_coasts():
    """v_WP while the estimate coasts past the observer's window (1.5 s; the final landing, 2 m up): the velocity it
    coasts with, the boxes' 0.5 m/s along x, not zero; v_WP_observed is NaN."""
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)]
    state = _run(seen + [(0.1 * k, False, True, None) for k in range(10, 31)], height_m=2.0)[-1]
    assert state.estimate.valid and not state.measured and not state.observer.valid
    system = HybridPadEstimator(FISHEYE, HybridPerceptionConfig().stereo.X_BL, Z_PAD)
    context = system.CreateDefaultContext()
    context.SetTime(state.time)
    context.SetAbstractState(0, state)  # the step at state.time taken: the outputs read it
    # the boxes' points, recovered to the undistortion's precision (1e-6 m), lie on the line the observer fits
    np.testing.assert_allclose(system.GetOutputPort("v_WP").Eval(context), v, atol=1e-3)
    assert np.all(np.isnan(system.GetOutputPort("v_WP_observed").Eval(context)))


@pytest.mark.parametrize("matched", [False, True])
def test_only_a_box_matched_this_frame_measures(matched):
    """With target_lock connected, a valid box measures only when the locked track was matched with a detection
    this frame (lock [id, 1]), then at the point it was drawn around; the box of a track coasting without one
    (lock [id, 0]) does not."""
    X_BL = HybridPerceptionConfig().stereo.X_BL
    X_WB, p_WP = RigidTransform([0.0, 0.0, 7.5]), np.array([1.0, -0.5, Z_PAD])
    system = HybridPadEstimator(FISHEYE, X_BL, Z_PAD)
    context = system.CreateDefaultContext()
    system.GetInputPort("target_box").FixValue(context, box_around(p_WP, X_WB))
    system.GetInputPort("target_valid").FixValue(context, [1.0])
    system.GetInputPort("target_lock").FixValue(context, [3.0, float(matched)])
    # level, the eye looking straight down at the ground (z = 0): its depth is its height
    system.GetInputPort("altitude").FixValue(context, [X_WB.multiply(X_BL).translation()[2]])
    system.GetInputPort("altitude_valid").FixValue(context, [1.0])
    system.GetInputPort("X_WB").FixValue(context, X_WB)
    assert system.GetOutputPort("hybrid_vector").Eval(context)[4] == float(matched)
    estimate = system.GetOutputPort("X_WP_estimate").Eval(context)
    assert estimate.valid == matched
    if matched:
        assert np.allclose(estimate.X_RT.translation(), p_WP, atol=1e-6)
        # a position alone: no heading in it (the hybrid source's estimates_heading is False)
        assert estimate.X_RT.rotation().IsExactlyIdentity()


def test_the_altitude_filter_knows_the_altimeters_nearest_range():
    _, scenario = load_scenario("ugv-hybrid")
    diagram, _ = build_gv_landing(scenario)
    altimeter, altitude = (diagram.GetSubsystemByName(name) for name in ("stereo_altimeter", "altitude_filter"))
    assert altitude.nearest_m == altimeter.estimator.nearest_m == pytest.approx(350.0 * 0.12 / 63)  # disparities 0-63


def test_the_estimator_and_the_logs_read_the_altitudes_they_are_named_for():
    """In the built ugv-hybrid diagram the hybrid pad estimator takes the altitude filter's altitude and its
    validity (not the raw stereo flag), and the `stereo_altitude` log is the altimeter's raw reading (not the
    filtered one, which `altitude` logs)."""
    _, scenario = load_scenario("ugv-hybrid")
    diagram, handles = build_gv_landing(scenario)
    wired = wiring(diagram)
    assert wired["hybrid_pad", "altitude"] == ("altitude_filter", "altitude")
    assert wired["hybrid_pad", "altitude_valid"] == ("altitude_filter", "valid")
    assert wired["altitude_filter", "altitude_valid"] == ("stereo_altimeter", "altitude_valid")
    assert wired["stereo_pad", "left_image"] == ("stereo_left", "color_image")  # the eye X_BL places
    logs = handles.perception.logs
    for name, source in (("stereo_altitude", ("stereo_altimeter", "altitude")),
                         ("stereo_valid", ("stereo_altimeter", "altitude_valid")),
                         ("altitude", ("altitude_filter", "altitude")),
                         ("altitude_valid", ("altitude_filter", "valid")),
                         ("hybrid", ("hybrid_pad", "hybrid_vector")),
                         ("v_WP", ("hybrid_pad", "v_WP_observed")),  # the observer's own: NaN where it has none
                         ("v_valid", ("hybrid_pad", "v_valid")),
                         ("target_box", ("box_tracker", "target_box")),
                         ("target_valid", ("box_tracker", "target_valid")),
                         ("lock", ("locked_track", "lock")),
                         ("detections", ("ugv_detections", "detection_vector"))):
        assert wired[logs[name].get_name(), logs[name].get_input_port().get_name()] == source, name


def test_the_hybrid_pad_estimator_is_given_the_pads_height_and_the_left_eyes_mount(monkeypatch):
    """The estimator meets the box's ray with the pad's plane, z = platform.p_VP's z (ugv-hybrid's 0.5 m body top),
    and takes the stereo height along the left eye's axis, at stereo.X_BL (the eye the depth is measured in)."""
    given = []

    class RecordingEstimator(HybridPadEstimator):
        def __init__(self, fisheye, X_BL, z_pad, *args, **kwargs):
            given.append((X_BL, z_pad))
            super().__init__(fisheye, X_BL, z_pad, *args, **kwargs)

    monkeypatch.setattr(hybrid_perception, "HybridPadEstimator", RecordingEstimator)
    _, scenario = load_scenario("ugv-hybrid")
    build_gv_landing(scenario)
    [(X_BL, z_pad)] = given
    assert scenario.platform.height_m == 0.5 and z_pad == 0.5
    stereo = scenario.hybrid.stereo
    assert not np.allclose(stereo.X_BL.translation(), stereo.X_BR.translation())  # the two eyes apart
    np.testing.assert_array_equal(X_BL.GetAsMatrix4(), stereo.X_BL.GetAsMatrix4())


def test_the_textured_ground_the_cameras_see_covers_the_path_just_over_the_plain_ground():
    """ugv-hybrid's straight path runs 400 m along x from the origin, its plain ground 25 m beyond each end:
    the 100 m textured squares, on the origin's grid, at x = 0, 100, .., 400 (x -50 to 450 m), each GROUND_LIFT_M
    over the plain ground (z = 0): the cameras' (perceived) copies."""
    _, scenario = load_scenario("ugv-hybrid")
    _, handles = build_gv_landing(scenario)
    inspector = handles.scene_graph.model_inspector()
    perceived = {inspector.GetName(g): inspector.GetPoseInFrame(g).translation()
                 for g in inspector.GetAllGeometryIds()
                 if inspector.GetName(g).startswith("textured_ground") and inspector.GetPerceptionProperties(g)}
    assert sorted(perceived) == ["textured_ground", *(f"textured_ground_{k}" for k in range(1, 5))]
    centres = np.array(sorted(perceived.values(), key=lambda p: p[0]))
    np.testing.assert_allclose(centres, [[100.0 * k, 0.0, GROUND_LIFT_M] for k in range(5)], atol=1e-12)


def test_scenario_loads():
    name, scenario = load_scenario("ugv-hybrid")
    assert name == "ugv-hybrid" and scenario.perception.source == "hybrid"
    assert scenario.landing.initial_height_m == 7.5 and scenario.landing.landing_height_m == 1.5
    assert scenario.vehicle.speed == 0.5 and scenario.hybrid.detector == "learned"


@pytest.mark.parametrize("setting, field", [("hybrid.detector=yolo", "hybrid.detector"),
                                            ("hybrid.tracker.rate_hz=20", "hybrid.tracker.rate_hz"),
                                            ("hybrid.tracker.lock_min_score=2", "hybrid.tracker.lock_min_score"),
                                            ("hybrid.tracker.min_score=1.5", "hybrid.tracker.min_score"),
                                            ("hybrid.tracker.measurement_std_px=.inf",
                                             "hybrid.tracker.measurement_std_px"),
                                            ("hybrid.fisheye.k1=.inf", "hybrid.fisheye.k1"),
                                            # SGBM leaves the image's first 64 columns unmatched
                                            ("hybrid.depth.window_cols=752", "hybrid.depth.window_cols"),
                                            ("hybrid.fisheye.mount_xyz_m=[.inf, 0.0, 0.0]",
                                             "hybrid.fisheye.mount_xyz_m"),
                                            ("hybrid.stereo_pad.max_height_m=0", "hybrid.stereo_pad.max_height_m"),
                                            ("hybrid.stereo_pad.threshold_window_px=4",
                                             "hybrid.stereo_pad.threshold_window_px"),
                                            ("hybrid.estimator.min_ray_down=2", "hybrid.estimator.min_ray_down"),
                                            # 0 would let a horizontal ray measure: the range is (0, 1]
                                            ("hybrid.estimator.min_ray_down=0",
                                             "hybrid.estimator.min_ray_down must lie in (0, 1]"),
                                            ("hybrid.estimator.approach_min_ray_down=0",
                                             "hybrid.estimator.approach_min_ray_down must lie in (0, 1]"),
                                            ("hybrid.fisheye.fov_deg=200", "hybrid.fisheye.fov_deg"),
                                            ("hybrid.fisheye.width=640", "hybrid.fisheye.width"),
                                            ("hybrid.refinement.method=yolo", "hybrid.refinement.method"),
                                            ("hybrid.tracker.cue_px=[1e9, 1e9]", "hybrid.tracker.cue_px"),
                                            ("hybrid.tracker.cue_px=[100, 512]", "hybrid.tracker.cue_px"),
                                            ("hybrid.classical.max_strip_angle_deg=-5",
                                             "hybrid.classical.max_strip_angle_deg"),
                                            ("hybrid.classical.min_part_px=-1", "hybrid.classical.min_part_px"),
                                            ("hybrid.classical.min_box_px=-3", "hybrid.classical.min_box_px"),
                                            ("hybrid.no_such_key=1", "hybrid.no_such_key"),
                                            # the observer steps once per fisheye frame, on the hybrid p_WP
                                            ("hybrid.velocity_observer.rate_hz=20",
                                             "hybrid.velocity_observer.rate_hz"),
                                            ("hybrid.velocity_observer.source=pixel",
                                             "hybrid.velocity_observer.source must be world"),
                                            # slower than the fisheye's 10 Hz as well as faster
                                            ("hybrid.tracker.rate_hz=5",
                                             "hybrid.tracker.rate_hz (5) must be hybrid.fisheye.rate_hz (10)"),
                                            ("hybrid.velocity_observer.rate_hz=5",
                                             "hybrid.velocity_observer.rate_hz (5) must be hybrid.fisheye.rate_hz "
                                             "(10)")])
def test_bad_setting_names_the_field(setting, field):
    with pytest.raises(ConfigError, match=re.escape(field)):
        load_scenario("ugv-hybrid", overrides=[setting])


def test_the_defaults_the_docs_state():
    """hybrid_stereo's docstring and docs/scenarios.md: the stereo pair at the fisheye's 10 Hz; docs/scenarios.md:
    the velocity observer's `fit` `linear` here (Eq. 18-19's `mean` is VelocityObserverConfig's default)."""
    config = HybridPerceptionConfig()
    assert config.stereo.rate_hz == config.fisheye.rate_hz == 10.0
    assert config.velocity_observer.fit == "linear" and VelocityObserverConfig().fit == "mean"


def _hover_flight(xy, duration_s, *overrides):
    """A flight that starts hovering at IH at `xy` over the UGV's start (the UGV drives the straight path)."""
    _, scenario = load_scenario("ugv-hybrid", overrides=[f"start.xy_m=[{xy[0]}, {xy[1]}]", "start.height_m=7.5",
                                                         *overrides])
    return fly(scenario, duration_s, progress=False)


@pytest.fixture(scope="module")
def short_hybrid_run():
    return _hover_flight((0.5, 0.3), 3.0)


@pytest.mark.slow
def test_estimate_near_the_truth_once_valid(short_hybrid_run):
    """Measured (seed 0, hovering 7.5 m over the UGV, 3 s, the learned detector with its boxes re-centred by the
    colour, the default): valid from 0.2 s on (the tracker confirms a track in 3 frames), horizontal error at most
    0.039 m, rms 0.020 m; the velocity's rms error 0.035 m/s. Asserted with about 1.5x margin on the position
    (the network's boxes as they come, `hybrid.refinement.method=none`: 0.069 m, rms 0.033 m, which fails it)."""
    metrics, flight = short_hybrid_run
    log = flight.source_log
    valid = log["hybrid"][:, 0] > 0.5
    assert valid[3:].all()
    p_true = log["quadrotor_state"][:, P_WB] + log["true_relative_state"][:, P_BP_W]
    error = np.linalg.norm(log["hybrid"][valid, 1:3] - p_true[valid, :2], axis=1)
    assert error.max() < 0.06
    assert metrics["estimators"]["hybrid"]["position_m"]["rmse_horizontal"] < 0.03
    assert metrics["estimators"]["hybrid"]["velocity_mps"]["rmse_horizontal"] < 0.1
    assert flight.log["relative_state"][-1, VALID] == 1.0
    # The flight starts at IH: "after the climb" is all of it.
    assert metrics["estimators"]["hybrid"]["position_m_after_climb"] == metrics["estimators"]["hybrid"]["position_m"]


def test_run_prints_the_error_after_the_climb():
    metrics = {"perception": {"source": "hybrid"},
               "estimators": {"hybrid": {"position_m_after_climb": {"mae_xyz": [0.0046, 0.0068, 0.0], "samples": 90}}}}
    assert "ugv-hybrid: hybrid from the climb's end on: MAE x / y / z 0.0046 / 0.0068 / 0.0000 m" in summary_lines(
        "ugv-hybrid", metrics)
    metrics["estimators"]["hybrid"]["position_m_after_climb"] = {"samples": 0}  # never valid after it
    assert not any("climb" in line for line in summary_lines("ugv-hybrid", metrics))


def test_climb_ends_within_five_percent_of_ih():
    z = np.array([0.0, 3.0, 7.0, 7.2, 7.6, 7.4])
    assert climb_end_index(z, 7.5) == 3  # 7.125 m and above
    assert climb_end_index(z[:3], 7.5) is None


@pytest.mark.slow
def test_distractors_in_view_do_not_take_the_lock():
    """Four vehicles driving beside the UGV, one in its colour: the lock stays on one track, the estimate on the UGV
    (the same bounds as alone)."""
    metrics, flight = _hover_flight((0.5, 0.3), 3.0, "distractors.count=4", "distractors.same_colour=1")
    assert metrics["estimators"]["hybrid_detector"]["identity_switches"] == 0
    assert metrics["estimators"]["hybrid"]["position_m"]["rmse_horizontal"] < 0.06
    log = flight.source_log
    p_true = log["quadrotor_state"][:, P_WB] + log["true_relative_state"][:, P_BP_W]
    valid = log["hybrid"][:, 0] > 0.5
    assert valid[3:].all()
    assert np.linalg.norm(log["hybrid"][valid, 1:3] - p_true[valid, :2], axis=1).max() < 0.12


@pytest.mark.slow
def test_the_lock_follows_the_ugv_through_the_climbs_jerks():
    """The first 6.5 s of ugv-hybrid on the circle at 0.8 m/s, seed 0: the take-off's tilts jerk the UGV's box by
    30-60 px a frame. Measured: before the tracker's recovery its locked track took the jerks for motion, coasted
    off the image at 630 px/s from 4.4 s while the detector boxed the UGV in every frame (the target's box
    overlapping none of them), and the lock passed to a new track at 5.9 s (one identity switch); with it, one track
    from the lock on, and in every frame where a detection holds the UGV (IOU >= 0.5 with its true box) the
    target's box overlaps the true box at IOU 0.51 or more. Asserted: no switch, IOU >= 0.3 in those frames."""
    _, scenario = load_scenario("ugv-hybrid", overrides=["vehicle.path=circle", "vehicle.speed=0.8"], seed=0)
    metrics, flight = fly(scenario, 6.5, progress=False)
    assert metrics["estimators"]["hybrid_detector"]["identity_switches"] == 0
    log = flight.source_log
    truth = true_ugv_boxes(log["quadrotor_state"], log["vehicle_state"], scenario)
    locked = log["lock"][:, 0] >= 0
    seen = 0
    for row, true_box, target, is_locked in zip(log["detections"], truth, log["target_box"], locked):
        boxes = [row[5 * k + 2:5 * k + 6] for k in range((len(row) - 1) // 5) if row[5 * k + 1] > 0.5]
        if is_locked and true_box is not None and any(iou(b, true_box) >= 0.5 for b in boxes):
            seen += 1
            assert iou(target, true_box) >= 0.3
    assert seen >= 30  # 33 measured: the climb's frames from the lock (2.5 s) on


@pytest.mark.slow
def test_ugv_under_a_bridge_turns_invalid_then_is_found_again():
    """The UGV drives under a 1.5 m bridge deck (its pad wholly hidden from 3.5 to 4.5 s): measured (seed 0, the
    CNN detector, OpenCV 5.1), the estimate is at most 0.56 m off while valid (boxes of the UGV's visible part, the
    last at 3.1 s, then the 0.4 s approach coast), is invalid from 3.6 to 5.7 s, 0.31 m off when the lock is taken
    again and within 0.05 m over the last second. Asserted: never valid and over 1.5 m off (before the tracker's
    partial-view rule and lock_min_score: 10 m off and valid, locked on the ground's false alarms), nothing
    measured while the pad is hidden, invalid once the coast is spent, within 0.1 m over the last second."""
    _, flight = _hover_flight((0.5, 0.3), 9.0, "bridge.enabled=true", "bridge.at_m=2.45")
    log = flight.source_log
    t, valid = log["t"], log["hybrid"][:, 0] > 0.5
    p_true = log["quadrotor_state"][:, P_WB] + log["true_relative_state"][:, P_BP_W]
    error = np.linalg.norm(log["hybrid"][:, 1:3] - p_true[:, :2], axis=1)
    assert np.all(error[valid] < 1.5)
    hidden = (t >= 3.5) & (t <= 4.5)
    assert not (log["hybrid"][hidden, 4] > 0).any()  # `measured`: neither the box nor the stereo eye's fix
    coast_s = HybridPadConfig().approach_max_coast_s
    assert not valid[(t >= 3.5 + coast_s + 0.05) & (t <= 4.5)].any()
    last = t >= 8.0
    assert valid[last].all() and np.all(error[last] < 0.1)


@pytest.mark.slow
def test_estimate_invalid_out_of_view():
    """Hovering 60 m from the UGV (83 deg off the axis, beyond the fisheye's 75): never valid, never NaN as valid."""
    metrics, flight = _hover_flight((-45.0, -40.0), 1.0)
    log = flight.source_log
    assert not (log["hybrid"][:, 0] > 0.5).any()
    assert np.all(np.isnan(log["hybrid"][:, 1:4]))
    assert not (flight.log["relative_state"][:, VALID] > 0.5).any()
    assert metrics["estimators"]["hybrid"]["valid_fraction"] == 0.0


def test_estimator_gates_an_outlier():
    """In the final landing (1.45 m over the pad) a valid estimate ignores a measurement 1 m off its
    prediction (a part of the UGV boxed at close range), and coasts past the observer's window."""
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)]
    outlier = [(1.0, True, True, np.array([1.5, 0.0, Z_PAD]))]
    states = _run(seen + outlier + [(0.1 * k, False, True, None) for k in range(11, 40)], height_m=2.0)
    assert states[38].estimate.valid and not states[38].measured  # 2.9 s after the last: the observer's gone
    states = states[:11]
    last = states[-1]
    assert last.gated == 1 and last.estimate.valid and not last.measured
    assert np.allclose(last.estimate.X_RT.translation()[:2], [0.5, 0.0], atol=0.02)
    # Its std is the last measured ray's (1 / cos of its angle from the vertical), grown over the 0.1 s coast,
    # not the rejected ray's.
    p_WC = RigidTransform([0.0, 0.0, 2.0]).multiply(FISHEYE.X_BC).translation()
    below = p_WC[2] - Z_PAD
    used = math.hypot(below, math.dist(states[-2].last_p_WP[:2], p_WC[:2])) / below
    config = HybridPadConfig()
    assert math.sqrt(last.estimate.covariance[3, 3]) == pytest.approx(
        config.position_std_m * used + config.coast_std_growth_m_s * 0.1, rel=1e-9)


@pytest.mark.parametrize("off_m, used", [(0.8, True), (1.3, False)])
def test_the_gate_grows_with_the_time_since_the_last_measurement(off_m, used):
    """In the final landing, after a 2 s coast the gate is gate_m + gate_growth_m_s * 2 s = 1.1 m: a measurement
    0.8 m off the coast's prediction (beyond gate_m's 0.5 m alone) is used, one 1.3 m off is not."""
    v = np.array([0.5, 0.0, 0.0])
    seen = [(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)]
    blind = [(0.1 * k, False, True, None) for k in range(10, 29)]
    again = [(2.9, True, True, np.array([0.0, off_m, Z_PAD]) + v * 2.9)]
    config = HybridPadConfig()
    assert config.gate_m < 0.8 < config.gate_m + 2.0 * config.gate_growth_m_s < 1.3
    states = _run(seen + blind + again, config, height_m=2.0)
    assert states[-2].estimate.valid and not states[-2].measured
    predicted = states[-2].estimate.X_RT.translation() + 0.1 * states[-2].velocity
    assert abs(np.linalg.norm(again[0][3][:2] - predicted[:2]) - off_m) < 0.05
    last = states[-1]
    assert last.measured == used and last.gated == (0 if used else 1)
    if used:
        assert np.allclose(last.estimate.X_RT.translation(), again[0][3], atol=1e-6)


def test_the_stereo_pad_fix_is_not_gated():
    """In the final landing, a valid estimate moving at 0.5 m/s and a stereo eye's fix 1.5 m off its prediction
    (beyond the gate, which refuses such a box): the fix measures, ungated, the estimate on it at the pad's plane."""
    v = np.array([0.5, 0.0, 0.0])
    states = _run([(0.1 * k, True, True, np.array([0.0, 0.0, Z_PAD]) + v * 0.1 * k) for k in range(10)], height_m=2.0)
    last = states[-1]
    assert last.estimate.valid and last.velocity is not None
    X_WB = RigidTransform([0.0, 0.0, 2.0])
    fix = np.array([0.5, 1.5, Z_PAD + 0.03])  # the prediction at 1.0 s is [0.5, 0]
    predicted = last.last_p_WP + 0.1 * last.velocity
    config = HybridPadConfig()
    assert np.linalg.norm(fix[:2] - predicted[:2]) > config.gate_m + 0.1 * config.gate_growth_m_s
    state = hybrid_step(last, 1.0, np.full(4, np.nan), False, X_WB.multiply(FISHEYE.X_BC).translation()[2], True,
                        X_WB, FISHEYE, Z_PAD, config, VelocityObserverConfig(), pad_fix=fix)
    assert state.fixed and state.measured and state.gated == 0
    assert np.allclose(state.estimate.X_RT.translation(), [0.5, 1.5, Z_PAD])


@pytest.mark.parametrize("fix", [[1.0, 2.0, np.nan], [np.nan, 2.0, Z_PAD]], ids=["nan-z", "nan-x"])
def test_a_pad_fix_with_a_nan_entry_is_no_fix(fix):
    """A stereo eye's fix with any entry NaN is no fix: the box measures, and the estimate is its point."""
    X_WB = RigidTransform([0.0, 0.0, 5.0])
    h = X_WB.multiply(FISHEYE.X_BC).translation()[2]
    p = np.array([0.3, -0.2, Z_PAD])
    state = hybrid_step(HybridPadState(), 0.0, box_around(p, X_WB), True, h, True, X_WB, FISHEYE, Z_PAD,
                        HybridPadConfig(), VelocityObserverConfig(), pad_fix=np.array(fix))
    assert state.estimate.valid and state.measured and not state.fixed
    assert np.allclose(state.estimate.X_RT.translation(), p, atol=1e-6)


def test_the_hybrid_vector_codes_what_measured_the_frame():
    """hybrid_vector's `measured` (index 4): 1 for a frame the box measured, 2 for one the stereo eye's fix did, 0
    for one neither did (hybrid_metrics' stereo_pad_fraction counts the frames over 1.5)."""
    X_WB = RigidTransform([0.0, 0.0, 2.0])
    h = X_WB.multiply(FISHEYE.X_BC).translation()[2]
    p = np.array([0.1, -0.2, Z_PAD])
    frames = [(box_around(p, X_WB), True, None), (np.full(4, np.nan), False, p), (np.full(4, np.nan), False, None)]
    state, measured = HybridPadState(), []
    for k, (box, seen, fix) in enumerate(frames):
        state = hybrid_step(state, 0.1 * k, box, seen, h, True, X_WB, FISHEYE, Z_PAD, HybridPadConfig(),
                            VelocityObserverConfig(), pad_fix=fix)
        measured.append(hybrid_vector(state)[4])
    assert measured == [1.0, 2.0, 0.0]


def _state_rows(p_WB, rpy=(0.0, 0.0, 0.0), vehicle=(0.0, 0.0, 0.0)):
    """A one-frame quadrotor state (17) and vehicle state (4) for the metrics."""
    quad = np.zeros((1, 17))
    quad[0, P_WB] = p_WB
    quad[0, Q_WB] = RollPitchYaw(*rpy).ToQuaternion().wxyz()
    return quad, np.array([[*vehicle, 0.0]])


@pytest.mark.parametrize("p_WB, rpy, over_ugv", [
    ([0.45, 0.0, 3.0], (0.0, 0.0, 0.0), True),  # over the pad's centre (pad_offset_m)
    ([0.45, 5.0, 3.0], (0.0, 0.0, 0.7), False),  # beside the UGV, yawed
    ([0.45, -0.6, 3.0], (-0.25, 0.0, 0.0), False),  # by the UGV's side, rolled away: the ground
    ([0.45, -0.6, 3.0], (0.25, 0.0, 0.0), True),  # rolled towards it: its top
])
def test_true_window_depth_is_the_left_eyes_axis_to_the_ugv_or_the_ground(p_WB, rpy, over_ugv):
    _, scenario = load_scenario("ugv-hybrid")
    quad, vehicle = _state_rows(p_WB, rpy)
    depth = true_window_depth(quad, vehicle, scenario)[0]
    X_WL = RigidTransform(RollPitchYaw(*rpy), p_WB).multiply(scenario.hybrid.stereo.X_BL)
    top = scenario.platform.height_m + 0.001 if over_ugv else GROUND_LIFT_M  # the UGV's box top or the ground
    axis_down = -X_WL.rotation().col(2)[2]
    assert depth == pytest.approx((X_WL.translation()[2] - top) / axis_down, abs=1e-9)


def test_true_window_depth_is_nan_with_nothing_ahead():
    """On the ground at the start the eye hangs 5 cm under the body's origin, below the ground's plane."""
    _, scenario = load_scenario("ugv-hybrid")
    on_ground, _ = _state_rows([-1.5, -1.0, 0.0])
    looking_up, _ = _state_rows([-1.5, -1.0, 3.0], rpy=(math.pi, 0.0, 0.0))
    assert np.isnan(true_window_depth(np.vstack([on_ground, looking_up]), np.zeros((2, 4)), scenario)).all()


def test_ground_tiles_cover_the_rectangle_on_the_origins_grid():
    assert [c.tolist() for c in ground_tiles(100.0, [-25.0, -25.0], [425.0, 25.0])] == [
        [0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [300.0, 0.0], [400.0, 0.0]]
    assert [c.tolist() for c in ground_tiles(20.0, [-10.0, -9.0], [9.9, 9.0])] == [[0.0, 0.0]]
    assert len(ground_tiles(10.0, [-14.0, 0.0], [-4.0, 0.0])) == 2  # x -14 .. -4: the squares at -10 and 0


def test_the_stereo_altimeter_sees_texture_along_the_whole_path():
    """The straight path runs 400 m from the origin; ugv-hybrid's textured square is 100 m: repeated along it,
    the altimeter measures 3 m over the ground 60 and 380 m down the path (before: NaN past 50 m)."""
    _, scenario = load_scenario("ugv-hybrid", overrides=["vehicle.path=straight"])
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    add_renderer(scene_graph)
    add_textured_ground(scene_graph, scenario.hybrid.ground, GROUND_LIFT_M, scenario.vehicle.ground_extent())
    airframe = builder.AddSystem(AirframeGeometry(scenario.uav, scene_graph))
    builder.Connect(airframe.get_output_port(), scene_graph.get_source_pose_port(airframe.source_id))
    pose = builder.ExportInput(airframe.get_input_port(), "X_WB")
    pair = add_stereo_pair(builder, scene_graph, airframe.body_frame_id, scenario.hybrid.stereo, 0)
    altimeter = builder.AddSystem(StereoAltimeter(scenario.hybrid.stereo, scenario.hybrid.depth))
    builder.Connect(pair.left_image, altimeter.GetInputPort("left_image"))
    builder.Connect(pair.right_image, altimeter.GetInputPort("right_image"))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    for x in (60.0, 380.0):
        X_WB = RigidTransform([x, 0.0, 3.0])
        diagram.get_input_port(pose).FixValue(context, X_WB)
        own = altimeter.GetMyContextFromRoot(context)
        assert altimeter.GetOutputPort("altitude_valid").Eval(own)[0] == 1.0
        depth = X_WB.multiply(scenario.hybrid.stereo.X_BL).translation()[2] - GROUND_LIFT_M
        assert altimeter.GetOutputPort("altitude").Eval(own)[0] == pytest.approx(depth, rel=0.02)
