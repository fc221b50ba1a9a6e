"""Convex collision pieces laid out for separating axes, and the piece pairs near each candidate
(the batched checks, backend 'jax': `sweep_jax`, `collide_jax`; the device part is `pair_kernels`).

Pieces are precomputed once per collision shape (hull vertices, unit face normals and edge
directions, one per direction up to sign), placed in the world once per structure (kept for the
last structure; a structure grown by one part turns and moves only that part's) and in the unit's
frame once per call, and grouped by their size bucket (vertices, normals, edges: `LEVELS`, else
powers of two) into padded tables (`PieceSet`). Pairs are chosen on the host by boxes swept along
each candidate's approach (parts' boxes, then pieces' boxes: `near_pairs`), chunks of candidates
on threads (`near_pairs_threaded`).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from contextvars import copy_context
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import ConvexHull

from factory.parts import Part
from factory.physics.geometry import INSET_LDU, collision_shape
from factory.physics.check_state import current
from factory.physics.structure import Structure
from factory.physics.sweep import _boxes, box_interval
from factory.pose import Pose

LEVELS = ((8, 4, 4), (32, 16, 32), (64, 32, 64), (128, 64, 128))
"""Padded piece sizes (vertices, normals, edges): boxes; studs (16-gon prisms), slopes and round
cut pieces; larger cut pieces; coacd's."""


@dataclass(frozen=True)
class Piece:
    """A convex piece (inset, as the scene's) ready for separating axes."""

    verts: np.ndarray
    normals: np.ndarray
    """Unit face normals, one per direction up to sign."""
    edges: np.ndarray
    """Unit edge directions, one per direction up to sign."""
    stud: bool
    inset: float
    prism: np.ndarray
    """(3, 3): up to three directions along which the piece is a right prism (zero rows pad)."""

    @property
    def bucket(self) -> tuple[int, int, int]:
        """Padded (vertices, normals, edges): the first of `LEVELS` that holds the piece, else
        powers of two (few levels, few shapes to compile)."""
        size = len(self.verts), len(self.normals), len(self.edges)
        for level in LEVELS:
            if all(n <= m for n, m in zip(size, level)):
                return level
        return tuple(pow2(n, 1) for n in size)  # type: ignore[return-value]


def pow2(n: int, minimum: int) -> int:
    return max(minimum, 1 << max(0, math.ceil(math.log2(max(n, 1)))))


def _directions(v: np.ndarray) -> np.ndarray:
    """Unit vectors, one per direction up to sign (near-duplicates may both stay: harmless)."""
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    lead = np.argmax(np.abs(v) > 1e-9, axis=1)
    v = v * np.sign(v[np.arange(len(v)), lead])[:, None]
    _, first = np.unique(np.round(v * 1e7).astype(np.int64), axis=0, return_index=True)
    return v[np.sort(first)]


def convex_piece(verts: np.ndarray, stud: bool, inset: float) -> Piece:
    hull = ConvexHull(verts)
    normals = hull.equations[:, :3]
    edges = []
    for f, simplex in enumerate(hull.simplices):
        for j in range(3):
            nb = hull.neighbors[f][j]
            # A triangle edge is an edge of the polytope only between facets of two planes.
            if nb > f and normals[f] @ normals[nb] < 1 - 1e-9:
                a, b = np.delete(simplex, j)
                edges.append(hull.points[b] - hull.points[a])
    normals, edges = _directions(normals), _directions(np.array(edges))
    return Piece(np.ascontiguousarray(hull.points[hull.vertices]), normals, edges, stud, inset,
                  _prism_axes(normals, edges))


