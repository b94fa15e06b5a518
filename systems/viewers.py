"""What shows a run or records it, as systems: Meshcat trails drawn as it runs, and the camera's video."""

import os
from pathlib import Path

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat, Rgba
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.flags import is_set
from systems.sensors.camera import image_to_numpy


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
        if np.all(np.isfinite(p)) and (self._valid_index is None or is_set(position[self._valid_index])):
            self._points.append(p.copy())
        if len(self._points) >= 2:
            self._meshcat.SetLine(self._path, np.array(self._points).T, 2.0, self._rgba)


class MeshcatArrow(LeafSystem):
    """Draws a vector as an arrow in Meshcat at `path`, from a point: inputs `position` (vector of
    `size`, the point in W [m] at `points`) and `vector` (3, in W), sampled at `rate_hz`; the arrow is
    `scale` metres long per unit of the vector (a wind of 5 m/s at 0.4: 2 m), hidden where the
    vector is under `min_norm`."""

    def __init__(self, meshcat: Meshcat, path: str, size: int = 3, points: slice = slice(0, 3), scale: float = 0.4,
                 rgba: tuple = (0.2, 0.6, 1.0, 1.0), rate_hz: float = 10.0, min_norm: float = 0.05):
        super().__init__()
        self._meshcat, self._path, self._slice, self._scale, self._rgba = meshcat, path, points, scale, Rgba(*rgba)
        self._min_norm = min_norm
        self._position = self.DeclareVectorInputPort("position", size)
        self._vector = self.DeclareVectorInputPort("vector", 3)
        self.DeclareInitializationPublishEvent(lambda context: self._meshcat.Delete(self._path))
        self.DeclarePeriodicPublishEvent(1.0 / rate_hz, 0.0, self._publish)

    def _publish(self, context):
        tail, vector = self._position.Eval(context)[self._slice], self._vector.Eval(context)
        norm = float(np.linalg.norm(vector))
        if norm < self._min_norm or not np.all(np.isfinite(tail)):
            self._meshcat.SetProperty(self._path, "visible", False)
            return
        self._meshcat.SetLine(self._path, arrow_polyline(tail, vector * self._scale).T, 3.0, self._rgba)
        self._meshcat.SetProperty(self._path, "visible", True)


def arrow_polyline(tail: np.ndarray, vector: np.ndarray, head: float = 0.2) -> np.ndarray:
    """(5, 3) points of an arrow from `tail` along `vector` [m]: the shaft, then the head's two
    barbs (each `head` of the arrow's length, 25 deg off it) drawn from its tip."""
    tip = tail + vector
    length = np.linalg.norm(vector)
    along = vector / length
    side = np.cross(along, [0.0, 0.0, 1.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-6 else np.array([1.0, 0.0, 0.0])
    back, out = head * length * np.cos(np.radians(25)), head * length * np.sin(np.radians(25))
    return np.array([tail, tip, tip - back * along + out * side, tip, tip - back * along - out * side])


class VideoRecorder(LeafSystem):
    """Appends `color_image` to a video every `period_s`. Frames go to a temporary file, opened at the
    first frame (a diagram refused while it is built leaves none), that `finish()` renames to `path`, so an
    interrupted run leaves no half-written video."""

    def __init__(self, path: Path, period_s: float, width: int, height: int):
        super().__init__()
        self.path = Path(path)
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{self.path.suffix}")
        self._fps, self._size = 1.0 / period_s, (width, height)
        self._writer = None
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._write)

    def _write(self, context):
        if self._writer is None:
            self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), self._fps, self._size)
            if not self._writer.isOpened():
                raise OSError(f"cannot open a video writer for {self.path}")
        self._writer.write(cv2.cvtColor(image_to_numpy(self.get_input_port().Eval(context)), cv2.COLOR_RGBA2BGR))

    def finish(self) -> None:
        if self._writer is None:
            return  # no frame was written: no video
        self._writer.release()
        os.replace(self._tmp, self.path)

    def discard(self) -> None:
        if self._writer is not None:
            self._writer.release()
        self._tmp.unlink(missing_ok=True)


def draw_boxes(rgb: np.ndarray, detections, target_box: np.ndarray, target_valid: bool, lock: np.ndarray) -> np.ndarray:
    """A copy of the (H, W, 3 or 4) uint8 image with the detector's boxes (yellow, their scores) and the
    tracker's target box (green while locked and matched this frame, orange while predicted; its track id)
    drawn on it; boxes are [x, y, w, h] px (systems/perception/box_tracker.py)."""
    out = np.ascontiguousarray(rgb[..., :3]).copy()
    for box, score in detections:
        x, y, w, h = (round(float(v)) for v in box)
        cv2.rectangle(out, (x, y), (x + w - 1, y + h - 1), (255, 220, 0), 1)
        cv2.putText(out, f"{score:.2f}", (x, max(y - 3, 8)), cv2.FONT_HERSHEY_PLAIN, 0.8, (255, 220, 0), 1)
    if target_valid and np.all(np.isfinite(target_box)):
        x, y, w, h = (round(float(v)) for v in target_box)
        colour = (0, 230, 0) if is_set(lock[1]) else (255, 140, 0)
        cv2.rectangle(out, (x, y), (x + w - 1, y + h - 1), colour, 2)
        cv2.putText(out, f"id {int(lock[0])}", (x, y + h + 12), cv2.FONT_HERSHEY_PLAIN, 1.0, colour, 1)
    return out


class TrackOverlay(LeafSystem):
    """The fisheye stream with the UGV detector's boxes and the tracker's target drawn on it (`draw_boxes`),
    for `--video`. Inputs `color_image` (ImageRgba8U), `detections` (list of (box, score)), `target_box` (4),
    `target_valid` (1), `lock` (2: [track id, matched]); output `image` (ImageRgba8U, the same size)."""

    def __init__(self, width: int, height: int):
        super().__init__()
        self._image = self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self._detections = self.DeclareAbstractInputPort("detections", AbstractValue.Make([]))
        self._box = self.DeclareVectorInputPort("target_box", 4)
        self._valid = self.DeclareVectorInputPort("target_valid", 1)
        self._lock = self.DeclareVectorInputPort("lock", 2)
        self.DeclareAbstractOutputPort("image", lambda: AbstractValue.Make(ImageRgba8U(width, height)), self._calc)

    def _calc(self, context, output):
        drawn = draw_boxes(image_to_numpy(self._image.Eval(context)), self._detections.Eval(context),
                           self._box.Eval(context), is_set(self._valid.Eval(context)[0]), self._lock.Eval(context))
        image = output.get_mutable_value()
        image.mutable_data[..., :3] = drawn
        image.mutable_data[..., 3] = 255
