"""Downward camera: rendered tag corners against the pinhole projection of the true corners, the tag
detector on drawn frames, the image view helper, and the pixel-noise system on fixed images."""

import re

import cv2
import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.sensors import ImageRgba8U
from scipy.spatial.transform import Rotation

from models.apriltag import tag_image, tag_plate_scale
from systems.config import ConfigError
from systems.perception.apriltag import AprilTagDetector, TagDetectorSystem
from systems.perception.aruco import subpix_detector
from systems.platforms.stewart import TAG_ABOVE_DECK_M
from systems.sensors.camera import (
    CalibrationErrorConfig,
    CameraConfig,
    NoisyCamera,
    _pixel_grid,
    add_pixel_noise,
    distortion_folds,
    distortion_maps,
    image_to_numpy,
    make_camera,
    motion_blur_flow,
    motion_blur_kernel,
    noise_std_by_level,
    render_margin_px,
    undistort_pixels,
)
from systems.sensors.ground_truth import CameraVelocity, axis_flow
from tests.conftest import render_plane, rgba

# Seed 000 Eq. (10).
K_EQ10 = np.array([[458.5, 0.0, 258.7735], [0.0, 457.855, 252.308], [0.0, 0.0, 1.0]])


def test_default_intrinsics_are_eq_10():
    np.testing.assert_array_equal(CameraConfig().K, K_EQ10)
    assert (CameraConfig().width, CameraConfig().height) == (512, 512)


def true_corners_px(scene) -> np.ndarray:
    """The tag's black-square corners projected with cv2.projectPoints. The corners by hand in the
    deck frame P: the tag lies TAG_ABOVE_DECK_M above the deck; the camera sees the deck's +x to the
    right and its +y upwards in the image, so ArUco's top-left corner is at (-s, +s)."""
    s = scene.config.platform.tag_size_m / 2
    corners_P = np.array([[-s, s, TAG_ABOVE_DECK_M], [s, s, TAG_ABOVE_DECK_M], [s, -s, TAG_ABOVE_DECK_M],
                          [-s, -s, TAG_ABOVE_DECK_M]])
    X_CP = scene.X_WC().inverse().multiply(scene.X_WP_static()).GetAsMatrix4()
    rvec, _ = cv2.Rodrigues(X_CP[:3, :3])
    pixels, _ = cv2.projectPoints(corners_P, rvec, X_CP[:3, 3], K_EQ10, None)
    return pixels.reshape(4, 2)


def rendered(scene, t=0.0) -> np.ndarray:
    context = scene.context(t)
    return image_to_numpy(scene.eval(scene.handles.camera, "color_image", context)).copy()


@pytest.mark.parametrize("scene_name", ["hover_scene", "tilted_scene"])
def test_detected_corners_match_the_projected_true_corners(scene_name, request):
    scene = request.getfixturevalue(scene_name)
    image = rendered(scene)
    assert image.shape == (512, 512, 4) and image.dtype == np.uint8
    detected = AprilTagDetector(scene.config.platform.tag_id).detect(image)
    assert detected is not None
    expected = true_corners_px(scene)
    error = np.linalg.norm(detected - expected, axis=1)
    assert error.max() < 1.0, f"corner errors {error} px"
    if scene_name == "hover_scene":
        # Level deck 2 m under a level camera: a square of side fx * tag / (2 m - plate height), centred
        # on the principal point.
        side = 458.5 * 0.5 / (2.0 - TAG_ABOVE_DECK_M)
        np.testing.assert_allclose(expected[1, 0] - expected[0, 0], side, rtol=1e-12)
        np.testing.assert_allclose(expected.mean(axis=0), [258.7735, 252.308], atol=1e-9)
    else:
        # Not a square any more: the tilt and offset move the tag off-centre and change its sides.
        sides = np.linalg.norm(np.roll(expected, -1, axis=0) - expected, axis=1)
        assert np.ptp(sides) > 3.0 and np.linalg.norm(expected.mean(axis=0) - K_EQ10[:2, 2]) > 10.0


@pytest.mark.parametrize("scene_name", ["hover_scene", "tilted_scene"])
def test_one_threshold_window_finds_the_corners_opencvs_three_windows_find(scene_name, request):
    scene = request.getfixturevalue(scene_name)
    image = rendered(scene)
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    full = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), parameters)
    corners, ids, _ = full.detectMarkers(cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY))
    assert parameters.adaptiveThreshWinSizeMin != parameters.adaptiveThreshWinSizeMax
    assert ids is not None and ids.ravel().tolist() == [scene.config.platform.tag_id]
    one_window = AprilTagDetector(scene.config.platform.tag_id).detect(image)
    # The refinement starts from slightly different contour corners: within 0.02 px of each other.
    np.testing.assert_allclose(one_window, corners[0].reshape(4, 2), atol=0.02)


def test_the_lens_distorts_the_rendered_image_as_opencv_projects(tilted_scene, build_scene):
    # A strong lens (seed 001's, Table 1, moves these corners by a tenth of a pixel).
    distortion = [-0.4, 0.15, 0.01, -0.02, 0.0]
    config = tilted_scene.config
    distorted = build_scene(type(config)(**{**config.__dict__, "camera": CameraConfig(distortion=distortion)}))
    context = distorted.context()
    image = image_to_numpy(distorted.handles.color_image.Eval(distorted.handles.noisy_camera.GetMyContextFromRoot(
        context)))
    detected = AprilTagDetector(config.platform.tag_id).detect(image)
    X_CP = tilted_scene.X_WC().inverse().multiply(tilted_scene.X_WP_static()).GetAsMatrix4()
    s, z = config.platform.tag_size_m / 2, TAG_ABOVE_DECK_M
    corners_P = np.array([[-s, s, z], [s, s, z], [s, -s, z], [-s, -s, z]])
    expected, _ = cv2.projectPoints(corners_P, cv2.Rodrigues(X_CP[:3, :3])[0], X_CP[:3, 3], K_EQ10,
                                    np.array(distortion))
    expected = expected.reshape(4, 2)
    moved = np.linalg.norm(expected - true_corners_px(tilted_scene), axis=1)
    error = np.linalg.norm(detected - expected, axis=1)
    # as close as the undistorted render's corners are to their projection, and far closer than the
    # lens moved them where it moved them most
    assert error.max() < 1.0 and moved.max() > 1.5 and np.all(error[moved > 1.5] < moved[moved > 1.5] / 3)
    # The scene's detector knows the lens: its corners are back in the pinhole image. A model whose k1 is
    # 0.1 off (a poor calibration) leaves them off by about f k1 r^3 (r: normalised radius).
    undistorted = distorted.eval(distorted.handles.detector, "tag_detection", context).corners
    pinhole = true_corners_px(tilted_scene)
    assert np.linalg.norm(undistorted - pinhole, axis=1).max() < 1.0
    wrong_model = TagDetectorSystem(config.platform.tag_id, 512, 512, (K_EQ10, np.array(distortion) + [0.1, 0, 0, 0, 0]))
    wrong_context = wrong_model.CreateDefaultContext()
    wrong_model.get_input_port().FixValue(wrong_context, distorted.handles.color_image.Eval(
        distorted.handles.noisy_camera.GetMyContextFromRoot(context)))
    shift = np.linalg.norm(wrong_model.GetOutputPort("tag_detection").Eval(wrong_context).corners - undistorted, axis=1)
    radius = np.linalg.norm((pinhole - K_EQ10[:2, 2]) / 458.5, axis=1)
    np.testing.assert_allclose(shift, 458.5 * 0.1 * radius**3, rtol=0.3)
    assert shift.max() > 0.5


