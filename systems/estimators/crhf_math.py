"""Pure mathematics of the CRHF estimator (seed 000, Sec. 2.4, 2.7 and 2.8).

Camera and Range sensor Homogeneous Fusion: four ToF sensors around a downward camera give four
touch points on the deck; the plane through them, together with focal lengths and principal point
measured from the touch points' pixels, lifts the tag's detected corners to 3-D, and Arun's SVD
method turns the 3-D corners into the tag pose X_CT.

Our addition (not in the paper): the plane's normal from the four ranges does not improve as the
tag grows in the image, while the tag's normal from its corners does. Both normals come with a
covariance (first-order propagation of the range covariance through the plane fit, and of the
corner noise through the perspective-n-point solution), and their information-weighted mean in the
plane's tangent space replaces the range normal before the corners are lifted (`fuse_normals`). When
they disagree beyond noise, the corners' mirror pose tells which one is wrong, and where it cannot, the previous
frame's plane does (`plane_beyond_gate`).

Frames and units: everything is expressed in the camera frame C (+z along the optical axis,
+x right, +y down in the image), in metres. Pixels follow OpenCV: u right, v down, pixel centres
at integers. The tag frame T is the paper's camera-facing one (origin at the tag centre, z into the
tag face); see `tag_corners_T`.
"""

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix


def touch_points(p_C_sensors: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Touch points on the deck in C, metres, shape (N, 3) (Eq. 26: p_st = [p_s,xy, d_i]).

    p_C_sensors: (N, 3) sensor positions in C; ranges: (N,) ranges in metres measured along +z_C
    (the sensors point along the camera axis). Non-finite ranges give non-finite rows.
    """
    p = np.array(p_C_sensors, dtype=float)
    p[:, 2] += np.asarray(ranges, dtype=float)
    return p


class PlaneFit(NamedTuple):
    """A plane {p : normal . p = offset} in C (the form of Eq. 27).

    normal: (3,) unit normal, oriented away from the camera origin so that offset >= 0.
    offset: distance d of the plane from the camera origin, metres.
    rms_residual: RMS orthogonal distance of the fitted points from the plane, metres.
    degenerate: True when the points do not fix a plane (fewer than three, non-finite, coincident
        or collinear); normal and offset are then NaN.
    """

    normal: np.ndarray
    offset: float
    rms_residual: float
    degenerate: bool


def fit_plane(points: np.ndarray, rel_tol: float = 1e-6, abs_tol: float = 1e-9) -> PlaneFit:
    """Least-squares plane through (N, 3) points in metres (replaces Eq. 25-27).

    The paper takes the normal from one cross product of three touch points (Eq. 25) and d from an
    average; here all points enter a total-least-squares fit: the normal is the right singular
    vector of the centred points with the smallest singular value, and d = n . centroid. With
    singular values s0 >= s1 >= s2, the points are coincident when s0 <= abs_tol (metres) and
    collinear when s1 <= rel_tol * s0.
    """
    p = np.asarray(points, dtype=float)
    nan = np.full(3, np.nan)
    if p.shape[0] < 3 or not np.all(np.isfinite(p)):
        return PlaneFit(nan, np.nan, np.nan, True)
    centroid = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - centroid)
    if s[0] <= abs_tol or s[1] <= rel_tol * s[0]:
        return PlaneFit(nan, np.nan, np.nan, True)
    n = vt[2]
    d = float(n @ centroid)
    if d < 0:
        n, d = -n, -d
    return PlaneFit(n, d, float(s[2] / np.sqrt(len(p))), False)


def range_shift(p_C_sensors: np.ndarray, plane: PlaneFit, V_WC_C: np.ndarray, dt: float) -> np.ndarray:
    """Eq. 28's B u for the range track (our model of it): the change of each sensor's range (N,), metres, over
    dt seconds from the camera's own motion over a still deck plane (`plane`, in C at the step's start).

    V_WC_C: the camera's spatial velocity [w; v] in C, rad/s and m/s. In the camera's frame after the step
    (first order in dt) the plane is n' = n - (w dt) x n, d' = d - n . v dt, and a sensor at s_i ranges along
    z_C to r_i = (d - n . s_i) / n_z. Level plane and no rotation: -v_z dt for every sensor."""
    n, d = plane.normal, plane.offset
    v = np.asarray(V_WC_C[3:], dtype=float) * dt
    n_after = direction_after_turn(n, V_WC_C[:3], dt)
    s = np.asarray(p_C_sensors, dtype=float)
    return (d - n @ v - s @ n_after) / n_after[2] - (d - s @ n) / n[2]


def direction_after_turn(direction_C: np.ndarray, w_WC_C: np.ndarray, dt: float) -> np.ndarray:
    """A direction fixed in the world, given in C, expressed in the camera's frame after the camera turned at w_WC_C
    (rad/s, in C) for dt seconds: d - (w dt) x d, first order in dt (its length 1 + O(dt^2) for a unit d)."""
    return direction_C - np.cross(np.asarray(w_WC_C, dtype=float) * dt, direction_C)


def tangent_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane perpendicular to the unit vector `normal`.

    Tilts of a normal are expressed in this basis: the gnomonic chart n + E^T theta (normalised)
    maps a tilt theta (2,), in radians to first order, to a unit vector near n.
    """
    n = np.asarray(normal, dtype=float)
    helper = np.eye(3)[np.argmin(np.abs(n))]  # the axis least aligned with n
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(n, e1)])


