"""The touchdown node as a Drake system (systems/perception/rqrlp/node_systems.py) on views of the RQRLP made
by its homography (tests/test_rqrlp_nodes.py's `view`): re-anchored on the adjustment node's pose through the
camera's mount, then chaining, with the covariance of the anchor's pixel noise and the chain's length."""

from dataclasses import replace

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.rqrlp.measurements import (
    TRACK_STEP_PX,
    adjustment_measurement,
    pose_of_body,
    touchdown_measurement,
)
from systems.perception.rqrlp.node_systems import TouchdownNode
from systems.perception.rqrlp.nodes import layout_corners
from tests.test_rqrlp_nodes import CAMERA, LAYOUT, X_CP_at, view

# A mount off the body's axis: Rx(pi) with [0, 0, -0.04], the default, is its own inverse, so X_BC and X_BC^-1
# would be taken for one another unseen.
MOUNTED = replace(CAMERA, mount_xyz_m=[0.1, 0.05, -0.04])


def _image(grey: np.ndarray) -> ImageRgba8U:
    image = ImageRgba8U(CAMERA.width, CAMERA.height)
    image.mutable_data[:, :, :3] = grey[:, :, None]
    image.mutable_data[:, :, 3] = 255
    return image


def test_the_touchdown_node_anchors_through_the_mount_and_weighs_the_anchor_and_the_chain():
    """Frame 0: the adjustment node's pose (its fit's pixel noise 0.8 px) anchors the node; frames 1 and 2, no
    anchor: the chained pose is the true one (the anchor X_CP = X_BC^-1 X_PB^-1, whatever the mount), and its
    covariance is touchdown_measurement's at the anchor's 0.8 px and k frames of chain, sqrt(0.8^2 + k 0.1^2) px
    (not the floor MIN_PIXEL_STD, nor the chain's length before the frame)."""
    poses = [X_CP_at(1.0 - 0.05 * k, xy=(0.02 + 0.004 * k, -0.01 - 0.003 * k), yaw_deg=30.0 + 1.5 * k)
             for k in range(3)]
    X_BC, K, period = MOUNTED.X_BC, MOUNTED.K_estimated, MOUNTED.period_s
    anchor = adjustment_measurement(poses[0], layout_corners(LAYOUT), 0.8, 0.0, X_BC, K)
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
        assert m.view.pixel_std == pytest.approx(np.sqrt(0.8**2 + k * TRACK_STEP_PX**2), rel=1e-12)
        expected = touchdown_measurement(m.view.X_CP, LAYOUT.outline_corners_P, anchor.quality, k, k * period, X_BC, K)
        np.testing.assert_allclose(m.pose_covariance(X_BC), expected.pose_covariance(X_BC), rtol=1e-12)