def test_the_calibration_error_reaches_the_tag_corners_crhf_takes_through_the_estimators_lens_model(tilted_scene):
    """docs/scenarios.md (camera row): the tag detector, whose corners CRHF takes, undistorts them with the
    estimators' K and lens model (the scenes' wiring). Without a lens and a k1, k2 error that is the identity:
    the intrinsics' error leaves the corners as detected; a k1 error alone moves them by about f k1 r^3."""
    image = tilted_scene.eval(tilted_scene.handles.camera, "color_image", tilted_scene.context())
    detected = AprilTagDetector(tilted_scene.config.platform.tag_id).detect(image_to_numpy(image))

    def corners(**error):
        camera = CameraConfig(calibration_error=CalibrationErrorConfig(**error))
        detector = TagDetectorSystem(tilted_scene.config.platform.tag_id, 512, 512,
                                     (camera.K_estimated, camera.D_estimated))
        context = detector.CreateDefaultContext()
        detector.get_input_port().FixValue(context, image)
        return detector.GetOutputPort("tag_detection").Eval(context).corners

    np.testing.assert_array_equal(corners(fx_pct=3.0, fy_pct=-2.0, cx_px=4.0, cy_px=-3.0), detected)
    shift = np.linalg.norm(corners(k1=0.05) - detected, axis=1)
    radius = np.linalg.norm((detected - K_EQ10[:2, 2]) / 458.5, axis=1)
    np.testing.assert_allclose(shift, 458.5 * 0.05 * radius**3, rtol=0.1)
    assert shift.max() > 0.1


def test_the_estimators_intrinsics_are_the_lens_plus_the_calibration_error():
    """K_estimated: each focal length scaled by its per cent error, and the principal point moved by the pixels
    cx_px, cy_px (in their own signs); D_estimated: the lens's k1, k2 plus theirs."""
    camera = CameraConfig(calibration_error=CalibrationErrorConfig(fx_pct=3.0, fy_pct=-2.0, cx_px=4.0, cy_px=-3.0,
                                                                   k1=0.05, k2=-0.01))
    K = camera.K
    np.testing.assert_allclose(camera.K_estimated, [[1.03 * K[0, 0], 0.0, K[0, 2] + 4.0],
                                                    [0.0, 0.98 * K[1, 1], K[1, 2] - 3.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(camera.D_estimated, camera.D + [0.05, -0.01, 0.0, 0.0, 0.0])


def test_the_stewart_scene_tag_corner_model_agrees(tilted_scene):
    # The platform's own tag frame and corners, used by the logs, project to the same pixels.
    from systems.perception.apriltag import project_points

    handles = tilted_scene.handles
    X_CT = tilted_scene.X_WC().inverse().multiply(tilted_scene.X_WP_static()).multiply(handles.platform.X_PT)
    np.testing.assert_allclose(project_points(K_EQ10, X_CT, handles.platform.tag_corners_T()),
                               true_corners_px(tilted_scene), atol=1e-9)


TAG_ID = 3


def drawn_tags(*columns: int) -> ImageRgba8U:
    """A white 240 x 160 RGBA frame with tag36h11 id TAG_ID drawn 80 px wide (its black square the whole 80 px:
    OpenCV's image of the marker is the black square) at rows 40-120 and each of `columns`."""
    tag = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), TAG_ID, 80)
    image = ImageRgba8U(240, 160)
    image.mutable_data[:] = 255
    for column in columns:
        image.mutable_data[40:120, column:column + 80, :3] = tag[..., None]
    return image


def test_two_copies_of_the_tag_are_not_a_detection():
    """The detector finds one tag by id: one copy in the frame gives its corners (the black square's edges at 40 and
    120 px, pixel centres at whole numbers), two copies give None, as does another id."""
    corners = AprilTagDetector(TAG_ID).detect(image_to_numpy(drawn_tags(40)))
    np.testing.assert_allclose(corners, [[39.5, 39.5], [119.5, 39.5], [119.5, 119.5], [39.5, 119.5]], atol=0.2)
    assert AprilTagDetector(TAG_ID).detect(image_to_numpy(drawn_tags(20, 140))) is None
    assert AprilTagDetector(TAG_ID + 1).detect(image_to_numpy(drawn_tags(40))) is None


def tag_outputs(image: ImageRgba8U, time: float, lens=None):
    """The tag detector system's three outputs on `image` at `time`: (tag_detection, tag_corners, tag_detected);
    `lens`: the system's (K, D)."""
    system = TagDetectorSystem(TAG_ID, image.width(), image.height(), lens)
    context = system.CreateDefaultContext()
    context.SetTime(time)
    system.get_input_port().FixValue(context, image)
    return tuple(system.GetOutputPort(name).Eval(context) for name in ("tag_detection", "tag_corners", "tag_detected"))


def test_the_tag_detector_system_outputs_a_tag_and_its_absence():
    """With the tag in view: its detection stamped with the context's time, its corners (u0, v0, ..., u3, v3) and
    detected [1]. On a blank grey frame: no corners, all eight NaN (what the logs count as not detected), and [0]."""
    detection, corners, detected = tag_outputs(drawn_tags(40), 2.5)
    assert detection.detected and detection.time == 2.5
    np.testing.assert_allclose(corners, [39.5, 39.5, 119.5, 39.5, 119.5, 119.5, 39.5, 119.5], atol=0.2)
    assert list(detected) == [1.0]
    blank = ImageRgba8U(240, 160)
    blank.mutable_data[:] = 128
    detection, corners, detected = tag_outputs(blank, 2.5)
    assert not detection.detected and detection.time == 2.5
    assert corners.shape == (8,) and np.isnan(corners).all()
    assert list(detected) == [0.0]


def test_the_tag_detector_system_gives_the_corners_in_the_pinhole_image_of_its_lens_model():
    """A 0.5 m tag 2 m in front of the camera and off its axis (models.apriltag's texture on the plane), imaged
    through a barrel lens (k1 -0.2, remapped onto the pinhole view as NoisyCamera does): the system given the
    lens puts the corners where the detector finds them in the lens-free view and where the pinhole camera K
    projects the true ones (cv2.projectPoints; the refinement pulls a square's corners in by about 0.3 px),
    where the lens has moved them pixels away in the image."""
    lens = CameraConfig(distortion=[-0.2, 0.0, 0.0, 0.0, 0.0])
    s = 0.25  # half the black square [m]
    X_CT = RigidTransform(RotationMatrix.MakeZRotation(0.3), [0.45, 0.35, 2.0])  # facing the camera (R_CT = Rz)
    X_TP = RigidTransform(RotationMatrix.MakeXRotation(np.pi))  # the plate: y up in the tag's image, z out of it
    pinhole = render_plane(tag_image(TAG_ID), tag_plate_scale(2 * s), X_CT.multiply(X_TP), lens, background=255)
    distorted = cv2.remap(pinhole, *distortion_maps(lens), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    corners_T = np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])  # as printed: x right, y down
    X = X_CT.GetAsMatrix4()
    expected = cv2.projectPoints(corners_T, cv2.Rodrigues(X[:3, :3])[0], X[:3, 3], lens.K, None)[0].reshape(4, 2)
    corners = tag_outputs(rgba(distorted), 0.0, lens=(lens.K, lens.D))[0].corners
    assert np.linalg.norm(corners - AprilTagDetector(TAG_ID).detect(pinhole), axis=1).max() < 0.2
    assert np.linalg.norm(corners - expected, axis=1).max() < 0.5
    assert np.linalg.norm(AprilTagDetector(TAG_ID).detect(distorted) - expected, axis=1).max() > 5.0


