"""The quadrotor airframe as rendered geometry, and a hover pose source.

The body frame B is at the airframe's centre, x forward, y left, z up (Drake's convention).
The seam for flight dynamics: anything that outputs the body kinematics ports
  X_WB (RigidTransform), V_WB ([w_WB; v_WB] in W, rad/s and m/s), A_WB ([alpha_WB; a_WB] in W)
can drive `AirframeGeometry` and the IMU in place of `PrescribedPose` (seed 000 Fig. 22 assumes
a stable hovering drone over the moving deck).
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, FramePoseVector, GeometryFrame, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require_positive
from systems.geometry import register_visual


@dataclass
class AirframeConfig:
    """Visual dimensions of the quadrotor (m): rotors sit at 45 degrees, `rotor_arm_m` from the
    camera axis, so the ToF sensors of seed 000 (Fig. 20) hang under the propellers. This is the
    airframe the camera and Meshcat see; the flight dynamics' mixer has its own arms
    (`QuadrotorParams`, seed 002's Table 1)."""

    body_size_m: float = 0.12
    body_height_m: float = 0.05
    rotor_arm_m: float = 0.135
    propeller_radius_m: float = 0.065

    def validate(self, prefix: str = "uav") -> None:
        for name in ("body_size_m", "body_height_m", "rotor_arm_m", "propeller_radius_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")


class PrescribedPose(LeafSystem):
    """A body moving at constant velocity v_WB (m/s, world frame) from X_WB0 at t = 0, without
    rotating: outputs X_WB, V_WB = [0; v_WB] and A_WB = 0. v_WB = 0 is a hover."""

    def __init__(self, X_WB0: RigidTransform, v_WB=(0.0, 0.0, 0.0)):
        super().__init__()
        self._X_WB0, self._v_WB = X_WB0, np.asarray(v_WB, dtype=float)
        V_WB, A_WB = np.concatenate([np.zeros(3), self._v_WB]), np.zeros(6)
        self.DeclareAbstractOutputPort("X_WB", lambda: AbstractValue.Make(RigidTransform()),
                                       lambda context, output: output.set_value(self.X_WB(context.get_time())))
        self.DeclareVectorOutputPort("V_WB", 6, lambda context, output: output.SetFromVector(V_WB))
        self.DeclareVectorOutputPort("A_WB", 6, lambda context, output: output.SetFromVector(A_WB))

    def X_WB(self, t: float) -> RigidTransform:
        return RigidTransform(self._X_WB0.rotation(), self._X_WB0.translation() + self._v_WB * t)


class AirframeGeometry(LeafSystem):
    """Registers the airframe with SceneGraph and poses it from the X_WB input.

    Sensors attach to `body_frame_id` (cameras and ToF sensors move with the body)."""

    def __init__(self, config: AirframeConfig, scene_graph: SceneGraph):
        super().__init__()
        config.validate()
        self.source_id = scene_graph.RegisterSource("uav_airframe")
        self.body_frame_id = scene_graph.RegisterFrame(self.source_id, GeometryFrame("uav_body"))
        dark, red, prop = (0.15, 0.15, 0.17, 1.0), (0.8, 0.2, 0.15, 1.0), (0.2, 0.2, 0.22, 0.6)
        frame = self.body_frame_id
        register_visual(scene_graph, self.source_id, frame, RigidTransform(),
                        Box(config.body_size_m, config.body_size_m, config.body_height_m), "uav_body", dark)
        top = config.body_height_m / 2
        for i, angle in enumerate(np.deg2rad([45.0, 135.0, 225.0, 315.0])):
            direction = np.array([np.cos(angle), np.sin(angle), 0.0])
            arm_pose = RigidTransform(RotationMatrix.MakeZRotation(angle), direction * config.rotor_arm_m / 2)
            register_visual(scene_graph, self.source_id, frame, arm_pose,
                            Box(config.rotor_arm_m, 0.015, 0.012), f"uav_arm{i}", dark)
            register_visual(scene_graph, self.source_id, frame,
                            RigidTransform(direction * config.rotor_arm_m + [0, 0, top]),
                            Cylinder(config.propeller_radius_m, 0.004), f"uav_propeller{i}",
                            red if i in (0, 3) else prop)  # red: the two front rotors (+x_B)
        self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()),
                                       self._calc_geometry_pose)

    def _calc_geometry_pose(self, context, output):
        poses = output.get_mutable_value()
        poses.clear()
        poses.set_value(self.body_frame_id, self.get_input_port().Eval(context))
