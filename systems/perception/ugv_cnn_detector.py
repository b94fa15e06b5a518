"""The learned UGV detector: a small convolutional network, run by OpenCV's dnn module from an ONNX file
(models/ugv_detector.onnx, trained by models/train_ugv_cnn.py), on seed 003's raw fisheye frame as the
paper runs YOLOv3 (Sec. 2.2.1).

    detector = CnnDetector()
    detector.detect(rgb) -> [(box [x, y, w, h] px, score in [0, 1]), ...]   # highest score first

The network is a centre-point detector (Zhou et al. 2019, "Objects as Points"): per cell of a stride-4 grid,
the heat that a UGV's centre lies in the cell (0.5 at the decision threshold, which training folded into the
network), the centre's offset within the cell and log of the box's width and height in cells. A detection is
a cell whose heat is the largest in its 3 x 3 neighbourhood (Zhou et al.'s max-pool in place of NMS) and at
least `min_score`; greedy NMS then drops a box overlapping a better one. Boxes in OpenCV's Rect convention,
pixel-index space, as every UGV detector's (systems/perception/ugv_detector.py).
"""

from pathlib import Path

import cv2
import numpy as np

from systems.config import PROJECT_ROOT, ConfigError, project_file, require
from systems.perception.ugv_detector import Detection, non_maximum_suppression, to_rgb

DEFAULT_MODEL_PATH = PROJECT_ROOT / "models" / "ugv_detector.onnx"
OUTPUTS = 5  # heat, offset x, offset y, log w, log h (cells)


class CnnDetector:
    """The ONNX network through cv2.dnn (one instance per thread: a cv2.dnn.Net is not shared safely). A relative
    `model_path` is tried from the working directory, then from the project root (`systems.config.project_file`)."""

    def __init__(self, model_path: Path | str = DEFAULT_MODEL_PATH, min_score: float = 0.5, max_detections: int = 10,
                 nms_iou: float = 0.3):
        require(0.0 < min_score < 1.0, f"the CNN detector's min_score must lie in (0, 1), got {min_score}")
        self.model_path = project_file(model_path)
        self.min_score, self.max_detections, self.nms_iou = min_score, max_detections, nms_iou
        if not self.model_path.is_file():
            raise ConfigError(f"the UGV detector's model file {self.model_path} does not exist "
                              "(models/train_ugv_cnn.py writes it)")
        try:
            self.net = cv2.dnn.readNetFromONNX(str(self.model_path))
        except cv2.error as e:
            reason = str(e).strip().splitlines()[-1] if str(e).strip() else "unreadable"
            raise ConfigError(f"the UGV detector's model file {self.model_path} is not a readable ONNX network: "
                              f"{reason}") from None
        self._probe()

    def _probe(self) -> None:
        """Runs the network once on a blank frame: a model of another shape is a ConfigError here, not later."""
        try:
            out = self._forward(np.zeros((512, 512, 3), np.uint8))
        except cv2.error as e:
            raise ConfigError(f"the UGV detector's model file {self.model_path} does not run on a 512 x 512 RGB "
                              f"frame: {str(e).strip().splitlines()[-1]}") from None
        if out.ndim != 3 or out.shape[0] != OUTPUTS or 512 % out.shape[1] or out.shape[1] != out.shape[2]:
            raise ConfigError(f"the UGV detector's model file {self.model_path} gives outputs of shape "
                              f"{tuple(out.shape)}, not ({OUTPUTS}, H / s, W / s)")
        self.stride = 512 // out.shape[1]

    def _forward(self, rgb: np.ndarray) -> np.ndarray:
        """The network's output (5, H / s, W / s) for an RGB uint8 frame (any strides: a view of RGBA will do)."""
        # RGB as given, NCHW, [0, 1]: the values of cv2.dnn.blobFromImage(rgb, 1 / 255), bit for bit, at a tenth
        # of its cost (0.3 against 2.8 ms a 512 x 512 frame here; tests/test_ugv_cnn_detector.py).
        blob = rgb.transpose(2, 0, 1)[None].astype(np.float32, order="C")
        blob *= np.float32(1.0 / 255.0)
        self.net.setInput(blob)
        return np.asarray(self.net.forward())[0]

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """The UGV's boxes and scores in a 512 x 512 fisheye frame (module docstring), highest score first."""
        rgb = to_rgb(rgb)
        require(rgb.shape[:2] == (512, 512), f"the CNN detector takes 512 x 512 frames, got {rgb.shape[:2]}")
        return decode(self._forward(rgb), self.stride, self.min_score, self.nms_iou,
                      self.max_detections)


def decode(out: np.ndarray, stride: int, min_score: float, nms_iou: float = 0.3,
           max_detections: int = 10) -> list[Detection]:
    """Detections from the network's output (5, rows, cols): each 3 x 3 peak of the heat at or above
    `min_score`, its box centred at (col + offset x, row + offset y) cells, exp(log w, log h) cells wide and
    high, times `stride` px; then greedy NMS at `nms_iou`, at most `max_detections`, highest score first."""
    heat = np.ascontiguousarray(out[0])
    peaks = (heat >= min_score) & (heat >= cv2.dilate(heat, np.ones((3, 3), np.uint8)))
    rows, cols = np.nonzero(peaks)
    if rows.size == 0:
        return []
    scores = heat[rows, cols]
    cx, cy = (cols + out[1, rows, cols]) * stride, (rows + out[2, rows, cols]) * stride
    w, h = np.exp(out[3, rows, cols]) * stride, np.exp(out[4, rows, cols]) * stride
    boxes = np.column_stack([cx - w / 2, cy - h / 2, w, h]).astype(float)
    keep = non_maximum_suppression(boxes, scores, nms_iou, max_detections)
    return [(boxes[i], float(scores[i])) for i in keep]
