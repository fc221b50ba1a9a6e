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
  the part's faces within it (`faithful._refined`).

Every piece is inset by `INSET_LDU` (its faces moved inward), so mated parts that touch are not
penetrating and a penetration measured between inset pieces is a real overlap of at least
2 x INSET_LDU.

Here: a part's shape (`collision_shape`, `CollisionShape`), made of the body's pieces, decomposed
and cached on disk by `decompose` (its settings `DecompositionConfig`, coacd in a bounded child
process, `cache_dir`), made faithful by `faithful` (the faithfulness test, its ray casts in
`ray_grid`, the split along the part's faces), and the stud prisms and inset hulls of `hull`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from factory.cache import made_once
from factory.errors import LDrawLimitError
from factory.parts import Part
from factory.physics.decompose import (HULL_CELLS, DecompositionConfig, _body_mesh, _load, _save, cache_dir,
                                       decomposed_or_refused, hull_pieces)
from factory.physics.faithful import REFINED_VERSION, _refined
from factory.physics.hull import INSET_LDU, _hull_volume, inset_hull, stud_prism

__all__ = ["INSET_LDU", "MAX_COLLISION_TRIANGLES", "MIN_PIECE_LDU3", "CollisionShape", "DecompositionConfig",
           "cache_dir", "collision_shape", "inset_hull", "is_prepared", "stud_prism",
           "too_many_triangles"]

MIN_PIECE_LDU3 = 1e-3
"""Body pieces smaller than this (LDU^3) are dropped (MuJoCo refuses meshes of almost no volume)."""


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


MAX_COLLISION_TRIANGLES = 150_000
"""Triangles of a part's body (outside its studs, which become stud pieces without decomposition)
the collision decomposition takes. LDraw's library of the construction categories has at most
110,352 (39369, a Technic beam baseplate 19x11: its holes); its baseplates have tens of thousands
of triangles, all but about 80 in their studs. The decomposition's cost follows the surface's
shape more than its size, and its worst case measured here, a soup of random triangles, took 141 s
and 1.5 GB at 48,000 triangles, more than 300 s and 7.5 GB at 240,000, and was killed for memory at
24 GB at 1.2 million (in this process, before coacd). Renders and `factory.ldraw` take larger
parts."""


def too_many_triangles(part: Part) -> str | None:
    """Why the physics checks cannot take the part (more than `MAX_COLLISION_TRIANGLES` triangles
    outside its studs), or None: a property of the part, known without decomposing it."""
    body = int((~part.flat.in_stud).sum())
    if body > MAX_COLLISION_TRIANGLES:
        return (f"part {part.name} has {body:,} triangles outside its studs; the physics checks decompose parts "
                f"of at most {MAX_COLLISION_TRIANGLES:,}")
    return None


def _keys(verts: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig) -> tuple[str, str]:
    """(the decomposition's cache key, its refined pieces' key): the body mesh and the settings
    but `refine_cells`; then that key, `refine_cells` and `REFINED_VERSION`, which names how
    `_refined` works (a change to it must not reuse older entries)."""
    settings = asdict(cfg)
    refine = settings.pop("refine_cells")
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(verts).tobytes())
    h.update(np.ascontiguousarray(faces).tobytes())
    h.update(json.dumps(settings, sort_keys=True).encode())
    raw_key = h.hexdigest()[:24]
    return raw_key, hashlib.sha256(f"{raw_key}/refined/{refine}/{REFINED_VERSION}".encode()).hexdigest()[:24]


def is_prepared(part: Part, cfg: DecompositionConfig = DecompositionConfig()) -> bool:
    """Whether the part's collision pieces are in the cache already (`collision_shape` then reads
    them instead of decomposing the part)."""
    raw_key, key = _keys(*_body_mesh(part), cfg)
    return any((cache_dir() / f"{k}.npz").is_file() for k in (key, _hull_key(raw_key)))


def _hull_key(raw_key: str) -> str:
    """The cache key of the hull's pieces of a part coacd refused."""
    return hashlib.sha256(f"{raw_key}/hull/{HULL_CELLS}/{REFINED_VERSION}".encode()).hexdigest()[:24]


def _made(part: Part, verts: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig, raw_key: str,
          key: str) -> tuple[tuple[list[np.ndarray], float], str]:
    """(the part's refined pieces and inset, their cache key), made now and cached: coacd's pieces
    made faithful, or for a part coacd refuses its hull's pieces."""
    raw = _load(cache_dir() / f"{raw_key}.npz") or decomposed_or_refused(part, verts, faces, cfg, raw_key)
    if raw is not None:
        found = (_refined(part, raw[0], cfg), raw[1])
        _save(cache_dir() / f"{key}.npz", *found)
        return found, key
    # Refused by coacd: its hull's pieces, already faithful, under their own key (the refusal
    # stays, so that a wider limit tries coacd again: `decompose.hull_pieces`).
    key = _hull_key(raw_key)
    found = _load(cache_dir() / f"{key}.npz")
    if found is None:
        found = (hull_pieces(part, verts, cfg), cfg.inset_ldu)
        _save(cache_dir() / f"{key}.npz", *found)
    return found, key


def collision_shape(part: Part, cfg: DecompositionConfig = DecompositionConfig()) -> CollisionShape:
    """The part's inset collision pieces, from the disk cache or decomposed now (and cached).

    Two entries per part: the decomposition (keyed by the mesh and the settings but
    `refine_cells`), and its pieces made faithful (`_refined`, keyed by the first key and
    `refine_cells`), so that entries written before the refinement existed keep their meaning."""
    memo = part.__dict__.setdefault("_collision_shapes", {})
    if cfg in memo:
        return memo[cfg]
    too_many = too_many_triangles(part)
    if too_many:
        raise LDrawLimitError(too_many, getattr(part, "file", None))
    verts, faces = _body_mesh(part)
    raw_key, key = _keys(verts, faces, cfg)
    found = _load(cache_dir() / f"{key}.npz")
    if found is None:
        # Parts are prepared where they are first needed (a sampler's worker drawing one): two
        # processes needing one part at once make its pieces once, the second waiting.
        with made_once(cache_dir() / f"{raw_key}.lock"):
            found = _load(cache_dir() / f"{key}.npz")
            if found is None:
                found, key = _made(part, verts, faces, cfg, raw_key, key)
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
