"""Ground truth: the camera's velocity, the scene's motion across its image, and the pose of a target frame
P (e.g. the deck) in the camera frame C."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem


def pose_vector(X: RigidTransform) -> np.ndarray:
    """[x, y, z (m), qw, qx, qy, qz] of a pose (Drake's w-first quaternion)."""
    return np.concatenate([X.translation(), X.rotation().ToQuaternion().wxyz()])


def camera_motion(X_WB: RigidTransform, V_WB: np.ndarray, X_BC: RigidTransform) -> tuple[RigidTransform, np.ndarray]:
    """(X_WC, V_WC: [w; v] in W, rad/s and m/s) of a camera C mounted at X_BC on a body B moving at V_WB
    ([w; v] of B's origin in W): v_WC = v_WB + w_WB x p_BC_W."""
    p_BC_W = X_WB.rotation().multiply(X_BC.translation())
    return X_WB.multiply(X_BC), np.concatenate([V_WB[:3], V_WB[3:] + np.cross(V_WB[:3], p_BC_W)])


class CameraVelocity(LeafSystem):
    """The spatial velocity of a camera C mounted at X_BC on a body B, expressed in C: V_WC_C = R_CW [w_WB;
    v_WB + w_WB x p_BC_W] (rad/s, m/s).

    Inputs: X_WB (RigidTransform) and V_WB (6: [w; v] in W, rad/s and m/s). Output: V_WC_C (6: [w; v] in C)."""

    def __init__(self, X_BC: RigidTransform):
        super().__init__()
        self._X_BC = X_BC
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._V_WB = self.DeclareVectorInputPort("V_WB", 6)
        self.DeclareVectorOutputPort("V_WC_C", 6, self._calc)

    def _calc(self, context, output):
        X_WC, V_WC = camera_motion(self._X_WB.Eval(context), self._V_WB.Eval(context), self._X_BC)
        R_CW = X_WC.rotation().inverse()
        output.SetFromVector(np.concatenate([R_CW.multiply(V_WC[:3]), R_CW.multiply(V_WC[3:])]))


def axis_flow(X_WC: RigidTransform, V_WC: np.ndarray, X_WS: RigidTransform, V_WS: np.ndarray) -> np.ndarray:
    """[rate_x, rate_y] (rad/s): how fast the scene point on the optical axis of a camera C crosses its image,
    along C's x and y (the image moves at fx rate_x, fy rate_y px/s). The scene is the plane z = 0 of a frame S
    (the deck's top surface), moving with S. V_WC and V_WS are spatial velocities [w; v] in W of C's and S's
    origins (rad/s, m/s). The point p on the axis at depth Z, r_C = (0, 0, Z), moves in C at
    r_C' = R_CW ((v_p - v_C) - w_C x (p - p_C)), with v_p = v_S + w_S x (p - p_S). Zero when the axis does not
    meet the plane in front of the camera."""
    R_WC, p_WC = X_WC.rotation().matrix(), X_WC.translation()
    n_W, p_WS = X_WS.rotation().col(2), X_WS.translation()
    along = n_W @ R_WC[:, 2]
    depth = n_W @ (p_WS - p_WC) / along if abs(along) > 1e-9 else -1.0
    if depth <= 0:
        return np.zeros(2)
    p_W = p_WC + depth * R_WC[:, 2]
    v_p = V_WS[3:] + np.cross(V_WS[:3], p_W - p_WS)
    r_dot_C = R_WC.T @ (v_p - V_WC[3:] - np.cross(V_WC[:3], p_W - p_WC))
    return r_dot_C[:2] / depth


class AxisFlow(LeafSystem):
    """`axis_flow` (2, rad/s; `axis_flow`'s) of a camera C mounted at X_BC on a body B over the scene plane
    z = 0 of a moving frame S: what smears the image over an exposure (`NoisyCamera`'s input).

    Inputs: X_WB (RigidTransform), V_WB (6: [w; v] in W), X_WS (RigidTransform), V_WS (6: [w; v] in W)."""

    def __init__(self, X_BC: RigidTransform):
        super().__init__()
        self._X_BC = X_BC
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._V_WB = self.DeclareVectorInputPort("V_WB", 6)
        self._X_WS = self.DeclareAbstractInputPort("X_WS", AbstractValue.Make(RigidTransform()))
        self._V_WS = self.DeclareVectorInputPort("V_WS", 6)
        self.DeclareVectorOutputPort("axis_flow", 2, self._calc)

    def _calc(self, context, output):
        X_WC, V_WC = camera_motion(self._X_WB.Eval(context), self._V_WB.Eval(context), self._X_BC)
        output.SetFromVector(axis_flow(X_WC, V_WC, self._X_WS.Eval(context), self._V_WS.Eval(context)))


class RelativePose(LeafSystem):
    """X_CP = (X_WB X_BC)^-1 X_WP for a camera C mounted at X_BC on a body B.

    Inputs: X_WB (body pose), X_WP (target pose). Outputs: X_CP (RigidTransform) and
    X_CP_vector ([x, y, z, qw, qx, qy, qz], for logging)."""

    def __init__(self, X_BC: RigidTransform):
        super().__init__()
        self._X_BC = X_BC
        self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractInputPort("X_WP", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractOutputPort("X_CP", lambda: AbstractValue.Make(RigidTransform()),
                                       lambda c, o: o.set_value(self.X_CP(c)))
        self.DeclareVectorOutputPort("X_CP_vector", 7, lambda c, o: o.SetFromVector(pose_vector(self.X_CP(c))))

    def X_CP(self, context) -> RigidTransform:
        X_WC = self.get_input_port(0).Eval(context).multiply(self._X_BC)
        return X_WC.InvertAndCompose(self.get_input_port(1).Eval(context))
