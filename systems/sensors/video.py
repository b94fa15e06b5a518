"""Writes a camera stream to an MP4 file (OpenCV's VideoWriter, codec mp4v) at the camera rate."""

import os
from pathlib import Path

import cv2
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.sensors.camera import image_to_numpy


class VideoRecorder(LeafSystem):
    """Appends `color_image` to a video every `period_s`. Frames go to a temporary file that
    `finish()` renames to `path`, so an interrupted run leaves no half-written video."""

    def __init__(self, path: Path, period_s: float, width: int, height: int):
        super().__init__()
        self.path = Path(path)
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{self.path.suffix}")
        self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), 1.0 / period_s,
                                       (width, height))
        if not self._writer.isOpened():
            raise OSError(f"cannot open a video writer for {self.path}")
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._write)

    def _write(self, context):
        self._writer.write(cv2.cvtColor(image_to_numpy(self.get_input_port().Eval(context)), cv2.COLOR_RGBA2BGR))

    def finish(self) -> None:
        self._writer.release()
        os.replace(self._tmp, self.path)

    def discard(self) -> None:
        self._writer.release()
        self._tmp.unlink(missing_ok=True)
