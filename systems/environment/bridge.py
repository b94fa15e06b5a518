"""A bridge over the vehicle's path: an occluder that hides the vehicle from above while it drives under it
(seed 003 Sec. 4.4's tracking through occlusion; ours: its shape). Frames: W z up; the bridge frame D on the
ground at the path's point at arc length `at_m`, x along the path there.

The deck is `length_m` along the path, `width_m` across it, `thickness_m` thick, its underside `clearance_m`
over the ground, on two piers beside the road (`pier_m` thick, at the deck's ends across the path). Seen from
straight above, a pad of side a under a deck of length L is wholly hidden for (L - a) / v and partly for
(L + a) / v at the vehicle's speed v: the default 1.5 m deck hides seed 003's 1 m pad for 1 s at 0.5 m/s.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Box, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix

from systems.config import require, require_non_negative, require_positive
from systems.geometry import register_visual
from systems.vehicles.paths import Path


@dataclass
class BridgeConfig:
    """The scenario's `bridge` section (metres); none unless `enabled`."""

    enabled: bool = False
    at_m: float = 10.0  # arc length of the vehicle's path under the deck's centre
    length_m: float = 1.5
    width_m: float = 6.0
    thickness_m: float = 0.3
    clearance_m: float = 1.2  # over the ground: the vehicle must pass under it
    pier_m: float = 0.4

    def validate(self, prefix: str = "bridge") -> None:
        """Sizes positive, `at_m` on the path (not before its start), and room between the piers (the
        vehicle's width and the path's end are the scenario's checks)."""
        for name in ("length_m", "width_m", "thickness_m", "clearance_m", "pier_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_non_negative(self.at_m, f"{prefix}.at_m")
        require(self.width_m > 2 * self.pier_m,
                f"{prefix}.width_m ({self.width_m:g} m) must exceed twice {prefix}.pier_m ({self.pier_m:g} m): "
                f"the piers stand within the deck's width, one each side of the path")

    @property
    def gap_m(self) -> float:
        """The width between the piers' inner faces, centred on the path [m]."""
        return self.width_m - 2 * self.pier_m


def bridge_pose(path: Path, config: BridgeConfig) -> RigidTransform:
    """X_WD: on the ground at the path's point at `at_m`, x along the path."""
    return RigidTransform(RotationMatrix.MakeZRotation(path.heading(config.at_m)), [*path.position(config.at_m), 0.0])


def register_bridge(scene_graph: SceneGraph, path: Path, config: BridgeConfig) -> None:
    """Registers the deck and its piers, fixed in W, seen by Meshcat and the cameras."""
    source_id = scene_graph.RegisterSource("bridge")
    X_WD = bridge_pose(path, config)
    c, grey = config, (0.55, 0.55, 0.58, 1.0)
    register_visual(scene_graph, source_id, scene_graph.world_frame_id(),
                    X_WD.multiply(RigidTransform([0.0, 0.0, c.clearance_m + c.thickness_m / 2])),
                    Box(c.length_m, c.width_m, c.thickness_m), "bridge_deck", grey)
    for side in (1.0, -1.0):
        y = side * (c.width_m - c.pier_m) / 2
        register_visual(scene_graph, source_id, scene_graph.world_frame_id(),
                        X_WD.multiply(RigidTransform([0.0, y, c.clearance_m / 2])),
                        Box(c.length_m, c.pier_m, c.clearance_m), f"bridge_pier_{int(np.sign(side))}", grey)
