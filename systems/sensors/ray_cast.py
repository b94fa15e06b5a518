"""Rays cast on SceneGraph's geometry through its signed distance (Drake has no ray query).

Along a ray p + s d (world frame W, d a unit vector, s in m) each geometry's signed distance phi_G(s)
(`QueryObject.ComputeSignedDistanceToPoint`) is a convex function of s, since Drake's distance queries
take every shape as convex (a mesh as its convex hull). A convex function lies above its tangents, so
with the slope phi_G' = grad_W . d from the query:
  - phi_G' >= 0: the ray moves away from G or along it, and never meets it;
  - phi_G' < 0: it cannot meet G before s + phi_G / -phi_G' (a Newton step, never past the surface and at
    least phi_G, the sphere-tracing step).
The ray advances by the least such step over the geometries until one is within TOLERANCE_M: on a plane
one step lands on it, on a curved surface Newton's steps close in quadratically, and a ray that runs along
a face (where sphere tracing crawls) leaves it behind at once.
"""

import numpy as np

TOLERANCE_M = 1e-7  # a ray has hit a surface once it is this close to one
MAX_STEPS = 50  # a ray still not settled after this many is taken as seeing nothing


def cast_rays(query_object, p_W: np.ndarray, d_W: np.ndarray, max_range_m: float, ignore=frozenset()) -> np.ndarray:
    """Distances (m) along rays from the points p_W (n x 3, W) in the unit directions d_W (n x 3, W) to
    the first surface of a proximity geometry not in `ignore` (GeometryIds): 0 for a ray that starts
    inside one, inf where none is within max_range_m (or the ray does not settle in MAX_STEPS)."""
    hits = np.full(len(p_W), np.inf)
    for i, (p, d) in enumerate(zip(np.asarray(p_W, float), np.asarray(d_W, float))):
        s = 0.0
        for _ in range(MAX_STEPS):
            step, hit = np.inf, False
            for r in query_object.ComputeSignedDistanceToPoint(p + s * d, max_range_m - s):
                if r.id_G in ignore:
                    continue
                if r.distance < TOLERANCE_M:  # on a surface; at s = 0 also inside one
                    hit = True
                    break
                slope = float(r.grad_W @ d)
                if slope < 0:
                    step = min(step, r.distance / -slope)
            if hit:
                hits[i] = s
                break
            s += step
            if s > max_range_m:
                break
    return hits
