"""Closed-surface emitters for the generated LDraw geometry.

Coordinates are LDraw's: x right, y down (so "up" is -y), z toward the viewer, right-handed.
Every emitter states which way is out of the material for each face it adds; `Mesh.face` turns
the polygon so its right-hand (counter-clockwise) normal points that way, which is what
`0 BFC CERTIFY CCW` promises. Each emitter produces a closed solid: parts are unions of closed
solids that may touch along faces but never overlap, so the signed divergence sum of a part is its
material volume.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

SEGMENTS = 16
"""Segments per full circle, as in LDraw's 4-4*.dat primitives."""

DECIMALS = 4

Point = tuple[float, float, float]
Profile = Sequence[tuple[float, float]]
"""A convex polygon in the (z, y) plane, extruded along x."""


def fmt(v: float) -> str:
    """A number as LDraw text: at most 4 decimals, no trailing zeros, no '-0'."""
    s = f"{v:.{DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def circle(r: float, cx: float = 0.0, cz: float = 0.0) -> list[tuple[float, float]]:
    """(x, z) of a 16-gon of circumradius r, starting at +x and turning toward +z, like 4-4edge."""
    return [
        (cx + r * math.cos(2 * math.pi * k / SEGMENTS), cz + r * math.sin(2 * math.pi * k / SEGMENTS))
        for k in range(SEGMENTS)
    ]


def _sub(a: Point, b: Point) -> Point:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _normal(pts: Sequence[Point]) -> Point:
    """Newell's normal of a polygon (length = twice its area)."""
    nx = ny = nz = 0.0
    for i, a in enumerate(pts):
        b = pts[(i + 1) % len(pts)]
        nx += (a[1] - b[1]) * (a[2] + b[2])
        ny += (a[2] - b[2]) * (a[0] + b[0])
        nz += (a[0] - b[0]) * (a[1] + b[1])
    return (nx, ny, nz)


class Mesh:
    """Triangles and quads with outward CCW winding, written as type 3/4 lines."""

    def __init__(self) -> None:
        self.faces: list[tuple[Point, ...]] = []

    def face(self, pts: Sequence[Point], outward: Point) -> None:
        """Add a planar convex polygon, turned so its normal points along `outward`.

        Points are rounded to the precision they are written with; repeated points (a side of
        zero height) are dropped, and polygons of more than four corners are fanned.
        """
        clean: list[Point] = []
        for p in pts:
            q = tuple(round(c, DECIMALS) + 0.0 for c in p)
            if not clean or q != clean[-1]:
                clean.append(q)  # type: ignore[arg-type]
        while len(clean) > 1 and clean[0] == clean[-1]:
            clean.pop()
        if len(clean) < 3:
            return
        n = _normal(clean)
        if n[0] * outward[0] + n[1] * outward[1] + n[2] * outward[2] < 0:
            clean.reverse()
        if len(clean) <= 4:
            self.faces.append(tuple(clean))
        else:
            for i in range(1, len(clean) - 1):
                self.faces.append((clean[0], clean[i], clean[i + 1]))

    def lines(self, colour: int = 16) -> list[str]:
        return [
            f"{len(f)} {colour} " + " ".join(fmt(c) for p in f for c in p) for f in self.faces
        ]


def _edge_outward(a: tuple[float, float], b: tuple[float, float], centre: tuple[float, float]) -> Point:
    """Outward normal (x=0) of a profile edge a-b of a convex profile with the given centroid."""
    dz, dy = b[0] - a[0], b[1] - a[1]
    nz, ny = dy, -dz
    mz, my = (a[0] + b[0]) / 2 - centre[0], (a[1] + b[1]) / 2 - centre[1]
    if nz * mz + ny * my < 0:
        nz, ny = -nz, -ny
    return (0.0, ny, nz)


def _centroid(profile: Profile) -> tuple[float, float]:
    return (sum(p[0] for p in profile) / len(profile), sum(p[1] for p in profile) / len(profile))


def _bottom_span(profile: Profile, bottom: float) -> tuple[float, float]:
    zs = [z for z, y in profile if y == bottom]
    if len(zs) != 2:
        raise ValueError(f"profile {profile} needs exactly one edge on y={bottom}")
    return min(zs), max(zs)


def _prism_surfaces(
    mesh: Mesh, profile: Profile, half_x: float, bottom: float, sign: float
) -> None:
    """Sides and end caps of a profile extruded over x in [-half_x, half_x], except its bottom.

    sign=+1: the material is inside the prism; sign=-1: the prism is a cavity in material.
    """
    c = _centroid(profile)
    for i, a in enumerate(profile):
        b = profile[(i + 1) % len(profile)]
        if a[1] == bottom and b[1] == bottom:
            continue
        o = _edge_outward(a, b, c)
        mesh.face(
            [(-half_x, a[1], a[0]), (half_x, a[1], a[0]), (half_x, b[1], b[0]), (-half_x, b[1], b[0])],
            (0.0, sign * o[1], sign * o[2]),
        )
    for x in (-half_x, half_x):
        mesh.face([(x, y, z) for z, y in profile], (sign * x, 0.0, 0.0))


