"""Issue 12: the fisheye camera's per-frame cost (the five face renders against the remap that composes
them) and its projection error (rendered marker centroids against cv2.fisheye.projectPoints).

    .venv/bin/python benchmarks/fisheye.py [--frames 20] [--side-axis-deg 60]

Scene: diagrams/fisheye_markers.py's markers (18 red spheres 2 m from the camera, 0-74 deg off-axis, on the
renderer's clear colour). Composition variants timed on the same face images: one cv2.remap per face
into its region with BORDER_TRANSPARENT (fixed-point or float maps), and one remap from a stacked atlas
of the faces, the copy into the atlas included (what FisheyeCamera does).
"""

import argparse
import time

import cv2
import numpy as np

from diagrams.fisheye_markers import MARKER_DIRECTIONS_DEG, MarkerScene, marker_points_C, projection_errors
from systems.config import ConfigError
from systems.sensors.fisheye import BLACK, FisheyeConfig, fisheye_layout, rectify, rectify_maps


def best_ms(function, repeats: int) -> float:
    """The best of `repeats` timings of function() [ms] (the machine's other load only adds)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e3 * min(times)


class PerFace:
    """The alternative: one cv2.remap per face into its region of the output, pixels of other faces
    skipped by BORDER_TRANSPARENT; fixed-point (1/32 px) or float maps."""

    def __init__(self, layout, fixed: bool):
        self.tables = []
        for index in range(len(layout.faces)):
            rows, cols = np.nonzero(layout.face_of_pixel == index)
            region = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
            mine = layout.face_of_pixel[region] == index
            uv = np.where(mine[..., None], layout.face_uv[region], -1000.0).astype(np.float32)
            maps = cv2.convertMaps(uv[..., 0], uv[..., 1], cv2.CV_16SC2) if fixed else (uv[..., 0].copy(),
                                                                                         uv[..., 1].copy())
            self.tables.append((region, maps))

    def compose(self, faces, out):
        out[:] = BLACK
        for image, (region, maps) in zip(faces, self.tables):
            cv2.remap(image, *maps, cv2.INTER_LINEAR, dst=out[region], borderMode=cv2.BORDER_TRANSPARENT)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--side-axis-deg", type=float, default=FisheyeConfig.side_axis_deg,
                        help="the side faces' tilt (90: a cube map's faces, cropped)")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error(f"--frames must be at least 1, got {args.frames}")
    config = FisheyeConfig(side_axis_deg=args.side_axis_deg)
    try:
        config.validate()
    except ConfigError as e:
        parser.exit(2, f"{e}\n")
    start = time.perf_counter()
    layout = fisheye_layout(config)
    _ = layout.atlas_maps  # computed once, cached
    setup_ms = 1e3 * (time.perf_counter() - start)
    scene = MarkerScene(config, marker_points_C())
    rendered = sum(face.width * face.height for face in layout.faces)
    print(f"fisheye {config.width}x{config.height}, {config.fov_deg:g} deg, f {config.f:g} px, "
          f"k1 {config.k1:g}, k2 {config.k2:g}; faces {', '.join(f'{f.name} {f.width}x{f.height}' for f in layout.faces)}"
          f" = {rendered / 1e3:.0f} kpx (five full {config.face_px}-px cube faces: {5 * config.face_px**2 / 1e3:.0f} kpx)")
    print(f"tables: {setup_ms:.0f} ms once")

    render_ms = []
    for k in range(args.frames):
        scene.context.SetTime(0.1 * (k + 1))  # a new time: the faces render again
        start = time.perf_counter()
        faces = scene.face_images()
        render_ms.append(1e3 * (time.perf_counter() - start))
    faces = [np.ascontiguousarray(face) for face in faces]
    out = np.empty((config.height, config.width, 4), dtype=np.uint8)
    reference = layout.compose(faces).copy()
    per_face, per_face_float = PerFace(layout, fixed=True), PerFace(layout, fixed=False)
    per_face.compose(faces, out)  # the same image, but where a 1/32 px step rounds the other way at an edge
    assert np.mean(np.abs(out.astype(int) - reference).max(axis=-1) > 1) < 1e-3, "the variants differ"
    rect_maps = rectify_maps(config)
    repeats = max(args.frames, 20)
    print(f"\nper frame (ms): renders the median of {args.frames} frames, remaps the best of {repeats}")
    print(f"  render 5 faces (RgbdSensor colour, VTK)  {np.median(render_ms):7.2f}")
    print(f"  compose: atlas copy + one remap          {best_ms(lambda: layout.compose(faces, out), repeats):7.2f}"
          "   <- FisheyeCamera")
    print(f"  compose: remap per face, fixed-point     {best_ms(lambda: per_face.compose(faces, out), repeats):7.2f}")
    print(f"  compose: remap per face, float maps      {best_ms(lambda: per_face_float.compose(faces, out), repeats):7.2f}")
    print(f"  rectified view (one remap)               {best_ms(lambda: rectify(reference, rect_maps), repeats):7.2f}")

    error = projection_errors(scene)
    print(f"\nprojection error, {len(error)} markers: mean {error.mean():.3f} px, max {error.max():.3f} px")
    for (theta, _), e in sorted(zip(MARKER_DIRECTIONS_DEG, error)):
        print(f"  {theta:5.1f} deg off-axis: {e:.3f} px")


if __name__ == "__main__":
    main()
