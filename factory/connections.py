"""Where a part connects: studs from its stud primitives, sockets from its geometry.

Studs are read off the reference tree (`stud.dat` and its kin, wherever they sit). Sockets (places a
stud of another part can enter) are found by probing the underside with rays, so they work for parts
nobody listed: a socket is a spot on a stud-aligned grid, at a downward-facing rim, where a stud-sized
column (radius 6, height 4 LDU) is free of material, nothing lies below, and walls, bars or a tube
touch the stud from at least three sides. A socket ringed on all sides is a tube centre (`tube`),
others are anti-stud positions (`stud`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np

from factory.cache import kept, source_digest
from factory.errors import LDrawLimitError

STUD_RADIUS = 6.0
STUD_HEIGHT = 4.0
GRID = 10.0
"""Sockets sit on a half-stud grid (stud pitch 20 LDU): stud positions and tube centres both."""

UP = np.array([0.0, -1.0, 0.0])
"""LDraw's up: studs point this way, and a socket receives a stud moving this way."""

MAX_SOCKET_WORK = 100_000_000
"""Most triangle tests socket finding may spend on one part (all probe directions together), each
charged before it is done: each ray tested against a triangle counts one, and so does each rim
face measured from a spot, each spot tested against a triangle in a level-wide pass, each
triangle a pass or a probe's lookup looks at, and each spot of each level; a spot probed on its
own counts `PROBE_WORK` more. Measured on the project's 2-core machine (shared): every part of
LDraw's library (complete.zip's 4,564 parts of the construction categories) gets its sockets, the
most work being 3.0 x 10^7 (39369.dat, Technic beam baseplate 19 x 11, 110,352 triangles, 2.9 s;
6161.dat, brick 24 x 24 with a quarter circle, 42,652 triangles, 1.7 x 10^7, 2.4 s; 41539.dat,
plate 8 x 8, 2.5 x 10^6, 0.3 s), and baseplates, all refused before, need under 10^6 (3857.dat,
16 x 32, 24,652 triangles: 1.5 x 10^5, 0.1 s; 782.dat, 50 x 50, 120,084 triangles: 7.3 x 10^5,
0.5 s). Before, a probe scanned every triangle within the widest one's reach (all of a
baseplate) and 88 of the library's 413 parts over 5,000 triangles were refused. The generated
part of 128,000 triangles in 20 underside levels (tests/test_work_budgets.py's grid) is now
answered in 0.7 s (5.4 x 10^6), as every spot of it is closed below; shelves of 128,000
triangles in 20 levels that leave every spot to be probed on its own (tests/test_socket_finding.py)
are refused after 20 s at 200 MB (the old finder: 24 s, the 2 cores shared alike). Three times
the largest real need, so it refuses in seconds, not minutes: without it a part of 12,000
triangles took 25 s and one of 1.2 million ran past a minute at 3.4 GB (the reader's
2,000,000-triangle cap bounds a part's size, not this work)."""

PROBE_WORK = 5_000
"""What a spot probed on its own (`_Underside.probe`) counts besides its tests: the fixed cost of
its dozen numpy calls, 0.3-0.8 ms here, about what 5,000 tests in a large batch take. Without it a
part of many spots each near a handful of triangles would run for minutes within the budget."""

CHUNK_PAIRS = 1 << 16
"""Ray-triangle pairs tested in one numpy batch: a dozen temporaries of this many 3-vectors (1.5 MB
each), so memory stays bounded whatever the part's triangle count."""


MARGIN = 0.5
"""LDU added to the bounds by which spots and triangles are passed over (a box, a circle, a
reach), far above the rounding of the tests they stand for: passing one over never changes an
answer, it only spares the work."""


@dataclass(frozen=True)
class Connector:
    """A connection point in the part's frame: studs point out of the part along `axis`; a socket's
    `axis` is the direction a stud moves to enter it, so a mated stud and socket share pos and axis."""

    pos: tuple[float, float, float]
    axis: tuple[float, float, float]
    kind: str
    """'stud' for a stud; for a socket, 'stud' (anti-stud between walls) or 'tube' (tube centre)."""

    def to_json(self, with_kind: bool) -> dict:
        out = {"pos": [_r(v) for v in self.pos], "axis": [_r(v) for v in self.axis]}
        if with_kind:
            out["kind"] = self.kind
        return out


