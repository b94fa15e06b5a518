"""The fisheye camera (seed 003 section 2.1): the analytic model against cv2.fisheye, the face layout's
coverage, the composition on analytic face images, and rendered markers against
cv2.fisheye.projectPoints (the scene: diagrams/fisheye_markers.py)."""

import cv2
import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.geometry import SceneGraph
from pydrake.math import RollPitchYaw
from pydrake.systems.sensors import ImageRgba8U

from diagrams.fisheye_markers import BACKGROUND, MarkerScene, blob_centroids, marker_points_C, projection_errors
from systems.config import ConfigError
from systems.sensors.fisheye import (
    BLACK,
    FACE_MARGIN_PX,
    FACE_NAMES,
    FisheyeCamera,
    FisheyeConfig,
    distortion_fold_deg,
    face_rotations,
    fisheye_layout,
    in_field_of_view,
    make_face_sensor,
    pixel_rays,
    project_points,
    rectified_K,
    rectify,
    rectify_maps,
)

# Tolerances from measurement (benchmarks/fisheye.py, default config): mean 0.059 px, max 0.182 px (at
# 74 deg, where the 75 deg rim clips the blob); forgetting Drake's half-pixel offset gives mean 0.49 px.
MEAN_TOLERANCE_PX = 0.25
MAX_TOLERANCE_PX = 0.5


def synthetic_face_images(layout) -> list[np.ndarray]:
    """Face images painted from a smooth function of the ray's direction in C (`direction_colour`)."""
    images = []
    for face in layout.faces:
        u, v = np.meshgrid(np.arange(face.width, dtype=float), np.arange(face.height, dtype=float))
        rays_F = np.stack([(u - face.cx) / face.focal_px, (v - face.cy) / face.focal_px, np.ones_like(u)], axis=-1)
        rays_C = rays_F @ face.R_CF.matrix().T
        images.append(direction_colour(rays_C / np.linalg.norm(rays_C, axis=-1, keepdims=True)))
    return images


def direction_colour(rays: np.ndarray) -> np.ndarray:
    """RGBA uint8 of unit rays (..., 3): each channel linear in one component."""
    rgb = np.clip(np.rint(127.5 + 120.0 * rays), 0, 255)
    return np.concatenate([rgb, np.full(rgb.shape[:-1] + (1,), 255.0)], axis=-1).astype(np.uint8)


# ---------------------------------------------------------------- the model


def test_default_intrinsics_fit_150_deg_into_512_px():
    config = FisheyeConfig()
    config.validate()
    assert (config.width, config.height, config.fov_deg) == (512, 512, 150.0)
    # r = f theta (1 + k1 theta^2 + k2 theta^4) at 75 deg, by hand.
    theta = np.radians(75.0)
    radius = 200.0 * theta * (1 - 0.02 * theta**2 + 0.001 * theta**4)
    assert radius == pytest.approx(config.radius_px) and 250 < radius < 256


def test_projection_is_opencvs_equidistant_model_and_the_ray_inverts_it():
    config = FisheyeConfig()
    rng = np.random.default_rng(3)
    theta = rng.uniform(0.0, config.theta_max, 500)
    phi = rng.uniform(-np.pi, np.pi, 500)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    distance = rng.uniform(0.5, 20.0, (500, 1))
    pixels = project_points(distance * rays, config)
    r = config.f * theta * (1 + config.k1 * theta**2 + config.k2 * theta**4)
    by_hand = np.column_stack([config.cx + r * np.cos(phi), config.cy + r * np.sin(phi)])
    np.testing.assert_allclose(pixels, by_hand, atol=1e-9)
    angle = np.arccos(np.clip(np.sum(pixel_rays(pixels, config) * rays, axis=1), -1.0, 1.0))
    assert angle.max() < 1e-7
    assert in_field_of_view(pixels, config).all()
    assert not in_field_of_view(project_points([[np.sin(1.32), 0.0, np.cos(1.32)]], config), config).any()


