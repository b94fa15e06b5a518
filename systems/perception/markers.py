"""The five ArUco markers of seed 002 (Fig. 1c): their layout on the pad, its texture, and the
measurement of one marker's pose that both sources give (synthetic_markers.py, the paper's;
marker_detector.py, the rendered camera's).

Frames. Pad frame P: origin at the centre of the pad's top surface, x forward, y left, z up (out of
the pad). Marker frame M_i: at the centre of marker i, axes parallel to P's: the paper's markers
are all aligned with the pad (its q^{i/C} = q^{P/C}, Sec. 3). Printed upright in the pad texture
(image up = +y_P, image right = +x_P), M_i is also OpenCV's marker frame (x right, y up in the
marker image, z out of it), so solvePnP's pose of a marker is X_CM directly.

Layout (`MarkerLayout`, not given by the paper): DICT_4X4_50 ids 0-4 on the 1.0 m pad: id 0, 0.20 m,
at the origin of P (the paper's marker 1, whose frame is the pad's), and ids 1-4, 0.30 m, centred at
(+-0.30, +-0.30) m, counter-clockwise from front-left. Sizes follow the range, with the default
512 px camera (fx 458.5, 58 deg field of view; camera 0.04 m under the body): at the end of the
descent, the camera 0.36 m above the pad sees a 0.40 m square, which holds the centre marker (255
px) with 0.1 m to spare; from 10 m a corner marker spans 14 px (2.3 px per cell of its 6x6 grid)
and is still detected (tests/test_markers.py shows both). Every marker keeps a white margin of
one cell (a sixth of its edge) clear of other markers and inside the pad; a corner marker's margin
meets the centre marker at one corner point.
"""

import itertools
import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require
from systems.perception.aruco import aruco_dictionary
from systems.quaternion import paper_to_drake

MARKER_CELLS = 6  # a 4x4 ArUco marker: 4 data cells plus a one-cell black border on each side


@dataclass
class MarkerLayout:
    """ArUco markers on the pad, in the pad frame P (module docstring); marker 0 at P's origin."""

    dictionary: str = "DICT_4X4_50"  # an OpenCV cv2.aruco.DICT_* name
    ids: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    offsets_m: list[list[float]] = field(default_factory=lambda: [  # p_PM_i, m
        [0.0, 0.0, 0.0], [0.3, 0.3, 0.0], [-0.3, 0.3, 0.0], [-0.3, -0.3, 0.0], [0.3, -0.3, 0.0]])
    sizes_m: list[float] = field(default_factory=lambda: [0.2, 0.3, 0.3, 0.3, 0.3])  # black square's edge

    def validate(self, prefix: str = "markers", pad_size_m: float | None = None) -> None:
        """Checks the layout; with `pad_size_m`, also that every marker and its one-cell white margin
        lie on the square pad of that edge (m)."""
        require(hasattr(cv2.aruco, self.dictionary),
                f"{prefix}.dictionary '{self.dictionary}' is not an OpenCV ArUco dictionary")
        size = aruco_dictionary(self.dictionary).bytesList.shape[0]
        n = len(self.ids)
        require(n >= 1 and len(set(self.ids)) == n and all(0 <= i < size for i in self.ids),
                f"{prefix}.ids must be different ids below {size}")
        require(len(self.offsets_m) == n and all(len(p) == 3 for p in self.offsets_m),
                f"{prefix}.offsets_m needs one [x, y, z] per id")
        require(len(self.sizes_m) == n and all(s > 0 for s in self.sizes_m),
                f"{prefix}.sizes_m needs one positive size per id")
        require(np.allclose(self.offsets_m[0], 0.0),
                f"{prefix}.offsets_m[0] must be [0, 0, 0]: marker 0 is the pad frame")
        for marker_id, p in zip(self.ids, self.p_PM):
            require(p[2] == 0.0, f"{prefix}: marker {marker_id}'s offset z must be 0, the pad's texture is flat "
                                 f"(got {p[2]:g} m)")
        # A marker's one-cell white margin may meet another's black square but not cover it (pad_texture paints
        # the later marker over the earlier one): margins may overlap each other, being both white.
        margins = np.asarray(self.sizes_m, dtype=float) / 2 * (1 + 2 / MARKER_CELLS)
        for i, j in itertools.permutations(range(n), 2):
            apart = np.abs(self.p_PM[i, :2] - self.p_PM[j, :2])
            require(np.any(apart >= margins[i] + self.sizes_m[j] / 2 - 1e-9),
                    f"{prefix}: marker {self.ids[i]} with its one-cell white margin covers part of marker "
                    f"{self.ids[j]}")
        if pad_size_m is not None:
            for marker_id, p, size in zip(self.ids, self.p_PM, self.sizes_m):
                reach = np.abs(p[:2]) + size / 2 * (1 + 2 / MARKER_CELLS)
                require(np.all(reach <= pad_size_m / 2 + 1e-9),
                        f"{prefix}: marker {marker_id} with its margin reaches {reach.max():.3f} m from the centre, "
                        f"off the {pad_size_m:g} m pad")

    @property
    def p_PM(self) -> np.ndarray:
        """(n, 3) marker centres in P [m]."""
        return np.asarray(self.offsets_m, dtype=float).reshape(-1, 3)

    def index(self, marker_id: int) -> int | None:
        """Position of `marker_id` in the layout, or None if it is not one of its markers."""
        return self.ids.index(marker_id) if marker_id in self.ids else None


