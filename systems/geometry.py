"""Small helpers for registering visible geometry with SceneGraph, for pose conversions, and a ray's meeting with a
horizontal plane."""

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


def ray_to_plane(p_WC: np.ndarray, ray_W: np.ndarray, height_above_plane: float, z_plane: float,
                 min_ray_down: float = 0.5) -> np.ndarray | None:
    """Where a ray from a camera `height_above_plane` [m] above the horizontal plane z = z_plane meets it (W, m),
    the camera's x, y from p_WC: p_WC + s ray_W with s = height / -ray_W,z. ray_W (W) may have any length;
    `min_ray_down` is the least -ray_W,z (for a unit ray the cosine of its angle from straight down). None when the
    ray does not point down that much or the height is not positive."""
    down = -float(ray_W[2])
    if down < min_ray_down or not height_above_plane > 0:
        return None
    s = height_above_plane / down
    return np.array([p_WC[0] + s * ray_W[0], p_WC[1] + s * ray_W[1], z_plane])
