"""Visual geometry of a part, cached per process: faces split by colour code, and outline edges.

Faces are a triangle soup (three vertices per triangle, so MuJoCo computes flat per-face normals, no
smoothing across a brick's corners), split by colour code: code 16 takes the placement colour, 24 the
placement colour's edge colour, any other code its own colour. Parts that are not BFC-certified get
every triangle twice, once per winding, so back-face culling cannot open holes in them.

Edges are the part's LDraw type 2 lines; a part without any (the embedded library draws none) gets
its feature edges instead: mesh edges where the faces meet at more than 30 degrees, plus open
boundaries. Each edge becomes a thin square prism (`prisms`), whose radius is chosen per scene from
the pixel size so the outline is about one pixel wide.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from factory.cache import kept, source_digest
from factory.errors import LDrawLimitError
from factory.parts import Part

MAX_RENDER_TRIANGLES = 250_000
"""Triangles of one part the renders take (twice that for a part that is not BFC-certified, which
gets both windings). Scenes hold every triangle on the GPU or in OSMesa's memory, and a part of a
million triangles took 67.6 s and 4.2 GB to render one step (and ended in MuJoCo's "unknown
exception" under a 4 GB address-space limit); the largest of the 4,564 official parts of
`shared/ldraw_library.zip` has 120,084 (782.dat, by `Reader.triangle_count`). A larger part is
refused in one line, naming it."""

FEATURE_ANGLE_DEG = 30.0
"""Dihedral angle above which a mesh edge counts as an outline (studs have 22.5 degree facets)."""


@dataclass(frozen=True)
class PartGeometry:
    name: str
    groups: tuple[tuple[int, np.ndarray], ...]
    """(colour code, (n, 3, 3) triangles in LDU), code 16 first when present."""
    edges: np.ndarray
    """(m, 2, 3) outline segments in LDU, deduplicated."""
    vertices: np.ndarray
    """(k, 3) distinct vertices in LDU (for exact bounds of a placed part)."""


def _degenerate(tris: np.ndarray) -> np.ndarray:
    area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    return area2 < 1e-9


def _dedupe_segments(seg: np.ndarray) -> np.ndarray:
    if len(seg) == 0:
        return np.zeros((0, 2, 3))
    r = np.round(seg, 3)
    a, b = r[:, 0], r[:, 1]
    first = (a[:, 0] < b[:, 0]) | ((a[:, 0] == b[:, 0]) & ((a[:, 1] < b[:, 1]) | ((a[:, 1] == b[:, 1]) & (a[:, 2] <= b[:, 2]))))
    canon = np.where(first[:, None, None], r, r[:, ::-1])
    keep = np.linalg.norm(canon[:, 1] - canon[:, 0], axis=1) > 1e-6
    canon = canon[keep]
    _, idx = np.unique(canon.reshape(len(canon), 6), axis=0, return_index=True)
    return canon[np.sort(idx)]


def feature_edges(part: Part, angle_deg: float = FEATURE_ANGLE_DEG) -> np.ndarray:
    """Mesh edges with a dihedral angle above `angle_deg`, and boundary edges, as (m, 2, 3) LDU."""
    mesh = part.mesh
    if len(mesh.faces) == 0:
        return np.zeros((0, 2, 3))
    v = mesh.vertices
    sharp = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(angle_deg)]
    edges = np.sort(mesh.edges, axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[counts == 1]
    idx = np.concatenate([sharp, boundary]) if len(boundary) else sharp
    return v[idx]


@lru_cache(maxsize=4096)
def part_geometry(part: Part) -> PartGeometry:
    """The part's visual geometry (computed once per Part object; parts hash by identity); a part
    over `MAX_RENDER_TRIANGLES` is an `LDrawLimitError`."""
    flat = part.flat
    if len(flat.triangles) > MAX_RENDER_TRIANGLES:
        raise LDrawLimitError(f"part {part.name} has {len(flat.triangles):,} triangles; renders take parts of at "
                              f"most {MAX_RENDER_TRIANGLES:,}", getattr(part, "file", None))
    tris = np.asarray(flat.triangles, dtype=np.float64)
    codes = np.asarray(flat.colours)
    ok = ~_degenerate(tris) if len(tris) else np.zeros(0, bool)
    tris, codes = tris[ok], codes[ok]
    if not flat.certified:
        tris = np.concatenate([tris, tris[:, ::-1]])
        codes = np.concatenate([codes, codes])
    order = sorted(set(codes.tolist()), key=lambda c: (c != 16, c))
    groups = tuple((int(c), tris[codes == c]) for c in order)
    edges = np.asarray(flat.edges, dtype=np.float64)
    if len(edges) == 0:
        edges = feature_edges(part)
    verts = np.unique(np.round(tris.reshape(-1, 3), 4), axis=0) if len(tris) else np.zeros((0, 3))
    return PartGeometry(part.name, groups, _dedupe_segments(edges), verts)


def prisms(segments: np.ndarray, radius: float) -> np.ndarray:
    """Thin triangular prisms around segments, as (6m, 3, 3) triangles wound outward, in LDU.

    The cross-section is an equilateral triangle with circumradius `radius` (so the prism shows
    1.5 to 1.73 `radius` wide from any side); each prism is lengthened by `radius` at both ends so
    the outlines of a corner meet. No end caps: a segment seen end-on is a point anyway. Three
    sides, not four: edges are most of a scene's triangles, and each costs raster time.
    """
    if len(segments) == 0 or radius <= 0:
        return np.zeros((0, 3, 3))
    a, b = segments[:, 0], segments[:, 1]
    d = b - a
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    helper = np.eye(3)[np.argmin(np.abs(d), axis=1)]
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    a = a - d * radius
    b = b + d * radius
    angles = np.radians([90.0, 210.0, 330.0])
    corners = (np.cos(angles)[None, :, None] * u[:, None] + np.sin(angles)[None, :, None] * v[:, None]) * radius
    tris = []
    for k in range(3):
        c0, c1 = corners[:, k], corners[:, (k + 1) % 3]
        p00, p01, p10, p11 = a + c0, a + c1, b + c0, b + c1
        tris.append(np.stack([p00, p01, p11], axis=1))
        tris.append(np.stack([p00, p11, p10], axis=1))
    out = np.stack(tris, axis=1)  # (m, 6, 3, 3)
    # Wind each side outward: its normal must point away from the segment's axis.
    n = np.cross(out[:, :, 1] - out[:, :, 0], out[:, :, 2] - out[:, :, 0])
    centre = out.mean(axis=2) - (a[:, None] + b[:, None]) / 2
    outward = centre - np.einsum("mkj,mj->mk", centre, d)[..., None] * d[:, None]
    flip = np.einsum("mkj,mkj->mk", n, outward) < 0
    out[flip] = out[flip][:, ::-1]
    return out.reshape(-1, 3, 3)


def simplify_edges(segments: np.ndarray, tolerance: float) -> np.ndarray:
    """Fewer segments for the same outline: chain segments into polylines (through vertices where
    exactly two segments meet) and drop points within `tolerance` LDU of the chord (Douglas-Peucker).

    Stud and tube circles are drawn with 16 segments; at a render's pixel size most of those points
    are invisible, and every segment costs raster time. Corners (deviating more) are kept.
    """
    if len(segments) < 2 or tolerance <= 0:
        return segments
    pts = segments.reshape(-1, 3)
    keys, inverse = np.unique(np.round(pts, 3), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1, 2)
    nv = len(keys)
    adj: list[list[int]] = [[] for _ in range(nv)]
    for e, (i, j) in enumerate(inverse.tolist()):
        adj[i].append(e)
        adj[j].append(e)
    used = np.zeros(len(inverse), bool)
    chains: list[list[int]] = []

    def walk(start: int, edge: int) -> list[int]:
        chain = [start]
        v = start
        while True:
            used[edge] = True
            a, b = inverse[edge]
            v = b if a == v else a
            chain.append(v)
            if len(adj[v]) != 2:
                return chain
            nxt = adj[v][0] if adj[v][0] != edge else adj[v][1]
            if used[nxt]:
                return chain
            edge = nxt

    for v in range(nv):
        if len(adj[v]) != 2:
            for e in adj[v]:
                if not used[e]:
                    chains.append(walk(v, e))
    for e in range(len(inverse)):  # closed loops: every vertex has two segments
        if not used[e]:
            chains.append(walk(int(inverse[e][0]), e))

    out = []
    for chain in chains:
        p = keys[chain]
        keep = _douglas_peucker(p, tolerance)
        q = p[keep]
        out.append(np.stack([q[:-1], q[1:]], 1))
    res = np.concatenate(out) if out else np.zeros((0, 2, 3))
    return res[np.linalg.norm(res[:, 1] - res[:, 0], axis=1) > 1e-9]


def _douglas_peucker(p: np.ndarray, tol: float) -> np.ndarray:
    """Indices of the points of polyline `p` to keep (a closed loop is split at its far point)."""
    n = len(p)
    if n <= 2:
        return np.arange(n)
    keep = np.zeros(n, bool)
    keep[0] = keep[-1] = True
    if np.allclose(p[0], p[-1]):
        far = int(np.argmax(((p - p[0]) ** 2).sum(1)))
        keep[far] = True
        stack = [(0, far), (far, n - 1)]
    else:
        stack = [(0, n - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = p[i], p[j]
        ab = b - a
        L = float(np.sqrt(ab @ ab))
        rel = p[i + 1 : j] - a
        d2 = (rel * rel).sum(1)
        if L > 1e-12:
            along = rel @ (ab / L)
            d2 = d2 - along * along
        d = np.sqrt(np.maximum(d2, 0.0))
        k = int(np.argmax(d))
        if d[k] > tol:
            keep[i + 1 + k] = True
            stack += [(i, i + 1 + k), (i + 1 + k, j)]
    return np.nonzero(keep)[0]


SIMPLIFY = 0.6
"""Outline simplification tolerance, as a fraction of the edge radius (about half a pixel)."""


@lru_cache(maxsize=2048)
def outline_mesh(part: Part, radius: float) -> np.ndarray:
    """The part's outline prisms for an edge radius (LDU), simplified to about half a pixel."""
    return prisms(simplified_edges(part_geometry(part).edges, SIMPLIFY * radius), radius)


def simplified_edges(segments: np.ndarray, tolerance: float) -> np.ndarray:
    """`simplify_edges`, kept on disk by the segments, the tolerance and this file's digest
    (`outlines/` in the factory's cache folder, `factory.cache.kept`). Its polyline walk and
    Douglas-Peucker run in Python: on a lent H200, 4.2 s of a 4-object build's 33 s of render
    stage in one process, once per part and edge radius met, and every worker process of a build
    met them anew."""
    segments = np.ascontiguousarray(segments, dtype=np.float64)
    h = hashlib.sha256(source_digest(__file__).encode())  # a change to the simplification: new keys
    h.update(repr(float(tolerance)).encode())
    h.update(np.asarray(segments.shape, np.int64).tobytes())
    h.update(segments.tobytes())
    return kept("outlines", f"{h.hexdigest()[:32]}.npy", _read_segments,
                lambda: simplify_edges(segments, tolerance), _npy)


def _read_segments(data: bytes) -> np.ndarray | None:
    """A kept entry's (m, 2, 3) float64 segments, None when damaged or foreign."""
    try:
        a = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, EOFError, OSError):
        return None
    if not isinstance(a, np.ndarray) or a.dtype != np.float64 or a.ndim != 3 or a.shape[1:] != (2, 3):
        return None
    return a


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a, dtype=np.float64), allow_pickle=False)
    return buf.getvalue()
