"""Ground truth: the pose of a target frame P (e.g. the deck) in the camera frame C."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem


def pose_vector(X: RigidTransform) -> np.ndarray:
    """[x, y, z (m), qw, qx, qy, qz] of a pose (Drake's w-first quaternion)."""
    return np.concatenate([X.translation(), X.rotation().ToQuaternion().wxyz()])


class CameraVelocity(LeafSystem):
    """The velocity of a camera C mounted at X_BC on a body B, in C [m/s]: v_C = R_CW (v_WB + w_WB x p_BC_W).

    Inputs: X_WB (RigidTransform) and V_WB (6: [w; v] in W, rad/s and m/s). Output: v_C (3)."""

    def __init__(self, X_BC: RigidTransform):
        super().__init__()
        self._X_BC = X_BC
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._V_WB = self.DeclareVectorInputPort("V_WB", 6)
        self.DeclareVectorOutputPort("v_C", 3, self._calc)
        self.DeclareVectorOutputPort("w_C", 3, lambda c, o: o.SetFromVector(
            self._R_WC(c).inverse().multiply(self._V_WB.Eval(c)[:3])))

    def _R_WC(self, context):
        return self._X_WB.Eval(context).rotation().multiply(self._X_BC.rotation())

    def _calc(self, context, output):
        X_WB, V_WB = self._X_WB.Eval(context), self._V_WB.Eval(context)
        R_WB = X_WB.rotation()
        p_BC_W = R_WB.multiply(self._X_BC.translation())
        v_WC = V_WB[3:] + np.cross(V_WB[:3], p_BC_W)
        output.SetFromVector(R_WB.multiply(self._X_BC.rotation()).inverse().multiply(v_WC))


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
