"""Studs in every direction: a part attaches to a side stud sideways, and its buildability sweep
runs along that stud's own axis."""

from __future__ import annotations

import numpy as np
import pytest

from factory.physics.attach import feasible_poses
from factory.physics.structure import Structure
from factory.physics.sweep import approach
from conftest import at, part
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
    wall = at("3005", 10, -24, -70)  # a 1x1 brick standing in the plate's way out along -z
    r = swept(BASE + [wall], [plate])
    assert r.buildable is False and r.reason == "blocked" and r.blocked_by == (2,)