def _prism_axes(normals: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Face normals a along which the piece is a right prism: every edge along a or across it, and
    a x e a face normal for every edge e across it. Two pieces that are right prisms along one
    direction need no edge-edge axis: a x a = 0, a x e is a side normal, e x e' lies along a, the
    caps' normal (why most pairs, boxes, studs and slopes standing as built, skip them)."""
    out = np.zeros((3, 3))
    n = 0
    for a in normals:
        along = np.abs(edges @ a)
        if not np.all((along > 1 - 1e-9) | (along < 1e-9)):
            continue
        side = np.cross(a, edges[along < 1e-9])
        side /= np.linalg.norm(side, axis=1, keepdims=True)
        if np.all(np.abs(side @ normals.T).max(axis=1) > 1 - 1e-9) and n < 3:
            out[n] = a
            n += 1
    return out


def _padded(pieces: Sequence[Piece]) -> dict[tuple, tuple]:
    """The pieces grouped by bucket: {bucket: (piece indices, vertices, normals, edges)}, each
    piece's arrays padded to the bucket's sizes by repeating its first row (which changes no
    extreme value)."""
    def pad(a: np.ndarray, n: int) -> np.ndarray:
        return np.concatenate([a, np.repeat(a[:1], n - len(a), 0)])

    out: dict[tuple, list] = {}
    for i, p in enumerate(pieces):
        out.setdefault(p.bucket, []).append(i)
    return {b: (np.array(idx, np.int64),
                *(np.stack([pad(getattr(pieces[i], name), n) for i in idx]) for name, n in zip(("verts", "normals", "edges"), b)))
            for b, idx in out.items()}


@dataclass(frozen=True, eq=False)
class _Template:
    """One part's collision pieces (body, then studs) in its frame, laid out once for `PieceSet`."""

    stud: np.ndarray
    inset: np.ndarray
    prism: np.ndarray
    centres: np.ndarray
    """Each piece's centre as the scene's coincidence test takes it (the mean of its vertices)."""
    rows: dict
    """`_padded` of the pieces."""


_SHAPES: dict[int, tuple] = {}


def _template(part: Part) -> _Template:
    shape = collision_shape(part)
    if id(shape) not in _SHAPES:
        pieces = [convex_piece(v, False, shape.body_inset) for v in shape.body]
        pieces += [convex_piece(v, True, INSET_LDU) for v in shape.studs]
        centres = np.array([v.mean(axis=0) for v in (*shape.body, *shape.studs)]).reshape(-1, 3)
        template = _Template(np.array([p.stud for p in pieces], bool), np.array([p.inset for p in pieces]),
                             np.stack([p.prism for p in pieces]) if pieces else np.zeros((0, 3, 3)), centres,
                             _padded(pieces))
        _SHAPES[id(shape)] = (shape, template)  # the shape is kept, so its id is not reused
    return _SHAPES[id(shape)][1]


class PieceSet:
    """Placed pieces (world or unit frame) with their owner, grouped into padded bucket tables.

    `rows`: {bucket: (piece indices, ascending; vertices, normals, edges padded to the bucket)};
    `tables`: per bucket (vertices, normals, edges, centres), the rows `pair_kernels._gathered` picks from."""

    def __init__(self, stud: np.ndarray, inset: np.ndarray, prism: np.ndarray, centres: np.ndarray,
                 owner: np.ndarray, owners: int, rows: dict, box: np.ndarray | None = None):
        self.stud, self.inset, self.prism, self.centres = stud, inset, prism, centres
        self.owner, self.owners, self.n = owner, owners, len(stud)
        self.box = _piece_boxes(self.n, rows) if box is None else box
        self.start = np.searchsorted(self.owner, np.arange(self.owners + 1))  # pieces by owner
        # The box around each owner's pieces (an empty box where it has none).
        self.owner_box = np.empty((self.owners, 2, 3))
        self.owner_box[:, 0], self.owner_box[:, 1] = np.inf, -np.inf
        np.minimum.at(self.owner_box[:, 0], self.owner, self.box[:, 0])
        np.maximum.at(self.owner_box[:, 1], self.owner, self.box[:, 1])
        self.buckets = sorted(rows)
        self.bucket_of = np.zeros(self.n, np.int64)
        self.local = np.zeros(self.n, np.int64)
        self.tables = []
        self.verts = []
        for b, shape in enumerate(self.buckets):
            idx, verts, normals, edges = rows[shape]
            self.bucket_of[idx] = b
            self.local[idx] = np.arange(len(idx))
            self.tables.append((verts, normals, edges, self.centres[idx]))
            self.verts.append((verts, self.inset[idx]))

    @classmethod
    def of_pieces(cls, pieces: Sequence[Piece], centres: np.ndarray, owner: np.ndarray, owners: int) -> "PieceSet":
        return cls(np.array([p.stud for p in pieces], bool), np.array([p.inset for p in pieces]),
                   np.stack([p.prism for p in pieces]) if pieces else np.zeros((0, 3, 3)), centres, owner, owners,
                   _padded(pieces))


def _piece_boxes(n: int, rows: dict) -> np.ndarray:
    """(n, 2, 3): each piece's box (lowest and highest corner) from its bucket's vertices."""
    box = np.zeros((n, 2, 3))
    for idx, verts, _, _ in rows.values():
        box[idx, 0], box[idx, 1] = verts.min(axis=1), verts.max(axis=1)
    return box


@dataclass(frozen=True, eq=False)
class _PartPieces:
    """One part's pieces at its pose (`_Template` turned and moved), as `_joined` takes them."""

    stud: np.ndarray
    inset: np.ndarray
    prism: np.ndarray
    centres: np.ndarray
    rows: dict
    """{bucket: (the part's piece indices, vertices, normals, edges)}."""
    box: np.ndarray


def _part_pieces(part: Part, pose: Pose) -> _PartPieces:
    tp = _template(part)
    RT, t = pose.R.T, pose.t
    rows = {b: (idx, np.matmul(verts, RT) + t, np.matmul(normals, RT), np.matmul(edges, RT))
            for b, (idx, verts, normals, edges) in tp.rows.items()}
    return _PartPieces(tp.stud, tp.inset, np.matmul(tp.prism, RT), np.matmul(tp.centres, RT) + t, rows,
                       _piece_boxes(len(tp.stud), rows))


# A structure's parts' pieces are kept by part placed (the checker's `CheckState.placed_pieces`):
# a structure grown by one part turns and moves only that part's (it was a whole rebuild at every
# step, about 7 ms for 80 parts on the development machine).


def _joined(pieces: Sequence[_PartPieces]) -> PieceSet:
    """The `PieceSet` of parts' pieces, part after part."""
    counts = np.array([len(p.stud) for p in pieces], np.int64)
    owner = np.repeat(np.arange(len(pieces)), counts)
    if not counts.sum():
        return PieceSet(np.zeros(0, bool), np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 3)), owner, len(pieces), {})
    first = np.cumsum(counts) - counts
    gathered: dict[tuple, list] = {}
    for i, p in enumerate(pieces):
        for b, (idx, verts, normals, edges) in p.rows.items():
            gathered.setdefault(b, []).append((idx + first[i], verts, normals, edges))
    rows = {b: tuple(np.concatenate(x) for x in zip(*chunks)) for b, chunks in gathered.items()}
    return PieceSet(*(np.concatenate([getattr(p, name) for p in pieces]) for name in ("stud", "inset", "prism", "centres")),
                   owner, len(pieces), rows, np.concatenate([p.box for p in pieces]))


