"""Collision geometry of a part: inset convex pieces, decomposed once per machine and cached.

A part's collision shape is two kinds of convex pieces, all in the part's LDraw frame (LDU):
- **studs**: one exact 16-gon prism per stud (from the stud records), so a stud that lands on a
  wall or a slope collides;
- **body**: the rest of the mesh. Filling the hollow underside is harmless, because studs never
  collide with the part they are connected into (see `factory.physics.collide`). So when the
  body's convex hull covers only the part and its bottom-open cavity (bricks, plates, tiles,
  slopes: every sampled point of the hull is roofed and walled in by the part), the hull is the
  one body piece. Otherwise the body is cut by planes along the part's own axis-aligned faces
  (through the middle of a cell that has none, as along a curve) until every cell's hull is
  faithful in the same sense (a round plate's narrow base below its wider top, a corner brick's
  or a wedge's notch, a headlight brick's recess, a dish's dome below the stud it sits on): the
  pieces then follow the part's surface. Only where that takes too many cells does coacd split
  the body. Any piece still not faithful (coacd's hulls span concave corners) is then split along
  the part's faces within it (`_refined`).

Every piece is inset by `INSET_LDU` (its faces moved inward), so mated parts that touch are not
penetrating and a penetration measured between inset pieces is a real overlap of at least
2 x INSET_LDU.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from factory.connections import STUD_HEIGHT, STUD_RADIUS
from factory.cache import cache_root, keep
from factory.errors import LDrawLimitError
from factory.parts import Part

INSET_LDU = 0.25
"""How far every face of a collision piece is moved inward (BrickNet insets meshes by 0.25 LDU)."""
MIN_PIECE_LDU3 = 1e-3
"""Body pieces smaller than this (LDU^3) are dropped (MuJoCo refuses meshes of almost no volume)."""


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
    faithful_pitch_ldu: float = 1.5
    """Spacing of the points sampled inside a hull to test whether it is faithful."""
    min_cut_ldu: float = 1.5
    """Thinnest half of a cell halved through its middle: a thinner cell may hold no sample point
    (at `faithful_pitch_ldu`) and would pass the test whatever it fills."""
    split_cells: int = 256
    """How many cells the split along the part's faces may examine before giving the body to coacd
    (a split into n faithful pieces examines 2n - 1)."""
    stud_bores_roofed: bool = True
    """Whether the faithfulness test counts a hollow stud's bore as roofed (the stud's collision
    prism is solid, so filling the bore under it changes nothing)."""
    refine_cells: int = 256
    """How many cells the split of one unfaithful piece (`_refined`) may examine (the mudguard
    35789 needs 128 since the refinement samples to the inset). Not part of the decomposition's
    cache key: refined pieces are cached under their own (`collision_shape`)."""


REFINED_VERSION = 3
"""Version of the refinement (`_refined`), part of refined pieces' cache key. 3: samples the deepest point
of a hull the grid misses (`_Faithfulness.centre`) and keeps a cell too small to cut (it gave up
the whole piece). 2: samples every point the inset piece keeps,
halves cells down to twice the inset and drops pieces thinner than the inset (1: sampled 0.5 LDU
in, halved down to `min_cut_ldu`, kept every piece)."""


def cache_dir() -> Path:
    """Where decompositions are cached: `coacd/` in the factory's cache folder (`factory.cache`)."""
    return cache_root() / "coacd"


@dataclass(frozen=True, eq=False)
class CollisionShape:
    """Inset convex pieces of one part, in its LDraw frame (LDU)."""

    body: tuple[np.ndarray, ...]
    studs: tuple[np.ndarray, ...]
    body_inset: float
    """How far the body pieces sit inside the part's surface (LDU)."""
    key: str
    """Content hash of the part geometry and settings: names the cache entry and the MJCF meshes."""
    stud_at: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    """Each stud piece's base centre and axis, in the order of `studs`."""


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


MAX_COLLISION_TRIANGLES = 50_000
"""Triangles of a part the collision decomposition takes. The real subset's largest part has
10,089 (74323.dat); the decomposition's cost follows the surface's shape more than its size, and
its worst case measured here, a soup of random triangles, took 141 s and 1.5 GB at 48,000
triangles, more than 300 s and 7.5 GB at 240,000, and was killed for memory at 24 GB at 1.2
million (in this process, before coacd). Renders and `factory.ldraw` take larger parts."""

