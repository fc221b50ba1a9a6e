"""Shallow overlaps measured again in the parts themselves (`physics.solid_overlap`)."""

from __future__ import annotations

import numpy as np
import pytest

from ldraw_support import LIBRARY_ZIP, needs_ldraw
from factory.ldraw import get_reader
from factory.parts import load_part
from factory.physics.collide import CollisionScene
from factory.physics.solid_overlap import PITCH_LDU, REFINE_LDU, corrected, deepest_solid, solid_depth
from factory.physics.structure import Placed, Structure
from factory.pose import Pose


def _pieces_depth(a, a_pose: Pose, b, b_pose: Pose) -> float:
    scene = CollisionScene(Structure([Placed(b, 4, b_pose)]), [(a, Pose.identity())], 1e6)
    return scene.penetration(a_pose, set())[0]


@pytest.mark.parametrize("overlap", [0.55, 0.7, 1.0])
@pytest.mark.parametrize("phase", [0.0, 0.1, 0.2])
def test_a_real_overlap_of_box_parts_keeps_its_exact_depth(embedded_reader, overlap, phase):
    # Two 2x4 bricks side by side, pushed `overlap` into one another (a sub-pitch `phase` puts the
    # faces anywhere between grid points). Their pieces are the bricks: the grid's two measures
    # agree, and the pieces' exact depth stands, past the tolerance (0.5) where it is.
    brick = load_part(embedded_reader, "3001")
    a = Pose(np.eye(3), [phase, 0.0, 0.0])
    b = Pose(np.eye(3), [phase + 80.0 - overlap, 0.0, 0.0])
    pieces = _pieces_depth(brick, b, brick, a)
    assert pieces == pytest.approx(overlap, abs=1e-3)
    solid, grown = solid_depth(brick, b, brick, a)
    assert abs(solid - grown) <= 1e-9  # the pieces are the part: the same points on the grid
    assert abs(solid - overlap) <= 2 * PITCH_LDU  # a grid measure: within about a pitch either way
    assert deepest_solid([(brick, b)], [(brick, a)], [pieces], 0.5) == pytest.approx(overlap, abs=1e-3)


def test_parts_apart_or_stacked_on_studs_do_not_overlap(embedded_reader):
    brick = load_part(embedded_reader, "3001")
    base = Pose(np.eye(3), [0.0, 0.0, 0.0])
    assert solid_depth(brick, Pose(np.eye(3), [81.0, 0.0, 0.0]), brick, base) == (0.0, 0.0)
    # On its studs: the studs stand in the upper brick's hollow, which is no solid.
    on = Pose(np.eye(3), [0.0, -24.0, 0.0])
    solid, _ = solid_depth(brick, on, brick, base)
    assert solid == 0.0


def test_pieces_reaching_past_the_solids_are_measured_by_the_solids():
    # What pieces reach past the part on the grid comes off their exact depth.
    assert corrected(1.2, (0.25, 1.25)) == pytest.approx(0.25)
    assert corrected(1.2, (0.75, 1.25)) == pytest.approx(0.75)
    assert corrected(0.6, (0.25, 0.25)) == pytest.approx(0.6)


@needs_ldraw
def test_a_wing_over_curved_slopes_is_judged_on_the_parts_not_their_pieces():
    # A wing plate 43719 turned about Y, over two curved slopes 50947 whose rounded tops its
    # underside follows: the pieces (faithful where sampled, 1.5 LDU apart) overlap 1.09 LDU past
    # the tolerance; in the parts themselves nothing overlaps, and what the pieces reach past the
    # solids comes off their depth. Pushed 1.5 LDU further down, the overlap is the parts' own.
    reader = get_reader(str(LIBRARY_ZIP))
    wing, slope = load_part(reader, "43719"), load_part(reader, "50947")
    turned = np.diag([-1.0, 1.0, -1.0])
    quarter = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    slopes = [Pose(quarter, [x, -8.0, -40.0]) for x in (-30.0, 30.0)]
    drawn = Pose(turned, [0.0, -16.0, 0.0])
    pieces = [_pieces_depth(wing, drawn, slope, at) for at in slopes]
    assert all(0.9 < p <= REFINE_LDU for p in pieces)
    parts = deepest_solid([(wing, drawn)], [(slope, at) for at in slopes], pieces, 0.5)
    assert parts is not None and parts <= 0.5
    pressed = Pose(turned, [0.0, -14.5, 0.0])
    deeper = [_pieces_depth(wing, pressed, slope, at) for at in slopes]
    assert deepest_solid([(wing, pressed)], [(slope, at) for at in slopes], deeper, 0.5) > 0.5


def test_points_in_pieces_are_those_a_box_then_planes_test_of_every_piece_finds(real_reader):
    """`in_pieces` takes each piece's points by the x-sorted slice its box spans: the answer is that
    of testing every point against every piece's box and planes, for a part turned off its axes
    too, its mated studs left out."""
    from factory.physics.geometry import collision_shape
    from factory.physics.solid_overlap import _free_studs, _grids, in_pieces

    rng = np.random.default_rng(4)
    for name, pose in (("3701", Pose(np.eye(3), [3.0, -8.0, 1.0])),
                       ("3062b", Pose(np.array([[0.8, 0, 0.6], [0, 1, 0], [-0.6, 0, 0.8]]), [0.0, 0.0, 0.0]))):
        part = load_part(real_reader, name)
        tris = part.flat.triangles.reshape(-1, 3)
        local = rng.uniform(tris.min(0) - 3, tris.max(0) + 3, size=(20000, 3))
        mated = pose.apply(np.array([a for a, _ in collision_shape(part).stud_at[:1]], float).reshape(-1, 3))
        _, body, studs = _grids(part)
        free = [f for f, keep in zip(studs, _free_studs(part, pose, mated)) if keep]
        want = np.zeros(len(local), bool)
        for planes, lo, hi in body + free:
            box = np.all((local >= lo) & (local <= hi), axis=1)
            want |= box & ((local @ planes[:, :3].T + planes[:, 3]).max(axis=1) <= 0.0)
        got = in_pieces(part, pose, local, mated)
        assert np.array_equal(got, want), name
        assert 0 < got.sum() < len(local)
