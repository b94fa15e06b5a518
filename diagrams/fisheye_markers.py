"""Seed 003's fisheye against its analytic model: red spheres at known directions around the camera,
nothing else, and the distance from each rendered blob's centroid to cv2.fisheye.projectPoints of its
centre. Shared by tests/test_fisheye.py and benchmarks/fisheye.py.

    scene = MarkerScene(FisheyeConfig(), marker_points_C())
    errors_px = projection_errors(scene)
"""

import numpy as np
from pydrake.geometry import GeometryInstance, PerceptionProperties, RenderLabel, Rgba, SceneGraph, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import DiagramBuilder

from systems.sensors.fisheye import FisheyeConfig, add_fisheye_camera, in_field_of_view, project_points

BACKGROUND = np.array([217, 224, 230])  # the renderer's clear colour (0.85, 0.88, 0.9) in 8 bits
MARKER_DISTANCE_M = 2.0
MARKER_RADIUS_M = 0.04  # 1.1 deg: blobs of about 8-11 px across
# Marker directions in C: (angle from the optical axis, azimuth from +x_C towards +y_C) [deg]. They
# cover the axis, the seams (down/side at 30 deg on the side axes, side/side at 45 deg azimuths, the
# triple points at 39.2 deg) and the rim at 60-74 deg.
MARKER_DIRECTIONS_DEG = [(0, 0), (15, 200), (30, 0), (30, 90), (39.2, 45), (39.2, 225), (45, 300), (50, 160),
                         (55, 135), (60, 270), (63, 30), (65, 315), (68, 100), (70, 0), (72, 190), (74, 160),
                         (74, 225), (74, 45)]


def marker_points_C(directions_deg=MARKER_DIRECTIONS_DEG, distance_m=MARKER_DISTANCE_M) -> np.ndarray:
    """Marker centres (N, 3) in the camera frame C [m]."""
    theta, phi = np.radians(np.asarray(directions_deg, dtype=float)).T
    return distance_m * np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


class MarkerScene:
    """Red spheres at known points p_C around a fisheye on the world frame (C = the world's frame
    turned by config.X_BC), nothing else: the background is the renderer's clear colour."""

    def __init__(self, config: FisheyeConfig, points_C: np.ndarray, radius_m: float = MARKER_RADIUS_M):
        builder = DiagramBuilder()
        scene_graph = builder.AddSystem(SceneGraph())
        source = scene_graph.RegisterSource("markers")
        X_WC = config.X_BC
        for i, p_C in enumerate(points_C):
            instance = GeometryInstance(RigidTransform(X_WC.multiply(p_C)), Sphere(radius_m), f"marker_{i}")
            properties = PerceptionProperties()
            properties.AddProperty("phong", "diffuse", Rgba(1.0, 0.0, 0.0, 1.0))
            properties.AddProperty("label", "id", RenderLabel(i + 1))
            instance.set_perception_properties(properties)
            scene_graph.RegisterAnchoredGeometry(source, instance)
        self.rig = add_fisheye_camera(builder, scene_graph, scene_graph.world_frame_id(), config)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.config, self.points_C = config, points_C

    def fisheye_image(self) -> np.ndarray:
        return self.rig.color_image.Eval(self.rig.camera.GetMyContextFromRoot(self.context)).data.copy()

    def rectified_image(self) -> np.ndarray:
        return self.rig.rectified_image.Eval(self.rig.camera.GetMyContextFromRoot(self.context)).data.copy()

    def face_images(self) -> list[np.ndarray]:
        return [s.color_image_output_port().Eval(s.GetMyContextFromRoot(self.context)).data.copy()
                for s in self.rig.sensors]


def blob_centroids(image: np.ndarray, expected_px: np.ndarray, valid: np.ndarray | None = None,
                   window_px: int = 20) -> np.ndarray:
    """Centroids (N, 2) of the red blobs near the expected pixels, weighted by how far the green
    channel falls from the background's (partial pixels at the edges count in part), over the
    `valid` pixels (all by default); NaN if none."""
    weight = np.clip((BACKGROUND[1] - image[..., 1].astype(float)) / BACKGROUND[1], 0.0, 1.0)
    if valid is not None:
        weight[~valid] = 0.0
    centroids = []
    for u, v in expected_px:
        u0, v0 = round(u) - window_px, round(v) - window_px
        patch = weight[max(v0, 0):v0 + 2 * window_px + 1, max(u0, 0):u0 + 2 * window_px + 1]
        rows, cols = np.mgrid[max(v0, 0):max(v0, 0) + patch.shape[0], max(u0, 0):max(u0, 0) + patch.shape[1]]
        total = patch.sum()
        centroids.append([(patch * cols).sum() / total, (patch * rows).sum() / total] if total > 1 else [np.nan] * 2)
    return np.array(centroids)


def projection_errors(scene: MarkerScene) -> np.ndarray:
    """Distances [px] between the markers' blob centroids in the composed fisheye image and
    cv2.fisheye.projectPoints of their centres."""
    config = scene.config
    expected = project_points(scene.points_C, config)
    u, v = np.meshgrid(np.arange(config.width), np.arange(config.height))
    inside = in_field_of_view(np.column_stack([u.ravel(), v.ravel()]), config).reshape(u.shape)
    return np.linalg.norm(blob_centroids(scene.fisheye_image(), expected, inside) - expected, axis=1)