def test_the_field_of_view_circle_is_centred_on_the_principal_point():
    """in_field_of_view is whether a pixel's ray lies within fov_deg / 2 of the optical axis, also with the
    principal point off the image centre and cx != cy: rays just inside and just outside the field of view, all
    round the axis, projected by OpenCV's fisheye model, fall inside and outside the circle."""
    config = FisheyeConfig(cx=300.0, cy=200.0)
    half = np.radians(config.fov_deg / 2)
    phi = np.linspace(-np.pi, np.pi, 72, endpoint=False)
    for theta, expected in ((half - 0.01, True), (half + 0.01, False)):
        rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                np.full_like(phi, np.cos(theta))])
        inside = in_field_of_view(project_points(rays, config), config)
        assert np.all(inside == expected), np.degrees(phi[inside != expected])


def test_a_pixel_exactly_on_the_circle_is_in_view():
    """The circle's radius is the module docstring's f theta_d(75 deg) = 253.6 px (by hand), and a pixel exactly
    that far from the principal point, right of it or above it, is within the field of view (<=, not <)."""
    config = FisheyeConfig()
    theta = np.radians(75.0)
    assert config.radius_px == pytest.approx(200.0 * theta * (1 - 0.02 * theta**2 + 0.001 * theta**4), rel=1e-12)
    assert config.radius_px == pytest.approx(253.596, abs=1e-3)
    on_circle = [[config.cx + config.radius_px, config.cy], [config.cx, config.cy - config.radius_px]]
    assert in_field_of_view(on_circle, config).all()


def test_a_distortion_whose_slope_reaches_zero_at_the_rim_folds_there():
    """With k2 = 0 and k1 = -1 / (3 theta_max^2), theta_d = theta (1 + k1 theta^2) has slope 1 + 3 k1 theta^2 = 0
    exactly at the field's edge, 75 deg (the float sum is exactly 0.0 there): theta_d stops growing at the rim, a
    fold (slope <= 0, not only < 0), and the config is refused."""
    config = FisheyeConfig(k2=0.0)
    config.k1 = -1 / (3 * config.theta_max**2)  # about -0.1945
    assert 1 + 3 * config.k1 * config.theta_max**2 == 0.0
    assert distortion_fold_deg(config) == pytest.approx(75.0)
    with pytest.raises(ConfigError, match="fold"):
        config.validate()

# ---------------------------------------------------------------- the faces and the composition


def test_every_pixel_of_the_circle_has_a_face_and_none_outside():
    config = FisheyeConfig()
    layout = fisheye_layout(config)
    u, v = np.meshgrid(np.arange(config.width), np.arange(config.height))
    inside = in_field_of_view(np.column_stack([u.ravel(), v.ravel()]), config).reshape(u.shape)
    np.testing.assert_array_equal(layout.face_of_pixel >= 0, inside)
    assert set(np.unique(layout.face_of_pixel[inside])) == set(range(5))
    for index, face in enumerate(layout.faces):
        uv = layout.face_uv[layout.face_of_pixel == index]
        # Bilinear interpolation reads (floor, floor + 1): inside the render, with the margin.
        assert uv.min() >= FACE_MARGIN_PX - 1e-9
        assert (uv[:, 0].max() <= face.width - 1 - FACE_MARGIN_PX + 1e-9
                and uv[:, 1].max() <= face.height - 1 - FACE_MARGIN_PX + 1e-9)
    # Far fewer pixels rendered than five full cube faces.
    assert sum(face.width * face.height for face in layout.faces) < 0.5 * 5 * config.face_px**2


