"""Studs in every direction: a part attaches to a side stud sideways, and its buildability sweep
runs along that stud's own axis."""

from __future__ import annotations

import numpy as np
import pytest

from factory.physics.attach import feasible_poses
from factory.physics.structure import Structure
from factory.physics.sweep import PRESS_MIN_LDU, approach
from ldraw_support import at, part
from test_sweep import swept

pytestmark = pytest.mark.usefixtures("isolated_cache")

BASE = [at("3020", 0, 0, 0), at("4070", 10, -24, -10)]  # a headlight brick on a 2x4 plate; side stud to -z


def _sideways(structure: Structure, name: str):
    """The attachments of `name` that sit on the headlight brick's side stud (turned a quarter)."""
    side = np.array([0.0, 0.0, -1.0])
    out = []
    for pose in feasible_poses(structure, part(name)):
        down = pose.R @ np.array([0.0, 1.0, 0.0])  # the part's own down: toward what it sits on
        if np.allclose(down, -side, atol=1e-6) and pose.t[2] < -20:
            out.append(pose)
    return out


def test_a_plate_attaches_to_a_side_stud_and_comes_along_that_stud():
    headlight = part("4070")
    studs = [np.array(s.axis) for s in headlight.studs]
    assert any(np.allclose(a, [0, 0, -1]) for a in studs)  # the embedded headlight brick's side stud
    structure = Structure(BASE)
    poses = _sideways(structure, "3024")
    assert poses, "no attachment of a 1x1 plate onto the side stud"
    plate = at("3024", *poses[0].t, R=poses[0].R)
    found = approach(structure, [(plate.part, plate.pose)])
    assert found.direction is not None and np.allclose(found.direction, [0, 0, 1])  # along the stud, inward
    assert swept(BASE, [plate]).buildable


def test_a_side_attachment_is_blocked_by_a_part_in_front_of_it():
    structure = Structure(BASE)
    pose = _sideways(structure, "3024")[0]
    plate = at("3024", *pose.t, R=pose.R)
    wall = at("3005", 10, -24, -60)  # a 1x1 brick 18 LDU in front of the plate's stud, along -z
    r = swept(BASE + [wall], [plate])
    assert r.buildable is False and r.reason == "blocked" and r.blocked_by == (2,)
    # 28 LDU in front: room for a fingertip's end (`sweep.PRESS_MIN_LDU`), the plate brought in
    # from the side.
    r = swept(BASE + [at("3005", 10, -24, -70)], [plate])
    assert r.buildable and r.at_ldu == PRESS_MIN_LDU


def test_the_load_model_carries_a_side_stud_across_and_along_its_own_axis():
    """A 1x8 brick hung by an end socket on the headlight brick's side stud: lying level, the load
    grows with its reach from the stud (the weight's moment); standing up on it at a weak clutch,
    the side stud itself (headlight -> brick, axis -z) is the connection named failing."""
    from factory.physics.load_model import LoadConfig, load_model
    from factory.physics.statics import judge

    def verdict(pose, cfg=LoadConfig()):
        s = Structure(BASE + [at("3008", *pose.t, R=pose.R)])
        side = [c for c in s.connections if c[0] == 1 and c[1] == 2]
        assert len(side) == 1 and np.allclose(side[0][3], [0, 0, -1])  # the one stud, along its own axis
        return judge(load_model(s.placed, s.connections, s.floor_y(), [2], s.links, cfg), cfg)

    poses = _sideways(Structure(BASE), "3008")
    level: dict[float, list] = {}
    for p in poses:
        v = verdict(p)
        if np.isclose(p.t[1], -14) and v.reason != "unstable":  # lying level, not tipping the whole
            level.setdefault(abs(p.t[0] - 10), []).append(v)
    assert len(level) >= 3 and all(v.stands for vs in level.values() for v in vs)
    loads = [[v.load for v in level[r]] for r in sorted(level)]
    assert all(max(a) < min(b) for a, b in zip(loads, loads[1:]))
    upright = next(p for p in poses if p.t[1] < -60)
    weak = verdict(upright, LoadConfig(clutch_n=0.05))
    assert verdict(upright).stands and not weak.stands and weak.reason == "overload"
    assert (weak.failing[0].stud_part, weak.failing[0].socket_part) == (1, 2)
