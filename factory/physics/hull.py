"""Convex pieces as point sets: a hull with its faces moved inward (`inset_hull`, by `INSET_LDU` in
a part's collision shape), the point deepest inside halfspaces, a stud's prism, a hull's volume."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from factory.connections import STUD_HEIGHT, STUD_RADIUS

INSET_LDU = 0.25
"""How far every face of a collision piece is moved inward (BrickNet insets meshes by 0.25 LDU)."""


def inset_hull(points: np.ndarray, inset: float, clip: np.ndarray | None = None) -> np.ndarray | None:
    """Vertices of the convex hull of `points` with every face moved `inset` inward, also cut by
    the halfspaces `clip` (rows a, b, c, d: inside where a x + b y + c z + d <= 0). None if empty."""
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return None
    eq = hull.equations.copy()
    eq[:, 3] += inset
    if clip is not None:
        eq = np.concatenate([eq, clip])
    centre = _interior_point(eq)
    if centre is None:
        return None
    try:
        verts = HalfspaceIntersection(eq, centre).intersections
        inner = ConvexHull(verts)
    except (QhullError, ValueError):
        return None
    return np.ascontiguousarray(verts[inner.vertices])


def _interior_point(eq: np.ndarray, min_depth: float = 1e-3) -> np.ndarray | None:
    """The point deepest inside the halfspaces (Chebyshev centre), None if thinner than min_depth."""
    norms = np.linalg.norm(eq[:, :3], axis=1)
    a = np.column_stack([eq[:, :3], norms])
    res = linprog(c=[0, 0, 0, -1], A_ub=a, b_ub=-eq[:, 3], bounds=[(None, None)] * 3 + [(0, None)])
    if not res.success or res.x[3] < min_depth:
        return None
    return res.x[:3]


def stud_prism(pos, axis, segments: int = 16) -> np.ndarray:
    """Vertices of a stud (radius 6, height 4 LDU) standing at `pos` along unit `axis`."""
    axis = np.asarray(axis, dtype=np.float64)
    ref = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(axis, ref)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    ang = np.arange(segments) * (2 * np.pi / segments)
    ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    base = np.asarray(pos) + STUD_RADIUS * ring
    return np.concatenate([base, base + STUD_HEIGHT * axis])


def _hull_volume(points: np.ndarray) -> float:
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):
        return 0.0
