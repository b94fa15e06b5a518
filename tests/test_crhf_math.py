"""Tests of the CRHF mathematics against analytic cases, OpenCV and SciPy."""

import cv2
import numpy as np
import pytest
import scipy.stats
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from scipy.spatial.transform import Rotation

from systems.estimators.crhf_math import (
    NORMAL_GATE,
    CornerNormal,
    PlaneFit,
    arun_rigid_transform,
    corner_normal,
    corners_fit_a_tag,
    crhf_tag_pose,
    direction_after_turn,
    fit_plane,
    focal_lengths_from_touch_points,
    fuse_gaussian,
    fuse_normals,
    intersect_pixel_rays_with_plane,
    mirror_corner_normal,
    plane_beyond_gate,
    plane_through_centroid,
    plane_tilt_covariance,
    principal_point_from_touch_points,
    range_shift,
    residual_gate,
    tangent_basis,
    touch_points,
)
from systems.perception.apriltag import tag_corners_T
from systems.sensors.tof import sensor_positions_C

# Camera intrinsics of seed 000, Eq. 10 (printed transposed there, MATLAB style).
FX, FY, CX, CY = 458.5, 457.855, 258.7735, 252.308
K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
SENSOR_RADIUS = 0.137  # m; Table 4's a = 44.43 px = fx * 0.0969 m per axis, 0.0969 * sqrt(2)
TAG_SIZE = 0.16  # m

# A tilted deck: the tag pose in the camera (T's z points into the tag, away from the camera).
X_CT = RigidTransform(RollPitchYaw(0.2, -0.15, 0.3), [0.05, -0.03, 1.2])


def deck_plane(X_CT):
    """The plane n . p = d of the tag's face, n pointing away from the camera."""
    n = X_CT.rotation().matrix()[:, 2]
    return n, float(n @ X_CT.translation())


def ranges_to_plane(p_C_sensors, n, d):
    """Ranges along +z_C from each sensor to the plane n . p = d."""
    return (d - p_C_sensors @ n) / n[2]


def project(p_C):
    """Pixels of points in C through K, with OpenCV's projectPoints as the reference projection."""
    uv, _ = cv2.projectPoints(p_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, None)
    return uv.reshape(-1, 2)


def test_sensor_positions_follow_eq_21_to_24():
    p = sensor_positions_C(SENSOR_RADIUS)
    np.testing.assert_allclose(np.linalg.norm(p[:, :2], axis=1), SENSOR_RADIUS)
    np.testing.assert_array_equal(p[:, 2], 0.0)
    np.testing.assert_array_equal(np.sign(p[:, :2]), [[-1, -1], [-1, 1], [1, 1], [1, -1]])
    np.testing.assert_allclose(p.sum(axis=0), 0.0, atol=1e-15)


def test_touch_points_add_the_range_along_the_camera_axis():
    p_s = sensor_positions_C(0.1)
    p_t = touch_points(p_s, [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(p_t[:, :2], p_s[:, :2])
    np.testing.assert_array_equal(p_t[:, 2], [1.0, 2.0, 3.0, 4.0])


def test_plane_fit_recovers_an_exact_tilted_plane_from_four_touch_points():
    n, d = deck_plane(X_CT)
    p_s = sensor_positions_C(SENSOR_RADIUS)
    plane = fit_plane(touch_points(p_s, ranges_to_plane(p_s, n, d)))
    assert not plane.degenerate
    np.testing.assert_allclose(plane.normal, n, atol=1e-12)
    assert plane.offset == pytest.approx(d, abs=1e-12)
    assert plane.rms_residual < 1e-12


def test_range_shift_is_the_level_decks_along_the_axis_and_first_order_on_a_tilted_one():
    p_s = sensor_positions_C(SENSOR_RADIUS)
    level = fit_plane(touch_points(p_s, np.full(4, 1.2)))
    V_WC_C = np.array([0.0, 0.0, 0.0, 0.3, -0.2, 0.4])  # sideways over a level deck changes no range
    np.testing.assert_allclose(range_shift(p_s, level, V_WC_C, 0.05), np.full(4, -0.4 * 0.05), atol=1e-15)
    # Turning and moving over the tilted deck of X_CT: against the ranges from the camera moved rigidly
    # (rotation vector w dt, translation v dt, in C), the error is second order in dt.
    n, d = deck_plane(X_CT)
    plane = fit_plane(touch_points(p_s, ranges_to_plane(p_s, n, d)))
    V_WC_C = np.array([0.4, -0.3, 0.2, 0.3, -0.2, 0.4])

    def error(dt):
        """The largest error of the shift over dt, and the largest change of a range."""
        X_C0C1 = RigidTransform(RotationMatrix(Rotation.from_rotvec(V_WC_C[:3] * dt).as_matrix()), V_WC_C[3:] * dt)
        change = ranges_to_plane(p_s, *deck_plane(X_C0C1.inverse().multiply(X_CT))) - ranges_to_plane(p_s, n, d)
        return np.max(np.abs(change - range_shift(p_s, plane, V_WC_C, dt))), np.max(np.abs(change))

    (e1, change), (e2, _) = error(0.05), error(0.025)
    assert e1 < 0.03 * change  # 0.37 mm of a 31 mm change at these rates
    assert e2 == pytest.approx(e1 / 4.0, rel=0.1)


def test_a_world_fixed_direction_after_the_cameras_turn_is_the_exact_rotations_to_first_order():
    # The camera turns by the rotation vector w dt (in C): a direction fixed in the world is then R^T n in its frame.
    n = X_CT.rotation().col(2)
    w = np.array([0.4, -2.0, 0.7])  # rad/s

    def error(dt):
        exact = RotationMatrix(Rotation.from_rotvec(w * dt).as_matrix()).inverse().multiply(n)
        return np.linalg.norm(direction_after_turn(n, w, dt) - exact), np.linalg.norm(exact - n)

    (e1, turned), (e2, _) = error(0.05), error(0.025)
    assert e1 < 0.1 * turned  # a 6.2 deg turn moves n by 5.3 deg; the first-order n is 0.29 deg off
    assert e2 == pytest.approx(e1 / 4.0, rel=0.1)


def test_three_points_fix_a_plane():
    # Fewer than three points are degenerate; three not on one line fix their plane exactly.
    plane = fit_plane(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]))
    assert not plane.degenerate
    np.testing.assert_allclose(plane.normal, [0.0, 0.0, 1.0], atol=1e-15)
    assert plane.offset == pytest.approx(1.0) and plane.rms_residual < 1e-15


