"""The corner-cut plate: plate 3 x 3 without corner (2450), a wedge plate of 45 degrees.

A plate 3 x 3 with the corner at (+x, -z) cut off along a line at 45 degrees from (-10, -30) to
(30, 10): the cut takes two stud cells' length off each of the two edges it meets. The cut line
runs through the centres of the cells at (0, -20) and (20, 0), which keep no stud. Under the
part, its walls (4 thick) follow the outline; the wall along the cut is notched 6 LDU either side
of those two cell centres, so a stud of a part below can stand there (half under the plate), held
by the notch's ends and the nearest tube. The tube that would stand at (10, -10), on the cut, is
left out, and a rib from the middle of the cut wall toward the centre holds a stud under the
centre cell with the three tubes, as on the real part.
"""

from __future__ import annotations

import math

from factory.embedded.catalog import WEDGE, PartSpec
from factory.embedded.geometry import Mesh, prism
from factory.embedded.kit import (
    PITCH,
    PLATE_HEIGHT,
    STUD_RADIUS,
    TOP,
    TUBE_OUTER,
    WALL,
    between,
    flat,
    grid,
    part_body,
    top_studs,
    underside,
)

CUT = 2 * PITCH
"""Length cut off each of the two edges that meet at the removed corner."""

NOTCH = STUD_RADIUS
"""Half length of each notch along the cut wall."""

RIB = (math.sqrt(2.0), WALL)
"""The rib: half width along the cut wall, length inward from the wall's inner face."""

Point2 = tuple[float, float]


def _offset(p: Point2, along: float, inward: float) -> Point2:
    """`p` moved `along` the cut (toward +x, +z) and `inward` (toward -x, +z), in (x, z)."""
    s = math.sqrt(0.5)
    return (p[0] + s * (along - inward), p[1] + s * (along + inward))


def _cut_wall(mesh: Mesh, a: Point2, b: Point2, ends: tuple[Point2, Point2], notched: list[float]) -> None:
    """The wall along the cut from `a` to `b` (4 thick, its inner corners `ends`), left out within
    `NOTCH` of each distance along it in `notched`, and the rib from its middle."""
    length = math.dist(a, b)
    cuts = [0.0] + [e for c in sorted(notched) for e in (c - NOTCH, c + NOTCH)] + [length]
    for s0, s1 in zip(cuts[::2], cuts[1::2]):
        # Square across the wall at a notch; the mitred corner at either end of the wall.
        inner0 = ends[0] if s0 == 0.0 else _offset(a, s0, WALL)
        inner1 = ends[1] if s1 == length else _offset(a, s1, WALL)
        prism(mesh, [_offset(a, s0, 0.0), _offset(a, s1, 0.0), inner1, inner0], 1, TOP, PLATE_HEIGHT)
    mid, w = length / 2, RIB[0]
    rib = [_offset(a, mid - w, WALL), _offset(a, mid + w, WALL),
           _offset(a, mid + w, WALL + RIB[1]), _offset(a, mid - w, WALL + RIB[1])]
    prism(mesh, rib, 1, TOP, PLATE_HEIGHT)


def wedge(spec: PartSpec) -> list[str]:
    mesh = Mesh()
    refs: list[str] = []
    h = spec.nx * PITCH / 2
    a, b = (h - CUT, -h), (h, -h + CUT)  # the cut, from the front edge to the right edge
    outline = [(-h, -h), a, b, (h, h), (-h, h)]
    prism(mesh, outline, 1, 0.0, TOP)

    # The walls: between the outline and the same outline 4 LDU further in, one trapezoid an edge.
    # Where the cut meets an edge at 135 degrees, the inner corner lies 4 (sqrt 2 - 1) further
    # along that edge than the outer one.
    k = WALL * (math.sqrt(2.0) - 1)
    inner = [(-h + WALL, -h + WALL), (a[0] - k, a[1] + WALL), (b[0] - WALL, b[1] + k),
             (h - WALL, h - WALL), (-h + WALL, h - WALL)]
    for i in (0, 2, 3, 4):  # edge 1 is the cut
        j = (i + 1) % len(outline)
        prism(mesh, [outline[i], outline[j], inner[j], inner[i]], 1, TOP, PLATE_HEIGHT)

    def beyond(x: float, z: float) -> float:
        """How far (x, z) lies past the cut, outward (negative: inside the plate)."""
        return ((x - z) - (a[0] - a[1])) * math.sqrt(0.5)

    cells = [(x, z) for x in grid(spec.nx) for z in grid(spec.nz)]
    _cut_wall(mesh, a, b, (inner[1], inner[2]), [math.dist(a, c) for c in cells if abs(beyond(*c)) < 1e-9])
    studs = [c for c in cells if beyond(*c) <= -STUD_RADIUS]
    tubes = [(x, z) for x in between(spec.nx) for z in between(spec.nz)
             if beyond(x, z) <= -(WALL + TUBE_OUTER)]
    underside(refs, mesh, tubes, True, flat, PLATE_HEIGHT)
    return part_body(top_studs(studs), refs, mesh)


FAMILIES = {WEDGE: wedge}