def _r(v: float) -> float:
    r = round(float(v), 4)
    return 0.0 if r == 0 else r


def studs_from_flat(studs: np.ndarray) -> tuple[Connector, ...]:
    """Connectors from the (k, 2, 3) stud records of a flattened part, in a stable order."""
    rows = sorted(
        (tuple(_r(v) for v in s[0]), tuple(round(float(v), 6) + 0.0 for v in s[1])) for s in studs
    )
    return tuple(Connector(pos, axis, "stud") for pos, axis in rows)


class _Work:
    """Triangle tests spent on one part's sockets, refused past `MAX_SOCKET_WORK` (read when
    spent, so a test can lower it) with the file named."""

    def __init__(self, where: str | None, triangles: int):
        self.where = where
        self.triangles = triangles
        self.spent = 0

    def spend(self, tests: int) -> None:
        self.spent += int(tests)
        if self.spent > MAX_SOCKET_WORK:
            raise LDrawLimitError(
                f"finding the sockets of this part ({self.triangles:,} triangles) needs more than "
                f"{MAX_SOCKET_WORK:,} ray-triangle tests; refusing it (the parts of LDraw's library "
                "need at most about 30,000,000)", self.where)


def first_hits(tris: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance along each ray to the first triangle it meets (inf where none); Moller-Trumbore.

    Both faces count: LDraw meshes are not always closed, and a probe must see every surface.
    Triangles are tested in chunks of at most `CHUNK_PAIRS` ray-triangle pairs.
    """
    best = np.full(len(origins), np.inf)
    if len(tris) == 0 or len(origins) == 0:
        return best
    step = max(1, CHUNK_PAIRS // len(origins))
    for k in range(0, len(tris), step):
        best = np.minimum(best, _first_hits(tris[k:k + step], origins, dirs))
    return best


def _first_hits(tris: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    v0 = tris[:, 0]
    e1 = tris[:, 1] - v0
    e2 = tris[:, 2] - v0
    o = origins[:, None, :]
    d = dirs[:, None, :]
    p = _cross(d, e2[None])
    det = np.einsum("rtk,tk->rt", p, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - v0[None]
    u = np.einsum("rtk,rtk->rt", s, p) * inv
    q = _cross(s, e1[None])
    v = np.einsum("rtk,rtk->rt", np.broadcast_to(d, q.shape), q) * inv
    t = np.einsum("rtk,tk->rt", q, e2) * inv
    eps = 1e-7
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 1e-6)
    t = np.where(hit, t, np.inf)
    return t.min(axis=1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`np.cross` of 3-vectors on the last axis, broadcast: the same products and differences,
    so the same bits, without its axis handling (much of a small cast's time)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _disc(radius: float) -> np.ndarray:
    ang = np.arange(8) * (np.pi / 4) + np.pi / 8
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    return np.concatenate([[[0.0, 0.0]], ring * radius, ring * radius * 0.55])


_DISC = _disc(STUD_RADIUS - 0.5)
_CELL = np.array(
    [[x, 0.05, z] for x in (-9.5, 0.0, 9.5) for z in (-9.5, 0.0, 9.5) if x or z], dtype=np.float64
)
_DIRS8 = np.array(
    [[np.cos(a), 0.0, np.sin(a)] for a in np.arange(8) * (np.pi / 4)], dtype=np.float64
)


def _distance_2d(tris: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance from point p (2,) to each triangle (n, 3, 2) in the plane, or from each point p
    (n, 2) to its triangle; 0 inside. Each distance is the same sums either way."""
    p = p[:, None, :] if p.ndim == 2 else p
    a, b = tris, np.roll(tris, -1, axis=1)
    ab = b - a
    t = np.clip(np.einsum("nkj,nkj->nk", p - a, ab) / np.maximum(np.einsum("nkj,nkj->nk", ab, ab), 1e-12), 0, 1)
    edge = np.linalg.norm(a + t[..., None] * ab - p, axis=2).min(axis=1)
    cross = ab[..., 0] * (p - a)[..., 1] - ab[..., 1] * (p - a)[..., 0]
    inside = np.all(cross >= -1e-9, axis=1) | np.all(cross <= 1e-9, axis=1)
    return np.where(inside, 0.0, edge)


def find_sockets(tris: np.ndarray, stud_columns=(), work: _Work | None = None,
                 where: str | None = None) -> tuple[Connector, ...]:
    """Sockets on the underside of a part, from its triangles (n, 3, 3) in LDU. `stud_columns`:
    the (x, z) of the part's own studs that point up, where a stud held only from two opposite
    sides counts too (`_pinched`). Past `MAX_SOCKET_WORK` triangle tests (`work`, shared by a
    part's probe directions) an `LDrawLimitError` naming `where` (the part's file).

    Each rim level is worked on as a whole first: its spots with a rim face within reach
    (`_rim_within`), less those that surely have material below (`_Underside.drop_closed`), each
    measured only against the faces and triangles whose boxes hold it. What is left (the sockets,
    and the few spots that fail later) is probed one spot at a time against the triangles near
    it, found by a lookup (`_Buckets`), so no step passes over all the part's triangles per spot.
    The answer is that of probing every spot against every triangle: only spots and triangles
    that cannot change it are passed over."""
    work = work if work is not None else _Work(where, len(tris))
    columns = np.asarray(stud_columns, float).reshape(-1, 2)
    if len(tris) == 0:
        return ()
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    flat_y = np.ptp(tris[:, :, 1], axis=1) < 1e-6
    facing = flat_y & (np.abs(n[:, 1]) > 1e-9)
    levels = np.unique(np.round(tris[facing, 0, 1], 3))
    lo = tris.min(axis=(0, 1))
    hi = tris.max(axis=(0, 1))
    xs = np.arange(np.ceil((lo[0] + STUD_RADIUS) / GRID), np.floor((hi[0] - STUD_RADIUS) / GRID) + 1) * GRID
    zs = np.arange(np.ceil((lo[2] + STUD_RADIUS) / GRID), np.floor((hi[2] - STUD_RADIUS) / GRID) + 1) * GRID
    if len(levels) == 0 or len(xs) == 0 or len(zs) == 0:
        return ()
    # Every spot of every level is looked at once (charged before any grid is made, so a part
    # spread over a vast grid is refused before it takes memory).
    work.spend(len(levels) * len(xs) * len(zs))
    part = _Underside(tris)
    under = _on_grid(columns, xs, zs)
    rim_y = np.round(tris[facing, 0, 1], 3)
    order = np.argsort(rim_y, kind="stable")
    rim, rim_y, rim_n = tris[facing][order][:, :, [0, 2]], rim_y[order], np.abs(n[facing, 1])[order]
    starts = np.searchsorted(rim_y, levels, side="left")
    ends = np.searchsorted(rim_y, levels, side="right")
    found: list[Connector] = []
    for y0, a, b in zip(levels, starts, ends):
        alive = _rim_within(rim[a:b], rim_n[a:b], xs, zs, STUD_RADIUS + 1.0, work)
        part.drop_closed(alive, xs, zs, y0, work)
        for i, j in np.argwhere(alive):
            kind = part.probe(np.array([xs[i], y0, zs[j]]), bool(under[i, j]), work)
            if kind:
                found.append(Connector((_r(xs[i]), _r(y0), _r(zs[j])), tuple(UP.tolist()), kind))
    return tuple(sorted(found, key=lambda c: (c.pos[1], c.pos[0], c.pos[2])))


def _on_grid(columns: np.ndarray, xs: np.ndarray, zs: np.ndarray) -> np.ndarray:
    """Which spots of the grid (len(xs), len(zs)) lie within 1e-3 of one of `columns` (k, 2)."""
    out = np.zeros((len(xs), len(zs)), bool)
    for cx, cz in columns:
        i = np.flatnonzero(np.abs(xs - cx) < 1e-3)
        j = np.flatnonzero(np.abs(zs - cz) < 1e-3)
        out[np.ix_(i, j)] = True
    return out


def _rim_within(flat: np.ndarray, area2: np.ndarray, xs: np.ndarray, zs: np.ndarray, reach: float,
                work: _Work) -> np.ndarray:
    """Which spots of the grid (len(xs), len(zs)) have a rim face (`flat`, (k, 3, 2) in x, z, of
    twice the area `area2`) within `reach`: a rim face at the level must touch the stud, as the
    opening is the end of the material around it (a ledge further from the stud, such as a rib
    inside a cavity, is not). Each face is measured (`_distance_2d`, the same sums) only from the
    spots in its box widened by `reach`; each such measure counts one."""
    # `_distance_2d` takes a point within 1e-9 of every edge line as inside: for a face of almost
    # no area that is a point up to about size * 2e-9 / area2 beyond it.
    size = np.ptp(flat, axis=1).max(axis=1)
    slack = reach + MARGIN + size * np.minimum(1.0, 2e-9 / area2)
    i0 = np.searchsorted(xs, flat[:, :, 0].min(axis=1) - slack, side="left")
    i1 = np.searchsorted(xs, flat[:, :, 0].max(axis=1) + slack, side="right")
    j0 = np.searchsorted(zs, flat[:, :, 1].min(axis=1) - slack, side="left")
    j1 = np.searchsorted(zs, flat[:, :, 1].max(axis=1) + slack, side="right")
    work.spend(int((np.maximum(i1 - i0, 0) * np.maximum(j1 - j0, 0)).sum()))
    out = np.zeros((len(xs), len(zs)), bool)
    for k, i, j in _grid_pairs(i0, i1, j0, j1):
        near = _distance_2d(flat[k], np.stack([xs[i], zs[j]], 1)) <= reach
        out[i[near], j[near]] = True
    return out


def _grid_pairs(i0: np.ndarray, i1: np.ndarray, j0: np.ndarray, j1: np.ndarray):
    """(k, i, j) for every box k and spot (i, j) of it (rows [i0, i1), columns [j0, j1) of a
    grid), in chunks of about `CHUNK_PAIRS` (a box is cut into strips of rows to fit, a strip
    being at least one row)."""
    w = j1 - j0
    h = np.maximum(i1 - i0, 0) * (w > 0)
    step = np.maximum(1, CHUNK_PAIRS // np.maximum(w, 1))
    strips = -(-h // step)
    k = np.repeat(np.arange(len(h)), strips)
    first = np.repeat(np.cumsum(strips) - strips, strips)
    s0 = i0[k] + (np.arange(len(k)) - first) * step[k]
    s1 = np.minimum(s0 + step[k], i1[k])
    count = (s1 - s0) * w[k]
    ends = np.cumsum(count)
    start = 0
    while start < len(k):
        base = ends[start - 1] if start else 0
        end = max(start + 1, int(np.searchsorted(ends, base + CHUNK_PAIRS, side="right")))
        c = count[start:end]
        r = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        width = np.repeat(w[k[start:end]], c)
        yield (np.repeat(k[start:end], c), np.repeat(s0[start:end], c) + r // width,
               np.repeat(j0[k[start:end]], c) + r % width)
        start = end


def _turn_to_up(axis: np.ndarray) -> np.ndarray:
    """A rotation (a signed permutation) taking a principal `axis` to UP."""
    k = int(np.argmax(np.abs(axis)))
    sign = float(np.sign(axis[k]))
    if k == 1:
        return np.diag([1.0, 1.0, 1.0]) if sign < 0 else np.diag([1.0, -1.0, -1.0])
    r = np.zeros((3, 3))
    r[1, k] = -sign  # axis -> -y (UP)
    r[k, 1] = sign   # -y -> axis: a quarter turn in the (k, y) plane
    r[2 - k, 2 - k] = 1.0  # the third axis stays (k is 0 or 2, so it is 2 or 0)
    return r


def sockets_facing(tris: np.ndarray, studs, where: str | None = None) -> tuple[Connector, ...]:
    """Sockets entered along UP (the underside, `find_sockets`) and, for every other principal
    axis the part's own studs point along, the sockets entered along that axis: a part with studs
    on a side (a bracket) has its sockets at the back of that side, as a brick has them under its
    top. Other directions are not probed: a part has no reason to hold a stud there, and probing
    every side of every part would cost five more probes per part. Past `MAX_SOCKET_WORK` triangle
    tests in all, an `LDrawLimitError` naming `where` (the part's file)."""
    studs = list(studs)
    work = _Work(where, len(tris))

    def columns(r: np.ndarray) -> np.ndarray:
        # The (x, z) of the studs that point up once the part is turned by r.
        return np.array([(r @ c.pos)[[0, 2]] for c in studs if (r @ c.axis) @ UP > 0.999]).reshape(-1, 2)

    found = list(find_sockets(tris, columns(np.eye(3)), work))
    done = {tuple(UP)}
    for a in {c.axis for c in studs}:
        a = np.asarray(a, float)
        k = int(np.argmax(np.abs(a)))
        if abs(a[k]) < 0.999:
            continue  # studs off the principal axes: no grid to probe on
        key = tuple(np.sign(a[k]) * np.eye(3)[k])
        if key in done:
            continue
        done.add(key)
        r = _turn_to_up(np.array(key))
        for c in find_sockets(tris @ r.T, columns(r), work):
            pos = r.T @ np.array(c.pos)
            found.append(Connector(tuple(_r(v) for v in pos), tuple(_r(v) for v in key), c.kind))
    return tuple(sorted(found, key=lambda c: (c.axis, c.pos[1], c.pos[0], c.pos[2])))


def sockets_cached(tris: np.ndarray, studs, where: str | None = None) -> tuple[Connector, ...]:
    """`sockets_facing`, kept on disk by the part's triangles and studs and this file's digest
    (`sockets/` in the factory's cache folder, `factory.cache.kept`). Finding them is most of a
    part's first use: 0.23 s a part of the embedded library on the 2-core machine, so about 9 s
    for its 40 parts in every worker process of a build. A damaged entry is found again."""
    return kept("sockets", f"{_sockets_key(tris, studs)}.json", _read_sockets,
                lambda: sockets_facing(tris, studs, where), _rows)


def _read_sockets(data: bytes) -> tuple[Connector, ...] | None:
    """A cache entry's sockets, None unless it is a list of [pos (3 numbers), axis (3 numbers),
    'stud' or 'tube'] rows (damaged, truncated or foreign)."""
    try:
        rows = json.loads(data)
    except ValueError:
        return None
    if not isinstance(rows, list):
        return None
    out = []
    for row in rows:
        if not (isinstance(row, list) and len(row) == 3 and row[2] in ("stud", "tube")):
            return None
        pos, axis = row[0], row[1]
        if not all(isinstance(v, list) and len(v) == 3 and all(isinstance(x, float) for x in v) for v in (pos, axis)):
            return None
        out.append(Connector(tuple(pos), tuple(axis), row[2]))
    return tuple(out)


def _sockets_key(tris: np.ndarray, studs) -> str:
    # This file's digest: any change to how sockets are found makes new keys.
    h = hashlib.sha256(source_digest(__file__).encode())
    h.update(np.ascontiguousarray(tris, dtype=np.float64).tobytes())
    h.update(_rows(studs))
    return h.hexdigest()[:32]


def _rows(connectors) -> bytes:
    """Connectors as the JSON rows a cache entry holds: [pos, axis, kind] each."""
    return json.dumps([[list(c.pos), list(c.axis), c.kind] for c in connectors]).encode()


class _Buckets:
    """Triangles' footprints in the (x, z) plane as circles (centre, radius), bucketed once so a
    lookup finds those that may come within `reach` of a point without passing over the rest:
    each triangle sits in one size class (radius at most 10 * 2^k LDU), in the cell of its centre
    on a grid of that class's radius plus `reach`, so a lookup reads at most 3 x 3 cells a class.
    Memory is one entry a triangle whatever its size."""

    def __init__(self, xz: np.ndarray, radius: np.ndarray, reach: float):
        self.classes = []
        if len(xz) == 0:
            return
        k = np.ceil(np.log2(np.maximum(radius, GRID) / GRID)).astype(np.int64)
        k = np.where(GRID * 2.0 ** k < radius, k + 1, k)  # rounding of log2: radius <= 10 * 2^k
        for kk in np.unique(k):
            idx = np.flatnonzero(k == kk)
            span = GRID * 2.0 ** kk + reach
            origin = xz[idx].min(axis=0)
            cell = np.floor((xz[idx] - origin) / span).astype(np.int64)
            rows = int(cell[:, 1].max()) + 1
            key = cell[:, 0] * rows + cell[:, 1]
            order = np.argsort(key, kind="stable")
            top = cell.max(axis=0)
            self.classes.append((span, origin, rows, top, key[order], idx[order]))

    def near(self, p: np.ndarray) -> np.ndarray:
        """Indices (ascending) of the triangles whose circle may come within `reach` of p (x, z):
        all that do, and some that do not."""
        found = []
        for span, origin, rows, top, keys, idx in self.classes:
            a = np.maximum(np.floor((p - span - origin) / span).astype(np.int64), 0)
            b = np.minimum(np.floor((p + span - origin) / span).astype(np.int64), top)
            if (a > b).any():
                continue
            cx = np.arange(a[0], b[0] + 1) * rows
            lo = np.searchsorted(keys, cx + a[1], side="left")
            hi = np.searchsorted(keys, cx + b[1], side="right")
            found.extend(idx[i:j] for i, j in zip(lo, hi) if j > i)
        if not found:
            return np.zeros(0, np.int64)
        return np.sort(np.concatenate(found))


class _Underside:
    """A part's triangles made ready for probing, once per probe direction: bucketed by where they
    lie in (x, z), so a probe looks only at the triangles near it, and with each one's corner,
    edges and box, for the level-wide pass that drops spots closed below (`drop_closed`)."""

    NEAR = 14.0
    """A probe's neighbourhood: triangles whose bounding circle in (x, z) comes within this of the
    spot (the rays below reach 13.4 from it)."""

    def __init__(self, tris: np.ndarray):
        # Sorted along x, and scanned in that order: a probe's triangles are met in one order
        # whatever found them, so the same rays meet the same triangles in the same order.
        centres = tris.mean(axis=1)
        order = np.argsort(centres[:, 0], kind="stable")
        self.tris, self.centres = tris[order], centres[order]
        self.reach = np.linalg.norm(self.tris - self.centres[:, None], axis=2).max(axis=1)
        self.buckets = _Buckets(self.centres[:, [0, 2]], self.reach, self.NEAR + MARGIN)
        # For `drop_closed`: each triangle's corner and edges, and its area seen from above
        # (x, z), with whether its shape there is plain enough (no angle under about 0.06
        # degrees) that a ray's barycentric coordinates in it come out within 1e-9 of the truth,
        # here and in `first_hits` alike.
        t = self.tris
        self.a, self.e1, self.e2 = t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        den = self.e1[:, 0] * self.e2[:, 2] - self.e1[:, 2] * self.e2[:, 0]
        longest = np.maximum(self.e1[:, 0] ** 2 + self.e1[:, 2] ** 2, self.e2[:, 0] ** 2 + self.e2[:, 2] ** 2)
        self.sure = np.abs(den) > np.maximum(1e-9, 1e-3 * longest)
        self.den = np.where(self.sure, den, 1.0)
        self.box_lo, self.box_hi = t.min(axis=1)[:, [0, 2]], t.max(axis=1)[:, [0, 2]]
        self.hi_y = t[:, :, 1].max(axis=1)

    BELOW = np.concatenate([
        np.stack([_DISC[:, 0], np.full(len(_DISC), -0.05), _DISC[:, 1]], 1), _CELL])
    """Where `probe` casts its rays down from, about a spot: its opening, and its 20x20 cell."""

    def drop_closed(self, alive: np.ndarray, xs: np.ndarray, zs: np.ndarray, y0: float,
                    work: _Work) -> None:
        """Clears in `alive` (len(xs), len(zs)) the spots of rim level y0 that `probe` would turn
        down for material below, found for the whole level at once: a spot where one of the
        rays `probe` casts down surely meets a triangle (within 1e-8 of it in barycentric terms,
        where `first_hits` allows 1e-7, and in front of the ray's start by 1e-5, where it asks
        1e-6), so `probe`'s own test meets it too. Each spot tested against a triangle counts
        one, charged before it is tested."""
        rows, cols = np.flatnonzero(alive.any(axis=1)), np.flatnonzero(alive.any(axis=0))
        if not len(rows):
            return
        # The triangles that can be below a ray, near a spot left (one pass, each counts one).
        work.spend(len(self.tris))
        reach = np.abs(self.BELOW).max(axis=0) + 1e-6
        cand = np.flatnonzero(
            self.sure & (self.hi_y >= y0 - 0.05 + 1e-5)
            & (self.box_hi[:, 0] >= xs[rows[0]] - reach[0]) & (self.box_lo[:, 0] <= xs[rows[-1]] + reach[0])
            & (self.box_hi[:, 1] >= zs[cols[0]] - reach[2]) & (self.box_lo[:, 1] <= zs[cols[-1]] + reach[2]))
        for dx, dy, dz in self.BELOW:
            rows, cols = alive.any(axis=1), alive.any(axis=0)
            if not rows.any() or not len(cand):
                return
            oy = y0 + dy
            # The spots whose ray (x + dx, z + dz) lies in a triangle's box, among those alive.
            work.spend(len(cand))
            i0 = np.searchsorted(xs, self.box_lo[cand, 0] - dx - 1e-6, side="left")
            i1 = np.searchsorted(xs, self.box_hi[cand, 0] - dx + 1e-6, side="right")
            j0 = np.searchsorted(zs, self.box_lo[cand, 1] - dz - 1e-6, side="left")
            j1 = np.searchsorted(zs, self.box_hi[cand, 1] - dz + 1e-6, side="right")
            row_sum, col_sum = np.append(0, np.cumsum(rows)), np.append(0, np.cumsum(cols))
            m = (row_sum[i1] > row_sum[i0]) & (col_sum[j1] > col_sum[j0])
            k, i0, i1, j0, j1 = cand[m], i0[m], i1[m], j0[m], j1[m]
            work.spend(int(((i1 - i0) * (j1 - j0)).sum()))
            for t, i, j in _grid_pairs(i0, i1, j0, j1):
                keep = alive[i, j]
                t, i, j = k[t[keep]], i[keep], j[keep]
                sx = xs[i] + dx - self.a[t, 0]
                sz = zs[j] + dz - self.a[t, 2]
                e1, e2, den = self.e1[t], self.e2[t], self.den[t]
                u = (sx * e2[:, 2] - sz * e2[:, 0]) / den
                v = (e1[:, 0] * sz - e1[:, 2] * sx) / den
                y = self.a[t, 1] + u * e1[:, 1] + v * e2[:, 1]
                hit = (u >= -1e-8) & (v >= -1e-8) & (u + v <= 1 + 1e-8) & (y - oy >= 1e-5)
                alive[i[hit], j[hit]] = False

    def probe(self, c: np.ndarray, under_stud: bool, work: _Work) -> str | None:
        """The kind of socket at spot c (x, y, z), a point of a rim level, or None. Its rays are
        cast at the triangles near it (their bounding circle in (x, z) within `NEAR` of it), in
        the order of `tris`: the rays, the triangles and their order are those of a pass over all
        the part's triangles, so the answer is too; each stage's rays are charged as cast."""
        work.spend(PROBE_WORK)
        idx = self.buckets.near(c[[0, 2]])
        work.spend(len(idx))
        local = self.tris[idx[np.hypot(self.centres[idx, 0] - c[0], self.centres[idx, 2] - c[2])
                              <= self.reach[idx] + self.NEAR]]
        x, y0, z = c
        pts = np.stack([x + _DISC[:, 0], np.full(len(_DISC), y0), z + _DISC[:, 1]], 1)
        # Nothing below the opening, nor below the rim anywhere in the stud's 20x20 cell: the part
        # the stud belongs to fills that space (this rejects ledges inside a cavity) ...
        below = np.concatenate([pts - [0, 0.05, 0], c + _CELL])
        work.spend(len(local) * len(below))
        down = first_hits(local, below, np.tile([0.0, 1.0, 0.0], (len(below), 1)))
        if np.isfinite(down).any():
            return None
        # ... the stud's column is free ...
        work.spend(len(local) * len(pts))
        up = first_hits(local, pts + [0, 0.05, 0], np.tile(UP, (len(pts), 1)))
        if (up < STUD_HEIGHT - 0.45).any():
            return None
        # ... and it is roofed over by the part (not open sky beside it; a hollow stud above may
        # leave the centre open).
        if not np.isfinite(up).any():
            return None
        # Walls, bars or a tube hold it: count directions with a surface at the stud's radius.
        mid = c + UP * (STUD_HEIGHT / 2)
        work.spend(len(local) * len(_DIRS8))
        side = first_hits(local, np.tile(mid, (8, 1)), _DIRS8)
        touching = side <= STUD_RADIUS + 0.6
        if touching.all():
            return "tube"
        if touching.sum() >= 3 or (under_stud and _pinched(touching)):
            return "stud"
        return None


def _pinched(touching: np.ndarray) -> bool:
    """Whether the stud is held between two surfaces on opposite sides (at least 135 degrees
    apart): a tube and the wall across from it grip a stud as three walls do (the underside of a
    wheel holder plate, open towards its pins, has only its centre tube and one side wall).
    Asked only right under one of the part's own studs, where a plate's sockets are: between
    the long walls of a 1x2 tile, half a stud off its grid, two sides are no socket."""
    k = np.flatnonzero(touching)
    apart = np.abs(k[:, None] - k[None, :]) % 8
    return bool((np.minimum(apart, 8 - apart) >= 3).any())