def test_the_tag_detector_finds_a_faint_blurred_tag_opencvs_three_windows_find():
    """A tag of 25 grey levels from black to white, blurred (sigma 2 px): OpenCV's search over 3, 13 and 23 px
    threshold windows finds it, and so does the detector's one window (23 px: class docstring), at the drawn
    corners (the blur pulls the refined ones in by under half a pixel); a 13 px window alone misses it."""
    grey = image_to_numpy(drawn_tags(40))[..., 0].astype(float)
    faint = cv2.GaussianBlur(np.round(128 + (grey - 127.5) * 25 / 255).astype(np.uint8), (0, 0), 2.0)

    def found(threshold_window_px):
        ids = subpix_detector("DICT_APRILTAG_36h11", threshold_window_px).detectMarkers(faint)[1]
        return ids is not None and TAG_ID in ids.ravel()

    assert found(None) and not found(13)
    np.testing.assert_allclose(AprilTagDetector(TAG_ID).detect(faint),
                               [[39.5, 39.5], [119.5, 39.5], [119.5, 119.5], [39.5, 119.5]], atol=0.5)


def test_image_to_numpy_is_a_view_without_copying():
    image = ImageRgba8U(5, 3)
    view = image_to_numpy(image)
    assert view.shape == (3, 5, 4)
    assert np.shares_memory(view, image.mutable_data)
    image.mutable_data[2, 4, 1] = 77
    assert view[2, 4, 1] == 77


def test_image_to_numpy_of_a_rendered_frame_shares_its_memory(hover_scene):
    context = hover_scene.context()
    image = hover_scene.eval(hover_scene.handles.camera, "color_image", context)
    assert np.shares_memory(image_to_numpy(image), image.data)


def synthetic_image(width=256, height=192) -> ImageRgba8U:
    """A smooth RGB gradient kept within 40..215, so noise of a few levels never saturates."""
    image = ImageRgba8U(width, height)
    y, x = np.mgrid[0:height, 0:width]
    image.mutable_data[..., 0] = 40 + (175 * x / width).astype(np.uint8)
    image.mutable_data[..., 1] = 40 + (175 * y / height).astype(np.uint8)
    image.mutable_data[..., 2] = 128
    image.mutable_data[..., 3] = 255
    return image


def noisy_output(std, t, seed=0, image=None):
    image = image or synthetic_image()
    config = CameraConfig(width=image.width(), height=image.height(), cx=image.width() / 2, cy=image.height() / 2,
                          pixel_noise_std=std)
    camera = NoisyCamera(config, seed)
    context = camera.CreateDefaultContext()
    camera.get_input_port().FixValue(context, image)
    context.SetTime(t)
    return image_to_numpy(image).astype(float), image_to_numpy(camera.get_output_port().Eval(context)).astype(float)


def test_zero_noise_returns_the_rendered_image_unchanged():
    clean, out = noisy_output(0.0, 0.35)
    np.testing.assert_array_equal(out, clean)


@pytest.mark.parametrize("std", [2.0, 6.0])
def test_noise_has_the_requested_std(std):
    clean, out = noisy_output(std, 0.35)
    diff = out - clean
    assert np.std(diff[..., :3]) == pytest.approx(std, rel=0.1)
    assert abs(np.mean(diff[..., :3])) < 0.05 * std
    np.testing.assert_array_equal(diff[..., 3], 0.0)  # alpha untouched
    # Independent per pixel and channel: neighbours are uncorrelated.
    r = diff[..., 0]
    assert abs(np.corrcoef(r[:, :-1].ravel(), r[:, 1:].ravel())[0, 1]) < 0.05
    assert abs(np.corrcoef(diff[..., 0].ravel(), diff[..., 1].ravel())[0, 1]) < 0.05


def test_sensor_noise_is_shot_noise_plus_read_noise():
    # Poisson shot noise: a level v holds v / 255 of the full well, variance = electrons; read noise adds.
    full_well, read = 4000.0, 8.0
    gain = 255.0 / full_well
    for level in (20, 200):
        image = ImageRgba8U(128, 128)
        image.mutable_data[...] = level
        config = CameraConfig(width=128, height=128, cx=64, cy=64, full_well_e=full_well, read_noise_e=read)
        camera = NoisyCamera(config, seed=3)
        context = camera.CreateDefaultContext()
        camera.get_input_port().FixValue(context, image)
        diff = image_to_numpy(camera.get_output_port().Eval(context)).astype(float) - level
        expected = np.sqrt(level * gain + (read * gain) ** 2)
        assert np.std(diff[..., :3]) == pytest.approx(expected, rel=0.1)
        np.testing.assert_array_equal(diff[..., 3], 0.0)
    assert np.sqrt(200 * gain) > 2.5 * np.sqrt(20 * gain)  # the two levels' noise differs clearly


def test_read_noise_is_converted_to_levels_before_squaring():
    # 255 / 2550 = 0.1 levels per electron: 50 e- of read noise is 5 levels (variance 25, not 50 * 0.1^2). Level
    # 128 holds 128 / 255 * 2550 = 1280 e-, shot variance 1280 e-^2 * 0.1^2 = 12.8 levels^2, adding to the 25.
    std = noise_std_by_level(CameraConfig(full_well_e=2550.0, read_noise_e=50.0))
    assert std.shape == (256,)
    assert std[0] == pytest.approx(5.0)
    assert std[128] == pytest.approx(np.sqrt(128 * 0.1 + 5.0**2))


