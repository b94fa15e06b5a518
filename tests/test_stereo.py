"""Seed 003's stereo altitude: the rendered MYNT EYE pair over textured ground against Figure 16's
bounds, the depth functions and the altimeter on synthetic pairs, the altitude Kalman filter (Eq. 13-14)
on analytic cases, and bad configurations."""

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

import models.ground_texture as ground_texture
from diagrams.stereo_hover import (
    GROUND_SHOWN_LIFT_M,
    GroundConfig,
    StereoHoverConfig,
    add_stereo_altimeter,
    add_textured_ground,
    build_stereo_hover,
)
from models.apriltag import source_digest
from models.ground_texture import ground_texture_image, ground_texture_mesh
from systems.config import ConfigError
from systems.estimators.altitude_kf import (
    AltitudeFilterSystem,
    AltitudeKfConfig,
    AltitudeKfState,
    altitude_kf_step,
    measurement,
    predict,
    process_noise,
)
from systems.perception.stereo_depth import (
    StereoAltimeter,
    StereoAltitudeEstimator,
    StereoDepthConfig,
    central_window,
    depth_from_disparity,
    disparity,
    make_matcher,
    window_altitude,
    window_crop,
)
from systems.sensors.stereo import StereoConfig, add_stereo_pair
from tests.conftest import wiring

F_PX = 350.0  # 2.1 mm / 6 um
BASELINE = 0.12

# ---------------------------------------------------------------------------------------------
# The rendered pair


@pytest.fixture(scope="module")
def hover():
    """The pair over the textured ground, with 2 levels of pixel noise per eye; (diagram, handles)."""
    config = StereoHoverConfig()
    config.stereo.pixel_noise_std = 2.0
    return build_stereo_hover(config)


def raw_altitude(hover, X_WB: RigidTransform, t: float = 0.0) -> tuple[float, float]:
    diagram, handles = hover
    context = diagram.CreateDefaultContext()
    context.SetTime(t)
    handles.fix_X_WB(diagram, context, X_WB)
    altimeter_context = handles.altimeter.GetMyContextFromRoot(context)
    return (handles.altimeter.GetOutputPort("altitude").Eval(altimeter_context)[0],
            handles.altimeter.GetOutputPort("altitude_valid").Eval(altimeter_context)[0])


def camera_height(X_WB: RigidTransform) -> float:
    """The left eye's height above the ground (z = 0): the true altitude of a level pair."""
    return X_WB.multiply(StereoConfig().X_BL).translation()[2]


# Heights of the left eye (m); none of them an integer disparity (42 / Z px), where a rendered pair is
# an exact pixel shift and every matcher is exact. Figure 16: error < 0.2 m in 0.7-3 m, < 1 m in 3-8 m.
# Up to 7.7 m: from about 7.8 m SGBM's bias towards 5 px (8.4 m) reads beyond the 8 m range, invalid.
HEIGHTS = [0.75, 1.3, 2.45, 2.95, 4.4, 5.45, 6.7, 7.7]


@pytest.mark.slow
@pytest.mark.parametrize("height", HEIGHTS)
def test_rendered_altitude_is_within_figure_16_bounds(hover, height):
    X_WB = RigidTransform([0.4 * height, -0.3, height - StereoConfig().mount_xyz_m[2]])
    assert camera_height(X_WB) == pytest.approx(height, abs=1e-12)
    altitude, valid = raw_altitude(hover, X_WB, t=height)
    bound = 0.2 if height < 3.0 else 1.0
    assert valid == 1.0
    # Measured (benchmarks/stereo.py): at most 0.03 m below 3 m and 0.31 m up to 8 m (SGBM's sub-pixel
    # bias towards whole disparities), with these 2 levels of noise.
    assert abs(altitude - height) < bound, f"raw altitude {altitude:.3f} m at {height} m"


@pytest.mark.slow
@pytest.mark.parametrize("where", ["too_close", "too_far", "off_the_ground"])
def test_rendered_altitude_is_invalid_without_a_match(hover, where):
    # the eyes 0.5 m up: 84 px of disparity, beyond the 64 searched; 10 m up: SGBM matches (10.35 m) but
    # beyond the 8 m range; 60 m off the 20 m ground: the sky's flat colour.
    X_WB = {"too_close": RigidTransform([0.0, 0.0, 0.45]), "too_far": RigidTransform([0.0, 0.0, 10.05]),
            "off_the_ground": RigidTransform([60.0, 0.0, 3.0])}[where]
    altitude, valid = raw_altitude(hover, X_WB)
    assert valid == 0.0 and math.isnan(altitude)