def _set_of(items: Sequence[tuple[Part, Pose]]) -> PieceSet:
    """The pieces of parts at poses: each part's `_Template` turned and moved."""
    return _joined([_part_pieces(part, pose) for part, pose in items])


# The last structures' and units' pieces are the checker's (`CheckState.structure_pieces`,
# `unit_sets`): the sampler checks one part against one structure in several calls per step.


def unit_set(rel: Sequence[tuple[Part, Pose]]) -> PieceSet:
    """The unit's pieces in its own frame, kept for the last unit."""
    key = tuple((id(part), pose.R.tobytes(), pose.t.tobytes()) for part, pose in rel)
    return current().unit_sets.get(key, [part for part, _ in rel], lambda: _set_of(rel))


def structure_set(structure: Structure) -> tuple[PieceSet, np.ndarray]:
    """The structure's pieces in the world and its parts' boxes, kept for the last structure."""
    state = current()

    def build():
        kept = state.placed_pieces
        pieces = []
        for p in structure.placed:
            if p not in kept:
                kept[p] = _part_pieces(p.part, p.pose)
            pieces.append(kept[p])
        return _joined(pieces), _boxes([(p.part, p.pose) for p in structure.placed])

    return state.structure_pieces.get(tuple(id(p) for p in structure.placed), list(structure.placed), build)


# --- Pairs near each candidate --------------------------------------------------------------------


