"""Round 1 x 1 parts: the round plate and the round brick.

Both are stacks of 16-sided cylinders and tubes about the stud's axis (the same 16-gon as the
studs, circumradius 10 for the outside, so the part's box is the 20 x 20 of a 1 x 1 cell). Under
each is a ring of inner radius 6: a stud entering it is held all round, a `tube` socket.
"""

from __future__ import annotations

from factory.embedded.catalog import ROUND_BRICK, ROUND_PLATE, PartSpec
from factory.embedded.geometry import Mesh, cylinder
from factory.embedded.kit import (
    BRICK_HEIGHT,
    HOLLOW_STUD_RADIUS,
    PITCH,
    PLATE_HEIGHT,
    TOP,
    TUBE_INNER,
    TUBE_OUTER,
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


def round_brick(spec: PartSpec) -> list[str]:
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


FAMILIES = {ROUND_PLATE: round_plate, ROUND_BRICK: round_brick}
