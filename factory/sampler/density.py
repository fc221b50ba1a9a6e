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

from functools import lru_cache
from typing import Iterable

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from factory.parts import Part
from factory.pose import Pose


@lru_cache(maxsize=None)
def part_hull_points(part: Part) -> np.ndarray:
    """The vertices of the part's convex hull, in its own frame (LDU)."""
    pts = np.unique(np.round(part.flat.triangles.reshape(-1, 3), 6), axis=0)
    try:
        return pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):
        return pts


def hull_volume(points: np.ndarray) -> tuple[float, np.ndarray]:
    """(volume, hull vertices) of a point set; (0, points) when it is flat or too small."""
    volume, vertices, _ = _hull(points)
    return volume, vertices


def _hull(points: np.ndarray) -> tuple[float, np.ndarray, np.ndarray | None]:
    """`hull_volume` and the hull's facet planes (n . x + d <= 0 inside; None without a hull)."""
    try:
        h = ConvexHull(points)
    except (QhullError, ValueError):
        return 0.0, points, None
    return float(h.volume), points[h.vertices], h.equations


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

    def add(self, part: Part, pose: Pose) -> float:
        self.volume += part.volume_ldu3
        self.hull_volume, self.points, self.planes = _hull(np.concatenate([self.points, pose.apply(part_hull_points(part))]))
        return self.density()

    def density(self) -> float:
        return self.volume / self.hull_volume if self.hull_volume > 0 else 0.0

    def densities_with(self, part: Part, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """`density_with` at each of n poses (R (n, 3, 3), t (n, 3)): a candidate whose points all
        lie inside the current hull leaves it as it is (no hull to compute); for the rest, the
        hull of the current hull's vertices and the candidate's points outside it."""
        pts = np.einsum("nij,pj->npi", R, part_hull_points(part)) + t[:, None]
        volume = self.volume + part.volume_ldu3
        out = np.zeros(len(pts))
        if self.planes is None:
            for i, p in enumerate(pts):
                hull, _ = hull_volume(np.concatenate([self.points, p]))
                out[i] = volume / hull if hull > 0 else 0.0
            return out
        normal, offset = self.planes[:, :3].T, self.planes[:, 3]
        for i, p in enumerate(pts):
            outside = ((p @ normal + offset) > INSIDE_LDU).any(axis=1)
            if not outside.any():
                out[i] = volume / self.hull_volume
                continue
            hull, _ = hull_volume(np.concatenate([self.points, p[outside]]))
            out[i] = volume / hull if hull > 0 else 0.0
        return out

    def density_with(self, part: Part, pose: Pose) -> float:
        """The density after adding `part` at `pose` (the tracker is not changed)."""
        return float(self.densities_with(part, pose.R[None], pose.t[None])[0])


def density(placed: Iterable[tuple[Part, Pose]]) -> float:
    """The density of placed parts: summed part volume / convex hull volume (see module doc)."""
    tracker = DensityTracker()
    for part, pose in placed:
        tracker.add(part, pose)
    return tracker.density()