def test_analog_gain_amplifies_fewer_electrons_to_the_same_level():
    # At gain 4 a level holds a quarter of the electrons: shot noise (in levels) doubles, read noise quadruples.
    full_well, read, level = 4000.0, 3.0, 120
    image = ImageRgba8U(128, 128)
    image.mutable_data[...] = level
    std = {}
    for gain in (1.0, 4.0):
        config = CameraConfig(width=128, height=128, cx=64, cy=64, full_well_e=full_well, read_noise_e=read,
                              analog_gain=gain)
        camera = NoisyCamera(config, seed=5)
        context = camera.CreateDefaultContext()
        camera.get_input_port().FixValue(context, image)
        std[gain] = np.std(image_to_numpy(camera.get_output_port().Eval(context))[..., :3].astype(float) - level)
        electrons = level / 255 * full_well / gain
        assert std[gain] == pytest.approx(np.sqrt(electrons + read**2) * gain * 255 / full_well, rel=0.1)
    assert std[4.0] > 1.8 * std[1.0]


def axis_point_flow_by_projection(K, X_WC, V_WC, X_WS, V_WS, dt=1e-5):
    """px/s at which the scene point on the camera's axis moves in the image: that point, carried with the
    plane's frame S for dt, projected by OpenCV into the camera carried for dt (both moved by exact screws)."""
    def moved(X, V):
        turn = RotationMatrix(Rotation.from_rotvec(V[:3] * dt).as_matrix())
        return RigidTransform(turn.multiply(X.rotation()), X.translation() + V[3:] * dt)
    n, p_WC, z_WC = X_WS.rotation().col(2), X_WC.translation(), X_WC.rotation().col(2)
    p_W = p_WC + (n @ (X_WS.translation() - p_WC)) / (n @ z_WC) * z_WC
    p_W_later = moved(X_WS, V_WS).multiply(X_WS.inverse().multiply(p_W))
    p_C_later = moved(X_WC, V_WC).inverse().multiply(p_W_later)
    uv, _ = cv2.projectPoints(p_C_later.reshape(1, 3), np.zeros(3), np.zeros(3), K, None)
    return (uv.ravel() - K[:2, 2]) / dt


@pytest.mark.parametrize("camera_velocity, deck_velocity", [
    ([0.0, 0.6, 0.0, 0.0, 0.0, 0.0], [0.0] * 6),  # the camera turning over a still deck
    ([0.0, 0.0, 0.0, 0.3, -0.2, -0.4], [0.0] * 6),  # sliding and descending
    ([0.0] * 6, [0.3, -0.2, 0.1, 0.1, 0.0, 0.2]),  # the deck rolling, pitching and heaving under it
    ([0.3, -0.2, 1.0, 0.3, 0.1, -0.4], [0.3, -0.2, 0.1, 0.1, 0.0, 0.2]),  # all of it, tilted
])
def test_the_axis_flow_is_how_fast_the_scene_on_the_axis_crosses_the_image(camera_velocity, deck_velocity):
    K, T = CameraConfig().K, 0.01
    tilted = camera_velocity[2] != 0.0
    X_WC = RigidTransform(RollPitchYaw(np.pi + (0.2 if tilted else 0.0), -0.1 if tilted else 0.0, 0.4),
                          [0.1, -0.2, 3.0])  # looking down from 3 m
    X_WS = RigidTransform(RollPitchYaw(0.03, -0.05, 0.2), [0.0, 0.1, 1.0])  # the deck's top, 2 m below
    V_WC, V_WS = np.array(camera_velocity), np.array(deck_velocity)
    expected = axis_point_flow_by_projection(K, X_WC, V_WC, X_WS, V_WS)
    assert np.linalg.norm(expected) > 10.0  # px/s: each case moves the image
    np.testing.assert_allclose(motion_blur_flow(K, axis_flow(X_WC, V_WC, X_WS, V_WS), T), expected * T,
                               rtol=1e-3, atol=1e-6)


def test_a_camera_turning_over_a_still_scene_smears_by_its_rotation_alone():
    K = CameraConfig().K
    X_WC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.0, 0.0, 2.0])
    w_C = np.array([0.3, -0.2, 1.0])  # in C; C's axes are W's turned about x by pi
    rate = axis_flow(X_WC, np.concatenate([X_WC.rotation().multiply(w_C), np.zeros(3)]), RigidTransform(),
                     np.zeros(6))
    np.testing.assert_allclose(motion_blur_flow(K, rate, 1.0), [-K[0, 0] * w_C[1], K[1, 1] * w_C[0]], rtol=1e-12)


def test_no_axis_flow_where_the_axis_misses_the_plane():
    looking_up = RigidTransform([0.0, 0.0, 2.0])  # C's +z is W's +z: away from the ground
    assert np.all(axis_flow(looking_up, np.array([0.0, 1.0, 0.0, 0.5, 0.0, 0.0]), RigidTransform(),
                            np.zeros(6)) == 0.0)


def test_no_axis_flow_from_a_camera_on_the_plane():
    """A camera exactly on the scene plane (depth 0 along its axis) has no scene point ahead to track: the flow
    is zero and finite, not a division by the zero depth, however the camera moves."""
    on_plane = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.3, -0.2, 0.0])  # looking down from z = 0
    for V_WC in (np.array([0.0, 1.0, 0.0, 0.5, 0.0, -0.2]), np.zeros(6)):
        rate = axis_flow(on_plane, V_WC, RigidTransform(), np.zeros(6))
        assert np.all(np.isfinite(rate)) and np.all(rate == 0.0)


def test_a_blur_kernel_is_a_centred_line_of_the_flow_s_length():
    assert motion_blur_kernel(np.array([0.3, 0.2])) is None
    flow = np.array([6.0, -3.0])
    kernel = motion_blur_kernel(flow).astype(float)
    assert kernel.sum() == pytest.approx(1.0)
    centre = kernel.shape[0] // 2
    v, u = np.mgrid[:kernel.shape[0], :kernel.shape[1]] - centre
    np.testing.assert_allclose([np.sum(kernel * u), np.sum(kernel * v)], 0.0, atol=1e-9)
    along = (u * flow[0] + v * flow[1]) / np.linalg.norm(flow)
    across = (u * flow[1] - v * flow[0]) / np.linalg.norm(flow)
    # A uniform segment of length L has variance L^2 / 12 along it (plus the bilinear share's spread).
    assert np.sum(kernel * along**2) == pytest.approx(np.linalg.norm(flow) ** 2 / 12, rel=0.1)
    assert np.sum(kernel * across**2) < 0.2


