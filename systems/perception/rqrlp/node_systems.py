"""Seed 001's three vision nodes (nodes.py) as Drake systems on the camera's stream.

Each has input `color_image` (ImageRgba8U, the distorted camera image) and output `measurement`:
a list holding the node's NodeMeasurement (measurements.py, stamped with the context's time), empty
where the node found nothing. The approaching and adjustment nodes are functions of the frame, computed when evaluated:
evaluate them at the camera rate (the federated filter does, at its camera steps). The touchdown
node keeps its tracker between frames (stepped at the camera rate) and takes the adjustment node's
`anchor` input: it chains from the previous frame (Eq. 3) and re-anchors on every adjustment pose.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.aruco import to_grey
from systems.perception.rqrlp.measurements import (
    MIN_PIXEL_STD,
    NODE_VECTOR_SIZE,
    NodeMeasurement,
    adjustment_measurement,
    approach_measurement,
    node_vector,
    touchdown_measurement,
)
from systems.perception.rqrlp.nodes import TouchdownTracker, adjustment, approach, layout_corners
from systems.perception.rqrlp.pattern import RqrlpLayout
from systems.sensors.camera import CameraConfig, image_to_numpy
from systems.stepped import SteppedValue


def as_list(measurement: NodeMeasurement | None) -> list:
    """A node's output port value: [measurement], or [] for None."""
    return [] if measurement is None else [measurement]


def first(measurements: list) -> NodeMeasurement | None:
    """The measurement in a node's output, or None."""
    return measurements[0] if measurements else None


def approach_node(grey: np.ndarray, time: float, camera: CameraConfig, layout: RqrlpLayout) -> NodeMeasurement | None:
    found = approach(grey, camera.K_estimated, camera.D_estimated, layout)
    K = camera.K_estimated  # the estimators' intrinsics, as `approach` took them
    return None if found is None else approach_measurement(found.p_CP, found.side_px, time,
                                                           float(np.sqrt(K[0, 0] * K[1, 1])))


def adjustment_node(grey: np.ndarray, time: float, camera: CameraConfig,
                    layout: RqrlpLayout) -> NodeMeasurement | None:
    """The adjustment node's pose, its covariance from the corners the pose was fitted to (its inliers)."""
    found = adjustment(grey, camera.K_estimated, camera.D_estimated, layout)
    return None if found is None else adjustment_measurement(found.X_CP, layout_corners(layout)[found.inliers],
                                                             found.pixel_std, time, camera.X_BC, camera.K_estimated)


class _ImageNode(LeafSystem):
    """A node that is a function of the frame: `node(grey, time, camera, layout)`."""

    def __init__(self, node, camera: CameraConfig, layout: RqrlpLayout):
        super().__init__()
        self._node, self._camera, self._layout = node, camera, layout
        self._image = self.DeclareAbstractInputPort("color_image",
                                                    AbstractValue.Make(ImageRgba8U(camera.width, camera.height)))
        self.DeclareAbstractOutputPort("measurement", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        grey = to_grey(image_to_numpy(self._image.Eval(context)))
        output.set_value(as_list(self._node(grey, context.get_time(), self._camera, self._layout)))


class ApproachNode(_ImageNode):
    """The approaching node: the pattern's centre in the camera from its outline (p_CP)."""

    def __init__(self, camera: CameraConfig, layout: RqrlpLayout):
        super().__init__(approach_node, camera, layout)


class AdjustmentNode(_ImageNode):
    """The adjustment node: the body's pose in the pattern from the location markers (X_PB)."""

    def __init__(self, camera: CameraConfig, layout: RqrlpLayout):
        super().__init__(adjustment_node, camera, layout)


@dataclass(frozen=True)
class TouchdownStep:
    """The touchdown node after a frame: its tracker, the anchor's pixel noise, the measurement."""

    time: float | None = None
    tracker: TouchdownTracker | None = None
    anchor_px: float = MIN_PIXEL_STD
    measurement: NodeMeasurement | None = None


class TouchdownNode(LeafSystem):
    """The touchdown node: the pose chained by optical flow from the previous frame (X_PB).

    Inputs `color_image` and `anchor` (the adjustment node's `measurement`, same frame)."""

    def __init__(self, camera: CameraConfig, layout: RqrlpLayout):
        super().__init__()
        self._camera, self._outline = camera, layout.outline_corners_P
        self._image = self.DeclareAbstractInputPort("color_image",
                                                    AbstractValue.Make(ImageRgba8U(camera.width, camera.height)))
        self._anchor = self.DeclareAbstractInputPort("anchor", AbstractValue.Make([]))
        initial = TouchdownStep(tracker=TouchdownTracker(camera.K_estimated, camera.D_estimated, layout))
        self._now = SteppedValue(self, "touchdown", initial, camera.period_s, self._step, lambda s: s.time).now
        self.DeclareAbstractOutputPort("measurement", lambda: AbstractValue.Make([]),
                                       lambda c, o: o.set_value(as_list(self._now.Eval(c).measurement)),
                                       {self._now.ticket()})

    def _step(self, context, previous: TouchdownStep) -> TouchdownStep:
        t, c = context.get_time(), self._camera
        grey = to_grey(image_to_numpy(self._image.Eval(context)))
        tracker, X_CP, _ = previous.tracker.track(grey)
        measurement = None if X_CP is None else touchdown_measurement(
            X_CP, self._outline, previous.anchor_px, tracker.chained, t, c.X_BC, c.K_estimated)
        anchor, anchor_px = first(self._anchor.Eval(context)), previous.anchor_px
        if anchor is not None:
            X_CP_anchor = c.X_BC.inverse().multiply(anchor.X_PB.inverse())
            tracker, anchor_px = tracker.anchored(grey, X_CP_anchor), max(anchor.quality, MIN_PIXEL_STD)
        return TouchdownStep(t, tracker, anchor_px, measurement)


class NodeMeasurementToVector(LeafSystem):
    """Input `measurement` (a node's list); output `node_vector` (measurements.node_vector), for
    Drake's vector loggers."""

    def __init__(self):
        super().__init__()
        self.DeclareAbstractInputPort("measurement", AbstractValue.Make([]))
        self.DeclareVectorOutputPort("node_vector", NODE_VECTOR_SIZE,
                                     lambda c, o: o.SetFromVector(node_vector(first(self.get_input_port().Eval(c)))))
