"""Collision geometry of a part: inset convex pieces, decomposed once per machine and cached.

A part's collision shape is two kinds of convex pieces, all in the part's LDraw frame (LDU):
- **studs**: one exact 16-gon prism per stud (from the stud records), so a stud that lands on a
  wall or a slope collides;
- **body**: the rest of the mesh. Filling the hollow underside is harmless, because studs never
  collide with the part they are connected into (see `factory.physics.collide`). So when the
  body's convex hull covers only the part and its bottom-open cavity (bricks, plates, tiles,
  slopes: every sampled point of the hull is roofed and walled in by the part), the hull is the
  one body piece; otherwise (brackets, mudguards, hinges) coacd splits the body, coarsely.

Every piece is inset by `INSET_LDU` (its faces moved inward), so mated parts that touch are not
penetrating and a penetration measured between inset pieces is a real overlap of at least
2 x INSET_LDU.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from factory.connections import STUD_HEIGHT, STUD_RADIUS
from factory.parts import Part

INSET_LDU = 0.25
"""How far every face of a collision piece is moved inward (BrickNet insets meshes by 0.25 LDU)."""


@dataclass(frozen=True)
class DecompositionConfig:
    """coacd settings for part bodies; part of the cache key."""

    threshold: float = 0.05
    """coacd concavity threshold, for parts whose hull is not faithful (brackets, holders, seats):
    they are concave where other parts sit, so the split must be fine."""
    max_convex_hull: int = 32
    """Upper bound on body pieces per part (contacts cost grows with pieces)."""
    preprocess_resolution: int = 50
    """coacd's voxel resolution for its manifold preprocessing."""
    mcts_iterations: int = 60
    mcts_nodes: int = 12
    mcts_max_depth: int = 2
    seed: int = 0
    inset_ldu: float = INSET_LDU
    snap_ldu: float = 1.0
    """A coacd piece is rebuilt from the part's vertices within this distance of it."""


def cache_dir() -> Path:
    """Where decompositions are cached: `$BRICK_FACTORY_CACHE` or `~/.cache/brick-factory`."""
    root = os.environ.get("BRICK_FACTORY_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "brick-factory")
    return Path(root) / "coacd"


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """Inset convex pieces of one part, in its LDraw frame (LDU)."""

    body: tuple[np.ndarray, ...]
    studs: tuple[np.ndarray, ...]
    body_inset: float
    """How far the body pieces sit inside the part's surface (LDU)."""
    key: str
    """Content hash of the part geometry and settings: names the cache entry and the MJCF meshes."""


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
    from scipy.optimize import linprog

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


def _decompose(vertices: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig) -> list[np.ndarray]:
    import coacd

    coacd.set_log_level("error")
    mesh = coacd.Mesh(vertices, faces)
    pieces = coacd.run_coacd(
        mesh,
        threshold=cfg.threshold,
        max_convex_hull=cfg.max_convex_hull,
        preprocess_mode="auto",
        preprocess_resolution=cfg.preprocess_resolution,
        mcts_iterations=cfg.mcts_iterations,
        mcts_nodes=cfg.mcts_nodes,
        mcts_max_depth=cfg.mcts_max_depth,
        seed=cfg.seed,
    )
    return [np.asarray(v, dtype=np.float64) for v, _ in pieces]


_SIDES = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0], [0, -1.0, 0]])


def _hull_is_faithful(tris: np.ndarray, pitch: float = 3.0) -> bool:
    """Whether every point of the body's hull lies under the part's roof and between its walls.

    A sample point in a bottom-open cavity passes (rays up and sideways all meet the part); a point
    in an outside concavity (an L-bracket's inner corner, a wheel arch) has a ray that escapes.
    """
    from factory.connections import first_hits

    pts = tris.reshape(-1, 3)
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):
        return False
    lo, hi = pts.min(0) + 0.5, pts.max(0) - 0.5
    axes = [np.arange(a, b + 1e-9, pitch) if b > a else np.array([(a + b) / 2]) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = np.all(grid @ hull.equations[:, :3].T + hull.equations[:, 3] < -0.5, axis=1)
    grid = grid[inside]
    for d in _SIDES:
        for chunk in np.array_split(grid, max(1, len(grid) // 256)):
            if len(chunk) and not np.isfinite(first_hits(tris, chunk, np.tile(d, (len(chunk), 1)))).all():
                return False
    return True


def _snap(piece: np.ndarray, verts: np.ndarray, snap: float) -> np.ndarray | None:
    """The part's vertices that lie in (or within `snap` of) a convex piece, or None if too few."""
    try:
        eq = ConvexHull(piece).equations
    except (QhullError, ValueError):
        return None
    inside = np.all(verts @ eq[:, :3].T + eq[:, 3] <= snap, axis=1)
    pts = verts[inside]
    if len(pts) < 4 or np.linalg.matrix_rank(pts - pts.mean(0), tol=1e-6) < 3:
        return None
    return pts


def _body_mesh(part: Part) -> tuple[np.ndarray, np.ndarray]:
    tris = part.flat.triangles[~part.flat.in_stud]
    verts, faces = np.unique(np.round(tris.reshape(-1, 3), 4), axis=0, return_inverse=True)
    faces = faces.reshape(-1, 3)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return verts, faces[keep]


def collision_shape(part: Part, cfg: DecompositionConfig = DecompositionConfig()) -> CollisionShape:
    """The part's inset collision pieces, from the disk cache or decomposed now (and cached)."""
    memo = part.__dict__.setdefault("_collision_shapes", {})
    if cfg in memo:
        return memo[cfg]
    verts, faces = _body_mesh(part)
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(verts).tobytes())
    h.update(np.ascontiguousarray(faces).tobytes())
    h.update(json.dumps(asdict(cfg), sort_keys=True).encode())
    key = h.hexdigest()[:24]
    path = cache_dir() / f"{key}.npz"
    body: list[np.ndarray] | None = None
    if path.exists():
        try:
            with np.load(path) as data:
                body = [data[f"p{i}"] for i in range(int(data["n"]))]
                inset = float(data["inset"])
        except (OSError, ValueError, KeyError):
            body = None  # a damaged entry is recomputed and replaced
    if body is None:
        inset = cfg.inset_ldu
        if not len(faces):
            body = []
        elif _hull_is_faithful(part.flat.triangles[~part.flat.in_stud]):
            body = [p for p in [inset_hull(verts, cfg.inset_ldu)] if p is not None]
        else:
            # coacd remeshes its input on a voxel grid, so its pieces bulge up to ~1 LDU out of
            # the part. Rebuild each piece as the hull of the part's own vertices it holds (within
            # a snap distance): pieces then follow the real surface.
            pieces = (_snap(r, verts, cfg.snap_ldu) for r in _decompose(verts, faces, cfg))
            body = [p for p in (inset_hull(r, cfg.inset_ldu) for r in pieces if r is not None) if p is not None]
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
        np.savez(tmp, n=len(body), inset=inset, **{f"p{i}": p for i, p in enumerate(body)})
        os.replace(tmp, path)
    studs = []
    for s in part.studs:
        prism = inset_hull(stud_prism(s.pos, s.axis), cfg.inset_ldu)
        if prism is not None:
            studs.append(prism)
    shape = CollisionShape(tuple(body), tuple(studs), inset, key)
    memo[cfg] = shape
    return shape
