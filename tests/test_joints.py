"""Clips, bars and hinges drawn without connector primitives: recognised by the cylinders of a
bar's radius (4 LDU) that both parts are drawn with, on one axis, so that a part held by one is
a connection through that joint (its overlap round the joint's axis left out, a joint for the
loads) instead of a `collision`, and the same part moved off the joint is still rejected. Poses are those
of the real designs in `../shared/ldraw_models` (the step is named)."""

from __future__ import annotations

import numpy as np
import pytest

from factory.embedded import generate_library
from factory.ldraw.library import Library
from factory.ldraw.reader import Reader
from factory.parts import box_corners, load_part
from factory.physics.check import check_units
from factory.physics.structure import Placed, Structure
from factory.pose import Pose
from ldraw_support import LDRAW, LIBRARY_ZIP, needs_ldraw

def kinds(v):
    return sorted({l.kind for l in v.joints})


def holders(v):
    return tuple(sorted({l.b for l in v.joints}))

I3 = np.eye(3)


@pytest.fixture(scope="module")
def at(real_reader):
    def _at(name, x, y, z, R=I3):
        return Placed(load_part(real_reader, name), 4, Pose(np.array(R, float), [x, y, z]))

    return _at


def verdict(structure, unit, backend="cpu"):
    unit = unit if isinstance(unit, list) else [unit]
    (v,) = check_units(Structure(list(structure)), [unit], backend, standing=False)
    return v


def moved(placed, by):
    return Placed(placed.part, placed.colour, Pose(placed.pose.R, placed.pose.t + np.asarray(by, float)))


def test_bar_size_cylinders_are_read_with_their_side(real_reader):
    # A bar is solid, a clip's grip hollow, hinge fingers solid; a plain brick has none, and a
    # round brick's hollow stud is a bore, not a bar.
    def bars(name):
        flat = load_part(real_reader, name).flat
        return len(flat.bars), sorted(flat.bar_out.tolist())

    assert bars("32828")[1] == [1.0, 1.0, 1.0]       # round plate with bar (its bar and handle)
    assert bars("15712") == (1, [-1.0])              # tile with clip
    assert bars("4214") == (5, [1.0] * 5)            # car roof holder: five fingers
    assert bars("4213") == (4, [1.0] * 4)            # car roof: four fingers between them
    assert bars("90397") == (4, [1.0] * 4)           # surf board: four pins underneath
    assert bars("3005") == (0, [])
    assert len(load_part(real_reader, "3062b").flat.bores) == 1


def test_the_sampler_library_has_no_bars():
    # Its parts are drawn without cylinder primitives: nothing in the sampler can be joined.
    reader = Reader(Library.embedded())
    names = [k.split("/", 1)[1] for k in generate_library() if k.startswith("parts/")]
    assert names
    for name in names:
        flat = load_part(reader, name).flat
        assert len(flat.bars) == 0 and len(flat.other_connectors) == 0, name


