"""Fidelity on real parts: round, curved and concave parts where people put them are accepted, the
same parts moved off their studs are still rejected, and bars in hollow studs are left to the
connections not modelled. Each structure is a few parts from the real LDraw subset, placed as in
the real designs of `../shared/ldraw_models` (the step is named where one was taken from there)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from factory.parts import box_corners, load_part
from factory.physics.check import check_units
from factory.physics.geometry import collision_shape
from factory.physics.structure import Placed, Structure
from factory.pose import Pose
from factory.symmetry import rotation_about
from factory.replay import _on_table
from factory.physics.check_state import DEFAULT

I3 = np.eye(3)
TURN = np.diag([-1.0, 1.0, -1.0])  # half a turn about the stud axis
SIDE = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # studs along -Z (on a side stud)
QUARTER = np.array([[0, 0, -1.0], [0, 1.0, 0], [1.0, 0, 0]])  # a quarter turn about the stud axis


@pytest.fixture(scope="module")
def at(real_reader):
    def _at(name, x, y, z, R=I3):
        return Placed(load_part(real_reader, name), 4, Pose(R, [x, y, z]))

    return _at


def verdict(structure, placed):
    (v,) = check_units(Structure(list(structure)), [[placed]], standing=False)
    return v


# (structure, candidate): LDraw y grows downwards, a part's origin is its top face; a plate is
# 8 LDU tall, a brick 24.
PLACEMENTS = {
    "round brick on a brick": lambda at: ([at("3005", 0, 0, 0)], at("3062b", 0, -24, 0)),
    "round brick beside bricks": lambda at: (
        [at("3020", 0, 0, 0), at("3005", -10, -24, -10), at("3005", 10, -24, -10), at("3004", 0, -24, 10)],
        at("3062b", -30, -24, -10)),
    "brick across round bricks": lambda at: (
        [at("3020", 0, 0, 0), at("3062b", -10, -24, -10), at("3062b", 10, -24, -10)], at("3004", 0, -48, -10)),
    "round plates side by side": lambda at: ([at("3020", 0, 0, 0), at("6141", -10, -8, -10)], at("6141", 10, -8, -10)),
    # The plate comes last: a round plate pushed in under it would be clamped (not buildable).
    "plate on a round plate": lambda at: (
        [at("3020", 0, 0, 0), at("3024", -30, -8, -10), at("6141", -10, -8, -10)], at("3022", -20, -16, 0)),
    "round plate on a headlight brick's side stud": lambda at: ([at("4070", 0, 0, 0)], at("6141", 0, 10, -14, SIDE)),
    "cone on a round plate": lambda at: ([at("6141", 0, 0, 0)], at("4589", 0, -24, 0)),
    "round tile beside a tile": lambda at: ([at("3020", 0, 0, 0), at("3068b", -20, -8, 0)], at("4150", 20, -8, 0)),
    "tile beside a round tile": lambda at: ([at("3020", 0, 0, 0), at("4150", 20, -8, 0)], at("3068b", -20, -8, 0)),
    "clip tile beside a tile": lambda at: ([at("3023", 0, 0, 0), at("3070b", -10, -8, 0)], at("15712", 10, -8, 0)),
    # A dish hangs 8 LDU down round the top of the brick it sits on.
    "dish on a 1x1 brick among plates": lambda at: (
        [at("3031", 0, 0, 0), at("3005", -10, -24, -10), at("3024", 10, -8, 10)], at("43898", -10, -32, -10)),
    "1x1 brick in a corner brick's notch": lambda at: (
        [at("3022", 0, 0, 0), at("2357", -10, -24, -10)], at("3005", 10, -24, 10)),
    "corner plate round a 1x1 plate": lambda at: (
        [at("3022", 0, 0, 0), at("3024", 10, -8, 10)], at("2420", -10, -8, -10)),
    "2x2 round plates stacked": lambda at: ([at("3003", 0, 0, 0), at("4032b", 0, -8, 0)], at("4032b", 0, -16, 0)),
    "round tile on a 2x2 round plate": lambda at: ([at("3022", 0, 0, 0), at("4032b", 0, -8, 0)], at("4150", 0, -16, 0)),
    "dish on a round plate": lambda at: (
        [at("3031", 0, 0, 0), at("3024", -10, -8, -10), at("6141", -10, -16, -10)], at("43898", -10, -24, -10)),
    # Covered Wagon, Cannon step 2: a wheel holder plate on a 2x4 plate (its underside open
    # towards the pins: sockets held by the centre tube and one wall).
    "wheel holder plate on a plate": lambda at: ([at("3020", 0, 0, 0, QUARTER)], at("6157", 0, -16, 20)),
}


@pytest.mark.parametrize("case", list(PLACEMENTS))
def test_round_and_notched_parts_where_people_put_them_are_accepted(at, case):
    structure, candidate = PLACEMENTS[case](at)
    v = verdict(structure, candidate)
    assert v.reason is None and v.connected, (case, v)


@pytest.mark.parametrize("case", ["round brick beside bricks", "round plates side by side",
                                  "cone on a round plate", "dish on a 1x1 brick among plates",
                                  "wheel holder plate on a plate"])
def test_round_parts_moved_off_their_studs_are_rejected(at, case):
    structure, good = PLACEMENTS[case](at)
    up = np.array([0.0, -1.0, 0.0])
    for name, moved, reasons in [
        ("shift", good.pose.t + [10.0, 0.0, 0.0], {"collision", "no-connection"}),
        ("lift", good.pose.t + 8.0 * up, {"no-connection"}),
    ]:
        v = verdict(structure, Placed(good.part, good.colour, Pose(good.pose.R, moved)))
        assert v.reason in reasons, (case, name, v)


@pytest.mark.parametrize("case, towards", [("round brick beside bricks", [1.0, 0.0, 0.0]),
                                           ("round plates side by side", [-1.0, 0.0, 0.0]),
                                           ("round tile beside a tile", [-1.0, 0.0, 0.0]),
                                           ("tile beside a round tile", [1.0, 0.0, 0.0])])
def test_round_parts_pushed_into_their_neighbour_are_rejected(at, case, towards):
    # 4 LDU into the part they touch (a round part's faces are 16-gons: its pieces must still
    # reach its rim, not only its inset hull's middle).
    structure, good = PLACEMENTS[case](at)
    v = verdict(structure, Placed(good.part, good.colour, Pose(good.pose.R, good.pose.t + 4.0 * np.array(towards))))
    assert v.reason in {"collision", "no-connection"} and v.max_penetration_ldu > 3.0, (case, v)


def test_a_wedge_fits_round_the_brick_in_its_notch(at):
    # LEGO Truck step 13: a 4x4 wedge on a 1x4 plate, round the 1x2 brick standing in its notch.
    # coacd's pieces of the wedge spanned the notch's corners (1.0 LDU into the brick); cut along
    # the wedge's own faces they follow its walls.
    structure = [at("3710", 0, 24, 0), at("3004", 0, 0, 0)]
    v = verdict(structure, at("4858", 0, 0, 0))
    assert v.reason is None and v.connections == 2, v
    assert verdict(structure, at("4858", 10, 0, 0)).reason == "collision"


def test_a_stud_in_a_hollow_it_does_not_connect_to_is_no_collision(at):
    # The same wedge over the side studs of a bracket (LEGO Truck step 13): they stand in the
    # wedge's hollow underside, which its collision pieces fill, without touching the wedge.
    structure = [at("3710", 0, 24, 0), at("3004", 0, 0, 0), at("2436a", 0, 24, -40)]
    v = verdict(structure, at("4858", 0, 0, 0))
    assert v.reason is None, v
    # A stud that meets a wall still collides: a 1x1 brick half a stud off, on a plate whose
    # studs then stand in its walls.
    v = verdict([at("3022", 0, 0, 0)], at("3005", 0, -24, -10))
    assert v.reason == "collision" and v.max_penetration_ldu > 3, v


def test_pieces_hold_only_the_part_and_its_cavities(real_reader):
    def inside(name, point):
        shape = collision_shape(load_part(real_reader, name))
        return any(np.all(ConvexHull(p).equations @ np.append(point, 1.0) < 0) for p in shape.body)

    # A round plate is two pieces: the disc on top and the narrower base under it, whose ring
    # stays open; its stud's socket is filled.
    assert len(collision_shape(load_part(real_reader, "6141")).body) == 2
    assert not inside("6141", [9.0, 5.5, 0.0]) and inside("6141", [0.0, 6.0, 0.0])
    # A corner brick's notch is empty, its underside cavity filled.
    assert not inside("2357", [20.0, 12.0, 20.0]) and inside("2357", [0.0, 12.0, 0.0])
    # A dish's dome below the stud it sits on holds the top of that stud's brick: left empty.
    assert not inside("43898", [0.0, 12.0, 0.0]) and not inside("43898", [8.0, 12.0, 0.0])


def test_a_bar_in_a_hollow_stud_is_a_joint(at, real_reader):
    # LEGO Truck step 17: an exhaust pipe's bar in the open side stud of a headlight brick (the
    # solid stud prism and the brick's body made it a 10 LDU collision).
    v = verdict([at("4070", 0, 0, 0, TURN)], at("71137", 0, 10, 21))
    assert v.reason is None and {l.kind for l in v.joints} == {"bar-in-stud"}, v
    # X1 Patrol Craft step 8: a torch in the open stud of a cone lying on its side (2.2 LDU). The
    # torch's handle is drawn with an axle hole's primitives at its end, not as a bar: no joint
    # mates there (an axle hole ends at the bore), so the connection is not placed and held rigid.
    cone = at("3942b", 0, -36, -56, SIDE)
    v = verdict([cone], at("3959", 0, -36, -80, TURN))
    assert v.reason == "unsupported-connection" and v.held_by == (0,), v
    # Off the stud's axis the bar is judged like any part.
    assert verdict([cone], at("3959", 10, -36, -80, TURN)).reason == "collision"
    # The bore is where the stud is hollow: a round brick's, not a plain stud's.
    assert len(load_part(real_reader, "3062b").flat.bores) == 1
    assert len(load_part(real_reader, "3005").flat.bores) == 0


def test_a_part_shifted_beside_a_hollow_stud_is_still_judged(at):
    # A hollow stud holds a bar, not any part that touches it: a brick shifted half a stud into a
    # round brick still collides.
    structure = [at("3020", 0, 0, 0), at("3062b", -10, -24, -10)]
    v = verdict(structure, at("3005", 0, -24, -10))
    assert v.reason == "collision", v


def test_a_part_pressed_onto_a_brackets_side_studs_connects_to_their_back(at, real_reader):
    # X1 Patrol Craft, Propulsor step 1: a round support lies on its side, its studs in the holes
    # at the back of a 2x2 bracket's side plate (sockets facing the way the bracket's side studs
    # point), with a round brick pressed on its far end in the same step.
    bracket = at("3956", 0, -16, 20)
    sockets = [c for c in load_part(real_reader, "3956").sockets if c.axis == (0.0, 0.0, -1.0)]
    assert len(sockets) == 4
    support = at("3940b", 0, -36, 0, SIDE)
    v = verdict([bracket], support)
    assert v.reason is None and v.connections == 4 and v.buildable, v
    # With the round brick already on its far end it could not go in: it would be clamped.
    v = verdict([bracket, at("3941", 0, -36, 48, SIDE)], support)
    assert v.reason == "clamped", v
    # Lifted off the studs it is not connected.
    assert verdict([bracket], at("3940b", 0, -36, 8, SIDE)).reason == "no-connection"


def test_minifig_pieces_join_by_minifig_joints(at):
    # X1 Patrol Craft's pilot, as its file builds him: helmet, then the head inside it, then the
    # torso whose neck enters the head. Neither is a stud connection; the pieces overlap by design.
    helmet = at("3842a", 0, -27, 0)
    head = at("3626bp01", 0, -27, 0)
    v = verdict([helmet], head)
    assert v.ok and [(l.b, l.kind, l.axis) for l in v.joints] == [(0, "minifig", None)], v
    v = verdict([helmet, head], at("973p90", 0, 0, 0))
    assert v.ok and {l.kind for l in v.joints} == {"minifig"}, v
    from factory.physics.unmodelled import joint_kind

    assert joint_kind(head.part, head.pose, helmet.part, helmet.pose) == "minifig"
    # A minifig head pushed into a brick is judged like any part.
    assert verdict([at("3001", 0, -20, 0)], head).reason == "collision"


def test_kept_stud_probe_answers_are_the_computed_ones(real_reader):
    """`studs_cross` answers a probe asked before from its store: the same answers as computing
    every probe, for studs crossing, standing free and in a hollow of a real brick, asked in
    mixed batches (some known, some new), and never another surface's answer."""
    from factory.physics import collide

    body = collide.part_surface(load_part(real_reader, "3001"))
    rng = np.random.default_rng(3)
    up = np.array([0.0, -1.0, 0.0])
    pos = np.concatenate([rng.uniform([-45, -10, -25], [45, 30, 25], size=(60, 3)),
                          np.array([[x, 4.0, z] for x in (-30, -10, 10, 30) for z in (-10, 10)])])
    axis = np.repeat(up[None], len(pos), axis=0)
    computed = collide._studs_cross(pos, axis, body)
    assert computed.any() and not computed.all()
    DEFAULT.crossed.clear()
    first = collide.studs_cross(pos[::2], axis[::2], body)
    assert np.array_equal(first, computed[::2])
    assert np.array_equal(collide.studs_cross(pos, axis, body), computed)  # half from the store
    other = collide.Surface.of(body.tris + np.array([0.0, 1000.0, 0.0]))  # the brick far away
    assert not collide.studs_cross(pos, axis, other).any()


