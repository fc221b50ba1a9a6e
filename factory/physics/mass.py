"""Mass properties of parts: mass, centre of mass and inertia from the convex collision pieces."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh

from factory.parts import Part
from factory.physics.geometry import collision_shape
from factory.pose import LDU_M

GRAVITY = 9.81
"""m/s^2; gravity pulls along LDraw +y (down)."""


@lru_cache(maxsize=None)
def part_mass_properties(part: Part) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, centre of mass in LDU part frame, inertia about the COM in kg m^2, LDraw axes).

    From the convex collision pieces (closed, unlike LDraw meshes), scaled to the part's mass.
    """
    shape = collision_shape(part)
    mass = part.mass_g / 1000.0
    vols, coms, inertias = [], [], []
    for verts in shape.body + shape.studs:
        hull = trimesh.convex.convex_hull(verts)
        if hull.volume <= 0:
            continue
        vols.append(hull.volume)
        coms.append(hull.center_mass)
        inertias.append(hull.moment_inertia / hull.volume)  # per unit density, about piece COM
    if not vols:
        centre = part.bbox.mean(axis=0)
        return mass, centre, np.eye(3) * 1e-9
    vols = np.array(vols)
    coms = np.array(coms)
    com = (vols[:, None] * coms).sum(0) / vols.sum()
    density = mass / vols.sum()
    inertia = np.zeros((3, 3))
    for v, c, i in zip(vols, coms, inertias):
        d = c - com
        inertia += density * (i * v + v * (d @ d * np.eye(3) - np.outer(d, d)))
    return mass, com, inertia * LDU_M**2
