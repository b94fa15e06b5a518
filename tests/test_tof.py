"""ToF range sensors: the range-limit function, the TofSensors system's ideal rays cast on small
SceneGraph scenes and its cones on fixed images of their shared depth camera, and the rays in the
Stewart scenes against the analytic ray-plane distance to a tilted and a moving deck."""

import copy
import math
import re

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, FramePoseVector, GeometryFrame, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource
from pydrake.systems.sensors import ImageDepth32F
from scipy.integrate import dblquad

from diagrams.stewart_scene import StewartSceneConfig
from systems.config import ConfigError
from systems.geometry import register_collision
from systems.noise import sample_rng
from systems.platforms.stewart import TAG_ABOVE_DECK_M
from systems.sensors.tof import (
    TOF_CAMERA_BACK_M,
    TofConfig,
    TofSensors,
    apply_range_limits,
    cone_range,
    flat_target_path_factor,
    make_tof_camera,
    ray_depths,
    sensor_positions_C,
    tof_camera_view,
    view_geometry,
)


def test_sensor_positions_follow_eq_21_to_24():
    a, c = 0.135, math.cos(math.radians(45.0))
    expected = [[-a * c, -a * c, 0], [-a * c, a * c, 0], [a * c, a * c, 0], [a * c, -a * c, 0]]
    np.testing.assert_allclose(sensor_positions_C(0.135, 45.0), expected, atol=1e-15)
    # At other angles the arm stays the distance from the axis, one sensor per quadrant.
    p = sensor_positions_C(0.2, 30.0)
    np.testing.assert_allclose(np.linalg.norm(p[:, :2], axis=1), 0.2)
    np.testing.assert_allclose(np.abs(p[:, 0]), 0.2 * math.cos(math.radians(30.0)))
    np.testing.assert_array_equal(np.sign(p[:, :2]), [[-1, -1], [-1, 1], [1, 1], [1, -1]])


def test_apply_range_limits():
    true = np.array([np.nan, np.inf, 0.0, 0.03, 0.04, 1.5, 4.0, 4.01, 3.999])
    noise = np.array([0.1, 0.1, 0.1, 0.002, -0.003, 0.004, -0.005, 0.006, 0.01])
    ranges, valid = apply_range_limits(true, noise, 0.04, 4.0)
    expected_valid = np.array([0, 0, 0, 0, 1, 1, 1, 0, 1], dtype=float)
    np.testing.assert_array_equal(valid, expected_valid)
    assert valid.dtype == float
    ok = expected_valid == 1
    np.testing.assert_allclose(ranges[ok], true[ok] + noise[ok], rtol=0, atol=1e-15)
    assert np.all(np.isnan(ranges[~ok]))
    # Validity is decided on the true range: noise that carries a reading over a limit keeps it valid.
    assert ranges[-1] == pytest.approx(4.009)
    # ... but not under zero: a bias of -5 cm at 4.5 cm reads no distance (before: -0.005 m, valid).
    ranges, valid = apply_range_limits(np.array([0.045, 0.06]), np.array([-0.05, -0.05]), 0.04, 4.0)
    np.testing.assert_array_equal(valid, [0.0, 1.0])
    assert np.isnan(ranges[0]) and ranges[1] == pytest.approx(0.01)
    # A reading of exactly zero (0.05 - 0.05 is 0.0 in doubles) is no distance either: invalid and NaN.
    assert 0.05 + -0.05 == 0.0
    ranges, valid = apply_range_limits(np.array([0.05]), np.array([-0.05]), 0.04, 4.0)
    assert valid[0] == 0.0 and np.isnan(ranges[0])


def camera_image(config: TofConfig, depth_of) -> ImageDepth32F:
    """The shared depth camera's image (`make_tof_camera`) of a scene whose z-depth from the camera plane
    along K's line of sight at normalised image coordinates (x, y) is depth_of(x, y) (m; 0: too close,
    inf: nothing)."""
    pixels, f, c = tof_camera_view(config)
    x = (np.arange(pixels) - c) / f
    s = np.broadcast_to(depth_of(x[None, :], x[:, None]), (pixels, pixels))
    image = ImageDepth32F(pixels, pixels)
    image.mutable_data[..., 0] = np.where(s == 0, 0.0, TOF_CAMERA_BACK_M + s)
    return image


def tof_with_image(config: TofConfig, depth_of, seed=0):
    tof = TofSensors(config, seed)
    context = tof.CreateDefaultContext()
    tof.get_input_port().FixValue(context, camera_image(config, depth_of))
    return tof, context


# The sensors' camera frame C in the tests' scenes: at the world's origin looking down (+z_C = -z_W).
X_WC_DOWN = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.0, 0.0, 0.0])


