"""The cheese slopes: slope 30 1 x 1 x 2/3 (54200) and slope 31 1 x 2 x 2/3 (85984), no studs.

Unlike the library's other parts, their origin is the centre of their bottom face, as in the real
library: a part stands on y=0 and rises to y=-15.6. The slope (rise 0.6 a run, 31 degrees) falls
from the back edge to a 4 LDU front face at z=-10; like the real parts, the top edge is cut flat at
y=-15.6 where the slope reaches that height (z=9.3333), short of the 16 LDU of 2/3 brick. The 1 x 2
is the 1 x 1's profile 40 wide, with a bar between its two stud cells, as under a plate 1 x 2.
"""

from __future__ import annotations

from factory.embedded.catalog import CHEESE, PartSpec
from factory.embedded.geometry import Mesh, hollow_prism
from factory.embedded.kit import PITCH, STUD_HEIGHT, WALL, between, part_body, underside

HALF = PITCH / 2
FRONT = 4.0
"""Height of the front face (z=-10)."""
RISE = 0.6
"""Height gained per LDU toward +z."""
HEIGHT = 15.6


def cheese(spec: PartSpec) -> list[str]:
    """One hollow prism along x. The cavity (walls 4) has a ceiling parallel to the slope, at a
    stud's height (4) above the bottom at the front wall, so a stud under the part fits its whole
    column (the real part's ceiling is 3 under the slope and notched for the stud instead). Under
    the 1 x 2, a bar between the cells from the bottom up to that ceiling (`kit.underside`: its
    collar follows the slope)."""
    mesh = Mesh()
    refs: list[str] = []
    half_x = spec.nx * PITCH / 2
    top_z = -HALF + (HEIGHT - FRONT) / RISE
    outer = [(-HALF, 0.0), (HALF, 0.0), (HALF, -HEIGHT), (top_z, -HEIGHT), (-HALF, -FRONT)]
    c = HALF - WALL
    cavity = [(-c, 0.0), (c, 0.0), (c, -STUD_HEIGHT - RISE * 2 * c), (-c, -STUD_HEIGHT)]
    hollow_prism(mesh, outer, half_x, cavity, half_x - WALL, 0.0)

    def ceiling(x: float, z: float) -> float:
        return -STUD_HEIGHT - RISE * (z + c)

    underside(refs, mesh, [(x, 0.0) for x in between(spec.nx)], False, ceiling, 0.0)
    return part_body([], refs, mesh)


FAMILIES = {CHEESE: cheese}
