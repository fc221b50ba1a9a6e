"""Gear teeth found from real gears' drawings, and meshing gears judged as meshing: drawn at a turn
where their teeth stand in each other's way (as designs draw them), they are placed, while a gear
whose body reaches into the other is still a collision."""

from __future__ import annotations

import numpy as np
import pytest

from factory.gears import meshes, part_teeth
from factory.ldraw.library import Library
from factory.ldraw.reader import Reader
from factory.parts import load_part
from factory.physics.check import check_units
from factory.physics.solid_overlap import solid_depth
from factory.physics.structure import Placed, Structure
from factory.pose import Pose
from factory.symmetry import rotation_about
from ldraw_support import LIBRARY_ZIP

ALONG_Z = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # an axle's X axis along Z


@pytest.fixture(scope="module")
def lib():
    if not LIBRARY_ZIP.is_file():
        pytest.skip(f"LDraw's complete.zip is not at {LIBRARY_ZIP}")
    reader = Reader(Library.from_path(LIBRARY_ZIP))

    def at(name, x, y, z, R=np.eye(3)):
        return Placed(load_part(reader, name), 4, Pose(np.array(R, float), [x, y, z]))

    at.part = lambda name: load_part(reader, name)
    return at


def test_teeth_are_counted_from_the_drawing(lib):
    counts = {name: [t.count for t in part_teeth(lib.part(name))]
              for name in ("3647", "4019", "3648b", "3649", "32269", "32270")}
    assert counts == {"3647": [8], "4019": [16], "3648b": [24], "3649": [40], "32269": [20], "32270": [12]}
    # The Technic module: tip radii 1.25 LDU a tooth plus an addendum, roots as far inside.
    for name, teeth in (("3647", 8), ("3648b", 24), ("3649", 40)):
        (t,) = part_teeth(lib.part(name))
        assert 1.25 * teeth + 2.0 < t.tip < 1.25 * teeth + 3.0 and 1.25 * teeth - 3.5 < t.root < 1.25 * teeth
    # Round parts, a beam, a ribbed bush, an axle connector and a pin have no teeth.
    for name in ("3941", "6141", "32524", "3713", "6538b", "2780", "3706", "3700"):
        assert part_teeth(lib.part(name)) == (), name


def test_only_holes_through_the_middle_of_a_part_are_searched_for_teeth(lib, monkeypatch):
    """`--parts all` spent most of 24 minutes of one object in teeth searches (a pass over a part's outline for
    each of its hole axes); a gear's teeth ring its part, so only holes through the middle of the
    part's box are searched: a beam 7 has 7 holes and one through its middle, a 40 tooth gear
    still has its ring."""
    from factory import gears

    searched = []
    real = gears._ring
    monkeypatch.setattr(gears, "_ring", lambda points, centre, u: searched.append(tuple(centre)) or real(points, centre, u))
    for name, rings, teeth in (("32524", 1, []), ("3649", 1, [40])):
        searched.clear()
        part = lib.part(name)
        gears.part_teeth.cache_clear()
        assert [t.count for t in gears.part_teeth(part)] == teeth and len(searched) == rings, (name, searched)


def test_gears_mesh_on_parallel_axes_at_their_pitch(lib):
    small, large = lib("3647", -20, 10, 25), lib("3648b", 20, 10, 25)
    assert meshes(small.part, small.pose, large.part, large.pose)
    # Closer, the hubs meet; farther than the tips reach, nothing meshes; turned to a right
    # angle, or beside each other along the axis, no teeth meet side by side.
    for x in (-13.0, -66.0):
        assert not meshes(small.part, Pose(np.eye(3), [x, 10, 25]), large.part, large.pose)
    assert not meshes(small.part, Pose(rotation_about([0, 1, 0], 90.0), [-20, 10, 25]), large.part, large.pose)
    assert not meshes(small.part, Pose(np.eye(3), [-20, 10, 50]), large.part, large.pose)
    # A round part as wide as a gear is not a gear.
    assert not meshes(lib.part("3941"), Pose(np.eye(3), [-20, 10, 25]), large.part, large.pose)


def geared_base(lib, driven, left_axle=True):
    """A Technic brick 1x4 (3701) on a 2x4 brick, an axle 3 (4519) through each outer hole (x = -20
    and 20, along Z from -20 to 40; the left one only with `left_axle`), and `driven` on the right
    one, built in turn."""
    structure = Structure([lib("3001", 0, 24, -10)])
    axles = [lib("4519", x, 10, 10, ALONG_Z) for x in ((-20, 20) if left_axle else (20,))]
    for placed in (lib("3701", 0, 0, 0), *axles, driven):
        (v,) = check_units(structure, [[placed]], "cpu", floor_y=48.0)
        assert v.ok, v
        structure.add(placed, v.links(len(structure)))
    return structure


def test_a_gear_drawn_tooth_on_tooth_with_the_gear_it_drives_is_placed(lib):
    # An 8 tooth gear on the left axle, 40 LDU from the 24 tooth gear on the right one: at their
    # catalogue turn their teeth stand 2.75 LDU in each other (a turn of the large one by half a
    # tooth, 7.5 degrees, clears them); the gear is held by its axle and meshes.
    structure = geared_base(lib, lib("3648b", 20, 10, 25))
    small = lib("3647", -20, 10, 25)
    large = structure.placed[-1]
    assert solid_depth(small.part, small.pose, large.part, large.pose)[0] > 2.5
    turned = Pose(rotation_about([0, 0, 1], 7.5), large.pose.t)
    assert solid_depth(small.part, small.pose, large.part, turned)[0] == 0.0
    (v,) = check_units(structure, [[small]], "cpu", floor_y=48.0)
    assert v.ok and v.stable and not v.collision, v
    assert [(l.kind, l.b) for l in v.joints] == [("technic-axle", 2)], v
    # With no axle of its own, the gear that meshes is held by nothing (the large gear turns it,
    # and holds it nowhere); a 16 tooth gear in its place reaches with its body, not only its
    # teeth, into the large gear's teeth (their pitch radii add up to 50 LDU, not 40).
    structure = geared_base(lib, lib("3648b", 20, 10, 25), left_axle=False)
    (v,) = check_units(structure, [[small]], "cpu", floor_y=48.0)
    assert v.reason == "no-connection" and not v.collision and not v.joints, v
    (v,) = check_units(structure, [[lib("4019", -20, 10, 25)]], "cpu", floor_y=48.0)
    assert v.reason == "collision", v