def hollow_prism(
    mesh: Mesh, outer: Profile, half_x: float, cavity: Profile, cavity_half_x: float, bottom: float
) -> None:
    """A shell: `outer` extruded along x, minus `cavity` extruded along x, open at y=bottom.

    Both profiles are convex, in (z, y), and have one edge on y=bottom; the bottom face is the
    rim between the outer and cavity outlines. A box brick is two rectangles.
    """
    _prism_surfaces(mesh, outer, half_x, bottom, +1.0)
    _prism_surfaces(mesh, cavity, cavity_half_x, bottom, -1.0)
    z0, z1 = _bottom_span(outer, bottom)
    iz0, iz1 = _bottom_span(cavity, bottom)
    ox, ix = half_x, cavity_half_x
    outer_ring = [(-ox, z0), (ox, z0), (ox, z1), (-ox, z1)]
    inner_ring = [(-ix, iz0), (ix, iz0), (ix, iz1), (-ix, iz1)]
    for i in range(4):
        (ax, az), (bx, bz) = outer_ring[i], outer_ring[(i + 1) % 4]
        (cx, cz), (dx, dz) = inner_ring[(i + 1) % 4], inner_ring[i]
        mesh.face(
            [(ax, bottom, az), (bx, bottom, bz), (cx, bottom, cz), (dx, bottom, dz)], (0.0, 1.0, 0.0)
        )


def box(mesh: Mesh, x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> None:
    """A solid axis-aligned box from (x0, y0, z0) to (x1, y1, z1)."""
    for axis in range(3):
        lo, hi = ((x0, x1), (y0, y1), (z0, z1))[axis]
        u, v = [((x0, x1), (y0, y1), (z0, z1))[a] for a in range(3) if a != axis]
        for value, sign in ((lo, -1.0), (hi, 1.0)):
            pts = []
            for a, b in ((u[0], v[0]), (u[1], v[0]), (u[1], v[1]), (u[0], v[1])):
                p = [a, b]
                p.insert(axis, value)
                pts.append(tuple(p))
            mesh.face(pts, tuple(sign if a == axis else 0.0 for a in range(3)))


Height = Callable[[float, float], float]


def cylinder(
    mesh: Mesh,
    r: float,
    top: float | Height,
    bottom: float,
    r_inner: float | None = None,
    cx: float = 0.0,
    cz: float = 0.0,
    caps: tuple[bool, bool] = (True, True),
) -> None:
    """A closed 16-sided cylinder (or tube, with r_inner) about a vertical axis at (cx, cz).

    It spans y from `top` to `bottom` (bottom > top: y is down). `top` may be a function of
    (x, z) giving the height of a surface the cylinder is cut by, such as a sloped ceiling that is
    planar over each 22.5 degree sector. `caps` = (top, bottom) says which ends are closed; an
    open end must be closed by another piece with the same rim.
    """
    h: Height = top if callable(top) else (lambda x, z, t=top: t)
    outer = circle(r, cx, cz)
    rings = [outer] + ([circle(r_inner, cx, cz)] if r_inner else [])
    for ring, side in zip(rings, (1.0, -1.0)):
        for k in range(SEGMENTS):
            (ax, az), (bx, bz) = ring[k], ring[(k + 1) % SEGMENTS]
            mx, mz = (ax + bx) / 2 - cx, (az + bz) / 2 - cz
            mesh.face(
                [(ax, bottom, az), (bx, bottom, bz), (bx, h(bx, bz), bz), (ax, h(ax, az), az)],
                (side * mx, 0.0, side * mz),
            )
    for k in range(SEGMENTS):
        (ax, az), (bx, bz) = outer[k], outer[(k + 1) % SEGMENTS]
        if r_inner:
            (cx2, cz2), (dx, dz) = rings[1][(k + 1) % SEGMENTS], rings[1][k]
            top_pts = [(ax, az), (bx, bz), (cx2, cz2), (dx, dz)]
        else:
            top_pts = [(ax, az), (bx, bz), (cx, cz)]
        if caps[0]:
            mesh.face([(x, h(x, z), z) for x, z in top_pts], (0.0, -1.0, 0.0))
        if caps[1]:
            mesh.face([(x, bottom, z) for x, z in top_pts], (0.0, 1.0, 0.0))


def prism(
    mesh: Mesh, polygon: Sequence[tuple[float, float]], axis: int, lo: float, hi: float
) -> None:
    """A convex polygon extruded along coordinate `axis` (0 x, 1 y, 2 z) from `lo` to `hi`.

    The polygon's points are in the other two coordinates, in increasing order ((y, z) along x,
    (x, z) along y, (x, y) along z), in either turning direction. A box is a rectangle; the slabs
    of an arch's curved wall and the pieces of a part's outline that no box fits are others.
    """

    def point(u: float, v: float, w: float) -> Point:
        p = [u, v]
        p.insert(axis, w)
        return (p[0], p[1], p[2])

    def along(sign: float) -> Point:
        return (sign if axis == 0 else 0.0, sign if axis == 1 else 0.0, sign if axis == 2 else 0.0)

    cu = sum(u for u, _ in polygon) / len(polygon)
    cv = sum(v for _, v in polygon) / len(polygon)
    for i, (au, av) in enumerate(polygon):
        bu, bv = polygon[(i + 1) % len(polygon)]
        # The edge's normal in the polygon's plane, turned away from the centroid.
        nu, nv = bv - av, au - bu
        if nu * ((au + bu) / 2 - cu) + nv * ((av + bv) / 2 - cv) < 0:
            nu, nv = -nu, -nv
        mesh.face(
            [point(au, av, lo), point(bu, bv, lo), point(bu, bv, hi), point(au, av, hi)],
            point(nu, nv, 0.0),
        )
    mesh.face([point(u, v, lo) for u, v in polygon], along(-1.0))
    mesh.face([point(u, v, hi) for u, v in polygon], along(1.0))


def lathe(mesh: Mesh, profile: Profile, cx: float = 0.0, cz: float = 0.0) -> None:
    """A closed solid of revolution about a vertical axis at (cx, cz): `profile`, a simple polygon
    in (r, y) with r >= 0 (either turning direction, convex or not), swept round the 16-gon.

    Each profile edge sweeps a ring of 16 planar faces (trapezoids; triangles where it ends on the
    axis): a cone or cylinder for a sloped or vertical edge, a flat ring for a horizontal one. A
    cone 1 x 1 is one profile: its slope, the ledge over its base and the bores inside it.
    """
    area2 = sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(profile, [*profile[1:], profile[0]]))
    turn = 1.0 if area2 > 0 else -1.0
    rings = [circle(r, cx, cz) for r, _ in profile]
    unit = circle(1.0)
    for i, (r0, y0) in enumerate(profile):
        j = (i + 1) % len(profile)
        r1, y1 = profile[j]
        # Out of the material, in (r, y): the edge's direction turned a quarter away from the inside.
        nr, ny = turn * (y1 - y0), -turn * (r1 - r0)
        for k in range(SEGMENTS):
            k1 = (k + 1) % SEGMENTS
            mx, mz = unit[k][0] + unit[k1][0], unit[k][1] + unit[k1][1]
            (ax, az), (bx, bz) = rings[i][k], rings[i][k1]
            (cx1, cz1), (dx, dz) = rings[j][k1], rings[j][k]
            mesh.face([(ax, y0, az), (bx, y0, bz), (cx1, y1, cz1), (dx, y1, dz)], (nr * mx, ny, nr * mz))