def test_the_ground_is_the_lowest_point_of_a_tilted_part(at):
    # Covered Wagon, main model: the cannon stands tilted 15 degrees about its axle; its wheels'
    # boxes turned with it reach 9.4 LDU below the wheels, so the ground was put there and the
    # barrels and the tile laid on the table beside the wagon were judged floating.
    wheel = at("4489b", 0, 0, 0, rotation_about(np.array([1.0, 0.0, 0.0]), 15.0) @ QUARTER)
    points = wheel.pose.apply(wheel.part.flat.triangles.reshape(-1, 3))
    built = Structure([wheel])
    assert built.floor_y() == pytest.approx(points[:, 1].max())
    assert wheel.pose.apply(box_corners(wheel.part.bbox))[:, 1].max() > built.floor_y() + 9.0
    # A tile lying on the table beside it is on the table; one a plate above it is not.
    assert _on_table(built, [at("3069b", 100, built.floor_y() - 8, 0)])
    assert not _on_table(built, [at("3069b", 100, built.floor_y() - 16, 0)])


def test_a_part_blocked_far_out_on_its_axis_comes_in_from_the_side(at):
    # LEGO Truck steps 7-8: lights pressed onto side studs of its front, the wheel holders 100 LDU
    # further out on their axis. Here: a round plate onto a headlight brick's side stud, a brick
    # standing 52 LDU further out on that axis (more than the fingertip's room, `PRESS_LDU`).
    base = at("3035", 0, 0, 0, QUARTER)
    light = at("4070", -10, -24, 10)
    ahead = at("3005", -10, -24, -70)
    plate = at("6141", -10, -14, -4, SIDE)
    v = verdict([base, light, ahead], plate)
    assert v.reason is None and v.connections == 1 and v.buildable, v
    # In a tunnel (1x4 bricks either side, a 4x4 plate over it, the base plate 4 LDU under it) as
    # long as the way to the brick ahead, it can only come along its axis: through that brick.
    tunnel = [at("3010", -30, -24, -40, QUARTER), at("3010", 10, -24, -40, QUARTER), at("3031", 0, -32, -40)]
    v = verdict([base, light, ahead] + tunnel, plate)
    assert v.reason == "blocked" and 2 in v.blocked_by, v
    # With the brick ahead within the fingertip's room, it cannot be pressed on either.
    v = verdict([base, light, at("3005", -10, -24, -30)], plate)
    assert v.reason == "blocked", v
    # A fingertip's end pushes it in where its width has no room: the brick's face 30 LDU from
    # the stud's tip (`PRESS_MIN_LDU` of 24 clear, not `PRESS_LDU`'s 40; the LEGO Truck's round
    # lights between its grille plates and its front).
    v = verdict([base, light, at("3005", -10, -24, -50)], plate)
    assert v.reason is None and v.buildable, v
    assert verdict([base, light, at("3005", -10, -24, -40)], plate).reason == "blocked"