def plane_tilt_covariance(
    p_C_touch: np.ndarray, plane: PlaneFit, range_covariance: np.ndarray, basis: np.ndarray
) -> np.ndarray:
    """(2, 2) covariance, rad^2, of the fitted plane's normal tilt in `basis` (our addition).

    p_C_touch: (N, 3) touch points in C, metres, that `fit_plane` turned into `plane`;
    range_covariance: (N, N) covariance of their ranges, m^2 (errors along +z_C, Eq. 26);
    basis: (2, 3) tangent basis of the plane's normal (`tangent_basis`).
    First order: a range error dr_i moves touch point i by n_z dr_i across the plane, and the
    total-least-squares normal tilts by minus the least-squares slope of those offsets over the
    points' centred in-plane coordinates Q (N, 2): theta = -n_z B dr with B = (Q^T Q)^-1 Q^T, so
    the covariance is n_z^2 B Sigma_r B^T.
    """
    p = np.asarray(p_C_touch, dtype=float)
    Q = (p - p.mean(axis=0)) @ basis.T
    B = np.linalg.solve(Q.T @ Q, Q.T)
    return plane.normal[2] ** 2 * B @ np.asarray(range_covariance, dtype=float) @ B.T


class CornerNormal(NamedTuple):
    """The tag's normal from its corners alone (a perspective-n-point solution), in C.

    normal: (3,) unit normal of the tag face, pointing into the tag (away from the camera), i.e.
        the z axis of R_CT. unit_covariance: (3, 3) its covariance per px^2 of corner noise
        (multiply by the variance of one corner coordinate). residual_px2: sum of squared
        reprojection residuals over the corners, px^2, with 2 N - 6 degrees of freedom.
    """

    normal: np.ndarray
    unit_covariance: np.ndarray
    residual_px2: float


def corner_normal(
    uv_corners: np.ndarray, focal_lengths: np.ndarray, principal_point: np.ndarray, p_T_corners: np.ndarray
) -> CornerNormal | None:
    """The tag normal from its corners and its first-order covariance (our addition).

    uv_corners: (N, 2) pixels; focal_lengths (fx, fy) and principal_point (cx, cy) in pixels;
    p_T_corners: (N, 3) the corners in T, metres. OpenCV's SQPnP gives rvec, tvec of X_CT;
    projectPoints gives the reprojection Jacobian J = d(uv)/d(rvec, tvec) (2N x 6), so with
    independent corner noise of variance s^2 per coordinate cov(rvec, tvec) = s^2 (J^T J)^-1;
    Rodrigues' Jacobian carries the rvec block to the normal R_CT[:, 2]. None if PnP fails (also on
    degenerate corners, where SQPnP raises, or where J^T J is singular).
    """
    K, p_T, uv = _pnp_problem(uv_corners, focal_lengths, principal_point, p_T_corners)
    try:
        ok, rvec, tvec = cv2.solvePnP(p_T, uv.reshape(-1, 1, 2), K, None, flags=cv2.SOLVEPNP_SQPNP)
        if not ok or not np.all(np.isfinite(rvec)):
            return None
        return _corner_normal_at(rvec, tvec, K, p_T, uv)
    except (cv2.error, np.linalg.LinAlgError):
        return None