@pytest.mark.parametrize("length", range(1, 11))
def test_a_blur_kernel_of_a_whole_number_of_pixels_along_either_axis_is_centred(length):
    """Smears of 1 to 10 px along +-x and +-y (even lengths reach the kernel's edge pixels): the kernel holds
    the whole line, sums to 1 and is centred on its middle pixel."""
    for flow in ([length, 0.0], [-length, 0.0], [0.0, length], [0.0, -length]):
        kernel = motion_blur_kernel(np.array(flow)).astype(float)
        assert kernel.sum() == pytest.approx(1.0)
        centre = kernel.shape[0] // 2
        v, u = np.mgrid[:kernel.shape[0], :kernel.shape[1]] - centre
        np.testing.assert_allclose([np.sum(kernel * u), np.sum(kernel * v)], 0.0, atol=1e-6)
        along = u if flow[0] else v
        assert np.abs(along[kernel > 1e-6]).max() == pytest.approx(length / 2, abs=1.0)  # reaches both ends


def test_a_smear_of_half_a_pixel_or_more_blurs():
    """motion_blur_kernel's threshold is half a pixel: under it no kernel, from it on a kernel (a 1 px smear
    blurs)."""
    assert motion_blur_kernel(np.array([0.49, 0.0])) is None
    for flow in ([0.51, 0.0], [0.0, 0.51], [1.0, 0.0], [0.6, 0.8]):
        kernel = motion_blur_kernel(np.array(flow))
        assert kernel is not None and kernel.sum() == pytest.approx(1.0)
    # Exactly half a pixel along u: a kernel, 2 ceil(0.25) + 3 = 5 wide, all on its middle row, symmetric about
    # its centre (the smear reaches a quarter pixel either side).
    kernel = motion_blur_kernel(np.array([0.5, 0.0]))
    assert kernel is not None and kernel.shape == (5, 5)
    row = kernel[2].astype(float)
    assert row.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(row, row[::-1], atol=1e-7)
    assert row[2] > 0.5 and row[1] > 0 and row[0] == 0


def test_the_camera_smears_a_point_along_its_turn_over_the_exposure():
    config = CameraConfig(width=96, height=96, cx=48, cy=48, exposure_s=0.01)
    image = ImageRgba8U(96, 96)
    image.mutable_data[..., :3] = 0
    image.mutable_data[..., 3] = 255
    image.mutable_data[48, 48, :3] = 255
    camera = NoisyCamera(config)
    context = camera.CreateDefaultContext()
    camera.GetInputPort("rendered_image").FixValue(context, image)
    # Unconnected: no smear.
    np.testing.assert_array_equal(image_to_numpy(camera.get_output_port().Eval(context)), image.data)
    camera.GetInputPort("axis_flow").FixValue(context, [-2.0, 0.0])  # a turn of 2 rad/s about y: 9.2 px along u
    out = image_to_numpy(camera.get_output_port().Eval(context))[..., 0].astype(float)
    columns = np.flatnonzero(out.sum(axis=0) > 0)
    assert np.flatnonzero(out.sum(axis=1) > 0).tolist() == [48]
    assert 8 <= columns[-1] - columns[0] <= 11 and out.sum() == pytest.approx(255, abs=12)
    assert "axis_flow" not in [camera_port.get_name() for camera_port in (
        NoisyCamera(CameraConfig()).get_input_port(i) for i in range(NoisyCamera(CameraConfig()).num_input_ports()))]


def test_the_smear_replicates_the_image_s_border():
    """A 4 px smear along u over an image lit (255) in its first column only: beyond the image's edge the scene is
    taken to go on as its border pixel (cv2.BORDER_REPLICATE), so the lit column keeps most of its light (about
    158 of 255, and its neighbour 97) rather than mirroring the dark columns (OpenCV's default: 62 in both). The
    output is the kernel's correlation with the edge-padded image, rounded."""
    config = CameraConfig(width=96, height=96, cx=48, cy=48, exposure_s=0.01)
    image = ImageRgba8U(96, 96)
    image.mutable_data[...] = 0
    image.mutable_data[:, 0, :3] = 255
    image.mutable_data[..., 3] = 255
    camera = NoisyCamera(config)
    context = camera.CreateDefaultContext()
    camera.GetInputPort("rendered_image").FixValue(context, image)
    axis_flow = [4.0 / (config.fx * config.exposure_s), 0.0]
    camera.GetInputPort("axis_flow").FixValue(context, axis_flow)
    out = image_to_numpy(camera.get_output_port().Eval(context)).astype(float)
    kernel = motion_blur_kernel(motion_blur_flow(config.K, np.array(axis_flow), config.exposure_s)).astype(float)
    half = kernel.shape[0] // 2
    padded = np.pad(image_to_numpy(image)[..., 0].astype(float), half, mode="edge")
    expected = sum(kernel[i, j] * padded[i:i + 96, j:j + 96] for i in range(kernel.shape[0])
                   for j in range(kernel.shape[1]))
    assert expected[0, 0] > 150 and expected[0, 1] > 90
    for channel in range(3):
        np.testing.assert_allclose(out[..., channel], expected, rtol=0, atol=0.51)
    np.testing.assert_array_equal(out[..., 3], 255)


def test_same_seed_and_time_give_identical_noise():
    _, a = noisy_output(3.0, 0.25, seed=1)
    _, b = noisy_output(3.0, 0.25, seed=1)
    _, same_frame = noisy_output(3.0, 0.25 + 1e-9, seed=1)  # the same 20 Hz frame index
    _, next_frame = noisy_output(3.0, 0.30, seed=1)
    _, other_seed = noisy_output(3.0, 0.25, seed=2)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, same_frame)
    assert np.mean(a != next_frame) > 0.5
    assert np.mean(a != other_seed) > 0.5


def test_a_blackout_covers_the_frames_on_its_bounds():
    """Frame times are k T in floating point: at 20 Hz the frame meant for 0.6 s comes at 12 * 0.05 =
    0.6000000000000001 s, and a blackout [0.3, 0.6] covers it (before, it came out lit)."""
    image = synthetic_image()
    config = CameraConfig(width=image.width(), height=image.height(), cx=image.width() / 2, cy=image.height() / 2,
                          blackouts_s=[[0.3, 0.6]])
    camera = NoisyCamera(config)
    context = camera.CreateDefaultContext()
    camera.get_input_port().FixValue(context, image)
    covered = []
    for k in range(4, 15):
        context.SetTime(k * config.period_s)
        frame = image_to_numpy(camera.get_output_port().Eval(context))
        covered.append(int(frame[..., :3].max()) == 0)
        if covered[-1]:
            assert int(frame[..., 3].min()) == 255  # a black frame, still opaque
    assert 12 * config.period_s > 0.6
    assert covered == [False] * 2 + [True] * 7 + [False] * 2  # 0.30 to 0.60 s: 7 frames


