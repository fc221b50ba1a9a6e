"""The corner plate: plate 2 x 2 corner (2420), an L of three stud cells.

As in the real library, its origin is the centre of the corner cell's stud, with the other two
cells at +x and +z, so the missing cell is at (20, 20): the part spans x and z from -10 to 30. Under
its 4 LDU top, walls 4 thick follow the L outline, and a bar (radius 4) stands between the corner
cell and each of the other two, as under a plate 1 x 2: a stud under any cell is held by two or
three walls and one or two bars.
"""

from __future__ import annotations

from factory.embedded.catalog import CORNER_PLATE, PartSpec
from factory.embedded.geometry import Mesh, box
from factory.embedded.kit import PITCH, PLATE_HEIGHT, TOP, WALL, flat, part_body, top_studs, underside


def corner_plate(spec: PartSpec) -> list[str]:
    """Boxes that touch but do not overlap: the top over the row along x and over the third
    cell, then the six walls round the L (the two along its inner corner meeting in a 4 x 4
    square there), then the two bars."""
    mesh = Mesh()
    refs: list[str] = []
    near, mid, far = -PITCH / 2, PITCH / 2, 3 * PITCH / 2  # -10, 10, 30
    box(mesh, near, far, 0.0, TOP, near, mid)  # top, the row along x
    box(mesh, near, mid, 0.0, TOP, mid, far)  # top, the cell at +z
    for x0, x1, z0, z1 in (
        (near, far, near, near + WALL),  # front (z = -10)
        (far - WALL, far, near + WALL, mid),  # right end (x = 30)
        (mid - WALL, far - WALL, mid - WALL, mid),  # along the inner side z = 10
        (mid - WALL, mid, mid, far - WALL),  # along the inner side x = 10
        (near, mid, far - WALL, far),  # back of the cell at +z (z = 30)
        (near, near + WALL, near + WALL, far - WALL),  # left (x = -10)
    ):
        box(mesh, x0, x1, TOP, PLATE_HEIGHT, z0, z1)
    underside(refs, mesh, [(PITCH / 2, 0.0), (0.0, PITCH / 2)], False, flat, PLATE_HEIGHT)
    return part_body(top_studs([(0.0, 0.0), (PITCH, 0.0), (0.0, PITCH)]), refs, mesh)


FAMILIES = {CORNER_PLATE: corner_plate}
