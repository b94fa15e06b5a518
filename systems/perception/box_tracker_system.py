"""The tracking-by-detection of seed 003 (Sec. 2.2.1; systems/perception/box_tracker.py) as a LeafSystem."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.perception.box_tracker import BoxTrackerConfig, TrackerState, step_tracker, target_box
from systems.sensors.camera import image_to_numpy
from systems.stepped import SteppedValue


class BoxTrackerSystem(LeafSystem):
    """Inputs: `detections` (list of box_tracker.Detection: boxes [x, y, w, h] px, (x, y) the top-left
    corner, and scores) and `color_image` (ImageRgba8U, width x height: the frame the boxes were found in, for the
    colour histograms; unconnected, the tracker uses the boxes alone).

    State: the TrackerState (all tracks and the target's lock), stepped by a periodic unrestricted update
    at `config.rate_hz` from t = 0 (SteppedValue: a reader at a frame time sees that frame's step). The
    inputs are read only at those times: connect a detector evaluated at the camera's rate.

    Outputs: `target_box` (4, px: the locked target's box [x, y, w, h], filtered or, while it coasts, predicted; NaN
    when no target is locked), `target_valid` (1: 1.0 when locked, else 0.0) and `tracks` (list of
    box_tracker.BoxTrack, every live track, tentative ones included).
    """

    def __init__(self, config: BoxTrackerConfig | None = None, width: int = 512, height: int = 512):
        super().__init__()
        self._config = config or BoxTrackerConfig()
        self._config.validate(width=width, height=height)
        self._detections = self.DeclareAbstractInputPort("detections", AbstractValue.Make([]))
        self._image = self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self._stepped = SteppedValue(self, "tracker", TrackerState(), self._config.period_s, self._step,
                                     lambda state: state.time)
        tickets = {self._stepped.now.ticket()}
        self.DeclareVectorOutputPort("target_box", 4, lambda c, o: o.SetFromVector(self._target(c)[0]), tickets)
        self.DeclareVectorOutputPort("target_valid", 1, lambda c, o: o.SetFromVector([float(self._target(c)[1])]),
                                     tickets)
        self.DeclareAbstractOutputPort("tracks", lambda: AbstractValue.Make([]),
                                       lambda c, o: o.set_value(list(self.state(c).tracks)), tickets)

    @property
    def config(self) -> BoxTrackerConfig:
        return self._config

    def state(self, context) -> TrackerState:
        """The tracker's state at the context's time (including the step of a frame at that time)."""
        return self._stepped.now.Eval(context)

    def _target(self, context) -> tuple[np.ndarray, bool]:
        return target_box(self.state(context))

    def _step(self, context, state: TrackerState) -> TrackerState:
        image = image_to_numpy(self._image.Eval(context)) if self._image.HasValue(context) else None
        return step_tracker(state, self._detections.Eval(context), image, context.get_time(), self._config)
