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
"""Most triangle tests socket finding may spend on one part (all probe directions together): each
ray tested against a triangle counts one (charged for all of a probe's 50 rays before they are
cast), and so does each triangle a probe scans for its neighbourhood or its rim. Measured on the
project's 2-core machine (shared) at 45-120 ns a test: the largest parts of the real LDraw subset
need about 2 x 10^7 (41539.dat, 7,804 triangles, 2.0 x 10^7 tests, 0.8-1.6 s; 74323.dat, 10,089
triangles, 2.0 x 10^7, 0.9-2.3 s), and a generated part of 128,000 triangles in 20 underside levels
is refused after 7-9 s at 164 MB. Five times the largest real need, so it refuses in seconds, not minutes:
without it a part of 12,000 triangles took 25 s and one of 1.2 million ran past a minute at 3.4 GB
(the reader's 2,000,000-triangle cap bounds a part's size, not this work)."""

CHUNK_PAIRS = 1 << 16
"""Ray-triangle pairs tested in one numpy batch: a dozen temporaries of this many 3-vectors (1.5 MB
each), so memory stays bounded whatever the part's triangle count."""


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
                f"{MAX_SOCKET_WORK:,} ray-triangle tests; refusing it (the largest parts of the real "
                "LDraw subset need about 20,000,000)", self.where)


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
    p = np.cross(d, e2[None])
    det = np.einsum("rtk,tk->rt", p, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - v0[None]
    u = np.einsum("rtk,rtk->rt", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rtk,rtk->rt", np.broadcast_to(d, q.shape), q) * inv
    t = np.einsum("rtk,tk->rt", q, e2) * inv
    eps = 1e-7
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 1e-6)
    t = np.where(hit, t, np.inf)
    return t.min(axis=1)


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
    """Distance from point p (2,) to each triangle (n, 3, 2) in the plane; 0 inside."""
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
    part's probe directions) an `LDrawLimitError` naming `where` (the part's file)."""
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
    centres = tris.mean(axis=1)
    reach = np.linalg.norm(tris - centres[:, None], axis=2).max(axis=1)
    # Sorted along x, so a probe scans only the triangles whose centres lie within reach in x.
    order = np.argsort(centres[:, 0], kind="stable")
    tris, centres, reach, facing = tris[order], centres[order], reach[order], facing[order]
    widest = float(reach.max())
    xs = np.arange(np.ceil((lo[0] + STUD_RADIUS) / GRID), np.floor((hi[0] - STUD_RADIUS) / GRID) + 1) * GRID
    zs = np.arange(np.ceil((lo[2] + STUD_RADIUS) / GRID), np.floor((hi[2] - STUD_RADIUS) / GRID) + 1) * GRID
    found: list[Connector] = []
    rim = tris[facing]
    rim_y = np.round(rim[:, 0, 1], 3)
    for y0 in levels:
        at_level = rim[rim_y == y0]
        if len(at_level) == 0:
            continue
        for x in xs:
            for z in zs:
                under = bool(len(columns)) and bool((np.abs(columns - [x, z]).max(axis=1) < 1e-3).any())
                kind = _probe(tris, centres, reach, at_level, np.array([x, y0, z]), under, work, widest)
                if kind:
                    found.append(Connector((_r(x), _r(y0), _r(z)), tuple(UP.tolist()), kind))
    return tuple(sorted(found, key=lambda c: (c.pos[1], c.pos[0], c.pos[2])))


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


def _probe(tris, centres, reach, rim, c, under_stud: bool = False, work: _Work | None = None,
           widest: float | None = None) -> str | None:
    work = work if work is not None else _Work(None, len(tris))
    work.spend(len(rim))
    widest = float(reach.max()) if widest is None else widest
    # A rim face at this level must touch the stud: the opening is the end of the material
    # around it (a ledge further from the stud, such as a rib inside a cavity, is not).
    rim_d = _distance_2d(rim[:, :, [0, 2]], c[[0, 2]]).min()
    if rim_d > STUD_RADIUS + 1.0:
        return None
    # Triangles sorted by centre x (`find_sockets`): only those within the widest reach in x can
    # be near, and only those are scanned (and charged).
    span = widest + 14.0
    a = int(np.searchsorted(centres[:, 0], c[0] - span, side="left"))
    b = int(np.searchsorted(centres[:, 0], c[0] + span, side="right"))
    work.spend(b - a)
    near = np.hypot(centres[a:b, 0] - c[0], centres[a:b, 2] - c[2]) <= reach[a:b] + 14.0
    local = tris[a:b][near]
    # Every ray below is tested against every local triangle: charged before it is cast.
    work.spend(len(local) * (len(_DISC) + len(_CELL) + len(_DISC) + len(_DIRS8)))
    pts = np.stack([c[0] + _DISC[:, 0], np.full(len(_DISC), c[1]), c[2] + _DISC[:, 1]], 1)
    # Nothing below the opening, nor below the rim anywhere in the stud's 20x20 cell: the part
    # the stud belongs to fills that space (this rejects ledges inside a cavity) ...
    below = np.concatenate([pts - [0, 0.05, 0], c + _CELL])
    down = first_hits(local, below, np.tile([0.0, 1.0, 0.0], (len(below), 1)))
    if np.isfinite(down).any():
        return None
    # ... the stud's column is free ...
    up = first_hits(local, pts + [0, 0.05, 0], np.tile(UP, (len(pts), 1)))
    if (up < STUD_HEIGHT - 0.45).any():
        return None
    # ... and it is roofed over by the part (not open sky beside it; a hollow stud above may
    # leave the centre open).
    if not np.isfinite(up).any():
        return None
    # Walls, bars or a tube hold it: count directions with a surface at the stud's radius.
    mid = c + UP * (STUD_HEIGHT / 2)
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
