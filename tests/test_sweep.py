"""Buildability sweeps on small structures built inline from the embedded library (LDraw frame, y
down: a brick's pose is its top face, its body 24 LDU below; a plate's 8). Each structure has a
known answer: reachable from above, under a roof, in a slot under an overhang, clamped between
studs and sockets, hanging from sockets, behind a blocker thinner than a step."""

from __future__ import annotations

import time

import numpy as np
import pytest

from factory import Pose
from factory.parts import box_corners
from factory.physics.attach import feasible_poses, lowest_y
from factory.physics.check import CheckConfig, _unit_connections
from factory.physics.collide import CollisionScene
from factory.physics.structure import Placed, Structure
from factory.physics.sweep import PRESS_LDU, SweepResult, approach, sweep
from factory.symmetry import rotation_about
from ldraw_support import at, part

I3 = np.eye(3)
TOL = CheckConfig().max_penetration_ldu


pytestmark = pytest.mark.usefixtures("isolated_cache")


def scene_for(structure: Structure, unit: list[Placed], floor_y: float | None = None):
    """The collision scene and connected set exactly as `check.check_units` builds them."""
    anchor = unit[0].pose
    rel = [(p.part, anchor.inverse() @ p.pose) for p in unit]
    scene = CollisionScene(structure, rel, floor_y if floor_y is not None else 1e6)
    world = [(p.part, p.pose) for p in unit]
    touched = {min(c[0], c[1]) for c in _unit_connections(structure, world) if min(c[0], c[1]) < len(structure)}
    return scene, world, touched


def swept(parts: list[Placed], unit: list[Placed], floor_y: float | None = None, **kw) -> SweepResult:
    """Sweep a unit whose final pose the collision check accepts (asserted: the sweep is for those)."""
    structure = Structure(parts)
    scene, world, touched = scene_for(structure, unit, floor_y)
    depth, _ = scene.penetration(unit[0].pose, touched)
    assert depth <= TOL, f"the final pose itself collides ({depth:.2f} LDU): not a sweep case"
    return sweep(scene, structure, world, touched, max_penetration_ldu=TOL, **kw)


def test_a_brick_on_top_of_a_wall_is_buildable_without_a_contact_query():
    wall = [at("3001", -80, 0, 0), at("3001", 0, 0, 0), at("3001", 80, 0, 0),
            at("3001", -40, -24, 0), at("3001", 40, -24, 0)]
    r = swept(wall, [at("3001", 0, -48, 0)])
    assert r.buildable and r.reason is None
    # Nothing but the two bricks it sits on is near its path: the box filter leaves no query.
    assert r.poses_checked == 0
    assert np.allclose(approach(Structure(wall), [(part("3001"), Pose(I3, [0, -48, 0]))]).direction, [0, 1, 0])


# A 2x8 base plate; two-brick-high walls of 2x2 bricks at x = -40 and 40 leave a 2x2 gap at x = 0.
GAP_WALLS = [at("3034", 0, 0, 0), at("3003", -40, -24, 0), at("3003", 40, -24, 0),
             at("3003", -40, -48, 0), at("3003", 40, -48, 0)]
ROOF = at("3795", 0, -56, 0)  # a 2x6 plate spanning both walls and the gap
GAP_BRICK = at("3003", 0, -24, 0)  # on the base plate, in the gap's lower course


def test_a_brick_pushed_under_a_roof_is_blocked_by_the_roof():
    r = swept(GAP_WALLS + [ROOF], [GAP_BRICK])
    assert r.buildable is False and r.reason == "blocked"
    assert r.blocked_by == (5,)  # the roof, not the walls the brick slides along
    assert r.depth_ldu > TOL
    # Met on the way down, within a step of where its walls (bottom at y = 0 seated) reach the
    # roof's top face (y = -56); the roof's studs before that stand in the brick's hollow
    # underside without touching it, which is no overlap.
    assert 54 - 2 < r.at_ldu < 56 and r.at_ldu + r.depth_ldu == pytest.approx(56, abs=0.5)


def test_the_same_gap_filled_before_the_roof_is_buildable():
    r = swept(GAP_WALLS, [GAP_BRICK])
    assert r.buildable and r.reason is None and r.blocked_by == ()
    # ... and the roof can then go on top.
    assert swept(GAP_WALLS + [GAP_BRICK], [ROOF]).buildable


