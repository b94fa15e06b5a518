"""Seed 001's vision nodes on views of the RQRLP made by its homography (the renderer's pinhole
image, then the lens' distortion as the camera applies it): the adjustment node against the truth
and against OpenCV's own PnP on the same corners, the approaching node's rough position, the
touchdown node's chain over a descent, and nothing found where there is nothing to find."""

import zlib
from dataclasses import replace

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from systems.perception.rqrlp import nodes
from systems.perception.rqrlp.homography import (
    homography_from_pose,
    plane_pose,
    pose_from_homography,
)
from systems.perception.rqrlp.measurements import approach_covariance
from systems.perception.rqrlp.node_systems import adjustment_node, approach_node
from systems.perception.rqrlp.nodes import (
    EDGE_MARGIN_PX,
    MAX_ASPECT,
    TouchdownTracker,
    adjustment,
    approach,
    corners_from_sides,
    layout_corners,
)
from systems.perception.rqrlp.pattern import RqrlpLayout, rqrlp_image
from systems.sensors.camera import CalibrationErrorConfig, CameraConfig, distortion_maps, undistort_pixels
from tests.conftest import render_plane

LAYOUT = RqrlpLayout()
TEXTURE = rqrlp_image(LAYOUT)
# Seed 001 Table 1's camera at half its 1920 x 1080 resolution (the same field of view), its lens.
CAMERA = CameraConfig(width=960, height=540, fx=640.0, fy=640.0, cx=474.45, cy=271.6,
                      distortion=[-0.00908, -0.03128, 0.00109, -0.00198, 0.0])
K, D = CAMERA.K, CAMERA.D
MAPS = distortion_maps(CAMERA)
LOOKING_DOWN = RotationMatrix.MakeXRotation(np.pi)


