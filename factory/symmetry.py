"""A part's rotational symmetry, found from its geometry.

A rotation S (about the part's origin) is a symmetry when it maps the part's vertex set onto itself:
every rotated vertex lands on a vertex. Candidates are the 24 rotations that keep the axes on axes
(bricks are built on a grid). A part that also maps onto itself under a 22.5 degree turn about an
axis is round about that axis: LDraw draws circles as 16-gons (48-gons at most in hi-res
primitives), so 16-fold symmetry is the most a round LDraw part shows, and we report it as
continuous.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from factory.cache import kept, source_digest

TOLERANCE = 0.01
"""LDU: how close a rotated vertex must land to a vertex."""


def axis_rotations() -> list[np.ndarray]:
    """The 24 proper rotations that permute the axes (with signs), identity first."""
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs)):
                m[row, col] = s
            if np.linalg.det(m) > 0:
                mats.append(m)
    mats.sort(key=lambda m: (not np.allclose(m, np.eye(3)), -np.trace(m)))
    return mats


def rotation_about(axis, degrees: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = np.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


@dataclass(frozen=True, eq=False)
class Symmetry:
    """The rotations S with S(part) = part, in the part's frame; a pose R and R @ S look the same."""

    rotations: tuple[np.ndarray, ...]
    continuous_axis: tuple[float, float, float] | None = None
    """Unit axis of continuous rotational symmetry (round parts), else None."""

    @property
    def order(self) -> int:
        """The number of discrete symmetry rotations found (including the identity)."""
        return len(self.rotations)

    def to_json(self) -> dict:
        axis = None if self.continuous_axis is None else [float(v) for v in self.continuous_axis]
        return {"order": self.order, "continuous_axis": axis}


def symmetry_cached(vertices: np.ndarray) -> Symmetry:
    """`find_symmetry`, kept on disk by the vertices and this file's digest (`symmetry/` in the
    factory's cache folder): it is most of loading a real part (0.08 s each, 68 s for the 813
    parts a usage prior gives on LDraw's library, in every worker process)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    h = hashlib.sha256(source_digest(__file__).encode())
    h.update(v.tobytes())
    return kept("symmetry", f"{h.hexdigest()[:32]}.json", _read_symmetry, lambda: find_symmetry(v), _symmetry_bytes)


def _symmetry_bytes(sym: Symmetry) -> bytes:
    return json.dumps({"rotations": [r.tolist() for r in sym.rotations], "axis": sym.continuous_axis}).encode()


def _read_symmetry(data: bytes) -> Symmetry | None:
    """A cache entry's symmetry, None unless it holds 3x3 rotations and an axis or null."""
    try:
        d = json.loads(data)
        rots = tuple(np.array(r, dtype=np.float64).reshape(3, 3) for r in d["rotations"])
        axis = None if d["axis"] is None else tuple(float(x) for x in d["axis"])
        if not rots or (axis is not None and len(axis) != 3):
            return None
        return Symmetry(rots, axis)
    except (ValueError, TypeError, KeyError, AttributeError):
        return None


def find_symmetry(vertices: np.ndarray) -> Symmetry:
    """The symmetry of a part given its vertices (k, 3) in LDU, about its origin."""
    pts = np.unique(np.round(np.asarray(vertices, dtype=np.float64), 4), axis=0)
    if len(pts) == 0:
        return Symmetry((np.eye(3),))
    tree = cKDTree(pts)

    def maps_onto_itself(rot: np.ndarray) -> bool:
        dist, _ = tree.query(pts @ rot.T, distance_upper_bound=TOLERANCE * 2)
        return bool(np.all(dist <= TOLERANCE))

    found = tuple(m for m in axis_rotations() if maps_onto_itself(m))
    continuous = None
    for axis in ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)):
        if maps_onto_itself(rotation_about(axis, 22.5)):
            continuous = axis
            break
    return Symmetry(found, continuous)
