"""Modified 1 x 2 plates and tiles: the grille tile and the jumper plate.

Both are a 1 x 2 plate's shell (40 x 20 x 8, a cavity 32 x 12 under a 4 LDU top), so a stud enters
under either end as under a plate 1 x 2. The groove the real parts have round the foot of their
sides (1 LDU) is left out, as on the library's other tiles and plates.
"""

from __future__ import annotations

from factory.embedded.catalog import GRILLE, JUMPER, PartSpec
from factory.embedded.geometry import Mesh, box, hollow_prism
from factory.embedded.kit import PITCH, PLATE_HEIGHT, TOP, WALL, flat, part_body, top_studs, underside

HALF_X, HALF_Z = PITCH, PITCH / 2

SLOTS = ((2.0, 6.0), (-6.0, -2.0))
"""The grille's two slots across z, each 4 wide: its top is three bars 4 wide along x. Over the
cavity they go through the top, over the end walls they are 4 deep, as on the real part."""

RIB = (4.0, 1.0)
"""Half size (x, z) of the rib in the middle of the grille's cavity, from the centre bar down to
the bottom (the real one has round ends): a stud under either end meets it as the bar under a
plate 1 x 2."""


def grille(spec: PartSpec) -> list[str]:
    """Tile 1 x 2 with grille: no studs; boxes that touch but do not overlap."""
    mesh = Mesh()
    cavity_x, cavity_z = HALF_X - WALL, HALF_Z - WALL
    # The top: three bars along x between and beside the slots.
    edges = sorted([-HALF_Z, HALF_Z] + [z for slot in SLOTS for z in slot])
    for z0, z1 in zip(edges[::2], edges[1::2]):
        box(mesh, -HALF_X, HALF_X, 0.0, TOP, z0, z1)
    # Below the top: the long walls, the end walls between them, and the rib.
    for z0, z1 in ((-HALF_Z, -cavity_z), (cavity_z, HALF_Z)):
        box(mesh, -HALF_X, HALF_X, TOP, PLATE_HEIGHT, z0, z1)
    for x0, x1 in ((-HALF_X, -cavity_x), (cavity_x, HALF_X)):
        box(mesh, x0, x1, TOP, PLATE_HEIGHT, -cavity_z, cavity_z)
    box(mesh, -RIB[0], RIB[0], TOP, PLATE_HEIGHT, -RIB[1], RIB[1])
    return part_body([], [], mesh)


def jumper(spec: PartSpec) -> list[str]:
    """Plate 1 x 2 with one hollow stud (`stud2.dat`, as on the real part) in the middle and the
    bar of a plate 1 x 2 under it."""
    mesh = Mesh()
    refs: list[str] = []
    outer = [(-HALF_Z, 0.0), (HALF_Z, 0.0), (HALF_Z, PLATE_HEIGHT), (-HALF_Z, PLATE_HEIGHT)]
    iz = HALF_Z - WALL
    cavity = [(-iz, TOP), (iz, TOP), (iz, PLATE_HEIGHT), (-iz, PLATE_HEIGHT)]
    hollow_prism(mesh, outer, HALF_X, cavity, HALF_X - WALL, PLATE_HEIGHT)
    underside(refs, mesh, [(0.0, 0.0)], False, flat, PLATE_HEIGHT)
    return part_body(top_studs([(0.0, 0.0)], "stud2.dat"), refs, mesh)


FAMILIES = {GRILLE: grille, JUMPER: jumper}
