"""What seed 001's vision nodes tell the federated filter (`NodeMeasurement`), with covariances from
the image: a pose's from the reprojection Jacobian of the points it was solved from (first order,
the pixel noise from the fit's residuals; `PatternView`: about the filter's own pose), the rough
position's from its apparent size."""

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform

from systems.quaternion import skew

MIN_PIXEL_STD = 0.3  # px: no fit is trusted beyond the renderer's quantisation
APPROACH_PIXEL_STD = 0.4  # px: the outline's sides and centre (open-landing: 0.3-0.4 px from 20 m to 5 m)
APPROACH_REL_STD = 0.002  # the rough position's relative depth error beyond its pixels' (tilt, lens)


@dataclass(frozen=True)
class PatternView:
    """A pose node's own result, the pattern's pose in the camera (Eq. 2's R and t), with what it was
    solved from: the points (N, 3, in P) through the pinhole K (the pixels undistorted) at pixel noise
    pixel_std (px). A filter takes its covariance (`covariance_at`) linearised about its own estimate:
    far off, the pose errs along the orbit about the pattern (tilt), and a covariance linearised about
    such a pose correlates its error with itself (tests/test_federated_filter.py)."""

    X_CP: RigidTransform
    points_P: np.ndarray
    K: np.ndarray
    pixel_std: float

    def covariance_at(self, X_CP: RigidTransform) -> np.ndarray:
        """(6x6) over [dtheta (in C), dp (in C)] (rad, m), about X_CP."""
        return pattern_pose_covariance(self.points_P, X_CP, self.K, self.pixel_std)


@dataclass(frozen=True)
class NodeMeasurement:
    """One node's measurement at `time` [s]: with `X_PB` a full pose of the body B in the pattern
    frame P, covariance (6x6) over [dtheta (rotation vector in P), dp] (rad, m), None where a `view`
    (a pose node's own result, which the filters update with) gives it (`pose_covariance`); else `p_CP`,
    the pattern's centre in the camera (m), covariance (3x3). `quality`: the node's own figure
    (features, pixels) for logs."""

    time: float
    node: str
    covariance: np.ndarray | None
    X_PB: RigidTransform | None = None
    p_CP: np.ndarray | None = None
    quality: float = 0.0
    view: PatternView | None = None

    @property
    def finite(self) -> bool:
        """Whether every number it carries is finite (one that is not has measured nothing)."""
        parts = [self.covariance, self.p_CP, None if self.X_PB is None else self.X_PB.GetAsMatrix34(),
                 None if self.view is None else self.view.X_CP.GetAsMatrix34(),
                 None if self.view is None else self.view.pixel_std]
        return all(np.all(np.isfinite(p)) for p in parts if p is not None)

    def pose_covariance(self, X_BC: RigidTransform) -> np.ndarray:
        """X_PB's covariance: `covariance`, or derived from the view (only a restart needs it)."""
        return self.covariance if self.view is None else body_pose_covariance(self.view, X_BC)


def pattern_pose_covariance(points_P: np.ndarray, X_CP: RigidTransform, K: np.ndarray, pixel_std: float) -> np.ndarray:
    """(6x6) covariance over [dtheta (rotation vector in C), dp (in C)] of the pattern's pose in the
    camera, X_CP, solved from the points (N, 3, in P) by a pinhole camera K with pixel noise
    `pixel_std`: pixel_std^2 (J^T J)^-1, J the reprojections' analytic Jacobian."""
    turned = (X_CP.rotation().matrix() @ np.asarray(points_P, dtype=float).T).T  # R_CP p
    p_C = turned + X_CP.translation()
    x, y, z = p_C.T
    J_pixel = np.zeros((len(p_C), 2, 3))  # d(pixel)/d(p_C)
    J_pixel[:, 0, 0], J_pixel[:, 0, 2] = K[0, 0] / z, -K[0, 0] * x / z**2
    J_pixel[:, 1, 1], J_pixel[:, 1, 2] = K[1, 1] / z, -K[1, 1] * y / z**2
    J_point = np.concatenate([-np.array([skew(p) for p in turned]), np.broadcast_to(np.eye(3), (len(p_C), 3, 3))],
                             axis=2)  # d(p_C)/d[dtheta, dp]: Exp(dtheta) R_CP p + p_CP + dp
    J = (J_pixel @ J_point).reshape(-1, 6)
    covariance = max(pixel_std, MIN_PIXEL_STD) ** 2 * np.linalg.inv(J.T @ J)
    return (covariance + covariance.T) / 2