# A 2x8 base plate; a 2x2 plate at x = 60 holds a 2x4 plate (x 0..80) one plate above the base,
# leaving a one-plate-high slot over x 0..40.
SLOT = [at("3034", 0, 0, 0), at("3022", 60, -8, 0), at("3020", 40, -16, 0)]


def test_a_tile_slid_into_a_one_plate_slot_under_an_overhang_is_blocked():
    # A tile has no studs: it sits on the base's studs and only touches the overhang's underside.
    r = swept(SLOT, [at("3068b", 20, -8, 0)])
    assert r.buildable is False and r.reason == "blocked" and r.blocked_by == (2,)
    assert approach(Structure(SLOT), [(part("3068b"), Pose(I3, [20, -8, 0]))]).reason is None


def test_a_plate_between_studs_below_and_sockets_above_is_clamped():
    plate = at("3022", 20, -8, 0)
    structure = Structure(SLOT)
    assert {c for _, c in structure.connections_with(plate.part, plate.pose)} == {"stud", "socket"}
    found = approach(structure, [(plate.part, plate.pose)])
    assert found.direction is None and found.reason == "clamped"
    r = swept(SLOT, [plate])
    assert r.buildable is False and r.reason == "clamped" and r.poses_checked == 0


# Two bricks stacked at x = 0 hold a 2x4 brick (x 20..100) at the third course: a 2x2 brick hangs
# from its sockets at x = 80, the ground (y = 24) a brick below.
TOWER = [at("3001", 0, 0, 0), at("3001", 0, -24, 0), at("3001", 60, -48, 0)]
HANGING = at("3003", 80, -24, 0)


# A 1x1 brick turned 45 degrees on the ground beside the hanging brick's path: its box reaches 4
# LDU into the path, its body stays 4 LDU clear, so the sweep queries poses on the way up.
DIAMOND = at("3005", 49.86, 0, -30.14, R=rotation_about((0, 1, 0), 45))


@pytest.mark.parametrize("floor_y", [None, 24.0])
def test_a_part_hanging_from_sockets_comes_from_below(floor_y):
    found = approach(Structure(TOWER), [(HANGING.part, HANGING.pose)])
    assert np.allclose(found.direction, [0, -1, 0])  # up: its studs lead into the sockets
    # With the sampler's fixed ground too (y = 24, the tower's bottom): the builder lifts the
    # model, and the poses queried below the ground do not count it.
    structure = Structure(TOWER + [DIAMOND])
    scene, world, touched = scene_for(structure, [HANGING], floor_y)
    r = sweep(scene, structure, world, touched)
    assert r.buildable and r.reason is None and r.poses_checked > 0
    if floor_y is not None:
        # ... and the ground is back in the scene after the sweep.
        below = Pose(I3, HANGING.pose.t + [0, 30, 0])
        assert scene.penetration(below, touched)[0] > 5


def test_a_part_hanging_from_sockets_is_blocked_by_a_part_below():
    below = at("3020", 40, 24, 0)  # a 2x4 plate under the lower brick, reaching under x = 60..80
    r = swept(TOWER + [below], [HANGING])
    assert r.buildable is False and r.reason == "blocked" and r.blocked_by == (3,)


# A 1x1 column eight bricks high on the stud (30, 10) of a 2x4 brick, topped by a 1x4 plate or a
# 2x2 tile reaching over x = 0; the candidate is a 2x2 brick at x = 0 beside the column.
COLUMN = [at("3001", 0, 0, 0)] + [at("3005", 30, -24 * k, 10) for k in range(1, 8)]
TOPS = {"plate": at("3710", 0, -176, 10), "tile": at("3068b", 20, -176, 0)}


@pytest.mark.parametrize("top", sorted(TOPS))
@pytest.mark.parametrize("step", [2.0, 10.0, 50.0])
def test_a_blocker_thinner_than_a_step_is_found(top, step):
    # 8 LDU thick (a plate's studs add 4), 140 LDU above the brick's studs; at step 50 the whole
    # interval where the boxes meet (~40 LDU) holds no grid pose: only halving where the bound
    # allows an overlap finds it. Along the axis all the way (`press_ldu=None`):
    r = swept(COLUMN + [TOPS[top]], [at("3003", 0, -24, 0)], step_ldu=step, press_ldu=None)
    assert r.buildable is False and r.blocked_by == (8,)
    # Coming down from above, the brick's bottom (its pose's y = 0 when seated) meets the
    # blocker's top (the plate's studs at y = -180, the tile's face at -176), found within a step.
    assert 175 - step < r.at_ldu < 180
    # Without the top the same path is clear.
    assert swept(COLUMN, [at("3003", 0, -24, 0)], step_ldu=step, press_ldu=None).buildable
    # A hand brings the brick in from the side under that high top and presses it down.
    r = swept(COLUMN + [TOPS[top]], [at("3003", 0, -24, 0)], step_ldu=step)
    assert r.buildable and r.at_ldu == PRESS_LDU


