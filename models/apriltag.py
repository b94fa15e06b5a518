"""AprilTag 36h11 texture and the textured plate mesh that carries it, generated from OpenCV's dictionary.

The plate is a unit square OBJ quad in its own frame (x right, y up in the tag image, z out of the
face) textured with the tag plus a one-cell white quiet zone: 10 cells across, of which the black
square is the middle 8. Scale it by `tag_plate_scale(tag_size_m)`.
"""

import hashlib
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


def _quad_files(stem: str) -> dict[str, bytes]:
    """The OBJ and MTL text of a unit quad in z = 0 showing `stem`.png upright when seen from +z."""
    return {".mtl": f"newmtl {stem}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {stem}.png\n".encode(),
            ".obj": (f"mtllib {stem}.mtl\n"
                     "v -0.5 -0.5 0\nv 0.5 -0.5 0\nv 0.5 0.5 0\nv -0.5 0.5 0\n"
                     "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                     "vn 0 0 1\n"
                     f"usemtl {stem}\n"
                     "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n").encode()}


def source_digest(*paths: Path) -> str:
    """10 hex digits of SHA-1 over these files and this one: a generated file named with it is made again
    whenever the code that makes it changes."""
    sha = hashlib.sha1()
    for path in (Path(__file__), *paths):
        sha.update(Path(path).read_bytes())
    return sha.hexdigest()[:10]


def quad_mesh(stem: str, image: np.ndarray, directory: Path = GENERATED_DIR) -> Path:
    """`stem`.obj/.mtl/.png in `directory`: a unit quad in z = 0 showing `image` upright when seen from +z.
    Returns the OBJ's path; files already there are reused, so `stem` must name this image and this code
    (`textured_quad_mesh`, or parameters with `source_digest`)."""
    directory.mkdir(parents=True, exist_ok=True)
    obj = directory / f"{stem}.obj"
    if obj.exists():
        return obj
    ok, png = cv2.imencode(".png", image)
    assert ok
    _write_atomic(directory / f"{stem}.png", png.tobytes())
    files = _quad_files(stem)
    _write_atomic(directory / f"{stem}.mtl", files[".mtl"])
    _write_atomic(obj, files[".obj"])  # last: its presence says the three are whole
    return obj


def textured_quad_mesh(name: str, image: np.ndarray, directory: Path = GENERATED_DIR) -> Path:
    """`quad_mesh` named `name` and 12 hex digits of SHA-1 over the image (its shape, type and pixels) and
    the quad's OBJ and MTL text: a file already there is reused only where it shows this image this way."""
    sha = hashlib.sha1(f"{image.shape} {image.dtype}".encode())
    sha.update(np.ascontiguousarray(image).tobytes())
    for text in _quad_files(name).values():
        sha.update(text)
    return quad_mesh(f"{name}_{sha.hexdigest()[:12]}", image, directory)


def tag_mesh_path(tag_id: int) -> Path:
    """The OBJ of the textured tag36h11 plate for `tag_id`, generated on first use."""
    return textured_quad_mesh(f"tag36h11_{tag_id:03d}", tag_image(tag_id))