def tof_in_scene(boxes, config: TofConfig | None = None, seed=0, frame_period_s=None):
    """TofSensors with ideal rays in a SceneGraph holding `boxes`, (X_CG, Box) pairs given in C, anchored
    in the world, and, on the frame the sensors are mounted on, a box of the UAV's own around them (which
    the rays must ignore). Returns (TofSensors, the diagram's context)."""
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    source = scene_graph.RegisterSource("test")
    mount = scene_graph.RegisterFrame(source, GeometryFrame("uav"))
    shapes = [(scene_graph.world_frame_id(), X_WC_DOWN.multiply(X_CG), box) for X_CG, box in boxes]
    shapes.append((mount, RigidTransform([0.0, 0.0, -0.01]), Box(0.4, 0.4, 0.05)))
    for i, (frame, X_FG, box) in enumerate(shapes):
        register_collision(scene_graph, source, frame, X_FG, box, f"box{i}")
    poses = FramePoseVector()
    poses.set_value(mount, RigidTransform())
    pose_source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(poses)))
    builder.Connect(pose_source.get_output_port(), scene_graph.get_source_pose_port(source))
    tof = builder.AddSystem(TofSensors(config or TofConfig(), seed, frame_period_s, (mount, X_WC_DOWN)))
    builder.Connect(scene_graph.get_query_output_port(), tof.get_input_port())
    return tof, builder.Build().CreateDefaultContext()


def quadrant_boxes(true_ranges):
    """A small box under each sensor whose face is true_ranges[i] along its axis (none for inf; around
    the sensor for 0: the sensor inside it)."""
    boxes = []
    for p_CS, r in zip(sensor_positions_C(0.135, 45.0), true_ranges):
        if np.isfinite(r):
            depth = 0.1 if r == 0 else 0.01
            boxes.append((RigidTransform(p_CS + [0.0, 0.0, r + depth / 2 - (0.05 if r == 0 else 0.0)]),
                          Box(0.05, 0.05, depth)))
    return boxes


def tof_system(true_ranges, seed=0, **config):
    """TofSensors whose rays meet a surface at each sensor's range (Eq. 21-24's order)."""
    return tof_in_scene(quadrant_boxes(true_ranges), TofConfig(**config), seed)


def outputs(tof, context, t=0.0):
    context.SetTime(t)
    own = tof.GetMyContextFromRoot(context)
    return [tof.GetOutputPort(name).Eval(own).copy() for name in ("ranges", "ranges_valid", "true_ranges")]


def test_noise_free_readings_are_the_ranges_along_the_axes():
    true = [0.5, 1.25, 2.0, 3.75]
    tof, context = tof_system(true)
    ranges, valid, truth = outputs(tof, context, 0.35)
    np.testing.assert_allclose(truth, true, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ranges, truth)
    np.testing.assert_array_equal(valid, [1, 1, 1, 1])


