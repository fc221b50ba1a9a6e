"""Parts of the real library: size, mass, studs, sockets found from geometry, symmetry."""

from __future__ import annotations

import numpy as np
import pytest

from factory.parts import load_part
from factory.symmetry import find_symmetry, rotation_about

from ldraw_support import LDRAW, needs_ldraw

pytestmark = needs_ldraw


def kinds(part):
    out = {}
    for s in part.sockets:
        out[s.kind] = out.get(s.kind, 0) + 1
    return out


def test_brick_2x4(real_reader):
    p = load_part(real_reader, "3001")
    assert p.bbox.tolist() == [[-40, -4, -20], [40, 24, 20]]
    assert len(p.studs) == 8 and kinds(p) == {"stud": 8, "tube": 3}
    assert {c.pos for c in p.studs} == {(x, 0.0, z) for x in (-30.0, -10.0, 10.0, 30.0) for z in (-10.0, 10.0)}
    assert all(c.axis == (0.0, -1.0, 0.0) for c in p.studs + p.sockets)
    tubes = sorted(c.pos for c in p.sockets if c.kind == "tube")
    assert tubes == [(-20.0, 24.0, 0.0), (0.0, 24.0, 0.0), (20.0, 24.0, 0.0)]
    # The LDraw mesh: 80x24x40 shell with 4 LDU walls and top, studs and tubes as 16-gons.
    assert p.volume_ldu3 == pytest.approx(39_400, rel=0.02)
    assert 2.5 < p.mass_g < 2.8


@pytest.mark.parametrize(
    "name, studs, sockets",
    [
        ("3070b", 0, {"stud": 1}),  # tile: no studs, one socket
        ("3039", 2, {"stud": 4, "tube": 1}),  # 45° slope 2x2: studs on the top row only
        ("3004", 2, {"stud": 2}),  # 1x2 brick: bar between the sockets
        ("3024", 1, {"stud": 1}),
        ("3003", 4, {"stud": 4, "tube": 1}),
        ("3665", 2, {"stud": 1}),  # a ~Moved to stub: geometry of 3665a
        ("3020", 8, {"stud": 8, "tube": 3}),
        ("3068b", 0, {"stud": 4, "tube": 1}),
        # Wheel holder plates, their undersides open towards the pins: each stud is held between
        # the centre tube and one side wall only (two opposite sides), right under a stud on top.
        ("6157", 4, {"stud": 4}),
        ("11002", 4, {"stud": 4}),
        # A 1x4 brick without bars underneath: its middle studs' sockets have only the long walls.
        ("3066", 4, {"stud": 4}),
        # Between a 1x2 tile's long walls half a stud off its grid is no socket (no stud above).
        ("3069b", 0, {"stud": 2}),
    ],
)
def test_connection_points(real_reader, name, studs, sockets):
    p = load_part(real_reader, name)
    assert len(p.studs) == studs
    assert kinds(p) == sockets


def test_sockets_receive_studs_of_a_part_below(real_reader):
    """A 2x4 brick stacked on another: every socket of the upper sits on a stud of the lower."""
    p = load_part(real_reader, "3001")
    studs = {c.pos for c in p.studs}
    shifted = {(s.pos[0], s.pos[1] - 24.0, s.pos[2]) for s in p.sockets if s.kind == "stud"}
    assert shifted == studs


def test_moved_stub_reports_its_target(real_reader):
    assert load_part(real_reader, "3665").moved_to == "3665a.dat"


@pytest.mark.parametrize(
    "name, order, continuous",
    [("3001", 2, None), ("3003", 4, None), ("3024", 4, None), ("3039", 1, None), ("3004", 2, None),
     ("4073", 4, (0.0, -1.0, 0.0)), ("3062b", 4, (0.0, -1.0, 0.0))],
)
def test_symmetry_from_geometry(real_reader, name, order, continuous):
    sym = load_part(real_reader, name).symmetry
    assert sym.order == order and sym.continuous_axis == continuous
    assert np.allclose(sym.rotations[0], np.eye(3))
    if order == 2:  # a 2x4 brick maps onto itself turned half way about the vertical
        assert any(np.allclose(r, np.diag([-1.0, 1.0, -1.0])) for r in sym.rotations)


def test_symmetry_group_is_closed_under_composition(real_reader):
    rots = load_part(real_reader, "3003").symmetry.rotations
    for a in rots:
        for b in rots:
            assert any(np.allclose(a @ b, c) for c in rots)


def test_symmetry_of_a_rotated_point_set():
    pts = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 0, 2], [0, 0, -2], [0, 3, 0]])
    assert find_symmetry(pts).order == 2
    ring = np.array([rotation_about((0, 1, 0), a) @ [5.0, 0, 0] for a in np.arange(16) * 22.5])
    assert find_symmetry(ring).continuous_axis == (0.0, -1.0, 0.0)


def test_every_part_of_the_library_loads(real_reader):
    names = sorted(p.name for p in (LDRAW / "parts").glob("*.dat"))
    connected, unconnected_system = 0, []
    for name in names:
        part = load_part(real_reader, name)
        assert len(part.flat.triangles) > 0, name
        assert np.all(part.bbox[0] <= part.bbox[1]), name
        connected += bool(part.studs or part.sockets)
        title = (LDRAW / "parts" / name).read_text(errors="replace").split("\n", 1)[0]
        if title.split()[1:2] in (["Brick"], ["Plate"], ["Slope"]) and not (part.studs or part.sockets):
            unconnected_system.append(name)
    # The subset grows with the models it serves, so count what is there. Technic pins,
    # axles, tyres, rims and minifig pieces have no stud connections; every brick, plate and
    # slope has.
    assert len(names) >= 200, f"only {len(names)} parts under {LDRAW / 'parts'}"
    assert connected >= 0.75 * len(names), f"{connected} of {len(names)} parts have studs or sockets"
    assert not unconnected_system, unconnected_system
