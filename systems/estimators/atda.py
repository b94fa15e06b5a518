"""ATDA, the baseline of seed 000 (section 2.5): the tag pose from its four detected corners alone.

The pose comes from OpenCV's `solvePnP` on the same OpenCV ArUco corners every estimator here
shares (pupil-apriltags would add a second detector and decode the image twice; the comparison with
CRHF is fairer on identical corners). The solver is `SOLVEPNP_SQPNP`, the globally optimal
minimiser of the reprojection error, not `SOLVEPNP_IPPE_SQUARE`: before OpenCV 5.1 (4.10 and 5.0,
which the project allows) IPPE_SQUARE returns a wrong pose whenever the tag is exactly parallel to the
image plane (head-on under a hovering camera both of its solutions reproject 80 px off; yawed 30
degrees the chosen one is 6.4 degrees off), which `tests/test_atda.py` shows; 5.1 solves it. A planar
square admits two poses of nearly equal reprojection error under noise; taking the smaller one is what
makes single-tag poses "flip", and the benchmark counts such frames.
"""

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.estimators.estimate import PoseEstimate
from systems.perception.apriltag import TagDetection, tag_corners_T

# T (camera-facing: y down, z into the tag) from OpenCV's marker frame S (y up, z out of the tag).
_X_ST = RigidTransform(RotationMatrix.MakeXRotation(np.pi))


def atda_pose(corners_px: np.ndarray, K: np.ndarray, tag_size_m: float) -> RigidTransform | None:
    """X_CT from the tag's four corners (4x2 px, ArUco order), or None if PnP fails."""
    object_points_S = _X_ST.multiply(tag_corners_T(tag_size_m).T).T
    ok, rvec, tvec = cv2.solvePnP(object_points_S, np.asarray(corners_px, dtype=float).reshape(4, 1, 2), K, None,
                                  flags=cv2.SOLVEPNP_SQPNP)
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    R_CS, _ = cv2.Rodrigues(rvec)
    return RigidTransform(RotationMatrix(R_CS), tvec.ravel()).multiply(_X_ST)


class AtdaEstimator(LeafSystem):
    """Input `tag_detection` (TagDetection); output `X_CT_estimate` (PoseEstimate), invalid when
    the tag is not detected. Stateless: evaluate it at the camera rate."""

    def __init__(self, K: np.ndarray, tag_size_m: float):
        super().__init__()
        self._K, self._tag_size = np.asarray(K, dtype=float), tag_size_m
        self.DeclareAbstractInputPort("tag_detection", AbstractValue.Make(TagDetection()))
        self.DeclareAbstractOutputPort("X_CT_estimate", lambda: AbstractValue.Make(PoseEstimate()), self._calc)

    def _calc(self, context, output):
        detection = self.get_input_port().Eval(context)
        X_CT = atda_pose(detection.corners, self._K, self._tag_size) if detection.detected else None
        output.set_value(PoseEstimate(context.get_time(), X_CT, True, reference="C", target="T") if X_CT is not None
                         else PoseEstimate.invalid(context.get_time(), "C", "T"))
