"""Meshcat helpers that are systems: lines drawn from a simulation as it runs."""

import numpy as np
from pydrake.geometry import Meshcat, Rgba
from pydrake.systems.framework import LeafSystem


class MeshcatTrail(LeafSystem):
    """Draws a point's trail in Meshcat at `path`: a line through its positions in W [m], sampled
    at `rate_hz` from `position[points]` of the vector input `position` (`size` long). Samples with a
    non-finite position, or with position[valid_index] below 0.5 when given (an invalid estimate),
    are left out."""

    def __init__(self, meshcat: Meshcat, path: str, size: int = 3, points: slice = slice(0, 3),
                 rgba: tuple = (0.1, 0.4, 0.9, 1.0), rate_hz: float = 10.0, valid_index: int | None = None):
        super().__init__()
        self._meshcat, self._path, self._slice, self._rgba, self._points = meshcat, path, points, Rgba(*rgba), []
        self._valid_index = valid_index
        self._position = self.DeclareVectorInputPort("position", size)
        self.DeclareInitializationPublishEvent(self._reset)
        self.DeclarePeriodicPublishEvent(1.0 / rate_hz, 0.0, self._publish)

    def _reset(self, context):
        self._points = []
        self._meshcat.Delete(self._path)

    def _publish(self, context):
        position = self._position.Eval(context)
        p = position[self._slice]
        if np.all(np.isfinite(p)) and (self._valid_index is None or position[self._valid_index] > 0.5):
            self._points.append(p.copy())
        if len(self._points) >= 2:
            self._meshcat.SetLine(self._path, np.array(self._points).T, 2.0, self._rgba)