def test_plane_fit_orients_the_normal_away_from_the_camera():
    points = np.array([[0, 0, 2.0], [1, 0, 2.0], [0, 1, 2.0], [1, 1, 2.0]])
    plane = fit_plane(points)
    np.testing.assert_allclose(plane.normal, [0, 0, 1], atol=1e-15)
    assert plane.offset == pytest.approx(2.0)


def test_plane_fit_with_noise_is_close_and_reports_the_residual():
    rng = np.random.default_rng(0)
    n, d = deck_plane(X_CT)
    e1 = np.cross(n, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    st = rng.uniform(-0.5, 0.5, size=(2000, 2))
    sigma = 1e-3
    points = d * n + st[:, :1] * e1 + st[:, 1:] * e2 + sigma * rng.standard_normal((2000, 1)) * n
    plane = fit_plane(points)
    assert np.degrees(np.arccos(plane.normal @ n)) < 0.05
    assert plane.offset == pytest.approx(d, abs=2e-4)
    assert plane.rms_residual == pytest.approx(sigma, rel=0.1)


def test_coincident_corners_give_no_normal_instead_of_raising():
    """Four corners on one pixel make OpenCV's SQPnP assert (OpenCV 5.1): no normal and no mirror pose."""
    corners = np.tile([[256.0, 256.0]], (4, 1))
    assert corner_normal(corners, (FX, FY), (CX, CY), tag_corners_T(0.5)) is None
    assert mirror_corner_normal(corners, (FX, FY), (CX, CY), tag_corners_T(0.5), np.array([0.0, 0.0, -1.0])) is None


def test_intrinsics_from_touch_points_recover_the_camera_on_a_tilted_deck():
    n, d = deck_plane(X_CT)
    p_s = sensor_positions_C(SENSOR_RADIUS)
    p_t = touch_points(p_s, ranges_to_plane(p_s, n, d))
    assert np.ptp(p_t[:, 2]) > 0.02  # the ranges really differ
    uv = project(p_t)
    c = principal_point_from_touch_points(p_t, uv)
    np.testing.assert_allclose(c, [CX, CY], atol=1e-9)
    f = focal_lengths_from_touch_points(p_t, uv, c)
    np.testing.assert_allclose(f, [FX, FY], atol=1e-9)


def test_focal_lengths_are_the_mean_of_the_touch_points_not_their_median():
    # Eq. 44 averages: per point fx = (u - cx) Z / X = 400, 400, 400, 440 and fy = 400 each, so fx = 1640 / 4 = 410
    # (a median would give 400).
    p_t = np.array([[0.1, 0.1, 2.0], [-0.1, 0.1, 2.0], [-0.1, -0.1, 2.0], [0.1, -0.1, 2.0]])
    uv = np.array([[340.0, 260.0], [300.0, 260.0], [300.0, 220.0], [342.0, 220.0]])
    np.testing.assert_allclose(focal_lengths_from_touch_points(p_t, uv, [320.0, 240.0]), [410.0, 400.0], atol=1e-9)


def test_focal_length_needs_sensors_off_the_axes():
    p_t = np.array([[0.0, 0.1, 1.0], [-0.1, 0.1, 1.0], [0.1, 0.1, 1.0], [0.1, -0.1, 1.0]])
    with pytest.raises(ValueError, match="axis"):
        focal_lengths_from_touch_points(p_t, np.zeros((4, 2)), [CX, CY])


def test_a_sensor_on_a_camera_axis_gives_an_invalid_pose_not_an_error():
    p_s = sensor_positions_C(SENSOR_RADIUS)
    p_s[0, 0] = 0.0  # sensor 1 on the camera's y axis
    X_CT_true = RigidTransform([0.0, 0.0, 2.0])
    p_T = tag_corners_T(TAG_SIZE)
    ranges = np.full(4, 2.0)
    estimate = crhf_tag_pose(p_s, ranges, project(touch_points(p_s, ranges)),
                             project(np.array([X_CT_true.multiply(p) for p in p_T])), p_T)
    assert not estimate.valid and np.isnan(estimate.focal_lengths).all()


def test_a_corner_ray_that_misses_the_deck_gives_an_invalid_pose_not_an_error():
    """A deck tilted 70 deg about y: the ray of a corner at u = 20 px meets its plane behind the camera, so that
    corner has no point on the deck and the frame is flagged invalid (without raising)."""
    p_s = sensor_positions_C(SENSOR_RADIUS)
    tilt = np.radians(70.0)
    n, d = np.array([np.sin(tilt), 0.0, np.cos(tilt)]), 1.0
    p_t = touch_points(p_s, ranges_to_plane(p_s, n, d))
    uv_corners = np.array([[20.0, 240.0], [300.0, 240.0], [300.0, 270.0], [20.0, 270.0]])
    assert n @ [(20.0 - CX) / FX, 0.0, 1.0] < 0  # so the ray meets n . p = d > 0 at a negative depth
    estimate = crhf_tag_pose(p_s, p_t[:, 2], project(p_t), uv_corners, tag_corners_T(TAG_SIZE),
                             intrinsics=([FX, FY], [CX, CY]))
    assert not estimate.valid and estimate.X_CT.IsExactlyIdentity()
    assert np.isnan(estimate.p_C_corners[[0, 3]]).all() and np.isfinite(estimate.p_C_corners[[1, 2]]).all()


@pytest.mark.parametrize("focal_lengths", [[-FX, FY], [FX, -FY]])
def test_given_intrinsics_with_a_negative_focal_length_give_an_invalid_pose(focal_lengths):
    """A focal length must be positive: given intrinsics with fx or fy < 0 (rays mirrored) are refused, while the
    same frame with the true ones is a valid pose."""
    p_s, p_T = sensor_positions_C(SENSOR_RADIUS), tag_corners_T(TAG_SIZE)
    ranges = np.full(4, 2.0)
    uv_corners = project(np.array([RigidTransform([0.0, 0.0, 2.0]).multiply(p) for p in p_T]))
    args = (p_s, ranges, project(touch_points(p_s, ranges)), uv_corners, p_T)
    assert crhf_tag_pose(*args, intrinsics=([FX, FY], [CX, CY])).valid
    assert not crhf_tag_pose(*args, intrinsics=(focal_lengths, [CX, CY])).valid


def test_given_intrinsics_do_not_validate_a_frame_whose_own_focal_lengths_are_negative():
    """This frame's own focal lengths must be positive too, even where the corners are lifted with given ones: touch
    pixels reflected through the principal point measure (u - cx) Z / X = -fx and -fy (the principal point, their
    mean, stays), and the frame is refused although the given intrinsics would lift its corners."""
    p_s, p_T = sensor_positions_C(SENSOR_RADIUS), tag_corners_T(TAG_SIZE)
    ranges = np.full(4, 2.0)
    uv_corners = project(np.array([RigidTransform([0.0, 0.0, 2.0]).multiply(p) for p in p_T]))
    reflected = 2.0 * np.array([CX, CY]) - project(touch_points(p_s, ranges))
    estimate = crhf_tag_pose(p_s, ranges, reflected, uv_corners, p_T, intrinsics=([FX, FY], [CX, CY]))
    np.testing.assert_allclose(estimate.focal_lengths, [-FX, -FY], rtol=1e-9)
    assert not estimate.valid and estimate.X_CT.IsExactlyIdentity()


def test_ray_plane_intersection_recovers_tag_corners_exactly():
    p_C_corners = np.array([X_CT.multiply(p) for p in tag_corners_T(TAG_SIZE)])
    n, d = deck_plane(X_CT)
    plane = fit_plane(p_C_corners)  # same plane as the deck
    np.testing.assert_allclose(plane.normal, n, atol=1e-12)
    points, valid = intersect_pixel_rays_with_plane(project(p_C_corners), [FX, FY], [CX, CY], plane)
    assert np.all(valid)
    np.testing.assert_allclose(points, p_C_corners, atol=1e-9)


def test_ray_plane_intersection_flags_rays_that_miss():
    # A vertical plane x = 1: the optical axis is parallel to it, rays to the left meet it behind.
    plane = fit_plane(np.array([[1.0, 0, 1], [1, 1, 1], [1, 0, 2], [1, 1, 2]]))
    points, valid = intersect_pixel_rays_with_plane(
        np.array([[CX, CY], [CX - 100, CY], [CX + 100, CY]]), [FX, FY], [CX, CY], plane
    )
    np.testing.assert_array_equal(valid, [False, False, True])
    assert np.all(np.isnan(points[:2]))
    assert points[2, 0] == pytest.approx(1.0)


def test_ray_plane_intersection_flags_a_plane_behind_the_camera():
    # The plane z = -1 (normal +z, offset -1): the optical axis' ray is not parallel to it but meets it at depth -1.
    points, valid = intersect_pixel_rays_with_plane(np.array([[CX, CY]]), [FX, FY], [CX, CY],
                                                    PlaneFit(np.array([0.0, 0.0, 1.0]), -1.0, 0.0, False))
    np.testing.assert_array_equal(valid, [False])
    assert np.all(np.isnan(points))


def test_ray_plane_intersection_flags_a_ray_nearly_parallel_to_the_plane():
    # The plane x = 1 and a ray 1e-13 rad off parallel to it: it meets the plane at a finite depth of about 1e13 m in
    # front of the camera, but its n . r is below 1e-12, so the row is invalid (and NaN).
    plane = PlaneFit(np.array([1.0, 0.0, 0.0]), 1.0, 0.0, False)
    points, valid = intersect_pixel_rays_with_plane(np.array([[320.0 + 4e-11, 240.0]]), [400.0, 400.0],
                                                    [320.0, 240.0], plane)
    np.testing.assert_array_equal(valid, [False])
    assert np.all(np.isnan(points))


def test_tag_corners_are_in_the_detectors_order_and_the_papers_frame():
    # A level tag under a level camera is upright in the image and X_CT = [I, (0, 0, h)] (Sec. 4.1):
    # the corners project to top-left, top-right, bottom-right, bottom-left ...
    uv = project(tag_corners_T(TAG_SIZE) + [0.0, 0.0, 2.0])
    np.testing.assert_array_equal(np.sign(uv - [CX, CY]), [[-1, -1], [1, -1], [1, 1], [-1, 1]])
    # ... which is the order the ArUco detector reports ...
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    image = np.full((200, 200), 255, np.uint8)
    image[50:150, 50:150] = cv2.aruco.generateImageMarker(dictionary, 3, 100)
    corners, _, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(image)
    np.testing.assert_array_equal(
        np.sign(corners[0].reshape(4, 2) - 99.5), [[-1, -1], [1, -1], [1, 1], [-1, 1]]
    )
    # ... and OpenCV's marker frame (IPPE_SQUARE's object points) is T turned by pi about x.
    square = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]]) * TAG_SIZE / 2
    ok, rvec, tvec = cv2.solvePnP(
        square, project(np.array([X_CT.multiply(p) for p in tag_corners_T(TAG_SIZE)])), K, None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    assert ok
    X_C_opencv = RigidTransform(RotationMatrix(cv2.Rodrigues(rvec)[0]), tvec.ravel())
    X_CT_from_opencv = X_C_opencv.multiply(RigidTransform(RotationMatrix.MakeXRotation(np.pi)))
    np.testing.assert_allclose(X_CT_from_opencv.GetAsMatrix4(), X_CT.GetAsMatrix4(), atol=1e-8)


def test_arun_recovers_a_known_transform_and_agrees_with_opencv_and_scipy():
    rng = np.random.default_rng(1)
    R = Rotation.random(random_state=2).as_matrix()
    t = np.array([0.3, -0.2, 1.5])
    p_A = rng.normal(size=(10, 3))
    X_BA = arun_rigid_transform(p_A, p_A @ R.T + t)
    np.testing.assert_allclose(X_BA.rotation().matrix(), R, atol=1e-12)
    np.testing.assert_allclose(X_BA.translation(), t, atol=1e-12)

    p_B = p_A @ R.T + t + 0.01 * rng.normal(size=p_A.shape)
    X_BA = arun_rigid_transform(p_A, p_B)
    # OpenCV's binding always fits Umeyama's scale too, so only its rotation is comparable.
    opencv, _ = cv2.estimateAffine3D(p_A, p_B, force_rotation=True)
    np.testing.assert_allclose(X_BA.rotation().matrix(), opencv[:, :3], atol=1e-9)
    scipy_R, _ = Rotation.align_vectors(p_B - p_B.mean(0), p_A - p_A.mean(0))
    np.testing.assert_allclose(X_BA.rotation().matrix(), scipy_R.as_matrix(), atol=1e-9)


def naive_rotation(p_A, p_B):
    """Arun's rotation without the reflection guard."""
    H = (p_A - p_A.mean(0)).T @ (p_B - p_B.mean(0))
    U, _, Vt = np.linalg.svd(H)
    return Vt.T @ U.T


def test_arun_reflection_guard_on_coplanar_tag_corners():
    p_T = tag_corners_T(TAG_SIZE)
    naive_dets = []
    for seed in range(20):
        R = Rotation.random(random_state=seed).as_matrix()
        p_C = p_T @ R.T + [0.1, 0.2, 1.0]
        naive_dets.append(np.linalg.det(naive_rotation(p_T, p_C)))
        X_CT = arun_rigid_transform(p_T, p_C)
        np.testing.assert_allclose(X_CT.rotation().matrix(), R, atol=1e-9)
        np.testing.assert_allclose(X_CT.translation(), [0.1, 0.2, 1.0], atol=1e-12)
    assert min(naive_dets) == pytest.approx(-1.0)  # the guard was exercised


def test_arun_returns_a_rotation_for_mirrored_points_like_scipy():
    rng = np.random.default_rng(3)
    p_A = rng.normal(size=(8, 3))
    p_B = p_A * [1.0, 1.0, -1.0]  # a mirror image: the best orthogonal map is a reflection
    assert np.linalg.det(naive_rotation(p_A, p_B)) == pytest.approx(-1.0)
    R = arun_rigid_transform(p_A, p_B).rotation().matrix()
    assert np.linalg.det(R) == pytest.approx(1.0)
    scipy_R, _ = Rotation.align_vectors(p_B - p_B.mean(0), p_A - p_A.mean(0))
    np.testing.assert_allclose(R, scipy_R.as_matrix(), atol=1e-9)


def test_arun_rejects_mismatched_inputs():
    with pytest.raises(ValueError, match="N >= 3"):
        arun_rigid_transform(np.zeros((2, 3)), np.zeros((2, 3)))


@pytest.mark.parametrize(
    "X_CT_true",
    [
        X_CT,
        # The paper's static test (Sec. 4.1): level tag 2 m straight below the camera.
        RigidTransform([0.0, 0.0, 2.0]),
    ],
)
def test_crhf_pipeline_recovers_the_tag_pose(X_CT_true):
    p_s = sensor_positions_C(SENSOR_RADIUS)
    n, d = deck_plane(X_CT_true)
    p_t = touch_points(p_s, ranges_to_plane(p_s, n, d))
    p_T = tag_corners_T(TAG_SIZE)
    uv_corners = project(np.array([X_CT_true.multiply(p) for p in p_T]))
    estimate = crhf_tag_pose(p_s, p_t[:, 2], project(p_t), uv_corners, p_T)
    assert estimate.valid
    np.testing.assert_allclose(estimate.focal_lengths, [FX, FY], atol=1e-8)
    np.testing.assert_allclose(estimate.X_CT.GetAsMatrix4(), X_CT_true.GetAsMatrix4(), atol=1e-9)


@pytest.mark.parametrize("scale", [1.0, 1.3])
def test_the_tag_residual_is_zero_on_the_tags_plane_and_grows_with_a_plane_too_deep(scale):
    # A level tag 2 m below; the ranges put the plane at 2 scale metres. The corners' rays meet it at scale
    # times their true points, so the lifted tag is `scale` times too large: the rigid fit leaves each corner
    # (scale - 1) times its distance from the centre, TAG_SIZE / sqrt(2), from the tag's.
    X_CT_true = RigidTransform([0.0, 0.0, 2.0])
    p_s = sensor_positions_C(SENSOR_RADIUS)
    p_T = tag_corners_T(TAG_SIZE)
    uv_corners = project(np.array([X_CT_true.multiply(p) for p in p_T]))
    ranges = np.full(4, 2.0 * scale)
    estimate = crhf_tag_pose(p_s, ranges, project(touch_points(p_s, ranges)), uv_corners, p_T,
                             intrinsics=([FX, FY], [CX, CY]))
    assert estimate.valid
    assert estimate.tag_residual_m == pytest.approx((scale - 1.0) * TAG_SIZE / np.sqrt(2.0), abs=1e-12)


def test_crhf_pipeline_flags_a_missing_range_without_raising():
    p_s = sensor_positions_C(SENSOR_RADIUS)
    estimate = crhf_tag_pose(
        p_s, [1.0, np.nan, 1.0, 1.0], np.full((4, 2), 100.0), np.full((4, 2), 100.0),
        tag_corners_T(TAG_SIZE),
    )
    assert not estimate.valid and estimate.plane.degenerate
    assert estimate.X_CT.IsExactlyIdentity() and np.isnan(estimate.tag_residual_m)


def test_non_finite_corners_give_an_invalid_pose_before_any_intrinsics():
    # A NaN corner pixel: the early return, with neither focal lengths nor a principal point measured.
    p_s = sensor_positions_C(SENSOR_RADIUS)
    n, d = deck_plane(X_CT)
    p_t = touch_points(p_s, ranges_to_plane(p_s, n, d))
    uv_corners = project(np.array([X_CT.multiply(p) for p in tag_corners_T(TAG_SIZE)]))
    uv_corners[0, 0] = np.nan
    estimate = crhf_tag_pose(p_s, p_t[:, 2], project(p_t), uv_corners, tag_corners_T(TAG_SIZE))
    assert not estimate.valid
    assert np.all(np.isnan(estimate.focal_lengths)) and np.all(np.isnan(estimate.principal_point))


@pytest.mark.parametrize("normal", [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.2, 0.9], [-0.6, 0.7, 0.2],
                                    [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
def test_tangent_basis_is_orthonormal_and_perpendicular_to_the_normal(normal):
    n = np.asarray(normal) / np.linalg.norm(normal)
    E = tangent_basis(n)
    np.testing.assert_allclose(E @ E.T, np.eye(2), atol=1e-15)
    np.testing.assert_allclose(E @ n, 0.0, atol=1e-15)


def tilt(n_ref, E, n):
    """Gnomonic tilt of the unit vector n about n_ref in the basis E."""
    return E @ n / (n_ref @ n)


def test_collinear_touch_points_fix_no_plane():
    assert fit_plane(np.array([[0.0, 0.0, 1.0], [0.1, 0.1, 1.1], [0.2, 0.2, 1.2], [0.3, 0.3, 1.3]])).degenerate


@pytest.mark.parametrize("correlated, X", [
    (False, X_CT), (True, X_CT),
    (False, RigidTransform(RollPitchYaw(0.7, 0.0, 0.3), [0.05, -0.03, 1.2])),  # 40 deg: n_z^2 0.59, not n_z's 0.77
])
def test_plane_tilt_covariance_matches_monte_carlo(correlated, X):
    rng = np.random.default_rng(4)
    n, d = deck_plane(X)
    p_s = sensor_positions_C(SENSOR_RADIUS)
    true_ranges = ranges_to_plane(p_s, n, d)
    cov = 0.002**2 * (np.eye(4) + (0.5 * (np.ones((4, 4)) - np.eye(4)) if correlated else 0.0))
    E = tangent_basis(n)
    draws = rng.multivariate_normal(true_ranges, cov, size=20000)
    tilts = np.array([tilt(n, E, fit_plane(touch_points(p_s, r)).normal) for r in draws])
    predicted = plane_tilt_covariance(touch_points(p_s, true_ranges), fit_plane(touch_points(p_s, true_ranges)),
                                      cov, E)
    np.testing.assert_allclose(tilts.mean(axis=0), 0.0, atol=3e-4)
    np.testing.assert_allclose(np.cov(tilts.T), predicted, rtol=0.05, atol=0.05 * np.abs(predicted).max())


def test_corner_normal_is_exact_on_exact_corners_and_its_covariance_matches_monte_carlo():
    p_T = tag_corners_T(TAG_SIZE)
    uv = project(np.array([X_CT.multiply(p) for p in p_T]))
    exact = corner_normal(uv, [FX, FY], [CX, CY], p_T)
    n = X_CT.rotation().matrix()[:, 2]
    np.testing.assert_allclose(exact.normal, n, atol=1e-9)
    assert exact.residual_px2 < 1e-12
    np.testing.assert_allclose(exact.unit_covariance @ n, 0.0, atol=1e-12)  # no spread along n

    rng = np.random.default_rng(5)
    sigma = 0.1  # px: first order holds (at 0.3 px this 60 px tag's mirror pose appears in the tail)
    E = tangent_basis(n)
    draws = [corner_normal(uv + sigma * rng.standard_normal(uv.shape), [FX, FY], [CX, CY], p_T)
             for _ in range(5000)]
    tilts = np.array([tilt(n, E, c.normal) for c in draws])
    predicted = sigma**2 * E @ exact.unit_covariance @ E.T
    np.testing.assert_allclose(np.cov(tilts.T), predicted, rtol=0.1, atol=0.1 * np.abs(predicted).max())
    # The residual has 2 N - 6 = 2 degrees of freedom: its mean over draws is 2 sigma^2.
    assert np.mean([c.residual_px2 for c in draws]) == pytest.approx(2 * sigma**2, rel=0.1)


def test_fuse_gaussian_in_one_dimension_by_hand():
    fused = fuse_gaussian([0.0], [[1.0]], [2.0], [[3.0]])
    # weights 3/4 and 1/4; variance (1 * 3) / (1 + 3); distance 2^2 / (1 + 3)
    np.testing.assert_allclose(fused.mean, [0.5])
    np.testing.assert_allclose(fused.covariance, [[0.75]])
    assert fused.mahalanobis2 == pytest.approx(1.0)


def test_fuse_gaussian_equals_the_information_form_and_lets_an_exact_estimate_win():
    rng = np.random.default_rng(6)
    M1, M2 = rng.normal(size=(2, 2, 2))
    A, B = M1 @ M1.T + 0.1 * np.eye(2), M2 @ M2.T + 0.1 * np.eye(2)
    a, b = rng.normal(size=(2, 2))
    fused = fuse_gaussian(a, A, b, B)
    info = np.linalg.inv(A) + np.linalg.inv(B)
    np.testing.assert_allclose(fused.covariance, np.linalg.inv(info), atol=1e-12)
    np.testing.assert_allclose(fused.mean, np.linalg.solve(info, np.linalg.solve(A, a) + np.linalg.solve(B, b)),
                               atol=1e-12)
    equal = fuse_gaussian(a, A, b, A)
    np.testing.assert_allclose(equal.mean, (a + b) / 2, atol=1e-12)
    np.testing.assert_allclose(equal.covariance, A / 2, atol=1e-12)
    np.testing.assert_allclose(fuse_gaussian(a, A, b, np.zeros((2, 2))).mean, b, atol=1e-12)


def corner_normal_at(n):
    """A corner normal with the given direction and an isotropic unit covariance of 1e-4 rad^2."""
    n = np.asarray(n) / np.linalg.norm(n)
    return n, (1e-4 * (np.eye(3) - np.outer(n, n)))


def fusion_case(corner_direction):
    """A level deck 2 m below the camera, its range covariance giving the same tilt variance 1e-4
    rad^2 on both axes as the corner normal's at a corner variance of 1 px^2."""
    p_s = sensor_positions_C(SENSOR_RADIUS)
    p_t = touch_points(p_s, np.full(4, 2.0))
    plane = fit_plane(p_t)
    unit = plane_tilt_covariance(p_t, plane, np.eye(4), tangent_basis(plane.normal))[0, 0]
    normal, covariance = corner_normal_at(corner_direction)
    return plane, p_t, 1e-4 / unit * np.eye(4), CornerNormal(normal, covariance, 0.0)


def test_fusing_equally_certain_normals_takes_the_mid_tilt_and_keeps_the_ranges_depth():
    plane, p_t, range_covariance, corners = fusion_case([0.02, -0.01, 1.0])
    fused = fuse_normals(plane, p_t, range_covariance, corners, 1.0)
    expected = np.array([0.01, -0.005, 1.0])
    # Exact up to the chart's second order: the corners' covariance grows by (1 + tilt^2) in it.
    np.testing.assert_allclose(fused.normal, expected / np.linalg.norm(expected), atol=1e-5)
    assert fused.normal @ p_t.mean(axis=0) == pytest.approx(fused.offset)  # through the touch points' centroid
    assert fused.offset / fused.normal[2] == pytest.approx(2.0)  # depth on the optical axis kept
    # A corner variance 3 times the unit weighs the corners by 1/4: a quarter of the tilt.
    quarter = fuse_normals(plane, p_t, range_covariance, corners, 3.0)
    expected = np.array([0.005, -0.0025, 1.0])
    np.testing.assert_allclose(quarter.normal, expected / np.linalg.norm(expected), atol=1e-5)


def test_an_exact_corner_normal_within_the_gate_wins_outright():
    # The gnomonic chart theta = E m / (n . m) maps the corners' normal m to the tilt whose n + E^T theta is
    # parallel to m; with zero covariance the corners' tilt is the fused one, so the fused normal is m exactly.
    p_t = touch_points(sensor_positions_C(SENSOR_RADIUS), np.full(4, 2.0))
    plane = fit_plane(p_t)
    tilt = np.radians(10.0)
    m = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    # Within the gate: the level plane's tilt variance is 1e-2 / (4 (r / sqrt 2)^2) per axis (the sensors at
    # (+-r / sqrt 2, +-r / sqrt 2)), so the corners' tilt tan(10 deg) is this many variances squared away.
    assert np.tan(tilt) ** 2 / (1e-2 / (2.0 * SENSOR_RADIUS**2)) < NORMAL_GATE
    fused = fuse_normals(plane, p_t, 1e-2 * np.eye(4), CornerNormal(m, np.zeros((3, 3)), 0.0), 1.0)
    np.testing.assert_allclose(fused.normal, m, atol=1e-9)


def test_a_corner_normal_beyond_the_gate_is_not_fused():
    plane, p_t, range_covariance, corners = fusion_case([0.2, 0.0, 1.0])  # 11 degrees off, sigma 10 mrad
    assert 0.2**2 / 2e-4 > NORMAL_GATE
    assert fuse_normals(plane, p_t, range_covariance, corners, 1.0) is None
    noisier = 2 * 0.2**2 / 1e-4 / NORMAL_GATE  # corners this noisy are within the gate
    assert fuse_normals(plane, p_t, range_covariance, corners, noisier) is not None


@pytest.mark.parametrize("corner_direction", [[0.0, 0.0, -1.0], [0.02, 0.0, -1.0]])
def test_a_corner_normal_facing_the_camera_is_not_fused(corner_direction):
    # The corners' normal in the other half-space from the ranges' is not the tag's plane: no fusion, even where its
    # tilt through the chart (0 here, or 0.02 flipped) would be within the gate.
    plane, p_t, range_covariance, corners = fusion_case(corner_direction)
    assert fuse_normals(plane, p_t, range_covariance, corners, 1.0) is None


def test_the_corners_tilt_variance_grows_by_sec4_of_their_tilt_through_the_chart():
    # Corners tilted a = 30 deg about y: the chart's row along the tilt, (e - tan a n) / cos a, maps their unit
    # tilt to sec^2 a, so a corner variance of 1000 cos^4 a px^2 gives them a tilt variance of
    # 1e-4 * 1000 = 0.1 rad^2, the ranges' at 1000 times fusion_case's covariance. Equally certain: the mid tilt
    # tan(a) / 2, the normal (tan(a) / 2, 0, 1) normalised. (Without the chart's -theta n^T term the corners' variance
    # is 0.1 cos^4 a and they would take 0.64 of the tilt.)
    a = np.radians(30.0)
    plane, p_t, range_covariance, corners = fusion_case([np.tan(a), 0.0, 1.0])
    fused = fuse_normals(plane, p_t, 1000.0 * range_covariance, corners, 1000.0 * np.cos(a) ** 4)
    expected = np.array([np.tan(a) / 2.0, 0.0, 1.0])
    np.testing.assert_allclose(fused.normal, expected / np.linalg.norm(expected), atol=1e-9)


def tilted_tag_on_the_axis(tilt_deg, height):
    """X_CT of a tag centred on the optical axis, tilted about x_C, and its exact corner pixels."""
    X = RigidTransform(RollPitchYaw(np.radians(tilt_deg), 0.0, 0.0), [0.0, 0.0, height])
    return X, project(np.array([X.multiply(p) for p in tag_corners_T(TAG_SIZE)]))


@pytest.mark.parametrize("tilt_deg, height", [(20.0, 2.0), (5.0, 1.2)])
def test_the_mirror_of_a_tag_on_the_axis_is_its_reflection_about_the_line_of_sight(tilt_deg, height):
    # By symmetry a planar PnP's second minimum for a tag centred on the optical axis is the tag tilted the
    # other way; it reprojects the exact corners only approximately (perspective tells them apart).
    X, uv = tilted_tag_on_the_axis(tilt_deg, height)
    p_T = tag_corners_T(TAG_SIZE)
    corners = corner_normal(uv, [FX, FY], [CX, CY], p_T)
    mirror = mirror_corner_normal(uv, [FX, FY], [CX, CY], p_T, corners.normal)
    np.testing.assert_allclose(corners.normal, X.rotation().matrix()[:, 2], atol=1e-9)
    np.testing.assert_allclose(mirror.normal, corners.normal * [1.0, -1.0, 1.0], atol=1e-7)
    assert mirror.residual_px2 > 0.1
    # Asked for the solution far from the mirror's normal, it gives back the true one.
    again = mirror_corner_normal(uv, [FX, FY], [CX, CY], p_T, mirror.normal)
    np.testing.assert_allclose(again.normal, corners.normal, atol=1e-7)
    assert again.residual_px2 < 1e-12


def ranges_and_touch_pixels(n, d):
    """Sensor positions, exact ranges to the plane n . p = d and their touch points' pixels."""
    p_s = sensor_positions_C(SENSOR_RADIUS)
    ranges = ranges_to_plane(p_s, n, d)
    return p_s, ranges, project(touch_points(p_s, ranges))


def test_corners_that_disagree_with_the_ranges_and_have_no_agreeing_mirror_set_the_plane():
    # The ranges see a level surface through the tag's centre (a cone reading around the deck), the corners a
    # tag tilted 15 deg: beyond the gate, and the corners' mirror (tilted -15 deg) agrees with neither, so the
    # corners' normal is taken through the touch points' centroid: the exact pose.
    X, uv = tilted_tag_on_the_axis(15.0, 1.2)
    p_s, ranges, uv_touch = ranges_and_touch_pixels(np.array([0.0, 0.0, 1.0]), 1.2)
    estimate = crhf_tag_pose(p_s, ranges, uv_touch, uv, tag_corners_T(TAG_SIZE),
                             range_covariance=0.005**2 * np.eye(4), corner_variance_px2=0.1)
    assert estimate.valid
    np.testing.assert_allclose(estimate.plane.normal, X.rotation().matrix()[:, 2], atol=1e-9)
    np.testing.assert_allclose(estimate.X_CT.GetAsMatrix4(), X.GetAsMatrix4(), atol=1e-8)
    assert estimate.touch_residual_m < 1e-12  # the touch points' own plane, not the one the corners chose
    assert estimate.plane.rms_residual > 0.02
    # The sensors sit on the diagonals, SENSOR_RADIUS / sqrt(2) off the tilt's axis (x_C): each touch point is
    # that times sin(15 deg) from the tilted plane through their centroid.
    assert estimate.touch_offset_m == pytest.approx(SENSOR_RADIUS / np.sqrt(2.0) * np.sin(np.radians(15.0)),
                                                    abs=1e-12)


@pytest.mark.parametrize("sensor, change", [(0, 0.03), (1, -0.03)], ids=["beyond", "camera-side"])
def test_the_touch_offset_is_the_farthest_touch_point_from_the_plane_taken(sensor, change):
    # As above, with one range 3 cm long (a sensor reading past the deck's edge), or 3 cm short on the other side
    # (the farthest point then between the plane and the camera): the offset the range gate reads is that point's
    # distance, the largest, not the four's mean nor the largest signed one. The plane has the tag's normal
    # n = (0, -sin 15, cos 15) through the touch points' centroid, which the change moves by change / 4 along z_C:
    # the changed point, at y = -r / sqrt 2 (long) or +r / sqrt 2 (short), lies r / sqrt 2 sin 15 + 3/4 |change|
    # cos 15 from it on the side it moved to, the others at most r / sqrt 2 sin 15 + 1/4 |change| cos 15.
    X, uv = tilted_tag_on_the_axis(15.0, 1.2)
    p_s, ranges, _ = ranges_and_touch_pixels(np.array([0.0, 0.0, 1.0]), 1.2)
    ranges[sensor] += change
    estimate = crhf_tag_pose(p_s, ranges, project(touch_points(p_s, ranges)), uv, tag_corners_T(TAG_SIZE),
                             range_covariance=0.005**2 * np.eye(4), corner_variance_px2=0.1)
    assert estimate.valid
    np.testing.assert_allclose(estimate.plane.normal, X.rotation().matrix()[:, 2], atol=1e-9)
    offsets = np.abs(touch_points(p_s, ranges) @ estimate.plane.normal - estimate.plane.offset)
    assert offsets.max() > 1.2 * offsets.mean()
    assert estimate.touch_offset_m == pytest.approx(offsets.max(), abs=1e-12)
    tilt = np.radians(15.0)
    assert estimate.touch_offset_m == pytest.approx(
        SENSOR_RADIUS / np.sqrt(2.0) * np.sin(tilt) + 0.75 * abs(change) * np.cos(tilt), abs=1e-12)


def test_corners_whose_mirror_agrees_with_the_ranges_are_flagged_without_a_previous_frame():
    # The ranges see the plane of the corners' mirror pose: the corners are ambiguous, and with no previous frame
    # nothing tells which plane is the tag's. The frame is flagged, its plane the ranges'.
    _, uv = tilted_tag_on_the_axis(15.0, 1.2)
    count, rvecs, tvecs, _ = cv2.solvePnPGeneric(tag_corners_T(TAG_SIZE), uv.reshape(-1, 1, 2), K, None,
                                                  flags=cv2.SOLVEPNP_IPPE)
    mirror = RigidTransform(RotationMatrix(cv2.Rodrigues(rvecs[1])[0]), tvecs[1].ravel())
    assert count == 2 and mirror.rotation().matrix()[1, 2] > 0.2  # tilted the other way
    p_s, ranges, uv_touch = ranges_and_touch_pixels(*deck_plane(mirror))
    estimate = crhf_tag_pose(p_s, ranges, uv_touch, uv, tag_corners_T(TAG_SIZE),
                             range_covariance=0.005**2 * np.eye(4), corner_variance_px2=0.1)
    assert not estimate.valid
    np.testing.assert_allclose(estimate.plane.normal, mirror.rotation().matrix()[:, 2], atol=1e-9)
    assert estimate.plane.rms_residual < 1e-12


def test_ambiguous_corners_take_whichever_plane_is_nearer_the_previous_frames():
    # As above, the ranges see the plane of the corners' mirror pose. Where the previous frame's deck had the
    # corners' normal (the ranges tilted the mirror's way by cones), the corners' plane is taken: the exact pose;
    # where it had the ranges' (the corners took the wrong one of their two poses), the ranges' plane stays.
    X, uv = tilted_tag_on_the_axis(15.0, 1.2)
    _, rvecs, _, _ = cv2.solvePnPGeneric(tag_corners_T(TAG_SIZE), uv.reshape(-1, 1, 2), K, None,
                                         flags=cv2.SOLVEPNP_IPPE)
    mirror_normal = cv2.Rodrigues(rvecs[1])[0][:, 2]
    p_s, ranges, uv_touch = ranges_and_touch_pixels(mirror_normal, float(mirror_normal @ X.translation()))
    args = (p_s, ranges, uv_touch, uv, tag_corners_T(TAG_SIZE))
    options = dict(range_covariance=0.005**2 * np.eye(4), corner_variance_px2=0.1)
    # The previous deck turned a degree either way from each.
    turned = RotationMatrix(RollPitchYaw(0.0, np.radians(1.0), 0.0)).matrix()
    corners = crhf_tag_pose(*args, previous_normal=turned @ X.rotation().matrix()[:, 2], **options)
    np.testing.assert_allclose(corners.X_CT.GetAsMatrix4(), X.GetAsMatrix4(), atol=1e-8)
    ranges_kept = crhf_tag_pose(*args, previous_normal=turned @ mirror_normal, **options)
    np.testing.assert_allclose(ranges_kept.plane.normal, mirror_normal, atol=1e-9)


def test_on_a_tie_with_the_previous_normal_ambiguous_corners_keep_the_ranges_plane():
    # The ranges' plane tilted 0.2 rad one way, the corners' the other, and their mirror the ranges': ambiguous. The
    # previous deck straight ahead is equally near both (cosine cos 0.2 each): the ranges' plane is kept.
    s, c = np.sin(0.2), np.cos(0.2)
    plane = PlaneFit(np.array([s, 0.0, c]), 2.0 * c, 0.0, False)
    p_s = sensor_positions_C(SENSOR_RADIUS)
    p_t = touch_points(p_s, ranges_to_plane(p_s, plane.normal, 2.0 * c))
    corners = CornerNormal(np.array([-s, 0.0, c]), np.zeros((3, 3)), 0.0)
    mirror = CornerNormal(plane.normal, np.zeros((3, 3)), 0.0)
    kept = plane_beyond_gate(plane, p_t, 1e-6 * np.eye(4), corners, mirror, 1.0, previous_normal=[0.0, 0.0, 1.0])
    assert kept is plane


def test_the_residual_gate_is_the_f_quantile_of_the_pooled_noise_and_tends_to_the_chi_square_one():
    # The residual over twice a variance pooled over d degrees of freedom is F(2, d): SciPy's quantile.
    for dof in (2.0, 10.0, 24.0, 200.0, 1e6):
        assert residual_gate(dof) == pytest.approx(2.0 * scipy.stats.f.ppf(0.999, 2, dof), rel=1e-9)
    assert residual_gate(np.inf) == NORMAL_GATE and residual_gate(1e6) == pytest.approx(NORMAL_GATE, rel=1e-5)
    # The livelier deck with stewart-hardware's sensors, seed 2968811710 at 0.35 s: a 0.457 px^2 residual against
    # 0.030 px^2 pooled from five frames fits (taken as exact, the pool refused it, and the frame was lifted onto the
    # ranges' plane, 11.8 deg off).
    assert corners_fit_a_tag(0.457, 0.030, 10.0) and not corners_fit_a_tag(0.457, 0.030)


def test_the_plane_through_the_centroid_reports_the_rms_distance_of_the_points():
    # A normal of any length is normalised; three points 0.1 below the centroid's depth 1.1, one 0.3 above:
    # RMS sqrt((3 0.1^2 + 0.3^2) / 4) = sqrt(0.03), not the mean distance 0.15.
    plane = plane_through_centroid(np.array([0.0, 0.0, 2.0]),
                                   np.array([[0.1, 0.0, 1.0], [-0.1, 0.0, 1.0], [0.0, 0.1, 1.0], [0.0, -0.1, 1.4]]))
    np.testing.assert_allclose(plane.normal, [0.0, 0.0, 1.0], atol=1e-15)
    assert plane.offset == pytest.approx(1.1, abs=1e-12) and not plane.degenerate
    assert plane.rms_residual == pytest.approx(np.sqrt(0.03), abs=1e-12)


def test_without_a_mirror_or_with_corners_facing_the_camera_the_range_plane_stays():
    plane, p_t, range_covariance, corners = fusion_case([0.2, 0.0, 1.0])
    assert plane_beyond_gate(plane, p_t, range_covariance, corners, None, 1.0) is plane
    far = CornerNormal(*corner_normal_at([-0.2, 0.0, 1.0]), 0.0)
    assert plane_beyond_gate(plane, p_t, range_covariance, corners, far, 1.0).normal[0] > 0.19  # corners taken
    facing = CornerNormal(*corner_normal_at([0.2, 0.0, -1.0]), 0.0)
    assert plane_beyond_gate(plane, p_t, range_covariance, facing, far, 1.0) is plane


def test_corners_that_fit_no_rigid_tag_are_not_fused():
    # One corner 3 px off: the PnP residual (2 dof) is far beyond NORMAL_GATE times a 0.1 px^2 noise, so the plane
    # stays the ranges' exactly; at a noise that explains it the corners are fused and move the plane.
    assert corners_fit_a_tag(NORMAL_GATE * 0.1, 0.1) and not corners_fit_a_tag(NORMAL_GATE * 0.1 + 1e-9, 0.1)
    p_s = sensor_positions_C(SENSOR_RADIUS)
    n, d = deck_plane(X_CT)
    ranges = ranges_to_plane(p_s, n, d) + np.array([0.004, -0.004, 0.004, -0.004])  # a range plane a little off
    uv_corners = project(np.array([X_CT.multiply(p) for p in tag_corners_T(TAG_SIZE)]))
    uv_corners[0] += [3.0, 0.0]
    uv_touch = project(touch_points(p_s, ranges))
    args = (p_s, ranges, uv_touch, uv_corners, tag_corners_T(TAG_SIZE))
    refused = crhf_tag_pose(*args, range_covariance=0.005**2 * np.eye(4), corner_variance_px2=0.1)
    assert refused.corner_residual_px2 > NORMAL_GATE * 0.1
    np.testing.assert_allclose(refused.plane.normal, fit_plane(touch_points(p_s, ranges)).normal, atol=1e-12)
    fused = crhf_tag_pose(*args, range_covariance=0.005**2 * np.eye(4),
                          corner_variance_px2=refused.corner_residual_px2)
    assert not np.allclose(fused.plane.normal, refused.plane.normal, atol=1e-6)


def test_the_pipeline_gates_the_corners_with_the_pooled_variances_degrees_of_freedom():
    """crhf_tag_pose judges the corners by residual_gate(corner_variance_dof): a residual between the exact-variance
    gate (NORMAL_GATE) and the 10-dof one is fused with a variance pooled over 10 dof and not with an exact one."""
    p_s, p_T = sensor_positions_C(SENSOR_RADIUS), tag_corners_T(TAG_SIZE)
    n, d = deck_plane(X_CT)
    ranges = ranges_to_plane(p_s, n, d)
    uv_corners = project(np.array([X_CT.multiply(p) for p in p_T]))
    uv_corners[0] += [3.0, 0.0]  # one corner 3 px off: no rigid tag fits exactly
    residual = corner_normal(uv_corners, [FX, FY], [CX, CY], p_T).residual_px2
    variance = residual / ((NORMAL_GATE + residual_gate(10.0)) / 2)  # the residual midway between the two gates
    args = (p_s, ranges, project(touch_points(p_s, ranges)), uv_corners, p_T)
    options = dict(range_covariance=1e-4 * np.eye(4), corner_variance_px2=variance)
    ranges_normal = fit_plane(touch_points(p_s, ranges)).normal
    exact = crhf_tag_pose(*args, corner_variance_dof=np.inf, **options)
    assert exact.valid and exact.corner_residual_px2 == pytest.approx(residual)
    np.testing.assert_allclose(exact.plane.normal, ranges_normal, atol=1e-12)  # not fused: the ranges' plane
    pooled = crhf_tag_pose(*args, corner_variance_dof=10.0, **options)
    assert pooled.valid and np.degrees(np.arccos(min(1.0, pooled.plane.normal @ ranges_normal))) > 0.5  # fused


def test_crhf_pipeline_with_fusion_and_given_intrinsics_recovers_the_tag_pose():
    p_s = sensor_positions_C(SENSOR_RADIUS)
    n, d = deck_plane(X_CT)
    p_t = touch_points(p_s, ranges_to_plane(p_s, n, d))
    p_T = tag_corners_T(TAG_SIZE)
    uv_corners = project(np.array([X_CT.multiply(p) for p in p_T]))
    uv_touch = project(p_t)
    for variance in (None, 0.1):
        estimate = crhf_tag_pose(p_s, p_t[:, 2], uv_touch, uv_corners, p_T,
                                 range_covariance=0.005**2 * np.eye(4), corner_variance_px2=variance)
        assert estimate.valid and estimate.corner_residual_px2 < 1e-12
        np.testing.assert_allclose(estimate.X_CT.GetAsMatrix4(), X_CT.GetAsMatrix4(), atol=1e-9)
    # Intrinsics given: the corners are lifted with them; the frame's own are still reported.
    wrong = crhf_tag_pose(p_s, p_t[:, 2], uv_touch, uv_corners, p_T, intrinsics=([FX * 1.01, FY], [CX, CY]))
    np.testing.assert_allclose(wrong.focal_lengths, [FX, FY], atol=1e-8)
    assert np.isnan(wrong.corner_residual_px2)
    assert not np.allclose(wrong.X_CT.translation(), X_CT.translation(), atol=1e-4)
