"""The pad as the gv scenes draw it: what a camera sees of its pattern (the markers or seed 001's
RQRLP) lies in the pad frame P's plane, where the truth puts it."""

import numpy as np
import pytest
from pydrake.geometry import ClippingRange, DepthRange, DepthRenderCamera, RenderCameraCore, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from pydrake.systems.sensors import RgbdSensor

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
