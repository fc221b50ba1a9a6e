"""Collision pieces that follow the part's surface: whether a convex hull is faithful to its part
(`_Faithfulness`: it fills only the part, its bottom-open cavities and its studs' bores), the split
of a body along the part's own faces into faithful pieces (`_split_faithful`, `_faithful_pieces`),
and the refinement of any piece that is not (`_refined`, its version `REFINED_VERSION`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from factory.errors import LDrawLimitError
from factory.parts import Part
from factory.physics.hull import _hull_volume, _interior_point, inset_hull, stud_prism
from factory.physics.ray_grid import _RayGrid

if TYPE_CHECKING:
    from factory.physics.decompose import DecompositionConfig

REFINED_VERSION = 3
"""Version of the refinement (`_refined`), part of refined pieces' cache key. 3: samples the deepest point
of a hull the grid misses (`_Faithfulness.centre`) and keeps a cell too small to cut (it gave up
the whole piece). 2: samples every point the inset piece keeps,
halves cells down to twice the inset and drops pieces thinner than the inset (1: sampled 0.5 LDU
in, halved down to `min_cut_ldu`, kept every piece)."""


SAMPLE_CHUNK = 1 << 23
"""Entries (sample points x hull faces) one step of the faithfulness test holds: 64 MB."""
MAX_SAMPLES = 500_000_000
"""Most sample points the faithfulness test takes in one hull (LDraw's raised 32x32 baseplate 2552
has about 20 million); past it the part is refused (hostile input: a hull kilometres across)."""


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

    def _grid(self, axis: int) -> _RayGrid:
        if axis not in self._grids:
            self._grids[axis] = _RayGrid(self.occluders, axis)
        return self._grids[axis]

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
        # A sample point must be closed in sideways (both ways along X and Z) and up (-Y).
        for axis in (0, 2):
            open_ = ~escaped
            escaped[open_] = ~self._grid(axis).enclosed(grid[open_])
        open_ = ~escaped
        escaped[open_] = ~self._grid(1).blocked(grid[open_], -1.0)  # up
        if self.socket_floor is not None:
            below = ~escaped & (grid[:, 1] > self.socket_floor + 0.5)
            escaped[below] = ~self._grid(1).blocked(grid[below], 1.0)
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
