"""Round parts: the round plate 1 x 1, the round bricks 1 x 1 and 2 x 2, and the cone 1 x 1.

All are stacks of 16-sided cylinders and tubes about the vertical axis through the origin (the same
16-gon as the studs, circumradius 10 for a 1 x 1 part's outside, so its box is the 20 x 20 of a
1 x 1 cell; 20 for the 2 x 2 brick). Under each is a ring of inner radius 6: a stud entering it is
held all round, a `tube` socket. The cone and the 2 x 2 brick have an axle hole (a cross) on their
axis, as the real parts do, which also makes them four-fold, not round, as LDraw finds them.
"""

from __future__ import annotations

from factory.embedded.catalog import CONE, ROUND_BRICK, ROUND_PLATE, PartSpec
from factory.embedded.geometry import Mesh, circle, cylinder, lathe, prism
from factory.embedded.kit import (
    AXLE_RADIUS,
    BRICK_HEIGHT,
    HOLLOW_STUD_RADIUS,
    PITCH,
    PLATE_HEIGHT,
    STUD_RADIUS,
    TOP,
    TUBE_INNER,
    TUBE_OUTER,
    WALL,
    axle_hole,
    grid,
    part_body,
    top_studs,
    underside,
)

OUTER = PITCH / 2

ROUND_PLATE_TOP = 3.0
"""The round plate's disc is 3 LDU thick (the real part's), so the tube under it is 5 tall."""

ROUND_BRICK_WAIST = 19.0
"""The round brick is 10 in radius down to y=19, then narrows to the tube radius 8 for its last
5 LDU, as the real part does (a stud beside it has room at its foot)."""


def round_plate(spec: PartSpec) -> list[str]:
    """A disc on a tube (`stud4.dat` stretched from the disc to the bottom), a stud on top."""
    mesh = Mesh()
    refs: list[str] = []
    cylinder(mesh, OUTER, 0.0, ROUND_PLATE_TOP)
    underside(refs, mesh, [(0.0, 0.0)], True, lambda x, z: ROUND_PLATE_TOP, PLATE_HEIGHT)
    return part_body(top_studs([(0.0, 0.0)]), refs, mesh)


CONE_BASE = 19.0
"""The cone widens from the radius of its stud (6) at its top to 10 at y=19, over a base of
radius 8 down to the bottom, as the real part does."""

CONE_AXLE = (12.0, 18.0)
"""The cone's axle hole spans y 12 to 18, between the bore of its hollow stud above (radius 4)
and the tube socket's cavity below (radius 6), as on the real part."""

FOOT = 20.0
"""The 2 x 2 round brick's wall is a full 16-gon down to y=20; its last 4 LDU are four lobes."""


def round_brick(spec: PartSpec) -> list[str]:
    """The round brick 1 x 1, or (`spec.nx` 2) the round brick 2 x 2."""
    if spec.nx > 1:
        return _round_brick_wide(spec)
    return _round_brick_1x1(spec)


def _round_brick_1x1(spec: PartSpec) -> list[str]:
    """A tube open from top to bottom: a hollow stud (`stud2.dat`) whose bore (radius 4) goes on
    through the 4 LDU top into the cavity of radius 6 below, as on the real part.

    Below the top, the wall is a tube of radii 8 and 6 down to the bottom with a sleeve of radii
    10 and 8 round it down to the waist: the two meet on a cylinder, so no flat face crosses the
    wall at the waist (the socket probe would take such a face, reaching the cavity, for the rim
    of a second socket at y=19)."""
    mesh = Mesh()
    cylinder(mesh, OUTER, 0.0, TOP, HOLLOW_STUD_RADIUS)
    cylinder(mesh, OUTER, TOP, ROUND_BRICK_WAIST, TUBE_OUTER)
    cylinder(mesh, TUBE_OUTER, TOP, BRICK_HEIGHT, TUBE_INNER)
    return part_body(top_studs([(0.0, 0.0)], "stud2.dat"), [], mesh)


def _lobes(outer: float, flat: float) -> list[list[tuple[float, float]]]:
    """(x, z) outlines of the four lobes round the foot of a round brick: the segments of the
    16-gon of circumradius `outer` beyond the lines x = +-flat and z = +-flat."""
    ring = circle(outer)
    (x1, z1), (x2, z2) = ring[1], ring[2]
    z = z1 + (x1 - flat) / (x1 - x2) * (z2 - z1)  # where x = flat meets the side ring[1]-ring[2]
    lobe = [(flat, -z), ring[15], ring[0], ring[1], (flat, z)]
    out = []
    for _ in range(4):
        out.append(lobe)
        lobe = [(-b, a) for a, b in lobe]  # a quarter turn about y
    return out


def _round_brick_wide(spec: PartSpec) -> list[str]:
    """Brick 2 x 2 round: four studs on a disc of radius 20, a wall 4 thick round a cavity of
    radius 16, and an axle hole down the middle in a column of radius 8 that ends in a tube.

    The wall's last 4 LDU are only four lobes, where the 16-gon reaches past the lines 16 from
    the centre; between them, under the diagonals, the foot is open, as on the real part. A stud
    under each stud cell stands in the 12 x 12 square between two lobes, the tube, and the wall
    over it (a `stud` socket); one under the middle enters the tube (a `tube` socket) up to the
    axle hole."""
    mesh = Mesh()
    refs: list[str] = []
    outer = spec.nx * PITCH / 2
    inner = outer - WALL
    cylinder(mesh, outer, 0.0, TOP, AXLE_RADIUS)  # the top, round the axle hole
    cylinder(mesh, outer, TOP, FOOT, inner)  # the wall
    cylinder(mesh, TUBE_OUTER, TOP, FOOT, AXLE_RADIUS)  # the column round the axle hole
    axle_hole(mesh, 0.0, FOOT)
    for lobe in _lobes(outer, inner):
        prism(mesh, lobe, 1, FOOT, BRICK_HEIGHT)
    underside(refs, mesh, [(0.0, 0.0)], True, lambda x, z: FOOT, BRICK_HEIGHT)
    studs = [(x, z) for x in grid(spec.nx) for z in grid(spec.nz)]
    return part_body(top_studs(studs), refs, mesh)


def cone(spec: PartSpec) -> list[str]:
    """Cone 1 x 1: a hollow stud (`stud2.dat`) on a cone from radius 6 at the top to 10 at
    y=19, on a base of radius 8, all one solid of revolution (`lathe`) round the stud's bore
    (radius 4) down to y=12 and the cavity (radius 6) from y=12 to the bottom; between them the
    axle hole's four pieces fill the cavity from y=12 to 18, leaving 6 LDU under them for a stud
    (a `tube` socket)."""
    mesh = Mesh()
    axle_top, axle_bottom = CONE_AXLE
    lathe(mesh, [
        (HOLLOW_STUD_RADIUS, 0.0), (STUD_RADIUS, 0.0), (OUTER, CONE_BASE), (TUBE_OUTER, CONE_BASE),
        (TUBE_OUTER, BRICK_HEIGHT), (TUBE_INNER, BRICK_HEIGHT), (TUBE_INNER, axle_top),
        (HOLLOW_STUD_RADIUS, axle_top),
    ])
    axle_hole(mesh, axle_top, axle_bottom)
    return part_body(top_studs([(0.0, 0.0)], "stud2.dat"), [], mesh)


FAMILIES = {ROUND_PLATE: round_plate, ROUND_BRICK: round_brick, CONE: cone}
