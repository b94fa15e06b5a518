"""The touchdown node as a Drake system (systems/perception/rqrlp/node_systems.py) on views of the RQRLP made
by its homography (tests/test_rqrlp_nodes.py's `view`): re-anchored on the adjustment node's pose through the
camera's mount, then chaining, with the covariance of the anchor's pixel noise and the chain's length."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.rqrlp.measurements import (
    TRACK_STEP_PX,
    adjustment_measurement,
    pose_of_body,
    touchdown_measurement,
)
from systems.perception.rqrlp.node_systems import AdjustmentNode, ApproachNode, NodeMeasurementToVector, TouchdownNode
from systems.perception.rqrlp.nodes import TouchdownTracker, layout_corners
from systems.sensors.camera import CalibrationErrorConfig
from tests.test_rqrlp_nodes import CAMERA, LAYOUT, X_CP_at, view

# A mount off the body's axis: Rx(pi) with [0, 0, -0.04], the default, is its own inverse, so X_BC and X_BC^-1
# would be taken for one another unseen.
MOUNTED = replace(CAMERA, mount_xyz_m=[0.1, 0.05, -0.04])


def _image(grey: np.ndarray) -> ImageRgba8U:
    image = ImageRgba8U(CAMERA.width, CAMERA.height)
    image.mutable_data[:, :, :3] = grey[:, :, None]
    image.mutable_data[:, :, 3] = 255
    return image


@pytest.mark.parametrize("anchor_std", [0.8, 0.1])
def test_the_touchdown_node_anchors_through_the_mount_and_weighs_the_anchor_and_the_chain(anchor_std):
    """Frame 0: the adjustment node's pose (its fit's pixel noise 0.8 px, or 0.1) anchors the node; frames 1 and 2,
    no anchor: the chained pose is the true one (the anchor X_CP = X_BC^-1 X_PB^-1, whatever the mount), and its
    covariance is touchdown_measurement's at the anchor's pixel noise, floored at MIN_PIXEL_STD (0.3 px), and k
    frames of chain: sqrt(0.8^2 + k 0.1^2) px, sqrt(0.3^2 + k 0.1^2) px for 0.1 (not the anchor's 0.1, nor the
    floor for 0.8, nor the chain's length before the frame). After the last frame's update (the pending events at
    its time) the node still shows that frame's step: it does not step again on the same frame."""
    poses = [X_CP_at(1.0 - 0.05 * k, xy=(0.02 + 0.004 * k, -0.01 - 0.003 * k), yaw_deg=30.0 + 1.5 * k)
             for k in range(3)]
    X_BC, K, period = MOUNTED.X_BC, MOUNTED.K_estimated, MOUNTED.period_s
    anchor = adjustment_measurement(poses[0], layout_corners(LAYOUT), anchor_std, 0.0, X_BC, K)
    anchor_px = max(anchor_std, 0.3)
    node = TouchdownNode(MOUNTED, LAYOUT)
    simulator = Simulator(node)
    context = simulator.get_mutable_context()
    for k, X_CP in enumerate(poses):
        if k > 0:
            simulator.AdvanceTo(k * period)  # takes frame k - 1's step with its inputs
        node.GetInputPort("color_image").FixValue(context, _image(view(X_CP)))
        node.GetInputPort("anchor").FixValue(context, AbstractValue.Make([anchor] if k == 0 else []))
        measured = node.GetOutputPort("measurement").Eval(context)
        if k == 0:
            assert measured == []  # nothing to chain from before the anchor
            continue
        assert len(measured) == 1
        m = measured[0]
        truth = pose_of_body(X_CP, X_BC)
        np.testing.assert_allclose(m.X_PB.translation(), truth.translation(), atol=0.01)
        assert m.quality == k
        assert m.view.pixel_std == pytest.approx(np.sqrt(anchor_px**2 + k * TRACK_STEP_PX**2), rel=1e-12)
        expected = touchdown_measurement(m.view.X_CP, LAYOUT.outline_corners_P, anchor_px, k, k * period, X_BC, K)
        np.testing.assert_allclose(m.pose_covariance(X_BC), expected.pose_covariance(X_BC), rtol=1e-12)
    simulator.AdvancePendingEvents()  # frame 2's update, at its own time
    (after,) = node.GetOutputPort("measurement").Eval(context)
    assert context.get_time() == 2 * period and after.quality == 2
    assert after.view.pixel_std == pytest.approx(np.sqrt(anchor_px**2 + 2 * TRACK_STEP_PX**2), rel=1e-12)
    np.testing.assert_array_equal(after.view.X_CP.GetAsMatrix34(), m.view.X_CP.GetAsMatrix34())


def test_the_touchdown_node_tracks_and_weighs_with_the_estimators_intrinsics():
    """With a calibration error (focal lengths 5 %, k1 0.01) the node's chained pose is a TouchdownTracker's with
    the estimators' K and D, anchored on frame 0 at the anchor's X_CP (X_BC^-1 X_PB^-1) and tracked on frame 1, and
    its covariance is taken through their K."""
    camera = replace(MOUNTED, calibration_error=CalibrationErrorConfig(fx_pct=5.0, fy_pct=5.0, k1=0.01))
    camera.validate()
    K_e, D_e, X_BC = camera.K_estimated, camera.D_estimated, camera.X_BC
    images = [view(X_CP_at(1.0)), view(X_CP_at(0.95, xy=(0.054, -0.033), yaw_deg=31.5))]
    anchor = adjustment_measurement(X_CP_at(1.0), layout_corners(LAYOUT), 0.8, 0.0, X_BC, K_e)
    tracker = TouchdownTracker(K_e, D_e, LAYOUT).anchored(images[0], X_BC.inverse().multiply(anchor.X_PB.inverse()))
    _, expected, _ = tracker.track(images[1])
    assert expected is not None
    node = TouchdownNode(camera, LAYOUT)
    simulator = Simulator(node)
    context = simulator.get_mutable_context()
    for k, image in enumerate(images):
        if k > 0:
            simulator.AdvanceTo(k * camera.period_s)
        node.GetInputPort("color_image").FixValue(context, _image(image))
        node.GetInputPort("anchor").FixValue(context, AbstractValue.Make([anchor] if k == 0 else []))
    (m,) = node.GetOutputPort("measurement").Eval(context)
    np.testing.assert_array_equal(m.view.K, K_e)
    np.testing.assert_allclose(m.view.X_CP.GetAsMatrix34(), expected.GetAsMatrix34(), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("node_type, height_m", [(ApproachNode, 10.0), (AdjustmentNode, 2.5)])
def test_the_image_nodes_stamp_their_measurement_with_the_contexts_time(node_type, height_m):
    node = node_type(CAMERA, LAYOUT)
    context = node.CreateDefaultContext()
    node.GetInputPort("color_image").FixValue(context, _image(view(X_CP_at(height_m))))
    context.SetTime(0.25)
    (m,) = node.GetOutputPort("measurement").Eval(context)
    assert m.time == 0.25


def test_node_measurement_to_vector():
    """A node's measurement logged as [present, X_PB's translation, its quaternion (w, x, y, z), quality]; none as
    present 0 and the rest NaN."""
    X_PB = RigidTransform(RotationMatrix.MakeZRotation(np.pi / 2), [0.1, -0.2, 1.5])
    # X_PB = (X_CP X_BC^-1)^-1: the pattern at X_CP = X_BC^-1 X_PB^-1 in the camera.
    X_CP = MOUNTED.X_BC.inverse().multiply(X_PB.inverse())
    m = adjustment_measurement(X_CP, layout_corners(LAYOUT), 0.6, 0.0, MOUNTED.X_BC, MOUNTED.K_estimated)
    to_vector = NodeMeasurementToVector()
    context = to_vector.CreateDefaultContext()
    to_vector.get_input_port().FixValue(context, AbstractValue.Make([m]))
    c = np.sqrt(0.5)  # the quaternion of a quarter turn about z: (cos 45 deg, 0, 0, sin 45 deg)
    np.testing.assert_allclose(to_vector.get_output_port().Eval(context), [1.0, 0.1, -0.2, 1.5, c, 0.0, 0.0, c, 0.6],
                               atol=1e-12)
    to_vector.get_input_port().FixValue(context, AbstractValue.Make([]))
    out = to_vector.get_output_port().Eval(context)
    assert out[0] == 0.0 and np.all(np.isnan(out[1:]))