def mirror_corner_normal(
    uv_corners: np.ndarray, focal_lengths: np.ndarray, principal_point: np.ndarray, p_T_corners: np.ndarray,
    normal: np.ndarray,
) -> CornerNormal | None:
    """The other pose the corners of a planar tag allow: of the two solutions of OpenCV's IPPE (Collins and
    Bartoli's planar PnP; the two minima of the reprojection error), the one whose normal is farther from
    `normal` (`corner_normal`'s), with its covariance and residual as in `corner_normal` (our addition).

    Arguments as in `corner_normal`. None if IPPE does not give two finite solutions (or raises).
    """
    K, p_T, uv = _pnp_problem(uv_corners, focal_lengths, principal_point, p_T_corners)
    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(p_T, uv.reshape(-1, 1, 2), K, None, flags=cv2.SOLVEPNP_IPPE)
        solutions = [(r, t) for r, t in zip(rvecs, tvecs) if np.all(np.isfinite(r)) and np.all(np.isfinite(t))]
        if len(solutions) < 2:
            return None
        normals = [cv2.Rodrigues(r)[0][:, 2] for r, _ in solutions]
        farther = int(np.argmin([n @ np.asarray(normal, dtype=float) for n in normals]))
        return _corner_normal_at(*solutions[farther], K, p_T, uv)
    except (cv2.error, np.linalg.LinAlgError):
        return None


def _pnp_problem(uv_corners, focal_lengths, principal_point, p_T_corners):
    """(K, p_T (N, 3) m, uv (N, 2) px) as float arrays for OpenCV's PnP solvers."""
    fx, fy = focal_lengths
    cx, cy = principal_point
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, np.asarray(p_T_corners, dtype=float), np.asarray(uv_corners, dtype=float).reshape(-1, 2)


def _corner_normal_at(rvec, tvec, K, p_T, uv) -> CornerNormal:
    """`corner_normal`'s normal, covariance and residual at the PnP solution (rvec, tvec) of X_CT."""
    uv_model, J = cv2.projectPoints(p_T, rvec, tvec, K, None)
    J = J[:, :6]
    R, dR = cv2.Rodrigues(rvec)  # dR[i, 3 r + c] = d R[r, c] / d rvec[i]
    dn = dR[:, 2::3].T  # d R[:, 2] / d rvec, (3, 3)
    cov_rvec = np.linalg.inv(J.T @ J)[:3, :3]
    residual = float(np.sum((uv_model.reshape(-1, 2) - uv) ** 2))
    return CornerNormal(R[:, 2], dn @ cov_rvec @ dn.T, residual)


class Fusion(NamedTuple):
    """Information-weighted mean of two Gaussian estimates of one quantity.

    mean, covariance: the fused estimate. mahalanobis2: squared Mahalanobis distance between the
    two estimates over the sum of their covariances (chi-square with dim degrees of freedom when
    both are right).
    """

    mean: np.ndarray
    covariance: np.ndarray
    mahalanobis2: float


def fuse_gaussian(mean_a, cov_a, mean_b, cov_b) -> Fusion:
    """Fuse two independent Gaussian estimates (our addition; the paper fuses no covariances).

    The information form (A^-1 + B^-1)^-1 (A^-1 a + B^-1 b) written as a Kalman update,
    a + A (A + B)^-1 (b - a) with covariance A - A (A + B)^-1 A, so that either covariance may be
    singular (an exact estimate wins outright) as long as their sum is not.
    """
    a, b = np.asarray(mean_a, dtype=float), np.asarray(mean_b, dtype=float)
    A, B = np.asarray(cov_a, dtype=float), np.asarray(cov_b, dtype=float)
    S = A + B
    difference = b - a
    gain = np.linalg.solve(S, A).T  # A S^-1, both symmetric
    covariance = A - gain @ A
    return Fusion(a + gain @ difference, (covariance + covariance.T) / 2,
                  float(difference @ np.linalg.solve(S, difference)))


# Gate on the two normals' disagreement: the chi-square quantile with 2 degrees of freedom at
# 0.999 (its survival function is exp(-x / 2)). Beyond it the corners' normal is not the same
# plane's within noise, and `plane_beyond_gate` decides which of the two is wrong. `corners_fit_a_tag`
# judges the corners' own PnP residual at the same probability.
GATE_PROBABILITY = 0.999
NORMAL_GATE = -2.0 * np.log(1.0 - GATE_PROBABILITY)


