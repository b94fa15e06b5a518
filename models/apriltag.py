"""AprilTag 36h11 texture and the textured plate mesh that carries it, generated from OpenCV's dictionary.

The plate is a unit square OBJ quad in its own frame (x right, y up in the tag image, z out of the
face) textured with the tag plus a one-cell white quiet zone: 10 cells across, of which the black
square is the middle 8. Scale it by `tag_plate_scale(tag_size_m)`.
"""

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

GENERATED_DIR = Path(__file__).resolve().parent / "generated"
CELLS_BLACK_SQUARE = 8  # 6x6 data bits plus a one-cell black border
CELLS_WITH_QUIET_ZONE = 10
PIXELS_PER_CELL = 64


def tag_plate_scale(tag_size_m: float) -> float:
    """Edge (m) of the plate, quiet zone included, for a black square of edge tag_size_m."""
    return tag_size_m * CELLS_WITH_QUIET_ZONE / CELLS_BLACK_SQUARE


def tag_image(tag_id: int) -> np.ndarray:
    """The tag with its white quiet zone as an 8-bit grey image, 640x640 px."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    side = CELLS_WITH_QUIET_ZONE * PIXELS_PER_CELL
    image = np.full((side, side), 255, np.uint8)
    image[PIXELS_PER_CELL:-PIXELS_PER_CELL, PIXELS_PER_CELL:-PIXELS_PER_CELL] = cv2.aruco.generateImageMarker(
        dictionary, tag_id, CELLS_BLACK_SQUARE * PIXELS_PER_CELL, borderBits=1)
    return image


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def textured_quad_mesh(name: str, image: np.ndarray, directory: Path = GENERATED_DIR) -> Path:
    """Writes `name`.obj/.mtl/.png: a unit quad in z = 0 showing `image` upright when seen from +z.
    Returns the OBJ's path; files already there are reused."""
    directory.mkdir(parents=True, exist_ok=True)
    obj = directory / f"{name}.obj"
    if obj.exists():
        return obj
    ok, png = cv2.imencode(".png", image)
    assert ok
    _write_atomic(directory / f"{name}.png", png.tobytes())
    _write_atomic(directory / f"{name}.mtl", (
        f"newmtl {name}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {name}.png\n").encode())
    _write_atomic(obj, (
        f"mtllib {name}.mtl\n"
        "v -0.5 -0.5 0\nv 0.5 -0.5 0\nv 0.5 0.5 0\nv -0.5 0.5 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "vn 0 0 1\n"
        f"usemtl {name}\n"
        "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n").encode())
    return obj


def tag_mesh_path(tag_id: int) -> Path:
    """The OBJ of the textured tag36h11 plate for `tag_id`, generated on first use."""
    return textured_quad_mesh(f"tag36h11_{tag_id:03d}", tag_image(tag_id))
