"""The cheese slope: slope 30 1 x 1 x 2/3 (54200), no stud.

Unlike the library's other parts, its origin is the centre of its bottom face, as in the real
library: the part stands on y=0 and rises to y=-15.6. The slope (rise 0.6 a run, 31 degrees) falls
from the back edge to a 4 LDU front face at z=-10; like the real part, its top edge is cut flat at
y=-15.6 where the slope reaches that height (z=9.3333), short of the 16 LDU of 2/3 brick.
"""

from __future__ import annotations

from factory.embedded.catalog import CHEESE, PartSpec
from factory.embedded.geometry import Mesh, hollow_prism
from factory.embedded.kit import PITCH, STUD_HEIGHT, WALL, part_body

HALF = PITCH / 2
FRONT = 4.0
"""Height of the front face (z=-10)."""
RISE = 0.6
"""Height gained per LDU toward +z."""
HEIGHT = 15.6


def cheese(spec: PartSpec) -> list[str]:
    """One hollow prism along x. The cavity (walls 4) has a ceiling parallel to the slope, at a
    stud's height (4) above the bottom at the front wall, so a stud under the part fits its whole
    column (the real part's ceiling is 3 under the slope and notched for the stud instead)."""
    mesh = Mesh()
    top_z = -HALF + (HEIGHT - FRONT) / RISE
    outer = [(-HALF, 0.0), (HALF, 0.0), (HALF, -HEIGHT), (top_z, -HEIGHT), (-HALF, -FRONT)]
    c = HALF - WALL
    cavity = [(-c, 0.0), (c, 0.0), (c, -STUD_HEIGHT - RISE * 2 * c), (-c, -STUD_HEIGHT)]
    hollow_prism(mesh, outer, HALF, cavity, c, 0.0)
    return part_body([], [], mesh)


FAMILIES = {CHEESE: cheese}