def test_a_mudguard_stands_beside_the_plate_under_its_rounded_end(at):
    # Vintage Car step 10: a mudguard with rounded ends on the chassis plates, its front end down
    # beside a 1x3 plate. coacd's pieces of the mudguard (too curved to be cut along its faces)
    # are hulls of its vertices near each piece and spanned the corner between its end and a
    # ledge above: 3.7 LDU past the end's face, a 1.9 LDU overlap with the plate. Each piece
    # that is not faithful is now split along the part's faces.
    turn, quarter_back = np.diag([-1.0, 1.0, -1.0]), QUARTER.T
    chassis = [at("4282", 0, 0, 0, turn), at("3623", -130, 0, 30, turn), at("3623", -130, 0, -30, turn),
               at("3020", -120, -8, 0, QUARTER), at("3035", 20, -8, 0), at("18892", -80, -8, 0, quarter_back)]
    v = verdict(chassis, at("35789", -80, -40, 40, turn))
    assert v.reason is None and v.connections == 4, v
    # Pushed 4 LDU towards the plate it is not on its studs, and it overlaps the plate.
    assert verdict(chassis, at("35789", -80, -40, 36, turn)).reason == "collision"
    # No piece holds the point beside the end's face where the plate's edge lies (the part's
    # own frame: its end's face at z = 0, the plate below the ledge at y > 40).
    shape = collision_shape(at("35789", 0, 0, 0).part)
    assert not any(np.all(ConvexHull(p).equations @ [34.0, 44.0, 1.0, 1.0] < 0) for p in shape.body)