def test_meshcat_sees_the_ground_averaged_down_and_the_cameras_the_whole_texture(tmp_path):
    """Meshcat's copy is the cameras' texture averaged over 4 x 4 texel blocks (a 256 px texture shown at
    64): each of its texels the mean of its block, to the 8 bits' rounding."""
    whole = cv2.imread(str(ground_texture_mesh(5, 256, 2, 4, tmp_path).with_suffix(".png")), cv2.IMREAD_GRAYSCALE)
    shown = cv2.imread(str(ground_texture_mesh(5, 256, 2, 4, tmp_path, shown_pixels=64).with_suffix(".png")),
                       cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(whole, ground_texture_image(5, 256, 2, 4))
    assert shown.shape == (64, 64)
    block_means = whole.reshape(64, 4, 64, 4).mean(axis=(1, 3))
    assert np.abs(shown - block_means).max() <= 0.5
    with pytest.raises(ValueError, match="shown_pixels"):
        ground_texture_mesh(5, 256, 2, 4, tmp_path, shown_pixels=256)


def test_the_ground_texture_is_at_least_64_pixels():
    with pytest.raises(ValueError, match="pixels >= 64"):
        ground_texture_image(0, 63, 2, 4)
    assert ground_texture_image(0, 64, 2, 4).shape == (64, 64)


def test_the_ground_texture_is_stretched_to_8_247_with_its_half_per_cent_tails_cut():
    """The 0.5 % and 99.5 % quantiles go to 8 and 247 (to the 8 bits' truncation); the 0.5 % beyond each lies
    under 8 and from 247 up, the farthest of it clipped at 0 and 255."""
    image = ground_texture_image(0, 256, 2, 4)
    np.testing.assert_allclose(np.percentile(image, [0.5, 99.5]), [8, 247], atol=1.0)
    np.testing.assert_allclose([np.mean(image < 8), np.mean(image >= 247)], 0.005, atol=0.001)
    assert image.min() == 0 and image.max() == 255


@pytest.mark.parametrize("pixels, finest_texels, octaves", [(256, 4, 1), (512, 2, 4)])
def test_the_ground_texture_has_every_octaves_squares(pixels, finest_texels, octaves):
    """Octave k's squares are finest_texels 2^k texels, each its own random level, all octaves the same amplitude
    (module docstring): two texels d apart along a row or column share octave k's square in a fraction
    1 - d / side_k of the image (0 once d reaches the side), so the texture's correlation at lag d is that
    fraction's mean over the octaves (to 0.04: the sampling of a few hundred squares and the clipped tails)."""
    image = ground_texture_image(0, pixels, finest_texels, octaves).astype(float)
    sides = finest_texels * 2.0 ** np.arange(octaves)
    for d in (1, 2, 4, 8, 16):
        along_rows = np.corrcoef(image[:, :-d].ravel(), image[:, d:].ravel())[0, 1]
        along_columns = np.corrcoef(image[:-d].ravel(), image[d:].ravel())[0, 1]
        expected = np.mean(np.clip(1 - d / sides, 0.0, None))
        assert abs((along_rows + along_columns) / 2 - expected) < 0.04, f"lag {d}"


def ground_geometries(scene_graph: SceneGraph) -> dict:
    """{name: (perceived, illustrated, mesh file name, mesh scale, z [m])} of the textured ground's geometries."""
    inspector = scene_graph.model_inspector()
    roles = {}
    for geometry_id in inspector.GetAllGeometryIds():
        name = inspector.GetName(geometry_id)
        if name.startswith("textured_ground"):
            shape = inspector.GetShape(geometry_id)
            roles[name] = (inspector.GetPerceptionProperties(geometry_id) is not None,
                           inspector.GetIllustrationProperties(geometry_id) is not None,
                           Path(shape.source().path()).name, shape.scale(),
                           inspector.GetPoseInFrame(geometry_id).translation()[2])
    return roles


def ground_mesh_name(pixels: int, shown: str = "") -> str:
    """The file name ground_texture_mesh gives the seed 0 texture of `pixels` a side (default texels, octaves)."""
    return f"ground_texture_s0_p{pixels}_f2_o8{shown}_{source_digest(Path(ground_texture.__file__))}.obj"


def test_the_ground_has_one_geometry_per_role():
    """The whole texture only for the cameras (perception) in z = 0, the averaged copy only for Meshcat,
    1 cm higher (a browser's depth buffer does not resolve less over the plain ground); both 20 m a side."""
    diagram, _ = build_stereo_hover(StereoHoverConfig())
    scene_graph = next(s for s in diagram.GetSystems() if isinstance(s, SceneGraph))
    assert ground_geometries(scene_graph) == {
        "textured_ground": (True, False, ground_mesh_name(4096), 20.0, 0.0),
        "textured_ground_shown": (False, True, ground_mesh_name(4096, "_shown1024"), 20.0, 0.01)}


def test_the_hover_scene_has_the_configured_ground():
    """A 7 m ground of a 64 px texture (no averaged copy under GROUND_SHOWN_PIXELS): both geometries that mesh,
    scaled to 7 m."""
    diagram, _ = build_stereo_hover(StereoHoverConfig(ground=GroundConfig(size_m=7.0, texture_pixels=64)))
    scene_graph = next(s for s in diagram.GetSystems() if isinstance(s, SceneGraph))
    assert ground_geometries(scene_graph) == {"textured_ground": (True, False, ground_mesh_name(64), 7.0, 0.0),
                                              "textured_ground_shown": (False, True, ground_mesh_name(64), 7.0, 0.01)}


def test_a_raised_ground_is_at_its_height_for_the_cameras_and_lifted_for_meshcat():
    scene_graph = SceneGraph()
    add_textured_ground(scene_graph, GroundConfig(texture_pixels=64), height_m=0.5)
    z = {name: geometry[-1] for name, geometry in ground_geometries(scene_graph).items()}
    assert z == pytest.approx({"textured_ground": 0.5, "textured_ground_shown": 0.5 + GROUND_SHOWN_LIFT_M}, abs=1e-12)


def test_add_stereo_altimeter_wires_the_pair_into_the_altimeter_and_the_altimeter_into_the_filter():
    """The left eye's stream to the altimeter's left input and the right's to its right, the altimeter's
    altitude and altitude_valid to the filter's inputs of those names, and the filter told the altimeter's
    nearest range (f b / (disparities - 1), seed 003's near band)."""
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    config = StereoConfig()
    pair = add_stereo_pair(builder, scene_graph, scene_graph.world_frame_id(), config)
    altimeter, altitude_filter = add_stereo_altimeter(builder, pair, config, StereoDepthConfig(), AltitudeKfConfig())
    diagram = builder.Build()
    wired = wiring(diagram)
    assert wired["stereo_altimeter", "left_image"] == (pair.left.get_name(), pair.left_image.get_name())
    assert wired["stereo_altimeter", "right_image"] == (pair.right.get_name(), pair.right_image.get_name())
    assert wired["altitude_filter", "altitude"] == ("stereo_altimeter", "altitude")
    assert wired["altitude_filter", "altitude_valid"] == ("stereo_altimeter", "altitude_valid")
    disparities = StereoDepthConfig().disparities_for(config)
    assert altitude_filter.nearest_m == pytest.approx(F_PX * BASELINE / (disparities - 1), rel=1e-12)
    assert altitude_filter.nearest_m == altimeter.estimator.nearest_m


def test_the_eyes_are_a_rectified_pair_one_baseline_apart():
    from pydrake.geometry import SceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    pair = add_stereo_pair(builder, scene_graph, scene_graph.world_frame_id(), StereoConfig())
    X_BL, X_BR = pair.left_sensor.default_X_PB(), pair.right_sensor.default_X_PB()  # the sensors' poses on the body
    X_LR = X_BL.inverse().multiply(X_BR)
    np.testing.assert_allclose(X_LR.rotation().matrix(), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(X_LR.translation(), [BASELINE, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(X_BL.rotation().col(2), [0.0, 0.0, -1.0], atol=1e-12)  # looking down
    np.testing.assert_allclose(X_BL.rotation().col(0), [1.0, 0.0, 0.0], atol=1e-12)  # image right = forward
    for sensor in (pair.left_sensor, pair.right_sensor):
        info = sensor.default_color_render_camera().core().intrinsics()
        assert (info.width(), info.height()) == (752, 480)
        np.testing.assert_allclose([info.focal_x(), info.focal_y(), info.center_x(), info.center_y()],
                                   [F_PX, F_PX, 376.0, 240.0], rtol=1e-12)  # Drake's centre: OpenCV's + 0.5


def test_each_eye_is_the_stereo_config_as_a_camera():
    """StereoConfig.eye() carries every setting an eye's camera needs: size, intrinsics, rate, pixel noise,
    clipping and mount (none left at CameraConfig's defaults)."""
    stereo = StereoConfig(width=640, height=400, focal_length_px=300.0, cx=310.0, cy=190.0, rate_hz=45.0,
                          pixel_noise_std=1.5, near_m=0.2, far_m=40.0, mount_xyz_m=[0.1, 0.02, -0.03])
    eye = stereo.eye()
    assert (eye.width, eye.height, eye.fx, eye.fy, eye.cx, eye.cy) == (640, 400, 300.0, 300.0, 310.0, 190.0)
    assert (eye.rate_hz, eye.pixel_noise_std, eye.near_m, eye.far_m) == (45.0, 1.5, 0.2, 40.0)
    assert eye.mount_xyz_m == [0.1, 0.02, -0.03]


def test_the_two_eyes_have_the_configured_pixel_noise_each_its_own():
    """The pair's two NoisyCameras add pixel_noise_std of noise to the same grey image, and the two eyes'
    noise is independent (uncorrelated across the 752 x 480 x 3 values), as two sensors' is."""
    from pydrake.geometry import SceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    pair = add_stereo_pair(builder, scene_graph, scene_graph.world_frame_id(), StereoConfig(pixel_noise_std=2.0), 5)
    grey = np.full((480, 752), 128, np.uint8)
    noise = []
    for camera in (pair.left, pair.right):
        context = camera.CreateDefaultContext()
        camera.GetInputPort("rendered_image").FixValue(context, rgba(grey))
        context.SetTime(1.0 / 60.0)
        noise.append(camera.get_output_port().Eval(context).data[..., :3].astype(float).ravel() - 128.0)
    for n in noise:
        assert n.std() == pytest.approx(math.sqrt(2.0**2 + 1.0 / 12.0), rel=0.03)  # plus rounding to levels
    assert abs(np.corrcoef(noise[0], noise[1])[0, 1]) < 0.05


def test_the_hover_scenes_seed_seeds_the_eyes_noise():
    """Two stereo-hover scenes of different seeds, with pixel noise, give the same grey image different noise in
    the left eye (the scene's seed reaches the pair)."""
    grey = np.full((480, 752), 128, np.uint8)
    images = []
    for seed in (0, 1):
        config = StereoHoverConfig(seed=seed)
        config.stereo.pixel_noise_std = 2.0
        left = build_stereo_hover(config)[1].pair.left
        context = left.CreateDefaultContext()
        left.GetInputPort("rendered_image").FixValue(context, rgba(grey))
        context.SetTime(1.0 / 60.0)
        images.append(left.get_output_port().Eval(context).data[..., :3].copy())
    assert all(image.std() > 1.0 for image in images)  # noisy
    assert np.mean(images[0] != images[1]) > 0.5


# ---------------------------------------------------------------------------------------------
# Depth functions and the altimeter on synthetic pairs


def test_defaults_are_the_paper_camera():
    c = StereoConfig()
    assert (c.width, c.height, c.baseline_m, c.rate_hz) == (752, 480, 0.12, 60.0)
    assert c.period_s == pytest.approx(1 / 60)
    assert c.focal_length_px == pytest.approx(F_PX)
    # The docstring's mount: the pair's centre under the body origin, 5 cm down, the baseline along +x_B.
    left, right = c.X_BL.translation(), c.X_BR.translation()
    np.testing.assert_allclose((left + right) / 2, [0.0, 0.0, -0.05], atol=1e-12)
    np.testing.assert_allclose(right - left, [BASELINE, 0.0, 0.0], atol=1e-12)
    assert StereoDepthConfig().disparities_for(c) == 64  # 350 * 0.12 / 0.7 = 60 px, rounded up to 16s
    assert StereoAltitudeEstimator(c).nearest_m == pytest.approx(F_PX * BASELINE / 63)  # 0.667 m: 0-63 px searched
    assert central_window((480, 752), (c.cx, c.cy), 100, 100) == (slice(190, 290), slice(326, 426))


def test_depth_from_disparity_is_eq_11():
    d = np.array([42.0, 21.0, 0.0, -1.0, np.nan])
    np.testing.assert_allclose(depth_from_disparity(d, F_PX, BASELINE), [1.0, 2.0, np.nan, np.nan, np.nan])


def test_window_altitude_is_eq_12_over_valid_pixels():
    depth = np.full((10, 10), 2.0)
    depth[:3] = 4.0
    depth[9] = np.nan
    altitude, valid, fraction = window_altitude(depth, 0.5)
    assert valid and fraction == 0.9 and altitude == pytest.approx((30 * 4.0 + 60 * 2.0) / 90)
    assert window_altitude(depth, 0.5, "median")[0] == 2.0
    depth[:6] = np.nan
    altitude, valid, fraction = window_altitude(depth, 0.5)
    assert not valid and math.isnan(altitude) and fraction == pytest.approx(0.3)


@pytest.mark.parametrize("cx", [376.0, 376.5, 377.0, 377.5])
@pytest.mark.parametrize("cols", [100, 99])
def test_the_window_is_centred_on_any_centre(cx, cols):
    """Pixel j's centre is at x = j (OpenCV): the window's columns start .. start + cols - 1 have their middle at
    start + (cols - 1) / 2, within half a pixel of the configured centre for whole and half-pixel centres of either
    parity, an even and an odd width (Python's round takes halves to even)."""
    rows, columns = central_window((480, 752), (cx, 239.5), 100, cols)
    assert columns.stop - columns.start == cols and rows == slice(190, 290)
    assert abs(columns.start + (cols - 1) / 2 - cx) <= 0.5


@pytest.mark.parametrize("centre_xy, rows, cols, expected", [
    ((375.5, 239.5), 480, 752, (slice(0, 480), slice(0, 752))),  # the whole frame
    ((740.0, 470.0), 100, 100, (slice(380, 480), slice(652, 752))),  # pushed back inside at the bottom right
    ((3.0, 2.0), 100, 100, (slice(0, 100), slice(0, 100))),  # and at the top left
])
def test_the_window_is_clipped_to_the_image(centre_xy, rows, cols, expected):
    """A window that would cross the image's edge is moved back inside it, ending on its last row and column."""
    assert central_window((480, 752), centre_xy, rows, cols) == expected


@pytest.mark.parametrize("window, expected", [
    # 190 - 24, 290 + 24; 326 - 24 - 64, 426 + 24
    ((slice(190, 290), slice(326, 426)), (slice(166, 314), slice(238, 450))),
    ((slice(0, 100), slice(30, 130)), (slice(0, 124), slice(0, 154))),  # clipped at the top and left
    ((slice(400, 480), slice(700, 752)), (slice(376, 480), slice(612, 752))),  # and at the bottom and right
])
def test_the_crop_is_the_window_with_its_margin_and_the_search_to_its_left(window, expected):
    """window_crop with 64 disparities and a 24 px margin: the margin on every side, the 64 searched columns
    further left, clipped to the 752 x 480 image."""
    assert window_crop((480, 752), window, 64, 24) == expected


def test_window_of_takes_the_windows_pixels_out_of_the_matched_region():
    """Through the crop and back: an image of each pixel's index, cropped to the matched region, gives the
    window's indices of the full frame."""
    estimator = StereoAltitudeEstimator(StereoConfig())
    full = np.arange(480 * 752).reshape(480, 752)
    np.testing.assert_array_equal(estimator.window_of(full[estimator.crop]), full[estimator.window])


def test_the_configured_estimator_gives_the_altitude():
    """estimator "median": 10 % of the window on a farther object (6 px, 7 m) over ground at 21 px (2 m): the
    altitude is NumPy's median of Eq. 11's depths, 2 m (their mean is 2.5 m)."""
    window = np.full((100, 100), 21.0)
    window[:10] = 6.0
    depth = F_PX * BASELINE / window
    median = StereoAltitudeEstimator(StereoConfig(), StereoDepthConfig(estimator="median")).altitude(window)
    assert median.valid and median.altitude_m == pytest.approx(float(np.median(depth)), rel=1e-12)
    mean = StereoAltitudeEstimator(StereoConfig(), StereoDepthConfig(estimator="mean")).altitude(window)
    assert mean.valid and mean.altitude_m == pytest.approx(float(np.mean(depth)), rel=1e-12)
    assert abs(mean.altitude_m - median.altitude_m) > 0.4


def test_a_window_exactly_min_valid_fraction_matched_is_valid():
    """Invalid only when fewer than min_valid_fraction of the window's pixels have a depth: exactly 60 % with
    0.6 is valid, one pixel fewer is not."""
    depth = np.full((10, 10), np.nan)
    depth.flat[:60] = 2.0
    assert window_altitude(depth, 0.6) == (2.0, True, 0.6)
    depth.flat[59] = np.nan
    altitude, valid, fraction = window_altitude(depth, 0.6)
    assert not valid and math.isnan(altitude) and fraction == pytest.approx(0.59)


def test_an_altitude_exactly_at_max_altitude_m_is_valid_and_an_empty_window_is_not():
    """Invalid only beyond max_altitude_m: a window all at 8 m with an 8 m range is valid, all of it matched. A
    window of no pixels has none matched (fraction 0) and no altitude."""
    assert window_altitude(np.full((2, 2), 8.0), 0.6, "mean", 8.0) == (8.0, True, 1.0)
    altitude, valid, fraction = window_altitude(np.empty((0, 0)), 0.6)
    assert math.isnan(altitude) and not valid and fraction == 0.0


def test_the_default_altimeter_refuses_a_window_55_per_cent_matched():
    """The default min_valid_fraction, 0.6 (StereoDepthConfig: under it the window is refused): a window of 21 px
    (2 m) matched over 55 % of its pixels is invalid, over 60 % valid."""
    estimator = StereoAltitudeEstimator(StereoConfig())
    window = np.full((100, 100), np.nan)
    window.flat[:5500] = 21.0
    refused = estimator.altitude(window)
    assert not refused.valid and math.isnan(refused.altitude_m) and refused.valid_fraction == pytest.approx(0.55)
    window.flat[:6000] = 21.0
    accepted = estimator.altitude(window)
    assert accepted.valid and accepted.altitude_m == pytest.approx(F_PX * BASELINE / 21.0, rel=1e-12)


@pytest.mark.parametrize("config", [StereoDepthConfig(),
                                    StereoDepthConfig(block_size=7, uniqueness_ratio=5, speckle_window_size=50,
                                                      speckle_range=1, disp12_max_diff=3)])
def test_the_matcher_has_the_configured_settings(config):
    """make_matcher passes every setting of the config to cv2.StereoSGBM (both configs' values differ from OpenCV's
    defaults: blockSize 3, the others 0) and searches disparities 0 to 63 in the full SGBM mode."""
    matcher = make_matcher(64, config)
    assert (matcher.getMinDisparity(), matcher.getNumDisparities()) == (0, 64)
    assert matcher.getBlockSize() == config.block_size
    assert matcher.getDisp12MaxDiff() == config.disp12_max_diff
    assert matcher.getUniquenessRatio() == config.uniqueness_ratio
    assert (matcher.getSpeckleWindowSize(), matcher.getSpeckleRange()) == (config.speckle_window_size,
                                                                           config.speckle_range)
    assert matcher.getMode() == cv2.STEREO_SGBM_MODE_SGBM


class FixedMatcher:
    """A stand-in for cv2.StereoSGBM whose compute returns the given fixed-point (1/16 px) disparities."""

    def __init__(self, raw: np.ndarray):
        self.raw = raw

    def compute(self, left, right):
        return self.raw.copy()


def test_disparity_is_sgbms_fixed_point_over_16_and_none_where_not_positive():
    """SGBM's 1/16 px disparities: -16 (its invalid mark with minDisparity 0) and 0 (infinitely far) are no match,
    8 and 32 are 0.5 and 2 px."""
    d = disparity(None, None, FixedMatcher(np.array([[-16, 0, 8, 32]], np.int16)))
    assert d.dtype == np.float32
    np.testing.assert_array_equal(d, [[np.nan, np.nan, 0.5, 2.0]])


@pytest.mark.parametrize("block_size", [3, 5, 11])
def test_the_matchers_smoothness_penalties_are_opencvs_recommended(block_size):
    """OpenCV's StereoSGBM requires P2 > P1 and recommends P1 = 8 cn B^2, P2 = 32 cn B^2 (cn = 1: grey images),
    the source make_matcher names."""
    matcher = make_matcher(16, StereoDepthConfig(block_size=block_size))
    assert matcher.getP2() > matcher.getP1()
    assert (matcher.getP1(), matcher.getP2()) == (8 * block_size**2, 32 * block_size**2)


def shifted_pair(d: int, noise_std: float = 0.0, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A textured left image and its right image, the scene d px further left (a plane at f B / d)."""
    texture = ground_texture_image(seed, 1024, 2, 7)[:480, : 752 + d]
    left = texture[:, :752].copy()  # left pixel x sees the texture's column x,
    right = texture[:, d:].copy()  # the right eye sees it at x - d
    rng = np.random.default_rng(seed)
    noisy = [np.clip(image + rng.normal(0, noise_std, image.shape), 0, 255).astype(np.uint8) for image in (left, right)]
    return noisy[0], noisy[1]


@pytest.mark.parametrize("d", [6, 14, 42, 60])
def test_altitude_of_a_shifted_pair_is_f_b_over_d(d):
    left, right = shifted_pair(d, noise_std=2.0)
    result = StereoAltitudeEstimator(StereoConfig()).estimate(left, right)
    assert result.valid
    assert result.altitude_m == pytest.approx(F_PX * BASELINE / d, rel=0.01)
    # matching the whole frame gives the same window
    full = StereoAltitudeEstimator(StereoConfig(), crop=False).estimate(left, right)
    assert full.altitude_m == pytest.approx(result.altitude_m, rel=0.01)


@pytest.mark.parametrize("max_altitude_m", [8.0, 3.0])
def test_an_altitude_beyond_max_altitude_m_is_invalid(max_altitude_m):
    """Seed 003's range ends at max_altitude_m: a pair shifted 4 px (10.5 m) matches exactly but reads
    NaN and invalid; 6 px (7 m) only when the range ends at 3 m; 21 px (2 m) is within both."""
    camera = StereoConfig(max_altitude_m=max_altitude_m)
    estimator = StereoAltitudeEstimator(camera)
    for d in (4, 6, 21):
        result = estimator.estimate(*shifted_pair(d))
        within = F_PX * BASELINE / d <= max_altitude_m
        assert result.valid == within, f"{d} px"
        assert result.valid_fraction > 0.95  # matched: invalid for its range alone
        if within:
            assert result.altitude_m == pytest.approx(F_PX * BASELINE / d, rel=1e-3)
        else:
            assert math.isnan(result.altitude_m)
    depth = np.full((10, 10), max_altitude_m + 0.01)
    assert window_altitude(depth, 0.5)[1] and not window_altitude(depth, 0.5, "mean", max_altitude_m)[1]


def test_the_search_reaches_its_nearest_range_and_no_nearer():
    """SGBM with 64 disparities searches 0-63 px: a pair shifted 63 px (0.667 m, `nearest_m`) reads its depth;
    where f b / min_altitude_m is exactly 64 px, 64 disparities do not reach it and the derived search is 80."""
    estimator = StereoAltitudeEstimator(StereoConfig())
    result = estimator.estimate(*shifted_pair(63, noise_std=2.0))
    assert result.valid and result.altitude_m == pytest.approx(estimator.nearest_m, rel=0.01)
    at_64 = StereoConfig(min_altitude_m=F_PX * BASELINE / 64)
    assert StereoDepthConfig().disparities_for(at_64) == 80
    with pytest.raises(ConfigError, match=r"does not reach the disparity at min_altitude_m \(64.0 px\)"):
        StereoDepthConfig(num_disparities=64).validate(camera=at_64)


def rgba(gray: np.ndarray) -> ImageRgba8U:
    image = ImageRgba8U(gray.shape[1], gray.shape[0])
    image.mutable_data[..., :3] = gray[..., None]
    image.mutable_data[..., 3] = 255
    return image


def test_altimeter_system_outputs_the_altitude_and_its_flag():
    altimeter = StereoAltimeter(StereoConfig())
    context = altimeter.CreateDefaultContext()
    left, right = shifted_pair(21)
    altimeter.GetInputPort("left_image").FixValue(context, rgba(left))
    altimeter.GetInputPort("right_image").FixValue(context, rgba(right))
    assert altimeter.GetOutputPort("altitude").Eval(context)[0] == pytest.approx(2.0, rel=1e-3)
    assert altimeter.GetOutputPort("altitude_valid").Eval(context)[0] == 1.0
    blank = np.full((480, 752), 128, np.uint8)  # no texture: nothing to match
    altimeter.GetInputPort("left_image").FixValue(context, rgba(blank))
    altimeter.GetInputPort("right_image").FixValue(context, rgba(blank))
    assert altimeter.GetOutputPort("altitude_valid").Eval(context)[0] == 0.0
    assert math.isnan(altimeter.GetOutputPort("altitude").Eval(context)[0])


# ---------------------------------------------------------------------------------------------
# The altitude Kalman filter (Eq. 13-14)

T = 1.0 / 60.0
KF = AltitudeKfConfig()
STD = 0.1
MATCHED = AltitudeKfConfig(measurement_std_m=STD, measurement_std_per_m2=0.0)  # the filter knows the noise


def run_kf(truth, std, valid=None, seed=0, config=KF):
    """Steps the filter on truth(t) plus N(0, std) noise at 60 Hz; returns the states."""
    rng = np.random.default_rng(seed)
    state, states = AltitudeKfState(), []
    for k, z in enumerate(truth):
        ok = True if valid is None else valid[k]
        state = altitude_kf_step(state, z + std * rng.standard_normal(), ok, k * T, config)
        states.append(state)
    return states


def errors(states, truth, rate):
    """Altitude and speed errors over the second half (after the start-up transient)."""
    half = len(states) // 2
    altitude = np.array([s.x[0] for s in states[half:]]) - truth[half:]
    speed = np.array([s.x[1] for s in states[half:]]) - rate
    return altitude, speed


def rms(e):
    return float(np.sqrt(np.mean(e**2)))


def test_kf_constant_altitude_with_noise_converges():
    n = 600
    truth = np.full(n, 3.0)
    states = run_kf(truth, STD, config=MATCHED)
    altitude, speed = errors(states, truth, 0.0)
    # measured: 0.025 m and 0.058 m/s rms (0.1 m raw noise at 60 Hz, 1 m/s^2 process noise)
    assert rms(altitude) < STD / 3, f"filtered rms {rms(altitude):.4f} m against raw {STD}"
    assert rms(speed) < 0.1 and abs(speed.mean()) < 0.03
    assert all(s.valid for s in states)
    # the covariance settles: symmetric, positive definite, steady
    P = states[-1].P
    np.testing.assert_allclose(P, P.T, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(P) > 0)
    np.testing.assert_allclose(P, states[-2].P, rtol=1e-3)


def test_kf_tracks_a_constant_descent_rate():
    rate, n = -0.5, 600
    truth = 6.0 + rate * np.arange(n) * T
    states = run_kf(truth, STD, seed=3, config=MATCHED)
    altitude, speed = errors(states, truth, rate)
    # no lag: a constant rate is in the model (a position-only filter would trail the ramp)
    assert abs(altitude.mean()) < 0.01 and rms(altitude) < STD / 3
    assert abs(speed.mean()) < 0.03 and rms(speed) < 0.1


def test_kf_models_are_eq_13_14_against_sampled_and_analytic_truths():
    """Eq. 14's R is the covariance of [Z, (Z - Z_prev) / T] from two independent readings (against 2e5 drawn
    pairs); Eq. 13's Q is a white acceleration held over the step, accel_std^2 G G^T, G = [T^2 / 2, T]; the
    filter starts with the reading's own variance."""
    config, T, z = AltitudeKfConfig(), 0.1, 4.0
    rng = np.random.default_rng(1)
    z0, z1 = z + config.measurement_std(z) * rng.standard_normal((2, 200_000))
    np.testing.assert_allclose(measurement(z, z, T, config)[2], np.cov(np.vstack([z1, (z1 - z0) / T])), rtol=0.03)
    G = np.array([T**2 / 2, T])
    np.testing.assert_allclose(process_noise(T, 2.0), 4.0 * np.outer(G, G), rtol=1e-12)
    first = altitude_kf_step(AltitudeKfState(), 5.0, True, 0.0, config)
    assert first.P[0, 0] == pytest.approx(config.measurement_std(5.0) ** 2, rel=1e-12)


def test_kf_rate_after_a_coasted_frame_is_not_taken_across_two_frames():
    """Every other frame without a reading on a steady 0.5 m/s descent: a reading after a gap is Z alone (its
    rate would span two frames), and the filter's rate stays the descent's."""
    config = replace(MATCHED, measurement_std_m=1e-4, measurement_std_per_m2=0.0)
    state = AltitudeKfState()
    for k in range(60):
        state = altitude_kf_step(state, 8.0 - 0.5 * k * T, k % 2 == 0, k * T, config)
    assert state.x[1] == pytest.approx(-0.5, abs=0.02)


def test_kf_coasts_on_invalid_input_then_turns_invalid():
    rate, n, lost = -0.5, 360, 240  # measured for 4 s, then nothing
    truth = 6.0 + rate * np.arange(n) * T
    valid = np.arange(n) < lost
    # The invalid frames carry finite numbers (the last reading, stale): the flag alone says not to use them.
    states = run_kf(np.where(valid, truth, truth[lost - 1]), 0.02, valid, seed=5)
    limit = int(KF.max_coast_s / T)  # 30 frames
    coasting = states[lost:lost + limit]
    assert all(s.valid for s in coasting)
    np.testing.assert_allclose([s.coast_s for s in coasting], T * np.arange(1, limit + 1))
    # the prediction follows the descent: after 0.5 s without a frame it is still within 3 cm
    assert abs(coasting[-1].x[0] - truth[lost + limit - 1]) < 0.03
    assert coasting[-1].P[0, 0] > states[lost - 1].P[0, 0]  # and knows it is less sure
    after = states[lost + limit + 1:]
    assert after and not any(s.valid for s in after) and all(np.isnan(s.x).all() for s in after)
    # a valid measurement starts it again, at that measurement, speed unknown (0)
    restarted = altitude_kf_step(after[-1], 2.0, True, n * T, KF)
    assert restarted.valid and restarted.x[0] == 2.0 and restarted.x[1] == 0.0


def test_kf_coasts_max_coast_s_whatever_the_time_of_its_last_measurement():
    """At 10 Hz (frame times k * 0.1 s) and max_coast_s 0.5 s, the 5th frame without a measurement is still valid
    and the 6th is not, whatever the time of the last measurement (before: the coast summed the frame intervals,
    and the float sum let go at the 5th for 13 of these 400 times, e.g. a last measurement at 0.1 s)."""
    for k0 in range(400):
        state = AltitudeKfState()
        for k in range(k0 - 2, k0 + 1):
            state = altitude_kf_step(state, 5.0, True, k * 0.1, KF)
        valid = []
        for k in range(k0 + 1, k0 + 7):
            state = altitude_kf_step(state, math.nan, False, k * 0.1, KF)
            valid.append(state.valid)
        assert valid == [True] * 5 + [False], f"last measurement at {k0 * 0.1:.1f} s"


def test_kf_takes_nan_flagged_valid_as_invalid_and_starts_invalid():
    state = altitude_kf_step(AltitudeKfState(), math.nan, True, 0.0, KF)
    assert not state.valid
    state = altitude_kf_step(state, 3.0, True, T, KF)
    state = altitude_kf_step(state, math.nan, True, 2 * T, KF)
    assert state.valid and state.coast_s == pytest.approx(T) and np.isfinite(state.x).all()


@pytest.mark.parametrize("altitude_m, std_m", [(2.0, 0.01 + 0.004 * 2.0**2), (5.0, 0.01 + 0.004 * 5.0**2)])
def test_kf_measurement_std_grows_with_the_altitudes_square(altitude_m, std_m):
    """sigma_Z = measurement_std_m + measurement_std_per_m2 * Z^2 (stereo's depth error grows as Z^2)."""
    config = AltitudeKfConfig(measurement_std_m=0.01, measurement_std_per_m2=0.004)
    assert config.measurement_std(altitude_m) == pytest.approx(std_m, rel=1e-12)


def test_kf_update_covariance_is_the_information_forms():
    """The Joseph form's P after an update equals (P^-1 + H^T R^-1 H)^-1 (left without its K R K^T, a filter
    grows overconfident)."""
    config = AltitudeKfConfig()
    first = altitude_kf_step(AltitudeKfState(), 5.0, True, 0.0, config)
    second = altitude_kf_step(first, 5.1, True, 0.1, config)
    _, P = predict(first.x, first.P, 0.1, config)
    _, H, R = measurement(5.1, 5.0, 0.1, config)
    np.testing.assert_allclose(second.P, np.linalg.inv(np.linalg.inv(P) + H.T @ np.linalg.solve(R, H)), rtol=1e-6)


def test_kf_without_the_rate_measurement_updates_on_the_altitude_alone():
    """use_rate_measurement False: Eq. 14's z is Z alone (H = [1, 0]) even with the previous frame's reading, and a
    step is the scalar Kalman update of the prediction, K = P H^T / (H P H^T + sigma_Z^2), computed here by hand."""
    config, T = AltitudeKfConfig(use_rate_measurement=False), 0.1
    z, H, R = measurement(5.1, 5.0, T, config)
    np.testing.assert_array_equal(z, [5.1])
    np.testing.assert_array_equal(H, [[1.0, 0.0]])
    np.testing.assert_allclose(R, [[config.measurement_std(5.1) ** 2]], rtol=1e-12)
    first = altitude_kf_step(AltitudeKfState(), 5.0, True, 0.0, config)
    second = altitude_kf_step(first, 5.1, True, T, config)
    A, G = np.array([[1.0, T], [0.0, 1.0]]), np.array([T**2 / 2, T])
    x, P = A @ first.x, A @ first.P @ A.T + config.accel_std_mps2**2 * np.outer(G, G)
    gain = P[:, 0] / (P[0, 0] + config.measurement_std(5.1) ** 2)
    np.testing.assert_allclose(second.x, x + gain * (5.1 - x[0]), rtol=1e-12)
    np.testing.assert_allclose(second.P, P - np.outer(gain, P[0]), rtol=1e-9)


def test_kf_system_outputs_are_predicted_to_the_contexts_time():
    """Between steps the outputs are the last step's state carried to the context's time at its rate."""
    system = AltitudeFilterSystem(period_s=0.1)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    system.GetInputPort("altitude_valid").FixValue(context, [1.0])
    for k in range(4):
        system.GetInputPort("altitude").FixValue(context, [5.0 - 0.2 * k])  # descending at 2 m/s
        simulator.AdvanceTo(0.1 * k)
    simulator.AdvanceTo(0.35)
    state = system.state(context)
    assert state.time == pytest.approx(0.3) and state.x[1] < -0.5
    assert system.GetOutputPort("altitude").Eval(context)[0] == pytest.approx(state.x[0] + 0.05 * state.x[1])
    assert system.GetOutputPort("vertical_speed").Eval(context)[0] == pytest.approx(state.x[1])


def test_kf_system_steps_at_the_camera_rate_and_coasts():
    system = AltitudeFilterSystem(KF, T)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    system.GetInputPort("altitude").FixValue(context, [2.0])
    system.GetInputPort("altitude_valid").FixValue(context, [1.0])
    simulator.AdvanceTo(1.0)
    out = {name: system.GetOutputPort(name).Eval(context)[0] for name in ("altitude", "vertical_speed", "valid")}
    assert out["valid"] == 1.0 and out["altitude"] == pytest.approx(2.0, abs=1e-9)
    assert out["vertical_speed"] == pytest.approx(0.0, abs=1e-9)
    assert system.state(context).time == pytest.approx(1.0)  # the step at t is seen at t
    system.GetInputPort("altitude").FixValue(context, [np.nan])
    system.GetInputPort("altitude_valid").FixValue(context, [0.0])
    simulator.AdvanceTo(1.4)
    assert system.GetOutputPort("valid").Eval(context)[0] == 1.0
    assert system.GetOutputPort("altitude").Eval(context)[0] == pytest.approx(2.0, abs=1e-9)
    simulator.AdvanceTo(1.6)
    assert system.GetOutputPort("valid").Eval(context)[0] == 0.0
    assert math.isnan(system.GetOutputPort("altitude").Eval(context)[0])


# ugv-hybrid's default run (seed 0) at 10 Hz from 20.0 s to 22.3 s, descending onto the UGV at 0.3 m/s: the
# raw altitude, flagged valid in every frame, and the UAV's true height, 0.552 m above the camera's depth over
# the roof (their mean difference over 20.0-20.9 s, std 3 mm). From 21.8 s the roof is nearer than the
# stereo's 0.656 m nearest range and SGBM matches wrongly (1.16-1.62 m); 21.0 s is an outlier too.
HYBRID_RAW = [1.183, 1.143, 1.113, 1.079, 1.052, 1.023, 0.990, 0.966, 0.934, 0.904, 1.105, 0.844, 0.886, 0.972,
              0.757, 0.725, 0.695, 0.668, 1.160, 1.568, 1.471, 1.536, 1.589, 1.624]
HYBRID_Z_WB = [1.731, 1.699, 1.666, 1.637, 1.606, 1.575, 1.545, 1.513, 1.484, 1.454, 1.424, 1.394, 1.363, 1.334,
               1.304, 1.274, 1.244, 1.212, 1.184, 1.154, 1.124, 1.094, 1.062, 1.034]
HYBRID_T, FIRST_WRONG, NEAREST = 0.1, 18, F_PX * BASELINE / 64


def run_near(readings, nearest=NEAREST, t0=0.0, state=None):
    states = [state or AltitudeKfState()]
    for k, z in enumerate(readings):
        states.append(altitude_kf_step(states[-1], z, True, t0 + k * HYBRID_T, KF, nearest))
    return states[1:]


def test_kf_does_not_follow_the_wrong_matches_under_the_nearest_range():
    truth = np.array(HYBRID_Z_WB) - 0.552
    states = run_near(HYBRID_RAW)
    # without the nearest range (as before it) the filter follows them: 1.1 m off, valid, at 0.5 m
    assert max(abs(s.x[0] - h) for s, h in zip(run_near(HYBRID_RAW, nearest=0.0), truth) if s.valid) > 1.0
    # with it: the true readings down to 0.668 m are used, the wrong ones not, and the coast follows the descent
    assert all(s.valid for s in states[:FIRST_WRONG + 5])
    assert all(abs(s.x[0] - h) < 0.1 for s, h in zip(states, truth) if s.valid)
    assert all(abs(s.x[0] - h) < 0.02 for s, h in zip(states[FIRST_WRONG - 3:], truth[FIRST_WRONG - 3:]) if s.valid)
    assert all(s.coast_s > 0 for s in states[FIRST_WRONG:FIRST_WRONG + 5])
    # then it lets go, and neither the wrong readings nor one alone at the range's near edge (the run read
    # 0.678 m at 0.09 m) start it again; two in a row there, as a climb back into range gives, do
    lost = states[FIRST_WRONG + 5]
    assert not lost.valid and lost.lost_near
    after = run_near([1.55, 1.6, 0.678, math.nan, 1.4, 0.7, 0.76], t0=len(HYBRID_RAW) * HYBRID_T, state=lost)
    assert [s.valid for s in after] == [False] * 6 + [True] and after[-1].x[0] == 0.76


def test_kf_lost_under_the_nearest_range_starts_again_on_a_fast_climb():
    """Lost under the range, then climbing back at 2.8 m/s (0.28 m a frame): the first reading lies in the near
    band and the next one above it, within the band's width of the first: the filter starts again there.
    A wrong match after an in-band reading (0.678 then 1.16 m, as the run read) does not start it."""
    lost = run_near(HYBRID_RAW)[-1]
    assert lost.lost_near
    t0 = len(HYBRID_RAW) * HYBRID_T
    climb = [NEAREST + 0.05 + 0.28 * k for k in range(6)]
    states = run_near(climb, t0=t0, state=lost)
    assert not states[0].valid and all(s.valid for s in states[1:])
    assert all(abs(s.x[0] - z) < 0.3 for s, z in zip(states[1:], climb[1:]))
    assert not any(s.valid for s in run_near([0.678, 1.16, 1.57, 1.47], t0=t0, state=lost))


@pytest.mark.parametrize("dropped", [None, 2])
def test_kf_near_the_nearest_range_still_follows_a_climb_out_of_it(dropped):
    """Hovering 0.25 m over the nearest range, then climbing at 1 m/s: the readings leaving the near band are
    coasted through until the filter lets go (in the band, but on a climb out of it, so not lost there), and the
    next starts it; also with a frame of the climb without a reading."""
    hover = [NEAREST + 0.25] * 10
    climb = [math.nan if k == dropped else NEAREST + 0.25 + 0.1 * k for k in range(1, 20)]
    states = run_near(hover + climb)
    assert all(s.valid for s in states[:10])
    assert not any(s.lost_near for s in states)
    assert all(s.valid and abs(s.x[0] - z) < 0.1 for s, z in zip(states[-8:], climb[-8:]))


def test_kf_let_go_in_the_near_band_does_not_start_again_on_a_wrong_match():
    """Hovering 0.15 m over the nearest range, then the UGV's roof slides under (0.3 m true, nearer than the range)
    and SGBM reads 1.4 m, flagged valid: the filter coasts through, lets go in the band, lost near, and the wrong
    readings do not start it again (before: the first after the let-go did, 1.1 m off, valid); two readings in a
    row in the band, as a climb back into range gives, do."""
    hover = [NEAREST + 0.15] * 10
    states = run_near(hover + [1.4] * 15)
    assert all(s.valid for s in states[:10])
    assert all(abs(s.x[0] - hover[0]) < 0.01 for s in states if s.valid)
    assert not states[-1].valid and states[-1].lost_near
    again = run_near([NEAREST + 0.05, NEAREST + 0.15], t0=len(states) * HYBRID_T, state=states[-1])
    assert [s.valid for s in again] == [False, True]


def test_kf_near_the_nearest_range_coasts_through_a_reading_under_it():
    """The near band is [nearest, nearest + near_band_m]: hovering 0.1 m over the nearest range, a reading 5 cm
    under it (nearer than the stereo can see: a wrong match) is not used; the filter coasts on its prediction,
    A x by hand."""
    states = run_near([NEAREST + 0.1] * 10)
    hovering = states[-1]
    coasted = altitude_kf_step(hovering, NEAREST - 0.05, True, 10 * HYBRID_T, KF, NEAREST)
    assert coasted.valid and coasted.coast_s == pytest.approx(HYBRID_T)
    np.testing.assert_allclose(coasted.x, [hovering.x[0] + HYBRID_T * hovering.x[1], hovering.x[1]], rtol=1e-12)


def test_kf_without_a_nearest_range_uses_a_reading_over_near_band_m():
    """nearest_m 0 (the default: no nearest range) has no near band: a filter hovering at 0.2 m, under near_band_m
    (0.3 m), uses a reading of 0.5 m (within the band it would coast through it, staying at 0.2 m)."""
    state = run_near([0.2] * 10 + [0.5], nearest=0.0)[-1]
    assert state.valid and state.coast_s == 0.0 and state.last_measurement == 0.5
    assert state.x[0] > 0.3


def test_kf_near_band_includes_the_nearest_range():
    """The near band is [nearest, nearest + near_band_m]: a reading exactly at the nearest range is in it, and used
    (the first reading of a climb back into range is there)."""
    state = run_near([NEAREST + 0.1, NEAREST + 0.1, NEAREST])[-1]
    assert state.valid and state.coast_s == 0.0 and state.last_measurement == NEAREST


def test_kf_a_prediction_at_the_near_bands_top_uses_a_reading_over_it():
    """Only a prediction under the near band's top (nearest + near_band_m) is in the band: one exactly there (a
    hover at the top, at rest) uses a reading over the band."""
    top = NEAREST + KF.near_band_m
    hovering = AltitudeKfState(np.array([top, 0.0]), np.diag([1e-4, 1e-2]), 0.0, top, 0.0, True)
    state = altitude_kf_step(hovering, top + 0.2, True, HYBRID_T, KF, NEAREST)
    assert state.valid and state.coast_s == 0.0 and state.last_measurement == top + 0.2


def test_kf_lost_near_does_not_start_on_a_reading_far_under_the_last():
    """Lost near, the next reading starts it only within near_band_m of the last in-band one, either way: one 0.35 m
    under it (under the nearest range too) does not, and, under the band, leaves no reading to start from."""
    lost = AltitudeKfState(time=0.0, last_measurement=NEAREST + 0.25, lost_near=True)
    state = altitude_kf_step(lost, NEAREST - 0.1, True, HYBRID_T, KF, NEAREST)
    assert not state.valid and state.lost_near and state.last_measurement is None


# ---------------------------------------------------------------------------------------------
# Bad configurations


@pytest.mark.parametrize("config, message", [
    (StereoConfig(baseline_m=0.0), "stereo.baseline_m must be positive"),
    (StereoConfig(focal_length_px=-1.0), "stereo.focal_length_px must be positive"),
    (StereoConfig(cx=800.0), "stereo.cx must lie inside the image"),
    (StereoConfig(cy=-0.6), "stereo.cy must lie inside the image"),
    (StereoConfig(near_m=0.1, far_m=0.102), "stereo.far_m must exceed stereo.near_m by over 2 %"),
    (StereoConfig(pixel_noise_std=-2.0), "stereo.pixel_noise_std must not be negative"),
    (StereoConfig(mount_xyz_m=[0.0, 0.0]), "stereo.mount_xyz_m needs 3 numbers"),
    (StereoConfig(min_altitude_m=0.11), "must be under half the image width"),
    # 376 px * 0.5 m / 0.5 m = 376 px: exactly half the 752 px width is not under it.
    (StereoConfig(focal_length_px=376.0, baseline_m=0.5, min_altitude_m=0.5), "must be under half the image width"),
    (StereoConfig(max_altitude_m=60.0), "must lie within the clipping range"),
    (StereoConfig(max_altitude_m=50.0), "must lie within the clipping range"),  # on the far plane (far_m 50)
    (StereoConfig(near_m=1.0, min_altitude_m=0.7), "must lie within the clipping range"),
    (StereoConfig(near_m=0.7, min_altitude_m=0.7), "must lie within the clipping range"),  # on the near plane
])
def test_bad_stereo_config_names_the_field(config, message):
    with pytest.raises(ConfigError, match=message):
        config.validate("stereo")


@pytest.mark.parametrize("config, message", [
    (GroundConfig(size_m=0.0), "ground.size_m must be positive"),
    (GroundConfig(texture_pixels=63), "ground.texture_pixels must lie in 64..8192"),
    (GroundConfig(texture_pixels=8193), "ground.texture_pixels must lie in 64..8192"),
])
def test_bad_ground_config_names_the_field(config, message):
    with pytest.raises(ConfigError, match=message):
        config.validate("ground")


@pytest.mark.parametrize("pixels", [64, 8192])
def test_ground_texture_pixels_at_their_limits_are_valid(pixels):
    GroundConfig(texture_pixels=pixels).validate("ground")


def test_add_stereo_pair_validates():
    from pydrake.geometry import SceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    with pytest.raises(ConfigError, match="stereo.rate_hz must be positive"):
        add_stereo_pair(builder, scene_graph, scene_graph.world_frame_id(), StereoConfig(rate_hz=0.0))


@pytest.mark.parametrize("config, message", [
    (StereoDepthConfig(block_size=4), "stereo_depth.block_size must be odd"),
    (StereoDepthConfig(num_disparities=40), "multiple of 16"),
    (StereoDepthConfig(num_disparities=32), r"does not reach the disparity at min_altitude_m \(60.0 px\)"),
    (StereoDepthConfig(window_rows=500), "larger than the 752 x 480 image"),
    (StereoDepthConfig(min_valid_fraction=0.0), "min_valid_fraction must lie in"),
    (StereoDepthConfig(estimator="mode"), "estimator must be 'mean' or 'median'"),
])
def test_bad_depth_config_names_the_field(config, message):
    with pytest.raises(ConfigError, match=message):
        config.validate(camera=StereoConfig())


@pytest.mark.parametrize("config", [StereoDepthConfig(block_size=1), StereoDepthConfig(block_size=11),
                                    StereoDepthConfig(window_cols=624)])
def test_depth_config_at_its_limits_is_valid(config):
    """Block sizes 1 and 11 (OpenCV's SGBM takes any odd size from 1); a 624 px window, which with the default
    camera starts at column round(375.5 - 312 + 0.5) = 64, the first that the 64 disparities leave matched."""
    config.validate(camera=StereoConfig())


def test_a_window_reaching_into_the_unmatched_columns_is_refused():
    """626 px wide, the window starts at column round(375.5 - 313 + 0.5) = 63, one of the first 64 that SGBM
    leaves unmatched."""
    with pytest.raises(ConfigError, match="reaches column 63 of the image, inside the first 64"):
        StereoDepthConfig(window_cols=626).validate(camera=StereoConfig())


@pytest.mark.parametrize("config, message", [
    (AltitudeKfConfig(accel_std_mps2=0.0), "altitude_kf.accel_std_mps2 must be positive"),
    (AltitudeKfConfig(measurement_std_m=0.0, measurement_std_per_m2=0.0), "cannot both be zero"),
    (AltitudeKfConfig(measurement_std_m=-0.01, measurement_std_per_m2=0.0),
     "altitude_kf.measurement_std_m must not be negative"),
    (AltitudeKfConfig(max_coast_s=-1.0), "altitude_kf.max_coast_s must not be negative"),
    (AltitudeKfConfig(near_band_m=0.0), "altitude_kf.near_band_m must be positive"),
])
def test_bad_kf_config_names_the_field(config, message):
    with pytest.raises(ConfigError, match=message):
        config.validate()