def residual_gate(pool_dof: float) -> float:
    """The largest PnP residual (2 degrees of freedom), in units of a corner variance pooled over pool_dof degrees
    of freedom, that noise explains at `GATE_PROBABILITY` (our addition).

    The residual over 2 times the pooled variance is F(2, pool_dof)-distributed, whose survival function is
    (1 + 2 x / pool_dof)^(-pool_dof / 2); its quantile, times 2, is pool_dof (exp(NORMAL_GATE / pool_dof) - 1).
    That is wider than `NORMAL_GATE` while the pool holds a few frames (2.2 times at 10 degrees of freedom), because
    their variance is itself uncertain, and tends to it as the pool grows (inf: `NORMAL_GATE`).
    """
    return NORMAL_GATE if np.isinf(pool_dof) else float(pool_dof * np.expm1(NORMAL_GATE / pool_dof))


def corners_fit_a_tag(residual_px2: float, corner_variance_px2: float, pool_dof: float = np.inf) -> bool:
    """Whether the corners' PnP reprojection residual (px^2, 2 degrees of freedom) is within `residual_gate` times the
    variance of one corner coordinate (px^2, pooled over pool_dof degrees of freedom; inf: known exactly): corners
    that fit no rigid tag (a corner track coasting through a fast turn) give no normal to fuse (our addition)."""
    return bool(residual_px2 <= residual_gate(pool_dof) * corner_variance_px2)


def fuse_normals(
    plane: PlaneFit, p_C_touch: np.ndarray, range_covariance: np.ndarray, corners: CornerNormal,
    corner_variance_px2: float,
) -> PlaneFit | None:
    """The deck plane with its normal fused from the ranges and the corners (our addition).

    plane: `fit_plane` of the touch points p_C_touch (N, 3, m, in C); range_covariance (N, N, m^2);
    corners: the corner normal; corner_variance_px2: variance of one corner coordinate, px^2.
    Both normals become tilts in the range normal's tangent basis E: the range plane's is 0 with
    `plane_tilt_covariance`; the corners' normal m maps through the gnomonic chart,
    theta = E m / (n . m), whose Jacobian (E - theta n^T) / (n . m) carries its covariance. The
    fused tilt gives the normal; the plane keeps passing through the touch points' centroid, so
    its offset (and the estimate's depth) stays the ranges'. None beyond `NORMAL_GATE`, or when the
    two normals point into opposite half-spaces: one of them is not the tag's plane.
    """
    n, m = plane.normal, corners.normal
    E = tangent_basis(n)
    cosine = float(n @ m)
    if cosine <= 0.0:
        return None
    theta = E @ m / cosine
    chart = (E - np.outer(theta, n)) / cosine
    cov_corners = corner_variance_px2 * chart @ corners.unit_covariance @ chart.T
    cov_ranges = plane_tilt_covariance(p_C_touch, plane, range_covariance, E)
    fused = fuse_gaussian(np.zeros(2), cov_ranges, theta, cov_corners)
    if fused.mahalanobis2 > NORMAL_GATE:
        return None
    return plane_through_centroid(n + E.T @ fused.mean, p_C_touch)


def plane_through_centroid(normal: np.ndarray, p_C_touch: np.ndarray) -> PlaneFit:
    """The plane with the given normal (3,) through the centroid of the touch points (N, 3, m, in C),
    with their RMS distance from it."""
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    p = np.asarray(p_C_touch, dtype=float)
    offset = float(normal @ p.mean(axis=0))
    return PlaneFit(normal, offset, float(np.sqrt(np.mean((p @ normal - offset) ** 2))), False)


