"""The embedded library's shapes beyond boxes (round plate and brick, grille tile, jumper plate,
cheese slope, headlight brick, brackets, arch, corner-cut plate) against the real parts in LDraw's
complete.zip beside the checkout: size, studs, sockets, symmetry and volume; their exact volumes;
and the convex prism emitter they are partly built with. Closed, outward geometry for every part is
checked in test_embedded_generator.py (`test_part_closed_with_positive_volume`).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from factory.embedded.arch import arch_line
from factory.embedded.catalog import BY_NUMBER
from factory.embedded.geometry import Mesh, prism
from factory.ldraw import Library, Reader
from factory.parts import load_part

REAL_ZIP = Path(__file__).resolve().parents[2] / "shared" / "ldraw_library.zip"

REAL_NAME = {
    "6141": "6141",
    "3062b": "3062b",
    "2412b": "2412b",
    "3794b": "3794b",
    "54200": "54200",
    "4070": "4070",
    "99781": "99781",
    "44728": "44728",
    "3659": "3659",
    "2450": "2450",
}
NEW = sorted(REAL_NAME)

A16 = 8 * math.sin(math.pi / 8)
"""Area of a 16-gon of circumradius 1."""
STUD = A16 * 36 * 4
HOLLOW_STUD = A16 * (36 - 16) * 4
BAR = A16 * 16


@pytest.fixture(scope="module")
def zip_reader() -> Reader:
    if not REAL_ZIP.is_file():
        pytest.skip(f"LDraw's complete.zip is not at {REAL_ZIP}")
    return Reader(Library.from_path(REAL_ZIP))


def test_the_new_shapes_are_in_the_catalogue():
    assert set(NEW) <= set(BY_NUMBER)
    kinds = {BY_NUMBER[n].kind for n in NEW}
    assert kinds == {"round_plate", "round_brick", "grille", "jumper", "cheese", "headlight", "bracket",
                     "arch", "wedge"}


@pytest.mark.parametrize("number", NEW)
def test_new_part_matches_the_real_one(embedded_reader, zip_reader, number):
    ours, real = load_part(embedded_reader, number), load_part(zip_reader, REAL_NAME[number])
    assert np.allclose(ours.bbox, real.bbox, atol=0.5), (ours.bbox, real.bbox)
    # Studs: where they stand and which way they point (the side studs of 4070, 99781 and 44728
    # point -z); sockets: where, entered which way, and of which kind.
    assert {c.pos + c.axis for c in ours.studs} == {c.pos + c.axis for c in real.studs}
    assert {(c.pos, c.axis, c.kind) for c in ours.sockets} == {(c.pos, c.axis, c.kind) for c in real.sockets}
    assert ours.symmetry.order == real.symmetry.order
    assert ours.symmetry.continuous_axis == real.symmetry.continuous_axis


@pytest.mark.parametrize("number", NEW)
def test_new_part_volume_is_close_to_the_real_one(embedded_reader, zip_reader, number):
    """Within 15% of the real part's volume as the project measures it (the divergence sum, which
    gives its mass). Several real meshes are not closed (99781, 44728, 3659, 2450, 4070: their sum
    changes with the origin), so for them the real figure is itself approximate: 99781 comes out
    12% under it though its boxes match the real file's sizes (a winding-number count of the real
    mesh finds matter spread thinly behind its hanging plate, where the file has none). 4070 is 7%
    over: its side stud is a solid stud.dat where the real one is hollow, with a bore through the
    front wall behind it."""
    ours, real = load_part(embedded_reader, number), load_part(zip_reader, REAL_NAME[number])
    assert ours.volume_ldu3 > 0
    assert ours.volume_ldu3 == pytest.approx(real.volume_ldu3, rel=0.15)


def _polygon_area(points) -> float:
    return abs(sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1]))) / 2


def _arch_volume() -> float:
    top = 80 * 4 * 20
    pillars = 2 * (20 * 20 * 20 - 12 * 20 * 12)
    opening = _polygon_area(arch_line(20.0))  # closed along y=24 between the opening's corners
    walls = 2 * 4 * (40 * 20 - opening)
    return top + pillars + walls + 4 * STUD


def _wedge_volume() -> float:
    root2 = math.sqrt(2)
    outline = 60 * 60 - 40 * 40 / 2
    inside = 52 * 52 - (32 + 4 * root2) ** 2 / 2  # the inner square less the cut 4 further in
    notches = 2 * 12 * 4
    rib = 2 * root2 * 4
    return outline * 4 + (outline - inside - notches + rib) * 4 + 3 * A16 * 28 * 4 + 6 * STUD


EXACT = {
    # round plate: disc 10 x 3, tube 8/6 x 5, stud
    "6141": A16 * (100 * 3 + 28 * 5) + STUD,
    # round brick: top 10/4 x 4, sleeve 10/8 x 15, tube 8/6 x 20, hollow stud
    "3062b": A16 * (84 * 4 + 36 * 15 + 28 * 20) + HOLLOW_STUD,
    # grille: three top bars, walls under them, rib 8 x 2 x 4
    "2412b": 3 * 40 * 4 * 4 + (40 * 20 - 32 * 12) * 4 + 8 * 2 * 4,
    # jumper: plate 1 x 2 shell, bar, hollow stud
    "3794b": 40 * 20 * 8 - 32 * 12 * 4 + BAR * 4 + HOLLOW_STUD,
    # cheese: pentagon (20 x 15.6 less the triangle over the slope) x 20 less the cavity 12 x 12
    # (ceiling 4 over the front, 11.2 over the back)
    "54200": (20 * 15.6 - (15.6 - 4) ** 2 / 0.6 / 2) * 20 - 12 * (4 + 11.2) / 2 * 12,
    # headlight: top, side walls, lip, back wall, front wall, two studs
    "4070": 20 * 4 * 16 + 2 * 4 * 20 * 16 + 20 * 4 * 4 + 12 * 8 * 4 + 12 * 16 * 4 + 2 * STUD,
    # brackets: top, hanging plate, back wall, side walls, two ribs, bar, studs
    "99781": 40 * 4 * 20 + 40 * 20 * 4 + 40 * 4 * 4 + 2 * 4 * 4 * 16 + 2 * 4 * 4 * 4 + BAR * 4 + 4 * STUD,
    "44728": 40 * 4 * 20 + 40 * 40 * 4 + 40 * 4 * 4 + 2 * 4 * 4 * 16 + 2 * 4 * 4 * 4 + BAR * 4 + 6 * STUD,
    "3659": _arch_volume(),
    "2450": _wedge_volume(),
}


@pytest.mark.parametrize("number", NEW)
def test_new_part_volume_is_its_solids(embedded_reader, number):
    """The divergence sum is the volume of the solids the part is built of (they touch, never
    overlap)."""
    assert load_part(embedded_reader, number).volume_ldu3 == pytest.approx(EXACT[number], rel=1e-4)


def test_headlight_and_bracket_side_studs_face_front(embedded_reader):
    for number, rows in (("4070", 1), ("99781", 1), ("44728", 2)):
        side = [c for c in load_part(embedded_reader, number).studs if c.axis == (0.0, 0.0, -1.0)]
        assert len(side) == (1 if number == "4070" else 2 * rows)
        assert {c.pos[2] for c in side} == ({-6.0} if number == "4070" else {-14.0})


def _unbalanced(tris: np.ndarray) -> int:
    count = Counter()
    for tri in np.round(tris, 3):
        pts = [tuple(p) for p in tri]
        for a, b in ((0, 1), (1, 2), (2, 0)):
            count[(pts[a], pts[b])] += 1
            count[(pts[b], pts[a])] -= 1
    return sum(1 for v in count.values() if v != 0)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_prism_is_closed_and_outward(axis):
    mesh = Mesh()
    pentagon = [(0.0, 0.0), (4.0, 0.0), (5.0, 3.0), (2.0, 5.0), (-1.0, 3.0)]
    prism(mesh, pentagon, axis, -2.0, 5.0)
    tris = np.array([t for f in mesh.faces for t in (
        [f[:3]] if len(f) == 3 else [(f[0], f[1], f[2]), (f[0], f[2], f[3])])], dtype=float)
    assert _unbalanced(tris) == 0
    assert np.linalg.det(tris).sum() / 6 == pytest.approx(_polygon_area(pentagon) * 7)
