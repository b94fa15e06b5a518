"""Seed 001's three vision nodes (Sec. 4.1) on one grey image of the RQRLP (pattern.py), as plain
functions of the image, the intrinsics K and the lens distortion D (OpenCV's).

- Approaching (`approach`): the pattern's black outline, the largest dark quadrilateral; a rough
  3-D position of its centre from its apparent size and centre (the paper keeps only the position).
- Adjustment (`adjustment`): the location markers, found by contour-hierarchy statistics (three
  nested squares of 7, 5 and 3 modules), told apart by the paper's geometry (Top is off the longest
  line between two markers, Right and Bottom by the side of that line Top is on), their 36 corners
  -> homography -> pose (homography.py, Eq. 1-2), refined to the least reprojection error (OpenCV's
  Levenberg-Marquardt).
- Touchdown (`TouchdownTracker`): features on the texture tracked between frames by pyramidal
  Lucas-Kanade flow -> inter-frame homography -> the pose chained from the previous one (Eq. 3),
  re-anchored whenever the adjustment node has a pose.
Each returns X_CP (the pattern P in the camera C) or None, with what the node's covariance needs.
"""

from dataclasses import dataclass

import cv2
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from systems.perception.rqrlp.homography import (
    homography_from_pose,
    plane_pose,
    pose_from_homography,
)
from systems.perception.rqrlp.measurements import fit_pixel_std
from systems.perception.rqrlp.pattern import MARKERS, MODULES, RqrlpLayout
from systems.sensors.camera import undistort_pixels

AREA_RATIO_TOLERANCE = 0.35  # nested squares' areas against 49 : 25 : 9, relative
MAX_ASPECT = 1.6  # the outline's longer side against its shorter (a square seen up to ~50 deg off its normal)
MIN_DARK_EDGE = 0.65  # the share of the outline's edges that its black border makes dark
EDGE_MARGIN_PX = 2  # an outline this close to the image's edge may be cut by it
EDGE_SEARCH_PX = 3.0  # how far across a square's side its edge is looked for (at most; under half a module)
EDGE_STEP_PX = 0.25  # the profile across a side is sampled this finely
# The contour's corners against the sides' crossings: up to 2.1 px where a light square's corners are eaten
# (a dark carrier in view raised Otsu's threshold from 124 to 157, and the square's hull turned); further
# off, another edge's.
MAX_CORNER_SHIFT_PX = 3.0
MIN_REFINED_BORDER_PX = 3.0  # the outline's corners are refined where its black border is this wide (6.4 m at f 640 px)


def dark_regions(grey: np.ndarray) -> np.ndarray:
    """The dark parts of the image (Otsu's threshold) as a binary mask (255 dark)."""
    _, binary = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
    return binary


def _quad(contour: np.ndarray) -> np.ndarray | None:
    """The contour's convex hull as a quadrilateral (4, 2) px, or None (a thin outline a pixel or two
    wide traces as a ragged contour: its hull is the square's)."""
    hull = cv2.convexHull(contour)
    approx = cv2.approxPolyDP(hull, 0.06 * cv2.arcLength(hull, True), True)
    if len(approx) != 4 or not cv2.isContourConvex(approx):
        return None
    return approx.reshape(4, 2).astype(np.float64)


# ---- Approaching ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ApproachResult:
    p_CP: np.ndarray  # the pattern's centre in C [m]
    corners_px: np.ndarray  # (4, 2) its outline in the undistorted image
    side_px: float  # its apparent size, sqrt of the outline's area [px]