SEESAW = """0 FILE main.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 seesaw.ldr
{step}1 16 0 0 0 1 0 0 0 1 0 0 0 1 prop.ldr
0 FILE seesaw.ldr
1 4 -30 0 -10 1 0 0 0 1 0 0 0 1 3005.dat
0 STEP
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 FILE prop.ldr
1 4 30 0 -10 1 0 0 0 1 0 0 0 1 3005.dat
"""


@pytest.mark.parametrize("step, held", [("", False), ("0 STEP\n", True)])
def test_sub_assemblies_of_one_step_go_in_together(write, step, held):
    # Covered Wagon, main model: the wagon stands on its rear wheels and rests its front on the
    # drawbar, a sub-assembly of the same step built after it. Here a 2x4 plate on a 1x1 brick
    # at one end (it tips alone) and a 1x1 brick under its other end, in one step of the main
    # model: judged with what goes in with it, it stands. A step later, it tips on the table
    # until the prop is in: held in hand meanwhile. Either way the finished model stands.
    # (Embedded parts: the test needs no ../shared.)
    from factory.replay import verify

    path = write("seesaw.mpd", SEESAW.format(step=step))
    found = verify(path, None)
    units = {r["assembly"]: r for r in found.records if r.get("unit")}
    seesaw = units["main/seesaw.ldr#1"]
    assert seesaw["reason"] is None and bool(seesaw.get("held_in_hand")) is held, units
    assert units["main/prop.ldr#1"]["reason"] is None and units["main/prop.ldr#1"]["connections"] == 1, units
    assert found.summary["finished_stands"] is True and found.summary["held_in_hand"] == int(held)