def plane_beyond_gate(
    plane: PlaneFit, p_C_touch: np.ndarray, range_covariance: np.ndarray, corners: CornerNormal,
    mirror: CornerNormal | None, corner_variance_px2: float, previous_normal: np.ndarray | None = None,
) -> PlaneFit | None:
    """The plane to lift the corners onto when `fuse_normals` refused the two normals (our addition); None
    when the frame cannot tell which of two planes is the deck's.

    Arguments as in `fuse_normals`; mirror: `mirror_corner_normal` of the same corners (None if IPPE gave no
    second solution); previous_normal: the last valid frame's deck normal in this frame's C (None: no previous
    frame; `direction_after_turn` carries it through the camera's own turn). One of
    the two normals is not the tag's plane:
    - the corners fix one plane and the ranges do not see it (a cone reading past the deck's edge, a biased
      sensor): the corners' normal is taken, through the touch points' centroid as in the fusion;
    - but the corners are ambiguous when their other solution (a planar PnP's mirror pose) agrees with the
      ranges within `NORMAL_GATE`. Then either the corners chose the wrong one of their two poses (a small tag
      seen square-on) or the ranges see a plane tilted the mirror's way (cones averaging the deck's surroundings),
      and the one nearer the previous frame's normal is taken (the ranges' on a tie), as deck and camera turn
      little in a frame. Without a previous normal (the first frame, or over `CrhfConfig.deck_normal_memory_s`
      after the last valid one) nothing tells them apart: None, and the frame is flagged invalid rather than
      given a plane that may be 10-30 deg off.
    The range plane is also kept when the corners' normal points into the other half-space, or when there
    is no mirror to judge the corners by.
    """
    if mirror is None or corners.normal @ plane.normal <= 0.0:
        return plane
    ambiguous = fuse_normals(plane, p_C_touch, range_covariance, mirror, corner_variance_px2) is not None
    if ambiguous and previous_normal is None:
        return None
    if ambiguous and plane.normal @ previous_normal >= corners.normal @ previous_normal:
        return plane
    return plane_through_centroid(corners.normal, p_C_touch)


def principal_point_from_touch_points(p_C_touch: np.ndarray, uv_touch: np.ndarray) -> np.ndarray:
    """Principal point (cx, cy) in pixels from the touch points and their pixels (Eq. 45).

    p_C_touch: (4, 3) touch points in C, metres; uv_touch: (4, 2) their pixel coordinates.
    Eq. 45 weights each touch pixel by the sensor's range d_i; we weight by the touch point's depth
    Z_i, which is d_i for sensors in the camera's z = 0 plane (Eq. 21-24). Since
    Z_i * u_i = Z_i * cx + fx * X_i, the weighted mean is exactly (cx, cy) whenever the sensors'
    lateral offsets sum to zero, as they do for the symmetric layout of Eq. 21-24.
    """
    z = np.asarray(p_C_touch, dtype=float)[:, 2]
    return z @ np.asarray(uv_touch, dtype=float) / z.sum()


def focal_lengths_from_touch_points(
    p_C_touch: np.ndarray, uv_touch: np.ndarray, principal_point: np.ndarray
) -> np.ndarray:
    """Focal lengths (fx, fy) in pixels from the touch points (Eq. 40-44).

    Each touch point gives fx_i = (u_i - cx) * Z_i / X_i and fy_i = (v_i - cy) * Z_i / Y_i
    (Eq. 40-43 solved for the focal length, pixels measured from the principal point); Eq. 44
    averages the four. p_C_touch: (4, 3) in C, metres; uv_touch: (4, 2) pixels;
    principal_point: (cx, cy) pixels. Raises ValueError if a sensor lies on a camera axis
    (X_i or Y_i zero), which the 45-degree layout of Eq. 21-24 never does.
    """
    p = np.asarray(p_C_touch, dtype=float)
    if np.any(np.abs(p[:, :2]) < 1e-9):
        raise ValueError("a touch point lies on the camera's x or y axis: focal length undefined")
    centred = np.asarray(uv_touch, dtype=float) - np.asarray(principal_point, dtype=float)
    return np.mean(centred * p[:, 2:3] / p[:, :2], axis=0)


