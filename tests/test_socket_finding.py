"""Socket finding does its work where sockets can be (`connections.find_sockets`): a baseplate of
LDraw's library gets its sockets well within the work budget, and real parts get the sockets a
plain search over every spot and every triangle finds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import factory.connections as connections
from factory.errors import LDrawLimitError
from factory.ldraw import get_reader
from factory.parts import load_part

from ldraw_support import LIBRARY_ZIP, needs_ldraw



def _plain_find_sockets(tris: np.ndarray, columns) -> list:
    """The rule of `find_sockets` as a plain search: every spot of the half-stud grid at every rim
    level, its rim measured against every rim face and its rays cast at every triangle of the part
    (no lookups, no level-wide pass, no budget). Rays and distances are `connections`' own."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    facing = (np.ptp(tris[:, :, 1], axis=1) < 1e-6) & (np.abs(n[:, 1]) > 1e-9)
    lo, hi = tris.min(axis=(0, 1)), tris.max(axis=(0, 1))
    xs = np.arange(np.ceil((lo[0] + 6) / 10), np.floor((hi[0] - 6) / 10) + 1) * 10
    zs = np.arange(np.ceil((lo[2] + 6) / 10), np.floor((hi[2] - 6) / 10) + 1) * 10
    columns = np.asarray(columns, float).reshape(-1, 2)
    rim_y = np.round(tris[facing, 0, 1], 3)
    down, up = np.array([0.0, 1.0, 0.0]), connections.UP
    found = []
    for y0 in np.unique(rim_y):
        rim = tris[facing][rim_y == y0][:, :, [0, 2]]
        for x in xs:
            for z in zs:
                if connections._distance_2d(rim, np.array([x, z])).min() > 7.0:
                    continue
                c = np.array([x, y0, z])
                disc = np.stack([x + connections._DISC[:, 0], np.full(len(connections._DISC), y0),
                                 z + connections._DISC[:, 1]], 1)
                below = np.concatenate([disc - [0, 0.05, 0], c + connections._CELL])
                if np.isfinite(connections.first_hits(tris, below, np.tile(down, (len(below), 1)))).any():
                    continue
                above = connections.first_hits(tris, disc + [0, 0.05, 0], np.tile(up, (len(disc), 1)))
                if (above < 3.55).any() or not np.isfinite(above).any():
                    continue
                touching = connections.first_hits(tris, np.tile(c + up * 2, (8, 1)), connections._DIRS8) <= 6.6
                under = bool((np.abs(columns - [x, z]).max(axis=1) < 1e-3).any())
                if touching.all():
                    found.append(((x, y0, z), "tube"))
                elif touching.sum() >= 3 or (under and connections._pinched(touching)):
                    found.append(((x, y0, z), "stud"))
    return found


def _plain_sockets_facing(tris: np.ndarray, studs) -> set:
    """`sockets_facing`'s directions (up, and each principal axis the studs point along), each
    searched plainly."""
    out = set()
    for key in {(0.0, -1.0, 0.0)} | {c.axis for c in studs if max(map(abs, c.axis)) > 0.999}:
        r = connections._turn_to_up(np.array(key))
        columns = [(r @ c.pos)[[0, 2]] for c in studs if (r @ c.axis) @ connections.UP > 0.999]
        for pos, kind in _plain_find_sockets(tris @ r.T, columns):
            p = r.T @ np.array(pos)
            out.add((tuple(connections._r(v) for v in p), tuple(connections._r(v) for v in key), kind))
    return out


@needs_ldraw
@pytest.mark.parametrize("name", [
    "3001",  # brick 2x4: tubes and anti-studs
    "3020",  # plate 2x4
    "3070b", "3069b",  # tiles
    "3039", "3040b",  # slopes
    "3700",  # Technic brick 1x2 with hole
    "3062b",  # round brick 1x1 with hollow stud
    "6141",  # round plate 1x1
    "3794b",  # jumper plate
    "99781", "44728",  # brackets: sockets at the back of their side studs too
    "4070",  # headlight brick: a socket in its back
    "3937", "3938",  # hinge base and top
])
def test_real_parts_get_the_sockets_a_plain_search_finds(real_reader, name):
    part = load_part(real_reader, name)
    tris = part.flat.triangles
    found = connections.sockets_facing(tris, part.studs, name)
    assert {(c.pos, c.axis, c.kind) for c in found} == _plain_sockets_facing(tris, part.studs)
    assert len(found) == len(set(found))


@pytest.mark.skipif(not LIBRARY_ZIP.is_file(), reason=f"LDraw's library is not at {LIBRARY_ZIP}")
def test_a_baseplate_gets_its_sockets_well_within_the_budget(monkeypatch):
    """Baseplate 16 x 32 (3857, 24,652 triangles): a thin plate with a flat bottom, no sockets.
    It needed more than 10^8 tests (refused); it needs about 1.5 x 10^5 now, so a budget of 10^6
    is plenty."""
    part = load_part(get_reader(str(LIBRARY_ZIP)), "3857")
    assert len(part.flat.triangles) > 20_000 and len(part.studs) == 512
    monkeypatch.setattr(connections, "MAX_SOCKET_WORK", 1_000_000)
    assert connections.sockets_facing(part.flat.triangles, part.studs, "3857.dat") == ()


def _shelves(k: int, levels: int) -> np.ndarray:
    """Shelves of k x k stud cells at `levels` heights, each a thin strip (a rim) beside a wall:
    no ray of a spot lies on a strip below, so no spot is dropped by the level-wide pass and every
    spot near a strip is probed on its own, against the strips and walls of every level."""
    out = []
    for level in range(levels):
        y = -4.0 * level
        for i in range(k):
            for j in range(k):
                x, z = i * 20.0, j * 20.0
                for q in ([[x - 10, y, z - 9.8], [x + 10, y, z - 9.8], [x + 10, y, z - 9.1], [x - 10, y, z - 9.1]],
                          [[x - 10, y, z - 10], [x - 10, y - 4, z - 10], [x + 10, y - 4, z - 10], [x + 10, y, z - 10]]):
                    out += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    return np.array(out)


def test_spots_probed_one_by_one_are_refused_past_the_budget(monkeypatch):
    tris = _shelves(3, 4)
    assert connections.sockets_facing(tris, []) == ()
    monkeypatch.setattr(connections, "MAX_SOCKET_WORK", 50_000)
    with pytest.raises(LDrawLimitError) as err:
        connections.sockets_facing(tris, [], "shelves.dat")
    assert "shelves.dat" in str(err.value) and "50,000 ray-triangle tests" in str(err.value)


def test_cross_is_numpys_to_the_bit():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(40, 1, 3)) * 10.0 ** rng.integers(-6, 6, (40, 1, 3))
    b = rng.normal(size=(1, 300, 3)) * 10.0 ** rng.integers(-6, 6, (1, 300, 3))
    assert np.array_equal(connections._cross(a, b), np.cross(a, b))
