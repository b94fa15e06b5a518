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
from systems.vehicles.ground_vehicle_geometry import GroundVehicleGeometry, PlatformConfig

PIXELS, RANGE_M = 33, 2.0


@pytest.mark.parametrize("platform", [
    PlatformConfig(),  # the markers on the vehicle's roof
    PlatformConfig(carrier="ground", height_m=0.02, pattern="rqrlp", pad_size_m=1.2),  # open-landing's
])
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