def view(X_CP: RigidTransform, supersample: int = 3, ground: int = 200, noise: float = 2.0,
         camera: CameraConfig = CAMERA) -> np.ndarray:
    """The grey image of the pattern at X_CP seen by `camera`: the plane's homography at `supersample` times
    the resolution averaged down, distorted by the lens, with the camera's pixel noise (`noise` levels,
    seeded by the pose)."""
    pinhole = render_plane(TEXTURE, LAYOUT.size_m, X_CP, camera, supersample, ground)
    maps = MAPS if camera is CAMERA else distortion_maps(camera)
    distorted = cv2.remap(pinhole, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    rng = np.random.default_rng(zlib.crc32(X_CP.GetAsMatrix34().tobytes()))
    return np.clip(distorted + rng.normal(0.0, noise, distorted.shape), 0, 255).astype(np.uint8)


def X_CP_at(height_m: float, xy=(0.05, -0.03), yaw_deg: float = 30.0, tilt_deg=(0.0, 0.0)) -> RigidTransform:
    """The pattern `height_m` under the camera, offset, yawed, and tilted (roll, pitch of the camera)."""
    R = RotationMatrix(RollPitchYaw(np.radians([*tilt_deg, 0.0]))).multiply(LOOKING_DOWN).multiply(
        RotationMatrix.MakeZRotation(np.radians(yaw_deg)))
    return RigidTransform(R, [*xy, height_m])


def errors(estimate: RigidTransform, truth: RigidTransform) -> tuple[float, float]:
    """(position error [m], rotation error [deg])."""
    return (float(np.linalg.norm(estimate.translation() - truth.translation())),
            float(np.degrees(truth.rotation().InvertAndCompose(estimate.rotation()).ToAngleAxis().angle())))


def test_eq_2_recovers_a_pose_from_its_homography():
    X_CP = X_CP_at(3.0, tilt_deg=(8.0, -5.0))
    H = homography_from_pose(X_CP, K)
    position, angle = errors(pose_from_homography(H * -2.5, K), X_CP)  # any scale, either sign
    assert position < 1e-12 and angle < 1e-9


def test_eq_2s_scale_is_the_mean_of_both_columns_norms():
    """H = K [r1, 1.1 r2, t] (its second column 10 % long, as noise may make it): K^-1 H's first two columns have
    norms 1 and 1.1, so the scale 2 / (1 + 1.1) shortens t to t 2 / 2.1."""
    X_CP = X_CP_at(3.0, tilt_deg=(8.0, -5.0))
    R, t = X_CP.rotation().matrix(), X_CP.translation()
    H = K @ np.column_stack([R[:, 0], 1.1 * R[:, 1], t])
    np.testing.assert_allclose(pose_from_homography(H, K).translation(), t * 2.0 / 2.1, rtol=1e-12)


def test_a_plane_pose_needs_four_points():
    """Three points fit no homography: no pose, where cv2.findHomography would raise."""
    X_CP = X_CP_at(3.0)
    points = layout_corners(LAYOUT)[:4]  # one square's corners
    rvec = cv2.Rodrigues(X_CP.rotation().matrix())[0]
    pixels = cv2.projectPoints(points, rvec, X_CP.translation(), K, None)[0].reshape(-1, 2)
    assert plane_pose(points[:3], pixels[:3], K) is None
    assert plane_pose(points, pixels, K) is not None


def test_eq_1_is_opencvs_homography_of_the_projected_pattern():
    """Eq. (1)'s H = K [r1 r2 t], scaled to H[2, 2] = 1, is the homography cv2.findHomography fits to the
    pattern's corners and their projections by cv2.projectPoints (which it scales alike; its fit to 1e-4)."""
    X_CP = X_CP_at(3.0, xy=(0.4, -0.2), tilt_deg=(8.0, -5.0))
    points = layout_corners(LAYOUT)
    rvec = cv2.Rodrigues(X_CP.rotation().matrix())[0]
    pixels = cv2.projectPoints(points, rvec, X_CP.translation(), K, None)[0].reshape(-1, 2)
    H, _ = cv2.findHomography(points[:, :2], pixels, 0)
    np.testing.assert_allclose(homography_from_pose(X_CP, K), H, rtol=1e-3, atol=1e-9)


@pytest.mark.parametrize("height_m, yaw_deg, tilt_deg", [(1.0, 0.0, (0, 0)), (2.5, 30.0, (6, -4)),
                                                        (4.0, 200.0, (-10, 8)), (3.0, -75.0, (3, 3))])
def test_adjustment_finds_the_pose_and_agrees_with_opencvs_pnp(height_m, yaw_deg, tilt_deg):
    X_CP = X_CP_at(height_m, yaw_deg=yaw_deg, tilt_deg=tilt_deg)
    found = adjustment(view(X_CP), K, D, LAYOUT, min_module_px=4.0)  # 4 m: 4.8 px modules, under the default 5
    assert found is not None
    position, angle = errors(found.X_CP, X_CP)
    assert position < 0.004 * height_m and angle < 1.0, (position, angle)
    assert found.rms_residual_px < 0.5
    ok, rvec, tvec = cv2.solvePnP(layout_corners(LAYOUT), found.corners_px, K, None, flags=cv2.SOLVEPNP_SQPNP)
    opencv = RigidTransform(RotationMatrix(cv2.Rodrigues(rvec)[0]), tvec.ravel())
    position, angle = errors(found.X_CP_homography, opencv)
    assert ok and position < 0.003 * height_m and angle < 1.0  # Eq. 2 minimises no reprojection error
    position, angle = errors(found.X_CP, opencv)
    assert position < 1e-4 * height_m and angle < 0.05  # refined to the same least-squares pose


@pytest.mark.parametrize("height_m, yaw_deg", [(1.5, 0.0), (2.5, 30.0), (3.5, 75.0)])
def test_adjustment_corners_are_where_the_squares_are(height_m, yaw_deg):
    """The refined corners against the corners' true projection: no square shrunk (the mean
    displacement away from each square's centre), each within a fraction of a pixel."""
    X_CP = X_CP_at(height_m, yaw_deg=yaw_deg, tilt_deg=(4, -3))
    found = adjustment(view(X_CP), K, D, LAYOUT)
    assert found is not None
    true, _ = cv2.projectPoints(layout_corners(LAYOUT), cv2.Rodrigues(X_CP.rotation().matrix())[0],
                                X_CP.translation(), K, None)
    true = true.reshape(-1, 4, 2)
    outward = true - true.mean(axis=1, keepdims=True)
    outward /= np.linalg.norm(outward, axis=2, keepdims=True)
    error = found.corners_px.reshape(-1, 4, 2) - true
    assert abs(np.mean(np.sum(error * outward, axis=2))) < 0.15  # cv2.cornerSubPix: 0.16-0.25 px inward here
    assert np.sqrt(np.mean(np.sum(error**2, axis=2))) < 0.35


def test_the_adjustment_nodes_pixel_noise_is_per_coordinate(monkeypatch):
    """Corners 0.5 px off in u and in v (std): the covariance's pixel noise, which it applies to each
    coordinate, is 0.5 px, not the residuals' 2-D RMS (sqrt(2) times it less the fit's dof, 0.68 px, which
    widened the pose's covariance as much)."""
    X_CP = X_CP_at(2.5, tilt_deg=(3, -2))
    grey = view(X_CP)
    true = cv2.projectPoints(layout_corners(LAYOUT), cv2.Rodrigues(X_CP.rotation().matrix())[0], X_CP.translation(),
                             K, D)[0].reshape(-1, 4, 2)
    rng = np.random.default_rng(0)

    def noisy(grey, quads, search_px):  # corners_from_sides: the true corners, 0.5 px noise
        return true + rng.normal(0.0, 0.5, true.shape), np.ones(len(quads), bool)

    monkeypatch.setattr(nodes, "corners_from_sides", noisy)
    stds = [adjustment_node(grey, 0.0, CAMERA, LAYOUT).view.pixel_std for _ in range(40)]
    assert np.mean(stds) == pytest.approx(0.5, rel=0.04)


def test_the_adjustment_nodes_covariance_is_of_the_corners_its_pose_was_fitted_to(monkeypatch):
    """The Top marker's 12 corners refined onto the wrong edges (8 px off): RANSAC leaves them out of the pose,
    and its covariance must leave them out too (it had claimed all 36: 0.47 mm of p_CP's x where 0.69 held)."""
    X_CP = X_CP_at(2.5, tilt_deg=(3, -2))
    grey = view(X_CP)
    true = cv2.projectPoints(layout_corners(LAYOUT), cv2.Rodrigues(X_CP.rotation().matrix())[0], X_CP.translation(),
                             K, D)[0].reshape(-1, 4, 2)
    rng = np.random.default_rng(1)

    def wrong_top(grey, quads, search_px):  # corners_from_sides: 0.3 px noise, the Top marker's 8 px off
        corners = true + rng.normal(0.0, 0.3, true.shape)
        corners[:3] += 8.0
        return corners, np.ones(len(quads), bool)

    monkeypatch.setattr(nodes, "corners_from_sides", wrong_top)
    measurement = adjustment_node(grey, 0.0, CAMERA, LAYOUT)
    np.testing.assert_array_equal(measurement.view.points_P, layout_corners(LAYOUT)[12:])
    np.testing.assert_array_equal(adjustment(grey, K, D, LAYOUT).inliers, np.arange(36) >= 12)


def test_adjustment_refuses_corners_whose_rms_residual_is_over_max_residual_px(monkeypatch):
    """Every corner 1.5 px off its true place, in random directions: about the pose fitted to them they
    are some 1.2 px off (RMS), over the 1 px max_residual_px, and adjustment gives no pose; allowed 2 px,
    it gives that pose."""
    X_CP = X_CP_at(2.5, tilt_deg=(3, -2))
    grey = view(X_CP)
    true = cv2.projectPoints(layout_corners(LAYOUT), cv2.Rodrigues(X_CP.rotation().matrix())[0], X_CP.translation(),
                             K, D)[0].reshape(-1, 4, 2)
    angle = np.random.default_rng(0).uniform(0.0, 2 * np.pi, true.shape[:2])
    off = true + 1.5 * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    monkeypatch.setattr(nodes, "corners_from_sides", lambda grey, quads, search_px: (off, np.ones(len(quads), bool)))
    assert adjustment(grey, K, D, LAYOUT) is None
    allowed = adjustment(grey, K, D, LAYOUT, max_residual_px=2.0)
    assert allowed is not None and 1.0 < allowed.rms_residual_px < 2.0


def test_adjustment_needs_the_markers_resolved():
    assert adjustment(view(X_CP_at(4.5)), K, D, LAYOUT) is None  # modules under 5 px
    assert adjustment(np.full((540, 960), 200, np.uint8), K, D, LAYOUT) is None
    assert adjustment(view(X_CP_at(1.0, xy=(0.6, 0.0))), K, D, LAYOUT) is None  # a marker out of view


@pytest.mark.parametrize("inner", [[(50, 50, 60, 60)], [(45, 45, 65, 65)], [(41, 41, 69, 69), (32, 32, 35, 35)]],
                         ids=["out_of_proportion", "inner_square_just_out_of_proportion", "two_squares_in_its_hole"])
def test_location_markers_pass_over_nested_squares_that_are_no_marker(inner):
    """Beside the pattern (2.5 m below), dark, light and dark nested squares that are no location marker:
    sides 71 : 51 : 11 px (areas 1 : 0.52 : 0.02, not 49 : 25 : 9); 71 : 51 : 21 px, whose outer and inner contours'
    70 and 20 px sides give the inner square 400 / 4900 * 49 / 9 - 1 = -56 % of a marker's area ratio, outside
    AREA_RATIO_TOLERANCE (35 %) but inside twice it; or a marker's 71 : 51 : 29 with a second square in its hole.
    The candidates are the pattern's three markers, each where its centre projects, and the pose is found (a
    fourth candidate lost it)."""
    X_CP = X_CP_at(2.5, xy=(0.3, 0.0), yaw_deg=10.0)
    grey = view(X_CP)
    cv2.rectangle(grey, (20, 20), (90, 90), 10, -1)
    cv2.rectangle(grey, (30, 30), (80, 80), 250, -1)
    for x0, y0, x1, y1 in inner:
        cv2.rectangle(grey, (x0, y0), (x1, y1), 10, -1)
    candidates = nodes.location_markers(grey)
    assert len(candidates) == 3
    centres_P = np.array([[*LAYOUT.marker_centres_P[m], 0.0] for m in ("top", "right", "bottom")])
    true = cv2.projectPoints(centres_P, cv2.Rodrigues(X_CP.rotation().matrix())[0], X_CP.translation(), K,
                             D)[0].reshape(-1, 2)
    found = np.array([c[0].mean(axis=0) for c in candidates])
    assert np.max(np.min(np.linalg.norm(true[:, None] - found[None], axis=2), axis=1)) < 1.0
    assert adjustment(grey, K, D, LAYOUT) is not None


@pytest.mark.parametrize("height_m", [4.0, 10.0, 20.0])
def test_approach_gives_a_rough_position_from_far(height_m):
    X_CP = X_CP_at(height_m, xy=(0.8, -0.5), tilt_deg=(5, -3))
    found = approach(view(X_CP), K, D, LAYOUT)
    assert found is not None
    assert np.linalg.norm(found.p_CP - X_CP.translation()) < 0.03 * height_m  # a few per cent of the range


@pytest.mark.parametrize("shape", ["triangle", "hexagon", "rectangle"])
def test_a_larger_dark_region_that_is_no_quadrilateral_does_not_hide_the_outline(shape):
    """A dark triangle or hexagon larger than the pattern (10 m below), apart from it: not a quadrilateral, it is
    passed over for the next largest region, the outline, as on the clean image. So is a dark 3 : 1 rectangle
    (a vehicle's body): a quadrilateral, but longer against its width than MAX_ASPECT (a square ~50 deg off)."""
    X_CP = X_CP_at(10.0, xy=(0.8, -0.5), tilt_deg=(5, -3))
    grey = view(X_CP)
    polygon = {"triangle": np.array([[60, 380], [260, 380], [160, 200]]),
               "hexagon": cv2.ellipse2Poly((150, 120), (90, 90), 0, 0, 360, 60),
               "rectangle": np.array([[60, 100], [360, 100], [360, 200], [60, 200]])}[shape]
    cv2.fillPoly(grey, [polygon.astype(np.int32)], 30)
    found, clean = approach(grey, K, D, LAYOUT), approach(view(X_CP), K, D, LAYOUT)
    assert found is not None and np.linalg.norm(found.p_CP - clean.p_CP) < 0.01


@pytest.mark.parametrize("fx_pct, fy_pct", [(5.0, 5.0), (5.0, 0.0)])
def test_the_approach_node_weighs_its_centre_by_the_estimators_focal_length(fx_pct, fy_pct):
    """With a focal-length calibration error the node finds the outline with the estimators' intrinsics and
    takes the centre's covariance with their focal length, sqrt(fx fy): 672 px at 5 % on both axes, not the
    renderer's 640; sqrt(672 * 640) = 655.8 px at 5 % on x alone, not fx's 672."""
    camera = replace(CAMERA, calibration_error=CalibrationErrorConfig(fx_pct=fx_pct, fy_pct=fy_pct))
    grey = view(X_CP_at(10.0, xy=(0.8, -0.5)))
    found = approach(grey, camera.K_estimated, camera.D_estimated, LAYOUT)
    measurement = approach_node(grey, 0.0, camera, LAYOUT)
    focal_px = np.sqrt(640.0 * (1 + fx_pct / 100) * 640.0 * (1 + fy_pct / 100))
    np.testing.assert_allclose(measurement.covariance, approach_covariance(found.p_CP, found.side_px, focal_px),
                               rtol=1e-12)


def test_the_adjustment_node_fits_and_weighs_with_the_estimators_intrinsics():
    """With a 5 % focal-length calibration error the node's pose is `adjustment`'s with the estimators' K and D
    (about 5 % deeper than the truth, as the renderer's K would not give), and its covariance is taken through
    their K."""
    camera = replace(CAMERA, calibration_error=CalibrationErrorConfig(fx_pct=5.0, fy_pct=5.0))
    X_CP = X_CP_at(2.5, tilt_deg=(3, -2))
    grey = view(X_CP)
    found = adjustment(grey, camera.K_estimated, camera.D_estimated, LAYOUT)
    measurement = adjustment_node(grey, 0.0, camera, LAYOUT)
    np.testing.assert_array_equal(measurement.view.K, camera.K_estimated)
    np.testing.assert_allclose(measurement.view.X_CP.GetAsMatrix34(), found.X_CP.GetAsMatrix34(), rtol=1e-12)
    depth, true_depth = found.X_CP.translation()[2], X_CP.translation()[2]
    assert depth / true_depth - 1 == pytest.approx(0.05, abs=0.01)
    assert abs(adjustment(grey, K, D, LAYOUT).X_CP.translation()[2] / true_depth - 1) < 0.01


def test_approach_depth_takes_the_focal_length_of_both_axes():
    """A camera whose pixels are not square (fx 640 px, fy 560): the outline's side, sqrt of its area, is the
    geometric mean of its sizes along both axes, and its depth f size / side with f = sqrt(fx fy), within
    `test_approach_depth_near`'s 0.15 % (with fx alone: sqrt(fx / fy) - 1 = 6.9 % too far)."""
    camera = replace(CAMERA, fy=560.0)
    for yaw_deg in (0.0, 45.0):
        X_CP = X_CP_at(3.0, xy=(0.1, -0.05), yaw_deg=yaw_deg)
        found = approach(view(X_CP, camera=camera), camera.K, camera.D, LAYOUT)
        assert found is not None
        assert abs(found.p_CP[2] / X_CP.translation()[2] - 1) < 0.0015, yaw_deg


@pytest.mark.parametrize("height_m", [2.0, 3.0, 4.0, 5.0, 5.5, 6.0])
def test_approach_depth_near_is_within_a_fraction_of_a_per_cent(height_m):
    """Where its border is a few pixels wide (MIN_REFINED_BORDER_PX, to 6.4 m) the outline's corners are its
    fitted sides' crossings: the depth within 0.15 % at any heading to 6 m (from the contour's corners: up to
    0.43 %; at 6.3 m, head-on, 0.156 %). Past 5 m the border is under 4 px wide and the search across it stays
    within its outer half (a search of EDGE_SEARCH_PX reached its inner edge: up to 0.69 % at 6 m)."""
    for yaw_deg in (0.0, 20.0, 45.0, 70.0):
        X_CP = X_CP_at(height_m, xy=(0.1, -0.05), yaw_deg=yaw_deg, tilt_deg=(2, -1))
        found = approach(view(X_CP), K, D, LAYOUT)
        assert found is not None
        assert abs(found.p_CP[2] / X_CP.translation()[2] - 1) < 0.0015, yaw_deg


@pytest.mark.parametrize("height_m", [8.0, 10.0])
def test_approach_depth_far_counts_the_outline_to_its_edge(height_m):
    """Past 6.4 m the outline's corners are the contour's, through its edge pixels' centres, half a pixel
    inside the edge: its side (54-68 px at 8-10 m) is a pixel more than the contour's, which alone puts the
    depth 1.5-1.9 % too far. The depth within 1 %, under that pixel's worth."""
    for yaw_deg in (0.0, 30.0):
        X_CP = X_CP_at(height_m, xy=(0.8, -0.5), yaw_deg=yaw_deg, tilt_deg=(5, -3))
        found = approach(view(X_CP), K, D, LAYOUT)
        assert found is not None
        assert abs(found.p_CP[2] / X_CP.translation()[2] - 1) < 0.01, yaw_deg


@pytest.mark.parametrize("height_m", [0.3, 0.9])
def test_approach_ignores_an_outline_the_image_cuts_and_the_texture_inside_it(height_m):
    assert approach(view(X_CP_at(height_m)), K, D, LAYOUT) is None  # 0.85 m at 0.9 m: taller than the image


def test_approach_ignores_an_outline_the_images_side_cuts():
    """The pattern 3 m below, its left edge 5-25 cm beyond the image's: the dark region's hull runs along the
    image's edge, a quadrilateral whose centre is not the pattern's, and no outline is given. 5 cm inside the
    image's edge, it is."""
    z = 3.0
    left = -CAMERA.cx / CAMERA.fx * z  # the image's left edge at that depth (the lens' distortion aside)
    for cut_m in (0.05, 0.15, 0.25):
        X_CP = X_CP_at(z, xy=(left + LAYOUT.size_m / 2 - cut_m, 0.0), yaw_deg=0.0)
        assert approach(view(X_CP), K, D, LAYOUT) is None, cut_m
    X_CP = X_CP_at(z, xy=(left + LAYOUT.size_m / 2 + 0.05, 0.0), yaw_deg=0.0)
    found = approach(view(X_CP), K, D, LAYOUT)
    assert found is not None and np.linalg.norm(found.p_CP - X_CP.translation()) < 0.03 * z


def test_approach_takes_no_dark_x_for_the_outline():
    """A dark X (two crossed beams, a shadow) larger than the pattern would be, with no pattern in view: its
    hull is a square-ish quadrilateral, but its edges are light, no border's: no outline."""
    grey = np.full((CAMERA.height, CAMERA.width), 200, np.uint8)
    cv2.line(grey, (60, 60), (300, 300), 30, 25)
    cv2.line(grey, (60, 300), (300, 60), 30, 25)
    assert approach(grey, K, D, LAYOUT) is None


def test_approach_takes_no_location_marker_for_the_outline_below_it():
    # Under 0.7 m the outline is out of view and a marker's dark squares are the largest square-ish
    # regions: the white margin inside the outline's border tells them apart.
    for height_m in (0.2, 0.6, 0.7):
        for xy in ((0.0, 0.0), (0.1, 0.05)):
            for yaw_deg in (30, 45, 60):
                assert approach(view(X_CP_at(height_m, xy=xy, yaw_deg=yaw_deg)), K, D, LAYOUT) is None


def test_touchdown_chains_the_pose_through_a_descent_without_markers_in_view():
    # From 1.2 m to 0.2 m over the texture, off the markers after the anchor, turning and drifting.
    poses = [X_CP_at(1.2 - 0.05 * k, xy=(0.02 + 0.004 * k, -0.01 - 0.003 * k), yaw_deg=30.0 + 1.5 * k)
             for k in range(21)]
    images = [view(X) for X in poses]
    tracker = TouchdownTracker(K, D, LAYOUT).anchored(images[0], poses[0])
    worst = (0.0, 0.0)
    for image, X_CP in zip(images[1:], poses[1:]):
        tracker, estimate, features = tracker.track(image)
        assert estimate is not None and features >= 12
        worst = np.maximum(worst, errors(estimate, X_CP))
    assert worst[0] < 0.01 and worst[1] < 1.0, worst
    assert tracker.chained == 20
    assert TouchdownTracker(K, D, LAYOUT).track(images[1])[1] is None  # no anchor, no pose


def test_touchdown_gives_no_pose_from_fewer_inliers_than_min_features():
    """A jump between two frames at 1 m (25 deg of yaw and 10 cm) that the flow mostly loses: the frames'
    homography rests on fewer than min_features (12) RANSAC inliers, and the tracker gives no pose and drops
    its chain (the pose from those 8 inliers was 0.24 m off)."""
    X_before = X_CP_at(1.0, xy=(0.02, -0.01), yaw_deg=30.0)
    X_after = X_CP_at(1.0, xy=(0.12, -0.01), yaw_deg=55.0)
    tracker = TouchdownTracker(K, D, LAYOUT).anchored(view(X_before), X_before)
    tracker, estimate, features = tracker.track(view(X_after))
    assert estimate is None and features < tracker.min_features
    assert tracker.H is None


def point_sampled_square(x0: float, x1: float, y0: float, y1: float, size: int = 80) -> np.ndarray:
    """A dark square on white as a point-sampling renderer draws it (Drake's): a pixel is dark when its
    centre (integer coordinates, OpenCV's) lies inside [x0, x1] x [y0, y1]."""
    c = np.arange(size)
    inside = ((c >= x0) & (c <= x1))[None, :] & ((c >= y0) & (c <= y1))[:, None]
    return np.where(inside, 20, 230).astype(np.uint8)


@pytest.mark.parametrize("x0, y0", [(20.1, 20.1), (20.4, 19.8), (19.7, 20.6)])
def test_sides_along_the_pixel_grid_are_refined_to_the_pixel_boundary(x0, y0):
    """A side along the pixel grid is a step whose gradient is a plateau a pixel wide; the best the
    image tells is the boundary between its last dark and first light pixels, and the refined corners
    are there."""
    x1, y1 = x0 + 30.35, y0 + 29.7
    grey = point_sampled_square(x0, x1, y0, y1)
    contour = np.array([[np.ceil(x0), np.ceil(y0)], [np.ceil(x0), np.floor(y1)], [np.floor(x1), np.floor(y1)],
                        [np.floor(x1), np.ceil(y0)]])
    corners, refined = corners_from_sides(grey, contour[None], 3.0)
    left, right, top, bottom = np.ceil(x0) - 0.5, np.floor(x1) + 0.5, np.ceil(y0) - 0.5, np.floor(y1) + 0.5
    expected = np.array([[left, top], [left, bottom], [right, bottom], [right, top]])
    assert refined[0]
    np.testing.assert_allclose(corners[0], expected, atol=0.02)


def test_a_light_squares_turned_hull_is_refined_to_its_sides():
    """A light square (a location marker's middle one, a hole in the dark mask) loses its corners' pixels
    to a high threshold, and its hull's corners come out turned, up to 2.1 px off (measured on a frame over
    the vehicle, Otsu's threshold 157): the sides' crossings are still the square's."""
    x0, y0 = 20.3, 19.6
    x1, y1 = x0 + 38.6, y0 + 38.5
    grey = 250 - point_sampled_square(x0, x1, y0, y1)
    left, right, top, bottom = np.ceil(x0) - 0.5, np.floor(x1) + 0.5, np.ceil(y0) - 0.5, np.floor(y1) + 0.5
    expected = np.array([[left, top], [left, bottom], [right, bottom], [right, top]])
    turned = expected + [[1.5, 0.1], [-0.5, -1.45], [-1.4, 0.5], [0.5, 2.05]]  # that frame's offsets
    corners, refined = corners_from_sides(grey, turned[None], 3.0)
    assert refined[0]
    np.testing.assert_allclose(corners[0], expected, atol=0.02)


def test_a_contour_farther_from_its_square_than_max_corner_shift_keeps_its_own_corners():
    """A contour 3 px off its square along both axes (its corners 4.2 px off the square's): the square's
    sides are found, within a 5 px search, but their crossings are over MAX_CORNER_SHIFT_PX (3 px) from the
    contour's corners, and the quadrilateral keeps its own, unrefined."""
    x0, y0 = 20.1, 20.1
    x1, y1 = x0 + 30.35, y0 + 29.7
    grey = point_sampled_square(x0, x1, y0, y1)
    left, right, top, bottom = np.ceil(x0) - 0.5, np.floor(x1) + 0.5, np.ceil(y0) - 0.5, np.floor(y1) + 0.5
    square = np.array([[left, top], [left, bottom], [right, bottom], [right, top]])
    contour = square + 3.0
    corners, refined = corners_from_sides(grey, contour[None], 5.0)
    assert not refined[0]
    np.testing.assert_array_equal(corners[0], contour)
    corners, refined = corners_from_sides(grey, (square + 1.5)[None], 5.0)  # 2.1 px off: refined to the square
    assert refined[0]
    np.testing.assert_allclose(corners[0], square, atol=0.02)


def test_the_peak_is_the_centroid_of_its_part_above_half_its_height():
    """An asymmetric peak, a tent rising over 2 px and falling over 1 (sampled every 0.25 px, its kinks on
    samples): its part above half its height is a triangle with corners at -1, 0 and 0.5 px, whose centroid
    is at the corners' mean, -1/6 px (weighed by the whole height of the samples above the half: -0.225 px).
    The mirrored tent's, +1/6 px."""
    offsets = np.arange(-3.0, 3.0 + 1e-9, 0.25)
    tent = np.interp(offsets, [-2.0, 0.0, 1.0], [0.0, 1.0, 0.0])
    profiles = np.array([tent, tent[::-1]])
    peak = np.argmax(profiles, axis=1)
    np.testing.assert_allclose(nodes._peak_centroid(profiles, peak, offsets), [-1 / 6, 1 / 6], atol=1e-12)


RING_K = np.array([[640.0, 0.0, 150.0], [0.0, 640.0, 100.0], [0.0, 0.0, 1.0]])


def ring_image(col: int, row: int, width: int, height: int, thickness: int = 2) -> np.ndarray:
    """A 300 x 200 px grey (230) image with a dark (20) rectangular ring `thickness` px wide, its outer pixels the
    columns col to col + width - 1 and rows row to row + height - 1, light (230) inside."""
    grey = np.full((200, 300), 230, np.uint8)
    grey[row:row + height, col:col + width] = 20
    grey[row + thickness:row + height - thickness, col + thickness:col + width - thickness] = 230
    return grey


@pytest.mark.parametrize("first_col, found", [
    (EDGE_MARGIN_PX, False), (EDGE_MARGIN_PX + 1, True),  # its first dark column
    (300 - 1 - EDGE_MARGIN_PX - 99, False), (300 - 2 - EDGE_MARGIN_PX - 99, True),  # its last: 297, 296
])
def test_approach_refuses_an_outline_within_edge_margin_px_of_the_images_side(first_col, found):
    """A 100 px ring whose outer dark column is EDGE_MARGIN_PX from the image's left side, or whose last is
    EDGE_MARGIN_PX from its right (width - 1 - EDGE_MARGIN_PX), may be cut by it: refused. One column further
    in, it is the outline, its corners on the ring's outer edge (half a pixel outside its outer pixels)."""
    result = approach(ring_image(first_col, 50, 100, 100), RING_K, None, LAYOUT)
    assert (result is not None) == found
    if found:
        box = np.r_[result.corners_px.min(axis=0), result.corners_px.max(axis=0)]
        np.testing.assert_allclose(box, [first_col - 0.5, 49.5, first_col + 99.5, 149.5], atol=0.25)


@pytest.mark.parametrize("width, height", [(81, 51), (51, 81)])
def test_approach_takes_an_outline_of_exactly_max_aspect(width, height):
    """A ring of 81 x 51 px: its contour, through its outer pixels' centres, has sides 80 and 50 px, in the ratio
    MAX_ASPECT exactly (a square seen ~50 deg off its normal): square-ish enough, it is the outline."""
    long, short = max(width, height) - 1, min(width, height) - 1
    assert long == MAX_ASPECT * short
    result = approach(ring_image(100, 60, width, height), RING_K, None, LAYOUT)
    assert result is not None


def test_approach_takes_the_largest_hull_not_the_largest_region():
    """A broken thin outline (a 60 px ring 2 px wide, a 5 px gap in its top side that closing does not bridge),
    far off, around a solid dark 25 px square: the ring's region is smaller (its contour's area 228 px^2) than
    the square's (576), but its hull is the largest: the outline, 60 px a side (the contour's 59 + 1; its border,
    2 px, too narrow for its sides to be refined), not the square's 25."""
    grey = ring_image(120, 70, 60, 60)
    grey[70:72, 148:153] = 230  # the gap
    grey[87:112, 137:162] = 20  # the solid square, inside the ring
    result = approach(grey, RING_K, None, LAYOUT)
    assert result is not None and result.side_px == 60.0


def test_approachs_centre_is_where_the_diagonals_cross():
    """The pattern tilted 30 deg, 2 m away: its centre projects 12.9 px from its corners' mean (perspective). The
    rough position's bearing is the centre's, within a pixel."""
    X_CP = X_CP_at(2.0, tilt_deg=(30, 0))
    points = np.vstack([LAYOUT.outline_corners_P, np.zeros(3)])
    projected = cv2.projectPoints(points, cv2.Rodrigues(X_CP.rotation().matrix())[0], X_CP.translation(), K,
                                  None)[0].reshape(-1, 2)
    assert np.linalg.norm(projected[:4].mean(axis=0) - projected[4]) > 10.0
    found = approach(view(X_CP), K, D, LAYOUT)
    assert found is not None
    bearing, true = found.p_CP[:2] / found.p_CP[2], X_CP.translation()[:2] / X_CP.translation()[2]
    assert np.linalg.norm(bearing - true) < 1.0 / CAMERA.fx


def test_corners_are_ordered_only_when_each_is_its_own():
    """A square along the image's axes (x right, up = -y in the image) comes back top-left, bottom-left,
    bottom-right, top-right; a diamond, its corners on the axes, ties (x - up and x + up are each greatest at two
    corners) and one corner comes out both bottom-right and top-right: None."""
    square = np.array([[10.0, 10.0], [0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    ordered = nodes._ordered(square, np.array([1.0, 0.0]), np.array([0.0, -1.0]))
    np.testing.assert_array_equal(ordered, [[0.0, 0.0], [0.0, 10.0], [10.0, 10.0], [10.0, 0.0]])
    diamond = np.array([[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]])
    assert nodes._ordered(diamond, np.array([1.0, 0.0]), np.array([0.0, -1.0])) is None


def test_the_peaks_run_goes_on_through_samples_at_exactly_half():
    """A profile [0, 2, 4, 2, 3, 0] peaking at index 2 (half 2): the run ends where it dips under the half, at
    indices 0 and 5, so holds 1 to 4, weighed by their heights above the half, 0, 2, 0 and 1: its centroid is
    (2 * 2 + 1 * 4) / 3 = 8/3, the sample at 4 counted though the one at 3 is no higher than the half."""
    centroid = nodes._peak_centroid(np.array([[0.0, 2.0, 4.0, 2.0, 3.0, 0.0]]), np.array([2]), np.arange(6.0))
    np.testing.assert_allclose(centroid, [8 / 3], rtol=1e-12)


def test_touchdown_features_are_taken_on_the_pattern_only():
    """A checkerboard (corners stronger than any of the texture's) beside the pattern, 1.5 m below: the tracker
    anchored there tracks features inside the pattern's outline only, as its homography maps it."""
    X_CP = X_CP_at(1.5)
    grey = view(X_CP)
    cells = (np.arange(80) // 10) % 2
    grey[:80, :80] = np.where(cells[:, None] ^ cells[None, :], 255, 0)
    tracker = TouchdownTracker(K, D, LAYOUT).anchored(grey, X_CP)
    outline = cv2.perspectiveTransform(LAYOUT.outline_corners_P[:, None, :2], tracker.H).reshape(-1, 2)
    assert len(tracker.points) >= tracker.min_features
    for point in undistort_pixels(tracker.points, K, D):
        assert cv2.pointPolygonTest(outline.astype(np.float32), tuple(map(float, point)), True) >= -2.0, point


def test_anchoring_starts_the_chain_afresh():
    """Anchored, tracked a frame (a chain of 1), and anchored again on that frame: its chain is 0 frames long (the
    touchdown measurement widens its covariance with it)."""
    poses = [X_CP_at(1.2), X_CP_at(1.15, xy=(0.054, -0.033), yaw_deg=31.5)]
    images = [view(X) for X in poses]
    tracker = TouchdownTracker(K, D, LAYOUT).anchored(images[0], poses[0])
    tracker, estimate, _ = tracker.track(images[1])
    assert estimate is not None and tracker.chained == 1
    assert tracker.anchored(images[1], poses[1]).chained == 0