# Vintage Car step 38: a round plate with bar under a round tile (a sub-assembly), its bar in the
# clip of a tile 15712 on the side stud of a 1x1 brick 87087 (step 29): no stud connection, and
# the clip's collision pieces fill the grip the bar lies in (1.8 LDU).
def clip_on_brick(at):
    return [at("87087", 50, -56, 50, [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
            at("15712", 50, -64, 50, [[-1, 0, 0], [0, 1, 0], [0, 0, -1]])]


def bar_unit(at, by=(0.0, 0.0, 0.0)):
    r = [[0, 1, 0], [0, 0, -1], [-1, 0, 0]]
    return [moved(at("32828", 48, -70, 70, r), by), moved(at("98138", 40, -70, 70, r), by)]


def test_a_bar_in_a_clip_is_a_joint(at):
    v = verdict(clip_on_brick(at), bar_unit(at))
    # The clip is drawn with cylinders of a bar's radius, not a clip primitive, so the joint is
    # known as a bar on the clip's axis; it holds the unit's round plate (part 0).
    assert v.ok and v.connected and v.connections == 0 and holders(v) == (1,) and kinds(v) == ["bar"], v
    assert {l.a for l in v.joints} == {0} and all(abs(l.axis[2]) == 1.0 for l in v.joints)
    # Slid 4 LDU along the bar it is still in the clip.
    assert kinds(verdict(clip_on_brick(at), bar_unit(at, (0, 0, 4)))) == ["bar"]


@pytest.mark.parametrize("by", [(0, 4, 0), (0, -8, 0), (4, 0, 0), (10, 0, 0)])
def test_a_bar_off_its_clips_axis_is_judged_like_any_part(at, by):
    v = verdict(clip_on_brick(at), bar_unit(at, by))
    assert v.reason in {"collision", "no-connection"}, (by, v)


# Car (car.ldr step 7): the hinge roof 4213 on the studs of the windscreen 3823, its four fingers
# between the five of the roof holder 4214 (1.3 LDU where the pieces fill the gaps between them).
def roof_holder(at):
    return [at("3823", 0, -88, -30), at("4214", 0, -88, 30)]


def test_hinge_fingers_between_fingers_are_a_joint(at):
    v = verdict(roof_holder(at), at("4213", 0, -96, 0))
    assert v.ok and holders(v) == (1,) and kinds(v) == ["bar"] and v.connections == 2, v


@pytest.mark.parametrize("by", [(10, 0, 0), (0, 0, 10), (0, -8, 0), (0, 4, 0)])
def test_hinge_fingers_moved_through_the_others_are_rejected(at, by):
    # Along the hinge's axis the fingers run into each other (no joint); across it, off the axis.
    v = verdict(roof_holder(at), moved(at("4213", 0, -96, 0), by))
    assert v.reason in {"collision", "no-connection"}, (by, v)


def test_a_collision_beside_a_joint_is_still_a_collision(at):
    # Joined to the holder, but also pushed into a brick standing where the roof goes: the
    # overlap that is not the joint's rejects it.
    v = verdict(roof_holder(at) + [at("3004", 0, -96, 0)], at("4213", 0, -96, 0))
    assert v.reason == "collision", v


# Vintage Car, main model: surf boards 90397 as running boards, their underside pins in the
# hollow side studs of plates 99206 (no stud connection: 4.0 LDU where the studs' solid
# collision prisms stand in the pins).
def test_pins_in_hollow_side_studs_are_a_joint(at):
    plate = at("99206", 60, -32, 50, [[-1, 0, 0], [0, 1, 0], [0, 0, -1]])
    board = at("90397", 30, -26, 68, [[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    v = verdict([plate], board)
    assert v.ok and holders(v) == (0,) and kinds(v) == ["bar-in-stud"], v
    # Off the studs' axes (across the board, or pulled off them) it is judged like any part.
    for by in [(0, 10, 0), (0, -10, 0), (0, 0, 8)]:
        assert verdict([plate], moved(board, by)).reason in {"collision", "no-connection"}, by


def test_two_hollow_studs_on_one_axis_hold_nothing(at):
    # A bore is hollow: a round brick pushed down into another round brick is a collision.
    v = verdict([at("3062b", 0, 0, 0)], at("3062b", 0, -20, 0))
    assert v.reason == "collision", v


def test_two_pins_end_to_end_hold_nothing(at):
    # Covered Wagon step 19: the horse's 1x2 brick, placed a step before the horse, stands over
    # the pin of the horse hitching 4587, its own underside pin 2 LDU above that one on one axis.
    # Two solid cylinders meeting end to end are no hinge (a finger must sit between two).
    hitch = at("4587", 0, 4, -40, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    assert verdict([hitch], at("3004", 0, -39, -138)).reason == "no-connection"


def test_a_plates_pin_in_a_hollow_stud_is_a_joint(at):
    # A 1x2 plate centred on a round brick: its underside pin in the brick's hollow stud, its two
    # ends free. Nothing else overlaps.
    v = verdict([at("3062b", 0, 0, 0)], at("3023", 0, -8, 0))
    assert v.ok and holders(v) == (0,) and kinds(v) == ["bar-in-stud"], v


@pytest.mark.parametrize("case", ["plate onto the open studs", "open studs under the plate"])
def test_an_overlap_away_from_the_joint_is_still_a_collision(at, case):
    # Vintage Car step 33 (shift faults): a 1x2 plate on a 1x2 plate with two open studs 35480,
    # shifted half a stud along it. One plate's pin stands in an open stud (a joint), but the
    # other open stud is under the 1x2 plate's end wall, 20 LDU from that axis: a collision.
    if case == "plate onto the open studs":
        v = verdict([at("35480", -40, 8, 0)], at("3023", -50, 0, 0))
    else:
        v = verdict([at("3023", -40, 0, 0)], at("35480", -50, 8, 0))
    assert v.reason == "collision" and v.max_penetration_ldu > 3, (case, v)


@pytest.mark.parametrize("backend", ["cpu", "jax"])
def test_both_backends_judge_joints_alike(at, backend, monkeypatch):
    # The batched collision rule finds the overlap; where the joint's zone is left out, MuJoCo is
    # asked about the holding part alone, never about the whole structure.
    scenes = []
    if backend == "jax":
        pytest.importorskip("jax")
        from factory.physics.collide import CollisionScene

        built = CollisionScene.__init__
        monkeypatch.setattr(CollisionScene, "__init__", lambda self, structure, *a: scenes.append(
            len(structure.placed)) or built(self, structure, *a))
    assert kinds(verdict(roof_holder(at), at("4213", 0, -96, 0), backend)) == ["bar"]
    assert verdict(roof_holder(at) + [at("3004", 0, -96, 0)], at("4213", 0, -96, 0), backend).reason == "collision"
    plate = at("99206", 60, -32, 50, [[-1, 0, 0], [0, 1, 0], [0, 0, -1]])
    board = at("90397", 30, -26, 68, [[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    assert kinds(verdict([plate], board, backend)) == ["bar-in-stud"]
    assert verdict([plate], moved(board, (0, 10, 0)), backend).reason in {"collision", "no-connection"}
    assert set(scenes) <= {1} and (backend == "cpu" or scenes)
    assert verdict(roof_holder(at), at("4213", 10, -96, 0), backend).reason == "collision"
    v = verdict(clip_on_brick(at), bar_unit(at), backend)
    assert v.ok and kinds(v) == ["bar"], v
    assert verdict([at("35480", -40, 8, 0)], at("3023", -50, 0, 0), backend).reason == "collision"


def test_a_part_on_a_side_stud_is_held_by_the_same_clutch_rule_on_both_backends(at, monkeypatch):
    # A tile clipped onto the side stud of a 1x1 brick, its clutch asked of the one-body program
    # (the closed form left out): the batched checks solve it with HiGHS on the host, as the
    # reference does (a device launch per round cost more than the programs).
    pytest.importorskip("jax")
    from factory.physics import clutch, lp_jax

    monkeypatch.setattr(clutch, "_closed_form", lambda *a: None)
    from factory.physics.check_state import CheckState, using

    launched = []
    real = lp_jax.solve_batch
    monkeypatch.setattr(lp_jax, "solve_batch", lambda *a, **k: launched.append(a) or real(*a, **k))

    brick, tile = clip_on_brick(at)
    verdicts = {}
    for backend in ("cpu", "jax"):
        with using(CheckState()):  # each backend asks its own programs (answers are kept)
            verdicts[backend] = verdict([brick], tile, backend)
    assert verdicts["jax"] == verdicts["cpu"] and verdicts["cpu"].clutch and verdicts["cpu"].connections == 1, verdicts
    assert not launched


# Joints carry loads (`joint_capacity`): hand-built with parts of `../shared/ldraw`, on a floor
# 24 LDU below the Technic brick's top.
ALONG_Z = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # a pin's X axis along Z
BEAM_ALONG_X = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # a beam's holes (its Y) along Z, its length along X


def standing(structure, placed):
    (v,) = check_units(structure, [[placed]], "cpu", floor_y=24.0)
    return v


def placed_on(structure, placed):
    """Place a part as the replay does: checked, then added with the links of its joints."""

    v = standing(structure, placed)
    assert v.ok, v
    structure.add(placed, v.links(len(structure)))
    return v


def test_a_beam_hung_on_one_free_pin_swings_and_on_two_pins_stands(at):
    # A Technic brick 1x4 (3701: pin holes along Z at x = -20, 0, 20, 10 LDU below its top) with a
    # pin (3673) half in a hole; a Technic beam 3 (32523) put on the pin's other half by its end
    # hole, lying along X. A pin turns freely in a hole: nothing holds the beam's weight, 20 LDU
    # from the pin, about the pin's axis.
    structure = Structure([at("3701", 0, 0, 0)])
    v = placed_on(structure, at("3673", -20, 10, 10, ALONG_Z))
    assert [(l.kind, l.point) for l in v.joints] == [("technic-pin", (-20.0, 10.0, 0.0))], v
    beam = at("32523", 0, 10, 20, BEAM_ALONG_X)
    v = standing(structure, beam)
    assert v.reason == "unstable" and [(l.b, l.kind) for l in v.joints] == [(1, "technic-pin")], v
    # It swings on that pin: the pin is named as failing, turned by more than it holds.
    assert [(f.socket_part, f.joint) for f in v.failing] == [(1, "technic-pin")] and v.failing[0].load > 1, v
    # A second pin under the beam's middle hole: two pins hold it by their shears.
    placed_on(structure, at("3673", 0, 10, 10, ALONG_Z))
    v = standing(structure, beam)
    assert v.ok and v.load < 0.1 and sorted((l.b, l.kind) for l in v.joints) == [(1, "technic-pin"), (2, "technic-pin")], v
    # The beam moved off the pins' axes is judged like any part; slid 5 LDU out along them it is
    # not pushed home on its pins (`unmodelled.SEATED_LDU`): no joint holds it.
    assert standing(structure, moved(beam, (0, -10, 0))).reason == "collision"
    v = standing(structure, moved(beam, (0, 0, 5)))
    assert not v.ok and not v.joints, v


def test_a_wheel_rim_on_a_wheel_pin_is_held_by_it(at):
    # A plate 2x2 with a wheel pin (4488: the pin along X from x = 20 to 34, 5 LDU below the
    # plate's top) and a rim (30027b: its wheel-pin hole along its -Z, turned to run along X).
    plate = [at("4488", 0, 0, 0)]
    rim = at("30027b", 36, 5, 0, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    v = verdict(plate, rim)
    assert v.ok and [(l.kind, l.point) for l in v.joints] == [("wheel-pin", (27.0, 5.0, 0.0))], v
    # Pushed on further it runs into the plate; off the pin's axis it holds nothing.
    assert verdict(plate, moved(rim, (-6, 0, 0))).reason is not None
    assert verdict(plate, moved(rim, (0, -8, 0))).reason in {"collision", "no-connection"}


def test_a_pin_goes_into_its_hole_along_its_axis_unless_both_ways_are_blocked(at):
    # The pin of the beam test, half in the Technic brick's end hole. It comes in along the
    # hole's axis from either side; with a 1x4 brick against the hole's far mouth it still comes
    # from the near side, and with another brick 10 LDU beyond the pin's outer end it has no way in.
    pin = at("3673", -20, 10, 10, ALONG_Z)
    v = verdict([at("3701", 0, 0, 0)], pin)
    assert v.ok and v.buildable is True, v
    far_wall = at("3010", 0, 0, -20)
    v = verdict([at("3701", 0, 0, 0), far_wall], pin)
    assert v.ok and v.buildable is True, v
    v = verdict([at("3701", 0, 0, 0), far_wall, at("3010", 0, 0, 50)], pin)
    assert v.reason == "blocked" and v.buildable is False and set(v.blocked_by) <= {1, 2} and v.blocked_by, v


@needs_ldraw
def test_the_sampler_attaches_through_joints():
    """With Technic parts the sampler grows objects through pins, axles and open studs as well as
    studs (`factory.physics.joint_attach`): steps held by joints alone, judged by the same checks,
    and the same object from the same seed. A part held by joints alone carries the parts put on
    it later (its joints are kept as the structure's links): a beam goes on a pin that is itself
    held only by its hole."""
    from factory.sampler import Sampler, SamplerConfig

    cfg = SamplerConfig(seed=3, parts=(("3701", 1.0), ("3673", 1.0), ("32523", 1.0), ("3707", 0.5), ("3023", 1.0)),
                        min_steps=8, max_steps=8)
    sampler = Sampler(cfg, ldraw=str(LDRAW))
    objs = [sampler.sample(i) for i in range(3)]
    assert all(o.end_reason == "target" and len(o.steps) == 8 for o in objs)
    held = [s for o in objs for s in o.steps if s.verdict.joints and not s.verdict.connections]
    assert {l.kind for s in held for l in s.verdict.joints} >= {"technic-pin", "technic-axle"}
    assert all(s.verdict.ok and s.verdict.stable for o in objs for s in o.steps[1:])
    # A pin's step: the pin lies on a hole's axis of the part it is in.
    pin = next(s for s in held if s.part == "3673.dat")
    assert abs(abs(pin.verdict.joints[0].axis[2]) - 1.0) < 1e-6 or abs(abs(pin.verdict.joints[0].axis[0]) - 1.0) < 1e-6
    # Chains of joints: a step held only by joints to a part that was itself held only by joints.
    chained = [(o.steps[l.b].part, s.part) for o in objs for s in o.steps if not s.verdict.connections
               for l in s.verdict.joints if o.steps[l.b].verdict.joints and not o.steps[l.b].verdict.connections]
    assert ("3673.dat", "32523.dat") in chained, chained
    assert sampler.sample(0).same_as(objs[0])


@needs_ldraw
def test_a_joint_part_with_nowhere_to_go_brings_a_part_that_offers_one():
    """A step whose first draw is a part held by joints alone (the pin 3673), where the structure
    offers no connector it mates, draws again among the parts that bring one (the Technic brick
    3701's holes), and the joint draw is made again at the next step, where the pin now goes in:
    pins come into objects whose other parts offer no hole, through a part their weights hardly
    ever draw."""
    from factory.sampler import Sampler, SamplerConfig

    cfg = SamplerConfig(seed=5, parts=(("3001", 1.0), ("3701", 0.001), ("3673", 0.5)), min_steps=5, max_steps=5)
    sampler = Sampler(cfg, ldraw=str(LDRAW))
    assert sampler.provider_p.tolist() == [0.0, 1.0, 0.0]
    objs = [sampler.sample(i) for i in range(3)]
    parts = [[s.part for s in o.steps] for o in objs]
    assert all(o.end_reason == "target" for o in objs), parts
    bricks = [(o, k) for o in objs for k, s in enumerate(o.steps) if s.part == "3701.dat"]
    assert bricks, parts
    for o, k in bricks:
        assert o.steps[k].draws >= 2  # drawn in place of the pin, never by its own weight
        if k + 1 < len(o.steps):  # the owed pin goes into its hole at the next step
            pin = o.steps[k + 1]
            assert pin.part == "3673.dat" and not pin.verdict.connections, parts
            assert {j.kind for j in pin.verdict.joints} == {"technic-pin"}, pin.verdict.joints
    assert sum(p.count("3673.dat") for p in parts) >= 3, parts
    # Without a part that brings a hole, the pin is never placed and nothing is drawn in its place.
    alone = Sampler(SamplerConfig(seed=5, parts=(("3001", 1.0), ("3673", 0.5)), min_steps=3, max_steps=3),
                    ldraw=str(LDRAW))
    assert alone.provider_p is None
    assert all(s.part == "3001.dat" for s in alone.sample(0).steps)


# A click hinge (44302a, dual finger, at the end of a 2x4 brick; 44301a, single finger) turns in
# steps (`joints.CLICK_STEP_DEG`): straight where the two halves' primitives are turned alike, the
# single finger's plate then lying beyond the pivot, studs up. The pivot is 30 LDU along X from each
# half's origin, 2 LDU below its top; the axis runs along Z.
HINGE_PIVOT = np.array([50.0, 2.0, 0.0])


def hinge_base(at):
    structure = Structure([at("3001", 0, 8, -10)])
    placed_on_floor(structure, at("44302a", 20, 0, 0))
    return structure


def hinged(at, angle):
    """44301a on 44302a's fingers, turned `angle` degrees up from straight."""
    from factory.symmetry import rotation_about

    turn = rotation_about(np.array([0.0, 0.0, 1.0]), -angle)
    straight = np.diag([-1.0, 1.0, -1.0])  # turned half round Y: its finger meets the other's
    t = turn @ (HINGE_PIVOT - straight @ np.array([30.0, 2.0, 0.0]) - HINGE_PIVOT) + HINGE_PIVOT
    return at("44301a", *t, turn @ straight)


def on_floor(structure, placed, floor_y=32.0):
    (v,) = check_units(structure, [[placed]], "cpu", floor_y=floor_y)
    return v


@pytest.mark.parametrize("angle", [0.0, 22.5, 45.0, 67.5, 90.0])
def test_a_plate_on_a_click_hinge_is_held_at_each_step(at, angle):
    structure = hinge_base(at)
    half = hinged(at, angle)
    v = placed_on_floor(structure, half)
    assert [(l.kind, l.b) for l in v.joints] == [("click-hinge", 1)], v
    # A 1x4 plate on the single finger's two studs, reaching away from the hinge.
    plate = at("3710", *(half.pose.t + half.pose.R @ np.array([-20.0, -8.0, 0.0])), half.pose.R)
    v = on_floor(structure, plate)
    assert v.ok and v.connections == 2 and v.stable and v.load < 1.0, v


@pytest.mark.parametrize("angle", [11.25, 33.75, -11.25])
def test_a_click_hinge_between_two_steps_holds_nothing(at, angle):
    # Half way between two steps no tooth sits in a notch: the fingers hold nothing (a little
    # off a step, as designs set them, still holds).
    structure = hinge_base(at)
    v = on_floor(structure, hinged(at, angle))
    assert not v.ok and not v.joints, v
    assert on_floor(structure, hinged(at, angle + 12.5 if angle > 0 else angle - 12.5)).ok


def placed_on_floor(structure, placed):
    v = on_floor(structure, placed)
    assert v.ok, v
    structure.add(placed, v.links(len(structure)))
    return v


@pytest.fixture(scope="module")
def lib_at():
    """`at` for parts of LDraw's complete.zip (`LIBRARY_ZIP`: wheels the subset lacks)."""
    if not LIBRARY_ZIP.is_file():
        pytest.skip(f"LDraw's complete.zip is not at {LIBRARY_ZIP}")
    reader = Reader(Library.from_path(LIBRARY_ZIP))

    def _at(name, x, y, z, R=I3):
        return Placed(load_part(reader, name), 4, Pose(np.array(R, float), [x, y, z]))

    return _at


def technic_base(at, holder):
    """A Technic brick 1x4 (3701) on a 2x4 brick, with `holder` (an axle or a pin along Z) through
    its middle hole (at x = 0, 10 LDU below its top), on a floor 48 LDU below its top."""
    structure = Structure([at("3001", 0, 24, -10)])
    for placed in (at("3701", 0, 0, 0), holder):
        (v,) = check_units(structure, [[placed]], "cpu", floor_y=48.0)
        assert v.ok, v
        structure.add(placed, v.links(len(structure)))
    return structure


def test_a_wheel_is_pressed_onto_an_axle_and_onto_a_pin(lib_at):
    def judged(structure, placed):
        (v,) = check_units(structure, [[placed]], "cpu", floor_y=48.0)
        return v

    # An axle 3 (4519) through the hole, z from -20 to 40; a wheel with an axle hole (3482, its
    # hole 20 LDU long along Z) pushed on from its outer end is held wherever its hole is all on
    # the axle, and stands; pushed only half way on, nothing holds it.
    on_axle = technic_base(lib_at, lib_at("4519", 0, 10, 10, ALONG_Z))
    for z in (25.0, 30.0):
        v = judged(on_axle, lib_at("3482", 0, 10, z))
        assert v.ok and v.stable and [(l.kind, l.b) for l in v.joints] == [("technic-axle", 2)], v
    v = judged(on_axle, lib_at("3482", 0, 10, 40))
    assert not v.ok and not v.joints, v
    # A pin (3673) half in the hole, its other half out (z 10 to 30); a wheel with a pin hole
    # (30285, turned so that its hub faces the brick) on that half spins on it, its centre of mass
    # on its axis: held, and it stands.
    on_pin = technic_base(lib_at, lib_at("3673", 0, 10, 10, ALONG_Z))
    wheel = lib_at("30285", 0, 10, 30, np.diag([1.0, -1.0, -1.0]))
    v = judged(on_pin, wheel)
    assert v.ok and v.stable and [(l.kind, l.b) for l in v.joints] == [("technic-pin", 2)], v
    v = judged(on_pin, moved(wheel, (0, 0, 10)))
    assert not v.ok and not v.joints, v


@needs_ldraw
def test_the_sampler_turns_click_hinges_to_their_steps():
    """With click hinge plates the sampler attaches a single finger between dual fingers
    (`joint_attach`), at one of the hinge's steps from straight (`joints.CLICK_STEP_DEG`)."""
    from factory.joints import click_angle, on_a_click, part_connectors
    from factory.sampler import Sampler, SamplerConfig

    cfg = SamplerConfig(seed=3, parts=(("44302a", 1.0), ("44301a", 1.0), ("3023", 1.0), ("3710", 0.5)),
                        min_steps=10, max_steps=10)
    sampler = Sampler(cfg, ldraw=str(LDRAW))
    obj = sampler.sample(0)
    hinged = [s for s in obj.steps if any(l.kind == "click-hinge" for l in s.verdict.joints)]
    assert hinged and all(s.verdict.ok and s.verdict.stable is not False for s in hinged), obj.steps
    for step in hinged:
        (link,) = step.verdict.joints
        holder = obj.steps[link.b]
        mine = next(c for c in part_connectors(load_part(sampler.reader, step.part)) if c.kind == "hinge")
        theirs = next(c for c in part_connectors(load_part(sampler.reader, holder.part)) if c.kind == "hinge")
        angle = click_angle(step.pose.R @ np.array(mine.ref), holder.pose.R @ np.array(theirs.ref),
                            holder.pose.R @ np.array(theirs.axis))
        assert on_a_click(angle) and abs(angle / 22.5 - round(angle / 22.5)) < 1e-6, angle
    assert sampler.sample(0).same_as(obj)


def test_holes_drawn_without_connector_primitives_are_found(lib_at):
    # A gear whose axle hole is drawn with rectangles and cylinder pieces (3648b), a Technic
    # plate's middle hole (3709b); an arch, a window and a tyre frame openings, not holes.
    from factory.joints import drawn_holes

    def holes(name):
        return [(c.kind, tuple(abs(v) for v in c.axis)) for c in drawn_holes(lib_at(name, 0, 0, 0).part.flat.triangles)]

    assert holes("3648b") == [("axle-hole", (0.0, 0.0, 1.0))]
    assert holes("3709b") == [("pin-hole", (0.0, 1.0, 0.0))]
    assert holes("3659") == holes("60594") == holes("3483") == holes("3001") == []
    # The gear goes onto an axle like a gear drawn with an axle hole primitive.
    on_axle = technic_base(lib_at, lib_at("4519", 0, 10, 10, ALONG_Z))
    (v,) = check_units(on_axle, [[lib_at("3648b", 0, 10, 25)]], "cpu", floor_y=48.0)
    assert v.ok and [(l.kind, l.b) for l in v.joints] == [("technic-axle", 2)], v


def test_a_fault_that_lands_on_another_connection_is_not_injected(at):
    # A 1x2 plate with one socket on a round brick's hollow stud, shifted half a stud: its
    # underside pin goes into the stud's bore, a real offset, not a fault. The same shift of a
    # 2x2 plate (no pin) lands on nothing; neither does a lift off the stud.
    from factory.replay import lands_on_a_joint

    structure = Structure([at("3062b", 0, 0, 0)])
    plate = at("3023", 10, -8, 0)
    shifted = moved(plate, (-10, 0, 0))
    assert lands_on_a_joint(structure, plate.part, shifted.pose, np.array([-10.0, 0, 0]))
    square = at("3022", 10, -8, 10)
    assert not lands_on_a_joint(structure, square.part, moved(square, (-10, 0, 0)).pose, np.array([-10.0, 0, 0]))
    assert not lands_on_a_joint(structure, plate.part, moved(plate, (0, -8, 0)).pose, np.array([0, -8.0, 0]))
    # A Technic brick 1x2 (32064a: a socket between its two, where its long walls hold a stud) on
    # two studs of a plate, shifted half a stud, sits on one of them: no fault. A brick 1x2
    # (3004) shifted so sits on none.
    base = Structure([at("3020", 0, 0, 0)])
    for name, lands in (("32064a", True), ("3004", False)):
        brick = at(name, 20, -24, -10)
        assert lands_on_a_joint(base, brick.part, moved(brick, (-10, 0, 0)).pose, np.array([-10.0, 0, 0])) is lands


@needs_ldraw
def test_a_structure_rebuilt_from_its_parts_keeps_their_joints():
    """`physics.linked`: the structure of a grown object rebuilt from its parts alone (as a dataset
    row gives them) has the joints the sampler kept as links when it placed each part held by
    joints alone, so a part hung on a pin still carries what is put on it."""
    from factory.physics.linked import linked
    from factory.sampler import Sampler, SamplerConfig

    cfg = SamplerConfig(seed=3, parts=(("3701", 1.0), ("3673", 1.0), ("32523", 1.0), ("3707", 0.5), ("3023", 1.0)),
                        min_steps=8, max_steps=8)
    sampler = Sampler(cfg, ldraw=str(LDRAW))
    obj = sampler.sample(2)
    kept = {(k, l.b, l.kind) for k, s in enumerate(obj.steps) if not s.verdict.connections
            for l in s.verdict.links(k)}
    assert {kind for *_, kind in kept} >= {"technic-pin", "technic-axle"}
    by_name = {p.name: p for p in sampler.parts}
    rebuilt = linked(Placed(by_name[s.part], s.colour, s.pose) for s in obj.steps)
    assert {(l.a, l.b, l.kind) for l in rebuilt.links} == kept
    assert Structure([Placed(by_name[s.part], s.colour, s.pose) for s in obj.steps]).links == []


def test_a_bush_runs_along_its_primitives_z_and_goes_onto_an_axle(lib_at):
    # LDraw draws a bush along its own Z (bush0 turns its axle hole from Y onto Z, z -10 to 10).
    # The long pin with stop bush (32054) has its bush (bush0 at x = -20, Z turned onto X) on its
    # pins' axis, beyond their end at x = -10; the bush with two flanges (3713) runs along Z, its
    # flange at z = -10.
    from factory.joints import part_connectors

    def bushes(name):
        return [(c.start, c.end, tuple(abs(v) for v in c.axis))
                for c in part_connectors(lib_at(name, 0, 0, 0).part) if c.kind == "bush"]

    assert bushes("32054") == [((-30.0, 0.0, 0.0), (-10.0, 0.0, 0.0), (1.0, 0.0, 0.0))]
    assert bushes("3713") == [((0.0, 0.0, -10.0), (0.0, 0.0, 10.0), (0.0, 0.0, 1.0))]
    # The bush pushed onto the axle 3 of `technic_base` (z from -20 to 40), beside the brick, is
    # held by it; moved off the axle's axis it is not.
    on_axle = technic_base(lib_at, lib_at("4519", 0, 10, 10, ALONG_Z))
    (v,) = check_units(on_axle, [[lib_at("3713", 0, 10, 30)]], "cpu", floor_y=48.0)
    assert v.ok and [(l.kind, l.b) for l in v.joints] == [("technic-axle", 2)], v
    (v,) = check_units(on_axle, [[lib_at("3713", 0, 4, 30)]], "cpu", floor_y=48.0)
    assert not v.ok and not v.joints, v


def test_a_hole_drawn_only_at_its_mouths_is_one_hole(lib_at):
    # The open-centre beam 64178 draws the holes through its 20 LDU thick arms (along Y) with a
    # 1.5 LDU `npeghol` primitive at each face, 17 LDU apart: one hole from y = -10 to 10, as a
    # Technic brick's hole drawn with a 2 LDU `peghole` at each mouth (3701) is.
    from factory.joints import part_connectors

    def hole_at(name, x, z):
        found = [c for c in part_connectors(lib_at(name, 0, 0, 0).part) if c.kind == "pin-hole" and
                 abs(c.axis[1]) > 0.99 and (c.start[0], c.start[2]) == (x, z)]
        return sorted(round(v, 4) for c in found for v in (c.start[1], c.end[1]))

    assert hole_at("64178", 40.0, 60.0) == [-10.0, 10.0]
    assert hole_at("64178", -40.0, -20.0) == [-10.0, 10.0]
    assert hole_at("3701", 0.0, 10.0) == []  # its holes run along Z
    # Mouths farther apart than `HOLE_GAP_LDU` that span more than one hole stay apart.
    from factory.joints import JointConnector, merged_holes

    def mouths(a, b):
        return [JointConnector("pin-hole", (0.0, a, 0.0), (0.0, a + 1.5, 0.0), (0.0, 1.0, 0.0)),
                JointConnector("pin-hole", (0.0, b, 0.0), (0.0, b + 1.5, 0.0), (0.0, 1.0, 0.0))]

    assert [(c.start, c.end) for c in merged_holes(mouths(0.0, 18.5))] == [((0.0, 0.0, 0.0), (0.0, 20.0, 0.0))]
    assert len(merged_holes(mouths(0.0, 19.0))) == 2


def test_a_stop_bush_against_a_holes_mouth_is_part_of_the_pins_joint(lib_at):
    # The long pin with stop bush (32054) pushed into the cross block 48989's pin hole at y = 20
    # (along X, x -10 to 10): its bush (radius 9, x -30 to -10) lies against the block's face. The
    # overlap there lies 8.0 to 8.3 LDU from the axis, beyond a pin's collar (8 LDU) but within the
    # bush's (`unmodelled.BUSH_RADIUS_LDU`): the pin's joint, not an overlap beyond it.
    block = [lib_at("48989", 0, 0, 0)]
    pin = lib_at("32054", 0, 20, 0)
    v = verdict(block, pin)
    assert v.reason != "unsupported-connection" and [(l.kind, l.b) for l in v.joints] == [("technic-pin", 0)], v
    assert v.max_penetration_ldu <= 0.5, v
    # Off the hole's axis it is judged on its overlap.
    v = verdict(block, moved(pin, (0, 3, 0)))
    assert not v.ok and not v.joints, v


def test_a_tyre_on_a_wheel_drawn_into_a_plate_is_held_by_its_hub(lib_at):
    """A tyre (3641: round, no studs, sockets or connectors) on a wheel drawn into a plate that has
    studs and sockets too (122c01, a 2x2 plate with its wheels), centred on the wheel's axis as
    set 889 places it, is held by its shape (`unmodelled.on_a_hub`); slid off along the axis or
    lifted off it, nothing holds it. (Held in hand: a plate alone with one tyre tips.)"""
    plate = Structure([lib_at("122c01", 0, 0, 0)])
    turned = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # the tyre's axis (its Z) along the plate's X
    for x in (-30.0, 30.0):
        (v,) = check_units(plate, [[lib_at("3641", x, 6, 0, turned)]], "cpu", standing=False)
        assert v.ok and [(l.kind, l.b) for l in v.joints] == [("by-shape", 0)], v
    for dx, dy in ((-20.0, 0.0), (0.0, -8.0)):
        (v,) = check_units(plate, [[lib_at("3641", -30 + dx, 6 + dy, 0, turned)]], "cpu", standing=False)
        assert not v.ok and not v.joints, v


def held_on(structure, placed):
    """Place a part held in hand: checked, then added with the links of its joints."""
    (v,) = check_units(structure, [[placed]], "cpu", standing=False)
    assert v.ok, v
    structure.add(placed, v.links(len(structure)))
    return v


def test_a_bush_is_threaded_onto_an_axle_between_the_bricks_it_goes_through(at):
    """A bush (3713) on an axle between two Technic bricks 1x4 (3701) that the axle goes through
    cannot slide on from either end, but a builder threads it on as the axle goes in (the
    Gearbox's bushes and gears between its Technic bricks): a replay (`CheckConfig.threaded`)
    accepts it, its approach 'threaded'; the sampler's checks, whose steps must go straight in,
    do not. With a plain brick (3010) at the axle's end instead, which the axle does not go
    through, a builder holds the bush in the gap and pushes the axle through the Technic brick
    into it (`sweep.held_in_place`: it reaches the gap from above, the axle left out): threaded;
    with the gap walled in and roofed over, nothing puts it there: blocked."""
    from factory.replay import REPLAY_CONFIG

    bush = at("3713", 0, -14, 0)
    through = Structure([at("3031", 0, 0, 0)])
    for brick in (at("3701", 0, -24, -30), at("3701", 0, -24, 30), at("3707", 0, -14, 0, ALONG_Z)):
        held_on(through, brick)
    (v,) = check_units(through, [[bush]], "cpu", REPLAY_CONFIG, standing=False)
    assert v.ok and v.approach == "threaded" and [(l.kind, l.b) for l in v.joints] == [("technic-axle", 3)], v
    (v,) = check_units(through, [[bush]], "cpu", standing=False)
    assert v.reason == "blocked" and set(v.blocked_by) == {1, 2}, v
    ends = Structure([at("3031", 0, 0, 0)])
    for brick in (at("3701", 0, -24, -30), at("3010", 0, -24, 30), at("4519", 0, -14, -10, ALONG_Z)):
        held_on(ends, brick)
    (v,) = check_units(ends, [[bush]], "cpu", REPLAY_CONFIG, standing=False)
    assert v.ok and v.approach == "threaded", v
    (v,) = check_units(ends, [[bush]], "cpu", standing=False)
    assert v.reason == "blocked" and set(v.blocked_by) == {1, 2}, v
    for wall in (at("3004", -30, -24, 0, ALONG_Z), at("3004", 30, -24, 0, ALONG_Z), at("3031", 0, -32, 0)):
        held_on(ends, wall)
    (v,) = check_units(ends, [[bush]], "cpu", REPLAY_CONFIG, standing=False)
    assert v.reason == "blocked" and {1, 2} <= set(v.blocked_by), v


def test_a_bush_slides_off_the_nearer_end_of_its_axle_past_nothing_beyond_it(lib_at):
    """A bush (3713) on an axle 6 (3706) that goes through a Technic brick 1x4 (3701) at its one
    end cannot come on from there; from the other end it slides on, however long the axle: only
    its way off the axle's end and a fingertip's room past it are swept
    (`sweep._off_the_joint`), so a brick (3010) 60 LDU past that end does not block it, while one
    20 LDU past it does."""
    base = lib_at("3030", 0, 0, 0, ALONG_Z)
    lo, hi = base.pose.apply(box_corners(base.part.bbox)).min(0), base.pose.apply(box_corners(base.part.bbox)).max(0)
    assert hi[2] - lo[2] >= 200 - 1e-6, (lo, hi)  # its length along Z
    bush = lib_at("3713", 0, -14, -50)
    for brick_z, blocked in ((90.0, False), (50.0, True)):
        s = Structure([base])
        for brick in (lib_at("3701", 0, -24, -90), lib_at("3706", 0, -14, -40, ALONG_Z), lib_at("3010", 0, -24, brick_z)):
            held_on(s, brick)
        (v,) = check_units(s, [[bush]], "cpu", standing=False)
        if blocked:
            assert v.reason == "blocked" and set(v.blocked_by) == {1, 3}, v
        else:
            assert v.ok and [(l.kind, l.b) for l in v.joints] == [("technic-axle", 2)], v


@needs_ldraw
def test_parts_held_by_joints_alone_get_a_shift_fault_across_their_axis(tmp_path):
    """`verify --faults` moved only parts on studs (a Technic model such as fll.mpd got no fault at
    all). A pin in a Technic brick's hole and a beam on two pins, each held by joints alone, get a
    shift of 10 LDU across the pins' axis: off their holes, each is rejected; neither gets a lift
    or a turn (along and about a pin it slides and turns on its joint)."""
    from factory.replay import summarize, verify_model

    along_z, beam = "0 0 -1 0 1 0 1 0 0", "0 0 1 1 0 0 0 1 0"
    model = tmp_path / "pinned.ldr"
    model.write_text("0 Pinned\n"
                     "1 15 0 0 0 1 0 0 0 1 0 0 0 1 3701.dat\n0 STEP\n"
                     f"1 0 -20 10 10 {along_z} 3673.dat\n1 0 0 10 10 {along_z} 3673.dat\n0 STEP\n"
                     f"1 4 0 10 20 {beam} 32523.dat\n0 STEP\n")
    records = list(verify_model(model, str(LDRAW), faults=True))
    plain = [r for r in records if "fault" not in r]
    assert [r["reason"] for r in plain] == [None, None, None, None]
    assert [r["joints"] for r in plain[1:]] == [["technic-pin"]] * 3
    faults = [r for r in records if "fault" in r]
    assert [(r["step"], r["index"], r["fault"]) for r in faults] == [(1, 0, "shift"), (1, 1, "shift"), (2, 0, "shift")]
    assert all(r["reason"] is not None for r in faults), faults
    assert summarize(records)["faults"]["shift"]["rejected"] == 1.0


def test_a_wheel_is_held_by_its_shape_only_on_its_pin(at):
    """A rim (4624, drawn with a hollow centre and no connector primitives) on a wheel pin of the
    plate 4600, as car.ldr places it, is held on the pin (its hole's bar-size cylinder). Shifted
    10 LDU across the pin's axis its box still shares a tenth with the plate's, and `verify
    --faults` accepted it, held by its shape: a part round about its own hole
    (`unmodelled._round_on_its_hole`: a wheel, a rim, a half pin) is held by shape only on the
    axis of one of the other part's connectors. A part whose drawn connectors are not where it
    holds is held by shape as before: the horse 74323 on its hitch 4587 as Covered Wagon's horse
    places them, its bores 10 LDU from the hitch's bars."""
    plate = [at("4600", 0, 0, 0)]
    rim = at("4624", 30, 6, 0, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    v = verdict(plate, rim)
    assert v.ok and {(l.kind, l.b) for l in v.joints} == {("bar", 0)}, v  # its hole's grip on the pin
    for by in ((0, 0, 10), (0, -10, 0), (0, 0, -10)):
        v = verdict(plate, moved(rim, by))
        assert not v.ok and not v.joints, (by, v)
    # A tyre (no connectors at all) on that rim is still held by its shape.
    tyre = at("3641", 30, 6, 0, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    v = verdict(plate + [rim], tyre)
    assert v.ok and ("by-shape", 1) in [(l.kind, l.b) for l in v.joints], v
    hitch = at("4587", 0, 4, -40, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    v = verdict([hitch], at("74323", 0, -7, -138))
    assert ("by-shape", 0) in [(l.kind, l.b) for l in v.joints], v


def test_a_bar_slid_out_of_its_clip_is_not_held_by_shape(at):
    """The hinge top 3938 on its base 3937 as car.ldr places them (one pose) is held by its
    fingers. Lifted 10 LDU its fingers' bars lie beside the base's grips, parallel and against
    their outsides, and its box still shares a tenth with the base's: `verify --faults` accepted
    it, held by its shape. A bar or handle beside a clip or grip it goes in, off its axis by no
    more than `unmodelled.BESIDE_CLIP_LDU`, is out of it: nothing holds it there."""
    base = [at("3937", 0, 0, 0)]
    top = at("3938", 0, 0, 0)
    v = verdict(base, top)
    assert v.ok and v.joints and "by-shape" not in [l.kind for l in v.joints], v
    v = verdict(base, moved(top, (0, -10, 0)))
    assert not v.ok and not v.joints, v