def test_the_faces_look_down_and_towards_the_images_right_bottom_left_and_top():
    """The module docstring: `down` along the optical axis (+z_C), the side faces side_axis_deg (60) off it towards
    the image's right (+x_C), bottom (+y_C), left (-x_C) and top (-y_C), in FACE_NAMES' order."""
    s, c = np.sin(np.radians(60.0)), np.cos(np.radians(60.0))
    expected = {"down": [0.0, 0.0, 1.0], "right": [s, 0.0, c], "bottom": [0.0, s, c], "left": [-s, 0.0, c],
                "top": [0.0, -s, c]}
    rotations = face_rotations(FisheyeConfig())
    assert len(rotations) == len(FACE_NAMES) == 5
    for name, R_CF in zip(FACE_NAMES, rotations):
        np.testing.assert_allclose(R_CF.col(2), expected[name], atol=1e-12, err_msg=name)


def test_each_face_sensor_sits_at_the_fisheyes_centre_turned_by_its_face_rotation():
    """Each face's RgbdSensor pose on the body is X_BF = X_BC [R_CF, 0] (not [R_CF, 0] X_BC): its origin is the
    fisheye's mount point and its axes are R_BC R_CF, with a mount both turned and moved off the body origin."""
    config = FisheyeConfig(mount_xyz_m=[0.1, -0.2, 0.3], mount_rpy_deg=[170.0, 10.0, 30.0])
    R_BC = RollPitchYaw(np.radians([170.0, 10.0, 30.0])).ToRotationMatrix().matrix()
    body = SceneGraph().world_frame_id()
    for face in fisheye_layout(config).faces:
        X_BF = make_face_sensor(face, config, body).default_X_PB()
        np.testing.assert_allclose(X_BF.translation(), [0.1, -0.2, 0.3], atol=1e-12, err_msg=face.name)
        np.testing.assert_allclose(X_BF.rotation().matrix(), R_BC @ face.R_CF.matrix(), atol=1e-12, err_msg=face.name)


def fixed_camera(config, face_images):
    camera = FisheyeCamera(config)
    context = camera.CreateDefaultContext()
    for index, image in enumerate(face_images):
        value = ImageRgba8U(image.shape[1], image.shape[0])
        value.mutable_data[:] = image
        camera.get_input_port(index).FixValue(context, value)
    return camera, context


@pytest.mark.parametrize("config", [FisheyeConfig(), FisheyeConfig(fov_deg=50.0), FisheyeConfig(cx=450.0)])
def test_composition_of_analytic_faces_matches_the_rays(config):
    """Faces painted from the ray's direction compose into the same function of each fisheye pixel's
    ray: the face frames, intrinsics and tables agree with the model, seams included. Also where a face serves
    no pixel: the side faces (60 deg off the axis) beyond a 50 deg field of view, or the side of the circle
    that a principal point far off the centre puts beyond the image (before: an empty array's minimum)."""
    camera, context = fixed_camera(config, synthetic_face_images(fisheye_layout(config)))
    image = camera.GetOutputPort("color_image").Eval(context).data
    layout = camera.layout
    inside = layout.face_of_pixel >= 0
    rows, cols = np.nonzero(inside)
    expected = direction_colour(pixel_rays(np.column_stack([cols, rows]), config))
    difference = np.abs(image[inside].astype(int) - expected.astype(int))
    # Each channel moves at most 120 levels per radian; the remap's 1/32 px steps and rounding give <= 2.
    assert difference.max() <= 2, difference.max()
    assert (image[~inside] == BLACK).all()


@pytest.mark.parametrize("config", [FisheyeConfig(), FisheyeConfig(cx=300.0, cy=220.0, k1=0.0, k2=0.0)])
def test_rectified_view_is_the_pinhole_view_with_the_new_K(config):
    """The rectified view painted from directions is `direction_colour` of K_new's pinhole rays, with the camera's
    own intrinsics: also with the principal point off the image centre and no distortion (k1 = k2 = 0)."""
    camera, context = fixed_camera(config, synthetic_face_images(fisheye_layout(config)))
    rectified = camera.GetOutputPort("rectified_image").Eval(context).data
    K_new = rectified_K(config)
    u, v = np.meshgrid(np.arange(config.width, dtype=float), np.arange(config.height, dtype=float))
    rays = np.stack([(u - K_new[0, 2]) / K_new[0, 0], (v - K_new[1, 2]) / K_new[1, 1], np.ones_like(u)], axis=-1)
    expected = direction_colour(rays / np.linalg.norm(rays, axis=-1, keepdims=True))
    assert np.abs(rectified.astype(int) - expected.astype(int)).max() <= 3
    # The maps are OpenCV's: a rectified pixel reads the fisheye where projectPoints puts its ray.
    maps = cv2.convertMaps(*rectify_maps(config), cv2.CV_32FC1)
    np.testing.assert_allclose(np.column_stack([maps[0][100, 300], maps[1][100, 300]]),
                               project_points(rays[100, 300], config), atol=0.05)