def test_add_pixel_noise_saturates_instead_of_wrapping():
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[:32] = 255
    noisy = add_pixel_noise(rgba, 20.0, np.random.default_rng(0))
    assert noisy.dtype == np.uint8
    # Near 255, noise only goes down (and no wrap to small values); near 0, only up.
    assert noisy[:32, :, :3].min() > 255 - 6 * 20 and noisy[32:, :, :3].max() < 6 * 20
    assert 0.3 < np.mean(noisy[:32, :, :3] == 255) < 0.7
    assert 0.3 < np.mean(noisy[32:, :, :3] == 0) < 0.7


def test_pixel_noise_has_the_requested_std_to_a_tenth_of_a_percent():
    """A grey 2048 x 2048 image at level 128 with noise std 40 (the draws' tails, 2.9 sigma, stay within 12..244:
    nothing saturates): the 12.6 M draws give their std to about 0.02 %; rounding to whole levels adds 1 / 12
    level^2 of variance. Alpha untouched."""
    rgba = np.full((2048, 2048, 4), 128, np.uint8)
    noisy = add_pixel_noise(rgba, 40.0, np.random.default_rng(0))
    noise = noisy[..., :3].astype(float) - 128
    assert noise.min() > -128 and noise.max() < 127
    assert np.std(noise) == pytest.approx(np.sqrt(40.0**2 + 1 / 12), rel=1e-3)
    assert abs(np.mean(noise)) < 0.06
    np.testing.assert_array_equal(noisy[..., 3], 128)


@pytest.mark.parametrize("shape", [(3, 3, 4), (1, 1, 4), (5, 7, 4)])
def test_add_pixel_noise_takes_images_of_any_size(shape):
    """Random bytes come 8 to a 64-bit word: an image whose byte count is no multiple of 8 (36, 4, 140) takes the
    words that cover it."""
    noisy = add_pixel_noise(np.full(shape, 128, np.uint8), 2.0, np.random.default_rng(0))
    assert noisy.shape == shape and noisy.dtype == np.uint8
    np.testing.assert_array_equal(noisy[..., 3], 128)


@pytest.mark.parametrize("changes, field", [
    ({"fx": 0.0}, "camera.fx"),
    ({"rate_hz": -1.0}, "camera.rate_hz"),
    ({"cx": 600.0}, "camera.cx"),
    ({"far_m": 0.01}, "camera.far_m"),
    # Drake's own limits (before: its RuntimeError at build time): the principal point within the image's pixels,
    # and the depth range, 1 % inside the clipping range at each end, not empty.
    ({"cx": 511.6}, "camera.cx must lie inside the image (-0.5 < cx < width - 0.5"),
    ({"cx": 511.5}, "camera.cx must lie inside the image"),  # the last pixel's outer edge itself
    ({"cy": -0.5}, "camera.cy must lie inside the image"),
    ({"near_m": 1.0, "far_m": 1.015}, "camera.far_m must exceed camera.near_m by over 2 %"),
    ({"pixel_noise_std": -1.0}, "camera.pixel_noise_std"),
    ({"full_well_e": -1.0}, "camera.full_well_e"),
    ({"exposure_s": -0.001}, "camera.exposure_s"),
    ({"exposure_s": 0.06}, "camera.exposure_s"),
    ({"exposure_s": 0.05}, "camera.exposure_s must lie within 0 and the frame period (0.05 s)"),  # = 1 / 20 Hz
    ({"blackouts_s": [[0.3, 0.3]]}, "camera.blackouts_s needs [start, end] pairs"),  # empty: start == end
    ({"read_noise_e": 3.0}, "camera.read_noise_e needs camera.full_well_e"),
    ({"analog_gain": 2.0}, "camera.analog_gain needs camera.full_well_e"),
    ({"analog_gain": 0.5, "full_well_e": 6000.0}, "camera.analog_gain"),
    ({"distortion": [0.1, 0.0]}, "camera.distortion needs 5 numbers"),
    ({"distortion": [-0.9, 0.0, 0.0, 0.0, 0.0]}, "camera.distortion folds the image"),
    # Turns back at r = 1.05 with r_d 0.70, under the corner's 0.80, which itself is never reached.
    ({"distortion": [-0.3, 0.0, 0.0, 0.0, 0.0]}, "camera.distortion folds the image"),
    # Tangential terms that fold it (before: only k1, k2, k3 were checked; 24 % of the image folded back): the
    # round trip names the pixel (before: it guessed "p1, p2 too large?", for radial lenses too).
    ({"distortion": [0.0, 0.0, 0.5, 0.0, 0.0]}, "camera.distortion cannot be inverted to 0.05 px at pixel (0, 0)"),
    ({"distortion": [0.0, 0.0, 0.0, 0.4, 0.0]}, "camera.distortion cannot be inverted to 0.05 px at pixel (0, 511)"),
    # The estimators' own lens model and principal point (before: accepted).
    ({"calibration_error": CalibrationErrorConfig(k1=-0.6)}, "camera.calibration_error"),
    # ... with their own focal lengths: k1 -0.1 at 40 % shorter ones folds at 91 % of the half-diagonal.
    ({"calibration_error": CalibrationErrorConfig(k1=-0.1, fx_pct=-40.0, fy_pct=-40.0)}, "camera.calibration_error"),
    ({"calibration_error": CalibrationErrorConfig(cx_px=1000.0)}, "camera.calibration_error.cx_px"),
    # 258.7735 + 253 = 511.7735, past the last pixel's edge at 511.5.
    ({"calibration_error": CalibrationErrorConfig(cx_px=253.0)}, "camera.calibration_error.cx_px"),
    # 239.5 + 245 = 484.5, past the last row's edge at 479.5 (though inside the width's 639.5).
    ({"width": 640, "height": 480, "cx": 319.5, "cy": 239.5, "calibration_error": CalibrationErrorConfig(cy_px=245.0)},
     "camera.calibration_error.cx_px and cy_px must keep"),
    ({"calibration_error": CalibrationErrorConfig(k1=1.0)}, "camera.calibration_error.k1 must be within +-1"),
    ({"calibration_error": CalibrationErrorConfig(k2=-1.0)}, "camera.calibration_error.k2 must be within +-1"),
    ({"calibration_error": CalibrationErrorConfig(fx_pct=50.0)}, "camera.calibration_error.fx_pct must be within +-50"),
    ({"calibration_error": CalibrationErrorConfig(fy_pct=-50.0)}, "calibration_error.fy_pct must be within +-50"),
])
def test_invalid_configuration_names_the_field(changes, field):
    with pytest.raises(ConfigError, match=re.escape(field)):
        CameraConfig(**changes).validate()


def test_the_pixel_grid_includes_the_last_row_and_column():
    # Every 8th of 512 pixels is 0..504 (64); the border's 511 makes 65 per axis.
    pixels = _pixel_grid(CameraConfig(), 8)
    expected = np.r_[np.arange(0, 512, 8), 511]
    assert pixels.shape == (65 * 65, 2)
    np.testing.assert_array_equal(np.unique(pixels[:, 0]), expected)
    np.testing.assert_array_equal(np.unique(pixels[:, 1]), expected)
    assert [511.0, 511.0] in pixels.tolist()


