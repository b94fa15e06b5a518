"""Colour-pad centroids in the camera stream (seed 000 Sec. 2.3: Eq. 11, Table 1, Eq. 12-16).

A thin LeafSystem over `systems.estimators.pad_calibration.pad_centroids`.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.estimators.pad_calibration import PAD_COLOURS, pad_centroids
from systems.sensors.camera import image_to_numpy


class PadCentroidsSystem(LeafSystem):
    """Finds the coloured pads in `color_image` (ImageRgba8U) whenever a consumer evaluates
    `pad_pixels`; consumers evaluate it at the camera rate (a logger or an estimator's periodic
    event), so the scene is rendered only then.

    Output `pad_pixels`: 2 * len(colours) numbers, (u, v) in pixels (OpenCV convention) of each
    pad's centroid in `colours` order (default PAD_COLOURS: sensors 1..4 of Eq. 21-24), NaN for a
    pad not found. Stateless.
    """

    def __init__(self, width: int, height: int, colours: tuple[str, ...] = PAD_COLOURS, min_area_px: int = 20):
        super().__init__()
        self._colours, self._min_area_px = tuple(colours), min_area_px
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclareVectorOutputPort("pad_pixels", 2 * len(self._colours), self._calc_pad_pixels)

    @property
    def colours(self) -> tuple[str, ...]:
        return self._colours

    def _calc_pad_pixels(self, context, output):
        image = image_to_numpy(self.get_input_port().Eval(context))
        centroids = pad_centroids(image, self._colours, self._min_area_px)
        output.SetFromVector(np.asarray(centroids, dtype=float).ravel())
