"""Rays cast on SceneGraph's geometry (`systems.sensors.ray_cast.cast_rays`) against their analytic
intersections with a tilted box and a cylinder, rays along a face, from inside, and past everything."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, Cylinder, FramePoseVector, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder

from systems.geometry import register_collision
from systems.sensors.ray_cast import cast_rays


def query_object(shapes):
    """SceneGraph's QueryObject for `shapes`, (X_WG, shape) pairs anchored in the world; and their ids."""
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    source = scene_graph.RegisterSource("test")
    world = scene_graph.world_frame_id()
    ids = [register_collision(scene_graph, source, world, X_WG, shape, f"g{i}")
           for i, (X_WG, shape) in enumerate(shapes)]
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    scene_graph.get_source_pose_port(source).FixValue(scene_graph.GetMyContextFromRoot(context),
                                                      AbstractValue.Make(FramePoseVector()))
    return scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context)), ids


def unit(v):
    return np.asarray(v, float) / np.linalg.norm(v)


def test_rays_meet_a_tilted_box_face_where_the_plane_is():
    # A box turned 20 deg about x and 10 about y, its top face through q with normal n.
    R = RotationMatrix.MakeXRotation(np.radians(20.0)).multiply(RotationMatrix.MakeYRotation(np.radians(10.0)))
    n, q = R.matrix()[:, 2], np.array([0.1, -0.2, 0.3])
    qo, _ = query_object([(RigidTransform(R, q - n * 0.25), Box(4.0, 4.0, 0.5))])
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.5, 0.5, (30, 2)), rng.uniform(2.0, 3.0, 30)])
    d = np.array([unit([*rng.uniform(-0.3, 0.3, 2), -1.0]) for _ in range(30)])
    expected = ((q - p) @ n) / (d @ n)
    np.testing.assert_allclose(cast_rays(qo, p, d, 20.0), expected, rtol=0, atol=1e-6)


def test_rays_meet_a_cylinder_where_the_quadratic_says():
    # A cylinder of radius 0.3 along the world's y axis at height 1; rays from above at angles in x z.
    radius, centre = 0.3, np.array([0.0, 0.0, 1.0])
    qo, _ = query_object([(RigidTransform(RotationMatrix.MakeXRotation(np.pi / 2), centre), Cylinder(radius, 5.0))])
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(-0.25, 0.25, 30), rng.uniform(-1.0, 1.0, 30), np.full(30, 3.0)])
    d = np.array([unit([rng.uniform(-0.05, 0.05), 0.0, -1.0]) for _ in range(30)])
    # |(p + s d - centre) in x z| = radius: a s^2 + b s + c = 0, the nearer root.
    w, dz = (p - centre)[:, [0, 2]], d[:, [0, 2]]
    a, b, c = np.sum(dz**2, 1), 2 * np.sum(w * dz, 1), np.sum(w**2, 1) - radius**2
    expected = (-b - np.sqrt(b**2 - 4 * a * c)) / (2 * a)
    np.testing.assert_allclose(cast_rays(qo, p, d, 20.0), expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("floor_first", [False, True])
def test_a_ray_along_a_face_passes_it_and_ignored_or_far_geometry_is_not_seen(floor_first):
    """A deck (top at z = 1, edge at x = 0) over a floor (top at z = 0); rays straight down. Registered either
    way round: a ray stops on the nearer surface it meets, whichever geometry the query lists first."""
    deck = (RigidTransform([-1.0, 0.0, 0.95]), Box(2.0, 2.0, 0.1))
    floor = (RigidTransform([0.0, 0.0, -0.05]), Box(5.0, 5.0, 0.1))
    qo, ids = query_object([floor, deck] if floor_first else [deck, floor])
    deck_id = ids[1] if floor_first else ids[0]
    down = np.tile([0.0, 0.0, -1.0], (5, 1))
    p = np.array([[-1e-3, 0, 2], [1e-6, 0, 2], [1e-3, 0, 2], [-0.5, 0, 0.97], [-0.5, 0, 3]])
    # A micrometre (10 tolerances) beside the edge the ray runs along the deck's side and on to the floor.
    np.testing.assert_allclose(cast_rays(qo, p, down, 20.0), [1.0, 2.0, 2.0, 0.0, 2.0], rtol=0, atol=1e-6)
    without_deck = cast_rays(qo, p, down, 20.0, frozenset([deck_id]))
    np.testing.assert_allclose(without_deck, [2.0, 2.0, 2.0, 0.97, 3.0], rtol=0, atol=1e-6)
    assert np.all(cast_rays(qo, p[[2, 4]], down[:2], 1.5) == np.inf)  # nothing within 1.5 m of either
    assert np.all(cast_rays(qo, p[:3], -down[:3], 20.0) == np.inf)  # looking up


def test_a_surface_at_exactly_the_range_is_hit():
    """A surface max_range_m away is within the range: hit at that distance; a hair nearer range sees nothing."""
    qo, _ = query_object([(RigidTransform([0.0, 0.0, -0.5]), Box(5.0, 5.0, 1.0))])  # top face at z = 0
    p, down = np.array([[0.0, 0.0, 2.0], [0.3, -0.2, 2.0]]), np.tile([0.0, 0.0, -1.0], (2, 1))
    np.testing.assert_array_equal(cast_rays(qo, p, down, 2.0), [2.0, 2.0])
    assert np.all(cast_rays(qo, p, down, np.nextafter(2.0, 0.0)) == np.inf)
