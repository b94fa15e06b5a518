"""The pad as the gv scenes draw it: what a camera sees of its pattern (the markers or seed 001's
RQRLP) lies in the pad frame P's plane, where the truth puts it."""

import numpy as np
import pytest
from pydrake.geometry import ClippingRange, DepthRange, DepthRenderCamera, RenderCameraCore, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from pydrake.systems.sensors import RgbdSensor

from systems.config import ConfigError
from systems.sensors.camera import RENDERER_NAME, add_renderer, camera_info
from systems.vehicles.ground_vehicle_geometry import PATTERN_GAP_M, GroundVehicleGeometry, PlatformConfig

PIXELS, RANGE_M = 33, 2.0
PLATFORMS = [
    PlatformConfig(),  # the markers on the vehicle's roof
    PlatformConfig(carrier="ground", height_m=0.02, pattern="rqrlp", pad_size_m=1.2),  # open-landing's
]


@pytest.mark.parametrize("platform", PLATFORMS)
def test_a_camera_sees_the_pattern_in_the_pad_frames_plane(platform):
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    add_renderer(scene_graph)
    pad = builder.AddSystem(GroundVehicleGeometry(3.5, platform, scene_graph))
    builder.Connect(builder.AddSystem(ConstantVectorSource(np.zeros(4))).get_output_port(), pad.get_input_port())
    builder.Connect(pad.get_output_port(), scene_graph.get_source_pose_port(pad.source_id))
    # A depth camera RANGE_M over P's origin (the vehicle at rest at W's origin: P at p_VP in W), looking down.
    c = (PIXELS - 1) / 2
    core = RenderCameraCore(RENDERER_NAME, camera_info(PIXELS, PIXELS, 40.0, 40.0, c, c), ClippingRange(0.1, 10.0),
                            RigidTransform())
    X_WC = RigidTransform(RotationMatrix.MakeXRotation(np.pi), platform.p_VP + [0.0, 0.0, RANGE_M])
    camera = builder.AddSystem(RgbdSensor(scene_graph.world_frame_id(), X_WC,
                                          DepthRenderCamera(core, DepthRange(0.1, 10.0))))
    builder.Connect(scene_graph.get_query_output_port(), camera.query_object_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    depth = camera.depth_image_32F_output_port().Eval(camera.GetMyContextFromRoot(context)).data[..., 0]
    centre = depth[PIXELS // 2 - 2:PIXELS // 2 + 3, PIXELS // 2 - 2:PIXELS // 2 + 3]
    np.testing.assert_allclose(centre, RANGE_M, atol=1e-4)  # drawn 1 mm above P before dde8e8b


@pytest.mark.parametrize("platform", PLATFORMS)
def test_the_pads_white_face_lies_a_gap_under_the_pattern(platform):
    """The pattern lies in P's plane and the pad's white box from the roof (P's plane less pad_thickness_m) up to
    PATTERN_GAP_M under it: flush with the pattern, the white face won the renderer's z-fight and hid the markers."""
    scene_graph = SceneGraph()
    pad = GroundVehicleGeometry(3.5, platform, scene_graph)
    inspector = scene_graph.model_inspector()
    geometry = {inspector.GetName(g): g for g in inspector.GetGeometries(pad.body_frame_id)}
    box, pattern = geometry["gv_pad"], geometry["gv_pad_pattern"]
    assert inspector.GetPoseInFrame(pattern).translation()[2] == pytest.approx(platform.height_m, abs=1e-12)
    z, height = inspector.GetPoseInFrame(box).translation()[2], inspector.GetShape(box).height()
    assert z + height / 2 == pytest.approx(platform.height_m - PATTERN_GAP_M, abs=1e-12)
    assert z - height / 2 == pytest.approx(platform.height_m - platform.pad_thickness_m, abs=1e-12)
    assert PATTERN_GAP_M >= 1e-4  # a gap the depth buffer resolves at the cameras' metres of range


def registered(platform, wheelbase_m=3.5, state=None):
    """The geometry's shapes by name: (shape, X_FG, X_WF with the vehicle at `state`, or None for no state)."""
    scene_graph = SceneGraph()
    vehicle = GroundVehicleGeometry(wheelbase_m, platform, scene_graph)
    poses = None
    if state is not None:
        context = vehicle.CreateDefaultContext()
        vehicle.get_input_port().FixValue(context, state)
        poses = vehicle.get_output_port().Eval(context)
    inspector = scene_graph.model_inspector()
    shapes = {}
    for g in inspector.GetAllGeometryIds():
        frame = inspector.GetFrameId(g)
        X_WF = None if poses is None else poses.value(frame)
        shapes[inspector.GetName(g)] = (inspector.GetShape(g), inspector.GetPoseInFrame(g), X_WF)
    return shapes


@pytest.mark.parametrize("changes", [
    {"rear_overhang_m": 0.0},  # the rear axle at the body's back end
    {"pattern": "rqrlp", "pad_size_m": 0.85},  # the RQRLP (0.85 m, seed 001 Table 2) filling the pad
    {"pad_offset_m": -0.05},  # the pad flush with the body's rear end (-0.55 m)
    {"pad_offset_m": 3.55},  # and with its front end (4.6 - 0.55 = 4.05 m)
])
def test_a_platform_at_the_limits_of_its_bounds_validates(changes):
    PlatformConfig(**changes).validate()


@pytest.mark.parametrize("changes, message", [
    # the roof (1.6 - 0.02 = 1.58 m under the pad's top) above the 0.3 m clearance; 0.31 m leaves 0.29 m
    ({"height_m": 0.31}, r"platform\.height_m \(0\.31\) must be above"),
    # the pad (1 m) off the body's rear (-0.55 m) or front (4.05 m) end
    ({"pad_offset_m": -0.1}, r"platform\.pad_offset_m \(-0\.1\) puts the pad off the roof"),
    ({"pad_offset_m": 3.8}, r"platform\.pad_offset_m \(3\.8\) puts the pad off the roof"),
    ({"pad_thickness_m": 0.0}, r"platform\.pad_thickness_m must be positive"),
])
def test_a_platform_out_of_its_bounds_is_refused_naming_the_field(changes, message):
    with pytest.raises(ConfigError, match=message):
        PlatformConfig(**changes).validate()


def test_the_rqrlp_pattern_is_drawn_at_its_own_size_not_the_pads():
    platform = PLATFORMS[1]  # a 1.2 m pad under the RqrlpLayout's default 0.85 m pattern (seed 001 Table 2)
    assert platform.pattern_size_m == pytest.approx(0.85)
    mesh, _, _ = registered(platform)["gv_pad_pattern"]
    np.testing.assert_allclose(mesh.scale3(), [0.85, 0.85, 0.85])  # the unit quad scaled to the pattern
    box, _, _ = registered(platform)["gv_pad"]
    assert (box.width(), box.depth()) == pytest.approx((1.2, 1.2))


def test_the_body_spans_the_clearance_to_the_roof_under_the_pad():
    """Defaults: 4.6 m long from 0.55 m behind the rear axle (x -0.55 to 4.05), 1.8 m wide, from the 0.3 m ground
    clearance up to the roof under the 0.02 m pad whose top is at 1.6 m (1.58 m)."""
    box, X_VB, _ = registered(PlatformConfig())["gv_body"]
    assert (box.width(), box.depth(), box.height()) == pytest.approx((4.6, 1.8, 1.28))
    np.testing.assert_allclose(X_VB.translation(), [(-0.55 + 4.05) / 2, 0.0, (0.3 + 1.58) / 2], atol=1e-12)
    np.testing.assert_allclose(X_VB.rotation().matrix(), np.eye(3), atol=1e-12)


@pytest.mark.parametrize("name, y", [("gv_wheel_rl", 0.9), ("gv_wheel_rr", -0.9)])
def test_the_rear_wheels_stand_on_the_ground_under_the_rear_axle_with_their_axles_along_it(name, y):
    """V's origin is on the ground under the rear axle; the 0.33 m wheels half outside the 1.8 m wide body."""
    wheel, X_VG, _ = registered(PlatformConfig())[name]
    assert (wheel.radius(), wheel.length()) == pytest.approx((0.33, 0.22))
    np.testing.assert_allclose(X_VG.translation(), [0.0, y, 0.33], atol=1e-12)
    assert abs(X_VG.rotation().matrix()[:, 2] @ [0.0, 1.0, 0.0]) == pytest.approx(1.0)  # the cylinder's axis


@pytest.mark.parametrize("state, fl, fr", [
    # at (2, 1) heading along +y: the front axle 3.5 m ahead along y, the left wheel on the -x side
    ([2.0, 1.0, np.pi / 2, 0.0], [2.0 - 0.9, 1.0 + 3.5, 0.33], [2.0 + 0.9, 1.0 + 3.5, 0.33]),
    ([0.0, 0.0, 0.0, 0.3], [3.5, 0.9, 0.33], [3.5, -0.9, 0.33]),  # steering turns the wheels, not their hubs
])
def test_the_front_wheels_ride_the_wheelbase_ahead_on_the_vehicles_pose(state, fl, fr):
    shapes = registered(PlatformConfig(), 3.5, np.array(state))
    for name, expected in (("gv_wheel_fl", fl), ("gv_wheel_fr", fr)):
        _, X_FG, X_WF = shapes[name]
        np.testing.assert_allclose(X_WF.multiply(X_FG).translation(), expected, atol=1e-12)


@pytest.mark.parametrize("heading", [0.0, 1.0])
def test_positive_steering_turns_the_front_wheels_axles_counterclockwise(heading):
    """Positive steering turns the vehicle counter-clockwise (heading rate v tan(theta) / L): the front wheels'
    axles turn from the vehicle's y axis towards -x by theta."""
    steering = 0.3
    shapes = registered(PlatformConfig(), 3.5, np.array([0.0, 0.0, heading, steering]))
    axle = [-np.sin(heading + steering), np.cos(heading + steering), 0.0]
    for name in ("gv_wheel_fl", "gv_wheel_fr"):
        _, X_FG, X_WF = shapes[name]
        assert abs(X_WF.multiply(X_FG).rotation().matrix()[:, 2] @ axle) == pytest.approx(1.0)