@pytest.mark.parametrize("config", [FisheyeConfig(), FisheyeConfig(width=640, height=480, cx=300.0, cy=250.0)])
def test_the_optical_axis_lands_on_the_rectified_image_centre(config):
    """A blob on the fisheye's optical axis (at its principal point) appears at the rectified view's centre,
    ((width - 1) / 2, (height - 1) / 2) in OpenCV's pixel coordinates (pixel centres at integers), wherever the
    fisheye's own principal point lies; the rectified view is width x height (not height x width)."""
    u, v = np.meshgrid(np.arange(config.width, dtype=float), np.arange(config.height, dtype=float))
    dip = np.exp(-((u - config.cx) ** 2 + (v - config.cy) ** 2) / (2 * 2.0**2))  # a Gaussian, sigma 2 px
    fisheye = np.zeros((config.height, config.width, 4), np.uint8)
    fisheye[..., :3], fisheye[..., 3] = BACKGROUND, 255
    fisheye[..., 1] = np.rint(BACKGROUND[1] * (1 - dip))  # blob_centroids weighs the green channel's dip
    centre = np.array([(config.width - 1) / 2, (config.height - 1) / 2])
    rectified = rectify(fisheye, rectify_maps(config))
    assert rectified.shape[:2] == (config.height, config.width)
    found = blob_centroids(rectified, [centre])[0]
    # The blob and the maps are symmetric about the axis, so the centroid stays put (to 1e-13 px here); 0.1 px is
    # room for the maps' 1/32 px rounding. A principal point at width / 2 (pixel-index space) puts it 0.5 px off.
    np.testing.assert_allclose(found, centre, atol=0.1)


# ---------------------------------------------------------------- rendered


@pytest.fixture(scope="module")
def marker_scene():
    return MarkerScene(FisheyeConfig(), marker_points_C())


def test_blob_centroids_need_a_whole_pixels_weight_and_ignore_pixels_greener_than_the_background():
    """A pixel's weight is its green channel's dip below the background's, over the background's (0 to 1): a
    lone pixel at half the background's green (weight 0.5) is no blob (NaN); two full-weight pixels at u = 100
    and 101 centre at 100.5 whatever a pixel greener than the background (255 > 224) nearby."""
    image = np.tile(BACKGROUND.astype(np.uint8), (200, 200, 1))
    image[100, 100, 1] = BACKGROUND[1] // 2
    assert np.isnan(blob_centroids(image, np.array([[100.0, 100.0]]))).all()
    image[100, 100, 1] = image[100, 101, 1] = 0
    image[100, 110, 1] = 255
    np.testing.assert_allclose(blob_centroids(image, np.array([[100.0, 100.0]])), [[100.5, 100.0]], atol=1e-12)


@pytest.mark.slow
def test_rendered_markers_land_where_projectpoints_puts_them(marker_scene):
    error = projection_errors(marker_scene)
    assert np.isfinite(error).all(), f"markers not found: {np.flatnonzero(~np.isfinite(error))}"
    assert error.mean() < MEAN_TOLERANCE_PX and error.max() < MAX_TOLERANCE_PX, f"errors {np.round(error, 3)} px"


