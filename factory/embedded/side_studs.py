"""Parts with studs on their front face as well as on top: the headlight brick and the brackets.

A side stud is `stud.dat` turned a quarter about x (`kit.TO_FRONT`) so it points -z, its base on
the front face, as the real parts' side studs point (theirs are hollow; these are solid). The
bodies are boxes that touch but do not overlap.
"""

from __future__ import annotations

from factory.embedded.catalog import BRACKET, HEADLIGHT, PartSpec
from factory.embedded.geometry import Mesh, box
from factory.embedded.kit import (
    BRICK_HEIGHT,
    PITCH,
    PLATE_HEIGHT,
    TO_FRONT,
    TOP,
    WALL,
    between,
    flat,
    grid,
    part_body,
    ref,
    top_studs,
    underside,
)

HALF = PITCH / 2

RECESS = 4.0
"""The headlight brick's front face stands back 4 LDU (z=-6) above a 4 LDU lip along its foot, so
its side stud (4 tall) ends flush with the lip and the brick stays 20 deep."""

BRACKET_PLATE = 4.0
"""The bracket's hanging plate is 4 LDU thick in front of the 1 x 2 plate (z -14 to -10), as in
the real library; its studs stand on its front face at z=-14."""


def headlight(spec: PartSpec) -> list[str]:
    """Brick 1 x 1 with headlight (the "Erling" brick).

    Under its 4 LDU top the walls at the sides run the full height; the front wall (4 thick,
    behind the recessed face) ends 4 above the bottom, over the cavity's front part; the back is
    open between the side walls from under the top down to y=16 (a 12 x 12 window, where a stud
    entering along -z is held by the side walls, the top and the back wall under it), with a back
    wall below. A stud from below enters between the side walls, the lip and the back wall.
    """
    mesh = Mesh()
    front = -HALF + RECESS
    inner = HALF - WALL
    box(mesh, -HALF, HALF, 0.0, TOP, front, HALF)  # top
    for x0, x1 in ((-HALF, -inner), (inner, HALF)):
        box(mesh, x0, x1, TOP, BRICK_HEIGHT, front, HALF)  # side walls
    box(mesh, -HALF, HALF, BRICK_HEIGHT - WALL, BRICK_HEIGHT, -HALF, front)  # lip under the face
    box(mesh, -inner, inner, TOP, BRICK_HEIGHT - WALL, front, front + WALL)  # front wall
    window = BRICK_HEIGHT - 2 * WALL
    box(mesh, -inner, inner, window, BRICK_HEIGHT, inner, HALF)  # back wall under the window
    studs = top_studs([(0.0, 0.0)]) + [ref("stud.dat", 0.0, HALF, front, matrix=TO_FRONT)]
    return part_body(studs, [], mesh)


def bracket(spec: PartSpec) -> list[str]:
    """Bracket 1 x 2 - 1 x 2 (or 2 x 2) Down: a plate 1 x 2 whose front edge carries a plate that
    hangs down `spec.rows` stud rows (20 LDU a row), its studs facing -z.

    The plate's cavity is closed at the front by the hanging plate; ribs from it under each stud
    column and the bar under the middle (as under a plate 1 x 2) hold a stud from below with the
    side and back walls.
    """
    mesh = Mesh()
    refs: list[str] = []
    half_x = spec.nx * PITCH / 2
    inner_x, back = half_x - WALL, HALF - WALL
    plate_z = -HALF - BRACKET_PLATE
    box(mesh, -half_x, half_x, 0.0, TOP, -HALF, HALF)  # top
    box(mesh, -half_x, half_x, 0.0, spec.rows * PITCH, plate_z, -HALF)  # the hanging plate
    box(mesh, -half_x, half_x, TOP, PLATE_HEIGHT, back, HALF)  # back wall
    for x0, x1 in ((-half_x, -inner_x), (inner_x, half_x)):
        box(mesh, x0, x1, TOP, PLATE_HEIGHT, -HALF, back)  # side walls
    for x in grid(spec.nx):
        box(mesh, x - 2.0, x + 2.0, TOP, PLATE_HEIGHT, -HALF, -HALF + WALL)  # ribs
    underside(refs, mesh, [(x, 0.0) for x in between(spec.nx)], False, flat, PLATE_HEIGHT)
    side = [
        ref("stud.dat", x, HALF + PITCH * row, plate_z, matrix=TO_FRONT)
        for row in range(spec.rows)
        for x in grid(spec.nx)
    ]
    return part_body(top_studs([(x, 0.0) for x in grid(spec.nx)]) + side, refs, mesh)


FAMILIES = {HEADLIGHT: headlight, BRACKET: bracket}