def test_connections_on_two_axes_are_not_judged():
    # A unit of two bricks: one on an upright brick's studs (seats moving down), one on the side
    # studs of a brick lying on its side (seats moving along -x).
    side = rotation_about((0, 0, 1), 90)  # studs along +x
    assert np.allclose(side @ [0, -1, 0], [1, 0, 0])
    parts = [at("3001", 0, 0, 0), at("3001", 200, 0, 0, R=side)]
    unit = [at("3001", 0, -24, 0), at("3001", 224, 0, 0, R=side)]
    found = approach(Structure(parts), [(p.part, p.pose) for p in unit])
    assert found.direction is None and found.reason == "two-axes"
    r = sweep(*_args(parts, unit))
    assert r.buildable is None and r.reason == "two-axes"
    floating = sweep(*_args(parts, [at("3001", 0, -100, 0)]))
    assert floating.buildable is None and floating.reason == "no-connection"


def _args(parts, unit):
    structure = Structure(parts)
    scene, world, touched = scene_for(structure, unit)
    return scene, structure, world, touched


def _plain_sweep(scene, structure, world, touched, step=2.0) -> tuple[bool, int]:
    """The definition without the box filter: every `step` from clear space to the final pose."""
    d = approach(structure, world).direction
    unit_hi = max(float((p.apply(box_corners(part.bbox)) @ d).max()) for part, p in world)
    s_max = unit_hi - min(float((p.pose.apply(box_corners(p.part.bbox)) @ d).min()) for p in structure.placed)
    anchor = world[0][1]
    n = 0
    for s in np.arange(s_max, 0, -step):
        n += 1
        if scene.penetration(Pose(anchor.R, anchor.t - s * d), touched)[0] > TOL:
            return False, n
    return True, n


@pytest.mark.parametrize("size", [30])
def test_sweep_cost_and_agreement_with_the_plain_sweep_on_grown_structures(size, capsys):
    """Accepted 2x4 brick candidates on a structure grown by the checker: the box filter changes no
    verdict of the plain definition; the time per candidate is printed (not asserted)."""
    from pipelines.bench_structures import grow

    s = grow(size)
    brick = part("3001")
    poses = [p for p in feasible_poses(s, brick)
             if lowest_y(brick, p.R[None], p.t[None])[0] <= 24.0 + TOL]
    scene = CollisionScene(s, [(brick, Pose.identity())], 1e6)  # one scene for the part type
    rng = np.random.default_rng(0)
    cases = []
    for i in rng.permutation(len(poses)):
        world = [(brick, poses[i])]
        touched = {min(c[0], c[1]) for c in _unit_connections(s, world) if min(c[0], c[1]) < len(s)}
        if scene.penetration(poses[i], touched)[0] <= TOL and approach(s, world).direction is not None:
            cases.append((world, touched))
        if len(cases) == 40:
            break
    fast, plain = [], []
    for world, touched in cases:
        t = time.perf_counter()
        r = sweep(scene, s, world, touched, press_ldu=None)
        fast.append((r.buildable, r.poses_checked, time.perf_counter() - t))
        t = time.perf_counter()
        ok, n = _plain_sweep(scene, s, world, touched)
        plain.append((ok, n, time.perf_counter() - t))
    assert [b for b, _, _ in fast] == [b for b, _, _ in plain]
    with capsys.disabled():
        print(f"\n{size} parts, {len(cases)} accepted candidates, per candidate (ms, queries):")
        for name, rows in (("box filter", fast), ("plain", plain)):
            for verdict in (True, False):
                sel = [(n, dt) for b, n, dt in rows if b is verdict]
                if sel:
                    ms, queries = np.mean([dt for _, dt in sel]) * 1e3, np.mean([n for n, _ in sel])
                    print(f"  {name:10s} {'buildable' if verdict else 'blocked':9s} x{len(sel):2d}: "
                          f"{ms:6.2f} ms, {queries:5.1f} queries")
