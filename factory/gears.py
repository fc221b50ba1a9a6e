"""Gear teeth, found from a part's own drawing, and whether two placed gears mesh.

A gear's outline seen along its hole's axis rises and falls: the tips of its teeth on one circle,
the roots between them on a smaller one (`Teeth`). LEGO's Technic gears are cut to one module:
their pitch radius is 1.25 LDU a tooth (8 teeth: 10 LDU; 40: 50), their tips reach about 2 LDU
past it, and they mesh on parallel axes as far apart as their pitch radii add up (an 8 and a 24
tooth gear 40 LDU apart). Designs draw both gears at their
catalogue turn, so drawn teeth often stand in each other's way where the real ones, turned by
half a tooth, interleave. The checks leave the overlap of two meshing gears out (`meshes`): their
tooth rings meet and their solid hubs do not. Bevel, crown and worm gears meeting at right angles
are not recognised yet: their overlap stays a collision.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from factory.joints import part_connectors

HOLE_KINDS = ("pin-hole", "axle-hole", "bush", "wheel-pin-hole")
"""The connectors a gear turns about: the hole its axle or pin goes through."""

PROFILE_BINS = 720
"""Angular bins of the outline (half a degree each): a 40 tooth gear's tooth spans 18."""
SAMPLE_LDU = 0.25
"""How densely the outline is sampled along the drawing's edges."""
MIN_TEETH = 6
"""Fewer rises round an axis are a part's arms or lobes (a beam, a cam), not teeth."""
TOOTH_DEPTH_LDU = (4.0, 8.0)
"""How deep a tooth may be from root to tip: Technic gears' are 4.7 to 7 LDU; the ribs of a bush
(3), the spokes of a wheel rim (3.2) and a beam's outline round one of its holes (18 and more) are
not teeth."""
PITCH_PER_TOOTH_LDU = 1.25
"""A Technic gear's pitch radius per tooth (8 teeth: 10 LDU, half a stud), which is what makes
gears mesh on holes a half stud apart."""
ADDENDUM_LDU = (1.0, 3.0)
"""How far past the pitch circle a Technic gear's tips reach (1.8 to 2.5 LDU drawn): teeth of
another pitch (a tread sprocket's, a rim's spokes) are not the module's, and do not mesh with it."""
EVEN = 0.2
"""How far (a share of the mean) the spacing of the teeth may vary: teeth are evenly spaced."""
PARALLEL_COS = float(np.cos(np.radians(5.0)))
"""Axes within 5 degrees of parallel mesh as spur gears."""
MESH_TOL_LDU = 0.5
"""How far the hubs (inside the root circles) may reach into each other for two gears to mesh:
the checks' overlap tolerance."""


@dataclass(frozen=True)
class Teeth:
    """A ring of teeth about one of a part's hole axes, in the part's LDraw frame (LDU)."""

    centre: tuple[float, float, float]
    """A point on the axis."""
    axis: tuple[float, float, float]
    """The axis (unit)."""
    count: int
    """How many teeth."""
    tip: float
    """The tip circle's radius."""
    root: float
    """The radius inside which the part is whole all round (the roots between teeth)."""
    along: tuple[float, float]
    """The stretch of the axis (from `centre`) the teeth span."""


def _edge_points(tris: np.ndarray) -> np.ndarray:
    """Points every `SAMPLE_LDU` along each edge of each triangle."""
    out = [tris.reshape(-1, 3)]
    for a, b in ((0, 1), (1, 2), (2, 0)):
        p, q = tris[:, a], tris[:, b]
        n = np.ceil(np.linalg.norm(q - p, axis=1) / SAMPLE_LDU).astype(np.int64)
        for k in np.unique(n[n > 1]):
            sel = n == k
            t = (np.arange(1, k) / k)[None, :, None]
            out.append((p[sel, None] + (q[sel] - p[sel])[:, None] * t).reshape(-1, 3))
    return np.concatenate(out)


