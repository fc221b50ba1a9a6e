"""Settling a predicted placement (`factory.physics.settle`) on small structures built inline from the
embedded library (LDraw frame, y down: a brick's pose is its top face, its body 24 LDU below; a
plate's 8). Each case has a known answer: dropped onto a plate, half off a tower's edge, 2 LDU off a
stud position, inside another part, exactly right, turned on the studs."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from factory import Pose
from factory.physics.collide import CollisionScene
from factory.physics.mass import part_mass_properties
from factory.physics.settle import (OUTCOMES, RESTING_LDU, SettleConfig, SettleStats, settle, settle_all, settle_model,
                                    still)
from factory.physics.snap import SnapRule, SnapTargets
from factory.physics.structure import Structure
from factory.symmetry import rotation_about
from ldraw_support import at, part

I3 = np.eye(3)
SEATED = Pose(I3, [0, -24, 0])
"""A 2x4 brick on the 4x4 plate `PLATE`, on all 8 of its studs."""

pytestmark = pytest.mark.usefixtures("isolated_cache")


def plate() -> Structure:
    return Structure([at("3031", 0, 0, 0)])


def tower() -> Structure:
    """Three 2x4 bricks stacked on the table (its top face at y = -48, the table at y = 24)."""
    return Structure([at("3001", 0, 0, 0), at("3001", 0, -24, 0), at("3001", 0, -48, 0)])


def test_a_brick_30_ldu_above_a_flat_plate_falls_onto_it():
    got = settle(plate(), part("3001"), Pose(I3, [0, -54, 0]))
    assert got.outcome == "rests-connected"
    assert got.pose.allclose(SEATED)
    assert got.moved_ldu == pytest.approx(30.0)
    assert got.connections == 8
    assert 0.0 < got.seconds < 0.2  # it fell first: a 30 LDU drop takes 0.05 s


def test_a_brick_half_off_the_edge_of_a_tower_falls_to_the_ground():
    s = tower()
    brick = part("3001")
    got = settle(s, brick, Pose(I3, [50, -78, 0]))  # 10 LDU off the nearest stud positions, 6 above
    assert got.outcome == "fell-off" and got.at_rest
    assert got.connections == 0
    lowest = float(got.pose.apply(brick.hull_points)[:, 1].max())
    assert lowest == pytest.approx(s.floor_y(), abs=0.5)  # on the table
    assert got.moved_ldu > 60.0


def test_a_brick_2_ldu_off_a_valid_stud_position_snaps_onto_it():
    got = settle(plate(), part("3001"), Pose(I3, [2, -24, 0]))
    assert got.outcome == "rests-connected"
    assert got.pose.allclose(SEATED)
    assert got.moved_ldu == pytest.approx(2.0)
    assert got.seconds == 0.0  # snapped before simulating


def test_a_brick_inside_another_part_collides():
    s = Structure([at("3001", 0, 0, 0)])
    inside = Pose(I3, [0, 0, 0])
    got = settle(s, part("3001"), inside)
    assert got.outcome == "collides"
    assert got.pose.allclose(inside) and got.moved_ldu == 0.0 and got.seconds == 0.0


def test_a_brick_overlapping_another_a_little_is_pushed_out():
    s = Structure([at("3001", 0, 0, 0)])
    brick = part("3001")
    pose = Pose(rotation_about((0, 1, 0), 30), [0, 0, 55])  # a corner 2.2 LDU into the other brick
    scene = CollisionScene(s, [(brick, Pose.identity())], s.floor_y())
    assert 0.5 < scene.penetration(pose, set())[0] < SettleConfig().collides_ldu
    got = settle(s, brick, pose)
    assert got.outcome == "pushed-out"
    assert scene.penetration(got.pose, set())[0] <= 0.5
    assert got.moved_ldu > 1.0


def test_a_brick_pushed_out_onto_the_studs_it_was_in_is_pushed_out():
    # Predicted turned (no connection to snap to) and 2.5 LDU down into the plate's studs: pushed
    # up, it rests on their tops. Resting there its inset pieces touch the studs', so the overlap
    # measure reads the two insets (RESTING_LDU), not an overlap of the real surfaces.
    s, brick = plate(), part("3001")
    pose = Pose(rotation_about((0, 1, 0), 45), [0, -25.5, 0])
    scene = CollisionScene(s, [(brick, Pose.identity())], s.floor_y())
    assert 0.5 < scene.penetration(pose, set())[0] < SettleConfig().collides_ldu
    got = settle(s, brick, pose)
    assert got.outcome == "pushed-out" and got.at_rest and got.connections == 0
    assert got.pose.t[1] == pytest.approx(-28.0, abs=0.6)  # on the studs' tops, as resting there
    assert 0.5 < scene.penetration(got.pose, set())[0] <= 0.5 + RESTING_LDU


def test_a_correct_pose_rests_connected_and_unchanged():
    got = settle(plate(), part("3001"), SEATED)
    assert got.outcome == "rests-connected"
    assert got.pose.allclose(SEATED) and got.moved_ldu == 0.0
    assert got.connections == 8 and got.seconds == 0.0


def test_a_brick_turned_45_degrees_rests_on_the_studs_unconnected():
    got = settle(plate(), part("3001"), Pose(rotation_about((0, 1, 0), 45), [0, -54, 0]))
    assert got.outcome == "rests-unconnected" and got.at_rest
    assert got.connections == 0
    # On the studs' tops (4 LDU above its seat), half an LDU lower: the two pieces' insets.
    assert got.pose.t[1] == pytest.approx(-28.0, abs=0.6)


def test_settling_is_deterministic():
    a = settle(tower(), part("3001"), Pose(I3, [50, -78, 0]))
    b = settle(tower(), part("3001"), Pose(I3, [50, -78, 0]))
    assert a.outcome == b.outcome and a.outcome in OUTCOMES
    assert np.array_equal(a.pose.R, b.pose.R) and np.array_equal(a.pose.t, b.pose.t)
    assert (a.moved_ldu, a.seconds, a.connections) == (b.moved_ldu, b.seconds, b.connections)


def test_settle_all_says_how_much_of_its_time_was_simulation():
    # Decided before simulating (exactly right: snapped at once; deep inside: collides) and two
    # drops: the stats count the simulated ones and time their steps within the whole call.
    brick, stats = part("3001"), SettleStats()
    got = settle_all([(plate(), brick, SEATED, None), (tower(), brick, Pose(I3, [0, -48, 0]), None),
                      (plate(), brick, Pose(I3, [0, -54, 0]), None), (tower(), brick, Pose(I3, [50, -78, 0]), None)],
                     stats=stats)
    assert [g.seconds > 0 for g in got] == [False, False, True, True]
    assert stats.simulated == 2
    assert 0.0 < stats.step_s < stats.total_s


def test_a_path_passing_no_candidate_is_skipped_whole():
    # `along` bounds `near` over a path straight between points: True wherever a pose on it may
    # snap, so False lets the poses go untested.
    targets, rule = SnapTargets.of(plate(), part("3001")), SnapRule()
    above = np.array([[0.0, -200.0, 0.0], [0.0, -150.0, 0.0]])  # far above the plate
    through = np.array([[0.0, -60.0, 0.0], [0.0, -12.0, 0.0]])  # both ends out of reach, the seat between
    assert not targets.along(above, rule) and targets.along(through, rule)
    assert not targets.near(Pose(I3, through[0]), rule) and not targets.near(Pose(I3, through[1]), rule)
    assert targets.near(Pose(I3, [0.0, -24.0, 0.0]), rule)


def test_the_rest_rule_bounds_each_window_by_its_last_pose():
    # Windows of 11 poses, many at once: the centre of mass within 0.1 LDU and the turn within 0.5
    # degrees of the last pose, whatever the earlier ones' order.
    config = SettleConfig()
    com = np.array([20.0, -12.0, 0.0])  # off the origin: a turn about the origin moves it

    def window(dt=0.0, degrees=0.0, first_only=False):
        R = np.repeat(I3[None], 11, 0)
        t = np.zeros((11, 3))
        k = slice(0, 1) if first_only else slice(0, 10)
        R[k] = rotation_about((0, 1, 0), degrees)
        t[k] = (dt, 0.0, 0.0)
        return R, t

    cases = [window(), window(0.09), window(0.11), window(0.11, first_only=True),
             window(degrees=0.4), window(degrees=0.6, first_only=True)]
    R = np.array([c[0] for c in cases])
    t = np.array([c[1] for c in cases])
    assert still(R, t, com, config).tolist() == [True, True, False, False, False, False]
    # 0.4 degrees about the origin moves the centre of mass 20 * 0.007 = 0.14 LDU; about the
    # centre of mass itself (each pose's translation making up for the turn) it moves nothing.
    about_com = R.copy(), t.copy()
    turned = rotation_about((0, 1, 0), 0.4)
    about_com[0][4, :10], about_com[1][4, :10] = turned, com - turned @ com
    assert still(*about_com, com, config)[4]
    assert still(R[:1], t[:1], np.array([com]), config).tolist() == [True]


def test_poses_tested_together_get_what_each_gets_alone():
    # A path is tested pose by pose in one pass (`near_many`): each pose's pairs and connection
    # points must stay its own, in a 2x4 brick's many candidates on a plate.
    targets, rule = SnapTargets.of(plate(), part("3001")), SnapRule()
    rng = np.random.default_rng(5)
    poses = [Pose(rotation_about((0, 1, 0), float(rng.uniform(-12, 12)) + 90.0 * int(rng.integers(4))),
                  np.array([20.0 * rng.integers(-2, 3), -24.0, 20.0 * rng.integers(-1, 2)]) + rng.normal(scale=2.0, size=3))
             for _ in range(40)]
    together = targets.near_many(np.array([p.R for p in poses]), np.array([p.t for p in poses]), rule)
    alone = [targets.near(p, rule) for p in poses]
    assert sum(map(bool, alone)) > 5 and sum(not a for a in alone) > 5  # poses that snap and poses that do not
    for a, b in zip(together, alone):
        assert [(c, d) for c, _, d in a] == [(c, d) for c, _, d in b]
        assert all(p.allclose(q, atol=0.0) for (_, p, _), (_, q, _) in zip(a, b))


def test_the_snapping_rule_bounds():
    targets = SnapTargets.of(plate(), part("3001"))
    rule = SnapRule()
    near = lambda pose: [p for _, p, _ in targets.near(pose, rule)]  # noqa: E731
    assert near(Pose(I3, [2.9, -24, 0]))[0].allclose(SEATED)
    assert not any(p.allclose(SEATED) for p in near(Pose(I3, [3.5, -24, 0])))
    assert near(Pose(I3, [0, -28.4, 0]))[0].allclose(SEATED)  # on the stud tops
    assert not any(p.allclose(SEATED) for p in near(Pose(I3, [0, -29, 0])))
    # Turned about its centre, a 2x4 brick's corner studs (31.6 LDU out) leave the 3 LDU first.
    assert near(Pose(rotation_about((0, 1, 0), 5.0), [0, -24, 0]))[0].allclose(SEATED)
    assert not any(p.allclose(SEATED) for p in near(Pose(rotation_about((0, 1, 0), 6.0), [0, -24, 0])))
    # A 1x1 plate's one stud stays put: the 10 degrees decide.
    one = SnapTargets.of(plate(), part("3024"))
    seat = Pose(I3, [10, -8, 10])
    assert one.near(Pose(rotation_about((0, 1, 0), 9.0), seat.t), rule)[0][1].allclose(seat)
    assert not one.near(Pose(rotation_about((0, 1, 0), 11.0), seat.t), rule)
    # Up to the part's symmetry: a 2x4 brick turned half round is the same placement, and the
    # snapped pose keeps the turn.
    half = rotation_about((0, 1, 0), 178.0)
    (first, *_) = near(Pose(half, [1, -24, 0]))
    assert np.allclose(first.t, SEATED.t) and np.allclose(first.R, rotation_about((0, 1, 0), 180.0), atol=1e-9)


def test_settle_model_holds_the_structure_fixed_and_the_part_free_with_its_mass():
    s = tower()
    brick = part("3001")
    scene = settle_model(s, brick, s.floor_y())
    m = scene.model
    assert isinstance(m, mujoco.MjModel)
    assert m.nbody == len(s) + 2 and m.njnt == 1 and m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert m.body_mass[scene.part_body] == pytest.approx(part_mass_properties(brick)[0])
    assert np.allclose(m.opt.gravity, [0, 0, -9.81])
    assert set(scene.owner.tolist()) == {-2, -1, 0, 1, 2}