def test_each_sensor_reads_a_tilted_plane_along_its_own_axis():
    # The plane z_C = h + a x_C + b y_C: the top face of a large box whose +z axis is the plane's normal
    # towards the camera.
    h, a, b = 0.3, np.tan(np.radians(25.0)), -np.tan(np.radians(10.0))
    n_C = np.array([a, b, -1.0]) / np.linalg.norm([a, b, -1.0])
    thickness = 0.1
    X_CG = RigidTransform(RotationMatrix.MakeFromOneVector(n_C, 2), [0.0, 0.0, h] - n_C * thickness / 2)
    tof, context = tof_in_scene([(X_CG, Box(3.0, 3.0, thickness))])
    p_CS = sensor_positions_C(0.135, 45.0)
    expected = h + a * p_CS[:, 0] + b * p_CS[:, 1]
    assert np.ptp(expected) > 0.05
    np.testing.assert_allclose(outputs(tof, context)[2], expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("edge_offset_m", [-0.03, -0.01, -1e-3, -1e-5, 1e-5, 1e-3, 0.01, 0.03])
def test_a_ray_beside_an_edge_reads_the_surface_it_meets(edge_offset_m):
    # A deck 1 m away up to x_C = edge_offset_m past sensors 3 and 4's axes, the ground 2 m away beyond:
    # the rays read the deck or the ground, the one their axis meets, however near the edge passes.
    x_edge = sensor_positions_C(0.135, 45.0)[2, 0] + edge_offset_m
    deck = (RigidTransform([x_edge - 1.0, 0.0, 1.05]), Box(2.0, 2.0, 0.1))
    ground = (RigidTransform([0.0, 0.0, 2.05]), Box(5.0, 5.0, 0.1))
    tof, context = tof_in_scene([deck, ground])
    truth = outputs(tof, context)[2]
    np.testing.assert_allclose(truth[:2], 1.0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(truth[2:], 1.0 if edge_offset_m > 0 else 2.0, rtol=0, atol=1e-6)


def test_out_of_range_and_unseen_give_nan_and_invalid():
    # Nothing seen (inf), the sensor inside a geometry (0), below the 0.04 m minimum, above the 4 m maximum.
    tof, context = tof_system([np.inf, 0.0, 0.02, 4.5], noise_std_m=0.01)
    ranges, valid, truth = outputs(tof, context, 1.0)
    assert np.all(np.isnan(ranges))
    np.testing.assert_array_equal(valid, [0, 0, 0, 0])
    assert truth[0] == np.inf and truth[1] == 0.0 and truth[3] == pytest.approx(4.5)


def test_noise_has_the_configured_std_and_is_seeded():
    std, period = 0.01, 1.0 / 20.0
    tof, context = tof_system([1.0, 2.0, 3.0, 3.5], noise_std_m=std)
    truth = np.array([1.0, 2.0, 3.0, 3.5])
    errors = np.array([outputs(tof, context, k * period)[0] - truth for k in range(1500)])
    assert np.all(np.abs(errors) < 6 * std)
    assert np.std(errors) == pytest.approx(std, rel=0.05)
    assert abs(np.mean(errors)) < 4 * std / math.sqrt(errors.size)
    # Independent from sensor to sensor and from sample to sample.
    assert np.max(np.abs(np.corrcoef(errors.T) - np.eye(4))) < 0.12
    assert abs(np.corrcoef(errors[:-1, 0], errors[1:, 0])[0, 1]) < 0.12
    # The same time gives the same noise; another seed other noise.
    np.testing.assert_array_equal(outputs(tof, context, 7 * period)[0] - truth, errors[7])
    other, other_context = tof_system(truth, seed=1, noise_std_m=std)
    assert np.all(outputs(other, other_context, 7 * period)[0] - truth != errors[7])


def cone_system(depth_of, **config):
    """TofSensors with a 27 degree cone whose camera sees the z-depth depth_of(x, y) along its line of
    sight at normalised image coordinates (x, y)."""
    return tof_with_image(TofConfig(cone_deg=27.0, **config), depth_of)


def cone_mean_path_per_m(z_per_m, half_angle: float) -> float:
    """The power-weighted mean path over a cone of the given half angle (rad), per metre, by quadrature over its
    disc in normalised image coordinates (x, y): the surface at z-depth z_per_m(x, y), a path z s (s = sqrt(1 +
    x^2 + y^2)) returning power s^-3 / (z s)^2, its solid angle (cos^3 in the image plane) over the squared path."""
    def integrand(rho, theta, moment):
        x, y, s = rho * math.cos(theta), rho * math.sin(theta), math.sqrt(1.0 + rho * rho)
        path = z_per_m(x, y) * s
        return path**moment * s**-3 / path**2 * rho

    def integral(moment):
        return dblquad(integrand, 0.0, 2.0 * math.pi, 0.0, math.tan(half_angle), args=(moment,))[0]

    return integral(1) / integral(0)


def test_a_cone_over_a_plane_square_to_its_axis_reads_its_distance():
    # A sensor's ranging is calibrated on a flat target square to its axis, which the VL53L1X reads to its
    # datasheet's +-20 mm all told. The raw power-weighted mean path there is 1.38 % long over a 27 deg cone
    # (28 mm at 2 m, more than that accuracy): the reading is that mean over this factor.
    half = math.radians(13.5)
    assert flat_target_path_factor(31, 27.0) == pytest.approx(cone_mean_path_per_m(lambda x, y: 1.0, half), rel=2e-4)
    assert flat_target_path_factor(31, 27.0) > 1.013
    for h in (0.5, 2.0, 3.5):
        tof, context = cone_system(lambda x, y: h)
        ranges, valid, truth = outputs(tof, context)
        np.testing.assert_allclose(ranges, h, rtol=1e-6)
        np.testing.assert_allclose(truth, h, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(valid, 1.0)


@pytest.mark.parametrize("tilt_deg", [8.0, 16.0])
def test_a_cone_over_a_tilted_plane_reads_its_calibrated_power_weighted_mean_path(tilt_deg):
    # A plane 2 m along the axis tilted about y: the near side returns more power, so the reading is short of the
    # axis' 2 m (0.56 mm at 8 deg, 2.3 mm at 16 deg), as the quadrature of the same physics says to 2 %.
    h, half, slope = 2.0, math.radians(13.5), math.tan(math.radians(tilt_deg))
    x, _, _ = view_geometry(31, 27.0)
    depth = np.broadcast_to(h / (1.0 + x[None, :] * slope), (31, 31))
    expected = h * cone_mean_path_per_m(lambda x, y: 1.0 / (1.0 + x * slope), half) / cone_mean_path_per_m(
        lambda x, y: 1.0, half)
    assert expected < h - 0.0005
    assert cone_range(depth, 27.0) - h == pytest.approx(expected - h, rel=0.02)


def deck_before_ground(x, y):
    """The shared depth camera's z-depth (`camera_image`) of a deck 1 m away up to x_C = 0.045 m and the ground
    2 m away beyond."""
    return np.where(x * (TOF_CAMERA_BACK_M + 1.0) < 0.045, 1.0, 2.0) + 0 * y


def test_a_cone_partly_over_an_edge_reads_between_the_two_surfaces_nearer_the_near_one():
    # A deck 1 m away up to x_C = 0.045 m, the ground 2 m away beyond: the cones of sensors 3 and 4
    # (x_C = +0.095 m) see the deck on their rays more than 0.05 m off their axes towards -x (about 0.37 of
    # the cone), and it returns 4 times the power per patch; their axes see the ground.
    tof, context = cone_system(deck_before_ground)
    ranges, _, truth = outputs(tof, context)
    assert np.all((ranges[2:] > 1.1) & (ranges[2:] < 1.5)), ranges
    np.testing.assert_allclose(truth[2:], 2.0, rtol=0, atol=1e-9)


def test_a_cone_s_range_noise_grows_with_its_reading_not_with_its_axis_range():
    """noise_std_per_m scales the noise by the cone's noise-free reading (what it ranges), not by its axis' true
    range: over the deck's edge sensors 3 and 4 read 1.1-1.5 m while their axes see the ground at 2 m. Each
    reading is the noise-free one plus its std, noise_std_per_m times that reading, times the k = 0 draw of the
    "tof" noise stream (seed 0)."""
    clean, _, truth = outputs(*cone_system(deck_before_ground))
    noisy, valid, _ = outputs(*cone_system(deck_before_ground, noise_std_per_m=0.01))
    assert np.all(clean[2:] < 1.5) and np.all(truth[2:] == 2.0)
    z = sample_rng(0, "tof", 0).standard_normal(4)
    assert np.all(np.abs(z[2:]) > 0.2)  # draws large enough to tell a std scaled by 1.2 m from one by 2 m
    np.testing.assert_array_equal(valid, 1.0)
    np.testing.assert_allclose(noisy, clean * (1 + 0.01 * z), rtol=1e-12, atol=0)


def test_ray_depths_on_a_plane_tilted_about_x_are_the_ray_plane_depths():
    """ray_depths places each ray's point in K's image by both its x and its y (sensor offset and direction):
    on the plane z_C = h + b y_C (tilted about x), a ray from p_S along [x_S, y_S, 1] meets it at
    s = (h + b y_S0) / (1 - b y_S), y_S0 the sensor's y, with x_S0 != y_S0 so the two cannot be swapped."""
    config = TofConfig(cone_deg=27.0)
    _, f, c = tof_camera_view(config)
    h, b = 2.0, math.tan(math.radians(15.0))
    # K's line of sight at (x, y) meets the plane at K-depth (h + back) / (1 - b y), z-depth from C's plane less back.
    depth_K = camera_image(config, lambda x, y: (h + TOF_CAMERA_BACK_M) / (1 - b * y) - TOF_CAMERA_BACK_M + 0 * x)
    p_CS = np.array([[0.09, -0.05, 0.0], [-0.1, 0.12, 0.0], [0.02, 0.1, 0.0], [-0.08, -0.11, 0.0]])
    x_S, y_S = np.array([0.0, 0.1, -0.2, 0.05]), np.array([0.0, -0.1, 0.2, 0.15])
    s = ray_depths(depth_K.data[..., 0], f, c, p_CS, x_S, y_S)
    np.testing.assert_allclose(s, (h + b * p_CS[:, 1]) / (1 - b * y_S), rtol=1e-6)


def test_ray_depths_across_a_depth_step_read_one_side_or_the_other():
    """Where a ray's point in K's image falls between pixels either side of an edge (1 m deck, 2 m ground),
    ray_depths takes the nearest pixel's depth: every reading is 1 m or 2 m, none between (an interpolated
    inverse depth would be a surface that is not there)."""
    config = TofConfig(cone_deg=27.0)
    _, f, c = tof_camera_view(config)
    edge = 0.045
    depth_K = camera_image(config, lambda x, y: np.where(x * (TOF_CAMERA_BACK_M + 1.0) < edge, 1.0, 2.0) + 0 * y)
    x_S = np.linspace(-0.06, 0.0, 61)
    p_CS = np.repeat(sensor_positions_C(0.135, 45.0)[2:3], len(x_S), axis=0)
    s = ray_depths(depth_K.data[..., 0], f, c, p_CS, x_S, np.zeros_like(x_S))
    assert np.all(np.isclose(s, 1.0, rtol=1e-6) | np.isclose(s, 2.0, rtol=1e-6)), s
    assert np.any(np.isclose(s, 1.0, rtol=1e-6)) and np.any(np.isclose(s, 2.0, rtol=1e-6))  # both sides are read


def test_a_cone_reads_past_pixels_too_close_to_render():
    """A plane 1 m square to the axis with the top three rows of the cone's image too close to render (depth 0):
    those pixels return nothing, as pixels that see nothing (inf) do; the rest read about 1 m, not NaN."""
    too_close, unseen = np.full((31, 31), 1.0), np.full((31, 31), 1.0)
    too_close[:3, :], unseen[:3, :] = 0.0, np.inf
    _, _, in_cone = view_geometry(31, 27.0)
    assert in_cone[:3, :].any()  # the rows are in the cone
    assert cone_range(too_close, 27.0) == pytest.approx(1.0, abs=0.02)
    assert cone_range(too_close, 27.0) == cone_range(unseen, 27.0)


def test_ray_depths_over_a_surface_too_close_to_render_read_zero():
    """K's depth image all 0 (a surface nearer than its near clipping plane): every ray reads 0, too close (as
    documented), not inf, nothing seen."""
    config = TofConfig(cone_deg=27.0)
    pixels, f, c = tof_camera_view(config)
    p_CS = sensor_positions_C(0.135, 45.0)
    s = ray_depths(np.zeros((pixels, pixels), np.float32), f, c, p_CS, np.zeros(len(p_CS)), np.zeros(len(p_CS)))
    np.testing.assert_array_equal(s, 0.0)


def test_ray_depths_past_the_edge_of_the_only_surface_read_nothing():
    """A deck 2 m away only for x_C < 0.04 m, nothing beyond: sensor 3's axis (x_C = 0.0955 m) passes it and reads
    inf. Followed out to the far clipping plane (20 m) its point in K's image, x_C / (back + s), stays beyond the deck's
    edge there (at 0.04 m / (back + 2 m)); a ray followed to infinity would land on K's centre, where the deck is."""
    config = TofConfig(cone_deg=27.0)
    _, f, c = tof_camera_view(config)
    edge = 0.04
    depth_K = camera_image(config, lambda x, y: np.where(x * (TOF_CAMERA_BACK_M + 2.0) < edge, 2.0, np.inf) + 0 * y)
    p_CS = sensor_positions_C(0.135, 45.0)[2:3]
    # At the far clipping plane the ray is over a pixel of K beyond the deck's edge: both pixels around it see nothing.
    assert f * (p_CS[0, 0] / (TOF_CAMERA_BACK_M + 20.0) - edge / (TOF_CAMERA_BACK_M + 2.0)) > 1.0
    s = ray_depths(depth_K.data[..., 0], f, c, p_CS, np.zeros(1), np.zeros(1))
    assert s[0] == np.inf, s


def test_the_shared_depth_camera_sees_every_cone_ray_out_to_twice_the_maximum_range():
    """K (tof_camera_view) is wide enough for every cone ray from the camera plane out to 2 x max_range_m (8 m) with
    two pixels of margin: sensor 3's outermost ray towards +x (the 31-pixel grid's last column, half a pixel inside
    the 13.5 deg half cone) is 2 pixels inside K's image edge at 8 m, and over a plane square to the axis at 7.95 m,
    just inside that reach, it reads the plane's 7.95 m, not inf."""
    config = TofConfig(cone_deg=27.0)
    pixels, f, c = tof_camera_view(config)
    x_edge = 15 * math.tan(math.radians(13.5)) / 15.5
    assert np.max(view_geometry(31, 27.0)[0]) == pytest.approx(x_edge, rel=1e-12)
    p_CS = sensor_positions_C(0.135, 45.0)[2:3]
    # Pixel centres 0..127: the image's edge is at 127.5, two pixels inside it 125.5.
    assert c + f * (p_CS[0, 0] + 8.0 * x_edge) / (TOF_CAMERA_BACK_M + 8.0) == pytest.approx(pixels - 0.5 - 2, abs=1e-9)
    depth_K = camera_image(config, lambda x, y: 7.95 + 0 * x * y)
    s = ray_depths(depth_K.data[..., 0], f, c, p_CS, np.array([x_edge]), np.zeros(1))
    np.testing.assert_allclose(s, 7.95, rtol=1e-6)


def test_the_shared_depth_camera_sits_behind_the_camera_plane_on_its_axis_with_the_sensors_ranges():
    """make_tof_camera: K at X_PK = X_PC [I, (0, 0, -TOF_CAMERA_BACK_M)], oriented like C on its axis behind its
    plane, with tof_camera_view's intrinsics; it clips at the sensors' 5 mm-20 m from the camera plane and reads
    depths within 5.05 mm-19.8 m of it (0 nearer, inf farther)."""
    config = TofConfig(cone_deg=27.0)
    X_PC = RigidTransform(RollPitchYaw(0.3, -0.2, 1.1), [0.4, -0.7, 2.5])
    sensor = make_tof_camera(SceneGraph().world_frame_id(), X_PC, config)
    R_PC = X_PC.rotation().matrix()
    camera = sensor.default_depth_render_camera()
    np.testing.assert_allclose(camera.core().sensor_pose_in_camera_body().GetAsMatrix4(), np.eye(4), atol=0)
    X_PK = sensor.default_X_PB()
    np.testing.assert_allclose(X_PK.rotation().matrix(), R_PC, rtol=0, atol=1e-15)
    np.testing.assert_allclose(X_PK.translation(), X_PC.translation() - TOF_CAMERA_BACK_M * R_PC[:, 2], rtol=0,
                               atol=1e-12)
    pixels, f, c = tof_camera_view(config)
    intrinsics = camera.core().intrinsics()
    assert (intrinsics.width(), intrinsics.height()) == (pixels, pixels)
    # Centred: Drake's principal point is at the image's middle (its pixel centres at +0.5).
    assert (intrinsics.focal_x(), intrinsics.focal_y(), intrinsics.center_x(), intrinsics.center_y()) == (
        f, f, pixels / 2, pixels / 2)
    clipping, depth_range = camera.core().clipping(), camera.depth_range()
    assert clipping.near() - TOF_CAMERA_BACK_M == pytest.approx(0.005, abs=1e-9)
    assert clipping.far() - TOF_CAMERA_BACK_M == pytest.approx(20.0, abs=1e-9)
    assert depth_range.min_depth() - TOF_CAMERA_BACK_M == pytest.approx(0.00505, abs=1e-9)
    assert depth_range.max_depth() - TOF_CAMERA_BACK_M == pytest.approx(19.8, abs=1e-9)


def test_a_cone_that_sees_nothing_is_invalid():
    tof, context = cone_system(lambda x, y: np.inf)
    ranges, valid, _ = outputs(tof, context)
    assert np.all(np.isnan(ranges)) and np.all(valid == 0)


def test_triggered_by_a_faster_camera_every_frame_draws_its_own_noise():
    config = TofConfig(noise_std_m=0.01)  # rate_hz 20: unused when the camera triggers the readings
    ranges = [2.0, 2.0, 2.0, 2.0]
    tof, context = tof_in_scene(quadrant_boxes(ranges), config, frame_period_s=0.04)  # a 25 Hz camera
    readings = np.array([outputs(tof, context, 0.04 * k)[0] for k in range(12)])
    assert len(np.unique(readings[:, 0])) == 12  # numbered by the camera's frames, none repeated
    at_own_rate, own_context = tof_in_scene(quadrant_boxes(ranges), TofConfig(noise_std_m=0.01, rate_hz=25.0))
    np.testing.assert_array_equal(readings, [outputs(at_own_rate, own_context, 0.04 * k)[0] for k in range(12)])
    assert np.all(np.abs(readings - ranges) < 0.05)


def test_on_its_own_clock_every_reading_draws_its_own_noise_whatever_the_camera_period():
    """trigger own_clock at 30 Hz beside a 20 Hz camera (frame_period_s 0.05 s): the readings are numbered for their
    noise by their own clock, so the 12 taken at k / 30 s (the periodic update's) have 12 distinct noise draws;
    numbered by the camera's period, round(k 30 / 20) would give 8 distinct numbers for 12 readings."""
    ranges = [2.0, 2.0, 2.0, 2.0]
    config = TofConfig(trigger="own_clock", rate_hz=30.0, noise_std_m=0.01)
    tof, context = tof_in_scene(quadrant_boxes(ranges), config, frame_period_s=0.05)
    own = tof.GetMyContextFromRoot(context)
    readings = []
    for k in range(12):
        context.SetTime(k / 30.0)
        readings.append(tof.EvalUniquePeriodicDiscreteUpdate(own).value()[:4].copy())
    readings = np.array(readings)
    assert len(np.unique(readings[:, 0])) == 12
    assert np.all(np.abs(readings - ranges) < 0.05)


def test_on_its_own_clock_the_readings_are_taken_at_its_rate_from_its_offset():
    config = TofConfig(trigger="own_clock", rate_hz=30.0, time_offset_s=0.01)
    tof, _ = tof_in_scene(quadrant_boxes([1.0, 1.0, 1.0, 1.0]), config, frame_period_s=0.05)
    event = tof.GetUniquePeriodicDiscreteUpdateAttribute()
    assert event.period_sec() == pytest.approx(1.0 / 30.0, rel=1e-15)
    assert event.offset_sec() == 0.01


def test_on_its_own_clock_before_its_first_reading_it_outputs_nan_invalid_and_inf():
    """Before the first reading (time_offset_s 0.01 s) the held outputs are no reading: ranges NaN, valid 0 and
    true ranges inf (nothing seen), as the class documents, though the boxes are 1 m under the sensors."""
    config = TofConfig(trigger="own_clock", rate_hz=30.0, time_offset_s=0.01)
    tof, context = tof_in_scene(quadrant_boxes([1.0, 1.0, 1.0, 1.0]), config)
    ranges, valid, truth = outputs(tof, context, 0.0)
    assert np.all(np.isnan(ranges))
    np.testing.assert_array_equal(valid, 0.0)
    assert np.all(np.isposinf(truth)), truth


def test_range_noise_grows_with_range_and_the_bias_offsets_every_reading():
    period, truth = 1.0 / 20.0, np.array([0.5, 1.0, 2.0, 3.0])
    tof, context = tof_system(truth, noise_std_m=0.002, noise_std_per_m=0.004, bias_m=0.01)
    errors = np.array([outputs(tof, context, k * period)[0] - truth for k in range(2000)])
    np.testing.assert_allclose(np.mean(errors, axis=0), 0.01, atol=4 * 0.014 / math.sqrt(2000))
    np.testing.assert_allclose(np.std(errors, axis=0), 0.002 + 0.004 * truth, rtol=0.06)


@pytest.mark.parametrize("changes, field", [
    ({"max_range_m": 0.03}, "tof.max_range_m"),
    ({"min_range_m": 0.0}, "tof.min_range_m must be positive"),
    ({"min_range_m": 1.0, "max_range_m": 1.0}, "tof.max_range_m must exceed tof.min_range_m"),  # an empty range
    ({"max_range_m": 25.0}, "tof.max_range_m"),
    ({"max_range_m": 20.0}, "tof.max_range_m must be below 20.0 m"),  # the render range's far end itself
    ({"noise_std_m": -0.1}, "tof.noise_std_m"),
    ({"rate_hz": 0.0}, "tof.rate_hz"),
    ({"arm_m": -0.1}, "tof.arm_m"),
    ({"cone_deg": 120.0}, "tof.cone_deg"),
    ({"cone_deg": 90.01}, "tof.cone_deg must lie within 0-90 deg"),
    ({"noise_std_per_m": -0.01}, "tof.noise_std_per_m"),
    ({"trigger": "free"}, "tof.trigger"),
    ({"trigger": "own_clock", "time_offset_s": 0.05}, "tof.time_offset_s"),
    ({"trigger": "own_clock", "time_offset_s": -0.01}, "tof.time_offset_s"),
    ({"time_offset_s": 0.01}, "tof.time_offset_s"),
    ({"angle_deg": 1e-9}, "tof.arm_m and tof.angle_deg give the sensors |y| = 2.36e-09 mm in C, under the 1 mm"),
    ({"angle_deg": 89.6}, "tof.arm_m and tof.angle_deg give the sensors |x| = 0.942 mm in C"),
    ({"arm_m": 0.0014}, "tof.arm_m and tof.angle_deg give the sensors |x| = 0.99 mm in C"),
])
def test_invalid_configuration_names_the_field(changes, field):
    with pytest.raises(ConfigError, match=re.escape(field)):
        TofSensors(TofConfig(**changes))


def test_the_checks_accept_their_bounds():
    """A 90 deg cone, and sensors exactly 1 mm off an axis: at 45 deg an arm of sqrt(2) mm puts them at |y| = 1 mm
    to the last bit (|x| one bit more)."""
    arm_m = 0.0014142135623730952
    offsets_m = np.abs(sensor_positions_C(arm_m, 45.0)[0, :2])
    assert offsets_m[1] == 1e-3 and offsets_m[0] >= 1e-3
    TofConfig(arm_m=arm_m, angle_deg=45.0).validate()
    TofConfig(cone_deg=90.0).validate()


def analytic_ranges(scene, X_WP=None):
    """Distance along +z of each sensor frame (at p_CS_i, oriented like the camera) to the tag plate's
    top plane, TAG_ABOVE_DECK_M above the top surface of the deck at X_WP (the static deck's by default);
    and the hit points in the deck frame."""
    c = scene.config.tof
    u, v = c.arm_m * math.cos(math.radians(c.angle_deg)), c.arm_m * math.sin(math.radians(c.angle_deg))
    X_WC, X_WP = scene.X_WC(), X_WP or scene.X_WP_static()
    d_W = X_WC.rotation().matrix()[:, 2]
    n_W = X_WP.rotation().matrix()[:, 2]
    p_plane = X_WP.multiply(np.array([0.0, 0.0, TAG_ABOVE_DECK_M]))
    ranges, hits_P = [], []
    for p_CS in ([-u, -v, 0], [-u, v, 0], [u, v, 0], [u, -v, 0]):
        p_W = X_WC.multiply(np.array(p_CS, dtype=float))
        r = n_W @ (p_plane - p_W) / (n_W @ d_W)
        ranges.append(r)
        hits_P.append(X_WP.inverse().multiply(p_W + r * d_W))
    return np.array(ranges), np.array(hits_P)


@pytest.mark.parametrize("scene_name", ["hover_scene", "tilted_scene"])
def test_rendered_ranges_match_the_ray_plane_distance(scene_name, request):
    scene = request.getfixturevalue(scene_name)
    expected, hits_P = analytic_ranges(scene)
    # The rays land on the tag plate (edge tag_size_m * 10/8), so its top plane is the right one.
    assert np.all(np.abs(hits_P[:, :2]) < scene.config.platform.tag_size_m * 10 / 8 / 2 - 0.02)
    if scene_name == "tilted_scene":
        assert np.ptp(expected) > 0.03  # the tilt makes the four ranges differ by centimetres
    context = scene.context()
    truth = scene.eval(scene.handles.tof, "true_ranges", context)
    # The rays are cast on the scene's geometry: exact to the cast's 0.1 um, far below the 0.5 mm the tag
    # plate floats above the deck.
    np.testing.assert_allclose(truth, expected, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(scene.eval(scene.handles.tof, "ranges", context), truth)
    np.testing.assert_array_equal(scene.eval(scene.handles.tof, "ranges_valid", context), [1, 1, 1, 1])


def test_rendered_ranges_follow_the_moving_deck(dynamic_run):
    # stewart-dynamic's deck (8 deg of roll and pitch, 10 of yaw, centimetres of translation) at 40 times
    # over its 200 s: each ray cast gives its analytic distance to the tag plate.
    scene = dynamic_run[0]
    errors = []
    for t in np.linspace(0.0, 200.0, 40):
        expected, hits_P = analytic_ranges(scene, scene.handles.platform.X_WP(t))
        assert np.all(np.abs(hits_P[:, :2]) < scene.config.platform.tag_size_m * 10 / 8 / 2 - 0.02)
        errors.append(scene.eval(scene.handles.tof, "true_ranges", scene.context(t)) - expected)
    assert np.max(np.abs(errors)) < 1e-6, np.max(np.abs(errors))


def test_on_its_own_clock_a_frame_reads_the_last_reading_taken_before_it(dynamic_run, build_scene):
    from pydrake.systems.analysis import Simulator

    from diagrams.stewart_run import collect_log

    config = copy.deepcopy(dynamic_run[0].config)
    config.tof.trigger, config.tof.rate_hz, config.tof.time_offset_s = "own_clock", 30.0, 0.01
    config.tof.noise_std_m, config.estimators = 0.0, []
    scene = build_scene(config)
    simulator = Simulator(scene.diagram)
    simulator.AdvanceTo(1.0)
    log = collect_log(scene.handles, simulator.get_context(), config)
    frames = log["t"]
    assert np.all(np.isnan(log["ranges"][frames < 0.01])) and not log["ranges_valid"][frames < 0.01].any()
    later = frames > 0.01
    # The readings at 0.01 + k / 30 s; the 20 Hz frames never coincide with them.
    taken = 0.01 + np.floor((frames[later] - 0.01) * 30.0) / 30.0
    expected = np.array([analytic_ranges(scene, scene.handles.platform.X_WP(t))[0] for t in taken])
    np.testing.assert_allclose(log["ranges"][later], expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(log["true_ranges"][later], expected, rtol=0, atol=1e-6)
    # Not the deck at the frame's own time: the readings are 0-33 ms old, the deck moves under them.
    at_frame = np.array([analytic_ranges(scene, scene.handles.platform.X_WP(t))[0] for t in frames[later]])
    assert np.max(np.abs(log["ranges"][later] - at_frame)) > 3e-4
    assert len(np.unique(log["ranges"][later][:, 0])) == len(taken)  # no reading read twice at 20 of 30 Hz


def test_noisy_ranges_scatter_about_the_rendered_truth(tilted_scene, build_scene):
    config = copy.deepcopy(tilted_scene.config)
    config.tof.noise_std_m = 0.01
    scene = build_scene(config)
    errors = []
    for k in range(20):
        context = scene.context(k * config.tof.period_s)
        errors.append(scene.eval(scene.handles.tof, "ranges", context)
                      - scene.eval(scene.handles.tof, "true_ranges", context))
    errors = np.array(errors)
    assert np.all(np.abs(errors) < 5 * 0.01)
    assert 0.5 * 0.01 < np.std(errors) < 1.5 * 0.01


def test_out_of_range_hover_gives_nan_and_invalid(build_scene):
    config = StewartSceneConfig()
    config.hover.height_above_deck_m = 5.0
    config.tof.max_range_m = 4.0
    scene = build_scene(config)
    context = scene.context()
    truth = scene.eval(scene.handles.tof, "true_ranges", context)
    np.testing.assert_allclose(truth, 5.0 - TAG_ABOVE_DECK_M, rtol=0, atol=1e-6)
    assert np.all(np.isnan(scene.eval(scene.handles.tof, "ranges", context)))
    np.testing.assert_array_equal(scene.eval(scene.handles.tof, "ranges_valid", context), [0, 0, 0, 0])


def test_the_rays_see_every_geometry_the_camera_sees(hover_scene):
    # Each frame's camera-seen (perception) geometry has a ray-seen (proximity) counterpart, the UAV's
    # own excepted (the rays ignore it): the deck and base themselves, the tag's mesh a box to its face.
    from pydrake.geometry import Role

    from diagrams.crhf_calibration import build_calibration_scene
    from diagrams.runner import load_scenario

    _, calibration = load_scenario("crhf-calibration")
    scenes = [(hover_scene.handles.scene_graph, hover_scene.diagram, hover_scene.handles.airframe.body_frame_id)]
    diagram, handles = build_calibration_scene(calibration)
    scenes.append((handles.scene_graph, diagram, handles.airframe.body_frame_id))
    for scene_graph, diagram, uav in scenes:
        inspector = scene_graph.model_inspector()
        frames = [f for f in inspector.GetAllFrameIds() if f != uav]
        seen = {f: inspector.NumGeometriesForFrameWithRole(f, Role.kPerception) for f in frames}
        ranged = {f: inspector.NumGeometriesForFrameWithRole(f, Role.kProximity) for f in frames}
        assert sum(seen.values()) >= 5
        assert all(ranged[f] >= seen[f] for f in frames), {inspector.GetName(f): (seen[f], ranged[f]) for f in frames}