def test_a_finished_model_that_tips_does_not_stand(write):
    # The seesaw without its prop: accepted held in hand, but the finished model tips.
    from factory.replay import verify

    path = write("tips.mpd", SEESAW.format(step="").replace("1 16 0 0 0 1 0 0 0 1 0 0 0 1 prop.ldr\n", ""))
    found = verify(path, None)
    assert [r.get("held_in_hand") for r in found.records if r.get("unit")] == [True]
    assert found.summary["finished_stands"] is False


HELD = """0 FILE held.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
0 STEP
1 4 100 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
{step}1 4 {x} 0 0 1 0 0 0 1 0 0 0 1 3001.dat
"""
BETWEEN = "1 4 -100 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"


@pytest.mark.parametrize("step, x, reason, waited", [("", 100, None, None), (BETWEEN, 100, None, 2),
                                                     ("", 200, "no-connection", None)])
def test_a_part_is_held_in_hand_until_a_later_steps_part_holds_it(write, step, x, reason, waited):
    # X-wing Fighter (Mini), step 1: a 3x2 plate with a hole laid beside the first plates,
    # touching none, fixed from below by the next step's plates. Here a 2x4 plate beside a brick,
    # a plate's height off the table, and a brick under it in the next step: held until then, it
    # is accepted; with a step between (another brick on the table) it is held until the brick
    # under it comes (`held_for_parts`: 2 parts later, as the Gearbox's gears wait for the axle
    # pushed through them); with nothing under it ever, nothing holds it. Lifted off the brick,
    # it is rejected.
    from factory.replay import summarize, verify_model

    path = write("held.ldr", HELD.format(step=step, x=x))
    records = list(verify_model(path, None, faults=True))
    plate = [r for r in records if r["part"] == "3020.dat" and "fault" not in r]
    assert [(r["reason"], r.get("held_for_parts")) for r in plate] == [(reason, waited)], plate
    lifted = [r for r in records if r["part"] == "3020.dat" and r.get("fault") == "lift"]
    assert all(r["reason"] == "no-connection" for r in lifted) and len(lifted) == (reason is None), lifted
    # Stud-connected placements are those the design connects by studs, whatever the checks say:
    # the brick under the plate (into its sockets), and the plate when that brick holds it.
    pairs = [(r["part"], r["stud_pairs"]) for r in records if "fault" not in r]
    assert pairs == [("3001.dat", 0), ("3020.dat", 8 if reason is None else 0)] + \
        ([("3001.dat", 0)] if step else []) + [("3001.dat", 0 if reason else 8)], pairs
    summary = summarize(records)
    assert summary["held_until_later"] == (waited is not None)
    assert (summary["stud_connected"], summary["stud_fidelity"]) == ((0, None) if reason else (2, 1.0))