def intersect_pixel_rays_with_plane(
    uv: np.ndarray, focal_lengths: np.ndarray, principal_point: np.ndarray, plane: PlaneFit
) -> tuple[np.ndarray, np.ndarray]:
    """3-D points in C, metres, where the pixels' viewing rays meet the plane (Eq. 46-53).

    uv: (N, 2) pixels; focal_lengths (fx, fy) and principal_point (cx, cy) in pixels.
    Each pixel's ray is r = [(u - cx)/fx, (v - cy)/fy, 1]; the point Z * r on n . p = d has
    Z = d / (n . r), which is Eq. 46-49 with the normalised coordinates written as (u - cx)/fx;
    X = Z (u - cx)/fx and Y = Z (v - cy)/fy is Eq. 50-53.
    Returns (points (N, 3), valid (N,)); a row is invalid (and NaN) when the plane is degenerate,
    the input is non-finite, or the ray is parallel to the plane or meets it behind the camera (the plane
    as `PlaneFit` holds it: its normal away from the camera, offset >= 0).
    """
    uv = np.asarray(uv, dtype=float)
    rays = np.column_stack(
        [(uv - np.asarray(principal_point, dtype=float)) / np.asarray(focal_lengths, dtype=float),
         np.ones(len(uv))]
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        denominator = rays @ plane.normal
        z = plane.offset / denominator
        valid = np.isfinite(z) & (denominator > 1e-12) & (z > 0)
        points = np.where(valid[:, None], z[:, None] * rays, np.nan)
    return points, valid


def arun_rigid_transform(p_AQ: np.ndarray, p_BQ: np.ndarray) -> RigidTransform:
    """X_BA minimising sum |p_BQ - X_BA p_AQ|^2 over rotations (Arun et al.; Eq. 54-61).

    p_AQ, p_BQ: (N, 3) corresponding points Q measured in frames A and B, N >= 3 and not all
    collinear. Centroids (Eq. 54-55), centred points (Eq. 56-57), H = sum of a_i b_i^T (Eq. 58),
    H = U S V^T (Eq. 59), R = V diag(1, 1, sign det(V U^T)) U^T (Eq. 60; the last entry is the
    reflection guard, needed e.g. for coplanar points such as a tag's corners), t = c_B - R c_A
    (Eq. 61).
    """
    p_AQ = np.asarray(p_AQ, dtype=float)
    p_BQ = np.asarray(p_BQ, dtype=float)
    if p_AQ.shape != p_BQ.shape or p_AQ.ndim != 2 or p_AQ.shape[1] != 3 or len(p_AQ) < 3:
        raise ValueError(f"need two (N, 3) point sets, N >= 3, got {p_AQ.shape} and {p_BQ.shape}")
    c_A = p_AQ.mean(axis=0)
    c_B = p_BQ.mean(axis=0)
    H = (p_AQ - c_A).T @ (p_BQ - c_B)
    U, _, Vt = np.linalg.svd(H)
    guard = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ guard @ U.T
    return RigidTransform(RotationMatrix(R), c_B - R @ c_A)


@dataclass(frozen=True)
class CrhfEstimate:
    """One CRHF frame: the tag pose and the intermediate quantities behind it.

    X_CT: tag pose in C (identity when not valid). valid: every step succeeded.
    plane: the deck plane the corners were lifted onto: the touch points' plane, its normal fused
    with the corners' (`fuse_normals`) when a corner variance was given and the gate passed, else as
    `plane_beyond_gate` chose (the touch points' plane where it could not choose). touch_residual_m: RMS
    distance of the touch points from their own least-squares plane (`fit_plane`), m; NaN when they do not fix one.
    focal_lengths (fx, fy) and principal_point (cx, cy): pixels, measured this frame from the
    touch points (Eq. 40-45), whichever intrinsics the corners were lifted with; NaN when the touch points
    fix no plane or a touch or corner pixel is not finite (the frame is then not measured at all).
    p_C_corners: (4, 3) tag corners in C, metres (NaN rows where a ray missed the plane).
    corner_residual_px2: the corners' PnP reprojection residual, px^2, 2 degrees of freedom (NaN
    when the corners' normal was not computed).
    tag_residual_m: RMS distance of p_C_corners from the tag placed at X_CT (Eq. 54-61's residual), m;
    NaN when not valid. The lifted corners of the tag's own plane fit it to the corner noise; a plane
    through another surface stretches or scales them away from it.
    touch_offset_m: the largest distance of a touch point from `plane`, m (NaN when not valid). Where the
    corners' normal is taken beyond the gate, a touch point on another surface (the ground past the deck's
    edge) lies this far from the plane and has moved it along its normal by a quarter of that.
    """

    X_CT: RigidTransform
    valid: bool
    plane: PlaneFit
    touch_residual_m: float
    focal_lengths: np.ndarray
    principal_point: np.ndarray
    p_C_corners: np.ndarray
    corner_residual_px2: float = np.nan
    tag_residual_m: float = np.nan
    touch_offset_m: float = np.nan


def crhf_tag_pose(
    p_C_sensors: np.ndarray,
    ranges: np.ndarray,
    uv_touch: np.ndarray,
    uv_corners: np.ndarray,
    p_T_corners: np.ndarray,
    *,
    intrinsics: tuple[np.ndarray, np.ndarray] | None = None,
    range_covariance: np.ndarray | None = None,
    corner_variance_px2: float | None = None,
    corner_variance_dof: float = np.inf,
    previous_normal: np.ndarray | None = None,
) -> CrhfEstimate:
    """The CRHF pipeline of Sec. 2.4-2.8 for one frame.

    p_C_sensors: (4, 3) sensor positions in C, metres (`systems.sensors.tof.sensor_positions_C`).
    ranges: (4,) ToF ranges, metres (NaN for a sensor that returned nothing).
    uv_touch: (4, 2) pixels of the touch points (from the pad calibration, Sec. 2.3).
    uv_corners: (4, 2) detected (or filtered) tag corners, pixels.
    p_T_corners: (4, 3) the same corners in the tag frame T, metres (`tag_corners_T`, Eq. 62).
    Our additions, each off when None: intrinsics, ((fx, fy), (cx, cy)) in pixels to lift the
    corners with instead of this frame's Eq. 40-45 (e.g. their mean over earlier frames);
    range_covariance, (4, 4) m^2 of the ranges: the corners' own normal is computed and its
    residual reported, and with corner_variance_px2 (variance of one corner coordinate, px^2) it
    is fused with the touch points' normal where the corners fit a rigid tag (`corners_fit_a_tag`, the variance
    pooled over corner_variance_dof degrees of freedom; `fuse_normals`; beyond its gate `plane_beyond_gate`, which
    looks for the corners' mirror solution only then, and previous_normal, the previous frame's deck normal in this
    frame's C; a frame whose two planes it cannot tell apart is flagged invalid, its plane the ranges').
    Never raises on bad measurements or a sensor on a camera axis: the estimate is then flagged invalid.
    """
    p_C_touch = touch_points(p_C_sensors, ranges)
    plane = fit_plane(p_C_touch)
    nan2 = np.full(2, np.nan)
    finite = np.all(np.isfinite(uv_touch)) and np.all(np.isfinite(uv_corners))
    if plane.degenerate or not finite:
        return CrhfEstimate(RigidTransform(), False, plane, plane.rms_residual, nan2, nan2, np.full((4, 3), np.nan))
    principal_point = principal_point_from_touch_points(p_C_touch, uv_touch)
    try:
        focal_lengths = focal_lengths_from_touch_points(p_C_touch, uv_touch, principal_point)
    except ValueError:  # a sensor on a camera axis: no focal length (`TofConfig.validate` refuses such a layout)
        return CrhfEstimate(RigidTransform(), False, plane, plane.rms_residual, nan2, principal_point,
                            np.full((4, 3), np.nan))
    f, c = (focal_lengths, principal_point) if intrinsics is None else intrinsics
    valid = bool(np.all(focal_lengths > 0) and np.all(np.asarray(f) > 0))
    residual, touch_residual = np.nan, plane.rms_residual
    if valid and range_covariance is not None:
        corners = corner_normal(uv_corners, f, c, p_T_corners)
        residual = np.nan if corners is None else corners.residual_px2
        if (corners is not None and corner_variance_px2 is not None
                and corners_fit_a_tag(corners.residual_px2, corner_variance_px2, corner_variance_dof)):
            fused = fuse_normals(plane, p_C_touch, range_covariance, corners, corner_variance_px2)
            if fused is None:
                mirror = mirror_corner_normal(uv_corners, f, c, p_T_corners, corners.normal)
                fused = plane_beyond_gate(plane, p_C_touch, range_covariance, corners, mirror, corner_variance_px2,
                                          previous_normal)
            valid = fused is not None
            plane = plane if fused is None else fused
    p_C_corners, hit = intersect_pixel_rays_with_plane(uv_corners, f, c, plane)
    valid = valid and bool(np.all(hit))
    if not valid:
        return CrhfEstimate(RigidTransform(), False, plane, touch_residual, focal_lengths, principal_point,
                            p_C_corners, residual)
    X_CT = arun_rigid_transform(p_T_corners, p_C_corners)
    misfit = X_CT.multiply(np.asarray(p_T_corners, dtype=float).T).T - p_C_corners
    tag_residual = float(np.sqrt(np.mean(np.sum(misfit**2, axis=1))))
    touch_offset = float(np.max(np.abs(p_C_touch @ plane.normal - plane.offset)))
    return CrhfEstimate(X_CT, True, plane, touch_residual, focal_lengths, principal_point, p_C_corners, residual,
                        tag_residual, touch_offset)
