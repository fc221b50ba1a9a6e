"""The arch: brick 1 x 4 with an arch cut from below (3659).

A brick 1 x 4 whose middle two stud cells are cut away from below up to a circular arch of radius
20 centred 4 LDU under the bottom face (so it meets the sides of the opening 4 above the bottom
and peaks 8 under the top, at y=8). Only the front and back walls (4 thick) follow the arch; the
middle of the span is open from below up to the 4 LDU top, as on the real part. Each end is a
1 x 1 pillar with a brick's cavity, where a stud enters from below.
"""

from __future__ import annotations

from factory.embedded.catalog import ARCH, PartSpec
from factory.embedded.geometry import Mesh, box, circle, prism
from factory.embedded.kit import BRICK_HEIGHT, PITCH, TOP, WALL, grid, part_body, top_studs

HALF_Z = PITCH / 2
CENTRE_Y = BRICK_HEIGHT + 4.0


def arch_line(span: float) -> list[tuple[float, float]]:
    """(x, y) of the arch's underside from x=-span to x=span: the lower half of the 16-gon of
    circumradius `span` about (0, CENTRE_Y) above the bottom face, ended by straight lines to
    the bottom corners of the opening."""
    ring = [(x, CENTRE_Y + z) for x, z in circle(span)]
    lower = ring[9:16]  # 202.5 to 337.5 degrees: from the left, over the top, to the right
    return [(-span, BRICK_HEIGHT)] + lower + [(span, BRICK_HEIGHT)]


def arch(spec: PartSpec) -> list[str]:
    mesh = Mesh()
    half_x = spec.nx * PITCH / 2
    span = half_x - PITCH  # the opening: all but the end cells
    inner_z = HALF_Z - WALL
    box(mesh, -half_x, half_x, 0.0, TOP, -HALF_Z, HALF_Z)  # top
    for sign in (-1.0, 1.0):  # the pillars: a brick 1 x 1's walls under each end cell
        near, far = sorted((sign * span, sign * half_x))
        for z0, z1 in ((-HALF_Z, -inner_z), (inner_z, HALF_Z)):
            box(mesh, near, far, TOP, BRICK_HEIGHT, z0, z1)
        for x0, x1 in ((near, near + WALL), (far - WALL, far)):
            box(mesh, x0, x1, TOP, BRICK_HEIGHT, -inner_z, inner_z)
    # The arched front and back walls: between each pair of points of the arch, a slab from the
    # top down to the arch (a convex quadrilateral in (x, y), extruded along z).
    line = arch_line(span)
    for (xa, ya), (xb, yb) in zip(line, line[1:]):
        for z0, z1 in ((-HALF_Z, -inner_z), (inner_z, HALF_Z)):
            prism(mesh, [(xa, TOP), (xb, TOP), (xb, yb), (xa, ya)], 2, z0, z1)
    return part_body(top_studs([(x, 0.0) for x in grid(spec.nx)]), [], mesh)


FAMILIES = {ARCH: arch}