HELD_BY_UNIT = """0 FILE held.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
0 STEP
1 4 100 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 16 100 0 0 1 0 0 0 1 0 0 0 1 leg.ldr
0 FILE leg.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
"""


def test_a_part_is_held_in_hand_until_a_sub_assembly_of_the_next_step_holds_it(write):
    # Covered Wagon's horse: a brick set on what the next step attaches as a sub-assembly.
    from factory.replay import verify_model

    path = write("held.mpd", HELD_BY_UNIT)
    plate = [r for r in verify_model(path, None) if r["part"] == "3020.dat"]
    assert [r["reason"] for r in plate] == [None], plate


# Vintage Car (verify's steps 50-53): the rear mudguards 35789 of the two step 26 units, then 1x3
# plates and a 1x4 plate laid beside their rounded ends, above their sockets, on the open side
# of the corner between a mudguard's side face and the wall of its row of sockets. Real poses.
TURN_Y = np.diag([-1.0, 1.0, -1.0])
ROUND_CORNER = {
    "1x3 plate beside the left mudguard": ("35789", (120, -40, -40), I3, "3623", (70, -32, -30), I3),
    "1x3 plate beside the right mudguard": ("35789", (120, -40, 40), TURN_Y, "3623", (70, -32, 30), I3),
    "1x4 plate across the left mudguard's end": ("35789", (120, -40, -40), I3, "3710", (90, -40, 0), QUARTER.T),
}


