"""The joints that hold a part beyond studs (`joints_between`: Technic pins and axles, wheel pins,
clips and bars, hinge fingers, bars in open studs, minifigure joints, tyres on rims), with where
their overlap lies, and whether a part may be held where no joint mates (`may_hold`: then its
placement is `unsupported-connection`, not judged).

A part's connector primitives, where it has them, say where a joint can be: connectors of the two
parts that mate lie on one axis, pushed home (a pin in a hole, a hinge finger between the other
half's fingers). Clips, bars and hinges are mostly drawn without connector primitives, but always
with cylinders of the bar's radius (`Flat.bars`: 4 LDU): a bar in a clip, a pin in a hollow stud
and hinge fingers between fingers put such cylinders of two parts on one axis (`bar_joints`). A
part drawn without any can only be judged by its shape: a new part with no sockets (a tyre, a rim)
against a placed part without studs or sockets. Minifigure pieces hold one another by joints of
their own (`is_minifig`). The overlap a joint makes (the collision pieces fill a clip's grip, a
hollow stud, the gaps between fingers, a pin's hole) lies round its axis (`Joint.zone`,
`Joint.radius`); the checks leave that out and judge the rest of the overlap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factory.gears import part_teeth
from factory.ldraw.other_connectors import BAR_RADIUS, CONNECTOR_KINDS, place_connectors
from factory.joints import (HOME_TOL_LDU, JointConnector, click_angle, mates, on_a_click, on_one_axis, part_connectors, part_stretches,
                            stretch_overlap, together)
from factory.minifig import FEET, FOOT_AXIS, in_a_slot, related, role
from factory.parts import Part, box_corners
from factory.physics.structure import connectors
from factory.pose import Pose

NEAR_LDU = 2.0
"""How far apart two connector axes may run, and how far apart along them the two stretches may
end, for the connectors to be one connection. Measured on the two real models (car.ldr, 4915): the
mated hinges are within 0.53 LDU of each other's axis (model files round rotated sub-assemblies)
and their stretches overlap; the faults the old count-based rule excused are 31 LDU or more off
any axis, and a fault moves a part 8-10 LDU. A move along the shared axis (a pin slid in its hole)
keeps the connectors on one line: only sliding past the end is caught."""
BAR_AXIS_LDU = 1.0
"""How far apart the axes of two bar-size cylinders may run for them to be one joint. A bar off
its clip's axis by more than a quarter of its radius is pressed into the clip's wall, not held;
the joints of the six real designs are on one axis to 0.01 LDU (the clip tile and the round plate
with bar of the Vintage Car, the car roof hinge, the surf board's pins in hollow side studs)."""
JOINT_RADIUS_LDU = 6.5
"""How far from a bar joint's axis the overlap it makes may lie: a stud's radius (a hollow stud's
wall round a pin; a clip's grip is thinner), and the overlap tolerance."""
TECHNIC_RADIUS_LDU = 8.0
"""The same for a joint of connector primitives (a Technic pin in its hole: the pin's collar, wider
than its 6 LDU shaft, sits in the counterbore at the hole's mouth; the friction pin 2780 in the
beam 18654 overlaps 1.3 LDU at 7 LDU from the axis, none beyond 8)."""
BUSH_RADIUS_LDU = 9.0
"""The same for a Technic joint with a bush on its axis, of either part, at its stretch: a bush's
collar is drawn to 9 LDU from its axis (`bush1`; the stop bush of the long pin 32054, the flanges
of 3713), and it lies against the face round the hole's mouth. 32054's stop bush against the
beam 64178 and the cross block 48989 overlaps them 1.1 to 1.4 LDU at 8.0 to 8.3 LDU from the
axis, the medium motor 99455 at up to 8.9."""

END_LDU = 0.5
"""How far the ends of two solid bar-size cylinders on one axis may be apart, or into each other,
for them to be fingers side by side (the checker's overlap tolerance)."""
PARALLEL_DEG = 10.0
"""Most angle between two connector axes that can still be one connection (mated: 0 degrees,
a turned hinge plate: 90)."""


def is_minifig(part: Part) -> bool:
    """A minifigure piece (LDraw titles them "Minifig ...", "~Minifig ..." for sub-pieces): head,
    headgear, torso, arms, hands, hips, legs and what they hold."""
    return part.description.lstrip("~_=| ").startswith("Minifig")


def held_otherwise(part: Part) -> bool:
    """Whether a new part can be held by more than studs: Technic or clip primitives, or no
    sockets to sit on studs with (a hinge top, a tyre, a rim). A tile or a cheese slope has
    sockets and nothing else to hold it: off its studs it is judged like any brick."""
    return len(part.flat.other_connectors) > 0 or not part.sockets


def offers_other(part: Part) -> bool:
    """Whether a placed part can hold another by more than studs: Technic or clip primitives, a
    hollow stud's bore (a bar goes in), or a side without studs or sockets (a hinge half, a tyre,
    a rim)."""
    return len(part.flat.other_connectors) > 0 or len(part.flat.bores) > 0 or not part.studs or not part.sockets


def _connectors(part: Part) -> np.ndarray:
    """Every connector of a part with a position: its primitives and its hollow studs' bores."""
    return np.concatenate([part.flat.other_connectors, part.flat.bores])


def _minifig_pair(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> bool:
    """Whether two touching minifigure pieces hold one another: in a slot of one another where
    their roles have one, or of one role never (`factory.minifig.related`); pieces with no slot
    between them (a hand on a torso, a tool in a hand) wherever they meet."""
    a, b = role(new.description), role(placed.description)
    return a is None or b is None or not related(a, b) or in_a_slot(a, new_pose, b, placed_pose)


def may_hold(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> bool:
    """Whether `placed` (touched by `new`) may hold `new` by a connection not modelled. When both
    have connectors with a position, their positions decide; otherwise the shapes (see the
    module). A hollow stud's bore counts as a position on either side, but not towards the new
    part's shape: a round brick off its studs is not held by its own bore."""
    if is_minifig(new) and is_minifig(placed):
        # Minifigure pieces join by their own joints (neck, shoulders, wrists, hips, headgear on
        # the head's stud, which sits inside it), none of them a stud connection: the LDraw
        # files place a head and a helmet, or a neck and a head, overlapping by design.
        return _minifig_pair(new, new_pose, placed, placed_pose)
    if part_teeth(new) and part_teeth(placed):
        return False  # gears mesh or collide (`factory.gears.meshes`): neither holds the other
    a, b = _connectors(new), _connectors(placed)
    if len(a) and len(b):
        return connectors_meet(place_connectors(a, new_pose.R, new_pose.t),
                               place_connectors(b, placed_pose.R, placed_pose.t))
    return held_otherwise(new) and offers_other(placed)


JOINTS = ("minifig", "click-hinge", "clip-bar", "wheel-pin", "technic-axle", "technic-pin", "bar-in-stud", "bar",
          "by-shape")
"""The kinds of connection the checker does not model yet, as `joint_kind` names them, most specific
first: minifigure joints; a click hinge, a clip on a bar or handle, a wheel pin, an axle (in an
axle or pin hole), a Technic pin or bush, told by the connector primitives that meet; a bar or pin
in a hollow stud's bore; a clip, bar or hinge told only by cylinders of a bar's radius on one axis
(`bar_joints`); and parts drawn without any of these, held by their shapes (a tyre on a rim)."""


def _joint_of(kinds: set[str]) -> str:
    for joint, of in (("click-hinge", {"hinge"}), ("clip-bar", {"clip", "handle"}), ("wheel-pin", {"wheel-pin", "wheel-pin-hole"}),
                      ("technic-axle", {"axle", "axle-hole"}), ("technic-pin", {"pin", "pin-hole", "bush"})):
        if kinds & of:
            return joint
    return "bar-in-stud"


def _kinded(part: Part) -> tuple[np.ndarray, list[str]]:
    """`_connectors` with what each is (`CONNECTOR_KINDS`; a hollow stud's bore is 'bore')."""
    kinds = [CONNECTOR_KINDS[k] for k in part.flat.other_kinds] + ["bore"] * len(part.flat.bores)
    return _connectors(part), kinds


def joint_kind(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> str | None:
    """Which kind of connection (`JOINTS`) `placed` may hold `new` by, where `may_hold` or
    `bar_joints` says it may; None where neither does."""
    if is_minifig(new) and is_minifig(placed):
        return "minifig" if _minifig_pair(new, new_pose, placed, placed_pose) else None
    (a, ka), (b, kb) = _kinded(new), _kinded(placed)
    if len(a) and len(b):
        pa, pb = place_connectors(a, new_pose.R, new_pose.t), place_connectors(b, placed_pose.R, placed_pose.t)
        met = {k for i, j in _meeting(pa, pb) for k in (ka[i], kb[j])}
        if met:
            return _joint_of(met)
    elif held_otherwise(new) and offers_other(placed):
        return "by-shape"
    if not len(bar_joints(new, new_pose, placed, placed_pose)):
        return None
    return "bar-in-stud" if _in_bore(new, new_pose, placed, placed_pose) else "bar"


def _in_bore(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> bool:
    """Whether a bar-size cylinder of one part lies in a hollow stud's bore of the other."""
    for (a, pa), (b, pb) in (((new, new_pose), (placed, placed_pose)), ((placed, placed_pose), (new, new_pose))):
        if len(a.flat.bars) and len(b.flat.bores) and len(bars_meet(
                place_connectors(a.flat.bars, pa.R, pa.t), a.flat.bar_out,
                place_connectors(b.flat.bores, pb.R, pb.t), -np.ones(len(b.flat.bores)))):
            return True
    return False


def _rounds(part: Part) -> tuple[np.ndarray, np.ndarray]:
    """A part's bar-size cylinders (`Flat.bars`) and hollow studs' bores, with their sides: +1
    solid, -1 hollow (a bore always), 0 not known."""
    return (np.concatenate([part.flat.bars, part.flat.bores]),
            np.concatenate([part.flat.bar_out, -np.ones(len(part.flat.bores))]))


def bars_meet(a: np.ndarray, a_out: np.ndarray, b: np.ndarray, b_out: np.ndarray) -> np.ndarray:
    """Where bar-size cylinders of `a` and `b` (in one frame, sides as `_rounds`) make a joint, as
    (k, 3, 3) stretches of axis (end, end, axis: the two cylinders' stretches together): on one
    axis (`PARALLEL_DEG`, `BAR_AXIS_LDU`), a solid one inside a hollow one (a bar or a pin in a
    clip or a bore: their stretches overlap), or a solid finger of one part between two solid
    fingers of the other, end to end within `END_LDU` (a hinge; two pins that only meet end to
    end, a brick's underside pin on another part's pin, hold nothing). Two hollow ones hold
    nothing; where a side is not known (0), either is allowed."""
    pairs = [(i, j) for i in range(len(a)) for j in range(len(b))
             if not (a_out[i] < 0 and b_out[j] < 0) and on_one_axis(a[i], b[j], PARALLEL_DEG, BAR_AXIS_LDU)]
    found = [(i, j) for i, j in pairs if a_out[i] * b_out[j] <= 0 and stretch_overlap(a[i], b[j]) > 0]
    solid = [(i, j) for i, j in pairs if a_out[i] >= 0 and b_out[j] >= 0]
    for fingers, others, side in ((a, b, 0), (b, a, 1)):
        ends: dict[int, dict] = {}
        for pair in solid:
            f, o = pair[side], pair[1 - side]
            u = fingers[f][2]
            x, y = sorted(fingers[f][:2] @ u), sorted(others[o][:2] @ u)
            if abs(y[1] - x[0]) <= END_LDU:
                ends.setdefault(f, {})["low"] = pair
            if abs(y[0] - x[1]) <= END_LDU:
                ends.setdefault(f, {})["high"] = pair
        found += [pair for e in ends.values() if len(e) == 2 for pair in e.values()]
    return np.array([together(a[i], b[j]) for i, j in found]).reshape(-1, 3, 3)


def bar_joints(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> np.ndarray:
    """Where `new` and `placed` meet at a clip, bar, hinge or pin joint (`bars_meet`), as stretches
    of axis (k, 3, 3) in the world frame; empty where they do not."""
    (a, a_out), (b, b_out) = _rounds(new), _rounds(placed)
    if not (len(a) and len(b)):
        return np.zeros((0, 3, 3))
    return bars_meet(place_connectors(a, new_pose.R, new_pose.t), a_out,
                     place_connectors(b, placed_pose.R, placed_pose.t), b_out)


def in_zone(points: np.ndarray, zones: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(n,) whether each point lies within its radius of one of the stretches of axis of `zones`
    (stretches (k, 3, 3), radii (k,)), between its ends grown by that radius."""
    points = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(len(points), bool)
    for (p0, p1, u), radius in zip(*zones):
        d = points - p0
        along = d @ u
        radial = np.linalg.norm(d - along[:, None] * u, axis=1)
        lo, hi = sorted([0.0, float((p1 - p0) @ u)])
        out |= (radial <= radius) & (along >= lo - radius) & (along <= hi + radius)
    return out


def zone_moved(zones: tuple[np.ndarray, np.ndarray] | None, pose) -> tuple[np.ndarray, np.ndarray] | None:
    """`zones` (stretches of axis (k, 3, 3): two ends and the axis; radii (k,)) moved by `pose`
    (a `factory.pose.Pose`); None stays None (a joint with no axis)."""
    if zones is None:
        return None
    stretches, radii = zones
    ends = pose.apply(stretches[:, :2].reshape(-1, 3)).reshape(-1, 2, 3)
    return np.concatenate([ends, (stretches[:, 2] @ pose.R.T)[:, None]], axis=1), radii


def separation(s: np.ndarray, t: np.ndarray) -> tuple[float, float, float]:
    """(angle in degrees, radial distance, gap along the axis) between two connectors (end, end,
    axis): how far `s` is from lying on `t`'s axis line, and how far apart their stretches end."""
    u = t[2]
    angle = float(np.degrees(np.arccos(min(1.0, abs(float(s[2] @ u))))))
    d = s[:2].mean(0) - t[0]
    radial = float(np.linalg.norm(d - (d @ u) * u))
    a, b = sorted((s[:2] - t[0]) @ u), sorted(t[:2] @ u - t[0] @ u)
    gap = max(0.0, a[0] - b[1], b[0] - a[1])
    return angle, radial, float(gap)


def _meeting(a: np.ndarray, b: np.ndarray):
    """(i, j) for each connector `a[i]` that lies on the axis of `b[j]` (both in one frame),
    within the tolerances above."""
    for i, s in enumerate(a):
        for j, t in enumerate(b):
            angle, radial, gap = separation(s, t)
            if angle <= PARALLEL_DEG and radial <= NEAR_LDU and gap <= NEAR_LDU:
                yield i, j


def connectors_meet(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether any connector of `a` (j, 3, 3) lies on the axis of one of `b` (k, 3, 3), both in
    one frame, within the tolerances above."""
    return next(_meeting(a, b), None) is not None


@dataclass(frozen=True)
class Joint:
    """Where a new part is held by a joint of a placed part (`joints_between`), world frame (LDU)."""

    kind: str
    """One of `JOINTS`."""
    point: tuple[float, float, float]
    """Where it holds: the middle of the stretch the two connectors share, or for a joint with no
    axis, the middle of where the two parts' boxes meet."""
    axis: tuple[float, float, float] | None
    """The joint's axis (the placed part's connector's); None for a minifigure joint or a part
    held by its shape."""
    zone: tuple | None
    """The stretch of axis (end, end, axis) round which the overlap the joint makes lies
    (`in_zone`); None where the joint has no axis: all of the overlap of the two parts is the
    joint's."""
    radius: float = JOINT_RADIUS_LDU
    """How far from `zone`'s axis that overlap may lie."""


def world_box(part: Part, pose: Pose) -> np.ndarray:
    """The axis-aligned box (2, 3: lowest, highest corner; LDU) a part fills at a pose."""
    world = pose.apply(box_corners(part.bbox))
    return np.stack([world.min(0), world.max(0)])


def boxes_near(a: np.ndarray, b: np.ndarray, gap: float = 2.0) -> bool:
    """Whether two boxes (`world_box`) are within `gap` LDU of each other: a coarse test of whether
    two parts may touch, and so be joined (the checks' touching distance, `collide.NEAR_LDU`, is
    a real gap of 1 LDU)."""
    return bool(np.all(a[0] <= b[1] + gap) and np.all(b[0] <= a[1] + gap))


def _box_meeting(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> tuple[float, float, float]:
    """The middle of where two parts' world boxes meet (overlap, or the gap between them)."""
    a, b = world_box(new, new_pose), world_box(placed, placed_pose)
    lo, hi = np.maximum(a[0], b[0]), np.minimum(a[1], b[1])
    return tuple(round(float(v), 4) for v in (lo + hi) / 2)


def _is_round(kind: str) -> bool:
    return kind in ("bar", "grip", "bore")


def _joint(kind: str, stretch: np.ndarray, radius: float = JOINT_RADIUS_LDU) -> Joint:
    mid = stretch[:2].mean(0)
    return Joint(kind, tuple(round(float(v), 4) for v in mid), tuple(round(float(v), 6) for v in stretch[2]),
                 tuple(tuple(round(float(v), 4) for v in row) for row in stretch), radius)


FOOT_LDU = 0.5
"""How far a stud may be from a minifigure's foot hole and still be in it (the designs' standing
figures: within 0.01 LDU of a stud, or 1 LDU or more off it)."""
STUD_HEIGHT_LDU = 4.0
"""How far a stud stands into a foot: the stretch round which a foot joint's overlap lies."""


def _feet_on_studs(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> list[Joint]:
    """A minifigure's feet (`factory.minifig.FEET`) on studs of `placed` pointing into them: one
    minifigure joint at each, its overlap round the stud."""
    feet = FEET.get(role(new.description))
    if not feet or not placed.studs:
        return []
    pos, axis = connectors(placed, placed_pose, "studs")
    into = axis @ (new_pose.R @ np.asarray(FOOT_AXIS)) > np.cos(np.radians(PARALLEL_DEG))
    out = []
    for at in new_pose.apply(np.asarray(feet)):
        hit = np.flatnonzero(into & (np.linalg.norm(pos - at, axis=1) <= FOOT_LDU))
        if len(hit):
            k = hit[0]
            out.append(_joint("minifig", np.stack([pos[k], pos[k] + STUD_HEIGHT_LDU * axis[k], axis[k]])))
    return out


def joints_between(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> list[Joint]:
    """The joints by which `placed` holds `new` (both at their world poses): a minifigure joint
    between two minifigure pieces (in a slot of one another, where their roles have one:
    `factory.minifig.related`), or at a minifigure's foot on a stud (`_feet_on_studs`); connector primitives of the two that mate (`joints.mates`:
    a pin in a pin hole, an axle in an axle hole, a clip on a bar or handle, a wheel on its pin,
    click hinge halves) on one axis (`NEAR_LDU`); bar-size cylinders or bores that meet
    (`bars_meet`: a bar in a clip or a hollow stud, hinge fingers between fingers); and where
    one side has no connector primitive, a part without sockets held by its shape (a wheel or
    half pin, `_round_on_its_hole`, only on the axis of one of the other's connectors)
    (a tyre on a rim; a part with sockets sits on studs, and one slid off them beside a part
    without any is not held). Empty where none holds it."""
    if is_minifig(new) and is_minifig(placed):
        if not _minifig_pair(new, new_pose, placed, placed_pose):
            return []  # out of its slot (a head beside its neck, a second torso on the first)
        return [Joint("minifig", _box_meeting(new, new_pose, placed, placed_pose), None, None)]
    if is_minifig(new):
        feet = _feet_on_studs(new, new_pose, placed, placed_pose)
        if feet:
            return feet
    if not part_connectors(new) and new.sockets:
        return []  # nothing to be held by (every part of the embedded library but the round ones)
    out: list[Joint] = []
    loose: list[np.ndarray] = []
    ca, cb = part_connectors(new), part_connectors(placed)
    pa = place_connectors(part_stretches(new), new_pose.R, new_pose.t)
    pb = place_connectors(part_stretches(placed), placed_pose.R, placed_pose.t)
    for i, j in _meeting(pa, pb):
        ka, kb = ca[i].kind, cb[j].kind
        if _is_round(ka) and _is_round(kb):
            continue  # two round cylinders: `bars_meet`'s rules, below
        freedom = mates(ka, kb)
        if freedom is None:
            continue  # two holes in line, a pin end to end with a pin: nothing holds
        if freedom.stepped and not _clicked(ca[i], new_pose, cb[j], placed_pose):
            loose.append(together(pa[i], pb[j]))  # between two steps: its fingers hold nothing
            continue
        if not freedom.stepped and stretch_overlap(pa[i], pb[j]) < min(ca[i].length, cb[j].length) - HOME_TOL_LDU:
            # Not pushed home: the shorter of the two lies wholly on the other (a pin all the way
            # into its hole, a hole all on its axle wherever it slides); a male end at a female's
            # mouth is not in it. Hinge halves meet end to end.
            continue
        stretch = together(pa[i], pb[j])
        bushed = any(c.kind == "bush" and on_one_axis(s, stretch, PARALLEL_DEG, NEAR_LDU) and
                     stretch_overlap(s, stretch) >= -NEAR_LDU
                     for conns, placed_at in ((ca, pa), (cb, pb)) for c, s in zip(conns, placed_at))
        found = _joint(_joint_of({ka, kb}), stretch, BUSH_RADIUS_LDU if bushed else TECHNIC_RADIUS_LDU)
        if not any(o.kind == found.kind and o.point == found.point for o in out):
            out.append(found)  # a hole drawn with a primitive at each mouth is one joint with a pin
    # Cylinders on the axis of a primitives' joint found above (a rim's hole round a wheel pin) or
    # of a click hinge turned between two steps (its fingers) are that joint's, not a bar's.
    taken = [np.array(o.zone) for o in out] + loose
    rounds = bar_joints(new, new_pose, placed, placed_pose)
    kind = "bar-in-stud" if len(rounds) and _in_bore(new, new_pose, placed, placed_pose) else "bar"
    for stretch in rounds:
        if not any(on_one_axis(stretch, z, PARALLEL_DEG, BAR_AXIS_LDU) and stretch_overlap(stretch, z) > 0 for z in taken):
            out.append(_joint(kind, stretch))
    if not out and not new.sockets and not (len(_connectors(new)) and len(_connectors(placed))) \
            and _box_share(new, new_pose, placed, placed_pose) >= SHAPE_SHARE \
            and (offers_other(placed) or on_a_hub(new, new_pose, placed, placed_pose)) \
            and not (part_teeth(new) and part_teeth(placed)) \
            and not (len(cb) and _round_on_its_hole(new) and not connectors_meet(pa, pb)) \
            and not _bar_beside_its_clip(ca, pa, cb, pb):
        # (Two gears share their boxes where their teeth meet: they mesh or collide, and neither
        # holds the other.) A wheel or a half pin goes on by its hole or pin: off the axis of
        # every connector of the part it meets (10 LDU off its wheel pin) it still shares a tenth
        # of their boxes, but nothing holds it; nor does anything hold a bar slid out of its clip,
        # beside it. Parts whose drawn connectors are not where they hold (a horse's bores 10 LDU
        # from its hitch's bars, air tanks round a neck) are held by their shapes.
        out.append(Joint("by-shape", _box_meeting(new, new_pose, placed, placed_pose), None, None))
    return out


_BARS, _CLIPS = {"bar", "handle"}, {"clip", "grip"}


def _bar_beside_its_clip(ca, pa, cb, pb) -> bool:
    """Whether a bar or handle of one part lies against the outside of a clip or grip of the other
    (`part_connectors` `ca`, `cb` placed as `pa`, `pb`): parallel, side by side along the axis,
    off it by more than a joint's `NEAR_LDU` but no more than `BESIDE_CLIP_LDU`."""
    for c, s in zip(ca, pa):
        for d, t in zip(cb, pb):
            if (c.kind in _BARS and d.kind in _CLIPS) or (c.kind in _CLIPS and d.kind in _BARS):
                angle, radial, gap = separation(s, t)
                if angle <= PARALLEL_DEG and gap <= NEAR_LDU and NEAR_LDU < radial <= BESIDE_CLIP_LDU:
                    return True
    return False


def _round_on_its_hole(part: Part) -> bool:
    """Whether one of the part's symmetries turns it about the axis line of one of its own joint
    connectors (`part_connectors`): a wheel or rim about its hole, a half pin about its pin."""
    conns = part_connectors(part)
    for S in part.symmetry.rotations[1:]:
        w, v = np.linalg.eig(S)
        axis = np.real(v[:, np.argmin(np.abs(w - 1.0))])  # a proper rotation keeps its axis
        for c in conns:
            u = np.asarray(c.axis, float)
            start = np.asarray(c.start, float)
            if abs(float(u @ axis)) >= np.cos(np.radians(PARALLEL_DEG)) \
                    and np.linalg.norm(start - (start @ u) * u) <= NEAR_LDU:  # its line through the origin
                return True
    return False


def _clicked(a: JointConnector, a_pose: Pose, b: JointConnector, b_pose: Pose) -> bool:
    """Whether two click hinge halves (at their parts' poses) are turned to one of the hinge's
    steps (`joints.on_a_click`); halves whose turn is not known are taken as held."""
    if a.ref is None or b.ref is None:
        return True
    return on_a_click(click_angle(a_pose.R @ np.array(a.ref), b_pose.R @ np.array(b.ref), b_pose.R @ np.array(b.axis)))


def on_a_hub(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> bool:
    """Whether `new` is a round part with no connectors of its own (a tyre) centred on the axis
    of one of `placed`'s connectors: a tyre on the wheel hub of a part that has studs and
    sockets too (122c01, a plate with its wheels drawn in), which `offers_other` does not see."""
    if new.symmetry.continuous_axis is None or new.studs or new.sockets or len(part_connectors(new)):
        return False
    axis = np.asarray(new.symmetry.continuous_axis, float)  # through the part's origin
    lo, hi = sorted(new.bbox @ axis)
    u = new_pose.R @ axis
    line = np.stack([new_pose.t + lo * u, new_pose.t + hi * u, u])
    return any(on_one_axis(s, line, PARALLEL_DEG, BAR_AXIS_LDU)
               for s in place_connectors(part_stretches(placed), placed_pose.R, placed_pose.t))


BESIDE_CLIP_LDU = 3 * BAR_RADIUS
"""How far off a clip's (or a grip's) axis a bar or handle parallel to it, beside it along the
axis, lies against the clip's outside rather than anywhere else: the clip's jaws, about a bar's
radius thick round a bar's radius, and the bar's own radius. Such a bar is out of the clip it
goes in, and the two parts' shapes do not hold it there (`joints_between`). Parts held by their
shapes on the 19 designs of ../shared/designs have no bar and clip closer than 16 LDU."""
SHAPE_SHARE = 0.1
"""How much of the smaller of two parts' boxes the boxes must share for one to hold the other by
its shape (a rim's box lies inside its tyre's; hinge halves drawn without connectors share the
stretch where their fingers interleave). A part merely touching one without studs (a brick slid
against a tile, a shift fault) shares none: it is not held by it."""


def _box_share(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> float:
    """The volume two parts' world boxes share, as a share of the smaller box's volume."""
    a, b = world_box(new, new_pose), world_box(placed, placed_pose)
    side = np.minimum(a[1], b[1]) - np.maximum(a[0], b[0])
    shared = float(np.prod(np.maximum(side, 0.0)))
    smaller = min(float(np.prod(a[1] - a[0])), float(np.prod(b[1] - b[0])))
    return shared / smaller if smaller > 0 else 0.0