def _clip(polygon: list[tuple[float, float]], n: tuple[float, float], p0: tuple[float, float]):
    """The part of a convex polygon where (p - p0) . n >= 0 (Sutherland-Hodgman, one edge)."""
    def side(p: tuple[float, float]) -> float:
        return (p[0] - p0[0]) * n[0] + (p[1] - p0[1]) * n[1]

    out: list[tuple[float, float]] = []
    for i, a in enumerate(polygon):
        b = polygon[(i + 1) % len(polygon)]
        sa, sb = side(a), side(b)
        if sa >= 0:
            out.append(a)
        if (sa > 0 > sb) or (sa < 0 < sb):
            t = sa / (sa - sb)
            out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
    clean: list[tuple[float, float]] = []
    for p in out:
        if not clean or math.dist(p, clean[-1]) > 1e-9:
            clean.append(p)
    while len(clean) > 1 and math.dist(clean[0], clean[-1]) <= 1e-9:
        clean.pop()
    return clean


def bored_prism(
    mesh: Mesh,
    outline: Sequence[tuple[float, float]],
    centre: tuple[float, float],
    radius: float,
    axis: int,
    lo: float,
    hi: float,
) -> None:
    """A convex polygon with a 16-sided hole through it, extruded along coordinate `axis` from `lo`
    to `hi` (points as for `prism`): a wall or block with a pin hole through it.

    The hole, of circumradius `radius` about `centre` (its first corner toward +u, as `circle`),
    lies inside `outline` (it may touch it). The material is cut by the rays from the centre
    through the hole's corners into 16 convex pieces, each between one side of the hole and the
    outline, each a closed prism."""
    ring = circle(radius, *centre)
    for k in range(SEGMENTS):
        a, b = ring[k], ring[(k + 1) % SEGMENTS]
        da = (a[0] - centre[0], a[1] - centre[1])
        db = (b[0] - centre[0], b[1] - centre[1])
        piece = list(outline)
        piece = _clip(piece, (-da[1], da[0]), centre)  # counter-clockwise of the ray through a
        piece = _clip(piece, (db[1], -db[0]), centre)  # clockwise of the ray through b
        piece = _clip(piece, (da[0] + db[0], da[1] + db[1]), a)  # beyond the hole's side a-b
        if len(piece) >= 3:
            prism(mesh, piece, axis, lo, hi)
