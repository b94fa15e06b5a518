"""The ground vehicle as a scene: the landing pad on its roof (`PlatformConfig`) and its visible
body, wheels and textured pad registered with SceneGraph (`GroundVehicleGeometry`). The pad shows
seed 002's ArUco markers or seed 001's RQRLP (`pattern`); with `carrier` ground it lies alone on the
ground (the vehicle, at rest, is not drawn).

Frames: the vehicle frame V is on the ground under the rear axle, x forward, z up; the pad frame P
has its origin at the centre of the pad's top surface, axes parallel to V's.
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, FramePoseVector, GeometryFrame, Mesh, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from models.apriltag import textured_quad_mesh
from systems.config import require, require_positive
from systems.geometry import register_visual
from systems.perception.markers import MarkerLayout, pad_texture
from systems.perception.rqrlp.pattern import RqrlpLayout, rqrlp_image, rqrlp_texture_name
from systems.vehicles.ground_vehicle import ground_pose

PATTERNS = ("markers", "rqrlp")
BODY_RGB = (0.75, 0.3, 0.15)  # the vehicle body's colour
CARRIERS = ("vehicle", "ground")
PATTERN_GAP_M = 0.001  # the pad's face under its pattern (P's plane), against z-fighting


@dataclass
class PlatformConfig:
    """The landing platform on the vehicle's roof (frames V and P: module docstring) and the
    vehicle's visible body (m)."""

    height_m: float = 1.6  # pad top above the ground, seed 002 Sec. 2.2
    pad_size_m: float = 1.0  # square pad, seed 003 Sec. 3.2.1 (1.0 x 1.0 m PVC pad)
    pad_thickness_m: float = 0.02
    pad_offset_m: float = 1.75  # pad centre ahead of the rear axle (half of seed 002's wheelbase)
    # Five ArUco markers (seed 002 Fig. 1c; seed 003's UGV carries an ArUco marker too), textured on
    # the pad; systems/perception/markers.py gives the default layout and why.
    markers: MarkerLayout = field(default_factory=MarkerLayout)
    pattern: str = "markers"  # what the pad shows: "markers" (the ArUco layout) or "rqrlp" (seed 001's pattern)
    rqrlp: RqrlpLayout = field(default_factory=RqrlpLayout)  # with pattern rqrlp, centred on the (white) pad
    carrier: str = "vehicle"  # "vehicle": on the roof; "ground": the pad alone, its top height_m above the ground
    # The visible body (not in the papers: a car the size of seed 002's 3.5 m wheelbase).
    body_length_m: float = 4.6
    body_width_m: float = 1.8
    rear_overhang_m: float = 0.55
    ground_clearance_m: float = 0.3
    wheel_radius_m: float = 0.33
    wheel_width_m: float = 0.22

    def validate(self, prefix: str = "platform") -> None:
        for name in ("height_m", "pad_size_m", "pad_thickness_m", "body_length_m", "body_width_m",
                     "ground_clearance_m", "wheel_radius_m", "wheel_width_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.pattern in PATTERNS, f"{prefix}.pattern '{self.pattern}' is not one of: {', '.join(PATTERNS)}")
        require(self.carrier in CARRIERS, f"{prefix}.carrier '{self.carrier}' is not one of: {', '.join(CARRIERS)}")
        if self.pattern == "rqrlp":
            self.rqrlp.validate(f"{prefix}.rqrlp")
            require(self.rqrlp.size_m <= self.pad_size_m,
                    f"{prefix}.rqrlp.size_m ({self.rqrlp.size_m:g}) is larger than the pad, {prefix}.pad_size_m "
                    f"({self.pad_size_m:g})")
        else:
            self.markers.validate(f"{prefix}.markers", self.pad_size_m)
        if self.carrier == "ground":
            require(self.height_m >= self.pad_thickness_m,
                    f"{prefix}.height_m ({self.height_m}) must be at least {prefix}.pad_thickness_m on the ground")
            return
        require(self.rear_overhang_m >= 0, f"{prefix}.rear_overhang_m must not be negative")
        require(self.height_m - self.pad_thickness_m > self.ground_clearance_m,
                f"{prefix}.height_m ({self.height_m}) must be above {prefix}.ground_clearance_m + pad_thickness_m")
        require(self.pad_size_m <= self.body_width_m,
                f"{prefix}.pad_size_m ({self.pad_size_m}) is wider than {prefix}.body_width_m ({self.body_width_m})")
        front, rear = self.body_length_m - self.rear_overhang_m, -self.rear_overhang_m
        require(rear <= self.pad_offset_m - self.pad_size_m / 2 and self.pad_offset_m + self.pad_size_m / 2 <= front,
                f"{prefix}.pad_offset_m ({self.pad_offset_m}) puts the pad off the roof "
                f"(the body spans {rear:g} to {front:g} m along the vehicle)")

    @property
    def pattern_size_m(self) -> float:
        """The side of the textured square on the pad: the whole pad, or the RQRLP on it."""
        return self.rqrlp.size_m if self.pattern == "rqrlp" else self.pad_size_m

    @property
    def p_VP(self) -> np.ndarray:
        """Pad centre (top surface) in the vehicle frame V [m]."""
        return np.array([self.pad_offset_m, 0.0, self.height_m])

    def X_WP(self, vehicle_state) -> RigidTransform:
        """The pad frame P in W for the vehicle's `state` [x, y, heading, steering]."""
        return ground_pose(vehicle_state).multiply(RigidTransform(self.p_VP))


def pad_texture_mesh(platform: PlatformConfig):
    """The unit textured quad (models/generated) carrying the pad's pattern (the markers'
    `pad_texture` or the RQRLP), generated on first use and named by its content."""
    if platform.pattern == "rqrlp":
        return textured_quad_mesh(rqrlp_texture_name(platform.rqrlp), rqrlp_image(platform.rqrlp))
    image = pad_texture(platform.markers, platform.pad_size_m)
    return textured_quad_mesh("gv_pad", image)


class GroundVehicleGeometry(LeafSystem):
    """Registers the vehicle (body, four wheels, the pad with its pattern; the pad alone with carrier
    ground) with SceneGraph and poses it from the input `vehicle_state` (4): the body frame is V,
    the front wheels steer."""

    def __init__(self, wheelbase_m: float, platform: PlatformConfig, scene_graph: SceneGraph):
        super().__init__()
        self.source_id = scene_graph.RegisterSource("ground_vehicle")
        sid, p = self.source_id, platform
        self.body_frame_id = scene_graph.RegisterFrame(sid, GeometryFrame("gv_body"))
        body = self.body_frame_id
        # The pattern lies in P's plane (what the estimators measure is where the truth puts it); the pad's
        # white face lies PATTERN_GAP_M under it, so the two never share a plane.
        pad = p.pad_thickness_m - PATTERN_GAP_M
        register_visual(scene_graph, sid, body,
                        RigidTransform([p.pad_offset_m, 0.0, p.height_m - PATTERN_GAP_M - pad / 2]),
                        Box(p.pad_size_m, p.pad_size_m, pad), "gv_pad", (0.95, 0.95, 0.95, 1.0))
        register_visual(scene_graph, sid, body, RigidTransform([p.pad_offset_m, 0.0, p.height_m]),
                        Mesh(str(pad_texture_mesh(p)), p.pattern_size_m), "gv_pad_pattern", rgba=None)
        self._front = []  # the steered wheels' frames and their positions in V
        if p.carrier == "vehicle":
            self._register_vehicle(scene_graph, wheelbase_m, p)
        self._state = self.DeclareVectorInputPort("vehicle_state", 4)
        self.DeclareAbstractOutputPort("geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc)

    def _register_vehicle(self, scene_graph: SceneGraph, wheelbase_m: float, p: PlatformConfig) -> None:
        """The body and the wheels."""
        sid, body = self.source_id, self.body_frame_id
        top = p.height_m - p.pad_thickness_m
        register_visual(scene_graph, sid, body, RigidTransform(
            [p.body_length_m / 2 - p.rear_overhang_m, 0.0, (p.ground_clearance_m + top) / 2]),
            Box(p.body_length_m, p.body_width_m, top - p.ground_clearance_m), "gv_body", (*BODY_RGB, 1.0))
        wheel = Cylinder(p.wheel_radius_m, p.wheel_width_m)
        R_wheel = RotationMatrix.MakeXRotation(np.pi / 2)  # cylinder axis (z) along the axle (y)
        y = p.body_width_m / 2  # wheels half outside the body (no coplanar faces)
        dark = (0.1, 0.1, 0.1, 1.0)
        for name, side in (("rl", 1), ("rr", -1)):
            register_visual(scene_graph, sid, body, RigidTransform(R_wheel, [0.0, side * y, p.wheel_radius_m]), wheel,
                            f"gv_wheel_{name}", dark)
        for name, side in (("fl", 1), ("fr", -1)):
            frame = scene_graph.RegisterFrame(sid, GeometryFrame(f"gv_wheel_{name}"))
            register_visual(scene_graph, sid, frame, RigidTransform(R_wheel), wheel, f"gv_wheel_{name}", dark)
            self._front.append((frame, np.array([wheelbase_m, side * y, p.wheel_radius_m])))

    def _calc(self, context, output):
        state = self._state.Eval(context)
        X_WV = ground_pose(state)
        poses = output.get_mutable_value()
        poses.clear()
        poses.set_value(self.body_frame_id, X_WV)
        for frame, p_VW in self._front:
            poses.set_value(frame, X_WV.multiply(RigidTransform(RotationMatrix.MakeZRotation(state[3]), p_VW)))
