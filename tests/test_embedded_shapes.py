"""The embedded library's shapes beyond boxes (round plate, round bricks 1 x 1 and 2 x 2, cone,
grille tile, jumper plate, cheese slopes 1 x 1 and 1 x 2, headlight brick, brackets, arch,
corner-cut plate, corner plate, technic brick) and the plates and tiles added with them, against
the real parts in LDraw's complete.zip beside the checkout: size, studs, sockets, symmetry and
volume; their exact volumes; and the convex prism, lathe and bored prism emitters they are partly
built with. Closed, outward geometry for every part is checked in test_embedded_generator.py
(`test_part_closed_with_positive_volume`).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from factory.embedded.arch import arch_line
from factory.embedded.catalog import BY_NUMBER
from factory.embedded.geometry import Mesh, bored_prism, lathe, prism
from factory.ldraw import Library, Reader
from factory.parts import load_part

from ldraw_support import LIBRARY_ZIP

REAL_ZIP = LIBRARY_ZIP

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
    "3032": "3032",
    "4477": "4477",
    "6636": "6636",
    "4162": "4162",
    "2420": "2420",
    "85984": "85984",
    "4589": "4589",
    "3941": "3941",
    "3700": "3700",
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
                     "arch", "wedge", "plate", "tile", "corner_plate", "cone", "technic_brick"}


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
    front wall behind it. Of the parts added since, the plates and tiles come 0.5-3% under, as the
    library's other plates do (3032 the most); the others within 1.5%."""
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


def _ring(r: float, k: int) -> tuple[float, float]:
    """Corner k of the 16-gon of circumradius r (0 at +x, turning toward +z)."""
    return r * math.cos(math.pi * k / 8), r * math.sin(math.pi * k / 8)


def _axle_piece() -> float:
    """One of the four pieces round an axle hole: a quarter of the 16-gon of radius 6 less the two
    half arms in it (2 wide, each a trapezoid from the centre to the 16-gon's side, which the arm's
    side z=2 meets at x = 6 - 2 (1 - cos 22.5) / sin 22.5), less their 2 x 2 overlap."""
    p = 6 - 2 * (1 - math.cos(math.pi / 8)) / math.sin(math.pi / 8)
    return A16 * 36 / 4 - (2 * (6 + p) - 4)


def _lobe() -> float:
    """A lobe at the foot of the round brick 2 x 2: the 16-gon of radius 20 beyond x=16."""
    (x1, z1), (x2, z2) = _ring(20, 1), _ring(20, 2)
    zc = z1 + (x1 - 16) / (x1 - x2) * (z2 - z1)
    return _polygon_area([(16, -zc), (x1, -z1), (20, 0), (x1, z1), (16, zc)])


def _housing() -> float:
    """The technic brick's housing in (x, y): 16 wide from the top (y=4) to the hole's axis
    (y=10), then the 16-gon of radius 8 about the axis, cut flat at y=18 for x within 4."""
    lower = [(8 * math.cos(math.pi * k / 8), 10 + 8 * math.sin(math.pi * k / 8)) for k in (1, 2)]
    return _polygon_area([(-8, 4), (8, 4), (8, 10), *lower, (4, 18), (-4, 18),
                          *[(-x, y) for x, y in reversed(lower)], (-8, 10)])


def _plate(nx: int, nz: int, h: float, studs: int, tubes: int, bars: int) -> float:
    return (nx * 20 * nz * 20 * h - (nx * 20 - 8) * (nz * 20 - 8) * (h - 4) + studs * STUD
            + (tubes * A16 * 28 + bars * BAR) * (h - 4))


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
    "3032": _plate(6, 4, 8, 24, 15, 0),
    "4477": _plate(10, 1, 8, 10, 0, 9),
    "6636": _plate(6, 1, 8, 0, 0, 5),
    "4162": _plate(8, 1, 8, 0, 0, 7),
    # corner plate: top over 3 cells, walls (the L less the inner L 32 x 12 + 12 x 20), 2 bars, studs
    "2420": 1200 * 4 + (1200 - (32 * 12 + 12 * 20)) * 4 + 2 * BAR * 4 + 3 * STUD,
    # cheese 1 x 2: the 1 x 1's profiles 40 and 32 wide, and a bar up to the ceiling over its axis
    # (y=-7.6): a bar and a collar cut by one plane hold as much as a bar to its height at the centre
    "85984": (20 * 15.6 - (15.6 - 4) ** 2 / 0.6 / 2) * 40 - 12 * (4 + 11.2) / 2 * 32 + BAR * 7.6,
    # cone: the lathe (cone r 6 to 10 over 19, base r 8 x 5, less the bore r 4 x 12 and the cavity
    # r 6 x 12), the axle hole's pieces (6 tall), the hollow stud
    "4589": A16 * (19 * (36 + 60 + 100) / 3 + 5 * 64 - 12 * 16 - 12 * 36) + 4 * 6 * _axle_piece() + HOLLOW_STUD,
    # round brick 2 x 2: top 20/6 x 4, wall 20/16 x 16, column 8/6 x 16, tube 8/6 x 4, the axle
    # hole's pieces 20 tall, four lobes 4 tall, four studs
    "3941": (A16 * (364 * 4 + 144 * 16 + 28 * 16 + 28 * 4) + 4 * 20 * _axle_piece() + 4 * 4 * _lobe()
             + 4 * STUD),
    # technic brick: top, long walls less the hole, end walls, housing less the hole, bar 6 tall,
    # two hollow studs
    "3700": (40 * 20 * 4 + 2 * (40 * 20 - A16 * 36) * 4 + 2 * 4 * 12 * 20 + (_housing() - A16 * 36) * 12
             + BAR * 6 + 2 * HOLLOW_STUD),
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


def _closed_volume(mesh: Mesh) -> tuple[int, float]:
    tris = np.array([t for f in mesh.faces for t in (
        [f[:3]] if len(f) == 3 else [(f[0], f[1], f[2]), (f[0], f[2], f[3])])], dtype=float)
    return _unbalanced(tris), float(np.linalg.det(tris).sum() / 6)


def test_lathe_is_closed_and_outward():
    """A profile that is not convex, touching the axis: a cone on a cylinder, bored from below."""
    mesh = Mesh()
    lathe(mesh, [(0.0, 0.0), (5.0, 10.0), (5.0, 14.0), (3.0, 14.0), (3.0, 12.0), (0.0, 12.0)])
    unbalanced, volume = _closed_volume(mesh)
    assert unbalanced == 0
    assert volume == pytest.approx(A16 * (10 * 25 / 3 + 4 * 25 - 2 * 9), rel=1e-4)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_bored_prism_is_closed_and_outward(axis):
    """A hole touching one side of the outline, as the technic brick's touches its top."""
    mesh = Mesh()
    outline = [(-8.0, 4.0), (8.0, 4.0), (8.0, 12.0), (3.0, 18.0), (-8.0, 16.0)]
    bored_prism(mesh, outline, (0.0, 10.0), 6.0, axis, -3.0, 5.0)
    unbalanced, volume = _closed_volume(mesh)
    assert unbalanced == 0
    assert volume == pytest.approx((_polygon_area(outline) - A16 * 36) * 8, rel=1e-4)