def _swept_boxes_meet(lo: np.ndarray, hi: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Whether some s > 0 has s d in (lo, hi) along every axis (last dimension)."""
    start, end = box_interval(lo, hi, d)
    return start < end


def near_pairs(uset: PieceSet, sset: PieceSet, sboxes, rel, R, t, d, conn, part_margin: float = 0.0,
               piece_margin: float = 0.0):
    """The piece pairs whose boxes meet at some s >= 0 along each candidate's d (d = 0: at its pose),
    overlapping by more than the margin along every axis (a negative margin: apart by less than
    it): (candidate, unit piece, structure piece, part, connected). Each member's box against each
    part's (`part_margin`), then each of its pieces against the box of the part's pieces, then
    against each of them (`piece_margin`); stud pieces of parts the candidate connects to are left
    out (they never collide). `conn`: (candidates, parts) connected."""
    def meet(a_lo, a_hi, b_lo, b_hi, dk, margin):
        return _swept_boxes_meet(a_lo - b_hi + margin, a_hi - b_lo - margin, dk)

    mb = np.stack([part.bbox for part, _ in rel])
    mR = np.stack([p.R for _, p in rel])
    mt = np.stack([p.t for _, p in rel])
    wR = np.einsum("kij,mjl->kmil", R, mR)
    centre = np.einsum("kmij,mj->kmi", wR, mb.mean(axis=1)) + np.einsum("kij,mj->kmi", R, mt) + t[:, None]
    half = np.einsum("kmij,mj->kmi", np.abs(wR), (mb[:, 1] - mb[:, 0]) / 2)
    kk, mm, jj = np.nonzero(meet((centre - half)[:, :, None], (centre + half)[:, :, None], sboxes[None, None, :, 0],
                                 sboxes[None, None, :, 1], d[:, None, None], part_margin))
    # Pieces: each piece of the member (its world box at each candidate, computed once per
    # candidate and piece) against the box of all the part's pieces, then against each of them.
    ubox = uset.box
    wc = np.einsum("kij,uj->kui", R, ubox.mean(axis=1)) + t[:, None]
    wh = np.einsum("kij,uj->kui", np.abs(R), (ubox[:, 1] - ubox[:, 0]) / 2)
    nu = np.diff(uset.start)[mm]
    rep = np.repeat(np.arange(len(kk)), nu)
    k, j = kk[rep], jj[rep]
    u = uset.start[mm[rep]] + np.arange(len(rep)) - np.repeat(np.cumsum(nu) - nu, nu)
    pbox = sset.owner_box
    lo_u, hi_u = wc[k, u] - wh[k, u], wc[k, u] + wh[k, u]
    near = meet(lo_u, hi_u, pbox[j, 0], pbox[j, 1], d[k], piece_margin)
    k, j, u, lo_u, hi_u = k[near], j[near], u[near], lo_u[near], hi_u[near]
    ns = np.diff(sset.start)[j]
    rep = np.repeat(np.arange(len(k)), ns)
    s = sset.start[j[rep]] + np.arange(len(rep)) - np.repeat(np.cumsum(ns) - ns, ns)
    k, j, u, lo_u, hi_u = k[rep], j[rep], u[rep], lo_u[rep], hi_u[rep]
    is_conn = conn[k, j]
    sb = sset.box[s]
    near = ~(is_conn & (uset.stud[u] | sset.stud[s]))
    near &= meet(lo_u, hi_u, sb[:, 0], sb[:, 1], d[k], piece_margin)
    return k[near], u[near], s[near], j[near], is_conn[near]


PAIR_CHUNK = 512
"""Candidates per chunk of pair selection; chunks run on `PAIR_THREADS` threads (numpy releases
the interpreter lock in its array operations, so a many-core host selects pairs in parallel
while the device computes)."""
PAIR_THREADS = min(8, os.cpu_count() or 1)


def in_chunks(fn, count: int) -> tuple:
    """fn(a, b) over candidates a..b-1 in chunks of `PAIR_CHUNK` on `PAIR_THREADS` threads, each
    returned array joined in candidate order (the same arrays as one call over all gives)."""
    spans = [(a, min(a + PAIR_CHUNK, count)) for a in range(0, count, PAIR_CHUNK)]
    if len(spans) <= 1 or PAIR_THREADS <= 1:
        parts = [fn(a, b) for a, b in spans]
    else:
        # Each chunk in a copy of this thread's context: the checker's state (`check_state`) too.
        runs = [(copy_context(), span) for span in spans]
        with ThreadPoolExecutor(min(PAIR_THREADS, len(spans))) as pool:
            parts = list(pool.map(lambda run: run[0].run(fn, *run[1]), runs))
    return tuple(np.concatenate(x) for x in zip(*parts))


def near_pairs_threaded(uset: PieceSet, sset: PieceSet, sboxes, rel, R, t, d, conn, part_margin: float = 0.0,
                        piece_margin: float = 0.0):
    """`near_pairs` of all candidates, in chunks on threads (`in_chunks`)."""
    def chunk(a, b):
        k, *rest = near_pairs(uset, sset, sboxes, rel, R[a:b], t[a:b], d[a:b], conn[a:b], part_margin, piece_margin)
        return (k + a, *rest)

    return in_chunks(chunk, len(R))
