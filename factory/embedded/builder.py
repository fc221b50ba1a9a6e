"""LDraw text of the generated parts and of the stud, bar and tube primitives they reference.

A part's origin is the centre of its top face (y=0), studs stand on it pointing -y, and the
underside is hollow, open at the bottom (sizes and how studs, tubes and bars are placed: `kit`).
The box-like families (bricks, plates, tiles, 45 degree slopes) are built here; the other shapes
in modules of their own, named after what they hold, which `part_file` hands them to.
"""

from __future__ import annotations

from collections.abc import Callable

from factory.embedded import arch, cheese, corner, modified, rounds, side_studs, technic, wedge
from factory.embedded.catalog import BRICK, INVERTED_SLOPE, PLATE, SLOPE, TILE, PartSpec
from factory.embedded.geometry import Mesh, cylinder, hollow_prism
from factory.embedded.kit import (
    BAR_RADIUS,
    BRICK_HEIGHT,
    HOLLOW_STUD_RADIUS,
    PITCH,
    PLATE_HEIGHT,
    PRIMITIVE_HEIGHT,
    STUD_RADIUS,
    TOP,
    TUBE_INNER,
    TUBE_OUTER,
    WALL,
    between,
    flat,
    grid,
    header,
    ldraw_file,
    part_body,
    top_studs,
    underside,
)

__all__ = ["header", "part_file", "primitives"]


# --- primitives -------------------------------------------------------------------------------


def primitives() -> dict[str, str]:
    """p/stud.dat (solid stud), p/stud2.dat (hollow stud: a tube, closed at both ends like every
    generated solid), p/stud3.dat (solid bar), p/stud4.dat (open tube), and the bar and tube
    without their y=0 end, p/stud3a.dat and p/stud4a.dat. All span y in [-4, 0]."""
    out = {}
    for name, desc, r, r_in, caps in (
        ("stud.dat", "Stud", STUD_RADIUS, None, (True, True)),
        ("stud2.dat", "Stud Open", STUD_RADIUS, HOLLOW_STUD_RADIUS, (True, True)),
        ("stud3.dat", "Stud Tube Solid", BAR_RADIUS, None, (True, True)),
        ("stud4.dat", "Stud Tube Open", TUBE_OUTER, TUBE_INNER, (True, True)),
        ("stud3a.dat", "Stud Tube Solid Closed at Top Only", BAR_RADIUS, None, (True, False)),
        ("stud4a.dat", "Stud Tube Open Closed at Top Only", TUBE_OUTER, TUBE_INNER, (True, False)),
    ):
        mesh = Mesh()
        cylinder(mesh, r, -PRIMITIVE_HEIGHT, 0.0, r_in, caps=caps)
        out[f"p/{name}"] = ldraw_file(header(desc, name, "Primitive"), mesh.lines())
    return out


# --- parts ------------------------------------------------------------------------------------


def _box_like(spec: PartSpec) -> list[str]:
    """Bricks, plates, tiles and 45 degree slopes: one hollow prism with tubes or bars under it."""
    mesh = Mesh()
    refs: list[str] = []
    half_x, half_z = spec.nx * PITCH / 2, spec.nz * PITCH / 2
    cavity_x = half_x - WALL
    studs = [(x, z) for x in grid(spec.nx) for z in grid(spec.nz)]

    if spec.kind in (BRICK, PLATE, TILE):
        h = BRICK_HEIGHT if spec.kind == BRICK else PLATE_HEIGHT
        outer = [(-half_z, 0.0), (half_z, 0.0), (half_z, h), (-half_z, h)]
        iz = half_z - WALL
        cavity = [(-iz, TOP), (iz, TOP), (iz, h), (-iz, h)]
        hollow_prism(mesh, outer, half_x, cavity, cavity_x, h)
        if spec.kind == TILE:
            studs = []
        if spec.nz >= 2:
            tubes = [(x, z) for x in between(spec.nx) for z in between(spec.nz)]
            underside(refs, mesh, tubes, True, flat, h)
        elif spec.bars:
            underside(refs, mesh, [(x, 0.0) for x in between(spec.nx)], False, flat, h)

    elif spec.kind == SLOPE:
        # Profile in (z, y): flat top z in [-10, 10], 45 degree face down to a 4 LDU lip at z=-30.
        h = BRICK_HEIGHT
        outer = [(-10.0, 0.0), (10.0, 0.0), (10.0, h), (-30.0, h), (-30.0, 20.0)]
        cavity = [(-10.0, TOP), (6.0, TOP), (6.0, h), (-26.0, h), (-26.0, 20.0)]
        hollow_prism(mesh, outer, half_x, cavity, cavity_x, h)
        studs = [(x, 0.0) for x in grid(spec.nx)]

        def ceiling(x: float, z: float) -> float:
            return TOP if z >= -10.0 else -z - 6.0

        if spec.nx >= 2:
            underside(refs, mesh, [(x, -10.0) for x in between(spec.nx)], True, ceiling, h)
        else:
            underside(refs, mesh, [(0.0, -10.0)], False, ceiling, h)

    elif spec.kind == INVERTED_SLOPE:
        # Profile in (z, y): top z in [-30, 10], bottom z in [-10, 10], 45 degree underside from
        # (z=-10, y=24) up to a 4 LDU front face at z=-30. Hollow only under the back row.
        h = BRICK_HEIGHT
        outer = [(-30.0, 0.0), (10.0, 0.0), (10.0, h), (-10.0, h), (-30.0, TOP)]
        cavity = [(-6.0, TOP), (6.0, TOP), (6.0, h), (-6.0, h)]
        hollow_prism(mesh, outer, half_x, cavity, cavity_x, h)
        studs = [(x, z) for x in grid(spec.nx) for z in (0.0, -PITCH)]
        underside(refs, mesh, [(x, 0.0) for x in between(spec.nx)], False, flat, h)

    else:
        raise ValueError(f"unknown part kind {spec.kind!r}")

    return part_body(top_studs(studs), refs, mesh)


_FAMILIES: dict[str, Callable[[PartSpec], list[str]]] = {
    **rounds.FAMILIES,
    **modified.FAMILIES,
    **cheese.FAMILIES,
    **side_studs.FAMILIES,
    **arch.FAMILIES,
    **wedge.FAMILIES,
    **corner.FAMILIES,
    **technic.FAMILIES,
}
"""Kind -> the function that writes a part's lines, for the shapes built outside this module."""


def part_file(spec: PartSpec) -> str:
    """The LDraw text of one catalogue part."""
    lines = _FAMILIES.get(spec.kind, _box_like)(spec)
    return ldraw_file(header(spec.description, spec.filename, "Part"), lines)