def approach(grey: np.ndarray, K: np.ndarray, D, layout: RqrlpLayout,
             min_side_px: float = 8.0) -> ApproachResult | None:
    """The outline: the largest square-ish dark region (its black border, closed over a pixel's gaps,
    with the dark texture and markers it holds; a white margin keeps it apart from a dark carrier),
    its convex hull a quadrilateral lying wholly in the image, dark along its edges;
    its centre where its diagonals cross, and its depth from its apparent size:
    z = f size_m / side_px, f = sqrt(fx fy), side_px the quadrilateral's sqrt(area). Where the border
    spans MIN_REFINED_BORDER_PX or more, the corners are its fitted sides' crossings
    (`corners_from_sides`, 0.05-0.1 % of depth error against 0.12-0.28 % from the contour at 1.5-5 m);
    farther off, a contour runs through its edge pixels' centres, half a pixel inside the edge, so
    side_px is the contour's sqrt(area) + 1."""
    closed = cv2.morphologyEx(dark_regions(grey), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    # Two levels: the dark regions' outer boundaries and their holes; a region inside a hole (the
    # pattern on a dark carrier's white pad) is an outer boundary again.
    contours, hierarchy = cv2.findContours(closed, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    height, width = grey.shape
    best = None
    outer = [c for c, h in zip(contours, hierarchy[0] if hierarchy is not None else []) if h[3] == -1]
    for contour in sorted(outer, key=lambda c: -cv2.contourArea(cv2.convexHull(c))):
        quad = _quad(contour)
        if quad is None:
            continue  # not a quadrilateral: a smaller region may be the outline
        if cv2.contourArea(quad.astype(np.float32)) < min_side_px**2:
            break
        (_, _), (w, h), _ = cv2.minAreaRect(quad.astype(np.float32))
        if max(w, h) <= MAX_ASPECT * min(w, h):
            best = quad  # the largest square-ish region: not the vehicle's body, say
            break
    if best is None or best.min() <= EDGE_MARGIN_PX or np.any(best >= [width - 1 - EDGE_MARGIN_PX,
                                                                      height - 1 - EDGE_MARGIN_PX]):
        return None
    if _dark_along_edges(closed, best) < MIN_DARK_EDGE:
        return None  # not a border: a blob of the texture, seen when the outline is out of view
    if not _light_inside_border(dark_regions(grey), best, layout):
        return None  # a location marker's square, seen when the outline is out of view
    border_px = np.sqrt(cv2.contourArea(best.astype(np.float32))) * layout.border_m / layout.size_m
    quad, refined = best[None], np.array([False])
    if border_px >= MIN_REFINED_BORDER_PX:  # the search stays within half the border: not its inner edge
        quad, refined = corners_from_sides(grey, quad, min(EDGE_SEARCH_PX, 0.45 * border_px))
    corners = undistort_pixels(quad[0], K, D)
    side = float(np.sqrt(cv2.contourArea(corners.astype(np.float32)))) + (0.0 if refined[0] else 1.0)
    if side < min_side_px:
        return None
    a, b, c, d = np.c_[corners, np.ones(4)]
    centre = np.cross(np.cross(a, c), np.cross(b, d))  # the diagonals' crossing, homogeneous
    z = np.sqrt(K[0, 0] * K[1, 1]) * layout.size_m / side
    return ApproachResult(z * np.linalg.solve(K, centre / centre[2]), corners, side)


def _dark_along_edges(mask: np.ndarray, quad: np.ndarray, samples: int = 32) -> float:
    """The share of points along the quadrilateral's edges that are dark in the mask."""
    s = np.linspace(0.0, 1.0, samples, endpoint=False)[:, None]
    points = np.concatenate([quad[i] + s * (quad[(i + 1) % 4] - quad[i]) for i in range(4)])
    cols, rows = np.round(points).astype(int).T
    return float(np.mean(mask[rows, cols] > 0))


def _light_inside_border(mask: np.ndarray, quad: np.ndarray, layout: RqrlpLayout, min_margin_px: float = 2.0) -> bool:
    """Whether the white margin inside the black border is light along the quadrilateral (the
    unclosed dark mask), where the margin spans min_margin_px or more; a location marker's squares
    are dark there (its ring is a module wide, a seventh of its side)."""
    side = np.sqrt(cv2.contourArea(quad.astype(np.float32)))
    if layout.margin_m / layout.size_m * side < min_margin_px:
        return True  # too small to tell: the largest square-ish region is the outline from afar
    inset = (layout.border_m + layout.margin_m / 2) / layout.size_m  # of the side, from each edge
    centre = quad.mean(axis=0)
    return 1.0 - _dark_along_edges(mask, centre + (1 - 2 * inset) * (quad - centre)) >= MIN_DARK_EDGE


# ---- Adjustment -------------------------------------------------------------------------------


@dataclass(frozen=True)
class AdjustmentResult:
    X_CP: RigidTransform  # Eq. (2)'s pose refined to the least reprojection error
    corners_px: np.ndarray  # (36, 2) undistorted, in the order of `layout_corners`
    inliers: np.ndarray  # (36,) bool: the corners the pose was fitted to (the homography's RANSAC inliers)
    rms_residual_px: float  # of the corners about the refined pose's projection, sqrt(mean(du^2 + dv^2)) [px]
    pixel_std: float  # the corners' noise per coordinate from those residuals (`fit_pixel_std`, the pose's 6 dof) [px]
    module_px: float  # a marker module's apparent size
    X_CP_homography: RigidTransform  # Eq. (2)'s own, from the homography


def location_markers(grey: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Candidates: contours nested three deep (dark, light, dark) whose quadrilaterals' areas go as
    49 : 25 : 9; each as its three squares' corners (4, 2) px, outer first."""
    contours, hierarchy = cv2.findContours(dark_regions(grey), cv2.RETR_TREE, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    hierarchy = hierarchy[0]
    out = []
    for i in range(len(contours)):
        j = hierarchy[i, 2]
        k = hierarchy[j, 2] if j != -1 else -1
        if k == -1 or hierarchy[j, 0] != -1 or hierarchy[k, 0] != -1:  # one hole, holding one square
            continue
        quads = [_quad(contours[n]) for n in (i, j, k)]
        if any(q is None for q in quads):
            continue
        areas = np.array([cv2.contourArea(q.astype(np.float32)) for q in quads])
        expected = np.array(MODULES, dtype=float) ** 2
        if areas[2] <= 0 or np.any(np.abs(areas / areas[0] * expected[0] / expected - 1) > AREA_RATIO_TOLERANCE):
            continue
        out.append(tuple(quads))
    return out


def classify(candidates) -> dict[str, tuple] | None:
    """Top, Right and Bottom among exactly three candidates: the two farthest apart are Right and
    Bottom; seen from Top, Right is the one clockwise of Bottom in the image (y down)."""
    if len(candidates) != 3:
        return None
    centres = [c[0].mean(axis=0) for c in candidates]
    pairs = [(0, 1), (0, 2), (1, 2)]
    a, b = max(pairs, key=lambda p: np.linalg.norm(centres[p[0]] - centres[p[1]]))
    top = 3 - a - b
    u, v = centres[a] - centres[top], centres[b] - centres[top]
    right, bottom = (a, b) if u[0] * v[1] - u[1] * v[0] > 0 else (b, a)
    return {"top": candidates[top], "right": candidates[right], "bottom": candidates[bottom]}


def _ordered(quad: np.ndarray, x_axis: np.ndarray, up_axis: np.ndarray) -> np.ndarray:
    """The quad's corners as the layout orders them: top-left, bottom-left, bottom-right, top-right
    of the upright pattern, whose right and up are the image directions x_axis and up_axis."""
    d = quad - quad.mean(axis=0)
    x, up = d @ x_axis, d @ up_axis
    order = [np.argmin(x - up), np.argmin(x + up), np.argmax(x - up), np.argmax(x + up)]
    return quad[order] if len(set(order)) == 4 else None


def layout_corners(layout: RqrlpLayout) -> np.ndarray:
    """(36, 3) the markers' corners in P, in `adjustment`'s order (marker, square, corner)."""
    return np.concatenate([layout.marker_corners_P(m).reshape(-1, 3) for m in MARKERS])


def refine_pose(X_CP: RigidTransform, points_P: np.ndarray, pixels: np.ndarray, K: np.ndarray) -> RigidTransform:
    """Eq. (2)'s pose (which minimises no image error: a fronto-parallel view's tilt comes out a few
    degrees off) refined by OpenCV's Levenberg-Marquardt on the reprojection error of the points
    (N, 3, in P) at the undistorted pixels (N, 2)."""
    rvec = cv2.Rodrigues(X_CP.rotation().matrix())[0]
    tvec = X_CP.translation().reshape(3, 1).copy()
    rvec, tvec = cv2.solvePnPRefineLM(points_P, pixels, K, None, rvec, tvec)
    return RigidTransform(RotationMatrix(cv2.Rodrigues(rvec)[0]), tvec.ravel())


def _peak_centroid(profiles: np.ndarray, k: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Each profile's (rows of `profiles`, sampled at `offsets`) peak position: the centroid of the run
    of samples above half its maximum (at index k) that holds it, each weighed by its height above
    that half: on a side along the pixel grid the rendered edge is a step, whose gradient is a plateau
    a pixel wide with the edge at its centre, not at its highest sample. The run ends where the profile
    dips under the half, before a neighbouring edge."""
    half = 0.5 * profiles[np.arange(len(k)), k][:, None]
    index = np.arange(profiles.shape[1])[None, :]
    low = profiles < half
    first = np.where(low & (index < k[:, None]), index, -1).max(axis=1) + 1
    last = np.where(low & (index > k[:, None]), index, profiles.shape[1]).min(axis=1) - 1
    weight = np.where((index >= first[:, None]) & (index <= last[:, None]), profiles - half, 0.0)
    return np.sum(weight * offsets[None, :], axis=1) / np.sum(weight, axis=1)


def corners_from_sides(grey: np.ndarray, quads: np.ndarray, search_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadrilaterals' corners (N, 4, 2) px refined to where their sides cross: (corners, refined (N,)
    bool). Each side's edge is found across it, at every pixel along it clear of its corners, where
    the grey level's gradient across it peaks (Sobel, sampled every EDGE_STEP_PX within +-search_px,
    the peak's centroid, `_peak_centroid`; a peak at the window's end is another edge's slope, dropped); cv2.fitLine
    (Huber) fits the side. A quad keeps its own corners when a side has under half its points or a
    corner would move over MAX_CORNER_SHIFT_PX. Ours: cv2.cornerSubPix leaves these squares' corners
    0.35-0.45 px inside each square on rendered frames (1.5-3.5 m, 5-13 px modules), which made the
    pose 0.1 % too far; the sides' crossings are within 0.15 px (docs/results.md, seed 001)."""
    g = grey.astype(np.float32)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    offsets = np.arange(-search_px, search_px + 1e-9, EDGE_STEP_PX)
    corners, refined = np.array(quads, dtype=np.float64), np.zeros(len(quads), bool)
    for q, quad in enumerate(corners):
        lines = []
        for i in range(4):
            a, b = quad[i], quad[(i + 1) % 4]
            length = np.linalg.norm(b - a)
            along = (b - a) / length
            normal = np.array([-along[1], along[0]])
            s = np.arange(2.0, length - 1.999, 1.0)  # two pixels clear of each corner
            if len(s) < 2:
                break
            xy = a + s[:, None, None] * along + offsets[None, :, None] * normal  # (points, offsets, 2)
            map_x, map_y = xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32)
            across = np.abs(cv2.remap(gx, map_x, map_y, cv2.INTER_LINEAR) * normal[0]
                            + cv2.remap(gy, map_x, map_y, cv2.INTER_LINEAR) * normal[1])
            k = np.argmax(across, axis=1)
            inside = (k > 0) & (k < len(offsets) - 1)
            if inside.sum() < max(2, len(s) / 2):
                break
            s, k, rows = s[inside], k[inside], np.flatnonzero(inside)
            points = a + s[:, None] * along + _peak_centroid(across[rows], k, offsets)[:, None] * normal
            vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
            lines.append(np.cross([x0, y0, 1.0], [x0 + vx, y0 + vy, 1.0]))
        if len(lines) < 4:
            continue
        crossings = np.cross(np.roll(lines, 1, axis=0), lines)  # corner i: sides i - 1 and i
        if np.all(np.abs(crossings[:, 2]) > 1e-12):
            moved = crossings[:, :2] / crossings[:, 2:]
            if np.all(np.linalg.norm(moved - quad, axis=1) <= MAX_CORNER_SHIFT_PX):
                corners[q], refined[q] = moved, True
    return corners, refined


def adjustment(grey: np.ndarray, K: np.ndarray, D, layout: RqrlpLayout, min_module_px: float = 5.0,
               max_residual_px: float = 1.0) -> AdjustmentResult | None:
    """The pose from the location markers (module docstring), corners refined to sub-pixel; None
    when a module is under min_module_px (5 px: 7.7 m with seed 001's 1280 px focal length and 30 mm
    modules, where the paper's adjustment pose "tends to stabilize" below 10 m; smaller ones blur
    into biased corners) or the
    corners' RMS residual about the fitted homography exceeds max_residual_px (corners refined onto
    the wrong edges)."""
    markers = classify(location_markers(grey))
    if markers is None:
        return None
    centres = {m: markers[m][0].mean(axis=0) for m in MARKERS}
    x_axis = centres["right"] - centres["top"]
    up_axis = centres["top"] - centres["bottom"]
    x_axis, up_axis = x_axis / np.linalg.norm(x_axis), up_axis / np.linalg.norm(up_axis)
    corners = []
    for m in MARKERS:
        for quad in markers[m]:
            ordered = _ordered(quad, x_axis, up_axis)
            if ordered is None:
                return None
            corners.append(ordered)
    corners = np.concatenate(corners)
    module = float(np.sqrt(cv2.contourArea(markers["top"][0].astype(np.float32)))) / MODULES[0]
    if module < min_module_px:
        return None
    refined, _ = corners_from_sides(grey, corners.reshape(-1, 4, 2), min(EDGE_SEARCH_PX, 0.45 * module))
    pixels = undistort_pixels(refined.reshape(-1, 2), K, D)
    points = layout_corners(layout)
    found = plane_pose(points, pixels, K)
    if found is None:
        return None
    X_CP_homography, inliers = found
    X_CP = refine_pose(X_CP_homography, points[inliers], pixels[inliers], K)
    H = homography_from_pose(X_CP, K)
    projected = np.c_[points[:, :2], np.ones(len(points))] @ H.T
    residual = pixels - projected[:, :2] / projected[:, 2:]
    rms = float(np.sqrt(np.mean(np.sum(residual[inliers] ** 2, axis=1))))
    if rms > max_residual_px:
        return None
    return AdjustmentResult(X_CP, pixels, inliers, rms, fit_pixel_std(residual[inliers], parameters=6), module,
                            X_CP_homography)


# ---- Touchdown --------------------------------------------------------------------------------


class TouchdownTracker:
    """Eq. (3): the pattern's homography into the current frame, H_w^{i+1} = H_i^{i+1} H_w^i, from
    features tracked between frames; anchored (and re-anchored) to a pose, e.g. the adjustment
    node's. Immutable steps: `track` returns the next tracker."""

    def __init__(self, K: np.ndarray, D, layout: RqrlpLayout, max_features: int = 200, min_features: int = 12):
        self.K, self.D = np.asarray(K, dtype=float), D
        self.outline_P = layout.outline_corners_P[:, :2]
        self.max_features, self.min_features = max_features, min_features
        self.grey = None  # the previous frame
        self.points = None  # (N, 2) features in it (distorted pixels)
        self.H = None  # pattern plane -> previous frame's undistorted pixels
        self.chained = 0  # frames since the anchor

    def anchored(self, grey: np.ndarray, X_CP: RigidTransform) -> "TouchdownTracker":
        """A tracker whose chain starts at this frame, where the pattern is at X_CP."""
        out = self._copy()
        out.H, out.chained, out.grey = homography_from_pose(X_CP, self.K), 0, grey
        out.points = self._features(grey, out.H)
        return out

    def track(self, grey: np.ndarray) -> tuple["TouchdownTracker", RigidTransform | None, int]:
        """(the tracker after this frame, X_CP or None, features used)."""
        out = self._copy()
        out.grey = grey
        if self.H is None or self.points is None or len(self.points) < self.min_features:
            out.H, out.points = None, None
            return out, None, 0
        moved, status, _ = cv2.calcOpticalFlowPyrLK(self.grey, grey, self.points.astype(np.float32).reshape(-1, 1, 2),
                                                   None, winSize=(21, 21), maxLevel=3)
        kept = status.ravel().astype(bool)
        if kept.sum() < self.min_features:
            out.H, out.points = None, None
            return out, None, int(kept.sum())
        before = undistort_pixels(self.points[kept], self.K, self.D)
        after = undistort_pixels(moved.reshape(-1, 2)[kept], self.K, self.D)
        step, inliers = cv2.findHomography(before, after, cv2.RANSAC, 1.5)
        if step is None or inliers.sum() < self.min_features:
            out.H, out.points = None, None
            return out, None, 0 if inliers is None else int(inliers.sum())
        out.H = step @ self.H
        out.H /= out.H[2, 2]
        out.chained = self.chained + 1
        survivors = moved.reshape(-1, 2)[kept][inliers.ravel().astype(bool)]
        out.points = survivors if len(survivors) >= self.max_features // 2 else self._features(grey, out.H)
        return out, pose_from_homography(out.H, self.K), int(inliers.sum())

    def _features(self, grey: np.ndarray, H: np.ndarray) -> np.ndarray | None:
        """Good features to track (Shi-Tomasi) inside the pattern's outline as H maps it (the lens'
        distortion neglected for this mask), in distorted pixels."""
        outline = cv2.perspectiveTransform(self.outline_P.reshape(-1, 1, 2), H).reshape(-1, 2)
        mask = np.zeros(grey.shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(outline).astype(np.int32), 255)
        points = cv2.goodFeaturesToTrack(grey, self.max_features, 0.01, 7, mask=mask)
        return None if points is None else points.reshape(-1, 2)

    def _copy(self) -> "TouchdownTracker":
        out = TouchdownTracker.__new__(TouchdownTracker)
        out.__dict__.update(self.__dict__)
        return out