COACD_SECONDS = 300
"""Wall time one part's coacd decomposition may take, unless `COACD_SECONDS_ENV` says otherwise.
Most real parts take 0.1-15 s here, but 11208.dat (a 2,288-triangle part of 40448) took more than
300 s on this project's 2-core machine; a soup of 12,000 random triangles ran past 200 s at
2.4 GB, and one of 1.2 million was killed for memory at 24 GB after 96 s. coacd is native code
that cannot be stopped from Python, so it runs in a child process under this limit and
`COACD_MEMORY_BYTES`."""
COACD_SECONDS_ENV = "BRICK_FACTORY_COACD_SECONDS"
"""Environment variable: seconds one decomposition may take (a slow machine meeting a slow part)."""
COACD_MEMORY_BYTES = 8 << 30
"""Address space of that child process (the 1.2-million-triangle soup reached 24 GB)."""


COARSE = {"preprocess_resolution": 30, "max_convex_hull": 16, "mcts_iterations": 20, "mcts_nodes": 8,
          "threshold": 0.1}
"""coacd settings of the second try, for a part whose decomposition ran past its time limit at
`DecompositionConfig`'s: the voxel resolution of coacd's preprocessing sets most of its time.
Measured on this project's 2-core machine, parts of LDraw's library that took more than 300 s:
6061 39 s coarse (1,232 triangles, 16 pieces), 48169 37 s, 4746 9 s. Which settings a part near
the limit gets can depend on the machine; the cache (and `pipelines.parts --pack`) keeps it."""


class DecompositionTooSlow(LDrawLimitError):
    """coacd ran past `coacd_seconds()` on a part."""


def coacd_seconds() -> float:
    """The decomposition's time limit: `COACD_SECONDS_ENV` when set, else `COACD_SECONDS`."""
    raw = os.environ.get(COACD_SECONDS_ENV, "").strip()
    if not raw:
        return COACD_SECONDS
    try:
        seconds = float(raw)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"{COACD_SECONDS_ENV} must be a number of seconds > 0, got {raw!r}")
    return seconds


_COACD_CHILD = """
import sys
try:  # set before numpy and coacd load (a preexec_fn is unsafe in threaded workers); POSIX only
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[3]), int(sys.argv[3])))
except ImportError:
    pass
import numpy as np
import coacd
data = np.load(sys.argv[1])
coacd.set_log_level("error")
args = {k: v.item() for k, v in data.items() if k not in ("vertices", "faces", "preprocess_mode")}
pieces = coacd.run_coacd(coacd.Mesh(data["vertices"], data["faces"]), preprocess_mode="auto", **args)
np.savez(sys.argv[2], *[np.asarray(v, dtype=np.float64) for v, _ in pieces])
"""


def _decompose(vertices: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig, name: str = "") -> list[np.ndarray]:
    """coacd's convex pieces of the mesh, computed in a child process bounded by `coacd_seconds()`
    and `COACD_MEMORY_BYTES`; past either, an `LDrawLimitError` naming the part."""
    with tempfile.TemporaryDirectory(prefix="bf-coacd-") as tmp:
        src, out = os.path.join(tmp, "mesh.npz"), os.path.join(tmp, "pieces.npz")
        np.savez(src, vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                 threshold=cfg.threshold, max_convex_hull=cfg.max_convex_hull,
                 preprocess_resolution=cfg.preprocess_resolution, mcts_iterations=cfg.mcts_iterations,
                 mcts_nodes=cfg.mcts_nodes, mcts_max_depth=cfg.mcts_max_depth, seed=cfg.seed)
        what = f"decomposing {name or 'a part'} ({len(faces):,} triangles) into convex pieces"
        limit = coacd_seconds()
        try:
            done = subprocess.run([sys.executable, "-c", _COACD_CHILD, src, out, str(int(COACD_MEMORY_BYTES))],
                                  capture_output=True, text=True, timeout=limit)
        except subprocess.TimeoutExpired:
            raise DecompositionTooSlow(f"{what} took more than {limit:g} s; refusing the part (on a slow machine, "
                                  f"{COACD_SECONDS_ENV}=SECONDS allows longer)", name or None) from None
        if done.returncode != 0 or not os.path.exists(out):
            tail = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise LDrawLimitError(f"{what} failed within {COACD_MEMORY_BYTES >> 20:,} MB of memory ({tail}); "
                                  "refusing the part", name or None)
        with np.load(out) as pieces:
            return [pieces[f"arr_{i}"] for i in range(len(pieces.files))]


