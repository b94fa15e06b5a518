"""Which pad markers the gv scene's camera detects from a pose over the pad: the scene rendered by
Drake (the gv diagram's camera, its pixel noise), OpenCV's ArUco and solvePnP as the marker stream
runs them (systems/perception/marker_detector.py). For a layout's coverage against height, tilt and
offset (benchmarks/marker_visibility.py).

    rig = VisibilityRig(config)                  # a gv config with estimation.source detector
    ids = rig.detected(camera_height_m=0.3, offset_xy_m=(0.1, 0.0), tilt_deg=5.0)

Frames: W (z up); the pad frame P at the pad's centre (the vehicle at its start, at rest, the pad
level); the camera C at `estimation.camera.X_BC` on the body B, whose heading is the pad's (x_B along
x_P) before the tilt, a roll about x_B [deg]. The camera height is the camera's height above the
pad's top [m]; the offset is the body's horizontal position from the pad's centre, in P [m].
"""

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_config import GvLandingConfig
from systems.config import require
from systems.perception.marker_detector import detect_marker_poses
from systems.perception.seam import P_BP_W
from systems.vehicles.quadrotor import quadrotor_state


class VisibilityRig:
    """The gv scene of `config` held at t = 0, to render the camera from chosen poses."""

    def __init__(self, config: GvLandingConfig):
        require(config.estimation.source == "detector", "the visibility rig renders the marker camera: "
                                                         "set estimation.source to detector")
        self.config = config
        self._diagram, self._handles = build_gv_landing(config)
        self._context = self._diagram.CreateDefaultContext()
        self._handles.initialize(self._context)
        port = self._handles.measurements.color_image
        self._image_port, self._image_context = port, port.get_system().GetMyContextFromRoot(self._context)
        truth = self._handles.truth
        relative = truth.get_output_port().Eval(truth.GetMyContextFromRoot(self._context))
        quad = self._handles.quadrotor
        p_WB = quad.GetOutputPort("state").Eval(quad.GetMyContextFromRoot(self._context))[0:3]
        self.p_WP = p_WB + relative[P_BP_W]  # the pad's centre, top surface
        vehicle = self._handles.vehicle
        self.yaw_WP = float(vehicle.GetOutputPort("state").Eval(vehicle.GetMyContextFromRoot(self._context))[2])
        self._camera = config.estimation.camera

    def detected(self, camera_height_m: float, offset_xy_m=(0.0, 0.0), tilt_deg: float = 0.0) -> set[int]:
        """The ids of the markers detected from that pose (module docstring)."""
        R_WP = RotationMatrix.MakeZRotation(self.yaw_WP)
        R_WB = R_WP.multiply(RotationMatrix(RollPitchYaw(np.radians(tilt_deg), 0.0, 0.0)))
        p_BC_W = R_WB.multiply(self._camera.X_BC.translation())
        p_WB = self.p_WP + R_WP.multiply([*offset_xy_m, camera_height_m]) - [0.0, 0.0, p_BC_W[2]]
        rotors = np.full(4, self.config.quadrotor.hover_rotor_speed())
        self._handles.quadrotor.set_state(self._context, quadrotor_state(p_WB, R_WB, rotor_speeds=rotors))
        image = self._image_port.Eval(self._image_context).data
        return {m.marker_id for m in detect_marker_poses(image, self._camera.K, self.config.platform.markers)}