def test_rendered_markers_land_where_projectpoints_puts_them_off_the_default_mount():
    """The markers are placed in C through the mount X_BC (the camera on W's origin as B): a mount whose
    translation is not its own inverse's (0.3 m forward) still puts them where projectPoints does, one
    distance per marker. (Renders, but in well under a second: not marked slow.)"""
    error = projection_errors(MarkerScene(FisheyeConfig(mount_xyz_m=[0.3, 0.0, 0.0]), marker_points_C()))
    assert error.shape == (len(marker_points_C()),)
    assert np.isfinite(error).all(), f"markers not found: {np.flatnonzero(~np.isfinite(error))}"
    assert error.mean() < MEAN_TOLERANCE_PX and error.max() < MAX_TOLERANCE_PX, f"errors {np.round(error, 3)} px"


@pytest.mark.slow
def test_rendered_circle_is_filled_without_gaps(marker_scene):
    config = marker_scene.config
    image = marker_scene.fisheye_image()
    u, v = np.meshgrid(np.arange(config.width), np.arange(config.height))
    inside = in_field_of_view(np.column_stack([u.ravel(), v.ravel()]), config).reshape(u.shape)
    near_marker = np.zeros_like(inside)
    for x, y in project_points(marker_scene.points_C, config):
        near_marker |= np.hypot(u - x, v - y) < 15
    background = inside & ~near_marker
    assert (np.abs(image[background][:, :3].astype(int) - BACKGROUND).max(axis=1) <= 1).all()
    assert (image[~inside] == BLACK).all()


@pytest.mark.slow
def test_rendered_markers_in_the_rectified_view(marker_scene):
    """Markers within the rectified view land on the pinhole projection with `rectified_K`."""
    config = marker_scene.config
    points = marker_scene.points_C
    pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), rectified_K(config), None)
    pixels = pixels.reshape(-1, 2)
    visible = (pixels > 15).all(axis=1) & (pixels < config.width - 16).all(axis=1) & (points[:, 2] > 0)
    assert visible.sum() >= 5
    error = np.linalg.norm(blob_centroids(marker_scene.rectified_image(), pixels[visible]) - pixels[visible], axis=1)
    assert error.max() < 2 * MAX_TOLERANCE_PX, f"errors {np.round(error, 3)} px"


# ---------------------------------------------------------------- configuration


@pytest.mark.parametrize("change, field", [
    ({"fov_deg": 180.0}, "fisheye.fov_deg"),
    ({"fov_deg": 0.0}, "fisheye.fov_deg"),
    ({"k1": -0.3}, "fisheye.k1 and fisheye.k2 fold"),
    ({"k2": -0.08}, "fisheye.k1 and fisheye.k2 fold"),
    ({"f": 0.0}, "fisheye.f must be positive"),
    ({"rate_hz": 0.0}, "fisheye.rate_hz must be positive"),
    ({"cx": 600.0}, "fisheye.cx"),
    ({"face_px": 8}, "fisheye.face_px"),
    ({"side_axis_deg": 95.0}, "fisheye.side_axis_deg"),
    ({"mount_rpy_deg": [180.0, 0.0]}, "fisheye.mount_rpy_deg"),
    ({"rectified_fov_deg": 180.0}, "fisheye.rectified_fov_deg"),
    ({"far_m": 0.01}, "fisheye.far_m"),
])
def test_bad_config_raises_naming_the_field(change, field):
    config = FisheyeConfig(**change)
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        config.validate()


@pytest.mark.parametrize("change", [{"face_px": 16}, {"side_axis_deg": 30.0}, {"side_axis_deg": 90.0}])
def test_config_at_its_limits_is_valid(change):
    """The limits themselves are allowed: faces of 16 px, side axes 30 or 90 deg off the optical axis."""
    FisheyeConfig(**change).validate()


def test_config_loads_from_yaml():
    config = yaml_load_typed(schema=FisheyeConfig, data="fov_deg: 120.0\nmount_xyz_m: [0.1, 0.0, -0.05]\n")
    assert config.fov_deg == 120.0 and config.mount_xyz_m == [0.1, 0.0, -0.05] and config.k1 == -0.02
