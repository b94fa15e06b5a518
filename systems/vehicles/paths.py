"""Planar reference paths for the ground vehicle, selected by name, parameterised by arc length.

`sine` is seed 002 Eq. (13); the others are the path shapes of seed 003 Fig. 9 (the paper gives
no dimensions, so the sizes are configuration). Every path starts at the World origin heading along
+x, but `sine` (along Eq. 13's slope, 45.15 deg) and `figure-eight` (its straights cross the origin at
45 deg). Open paths end after `length_m`; closed paths (circle, rectangle, figure-eight) repeat.
Corners are circular arcs of `radius_m`, since a car cannot turn on the spot.
"""

from dataclasses import dataclass

import numpy as np

from systems.config import require, require_positive

SAMPLE_SPACING_M = 0.1  # polyline resolution: 0.1 mm chord error on a 15 m radius
MAX_SIZE_M = 100_000.0  # a path's lengths and radius at most (a circle of it: 6.3 million samples, 150 MB)
# The open manoeuvres: their arcs' signed turning angles (rad), after the straight lead.
MANOEUVRE_TURNS = {"s-shape": (np.pi, -np.pi), "turn-90": (np.pi / 2,), "turn-180": (np.pi,)}


@dataclass
class PathConfig:
    name: str = "sine"  # one of PATH_NAMES
    length_m: float = 2000.0  # arc length of the open paths
    radius_m: float = 15.0  # every arc: circle, corners, turns, S and figure-eight lobes
    lead_m: float = 20.0  # straight run before the turns and the S
    side_m: float = 60.0  # rectangle: long straight side; the short one is half of it

    def validate(self, prefix: str = "path") -> None:
        """Names the fields as a scenario's flat keys: `{prefix}` for the name, `{prefix}_length_m`..."""
        require(self.name in PATH_NAMES,
                f"{prefix} '{self.name}' is not a path (known: {', '.join(PATH_NAMES)})")
        for name in ("radius_m", "lead_m", "side_m"):
            require_positive(getattr(self, name), f"{prefix}_{name}")
        for name in ("length_m", "radius_m", "lead_m", "side_m"):
            value = getattr(self, name)
            require(value <= MAX_SIZE_M, f"{prefix}_{name} must be at most {MAX_SIZE_M:g} m (the path is sampled every "
                                         f"{SAMPLE_SPACING_M:g} m), got {value:g}")
        # Under two sample spacings the polyline (Path) can be a single sample, which has no spacing.
        require(self.length_m >= 2 * SAMPLE_SPACING_M,
                f"{prefix}_length_m must be at least two sample spacings, {2 * SAMPLE_SPACING_M:g} m, "
                f"got {self.length_m}")
        if self.name in MANOEUVRE_TURNS:
            used = self.lead_m + sum(abs(angle) for angle in MANOEUVRE_TURNS[self.name]) * self.radius_m
            require(used <= self.length_m,
                    f"{prefix}_length_m = {self.length_m} is too short for '{self.name}' (needs at least {used:.2f}: "
                    f"{prefix}_lead_m and its turns' arcs)")