_SIDES = ((0, 1.0), (0, -1.0), (2, 1.0), (2, -1.0), (1, -1.0))
"""The directions a sample point must be closed in, as (axis, sign): sideways and up (-Y)."""
_BUCKET_LDU = 4.0
"""Cell size of the grid that sorts triangles for the axis-aligned ray casts."""
SAMPLE_CHUNK = 1 << 23
"""Entries (sample points x hull faces) one step of the faithfulness test holds: 64 MB."""
MAX_SAMPLES = 500_000_000
"""Most sample points the faithfulness test takes in one hull (LDraw's raised 32x32 baseplate 2552
has about 20 million); past it the part is refused (hostile input: a hull kilometres across)."""
MAX_GRID_ENTRIES = 1 << 22
"""Most (triangle, cell) entries of a `_RayGrid` (a 32x32 baseplate's top alone covers 25,600
cells of 4 LDU)."""


class _RayGrid:
    """The triangles of a part sorted for axis-aligned ray casts along one axis.

    A ray along the axis can only meet a triangle whose shadow on the plane across the axis holds
    the ray's origin, so each triangle is listed under every cell (`_BUCKET_LDU` square) of that
    plane its shadow's bounding box touches, once for all the casts of a part: a point is tested
    against the triangles of its own cell only. (Scanning every triangle for each cell of each
    cast took 111 of the 198 s that LDraw's boat hull 2560 took to prepare.)"""

    def __init__(self, tris: np.ndarray, axis: int):
        self.axis = axis
        self.a, self.b = [k for k in range(3) if k != axis]
        t2 = tris[:, :, [self.a, self.b]]
        # Signed doubled area in the plane: triangles seen edge-on cannot be met.
        area = ((t2[:, 1, 0] - t2[:, 0, 0]) * (t2[:, 2, 1] - t2[:, 0, 1])
                - (t2[:, 2, 0] - t2[:, 0, 0]) * (t2[:, 1, 1] - t2[:, 0, 1]))
        keep = np.abs(area) > 1e-9
        self.t2, self.t3, self.area = t2[keep], tris[keep], area[keep]
        self.origin = self.t2.reshape(-1, 2).min(0) if len(self.t2) else np.zeros(2)
        # Cells grow where the list would pass `MAX_GRID_ENTRIES` (triangles hundreds of LDU
        # across, as hostile input may draw): more triangles a cell, the same answers.
        self.cell = _BUCKET_LDU
        while True:
            lo = np.floor((self.t2.min(1) - self.origin) / self.cell).astype(np.int64)
            hi = np.floor((self.t2.max(1) - self.origin) / self.cell).astype(np.int64)
            nb = hi[:, 1] - lo[:, 1] + 1
            n = (hi[:, 0] - lo[:, 0] + 1) * nb
            if n.sum() <= MAX_GRID_ENTRIES:
                break
            self.cell *= 2
        tri = np.repeat(np.arange(len(n)), n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        ca = lo[tri, 0] + k // nb[tri]
        cb = lo[tri, 1] + k % nb[tri]
        keys = self._key(ca, cb)
        order = np.argsort(keys, kind="stable")
        self.keys, self.tris = keys[order], tri[order]

    @staticmethod
    def _key(ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
        return ca * (1 << 32) + cb  # cells are a few thousand across at most: no collisions

    def blocked(self, points: np.ndarray, sign: float) -> np.ndarray:
        """For each point, whether a ray along +-axis (`sign`) from it meets one of the triangles."""
        hit = np.zeros(len(points), bool)
        if not len(points) or not len(self.keys):
            return hit
        p2 = points[:, [self.a, self.b]]
        cell = np.floor((p2 - self.origin) / self.cell).astype(np.int64)
        keys, inverse = np.unique(self._key(cell[:, 0], cell[:, 1]), return_inverse=True)
        starts = np.searchsorted(self.keys, keys, side="left")
        stops = np.searchsorted(self.keys, keys, side="right")
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(len(keys) + 1))
        axis, t2, t3, area = self.axis, self.t2, self.t3, self.area
        for c in range(len(keys)):
            if starts[c] == stops[c]:
                continue
            near = self.tris[starts[c]:stops[c]]
            idx = order[bounds[c]:bounds[c + 1]]
            q = p2[idx][:, None, :]  # (points, 1, 2)
            v0, v1, v2 = t2[near, 0][None], t2[near, 1][None], t2[near, 2][None]
            # Barycentric coordinates of each point in each triangle's shadow.
            w1 = ((q[..., 0] - v0[..., 0]) * (v2[..., 1] - v0[..., 1])
                  - (v2[..., 0] - v0[..., 0]) * (q[..., 1] - v0[..., 1])) / area[near][None]
            w2 = ((v1[..., 0] - v0[..., 0]) * (q[..., 1] - v0[..., 1])
                  - (q[..., 0] - v0[..., 0]) * (v1[..., 1] - v0[..., 1])) / area[near][None]
            w0 = 1.0 - w1 - w2
            inside = (w0 >= -1e-7) & (w1 >= -1e-7) & (w2 >= -1e-7)
            depth = (w0 * t3[near, 0, axis][None] + w1 * t3[near, 1, axis][None]
                     + w2 * t3[near, 2, axis][None])
            ahead = sign * (depth - points[idx, axis][:, None]) > 1e-6
            hit[idx] = (inside & ahead).any(axis=1)
        return hit


@dataclass
class _Faithfulness:
    """Whether a convex hull holds only the part, its bottom-open cavities and the bores under its
    studs: no sample point inside it sees out of the part (a ray up or sideways meets none of the
    `occluders`). A point in an outside concavity (an L-bracket's inner corner, a wheel arch, the
    ring under a round plate's wider top) has a ray that escapes.

    A stud fills only the hollow above a socket's opening; a cavity that goes on below the
    sockets (a dish or a dome sitting on one stud) takes in the body of the part it sits on, so a
    point below the lowest socket counts as inside only if the part closes it from below too."""

    occluders: np.ndarray
    pitch: float
    socket_floor: float | None
    """The lowest socket opening (largest LDraw y), None for a part without sockets."""
    depth: float = 0.5
    """How far inside the hull a sample point must lie. The whole-body split samples 0.5 LDU in;
    the refinement (`_refined`) samples everything the inset piece keeps (`INSET_LDU` in), so a
    cell thinner than 1 LDU still holds sample points (see there)."""
    centre: bool = False
    """Whether a hull that holds no bin centre deeper than `depth` is sampled at its deepest point
    (its Chebyshev centre) where that lies deeper (the refinement's test). The grid's bin centres
    can all miss a hull: in a wedge one bin across, they lie on its sloping face. The steering stand 3829c01 kept such a wedge,
    1.35 x 2.2 LDU across, in the concave corner between its column and the plate at its foot, and
    the corner plate 2420 laid round the column (Vintage Car step 22) overlapped it by 1.26 LDU."""

    _grids: dict = field(default_factory=dict, repr=False, compare=False)
    """`_RayGrid` of the occluders per axis, made when first cast along it."""

    def _blocked(self, points: np.ndarray, axis: int, sign: float) -> np.ndarray:
        if axis not in self._grids:
            self._grids[axis] = _RayGrid(self.occluders, axis)
        return self._grids[axis].blocked(points, sign)

    def escapes(self, points: np.ndarray) -> bool:
        """Whether a sample point inside the hull of `points` sees out of the part.

        The grid is walked in chunks of at most `SAMPLE_CHUNK` entries (points x hull faces),
        stopping at the first point that escapes: the hull of a raised 32x32 baseplate (2552)
        holds about 20 million sample points, and testing them at once took more than 15 GB."""
        try:
            hull = ConvexHull(points)
        except (QhullError, ValueError):
            return False  # flat: holds no sample point
        # Bin centres along each axis, so that a cell a few LDU thick (a plate's top, a flange)
        # is sampled through its middle rather than skipped.
        lo, hi = points.min(0), points.max(0)
        axes = []
        for a, b in zip(lo, hi):
            n = max(1, int(round((b - a) / self.pitch)))
            axes.append(a + (np.arange(n) + 0.5) * (b - a) / n)
        shape = tuple(len(a) for a in axes)
        total = int(np.prod(shape))
        if total > MAX_SAMPLES:
            raise LDrawLimitError(f"testing the collision pieces of this part needs more than {MAX_SAMPLES:,} sample "
                                  f"points in one piece ({np.round(hi - lo).astype(int).tolist()} LDU across); refusing the part")
        eq = hull.equations
        step = max(1024, SAMPLE_CHUNK // len(eq))
        sampled = False
        for start in range(0, total, step):
            i, j, k = np.unravel_index(np.arange(start, min(total, start + step)), shape)
            grid = np.stack([axes[0][i], axes[1][j], axes[2][k]], -1)
            grid = grid[np.all(grid @ eq[:, :3].T + eq[:, 3] < -self.depth, axis=1)]
            sampled = sampled or len(grid) > 0
            if self._any_escapes(grid):
                return True
        if self.centre and not sampled:
            deepest = _interior_point(eq, self.depth + 1e-6)
            if deepest is not None:
                return self._any_escapes(deepest[None])
        return False

    def _any_escapes(self, grid: np.ndarray) -> bool:
        escaped = np.zeros(len(grid), bool)
        for axis, sign in _SIDES:
            open_ = ~escaped
            escaped[open_] = ~self._blocked(grid[open_], axis, sign)
        if self.socket_floor is not None:
            below = ~escaped & (grid[:, 1] > self.socket_floor + 0.5)
            escaped[below] = ~self._blocked(grid[below], 1, 1.0)
        return bool(escaped.any())


def _stud_caps(part: Part, segments: int = 16) -> np.ndarray:
    """A disc over each stud's top (triangles): a hollow stud's bore counts as roofed."""
    out = []
    for s in part.studs:
        prism = stud_prism(s.pos, s.axis, segments)
        top = prism[segments:]
        centre = top.mean(axis=0)
        out.append(np.stack([np.broadcast_to(centre, top.shape), top, np.roll(top, -1, axis=0)], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3, 3))


def _cut(polys: list[np.ndarray], axis: int | np.ndarray, at: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Polygons split by the plane x[axis] = at (or, for a normal vector `axis`, x . axis = at)
    into the parts below and above it."""
    normal = np.eye(3)[axis] if np.isscalar(axis) else np.asarray(axis, float)
    below, above = [], []
    for poly in polys:
        c = poly @ normal - at
        if c.max() <= 1e-9:
            below.append(poly)
            continue
        if c.min() >= -1e-9:
            above.append(poly)
            continue
        lo, hi = [], []
        for i in range(len(poly)):
            a, b, ca, cb = poly[i], poly[(i + 1) % len(poly)], c[i], c[(i + 1) % len(poly)]
            if ca <= 0:
                lo.append(a)
            if ca >= 0:
                hi.append(a)
            if (ca < 0 < cb) or (cb < 0 < ca):
                x = a + (ca / (ca - cb)) * (b - a)
                lo.append(x)
                hi.append(x)
        for side, pts in ((below, lo), (above, hi)):
            if len(pts) >= 3:
                side.append(np.array(pts))
    return below, above


def _hull_volume(points: np.ndarray) -> float:
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):
        return 0.0


def _split_faithful(polys: list[np.ndarray], test: _Faithfulness, min_cut: float,
                    budget: list[int], keep_small: bool = False) -> list[np.ndarray] | None:
    """Vertices of convex pieces covering the surface `polys`, each hull faithful (`test`),
    found by halving along the part's own axis-aligned faces (the cut that leaves the least hull
    volume first); None once `budget[0]` cells have been examined (coacd's case then), or where a
    cell that is not faithful cannot be cut (no face in it, thinner than two `min_cut`), unless
    `keep_small`: then that cell is kept as it is (the refinement's case: a cell under twice the
    inset at its thickest, rather than the whole piece it came from)."""
    budget[0] -= 1
    if budget[0] < 0:
        return None
    points = np.concatenate(polys)
    if len(points) < 4 or not test.escapes(points):
        return [points]
    lo, hi = points.min(0), points.max(0)
    # Every polygon edge (start, end), to find the points on each side of a cut without cutting.
    start = points
    end = np.concatenate([np.roll(p, -1, axis=0) for p in polys])
    # Candidate cuts: planes holding a face of the part, inside this cell; where there is none,
    # the cell's middle (a curved concavity has no face to cut along: halving the cell shrinks
    # what a hull can fill of it), into halves no thinner than `min_cut`.
    cuts = [(axis, at) for axis in range(3)
            for at in sorted({round(float(p[0, axis]), 3) for p in polys if np.ptp(p[:, axis]) < 1e-6})
            if lo[axis] + 0.5 < at < hi[axis] - 0.5]
    if not cuts:
        cuts = [(axis, float(lo[axis] + hi[axis]) / 2) for axis in range(3)
                if hi[axis] - lo[axis] >= 2 * min_cut]
    best = None
    for axis, at in cuts:
        ca, cb = start[:, axis] - at, end[:, axis] - at
        cross = ca * cb < 0
        t = (ca[cross] / (ca[cross] - cb[cross]))[:, None]
        on_cut = start[cross] + t * (end[cross] - start[cross])
        volume = (_hull_volume(np.concatenate([start[ca <= 0], on_cut]))
                  + _hull_volume(np.concatenate([start[ca >= 0], on_cut])))
        if best is None or volume < best[0]:
            best = (volume, axis, at)
    if best is None:
        return [points] if keep_small else None
    pieces = []
    for half in _cut(polys, best[1], best[2]):
        if not half:
            continue
        sub = _split_faithful(half, test, min_cut, budget, keep_small)
        if sub is None:
            return None
        pieces += sub
    return pieces


def _faithfulness(part: Part, cfg: DecompositionConfig, depth: float = 0.5) -> _Faithfulness:
    """The faithfulness test of the part's pieces (`_Faithfulness`), sampling `depth` inside."""
    occluders = part.flat.triangles
    if cfg.stud_bores_roofed and part.studs:
        occluders = np.concatenate([occluders, _stud_caps(part)])
    # Sockets entered from below only: a bracket's sockets behind its side studs are no floor.
    floor = max((c.pos[1] for c in part.sockets if c.axis == (0.0, -1.0, 0.0)), default=None)
    return _Faithfulness(occluders, cfg.faithful_pitch_ldu, floor, depth)


def _faithful_pieces(part: Part, cfg: DecompositionConfig) -> list[np.ndarray] | None:
    """Point sets of the body's faithful convex pieces: its hull alone when that is faithful, else
    the halves of `_split_faithful`; None where neither works (coacd's case)."""
    body = part.flat.triangles[~part.flat.in_stud]
    return _split_faithful(list(body), _faithfulness(part, cfg), cfg.min_cut_ldu, [cfg.split_cells])


def _within(polys: list[np.ndarray], piece: np.ndarray, reach: float) -> list[np.ndarray]:
    """The parts of the polygons inside the hull of `piece` grown by `reach` on every face."""
    try:
        eq = ConvexHull(piece).equations
    except (QhullError, ValueError):
        return []
    for n, d in zip(eq[:, :3], eq[:, 3]):
        polys, _ = _cut(polys, n, -d + reach)
        if not polys:
            break
    return polys


def _refined(part: Part, pieces: list[np.ndarray], cfg: DecompositionConfig) -> list[np.ndarray]:
    """Inset pieces, each one that is not faithful (a coacd piece is the hull of the part's
    vertices near it, and spans concave corners: the Vintage Car's mudguard 35789 reached 3.7 LDU
    past its rounded end into the plate beside it) replaced by faithful pieces of the part's
    surface within it (grown by the inset and the snap distance), split along the part's own
    faces as a whole body is; kept where that takes more than `refine_cells` cells.

    Here the test samples every point the inset piece keeps (deeper than the inset), not only
    those 0.5 LDU in as the whole-body split does, and a cell may be halved down to twice the
    inset: a half thinner than that keeps no inset piece, and a thicker one holds sample points.
    `_within` cuts the part's faces by the grown piece's planes, not along the part's own faces,
    so it can leave a slab under 1 LDU thick that held no point 0.5 in and passed whatever it
    filled. The Vintage Car's mudguard 35789: a slab 1 LDU thick (z 0..1 in its frame) joined
    the face of its side (z = 0) to the wall and the ledge of its row of sockets (x = -20,
    y = 24), spanning the open corner between them, above its sockets beside its rounded end,
    where the design lays 1x3 plates; its inset piece reached 7 LDU into them."""
    test = replace(_faithfulness(part, cfg, depth=cfg.inset_ldu), centre=True)
    body = list(part.flat.triangles[~part.flat.in_stud])
    out = []
    for piece in pieces:
        if not test.escapes(piece):
            out.append(piece)
            continue
        polys = _within(body, piece, cfg.inset_ldu + cfg.snap_ldu)
        split = (_split_faithful(polys, test, 2 * cfg.inset_ldu, [cfg.refine_cells], keep_small=True)
                 if polys else None)
        if split is None:
            out.append(piece)
            continue
        out += [p for p in (inset_hull(r, cfg.inset_ldu) for r in split)
                if p is not None and _width(p) >= cfg.inset_ldu]
    return out


def _width(piece: np.ndarray) -> float:
    """How thin a convex piece is: its least extent along the normal of one of its faces.

    A refined piece thinner than the inset came from a cell under three insets thick, which the
    test's grid (`faithful_pitch_ldu` apart) may hold no point of where it is a wedge: it is not
    known to be faithful, and no part overlaps it by more than its width, well under the checker's
    tolerance, so it is dropped. The mudguard 35789 kept such a wedge (0.06 LDU thick) in the
    open corner beside its rounded end, and MuJoCo measured the 1x3 plate lying there 0.56 LDU
    into it."""
    try:
        normals = ConvexHull(piece).equations[:, :3]
    except (QhullError, ValueError):
        return 0.0
    proj = piece @ normals.T
    return float((proj.max(0) - proj.min(0)).min())


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


def _load(path: Path) -> tuple[list[np.ndarray], float] | None:
    """A cached entry's pieces and inset, None if missing or damaged (then recomputed): empty
    (EOFError), truncated (BadZipFile), foreign or unreadable."""
    try:
        with np.load(path) as data:
            return [data[f"p{i}"] for i in range(int(data["n"]))], float(data["inset"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):  # OSError: missing too
        return None


def _save(path: Path, body: list[np.ndarray], inset: float) -> None:
    """Keep an entry (`factory.cache.keep`: atomic; a cache that cannot be written is worked
    without, said once on stderr)."""
    buf = io.BytesIO()
    np.savez(buf, n=len(body), inset=inset, **{f"p{i}": p for i, p in enumerate(body)})
    keep(path, buf.getvalue())


def _decomposed(part: Part, verts: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig) -> list[np.ndarray]:
    """The body's inset pieces (faithful hull, faces-cut pieces, else snapped coacd pieces)."""
    faithful = _faithful_pieces(part, cfg) if len(faces) else []
    if faithful is not None:
        return [p for p in (inset_hull(r, cfg.inset_ldu) for r in faithful) if p is not None]
    # coacd remeshes its input on a voxel grid, so its pieces bulge up to ~1 LDU out of the part.
    # Rebuild each piece as the hull of the part's own vertices it holds (within a snap
    # distance): pieces then follow the real surface.
    name = getattr(part, "file", None) or part.name
    try:
        raw = _decompose(verts, faces, cfg, name)
    except DecompositionTooSlow as slow:
        try:
            raw = _decompose(verts, faces, replace(cfg, **COARSE), name)
        except LDrawLimitError as again:
            raise LDrawLimitError(f"{slow.message}; again at coarser settings: {again.message}", slow.file) from None
    pieces = (_snap(r, verts, cfg.snap_ldu) for r in raw)
    return [p for p in (inset_hull(r, cfg.inset_ldu) for r in pieces if r is not None) if p is not None]


def _refusal_path(raw_key: str) -> Path:
    return cache_dir() / f"{raw_key}.json"


def _remember_refusal(raw_key: str, exc: LDrawLimitError) -> None:
    """Keep a refused decomposition's reason with the limits it ran under: the next process gives
    up at once instead of spending them again (a part that took more than 300 s, every run)."""
    keep(_refusal_path(raw_key), json.dumps({"seconds": coacd_seconds(), "memory": COACD_MEMORY_BYTES,
                                             "coarse": COARSE, "message": exc.message}).encode())


def _refused_before(raw_key: str, file) -> None:
    """Raise the kept refusal of this decomposition, if it ran under limits at least as wide as
    today's and tried today's coarser settings too (a larger `BRICK_FACTORY_COACD_SECONDS`, or a
    refusal kept before the second try existed, tries again). The message is kept without the
    file, which may be another machine's path (a packed cache)."""
    try:
        kept_ = json.loads(_refusal_path(raw_key).read_bytes())
        wide = float(kept_["seconds"]) >= coacd_seconds() and int(kept_["memory"]) >= COACD_MEMORY_BYTES \
            and kept_.get("coarse") == COARSE
        message = str(kept_["message"])
    except (OSError, ValueError, KeyError, TypeError):
        return
    if wide:
        raise LDrawLimitError(f"{message} (refused before; kept in the cache)", file)


def collision_shape(part: Part, cfg: DecompositionConfig = DecompositionConfig()) -> CollisionShape:
    """The part's inset collision pieces, from the disk cache or decomposed now (and cached).

    Two entries per part: the decomposition (keyed by the mesh and the settings but
    `refine_cells`), and its pieces made faithful (`_refined`, keyed by the first key and
    `refine_cells`), so that entries written before the refinement existed keep their meaning."""
    memo = part.__dict__.setdefault("_collision_shapes", {})
    if cfg in memo:
        return memo[cfg]
    if len(part.flat.triangles) > MAX_COLLISION_TRIANGLES:
        raise LDrawLimitError(f"part {part.name} has {len(part.flat.triangles):,} triangles; the physics checks "
                              f"decompose parts of at most {MAX_COLLISION_TRIANGLES:,}", getattr(part, "file", None))
    verts, faces = _body_mesh(part)
    settings = asdict(cfg)
    refine = settings.pop("refine_cells")
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(verts).tobytes())
    h.update(np.ascontiguousarray(faces).tobytes())
    h.update(json.dumps(settings, sort_keys=True).encode())
    raw_key = h.hexdigest()[:24]
    # REFINED_VERSION names how `_refined` works: a change to it must not reuse older entries.
    key = hashlib.sha256(f"{raw_key}/refined/{refine}/{REFINED_VERSION}".encode()).hexdigest()[:24]
    found = _load(cache_dir() / f"{key}.npz")
    if found is None:
        raw = _load(cache_dir() / f"{raw_key}.npz")
        if raw is None:
            _refused_before(raw_key, getattr(part, "file", None))
            try:
                raw = (_decomposed(part, verts, faces, cfg), cfg.inset_ldu)
            except LDrawLimitError as exc:
                _remember_refusal(raw_key, exc)
                raise
            _save(cache_dir() / f"{raw_key}.npz", *raw)
        found = (_refined(part, raw[0], cfg), raw[1])
        _save(cache_dir() / f"{key}.npz", *found)
    body, inset = found
    studs, stud_at = [], []
    for s in part.studs:
        prism = inset_hull(stud_prism(s.pos, s.axis), cfg.inset_ldu)
        if prism is not None:
            studs.append(prism)
            stud_at.append((np.array(s.pos, dtype=np.float64), np.array(s.axis, dtype=np.float64)))
    # A sliver left by a cut (a face just inside a cell's edge, inset) holds nothing a part could
    # overlap by the tolerance, and MuJoCo refuses a mesh of almost no volume.
    body = [p for p in body if _hull_volume(p) >= MIN_PIECE_LDU3]
    shape = CollisionShape(tuple(body), tuple(studs), inset, key, tuple(stud_at))
    memo[cfg] = shape
    return shape
