"""ATDA, the baseline of seed 000 (section 2.5): the tag pose from its four detected corners alone.

The pose comes from OpenCV's `solvePnP` on the same OpenCV ArUco corners every estimator here
shares (pupil-apriltags would add a second detector and decode the image twice; the comparison with
CRHF is fairer on identical corners). The solver is `SOLVEPNP_SQPNP` (Terzakis and Lourakis 2020), the
global minimiser of the squared reprojection errors in normalised image coordinates each weighted by its
point's squared depth (for a tag, whose corners lie at nearly one depth, nearly the reprojection error's
minimiser), not `SOLVEPNP_IPPE_SQUARE`: before OpenCV 5.1 (4.10 and 5.0,
which the project allows) IPPE_SQUARE returns a wrong pose whenever the tag is exactly parallel to the
image plane (head-on under a hovering camera both of its solutions reproject 80 px off; yawed 30
degrees the chosen one is 6.4 degrees off), which `tests/test_atda.py` shows; 5.1 solves it. A planar
square admits two poses of nearly equal reprojection error under noise; taking the smaller one is what
makes single-tag poses "flip", and the benchmark counts such frames.
"""

import time

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem, ValueProducer

from systems.estimators.estimate import PoseEstimate, RunningMean
from systems.perception.apriltag import TagDetection, tag_corners_T

# T (camera-facing: y down, z into the tag) from OpenCV's marker frame S (y up, z out of the tag).
_X_ST = RigidTransform(RotationMatrix.MakeXRotation(np.pi))
# No camera's image reaches a million pixels from its corner; the bound keeps the corners within float32's range
# and a tenth of a pixel, in the type OpenCV's contour functions take.
MAX_CORNER_PX = 1e6


def atda_pose(corners_px: np.ndarray, K: np.ndarray, tag_size_m: float) -> RigidTransform | None:
    """X_CT from the tag's four corners (4x2 px, ArUco order), or None where they cannot be a tag's image: a
    corner not finite or beyond `MAX_CORNER_PX`, the four not a convex quadrilateral of at least a square pixel
    (coincident corners make SQPnP raise, collinear ones give it a pose of nothing), or PnP fails or refuses them
    (SQPnP raises cv2.error on points too close together in normalised coordinates: a square of 2 px at f 458 px)."""
    corners = np.asarray(corners_px, dtype=float).reshape(4, 1, 2)
    if not np.all(np.abs(corners) < MAX_CORNER_PX):  # False for NaN too
        return None
    quad = corners.astype(np.float32)
    if not cv2.isContourConvex(quad) or cv2.contourArea(quad) < 1.0:
        return None
    object_points_S = _X_ST.multiply(tag_corners_T(tag_size_m).T).T
    try:
        ok, rvec, tvec = cv2.solvePnP(object_points_S, corners, K, None, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:
        return None
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    R_CS, _ = cv2.Rodrigues(rvec)
    return RigidTransform(RotationMatrix(R_CS), tvec.ravel()).multiply(_X_ST)


class AtdaEstimator(LeafSystem):
    """Input `tag_detection` (TagDetection); output `X_CT_estimate` (PoseEstimate) from the detection at the
    context's time, invalid when the tag is not detected; evaluate it at the camera rate. The estimate depends on
    no state: the only state, advanced by a periodic update at `period_s` (the camera's), is the wall time of each
    frame's pose so far (`per_frame_ms`, for reports)."""

    def __init__(self, K: np.ndarray, tag_size_m: float, period_s: float):
        super().__init__()
        self._K, self._tag_size = np.asarray(K, dtype=float), tag_size_m
        self.DeclareAbstractInputPort("tag_detection", AbstractValue.Make(TagDetection()))
        self._compute_ms = self.DeclareAbstractState(AbstractValue.Make(RunningMean()))
        self._frame = self.DeclareCacheEntry(
            "frame", ValueProducer(allocate=lambda: AbstractValue.Make((PoseEstimate(), 0.0)), calc=self._calc_frame),
            {self.time_ticket(), self.get_input_port().ticket()})
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._update)
        self.DeclareAbstractOutputPort("X_CT_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._frame.Eval(c)[0]), {self._frame.ticket()})

    def _calc_frame(self, context, value):
        """(the frame's PoseEstimate, the wall time of its pose in ms)."""
        detection = self.get_input_port().Eval(context)
        start = time.perf_counter()
        X_CT = atda_pose(detection.corners, self._K, self._tag_size) if detection.detected else None
        elapsed_ms = 1e3 * (time.perf_counter() - start)
        value.set_value((PoseEstimate(context.get_time(), X_CT, True, reference="C", target="T") if X_CT is not None
                         else PoseEstimate.invalid(context.get_time(), "C", "T"), elapsed_ms))

    def _update(self, context, state):
        compute_ms = context.get_abstract_state(self._compute_ms).get_value()
        state.get_mutable_abstract_state(self._compute_ms).set_value(compute_ms.add(self._frame.Eval(context)[1]))

    def per_frame_ms(self, context) -> float | None:
        """The mean wall time of a frame's pose so far (ms), None before the first; `context` is this system's."""
        return context.get_abstract_state(self._compute_ms).get_value().mean