def _basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(u, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.5:
        e1 = np.cross(u, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def _ring(points: np.ndarray, centre: np.ndarray, u: np.ndarray) -> Teeth | None:
    """The teeth round the axis through `centre` along `u`, None where the outline is not toothed."""
    rel = points - centre
    along = rel @ u
    radial = rel - along[:, None] * u
    rho = np.linalg.norm(radial, axis=1)
    e1, e2 = _basis(u)
    bins = ((np.arctan2(radial @ e2, radial @ e1) + np.pi) / (2 * np.pi) * PROFILE_BINS).astype(np.int64) % PROFILE_BINS
    outline = np.full(PROFILE_BINS, -1.0)
    np.maximum.at(outline, bins, rho)
    if (outline < 0).any():
        return None  # the drawing does not go all round this axis
    tip, root = float(outline.max()), float(outline.min())
    if not TOOTH_DEPTH_LDU[0] <= tip - root <= TOOTH_DEPTH_LDU[1]:
        return None
    high = outline >= (tip + root) / 2
    starts = np.flatnonzero(high & ~np.roll(high, 1))
    if len(starts) < MIN_TEETH:
        return None
    gaps = np.diff(np.r_[starts, starts[0] + PROFILE_BINS])
    addendum = tip - PITCH_PER_TOOTH_LDU * len(starts)
    if not ADDENDUM_LDU[0] <= addendum <= ADDENDUM_LDU[1] or gaps.std() > EVEN * gaps.mean():
        return None
    ring = along[rho >= (tip + root) / 2]
    return Teeth(tuple(float(v) for v in centre), tuple(float(v) for v in u), len(starts), round(tip, 4),
                 round(root, 4), (round(float(ring.min()), 4), round(float(ring.max()), 4)))


@lru_cache(maxsize=None)
def part_teeth(part) -> tuple[Teeth, ...]:
    """The part's rings of teeth, one per distinct hole axis that has one (none: not a gear)."""
    holes = [c for c in part_connectors(part) if c.kind in HOLE_KINDS]
    if not holes:
        return ()
    centre = np.asarray(part.bbox, float).mean(0)
    points = None
    out: list[Teeth] = []
    lines: list[tuple[np.ndarray, np.ndarray]] = []
    for c in holes:
        u, o = np.asarray(c.axis, float), np.asarray(c.start, float)
        off = centre - o
        if np.linalg.norm(off - (off @ u) * u) > TOOTH_DEPTH_LDU[1]:
            # A gear's teeth ring its part: a hole far off the middle of the part's box is not a
            # gear's (a Technic panel's hundreds of holes would each cost a pass over its outline).
            continue
        if points is None:
            points = _edge_points(np.asarray(part.flat.triangles, float))
        d = [o - w for _, w in lines]
        if any(abs(u @ v) > PARALLEL_COS and np.linalg.norm(x - (x @ v) * v) < MESH_TOL_LDU
               for (v, _), x in zip(lines, d)):
            continue  # the same axis as a hole seen before
        lines.append((u, o))
        ring = _ring(points, o, u)
        if ring is not None:
            out.append(ring)
    return tuple(out)


def _placed(t: Teeth, pose) -> tuple[np.ndarray, np.ndarray]:
    return pose.apply(np.asarray(t.centre)[None])[0], pose.R @ np.asarray(t.axis)


def meshes(a, a_pose, b, b_pose) -> bool:
    """Whether parts `a` and `b`, placed (`factory.pose.Pose`), are gears that mesh: rings of teeth
    on parallel axes, their teeth side by side along the axes, the tips of each reaching past the
    other's roots and the hubs inside the roots clear of each other. Their overlap is then the
    teeth's, which a turn of either gear by part of a tooth removes."""
    for s in part_teeth(a):
        ca, ua = _placed(s, a_pose)
        for t in part_teeth(b):
            cb, ub = _placed(t, b_pose)
            if abs(ua @ ub) < PARALLEL_COS:
                continue
            d = cb - ca
            apart = float(np.linalg.norm(d - (d @ ua) * ua))
            if not s.root + t.root - MESH_TOL_LDU <= apart < s.tip + t.tip:
                continue
            # The stretches of the shared axis direction the two rings span.
            lo_a, hi_a = sorted(float(ca @ ua) + np.array(s.along))
            along_b = float(cb @ ua) + np.sign(ub @ ua) * np.array(t.along)
            lo_b, hi_b = sorted(along_b)
            if min(hi_a, hi_b) > max(lo_a, lo_b):
                return True
    return False