def test_distortion_folds_is_where_the_radial_map_turns_back_short_of_the_farthest_corner():
    """distortion_folds measures against the farthest corner (the half-diagonal): a k1 lens, r_d = r (1 + k1 r^2),
    turns back at r* = 1 / sqrt(-3 k1), r_d(r*) = 2 r* / 3; with r_d(r*) between the nearest and the farthest
    corner's radius (principal point off-centre) it folds at r_d(r*) / farthest. A k3 lens, r_d = r (1 + k3 r^6),
    turns back at r* = (-1 / (7 k3))^(1/6), r_d(r*) = 6 r* / 7. Mild lenses: 0."""
    config = CameraConfig(cx=150.0, cy=140.0)
    radii = [np.hypot(u / config.fx, v / config.fy) for u in (config.cx, config.width - config.cx)
             for v in (config.cy, config.height - config.cy)]
    nearest, farthest = min(radii), max(radii)
    turn = (nearest + farthest) / 2  # r_d(r*)
    k1 = -1.0 / (3.0 * (1.5 * turn) ** 2)
    assert distortion_folds(config, [k1, 0.0, 0.0, 0.0, 0.0]) == pytest.approx(turn / farthest, rel=1e-3)
    k3 = -1.5
    r_star = (-1.0 / (7.0 * k3)) ** (1.0 / 6.0)
    assert 6.0 / 7.0 * r_star < farthest  # never reaches the farthest corner
    expected = 6.0 / 7.0 * r_star / farthest
    assert distortion_folds(config, [0.0, 0.0, 0.0, 0.0, k3]) == pytest.approx(expected, rel=1e-3)
    for D in ([-0.00908, -0.03128, 0.00109, -0.00198, 0.0], [-0.2, 0.0, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.0, 0.0]):
        assert distortion_folds(CameraConfig(), D) == 0.0


def test_a_k3_that_holds_the_radial_map_up_does_not_fold_it():
    """k1 -0.5, k3 0.5: the slope of r_d = r (1 - 0.5 r^2 + 0.5 r^6), 1 - 1.5 r^2 + 3.5 r^6, is least at r^4 = 1 / 7,
    0.62, and r_d reaches the half-diagonal (0.80) near r = 0.91; without k3's 7 k3 r^6 the slope would reach 0 at
    r = 0.82, short of it. The lens folds nothing and passes."""
    D = [-0.5, 0.0, 0.0, 0.0, 0.5]
    r_least = 7.0**-0.25
    assert 1 - 1.5 * r_least**2 + 3.5 * r_least**6 > 0.6
    assert distortion_folds(CameraConfig(), D) == 0.0
    CameraConfig(distortion=D).validate()


def test_distortion_folds_takes_each_axis_through_its_own_focal_length():
    """fx 500, fy 250, the principal point at 255.5 on a 512 square: the farthest corner is at (256.5 / 500,
    256.5 / 250) in normalised coordinates, radius 1.147 (through fx alone 0.725, which k1 -0.18 reaches before it
    turns). k1 -0.18 turns back at r* = 1 / sqrt(0.54), r_d = 2 r* / 3 = 0.907: at 79 % of the half-diagonal."""
    D = [-0.18, 0.0, 0.0, 0.0, 0.0]
    changes = {"fx": 500.0, "fy": 250.0, "cx": 255.5, "cy": 255.5}
    r_star = 1.0 / np.sqrt(3 * 0.18)
    expected = 2.0 * r_star / 3.0 / np.hypot(256.5 / 500.0, 256.5 / 250.0)
    assert distortion_folds(CameraConfig(**changes), D) == pytest.approx(expected, abs=1e-3)
    with pytest.raises(ConfigError, match=re.escape(
            f"camera.distortion folds the image (its radial map turns back at {expected:.0%} of the half-diagonal)")):
        CameraConfig(distortion=D, **changes).validate()


def test_the_render_margin_covers_the_rows_below_a_high_principal_point():
    """640 x 480, the principal point 100 px from the top, k1 -0.1: the bottom corners, farthest from it, sample
    the pinhole image farthest beyond its edge, below its last row (a barrel lens' undistortion grows with the
    radius, so along each border the corners go farthest). Each corner's pinhole radius r solves
    r (1 + k1 r^2) = r_d (its smallest positive root); the margin is the whole pixels beyond, plus one."""
    k1, f, cx, cy, w, h = -0.1, 500.0, 319.5, 100.0, 640, 480
    config = CameraConfig(width=w, height=h, fx=f, fy=f, cx=cx, cy=cy, distortion=[k1, 0.0, 0.0, 0.0, 0.0])
    corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
    x_d = (corners - [cx, cy]) / f
    r_d = np.linalg.norm(x_d, axis=1)
    r = [min(root.real for root in np.roots([k1, 0.0, 1.0, -rd]) if abs(root.imag) < 1e-12 and root.real > 0)
         for rd in r_d]
    x, y = ([cx, cy] + f * x_d * (np.array(r) / r_d)[:, None]).T
    below = y.max() - (h - 1)
    assert below > max(-x.min(), x.max() - (w - 1), -y.min())  # the bottom rows need the widest margin
    assert render_margin_px(config) == np.ceil(below) + 1


@pytest.mark.parametrize("changes", [{"cx": 511.45}, {"cx": -0.45, "cy": 511.45}, {"near_m": 1.0, "far_m": 1.0203}])
def test_drake_builds_the_camera_at_the_limits_the_check_lets_through(changes):
    config = CameraConfig(**changes)
    config.validate()
    make_camera(config, SceneGraph().world_frame_id(), RigidTransform())


@pytest.mark.parametrize("D", [[-0.2, 0.0, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.0, 0.0], [-0.6, 0.2, 0.0, 0.0, 0.0],
                               [-0.5, 0.0, 0.0, 0.0, 0.5]])
def test_a_lens_that_passes_maps_every_pixel_back_onto_itself(D):
    """Barrel (k1 -0.2: the corner pixels sample the pinhole image at r 0.93, where the map still grows),
    pincushion and a strong barrel lens that does not fold (k1 -0.6, k2 0.2: the radial map's slope stays
    above 0.19; before, undistortion's 40 iterations left its corners 3 px off and validate refused it):
    each distorted pixel's place in the pinhole render, distorted again by OpenCV's own projectPoints, is
    that pixel to 0.01 px, the corners included."""
    config = CameraConfig(distortion=D)
    config.validate()
    map_x, map_y = distortion_maps(config)
    rays = cv2.undistortPoints(np.stack([map_x.ravel(), map_y.ravel()], axis=1).reshape(-1, 1, 2).astype(np.float64),
                               config.K, None)
    back, _ = cv2.projectPoints(cv2.convertPointsToHomogeneous(rays), np.zeros(3), np.zeros(3), config.K, config.D)
    u, v = np.meshgrid(np.arange(config.width), np.arange(config.height))
    np.testing.assert_allclose(back.reshape(-1, 2), np.stack([u.ravel(), v.ravel()], axis=1), atol=0.01)