class Path:
    """A path in World x-y [m] as a polyline, resampled evenly along its arc length s [m] at
    about SAMPLE_SPACING_M.

    `heading` is the tangent direction [rad] (continuous, not wrapped), `curvature` its rate of
    change along s [1/m], positive turning left."""

    def __init__(self, s, xy, heading, curvature, closed: bool):
        self.length = float(s[-1])
        self.closed = closed
        count = int(np.ceil(self.length / SAMPLE_SPACING_M))
        self.spacing = self.length / count
        self.s = np.linspace(0.0, self.length, count + 1)
        self.xy = np.column_stack([np.interp(self.s, s, xy[:, 0]), np.interp(self.s, s, xy[:, 1])])
        self._heading = np.interp(self.s, s, heading)
        self._curvature = np.interp(self.s, s, curvature)
        self._last = count - 1  # the last sample that starts an interval
        self._lists = None  # the samples as lists, for sample(); made on first use

    def _wrap(self, s):
        return np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)

    def position(self, s) -> np.ndarray:
        s = self._wrap(s)
        return np.array([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])])

    def heading(self, s) -> float:
        return float(np.interp(self._wrap(s), self.s, self._heading))

    def curvature(self, s) -> float:
        return float(np.interp(self._wrap(s), self.s, self._curvature))

    @property
    def max_curvature(self) -> float:
        """The largest |curvature| [1/m] along the path: 1 / its tightest radius (0 for a straight)."""
        return float(np.abs(self._curvature).max())

    def sample(self, s: float) -> tuple[float, float, float, float]:
        """(x, y, heading, curvature) at one arc length s [m]: position(), heading() and
        curvature() in one look-up, in plain floats (the path follower's per-update path)."""
        s = float(s)
        s = s % self.length if self.closed else min(max(s, 0.0), self.length)
        u = s / self.spacing
        i = min(int(u), self._last)
        f = u - i
        lists = self._lists
        if lists is None:
            lists = self._lists = (self.xy[:, 0].tolist(), self.xy[:, 1].tolist(), self._heading.tolist(),
                                   self._curvature.tolist())
        return tuple(v[i] + f * (v[i + 1] - v[i]) for v in lists)

    def polyline(self, max_length_m: float = 400.0) -> np.ndarray:
        """(N, 2) points along the path in W [m], every k-th sample with k = max(1, samples // 2000) (under 4000
        points): all of a closed path, the first `max_length_m` of an open one."""
        s = self.s if self.closed else self.s[self.s <= max_length_m]
        return self.xy[np.searchsorted(self.s, s)][:: max(1, len(s) // 2000)]

    def nearest(self, p, s_hint: float | None = None, window_m: float = 10.0) -> float:
        """Arc length of the point nearest to p (2, m). With s_hint, only within window_m of it,
        so a vehicle keeps to its branch where the path crosses itself (figure-eight)."""
        px, py = float(p[0]), float(p[1])
        n = len(self.s)
        if s_hint is None:
            first, candidates = 0, self.xy
        else:
            centre = int(round(float(self._wrap(s_hint)) / self.spacing))
            half = int(np.ceil(window_m / self.spacing))
            first, stop = centre - half, centre + half + 1
            if self.closed and (first < 0 or stop > n - 1):  # across the closing point
                indices = np.mod(np.arange(first, stop), n - 1)
                d = (self.xy[indices, 0] - px) ** 2 + (self.xy[indices, 1] - py) ** 2
                return self._project_on_neighbours(px, py, int(indices[np.argmin(d)]))
            first, candidates = max(first, 0), self.xy[max(first, 0):min(stop, n)]
        d = (candidates[:, 0] - px) ** 2 + (candidates[:, 1] - py) ** 2
        return self._project_on_neighbours(px, py, first + int(np.argmin(d)))

    def _project_on_neighbours(self, px: float, py: float, i: int) -> float:
        """Refines sample i to the nearest point on its two adjacent chords; on a closed path the first and last
        samples are one point, so the chords on either side of it are the first and the last (closing) one."""
        best_s, best_d = float(self.s[i]), np.inf
        last = len(self.s) - 1
        for j in (i - 1, i):
            if self.closed:
                j = last - 1 if j < 0 else 0 if j >= last else j
            elif j < 0 or j >= last:
                continue
            ax, ay = self.xy[j].tolist()
            bx, by = self.xy[j + 1].tolist()
            ex, ey = bx - ax, by - ay
            t = min(max(((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey), 0.0), 1.0)
            d = (ax + t * ex - px) ** 2 + (ay + t * ey - py) ** 2
            if d < best_d:
                s0, s1 = self.s[j].item(), self.s[j + 1].item()
                best_s, best_d = s0 + t * (s1 - s0), d
        return best_s


def from_segments(segments, closed: bool, heading0: float = 0.0) -> Path:
    """A path from the origin through (length [m], curvature [1/m]) segments: lines and arcs."""
    s_all, xy_all, heading_all, curvature_all = [np.zeros(1)], [np.zeros((1, 2))], [[heading0]], [[0.0]]
    s0, xy0, h0 = 0.0, np.zeros(2), heading0
    for length, k in segments:
        sigma = np.linspace(0.0, length, max(2, int(np.ceil(length / SAMPLE_SPACING_M)) + 1))[1:]
        h = h0 + k * sigma
        if k == 0.0:
            xy = xy0 + np.outer(sigma, [np.cos(h0), np.sin(h0)])
        else:
            xy = xy0 + np.column_stack([np.sin(h) - np.sin(h0), np.cos(h0) - np.cos(h)]) / k
        s_all.append(s0 + sigma)
        xy_all.append(xy)
        heading_all.append(h)
        curvature_all.append(np.full(len(sigma), k))
        s0, xy0, h0 = s0 + length, xy[-1], h[-1]
    curvature_all[0] = [curvature_all[1][0]]
    return Path(np.concatenate(s_all), np.vstack(xy_all), np.concatenate(heading_all),
                np.concatenate(curvature_all), closed)


def sine_path(length_m: float) -> Path:
    """Seed 002 Eq. (13): y = 30 sin(2 pi x / 500) + 20 sin(2 pi x / 200) [m], cut at length_m."""
    a, b = (30.0, 2 * np.pi / 500), (20.0, 2 * np.pi / 200)
    x = np.arange(0.0, length_m + SAMPLE_SPACING_M, SAMPLE_SPACING_M / 2)  # arc length >= x
    y = a[0] * np.sin(a[1] * x) + b[0] * np.sin(b[1] * x)
    dy = a[0] * a[1] * np.cos(a[1] * x) + b[0] * b[1] * np.cos(b[1] * x)
    ddy = -a[0] * a[1] ** 2 * np.sin(a[1] * x) - b[0] * b[1] ** 2 * np.sin(b[1] * x)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    keep = s <= length_m
    return Path(s[keep], np.column_stack([x, y])[keep], np.arctan(dy)[keep],
                (ddy / (1 + dy**2) ** 1.5)[keep], closed=False)


def _open_manoeuvre(config: PathConfig) -> Path:
    """Straight lead, the arcs of MANOEUVRE_TURNS, then straight up to length_m (validate checks it fits)."""
    k = 1.0 / config.radius_m
    arcs = [(abs(angle) * config.radius_m, np.sign(angle) * k) for angle in MANOEUVRE_TURNS[config.name]]
    used = config.lead_m + sum(length for length, _ in arcs)
    return from_segments([(config.lead_m, 0.0), *arcs, (config.length_m - used, 0.0)], closed=False)


def _rectangle(config: PathConfig) -> Path:
    corner = (np.pi / 2 * config.radius_m, 1.0 / config.radius_m)
    sides = [(config.side_m, 0.0), corner, (config.side_m / 2, 0.0), corner]
    return from_segments(sides * 2, closed=True)


def _figure_eight(config: PathConfig) -> Path:
    """Two lobes of radius R joined by straights crossing at the origin at +-45 deg."""
    R = config.radius_m
    lobe = 1.5 * np.pi * R
    return from_segments([(R, 0.0), (lobe, -1.0 / R), (2 * R, 0.0), (lobe, 1.0 / R), (R, 0.0)],
                         closed=True, heading0=np.pi / 4)


_BUILDERS = {
    "sine": lambda c: sine_path(c.length_m),
    "straight": lambda c: from_segments([(c.length_m, 0.0)], closed=False),
    "s-shape": _open_manoeuvre,
    "rectangle": _rectangle,
    "circle": lambda c: from_segments([(2 * np.pi * c.radius_m, 1.0 / c.radius_m)], closed=True),
    "figure-eight": _figure_eight,
    "turn-90": _open_manoeuvre,
    "turn-180": _open_manoeuvre,
}
PATH_NAMES = tuple(_BUILDERS)


def make_path(config: PathConfig, prefix: str = "path") -> Path:
    """The named path; ConfigError (a ValueError) naming `prefix`'s fields for an unknown name or a
    bad size."""
    config.validate(prefix)
    return _BUILDERS[config.name](config)