def body_pose_covariance(view: PatternView, X_BC: RigidTransform) -> np.ndarray:
    """(6x6) covariance over [dtheta (in P), dp (in P)] of the body's pose in P, X_PB = (X_BC X_CP)^-1,
    from the view's about its own X_CP (first order: dtheta_P = -R_PC dtheta_C, dp_PB = [p_PB]x R_PC
    dtheta_C - R_PC dp_C)."""
    R_PC = view.X_CP.rotation().matrix().T
    p_PB = pose_of_body(view.X_CP, X_BC).translation()
    A = np.block([[-R_PC, np.zeros((3, 3))], [skew(p_PB) @ R_PC, -R_PC]])
    covariance = A @ view.covariance_at(view.X_CP) @ A.T
    return (covariance + covariance.T) / 2


def fit_pixel_std(residuals_px: np.ndarray, parameters: int) -> float:
    """The pixel noise per coordinate [px] from the residuals (N, 2) of a fit of `parameters` unknowns (a
    pose's 6): sqrt(sum r^2 / (2 N - parameters))."""
    residuals_px = np.asarray(residuals_px, dtype=float)
    return float(np.sqrt(np.sum(residuals_px**2) / max(residuals_px.size - parameters, 1)))


def approach_covariance(p_CP: np.ndarray, side_px: float, focal_px: float,
                        pixel_std: float = APPROACH_PIXEL_STD) -> np.ndarray:
    """(3x3) of the rough position p_CP = z [u, v, 1] (u, v the centre's normalised coordinates):
    the depth z from the apparent size, relative error pixel_std / side_px and APPROACH_REL_STD;
    u and v with pixel_std / focal_px; first order."""
    z = float(p_CP[2])
    u, v = p_CP[0] / z, p_CP[1] / z
    var_z = z**2 * ((pixel_std / side_px) ** 2 + APPROACH_REL_STD**2)
    var_uv = (pixel_std / focal_px) ** 2
    J = np.array([[z, 0.0, u], [0.0, z, v], [0.0, 0.0, 1.0]])  # d(p_CP)/d(u, v, z)
    return J @ np.diag([var_uv, var_uv, var_z]) @ J.T


TRACK_STEP_PX = 0.1  # px: the touchdown chain's drift per frame, a random walk (ours)


def pose_of_body(X_CP: RigidTransform, X_BC: RigidTransform) -> RigidTransform:
    """X_PB from the pattern seen in the camera (X_CP) and the camera's mount X_BC."""
    return X_BC.multiply(X_CP).inverse()


def approach_measurement(p_CP: np.ndarray, side_px: float, time: float, focal_px: float) -> NodeMeasurement:
    """The approaching node's rough position (nodes.approach) as the filter takes it."""
    return NodeMeasurement(time, "approach", approach_covariance(p_CP, side_px, focal_px), p_CP=np.asarray(p_CP),
                           quality=side_px)


def adjustment_measurement(X_CP: RigidTransform, points_P: np.ndarray, pixel_std: float, time: float,
                           X_BC: RigidTransform, K: np.ndarray) -> NodeMeasurement:
    """The adjustment node's pose (nodes.adjustment) with the covariance of its corners (points_P)
    as independent measurements at its fit's pixel noise per coordinate (`pixel_std`, px, from
    `fit_pixel_std`; also the measurement's `quality`); how consistent it is in the loop: docs/results.md
    (the federated filter's section)."""
    view = PatternView(X_CP, points_P, K, max(pixel_std, MIN_PIXEL_STD))
    return NodeMeasurement(time, "adjustment", None, X_PB=pose_of_body(X_CP, X_BC), quality=pixel_std, view=view)


def touchdown_measurement(X_CP: RigidTransform, outline_P: np.ndarray, anchor_px: float, chained: int, time: float,
                          X_BC: RigidTransform, K: np.ndarray) -> NodeMeasurement:
    """The touchdown node's chained pose (nodes.TouchdownTracker): the covariance of the pattern's
    outline corners (outline_P) at the anchor's pixel noise plus the chain's random walk,
    anchor_px^2 + chained TRACK_STEP_PX^2."""
    view = PatternView(X_CP, outline_P, K, float(np.sqrt(anchor_px**2 + chained * TRACK_STEP_PX**2)))
    return NodeMeasurement(time, "touchdown", None, X_PB=pose_of_body(X_CP, X_BC), quality=chained, view=view)


NODE_VECTOR_SIZE = 9  # node_vector's


def node_vector(measurement: NodeMeasurement | None) -> np.ndarray:
    """For logs: [present, x, y, z, qw, qx, qy, qz, quality]: a pose node's X_PB (m, in P), the
    approaching node's p_CP (m, in C) with a NaN quaternion; NaN but `present` 0 when None."""
    out = np.full(NODE_VECTOR_SIZE, np.nan)
    out[0] = float(measurement is not None)
    if measurement is None:
        return out
    out[8] = measurement.quality
    if measurement.X_PB is None:
        out[1:4] = measurement.p_CP
        return out
    out[1:4] = measurement.X_PB.translation()
    out[4:8] = measurement.X_PB.rotation().ToQuaternion().wxyz()
    return out