@pytest.mark.parametrize("D", [[-0.2, 0.0, 0.0, 0.0, 0.0], [-0.6, 0.2, 0.0, 0.0, 0.0],
                               [-0.1, 0.05, 0.002, -0.001, 0.0]])
def test_undistorting_pixels_inverts_opencvs_projection_to_the_image_corners(D):
    """The one undistortion every estimator uses (the tag detector's corners, the RQRLP nodes' pixels): pinhole
    pixels distorted by cv2.projectPoints come back to 1e-6 px, out to the image's corners, also for the strong
    barrel lens that validate accepts (OpenCV's default 5 iterations, or 40, leave its corners pixels off)."""
    config = CameraConfig(distortion=D)
    config.validate()
    corners = np.array([[0.0, 0.0], [config.width - 1.0, 0.0], [0.0, config.height - 1.0],
                        [config.width - 1.0, config.height - 1.0], [config.cx, config.cy], [10.0, 300.0]])
    pinhole = undistort_pixels(corners, config.K, config.D)
    rays = cv2.undistortPoints(pinhole.reshape(-1, 1, 2), config.K, None)
    back, _ = cv2.projectPoints(cv2.convertPointsToHomogeneous(rays), np.zeros(3), np.zeros(3), config.K, config.D)
    np.testing.assert_allclose(back.reshape(-1, 2), corners, atol=1e-6)
    np.testing.assert_array_equal(undistort_pixels(corners, config.K, None), corners)


def _checkerboard(x_n: np.ndarray, y_n: np.ndarray) -> np.ndarray:
    """A scene known at every ray: squares 0.05 wide in normalised image coordinates (x/z, y/z)."""
    return np.where((np.floor(x_n / 0.05) + np.floor(y_n / 0.05)) % 2 == 0, 230, 25).astype(np.uint8)


@pytest.mark.parametrize("D, size", [([-0.00908, -0.03128, 0.00109, -0.00198, 0.0], {}),
                                     ([-0.2, 0.0, 0.0, 0.0, 0.0], {}),
                                     ([-0.2, 0.0, 0.0, 0.0, 0.0], {"width": 256, "cx": 127.5})])  # taller than wide
def test_a_barrel_lens_images_the_scene_out_to_its_rim(D, size):
    """The pinhole render is render_margin_px wider on every side (make_camera), so the distorted image's rim,
    which looks beyond a same-size render, is the scene's: each output pixel equals the scene at its ray
    (exact undistortion) but where the bilinear sample straddles a square's edge. Before: the rim replicated
    the render's edge (stewart-hardware's lens: 1.9 % of the image; k1 -0.2: 16 %, a third of it wrong). A camera
    taller than wide needs its margin for the top and bottom rows."""
    config = CameraConfig(distortion=D, **size)
    config.validate()
    m = render_margin_px(config)
    info = make_camera(config, SceneGraph().world_frame_id(), RigidTransform()).default_color_render_camera().core(
        ).intrinsics()
    assert (info.width(), info.height()) == (config.width + 2 * m, config.height + 2 * m)
    assert (info.center_x(), info.center_y()) == (config.cx + m + 0.5, config.cy + m + 0.5)  # Drake's half pixel
    u, v = np.meshgrid(np.arange(info.width(), dtype=float), np.arange(info.height(), dtype=float))
    rendered = ImageRgba8U(info.width(), info.height())
    rendered.mutable_data[..., :3] = _checkerboard((u - config.cx - m) / config.fx, (v - config.cy - m) / config.fy)[
        ..., None]
    rendered.mutable_data[..., 3] = 255
    camera = NoisyCamera(config, 0)
    context = camera.CreateDefaultContext()
    camera.GetInputPort("rendered_image").FixValue(context, rendered)
    out = camera.get_output_port().Eval(context).data[..., 0].astype(int)
    u, v = np.meshgrid(np.arange(config.width, dtype=float), np.arange(config.height, dtype=float))
    rays = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2), config.K, config.D, None,
                               None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)).reshape(-1, 2)
    truth = _checkerboard(rays[:, 0], rays[:, 1]).reshape(out.shape).astype(int)
    map_x, map_y = distortion_maps(config)
    rim = (map_x < 0) | (map_x > config.width - 1) | (map_y < 0) | (map_y > config.height - 1)
    assert rim.mean() > 0.01  # the rim is there to test
    edge = np.ones(out.shape, bool)  # pixels whose bilinear sample does not straddle a square's edge
    for du, dv in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        edge &= np.roll(truth, (dv, du), axis=(0, 1)) == truth
    assert np.mean(np.abs(out - truth)[rim & edge] > 60) < 0.01


def test_camera_velocity_adds_the_lever_arm_and_turns_into_the_camera_frame():
    X_BC = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.1, 0.0, -0.04])
    system = CameraVelocity(X_BC)
    context = system.CreateDefaultContext()
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2), [1.0, 2.0, 3.0])
    system.GetInputPort("X_WB").FixValue(context, X_WB)
    # Descending at 0.4 m/s, yawing at 1 rad/s: the camera, 0.1 m ahead (W +y after the yaw), moves
    # 0.1 m/s towards W -x, and along its optical axis (W -z) at 0.4 m/s.
    system.GetInputPort("V_WB").FixValue(context, [0.0, 0.0, 1.0, 0.0, 0.0, -0.4])
    V_WC_C = system.GetOutputPort("V_WC_C").Eval(context)
    R_WC = X_WB.rotation().multiply(X_BC.rotation())
    np.testing.assert_allclose(R_WC.multiply(V_WC_C[3:]), [-0.1, 0.0, -0.4], atol=1e-12)
    assert V_WC_C[5] == pytest.approx(0.4)
    np.testing.assert_allclose(V_WC_C[:3], [0.0, 0.0, -1.0], atol=1e-12)  # the yaw about W +z is about C -z


def test_camera_velocity_is_turned_by_the_inverse_of_the_camera_s_rotation():
    """A camera on B's origin, B yawed +90 deg: R_CW = Rz(-90 deg) takes W's +x to C's -y and W's +y to C's +x
    (a rotation that is not its own inverse, unlike the X-rotation by pi of the test above)."""
    system = CameraVelocity(RigidTransform())
    context = system.CreateDefaultContext()
    system.GetInputPort("X_WB").FixValue(context, RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2), [1.0, 2.0, 3.0]))
    system.GetInputPort("V_WB").FixValue(context, [0.0, 2.0, 0.0, 1.0, 0.0, 0.0])  # w along W +y, v along W +x
    np.testing.assert_allclose(system.GetOutputPort("V_WC_C").Eval(context), [2.0, 0.0, 0.0, 0.0, -1.0, 0.0],
                               atol=1e-12)