def pad_texture(layout: MarkerLayout, pad_size_m: float = 1.0, pixels: int = 1200) -> np.ndarray:
    """The square pad of edge `pad_size_m` seen from above as a `pixels`-square grey image: white,
    with each marker upright (image up = +y_P, right = +x_P), for
    models.apriltag.textured_quad_mesh scaled by pad_size_m. The default 1200 px puts the default
    markers on the default 1 m pad on whole pixels per cell."""
    scale = pixels / pad_size_m
    image = np.full((pixels, pixels), 255, np.uint8)
    for marker_id, (x, y, _), size in zip(layout.ids, layout.p_PM, layout.sizes_m):
        side = int(round(size * scale))
        col = int(round((x + pad_size_m / 2) * scale - side / 2))
        row = int(round((pad_size_m / 2 - y) * scale - side / 2))
        require(0 <= row and row + side <= pixels and 0 <= col and col + side <= pixels,
                f"marker {marker_id} does not fit on the {pad_size_m:g} m pad")
        image[row:row + side, col:col + side] = cv2.aruco.generateImageMarker(
            aruco_dictionary(layout.dictionary), marker_id, side, borderBits=1)
    return image


@dataclass(frozen=True)
class MarkerMeasurement:
    """The pose of one marker M in the camera frame C.

    time: s, when the image was acquired (the instant the pose refers to).
    marker_id: the ArUco id.
    p_CM: (3,) m, the marker's centre in C.
    q_CM: (4,) the paper's scalar-last q^{M/C} = [x, y, z, w]: the numbers of Drake's quaternion of
      R_CM (systems/quaternion.py); unit for a valid measurement.
    Immutable (its arrays are read-only), so copies share it.
    """

    time: float
    marker_id: int
    p_CM: np.ndarray
    q_CM: np.ndarray

    def __post_init__(self):
        for name in ("p_CM", "q_CM"):
            array = np.array(getattr(self, name), dtype=float)
            array.flags.writeable = False
            object.__setattr__(self, name, array)

    @cached_property
    def quaternion_norm(self) -> float:
        """|q_CM|, NaN unless p_CM (3) and q_CM (4) are well-formed and finite: one check that
        every filter reading the measurement shares."""
        if self.p_CM.shape != (3,) or self.q_CM.shape != (4,):
            return math.nan
        p, q = self.p_CM.tolist(), self.q_CM.tolist()
        return math.sqrt(sum(v * v for v in q)) if all(map(math.isfinite, p + q)) else math.nan

    def __deepcopy__(self, memo):
        return self

    @property
    def X_CM(self) -> RigidTransform:
        return RigidTransform(RotationMatrix(paper_to_drake(self.q_CM / np.linalg.norm(self.q_CM))), self.p_CM)


def marker_corners_M(size_m: float) -> np.ndarray:
    """The black square's corners (4x3, m) in the marker frame M, in ArUco's order: top-left,
    top-right, bottom-right, bottom-left of the marker as printed (M: x right, y up, z out)."""
    s = size_m / 2
    return np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])


def measurements_vector(measurements, layout: MarkerLayout) -> np.ndarray:
    """One sample of a marker stream as a vector for logging: per layout marker [p_CM (3), q_CM (4)]
    (n * 7), NaN for a marker not measured (or measured twice, or not in the layout)."""
    out = np.full((len(layout.ids), 7), np.nan)
    ids = [m.marker_id for m in measurements]
    for m in measurements:
        i = layout.index(m.marker_id)
        if i is not None and ids.count(m.marker_id) == 1:
            out[i, :3], out[i, 3:] = m.p_CM, m.q_CM
    return out.ravel()


class MarkerMeasurementsToVector(LeafSystem):
    """Input `marker_measurements` (list of MarkerMeasurement); output `measurements_vector`
    (`measurements_vector`, n * 7), for Drake's vector loggers."""

    def __init__(self, layout: MarkerLayout):
        super().__init__()
        measurements = self.DeclareAbstractInputPort("marker_measurements", AbstractValue.Make([]))
        self.DeclareVectorOutputPort("measurements_vector", 7 * len(layout.ids), lambda c, o: o.SetFromVector(
            measurements_vector(measurements.Eval(c), layout)))
