"""The density reward: how compact an assembly is.

    density = (summed volume of the parts) / (volume of the convex hull of all their vertices)

Part volume is `Part.volume_ldu3` (the closed mesh's enclosed volume, so a brick's hollow
underside does not count); the hull is taken over every vertex of every placed part, studs
included. A lone 2x4 brick scores ~0.5; a tower or a sprawling line of parts, whose hull
encloses much empty space around it, scores low; a filled block scores high. It is scale free,
needs no grid or voxelisation, and is cheap to update: the hull of (assembly + new part) is the
hull of (the assembly's hull vertices + the new part's hull vertices), so each candidate costs
one small qhull call (~0.2 ms).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np
from scipy.spatial import ConvexHull, QhullError

try:  # qhull without the facet arrays `ConvexHull` builds; the same volume (see `_volume`)
    from scipy.spatial._qhull import _Qhull
except ImportError:  # a scipy that moved it: `ConvexHull` gives the same number
    _Qhull = None

from factory.parts import Part
from factory.pose import Pose


def _hull(points: np.ndarray, areas: bool = False):
    """(volume, hull vertices) of a point set ((0, points) when it is flat or too small), the
    hull's facet planes (n . x + d <= 0 inside, unit n; None without a hull) and, with `areas`,
    each facet's area (qhull's facets are triangles, one plane each)."""
    try:
        h = ConvexHull(points)
    except (QhullError, ValueError):
        return 0.0, points, None, None
    area = None
    if areas:
        a, b, c = (points[h.simplices[:, k]] for k in range(3))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    return float(h.volume), points[h.vertices], h.equations, area


def _volume(points: np.ndarray) -> float:
    """The volume of the points' hull (0 when it is flat or too small): qhull's run as
    `ConvexHull` makes it (option Qt, triangulated), read without building its facet arrays. A
    candidate's density needs the volume alone, and the sampler asks for ~17 a step (0.16 ms
    against 0.25 ms for 150 points on the development machine)."""
    if _Qhull is None:
        return _hull(points)[0]
    try:
        q = _Qhull(b"i", np.ascontiguousarray(points, dtype=np.double), b"", required_options=b"Qt")
    except (QhullError, ValueError):
        return 0.0
    try:
        q.triangulate()
        return float(q.volume_area()[0])
    finally:
        q.close()


INSIDE_LDU = 1e-9
"""A candidate point this close to the inside of the hull's every facet plane is inside: it
changes neither the hull nor its volume."""


class DensityTracker:
    """The density of a growing assembly, and of the assembly with one candidate added."""

    def __init__(self):
        self.volume = 0.0
        self.points = np.zeros((0, 3))
        self.hull_volume = 0.0
        self.planes: np.ndarray | None = None
        self.facet_areas: np.ndarray | None = None

    def add(self, part: Part, pose: Pose) -> float:
        self.volume += part.volume_ldu3
        self.hull_volume, self.points, self.planes, self.facet_areas = _hull(
            np.concatenate([self.points, pose.apply(part.hull_points)]), areas=True)
        return self.density()

    def density(self) -> float:
        return self.volume / self.hull_volume if self.hull_volume > 0 else 0.0

    def densities_with(self, part: Part, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """`density_with` at each of n poses (R (n, 3, 3), t (n, 3)): a candidate whose points all
        lie inside the current hull leaves it as it is (no hull to compute); for the rest, the
        hull of the current hull's vertices and the candidate's points outside it."""
        lazy = self.candidates(part, R, t)
        return np.array([lazy.exact(i) for i in range(len(t))])

    def candidates(self, part: Part, R: np.ndarray, t: np.ndarray) -> "CandidateDensities":
        """The densities of `part` at n poses, each computed when asked (`CandidateDensities`)."""
        return CandidateDensities(self, part, R, t)

    def density_with(self, part: Part, pose: Pose) -> float:
        """The density after adding `part` at `pose` (the tracker is not changed)."""
        return float(self.densities_with(part, pose.R[None], pose.t[None])[0])


HULL_BOUND_SLACK = 1e-9
"""Relative slack taken off the hull-volume lower bound, so that rounding can never put a bound
above the exact volume qhull gives."""


class CandidateDensities:
    """The density after adding a part at each of n poses: known at once for a candidate inside the
    current hull, computed with one qhull call when asked (`exact`) for the rest, and bounded from
    above for all at once (`upper`) without any.

    The bound: the hull with the candidate is at least the current hull plus, for any single
    candidate point q outside it, the pyramids from q over the hull's facets that q sees (exactly
    the hull of the current hull and q: beneath-beyond), so density <= volume / (that). The
    sampler asks `exact` only where the bound could change its choice (`sampler.KeyOrder`)."""

    def __init__(self, tracker: DensityTracker, part: Part, R: np.ndarray, t: np.ndarray):
        self.tracker = tracker
        self.volume = tracker.volume + part.volume_ldu3
        self.points = np.einsum("nij,pj->npi", R, part.hull_points) + t[:, None]
        n = len(self.points)
        self._exact: dict[int, float] = {}
        if tracker.planes is None:
            self.outside = np.ones((n, self.points.shape[1]), dtype=bool)
            self.upper = np.full(n, np.inf)
            return
        normal, offset = tracker.planes[:, :3].T, tracker.planes[:, 3]
        dist = self.points @ normal + offset  # (n, points, facets): > 0 where a facet sees the point
        self.outside = (dist > INSIDE_LDU).any(axis=2)
        for i in np.flatnonzero(~self.outside.any(axis=1)):
            self._exact[int(i)] = self.volume / tracker.hull_volume
        pyramids = np.where(self.outside, np.maximum(dist, 0.0) @ tracker.facet_areas, 0.0) / 3.0
        lower = (tracker.hull_volume + pyramids.max(axis=1)) * (1.0 - HULL_BOUND_SLACK)
        self.upper = np.where(lower > 0, self.volume / np.maximum(lower, 1e-300), np.inf)
        for i, d in self._exact.items():
            self.upper[i] = d

    def known(self, i: int) -> bool:
        return i in self._exact

    def exact(self, i: int) -> float:
        """The density with candidate i (one qhull call unless it lies inside the current hull)."""
        if i not in self._exact:
            p = self.points[i]
            if self.tracker.planes is not None:
                p = p[self.outside[i]]
            hull = _volume(np.concatenate([self.tracker.points, p]))
            self._exact[i] = self.volume / hull if hull > 0 else 0.0
        return self._exact[i]


def density(placed: Iterable[tuple[Part, Pose]]) -> float:
    """The density of placed parts: summed part volume / convex hull volume (see module doc)."""
    tracker = DensityTracker()
    for part, pose in placed:
        tracker.add(part, pose)
    return tracker.density()