@pytest.mark.parametrize("case", list(ROUND_CORNER))
def test_a_plate_beside_a_mudguards_end_is_clear_of_it(at, case):
    guard, g_at, g_r, plate, p_at, p_r = ROUND_CORNER[case]
    mudguard = at(guard, *g_at, g_r)
    v = verdict([mudguard], at(plate, *p_at, p_r))
    assert not v.collision and v.max_penetration_ldu <= 0.5, (case, v)
    # Pushed 4 LDU along the car and 4 down, into the mudguard's row of sockets, it overlaps the
    # mudguard's material: the corner is open, not the mudguard.
    into = np.array([4.0, 4.0, 0.0])
    v = verdict([mudguard], at(plate, *(np.array(p_at) + into), p_r))
    assert v.collision and v.max_penetration_ldu > 3.0, (case, v)


def test_a_corner_plate_round_a_steering_column_is_clear_of_it(at):
    # Vintage Car step 22: a corner plate 2420 laid on the steering stand 3829c01, round its
    # column. A refined piece of the stand was a wedge one sample bin across in the corner between
    # the column and the plate at its foot (all its bin centres on its sloping face, so never
    # tested): the corner plate overlapped it by 1.26 LDU. The hull's deepest point is sampled too.
    stand = at("3829c01", 30, -24, 20, QUARTER)
    v = check_units(Structure([stand]), [[at("2420", 30, -32, 0, TURN)]], standing=False, require_connection=False)[0]
    assert v.reason is None and v.max_penetration_ldu <= 0.5, v
    # Pushed 2 LDU into the column it overlaps it.
    v = check_units(Structure([stand]), [[at("2420", 30, -32, 2, TURN)]], standing=False, require_connection=False)[0]
    assert v.reason == "collision" and v.max_penetration_ldu > 1.5, v
    # No piece holds the corner (the stand's frame: the column's face at x = -10, the plate's
    # top at y = 0).
    shape = collision_shape(stand.part)
    assert not any(np.all(ConvexHull(p).equations @ [-10.6, -0.6, -8.0, 1.0] < 0) for p in shape.body)


ANY_ORDER = """0 FILE order.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3036.dat
1 4 -40 -24 10 1 0 0 0 1 0 0 0 1 3004.dat
1 4 40 -24 10 1 0 0 0 1 0 0 0 1 3004.dat
0 STEP
{first}1 1 0 -24 10 1 0 0 0 1 0 0 0 1 3004.dat
{then}"""
BRIDGE = "1 14 0 -32 10 1 0 0 0 1 0 0 0 1 3666.dat\n"


