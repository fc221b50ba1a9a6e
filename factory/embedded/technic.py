"""The technic brick: technic brick 1 x 2 with hole (3700).

A brick 1 x 2 (40 x 24 x 20, hollow studs as on the real part) with a pin hole of radius 6 through
it along z, its axis 10 under the top face (so the hole reaches up to the top's underside), as in
the real library. Around the hole, between the long walls, a housing 16 wide fills the middle of
the cavity down to y=18 (its foot follows the hole's 16-gon, radius 8, cut flat to the bar's
width), and a bar (radius 4) stands under it to the bottom. A stud under either stud cell stands
in the 8 x 12 cavity between the housing and the end wall, held by the long walls, the end wall
and the bar (a `stud` socket), as under the real part.

Simplified against the real part: the hole is straight (the real one is widened to radius 8 for
its last 2 LDU at each face), and the housing's foot is flat under the bar where the real one is
round and meets the bar in a curve.
"""

from __future__ import annotations

import math

from factory.embedded.catalog import TECHNIC_BRICK, PartSpec
from factory.embedded.geometry import Mesh, bored_prism, box
from factory.embedded.kit import (
    BAR_RADIUS,
    BRICK_HEIGHT,
    PITCH,
    STUD_RADIUS,
    TOP,
    TUBE_OUTER,
    WALL,
    grid,
    part_body,
    top_studs,
    underside,
)

HOLE_Y = 10.0
"""The pin hole's axis: y=10, x=0, along z."""
HOLE_RADIUS = STUD_RADIUS
HOUSING = TUBE_OUTER
"""Half width of the housing round the hole, and the radius its foot follows."""
HOUSING_FOOT = HOLE_Y + HOUSING


def _housing_outline() -> list[tuple[float, float]]:
    """(x, y) of the housing: a rectangle from the top down to the hole's axis, then the lower
    half of the 16-gon of radius 8 about the axis, its lowest side cut flat (x within the bar's
    radius) at y=18."""
    h = HOUSING
    lower = [(h * math.cos(math.pi * k / 8), HOLE_Y + h * math.sin(math.pi * k / 8)) for k in (1, 2)]
    return ([(-h, TOP), (h, TOP), (h, HOLE_Y), *lower, (BAR_RADIUS, HOUSING_FOOT),
             (-BAR_RADIUS, HOUSING_FOOT), *[(-x, y) for x, y in reversed(lower)], (-h, HOLE_Y)])


def technic_brick(spec: PartSpec) -> list[str]:
    mesh = Mesh()
    refs: list[str] = []
    half_x, half_z = spec.nx * PITCH / 2, spec.nz * PITCH / 2
    inner_z = half_z - WALL
    centre = (0.0, HOLE_Y)
    box(mesh, -half_x, half_x, 0.0, TOP, -half_z, half_z)  # top
    wall = [(-half_x, TOP), (half_x, TOP), (half_x, BRICK_HEIGHT), (-half_x, BRICK_HEIGHT)]
    for z0, z1 in ((-half_z, -inner_z), (inner_z, half_z)):
        bored_prism(mesh, wall, centre, HOLE_RADIUS, 2, z0, z1)  # the long walls, holed
    for x0, x1 in ((-half_x, -half_x + WALL), (half_x - WALL, half_x)):
        box(mesh, x0, x1, TOP, BRICK_HEIGHT, -inner_z, inner_z)  # end walls
    bored_prism(mesh, _housing_outline(), centre, HOLE_RADIUS, 2, -inner_z, inner_z)
    underside(refs, mesh, [(0.0, 0.0)], False, lambda x, z: HOUSING_FOOT, BRICK_HEIGHT)
    return part_body(top_studs([(x, 0.0) for x in grid(spec.nx)], "stud2.dat"), refs, mesh)


FAMILIES = {TECHNIC_BRICK: technic_brick}
