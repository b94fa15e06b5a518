"""Small helpers for registering visible geometry with SceneGraph and for pose conversions."""

from pathlib import Path

import numpy as np
from pydrake.geometry import (
    GeometryInstance,
    IllustrationProperties,
    PerceptionProperties,
    ProximityProperties,
    RenderLabel,
    Rgba,
    SceneGraph,
    Shape,
)
from pydrake.math import RigidTransform, RotationMatrix


def register_visual(
    scene_graph: SceneGraph,
    source_id,
    frame_id,
    X_FG: RigidTransform,
    shape: Shape,
    name: str,
    rgba=(0.7, 0.7, 0.7, 1.0),
    diffuse_map: Path | None = None,
    collidable: bool = False,
    illustrated: bool = True,
    perceived: bool = True,
):
    """Registers `shape` at pose X_FG in frame F, seen by Meshcat (illustration) unless not
    `illustrated`, by cameras (perception) unless not `perceived`, and by contact queries when
    `collidable`. `rgba` None keeps a mesh's own materials. Returns its GeometryId."""
    geometry_id = scene_graph.RegisterGeometry(source_id, frame_id, GeometryInstance(X_FG, shape, name))
    illustration, perception = IllustrationProperties(), PerceptionProperties()
    if rgba is not None:
        illustration.AddProperty("phong", "diffuse", Rgba(*rgba))
        perception.AddProperty("phong", "diffuse", Rgba(*rgba))
    if illustrated:
        scene_graph.AssignRole(source_id, geometry_id, illustration)
    if diffuse_map is not None:
        perception.AddProperty("phong", "diffuse_map", str(diffuse_map))
    perception.AddProperty("label", "id", RenderLabel(int(geometry_id.get_value() % RenderLabel.kMaxUnreserved)))
    if perceived:
        scene_graph.AssignRole(source_id, geometry_id, perception)
    if collidable:
        scene_graph.AssignRole(source_id, geometry_id, ProximityProperties())
    return geometry_id


def register_collision(scene_graph: SceneGraph, source_id, frame_id, X_FG: RigidTransform, shape: Shape, name: str):
    """Registers `shape` at pose X_FG in frame F for contact and distance queries only (unseen): a simple
    stand-in for a visual mesh that those queries cannot take. Returns its GeometryId."""
    geometry_id = scene_graph.RegisterGeometry(source_id, frame_id, GeometryInstance(X_FG, shape, name))
    scene_graph.AssignRole(source_id, geometry_id, ProximityProperties())
    return geometry_id


def wrap_angle(angle):
    """An angle (rad; a number or an array) wrapped to [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def frame_between(p_A: np.ndarray, p_B: np.ndarray) -> RigidTransform:
    """The pose of a frame at point A whose +z axis points towards point B (both in the same frame)."""
    return RigidTransform(RotationMatrix.MakeFromOneVector(np.asarray(p_B) - np.asarray(p_A), 2), p_A)
