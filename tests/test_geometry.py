"""The small geometry helpers (systems/geometry.py): the roles register_visual gives a shape, wrap_angle's
half-open range, and where a ray meets a horizontal plane."""

import numpy as np
import pytest
from pydrake.geometry import Box, SceneGraph
from pydrake.math import RigidTransform

from systems.geometry import ray_to_plane, register_visual, wrap_angle


@pytest.mark.parametrize("kwargs, roles", [
    ({}, {"illustration": True, "perception": True, "proximity": False}),  # seen, not touched
    ({"illustrated": False}, {"illustration": False, "perception": True, "proximity": False}),
    ({"perceived": False}, {"illustration": True, "perception": False, "proximity": False}),
    ({"collidable": True}, {"illustration": True, "perception": True, "proximity": True}),
], ids=["default", "not-illustrated", "not-perceived", "collidable"])
def test_register_visual_gives_the_roles_asked_for(kwargs, roles):
    scene_graph = SceneGraph()
    source = scene_graph.RegisterSource("test")
    geometry = register_visual(scene_graph, source, scene_graph.world_frame_id(), RigidTransform(), Box(1, 1, 1),
                               "box", **kwargs)
    inspector = scene_graph.model_inspector()
    assert {"illustration": inspector.GetIllustrationProperties(geometry) is not None,
            "perception": inspector.GetPerceptionProperties(geometry) is not None,
            "proximity": inspector.GetProximityProperties(geometry) is not None} == roles


def test_wrap_angle_wraps_to_the_half_open_range_from_minus_pi():
    assert wrap_angle(np.pi) == -np.pi and wrap_angle(-np.pi) == -np.pi  # [-pi, pi): pi itself is -pi
    np.testing.assert_allclose(wrap_angle(np.array([2 * np.pi + 0.5, -2 * np.pi - 0.5, 3.0])), [0.5, -0.5, 3.0],
                               rtol=0, atol=1e-12)


def test_a_ray_pointing_down_exactly_the_least_allowed_meets_the_plane():
    """A ray 45 degrees from straight down (-ray_z = 0.5 = min_ray_down, the ray of length 1/sqrt 2) from 10 m above
    the plane meets it 10 m further along x; a hair less steep is refused."""
    np.testing.assert_array_equal(ray_to_plane([1.0, 2.0, 10.0], [0.5, 0.0, -0.5], 10.0, 0.0), [11.0, 2.0, 0.0])
    assert ray_to_plane([1.0, 2.0, 10.0], [0.5, 0.0, -0.4999], 10.0, 0.0) is None