@pytest.mark.parametrize("same_step", [True, False])
def test_the_parts_of_one_step_go_in_in_any_order(write, same_step):
    # A 1x6 plate bridging two bricks, and a brick between them under the plate: listed after the
    # plate in the same step, it goes in first (pressed onto the base plate, then the plate on
    # it); in the step after the plate's, it cannot go in at all.
    from factory.replay import verify_model

    then = "0 STEP\n" if not same_step else ""
    path = write("order.ldr", ANY_ORDER.format(first=BRIDGE + then, then=""))
    records = [r for r in verify_model(path, None) if "fault" not in r]
    brick = records[-1]
    assert [r["part"] for r in records] == ["3036.dat", "3004.dat", "3004.dat", "3666.dat", "3004.dat"]
    assert records[3]["reason"] is None
    if same_step:
        assert brick["reason"] is None and brick["first_in_step"], brick
    else:  # between the plate on its studs and the base plate under it: no way in
        assert brick["reason"] == "clamped" and "first_in_step" not in brick, brick
    # Listed before the plate, it is simply built in that order
    path = write("order2.ldr", ANY_ORDER.format(first="", then=then + BRIDGE))
    records = [r for r in verify_model(path, None) if "fault" not in r]
    assert [r["reason"] for r in records] == [None] * 5 and not any("first_in_step" in r for r in records), records


def test_a_part_hung_from_a_later_part_of_its_step_links_only_to_parts_placed():
    # Gearbox.ldr (a Technic model): a part held by a pin of a part listed after it in its step
    # linked to that part's index before it was placed, and the loads of the next step indexed
    # past the structure. The later part makes the link when it comes (its own `held_by`).
    from factory.physics.check import Verdict

    v = Verdict(Pose.identity(), connected=False, connections=0, collision=False, max_penetration_ldu=0.0,
                held_by=(3, 7), reason="unsupported-connection")
    assert [(l.a, l.b) for l in v.links(5)] == [(5, 3)]


@pytest.mark.parametrize("twin, duplicate", [("1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat", True),
                                             ("1 4 0 -24 0 -1 0 0 0 1 0 0 0 -1 3001.dat", False),
                                             ("1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat", False)])
def test_a_part_placed_twice_at_one_pose_is_reported_as_a_duplicate(write, twin, duplicate):
    # The Gearbox places a 1x6 brick twice at one pose: judged, the second copy overlapped the
    # first as a collision. It is the design's error, reported apart; the brick on top is judged
    # on the first copy alone. The same brick turned half round, or another part there, is no
    # copy and still collides.
    from factory.replay import summarize, verify_model

    path = write("twice.ldr", "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"
                 "1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"
                 f"{twin}\n0 STEP\n1 4 0 -48 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n")
    records = [r for r in verify_model(path, None) if "fault" not in r]
    assert [r["reason"] for r in records] == [None, None, "duplicate" if duplicate else "collision", None]
    if duplicate:
        assert records[2]["duplicate_of"] == 1
    summary = summarize(records)
    assert summary["duplicates"] == int(duplicate)
    assert summary["accepted"] == 3 and summary["stud_connected"] == (2 if duplicate else 3)


UNDER_A_BRIDGE = """1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 80 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 4 60 -16 0 1 0 0 0 1 0 0 0 1 3068b.dat
0 STEP
1 1 60 -24 0 1 0 0 0 1 0 0 0 1 3022.dat
{between}1 14 40 -32 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
"""


@pytest.mark.parametrize("same_step", [True, False])
def test_a_part_laid_on_a_tile_goes_in_with_the_plate_pressed_onto_it(write, same_step):
    # Ferrari 512 S, step 14: a 2x2 plate laid on a tile beside a brick is held by a 2x4 plate of
    # its step that bridges it to the brick. Pushed up into that plate it meets the tile under it
    # (blocked); laid on the tile and held there while the bridge is pressed down onto both, it
    # goes in, whether the bridge is listed in its step or in the next.
    from factory.replay import verify_model

    path = write("bridge.ldr", UNDER_A_BRIDGE.format(between="" if same_step else "0 STEP\n"))
    records = [r for r in verify_model(path, None) if "fault" not in r]
    assert [r["part"] for r in records] == ["3001.dat", "3020.dat", "3068b.dat", "3022.dat", "3020.dat"]
    plate, bridge = records[3], records[4]
    assert bridge["reason"] is None and plate["reason"] is None, records
    assert plate["buildable"] and bridge["buildable"]
