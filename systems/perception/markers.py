"""The five ArUco markers of seed 002 (Fig. 1c) and their two measurement sources.

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

Sources, interchangeable, both giving `MarkerMeasurement`s:
- `synthetic_marker_measurements`: the paper's (Sec. 4): the true pose of each marker in the
  camera frame plus zero-mean Gaussian noise, 0.1 m on each position axis and 5 deg on each axis
  of a rotation vector that perturbs the attitude (the paper's "+-5 deg for q^{i/C}").
- `detect_marker_poses`: the rendered image, OpenCV ArUco detection and one cv2.solvePnP per
  marker (SOLVEPNP_SQPNP: OpenCV 5.0's IPPE_SQUARE fails on fronto-parallel squares, see
  systems/estimators/atda.py); markers not detected are simply absent.
"""

import math
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from systems.config import require, require_positive
from systems.estimators.quaternion import drake_to_paper, odot_matrix, paper_to_drake
from systems.noise import sample_index, sample_rng
from systems.perception.aruco import aruco_dictionary, subpix_detector, to_grey
from systems.sensors.camera import image_to_numpy

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
      R_CM (systems/estimators/quaternion.py); unit for a valid measurement.
    latency_s: s from acquisition until the measurement is available to a filter.
    Immutable (its arrays are read-only), so copies share it.
    """

    time: float
    marker_id: int
    p_CM: np.ndarray
    q_CM: np.ndarray
    latency_s: float = 0.0

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


def synthetic_marker_measurements(X_CP: RigidTransform, layout: MarkerLayout, rng: np.random.Generator,
                                  sigma_p: float = 0.1, sigma_deg: float = 5.0, time: float = 0.0,
                                  latency_s: float = 0.0) -> list[MarkerMeasurement]:
    """Seed 002 Sec. 4: every marker's true pose in C (from the pad pose X_CP) plus zero-mean
    Gaussian noise: sigma_p [m] on each axis of p_CM, and R_CM Exp(dtheta) with dtheta ~ N(0,
    sigma_deg^2 I3) in the marker frame for the attitude."""
    n = len(layout.ids)
    p_CM = X_CP.multiply(layout.p_PM.T).T + rng.normal(0.0, sigma_p, (n, 3))
    dtheta = rng.normal(0.0, np.radians(sigma_deg), (n, 3))
    angle = np.linalg.norm(dtheta, axis=1, keepdims=True)
    dq = np.hstack([np.sinc(angle / (2 * np.pi)) * dtheta / 2, np.cos(angle / 2)])  # [sin(a/2) axis, cos(a/2)]
    q_CM = dq @ odot_matrix(drake_to_paper(X_CP.rotation())).T  # q_CP (.) dq: R_CM = R_CP Exp(dtheta)
    return [MarkerMeasurement(time, marker_id, p, q, latency_s) for marker_id, p, q in zip(layout.ids, p_CM, q_CM)]


def marker_corners_M(size_m: float) -> np.ndarray:
    """The black square's corners (4x3, m) in the marker frame M, in ArUco's order: top-left,
    top-right, bottom-right, bottom-left of the marker as printed (M: x right, y up, z out)."""
    s = size_m / 2
    return np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])


def detect_marker_poses(rgb: np.ndarray, K: np.ndarray, layout: MarkerLayout, time: float = 0.0,
                        latency_s: float = 0.0) -> list[MarkerMeasurement]:
    """X_CM of every layout marker found in an RGB, RGBA (or grey) uint8 image from an undistorted
    pinhole camera with intrinsics K (OpenCV convention), stamped `time` [s]. Markers not found,
    found twice, or whose PnP fails are absent."""
    corners, ids, _ = subpix_detector(layout.dictionary).detectMarkers(to_grey(rgb))
    if ids is None:
        return []
    ids = ids.ravel()
    measurements = []
    for marker_id, marker_corners in zip(ids, corners):
        index = layout.index(int(marker_id))
        if index is None or np.count_nonzero(ids == marker_id) > 1:
            continue
        ok, rvec, tvec = cv2.solvePnP(marker_corners_M(layout.sizes_m[index]), marker_corners.reshape(4, 1, 2),
                                      np.asarray(K, dtype=float), None, flags=cv2.SOLVEPNP_SQPNP)
        if ok and np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec)):
            R_CM = RotationMatrix(cv2.Rodrigues(rvec)[0])
            measurements.append(MarkerMeasurement(time, int(marker_id), tvec.ravel(), drake_to_paper(R_CM), latency_s))
    return measurements


class MarkerDetectorSystem(LeafSystem):
    """Input `color_image` (ImageRgba8U); output `marker_measurements` (list of MarkerMeasurement,
    stamped with the context's time) from `detect_marker_poses`. Computed when evaluated: evaluate
    it at the camera rate."""

    def __init__(self, K: np.ndarray, layout: MarkerLayout, width: int, height: int):
        super().__init__()
        layout.validate()
        self._K, self._layout = np.asarray(K, dtype=float), layout
        self.DeclareAbstractInputPort("color_image", AbstractValue.Make(ImageRgba8U(width, height)))
        self.DeclareAbstractOutputPort("marker_measurements", lambda: AbstractValue.Make([]), self._calc)

    def _calc(self, context, output):
        image = image_to_numpy(self.get_input_port().Eval(context))
        output.set_value(detect_marker_poses(image, self._K, self._layout, context.get_time()))


class SyntheticMarkerSource(LeafSystem):
    """The paper's measurement source (Sec. 4) as a system.

    Inputs: X_WB (RigidTransform, the UAV body), X_WP (RigidTransform, the pad). The camera C is
    mounted at X_BC. Output `marker_measurements` (list of MarkerMeasurement): at sample time
    t_k = k period_s, the measurements acquired at t_k - latency_s (none before the first one has
    arrived). Noise of sample k comes from systems.noise.sample_rng(seed, "marker_measurements", k).
    latency_s must be a whole number of periods; with latency the acquired measurements wait in a
    first-in first-out state updated every period. Evaluate the output at sample times (the filter
    does, in its periodic update at the same period).
    """

    def __init__(self, layout: MarkerLayout, X_BC: RigidTransform, period_s: float = 0.035, seed: int = 0,
                 sigma_p: float = 0.1, sigma_deg: float = 5.0, latency_s: float = 0.0):
        super().__init__()
        layout.validate()
        require_positive(period_s, "period_s")
        require(sigma_p >= 0 and sigma_deg >= 0, "marker measurement noise must not be negative")
        self._delay_steps = int(round(latency_s / period_s))
        require(self._delay_steps >= 0 and abs(self._delay_steps * period_s - latency_s) < 1e-9,
                f"latency_s ({latency_s}) must be a non-negative whole number of periods ({period_s} s)")
        self._layout, self._X_BC, self._period, self._seed = layout, X_BC, period_s, seed
        self._noise = (sigma_p, sigma_deg)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._X_WP = self.DeclareAbstractInputPort("X_WP", AbstractValue.Make(RigidTransform()))
        if self._delay_steps:
            self._queue = self.DeclareAbstractState(AbstractValue.Make(()))
            self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._acquire)
        self.DeclareAbstractOutputPort("marker_measurements", lambda: AbstractValue.Make([]), self._calc)

    def measure(self, context) -> list[MarkerMeasurement]:
        """The measurements acquired now, from the inputs."""
        t = context.get_time()
        X_WC = self._X_WB.Eval(context).multiply(self._X_BC)
        X_CP = X_WC.InvertAndCompose(self._X_WP.Eval(context))
        rng = sample_rng(self._seed, "marker_measurements", sample_index(t, self._period))
        return synthetic_marker_measurements(X_CP, self._layout, rng, *self._noise, time=t,
                                             latency_s=self._delay_steps * self._period)

    def _acquire(self, context, state):
        queue = context.get_abstract_state(self._queue).get_value()
        state.get_mutable_abstract_state(self._queue).set_value((queue + (self.measure(context),))[-self._delay_steps:])

    def _calc(self, context, output):
        if not self._delay_steps:
            output.set_value(self.measure(context))
            return
        queue = context.get_abstract_state(self._queue).get_value()
        output.set_value(queue[0] if len(queue) == self._delay_steps else [])
