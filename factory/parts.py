"""Parts as the rest of the project sees them: mesh, size, mass, connection points, symmetry."""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from factory.cache import kept, source_digest
from factory.connections import Connector, sockets_cached, studs_from_flat
from factory.ldraw.reader import Flat, Reader
from factory.symmetry import Symmetry, symmetry_cached

ABS_DENSITY_G_CM3 = 1.05
LDU_CM = 0.04
"""Centimetres per LDraw unit (1 LDU = 0.4 mm)."""


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """The 8 corners (8, 3) of an axis-aligned box given as [lo, hi]."""
    lo, hi = np.asarray(bounds, float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

@dataclass(frozen=True, eq=False)
class Part:
    """A library part flattened into one mesh in its own LDraw frame (LDU, -Y up)."""

    name: str
    """File name as LDraw references it, e.g. `3001.dat`."""
    description: str
    moved_to: str | None
    """The part this number was renumbered to, when the file is a `~Moved to` stub."""
    flat: Flat
    file: str | None = None
    """The file it was read from (a library file, or the model that ships it), named in errors."""

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """The part's triangles with shared vertices merged (not necessarily watertight)."""
        tris = self.flat.triangles
        verts, faces = np.unique(np.round(tris.reshape(-1, 3), 5), axis=0, return_inverse=True)
        faces = faces.reshape(-1, 3)
        keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
        return trimesh.Trimesh(vertices=verts, faces=faces[keep], process=False)

    @cached_property
    def bbox(self) -> np.ndarray:
        """[[minx, miny, minz], [maxx, maxy, maxz]] in LDU."""
        tris = self.flat.triangles
        if len(tris) == 0:
            return np.zeros((2, 3))
        pts = tris.reshape(-1, 3)
        return np.stack([pts.min(0), pts.max(0)])

    @cached_property
    def hull_points(self) -> np.ndarray:
        """The vertices of the convex hull of the part's triangles (k, 3) in LDU, rounded to 1e-6:
        the part's extent along any direction (its box is exact only along its own axes), and the
        points the density reward's hull is made of."""
        tris = np.ascontiguousarray(self.flat.triangles, dtype=np.float64)
        h = hashlib.sha256(source_digest(__file__).encode())
        h.update(tris.tobytes())
        return kept("hulls", f"{h.hexdigest()[:32]}.npy", _read_points, lambda: _hull_points(tris), _points_bytes)

    @cached_property
    def volume_ldu3(self) -> float:
        """Enclosed volume from the signed divergence sum over the outward-wound triangles.

        Exact for closed, consistently wound (BFC-certified) parts; for uncertified ones the
        winding is unknown and the magnitude is an estimate.
        """
        t = self.flat.triangles
        if len(t) == 0:
            return 0.0
        signed = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0
        # Certified parts come out positive (their winding is outward); the magnitude also serves
        # uncertified parts wound inward throughout.
        return float(abs(signed))

    @property
    def mass_g(self) -> float:
        return self.volume_ldu3 * LDU_CM**3 * ABS_DENSITY_G_CM3

    @cached_property
    def studs(self) -> tuple[Connector, ...]:
        return studs_from_flat(self.flat.studs)

    @cached_property
    def sockets(self) -> tuple[Connector, ...]:
        return sockets_cached(self.flat.triangles, self.studs, self.file or self.name)

    @cached_property
    def symmetry(self) -> Symmetry:
        return symmetry_cached(self.flat.triangles.reshape(-1, 3))

    def to_json(self) -> dict:
        out = {
            "part": self.name,
            "description": self.description,
            "bbox_ldu": np.round(self.bbox, 4).tolist(),
            "volume_ldu3": round(self.volume_ldu3, 3),
            "mass_g": round(self.mass_g, 4),
            "studs": [c.to_json(with_kind=False) for c in self.studs],
            "sockets": [c.to_json(with_kind=True) for c in self.sockets],
            "symmetry": self.symmetry.to_json(),
        }
        if self.moved_to:
            out["moved_to"] = self.moved_to
        return out


def _hull_points(tris: np.ndarray) -> np.ndarray:
    pts = np.unique(np.round(tris.reshape(-1, 3), 6), axis=0)
    try:
        return pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):
        return pts  # flat or degenerate: every point


def _points_bytes(points: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(points, dtype=np.float64), allow_pickle=False)
    return buf.getvalue()


def _read_points(data: bytes) -> np.ndarray | None:
    """A cache entry's (k, 3) points, None if it is not one (damaged, truncated, foreign)."""
    try:
        pts = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError):
        return None
    return pts if pts.ndim == 2 and pts.shape[1] == 3 and pts.dtype == np.float64 else None


def load_part(reader: Reader, name, model: str | None = None) -> Part:
    """A part by name (`3001`, `3001.dat`), flattened once per reader and cached.

    `name` may also be a placed part (`factory.ldraw.PlacedPart`): its `part` and `model`. With a
    model (its path), the name is found as `build_steps` found it: the model's MPD blocks, its
    folder, then the library; without, in the library alone. The cache is keyed by the resolved
    file, so a model's own `mybrick.dat` and the library's are different parts.
    """
    if not isinstance(name, str):
        name, model = name.part, name.model
    res = reader.part(name, model)
    cache = reader.parts
    if res.key not in cache:
        base = name if name.lower().endswith((".dat", ".ldr")) else name + ".dat"
        cache[res.key] = Part(
            name=base.replace("\\", "/").lower(),
            description=res.file.description,
            moved_to=res.file.moved_to,
            flat=reader.flatten(res),
            file=res.file.path,
        )
    return cache[res.key]
