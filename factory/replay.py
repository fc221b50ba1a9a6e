"""Replay a human-designed model's build steps through the physics checks (`verify_model`).

The library behind `python -m pipelines.verify MODEL [--ldraw DIR] [--check-backend cpu|jax] --json`
and the physics records of the design dataset source (`pipelines.dataset.sources`).

Each placed part is checked against the parts placed before it in the same sub-assembly (the first
part of a sub-assembly, or one laid on the table beside it, needs no connection; a part may hang
from another part of its own step, or be held in hand until what the next step of its assembly
places holds it, or, failing that, until the first later part that holds it is on (gears set
between beams before the axle is pushed through them: `held_for_parts` in its record); the parts
of one step go in in any order, so a part that cannot be pressed in under or between parts of its
own step listed before it is judged going in first); a completed sub-assembly is checked as one
rigid unit against the parts of its parent placed before it. Each sub-assembly is checked in its own frame (as its
author built it) and is held in hand while built: only the main model must stand on the ground,
sub-assemblies are judged on their connections. A step that makes the main model tip on the table
(not a part swinging on a free joint, whose verdict names the joint) is judged as held in hand too,
as a person holds a Technic frame before its wheels are on (`held_in_hand` in its record). A part
or sub-assembly rejected where the design draws it is judged again seated on the connection it was
drawn within 3.5 LDU of (`physics.seat`: `seated_ldu` in its record), as hand-drawn CAD files set
parts a little off the grid. A part rejected only for meeting an earlier part that was itself
rejected while overlapping where drawn is judged without it (`drawn_wrong`: `judged_without`), so
one drawing error counts once.
One JSON object per placed part, and one with `"unit": true` per sub-assembly attachment.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from factory.drawn_wrong import judged_past, off_grid_ldu
from factory.errors import LDrawError, LDrawLimitError
from factory.ldraw import NO_PARTS, build_steps, get_reader
from factory.ldraw.model import count_parts
from factory.ldraw.subassembly import UnitDone, parent_of, relative_frame, to_local, walk
from factory.parts import load_part
from factory.physics.geometry import collision_shape
from factory.physics.check import CheckConfig, Verdict, check_units
from factory.physics.load_model import Link
from factory.physics.structure import Placed, Structure, canonical_key, connectors, match
from factory.physics.linked import links_by_joints
from factory.physics.seat import seat_offset
from factory.physics.unmodelled import JOINTS, boxes_near, joint_kind, joints_between, world_box
from factory.pose import Pose
from factory.symmetry import rotation_about


def _record(verdict: Verdict, **extra) -> dict:
    return {
        **extra,
        "collision": bool(verdict.collision),
        "max_penetration_ldu": verdict.max_penetration_ldu,
        "connected": verdict.connected,
        "connections": verdict.connections,
        "stable": verdict.stable,
        "load": verdict.load,
        "failing": [f.to_json() for f in verdict.failing],
        # Buildability in the design's own order: None where not judged (rejected before the
        # sweep, no stud connection, or connections on two axes: `approach` says which).
        "buildable": verdict.buildable,
        "approach": verdict.approach,
        "blocked_by": list(verdict.blocked_by),
        "reason": verdict.reason,
    }


def held_joints(structure: Structure, unit: list[Placed], verdict: Verdict) -> list[str]:
    """The kinds of unmodelled connection (`unmodelled.JOINTS`, most specific first) by which the
    parts of `verdict.held_by` may hold a part of `unit` (one part, or a sub-assembly's)."""
    found = {joint_kind(p.part, p.pose, structure.placed[j].part, structure.placed[j].pose)
             for j in verdict.held_by for p in unit}
    return [j for j in JOINTS if j in found]


def _joint_record(structure: Structure, unit: list[Placed], verdict: Verdict) -> dict:
    """A record's `joints`: the kinds of joint that hold the unit (`verdict.joints`), or for an
    unsupported connection the kinds that may (`held_joints`), most specific first; none: {}."""
    if verdict.reason == "unsupported-connection":
        return {"joints": held_joints(structure, unit, verdict)}
    kinds = {l.kind for l in verdict.joints}
    return {"joints": [j for j in JOINTS if j in kinds]} if kinds else {}


NO_VOLUME = "no-volume"
"""The reason of a part with no volume (faces in one plane, e.g. a sticker): not checked."""


def _solid(part) -> bool:
    """Whether the part has a collision piece (`geometry.collision_shape`): a body or a stud."""
    shape = collision_shape(part)
    return bool(shape.body or shape.studs)


DUPLICATE = "duplicate"
"""The reason of a part placed where the same part already is (the same file at the same pose, up
to `DUPLICATE_LDU`): two copies no builder could place, an authoring error of the design (the
Gearbox places a 1x6 brick and a Technic brick twice so). Reported, not checked, left out of the
structure and of the acceptance rate, as `no-volume`."""

DUPLICATE_LDU = 0.01
"""How close two copies' origins and axes (each column of the pose's matrix) must be to be one."""


def duplicate_of(structure: Structure, placed: Placed) -> int | None:
    """The index of a part of `structure` that `placed` duplicates (`DUPLICATE`), None if none."""
    for i, q in enumerate(structure.placed):
        if (q.part.name.lower() == placed.part.name.lower()
                and np.abs(q.pose.t - placed.pose.t).max() <= DUPLICATE_LDU
                and np.abs(q.pose.R - placed.pose.R).max() <= DUPLICATE_LDU / 20.0):
            return i
    return None


def _flat_record(reason: str = NO_VOLUME, **extra) -> dict:
    """The record of a part not checked (`_record` of an empty verdict): no volume, or a duplicate."""
    return _record(Verdict(Pose.identity(), connected=False, connections=0, collision=False,
                           max_penetration_ldu=0.0, reason=reason), **extra)


def _faults(structure, local: Placed, backend, config, standing, step, index, finished=None, joint_axes=()):
    # Faults follow the part's connection: 'up' is away from the studs it sits on (or hangs from),
    # 'sideways' is across that axis, 'turn' is about it through the part's origin. A part held by
    # joints alone (`joint_axes`: a beam on its pins, a wheel on its axle) gets the shift only,
    # across the first joint's axis: along it pins and axles slide part way in and out, and about
    # it pins and wheels turn, so neither moves it off its connection.
    axes = []
    sp, sa, _ = structure.studs
    kp, ka, _ = structure.sockets

    cp, ca = connectors(local.part, local.pose, "sockets")
    for i, _ in match(sp, sa, cp, ca):
        axes.append(sa[i])  # a structure stud in our socket: we sit on it, away = its axis
    cp, ca = connectors(local.part, local.pose, "studs")
    for _, j in match(cp, ca, kp, ka):
        axes.append(-ka[j])  # our stud in a structure socket above: away = against its axis
    by_joints = not axes
    if by_joints:
        if not len(joint_axes):
            return
        axes = [np.asarray(joint_axes[0], float)]
    up = np.mean(axes, axis=0)
    up = up / np.linalg.norm(up)
    side = np.cross(up, [0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.cross(up, [1.0, 0.0, 0.0])
    side = side / np.linalg.norm(side)
    for name in ("shift",) if by_joints else FAULTS:
        if name == "turn":
            moved = Pose(rotation_about(up, 90.0) @ local.pose.R, local.pose.t)
            if canonical_key(local.part, moved) == canonical_key(local.part, local.pose) or np.allclose(
                world_box(local.part, moved), world_box(local.part, local.pose), atol=1.0
            ):
                # The part looks the same turned, or fills the same box (a 1x1 or 2x2 part: only
                # its slope or face turns): nothing it could clash with moves, no fault to inject.
                continue
        else:
            move = 8.0 * up if name == "lift" else 10.0 * side
            moved = Pose(local.pose.R, local.pose.t + move)
            if lands_on_a_joint(structure, local.part, moved, move, up if by_joints else None):
                continue  # not a fault: builders put parts there
        (v,) = check_units(structure, [[Placed(local.part, local.colour, moved)]], backend, config,
                           standing=standing)
        yield _record(v, step=step, index=index, part=local.part.name, color=local.colour, fault=name,
                      **_joint_record(structure, [Placed(local.part, local.colour, moved)], v))
        if name == "turn" and finished is not None:
            # The same turn in the finished design: every other part of the assembly in place,
            # those built later too (a turn that fits the parts built so far can still clash
            # with the parts the design puts around it).
            others = Structure([q for q in finished if q is not local])
            (v,) = check_units(others, [[Placed(local.part, local.colour, moved)]], backend, config,
                               standing=standing)
            yield _record(v, step=step, index=index, part=local.part.name, color=local.colour,
                          fault=TURN_FINISHED)


SLIDING_JOINTS = ("clip-bar", "bar", "bar-in-stud", "technic-axle")
"""Joint kinds a part slides along (`joints.FREEDOMS`): moved along such a joint's axis it is
still on it."""


def lands_on_a_joint(structure: Structure, part, moved: Pose, move: np.ndarray,
                     held_axis: np.ndarray | None = None) -> bool:
    """Whether a fault's move puts the part on another real connection, so that it is no fault:
    a socket of it on a stud or a stud of it in a socket (a Technic brick 1x2's middle socket,
    where its long walls hold a stud, on the stud half a stud over: the Gearbox's 32064), its pin
    into a hollow stud's bore (a plate or Technic brick half a stud over, its underside pin in an
    open stud: builders offset parts so), or along the axis of a joint it slides on (an antenna's
    bar lifted up its clip); for a part held by joints on `held_axis`, any joint of that axis (a
    Technic brick with holes half a stud apart, moved onto its next hole). Told by the parts'
    connectors (`stud_pairs`, `unmodelled.joints_between`), not by the checks' verdict."""
    u = np.asarray(move, float) / np.linalg.norm(move)
    if stud_pairs(structure, [Placed(part, 0, moved)]):
        return True  # on studs there: a 1-wide Technic brick's middle socket on a stud half a stud over
    box = world_box(part, moved)
    for q in structure.placed:
        if not boxes_near(box, world_box(q.part, q.pose)):
            continue
        for j in joints_between(part, moved, q.part, q.pose):
            if j.kind == "bar-in-stud":
                return True
            if j.axis is None:
                continue
            along = abs(float(np.asarray(j.axis) @ u)) > 0.98
            if (j.kind in SLIDING_JOINTS and along) or (
                    held_axis is not None and abs(float(np.asarray(j.axis) @ held_axis)) > 0.98):
                return True
    return False


def _add_unit(structure: Structure, unit: list[Placed], inner_links, verdict: Verdict) -> None:
    """Add a finished sub-assembly's parts to its parent, with its own rigid links (renumbered) and,
    if the unit is held by an unmodelled connection, a link from its first part."""
    base = len(structure)
    for k, p in enumerate(unit):
        structure.add(p, verdict.links(base + k, k))
    structure.links.extend(Link(l.a + base, l.b + base, l.point) for l in inner_links)


def _on_table(structure: Structure, unit: list[Placed]) -> bool:
    """A first part, or one laid on the table beside the structure (its bottom within half a plate
    of the structure's lowest point): it needs no connection yet (a base layer is bridged later)."""
    if not len(structure):
        return True
    return Structure(list(unit)).floor_y() >= structure.floor_y() - 4.0


REPLAY_CONFIG = CheckConfig(threaded=True)
"""The checks' thresholds for a replay: the defaults, with parts threaded onto axles
(`CheckConfig.threaded`): people's designs put an axle through beams before the bushes and gears
between them."""

MAX_VERIFY_PARTS = 400
"""Most parts a model may place for `verify_model`, refused up front (counted before its steps are
expanded): each part is checked against all placed before it, so the time grows about as the square
of the parts. Measured here (2 shared cores, stacked 2x4 bricks, no faults): 100 parts 4.3 s, 400
parts 48 s, so 400 ends within a minute (faults take several times that); the largest model of
the real set places 200 (Vintage Car). A 2 KB MPD expanding to 10^5 parts ran 48 s before MuJoCo's
`mj_stackAlloc: out of memory`; the reader's own cap (`MAX_MODEL_PARTS`, 200,000) bounds reading,
not checking."""

FAULTS = ("shift", "lift", "turn")
"""Injected faults: 10 LDU sideways, 8 LDU up (off its studs), a quarter turn about the stud axis
through the part's origin (only where that changes the geometry; a shift or lift only where it
does not land the part on another real connection: `lands_on_a_joint`). Each is checked against the
parts placed before it; the turn also against the finished design (`TURN_FINISHED`). A part held
by joints alone gets the shift only, across its joint's axis (`_faults`)."""
TURN_FINISHED = "turn-in-finished-design"


def stud_pairs(structure: Structure, unit: list[Placed]) -> int:
    """Stud-in-socket pairs between a unit at its pose and the structure, whatever the checks say
    of it: whether the design connects the placement by studs (a tyre on its rim, a part held only
    by a clip, or one laid loose has none)."""
    sp, sa, _ = structure.studs
    kp, ka, _ = structure.sockets
    n = 0
    for q in unit:
        n += len(match(sp, sa, *connectors(q.part, q.pose, "sockets")))
        n += len(match(*connectors(q.part, q.pose, "studs"), kp, ka))
    return n


def _held_by(structure: Structure, later: list[Placed]) -> Structure | None:
    """`structure` with the next step's parts added (None when there are none), as `_joined`."""
    if not later:
        return None
    return _joined(structure, later)


def _held_until(structure: Structure, local: Placed, later: list[Placed]) -> tuple[Structure, int] | None:
    """(`structure` with the `later` parts up to the first that holds `local` by studs or a joint
    added (`_joined`), how many parts that is); None where none of them holds it."""
    alone = Structure([local])
    for n, q in enumerate(later, 1):
        if stud_pairs(alone, [q]) or links_by_joints([local], q):
            return _joined(structure, later[:n]), n
    return None


def _joined(structure: Structure, later: list[Placed]) -> Structure:
    """`structure` with the `later` parts (of the same step, or of the next) added, each linked by
    the joints it makes with the parts before it (`unmodelled.joints_between`; studs join by
    themselves): what holds them when they are judged together (four tyres on their rims)."""
    out = Structure(list(structure.placed))
    out.links.extend(structure.links)
    for q in later:
        out.add(q, links_by_joints(out.placed, q))
    return out


def _in_hand(structure: Structure, unit: list[Placed], v: Verdict, backend, config, standing: bool,
             unit_links=()) -> tuple[Verdict, bool]:
    """(verdict, whether held in hand): a unit that makes the standing model tip on the table (or
    leaves it no equilibrium on its lowest point), not one that swings on its own joints (a swing
    names its joint), judged again as held while built, as a sub-assembly is held (a Technic
    frame before its wheels); `v` itself where that does not accept it either."""
    if v.reason != "unstable" or not standing or v.failing:
        return v, False
    (w,) = check_units(structure, [unit], backend, config, standing=False, unit_links=unit_links)
    return (w, True) if w.ok else (v, False)


NO_WAY_IN = ("blocked", "clamped")
"""Reasons of a part that cannot reach its place along its approach."""


def _in_hand_with(v: Verdict, structure: Structure, local: Placed, later: list[Placed], backend, config,
                  standing: bool) -> Verdict:
    """`v`, the verdict of `local` judged with the `later` parts it hangs from; where it finds no
    way in (`NO_WAY_IN`), the verdict of `local` going in held in hand with those later parts
    pressed onto it by studs, as one unit, if that accepts it."""
    if v.reason not in NO_WAY_IN:
        return v
    alone = Structure([local])
    onto = [q for q in later if stud_pairs(alone, [q])]
    if not onto:
        return v
    unit = [local, *onto]
    (w,) = check_units(structure, [unit], backend, config, require_connection=not _on_table(structure, unit),
                       standing=standing)
    return w if w.ok else v


def _first(structure: Structure, n: int) -> Structure:
    """A new structure of the first `n` parts of `structure`, with the links among them."""
    out = Structure(structure.placed[:n])
    out.links.extend(l for l in structure.links if l.a < n and l.b < n)
    return out


def _going_first(structure: Structure, start: int, local: Placed, backend, config, standing: bool):
    """(verdict, structure judged on) of `local` going in before the parts of its step already
    placed (`structure.placed[start:]`), when it is accepted there and each of those parts is
    still accepted after it, in their order; else None."""
    before = _first(structure, start)
    (w,) = check_units(before, [[local]], backend, config, require_connection=not _on_table(before, [local]),
                       standing=standing)
    if not w.ok:
        return None
    after = _first(structure, start)
    after.add(local, w.links(len(after)))
    for q in structure.placed[start:]:
        (u,) = check_units(after, [[q]], backend, config, require_connection=not _on_table(after, [q]),
                           standing=standing)
        if not u.ok:
            return None
        after.add(q, u.links(len(after)))
    return w, before


def _seated(structure: Structure, unit: list[Placed], v: Verdict, backend, config, standing: bool,
            unit_links=()) -> tuple[Verdict, list[Placed], float | None]:
    """A unit rejected where the design draws it, judged again seated on the connection it was
    drawn beside (`seat.seat_offset`: within `seat.SEAT_LDU`): (verdict, unit, how far it moved),
    the unit as given and None where it is accepted as drawn or nothing seats it."""
    if v.ok:
        return v, unit, None
    move = seat_offset(structure, unit)
    if move is None:
        return v, unit, None
    unit = [Placed(p.part, p.colour, Pose(p.pose.R, p.pose.t + move)) for p in unit]
    (v,) = check_units(structure, [unit], backend, config, require_connection=not _on_table(structure, unit),
                       standing=standing, unit_links=unit_links)
    return v, unit, float(np.linalg.norm(move))


def _seat_record(seated: float | None) -> dict:
    """A record's `seated_ldu`: how far the part was moved onto its connection (none if not)."""
    return {} if seated is None else {"seated_ldu": round(seated, 3)}


def _off_grid_record(structure: Structure, unit: list[Placed], v: Verdict) -> dict:
    """A rejected record's `off_grid_ldu` (`drawn_wrong.off_grid_ldu`): the design draws the part
    that far off the stud grid of the parts it meets, so no real part goes there."""
    if v.ok or v.reason == "unsupported-connection":
        return {}
    off = off_grid_ldu(structure, unit)
    return {} if off is None else {"off_grid_ldu": off}


def verify_model(model_path, ldraw=None, backend: str = "cpu", config: CheckConfig = REPLAY_CONFIG,
                 faults: bool = False):
    """Yield one record per placed part and per sub-assembly attachment, in build order; return
    the finished main model's structure (None where the main model places nothing).

    With `faults`, every accepted stud-connected part is also checked shifted, lifted and turned
    (records with a `"fault"` key), against the same structure.
    """
    reader = get_reader(ldraw)
    frames: dict[str, Pose] = {}
    blocks: dict[str, int] = {}
    flexible: set[str] = set()
    model = reader.open_model(model_path)
    placed = count_parts(reader, model)
    if placed > MAX_VERIFY_PARTS:
        raise LDrawLimitError(f"model places {placed:,} parts; verify checks at most {MAX_VERIFY_PARTS:,} "
                              "(each part is checked against all placed before it)", str(model_path))
    steps = build_steps(reader, model, frames, blocks, flexible)
    if not steps:
        raise LDrawError(NO_PARTS, str(model_path))
    # Every part of each assembly in its own frame, in build order; a finished sub-assembly also
    # belongs to its parents (for the turn fault judged in the finished design).
    locals_of: dict[int, list[Placed]] = {}
    finished: dict[str, list[Placed]] = {}
    for step in steps:
        move = to_local(frames, step.assembly)
        locals_of[id(step)] = [Placed(load_part(reader, p), p.colour, move @ p.pose) for p in step.parts]
        finished.setdefault(step.assembly, []).extend(q for q in locals_of[id(step)] if _solid(q.part))
    for depth in range(max((t.count("/") for t in finished), default=0), 0, -1):
        for tag in [t for t in finished if t.count("/") == depth]:
            parent = parent_of(tag)
            move = relative_frame(frames, parent, tag)
            finished.setdefault(parent, []).extend(Placed(q.part, q.colour, move @ q.pose) for q in finished[tag])

    def in_block(assembly: str, block: int, after: str | None = None) -> list[Placed]:
        """What STEP block `block` of `assembly`'s file places, in its frame: the sub-assemblies it
        references (those after `after`, if given), whole, and its own solid parts."""
        units = [t for t in finished if parent_of(t) == assembly and blocks.get(t) == block]
        out = []
        for t in units[units.index(after) + 1:] if after is not None else units:
            move = relative_frame(frames, assembly, t)
            out += [Placed(q.part, q.colour, move @ q.pose) for q in finished[t]]
        for step in steps:
            if step.assembly == assembly and step.block == block:
                out += [q for q in locals_of[id(step)] if _solid(q.part)]
        return out

    def going_in_with(tag: str) -> list[Placed]:
        """The parts that go in with sub-assembly `tag`, in its parent's frame: the later
        sub-assemblies its parent's file references in the same STEP block, and the parts that
        block places itself (a wagon rests its front on the drawbar built beside it)."""
        return in_block(parent_of(tag), blocks[tag], after=tag)

    next_step: dict[int, list[Placed]] = {}
    """Per step: what the next STEP block of its assembly's file places (`in_block`)."""
    later_blocks: dict[int, list[int]] = {}
    """Per step: the later STEP blocks of its assembly's file, in order (`later_parts`)."""
    for step in steps:
        later = [t.block for t in steps if t.assembly == step.assembly and t.block > step.block]
        later += [b for t, b in blocks.items() if t in finished and parent_of(t) == step.assembly and b > step.block]
        if later:
            next_step[id(step)] = in_block(step.assembly, min(later))
            later_blocks[id(step)] = sorted(set(later))

    def later_parts(step) -> list[Placed]:
        """What every later STEP block of `step`'s assembly places, in order: asked only for a
        part that nothing holds yet (`_held_until`)."""
        return [q for b in later_blocks.get(id(step), []) for q in in_block(step.assembly, b)]

    structures: dict[str, Structure] = {}
    """The parts placed so far in every open assembly, in its own frame, with their rigid links."""
    wrong: dict[str, set[int]] = {}
    """Per open assembly: its parts drawn where they cannot be, and the segments of its flexible
    elements (`drawn_wrong`): later parts are judged past them."""
    for event in walk(steps, frames):
        if isinstance(event, UnitDone):
            done = structures.pop(event.tag)
            parent = structures.setdefault(event.parent, Structure())
            standing = event.parent == "main"
            unit = [Placed(p.part, p.colour, event.to_parent @ p.pose) for p in done.placed]
            if not unit:  # a sub-assembly of parts with no volume only: each was reported
                continue
            (v,) = check_units(parent, [unit], backend, config, require_connection=not _on_table(parent, unit),
                               standing=standing, unit_links=done.links)
            v, unit, seated = _seated(parent, unit, v, backend, config, standing, done.links)
            along = going_in_with(event.tag) if v.reason in WAITS_FOR_LATER else []
            judged_on = parent
            if along:
                # As the parts of one step: it may rest on what goes in with it.
                judged_on = _joined(parent, along)
                (v,) = check_units(judged_on, [unit], backend, config,
                                   require_connection=not _on_table(judged_on, unit), standing=standing,
                                   unit_links=done.links)
            v, held_in_hand = _in_hand(judged_on, unit, v, backend, config, standing, done.links)
            joints = _joint_record(judged_on, unit, v)
            yield _record(v, step=event.last_step, index=0, part=event.tag.rsplit("/", 1)[-1],
                          color=unit[0].colour, unit=True, assembly=event.tag,
                          stud_pairs=stud_pairs(judged_on, unit), **({"held_in_hand": True} if held_in_hand else {}),
                          **_seat_record(seated), **_off_grid_record(judged_on, unit, v), **joints)
            wrong.setdefault(event.parent, set()).update(len(parent) + i for i in wrong.pop(event.tag, ()))
            if event.tag in flexible:
                # A chain's links or a hose's segments bend aside for the parts they hook on or
                # lie over (`drawn_wrong`: judged without them, as parts drawn where none can be).
                wrong[event.parent].update(range(len(parent), len(parent) + len(unit)))
            _add_unit(parent, unit, done.links, v)
            continue
        step = event.step
        structure = structures.setdefault(step.assembly, Structure())
        standing = step.assembly == "main"
        locals_ = locals_of[id(step)]
        step_start = len(structure)
        for index, (placed, local) in enumerate(zip(step.parts, locals_)):
            if not _solid(local.part):
                # A sticker or another part with no volume: nothing to collide, weigh or hold; it is
                # reported and left out of the structure (nothing rests on it).
                yield _flat_record(step=step.index, index=index, part=placed.part, color=placed.colour)
                continue
            twin = duplicate_of(structure, local)
            if twin is not None:
                yield _flat_record(DUPLICATE, step=step.index, index=index, part=placed.part, color=placed.colour,
                                   duplicate_of=twin)
                continue
            judged_on = structure
            (v,) = check_units(judged_on, [[local]], backend, config,
                               require_connection=not _on_table(judged_on, [local]), standing=standing)
            v, (local,), seated = _seated(structure, [local], v, backend, config, standing)
            later = [q for q in locals_[index + 1 :] if _solid(q.part)]
            if v.reason in WAITS_FOR_LATER and later:
                # Parts of one step go in together: a part may hang from one listed after it (a
                # beam on the pins pushed through it next), and the step is judged standing once
                # all its parts are in.
                judged_on = _joined(structure, later)
                (v,) = check_units(judged_on, [[local]], backend, config,
                                   require_connection=not _on_table(judged_on, [local]), standing=standing)
                # Pushed onto the later parts it hangs from, it may not get in; held in hand with
                # them pressed onto it (a plate under a tile that bridges it to the model), it does.
                v = _in_hand_with(v, structure, local, later, backend, config, standing)
            held = _held_by(judged_on, next_step.get(id(step), [])) if v.reason in WAITS_FOR_LATER else None
            if held is not None:
                # Held in hand until the next step of its assembly is on (a plate laid beside the
                # model, then fixed from below; a brick set on a horse that comes next, whole):
                # accepted if that holds it.
                (w,) = check_units(held, [[local]], backend, config, standing=standing)
                w = _in_hand_with(w, judged_on, local, held.placed[len(judged_on):], backend, config, standing)
                if w.ok:
                    v, judged_on = w, held
            v, held_in_hand = _in_hand(judged_on, [local], v, backend, config, standing)
            waited = 0
            if v.reason in WAITS_FOR_LATER:
                # Held in hand until a later step puts on the part that holds it (gears set between
                # beams, then the axle pushed through them), with what comes on before it.
                until = _held_until(judged_on, local, later_parts(step))
                if until is not None:
                    # Its way in is its holder's: the holder, pushed in later, is swept through it.
                    (w,) = check_units(until[0], [[local]], backend, config, standing=standing, sweep=False)
                    if w.ok:
                        v, judged_on, waited = w, until[0], until[1]
            first = None
            if v.reason in NO_WAY_IN and step_start < len(structure):
                # The parts of one step go in in any order: a part that cannot be pressed in under
                # or between parts of its own step listed before it (a brick under the plate that
                # bridges it) is judged going in first, and those parts again after it.
                first = _going_first(structure, step_start, local, backend, config, standing)
                if first is not None:
                    v, judged_on = first
            past = []
            if judged_on is structure:
                # A part drawn where an earlier part drawn wrong is: that error counts once.
                v, past = judged_past(structure, wrong.get(step.assembly, set()), [local], v, backend, config,
                                      not _on_table(structure, [local]), standing)
            joints = _joint_record(judged_on, [local], v)
            yield _record(v, step=step.index, index=index, part=placed.part, color=placed.colour,
                          stud_pairs=stud_pairs(judged_on, [local]), **({"first_in_step": True} if first else {}),
                          **({"held_in_hand": True} if held_in_hand else {}), **_seat_record(seated),
                          **({"judged_without": past} if past else {}),
                          **({"held_for_parts": waited} if waited else {}), **_off_grid_record(judged_on, [local], v),
                          **joints)
            joint_axes = [l.axis for l in v.joints if l.axis is not None]
            if faults and v.ok and (v.connections or joint_axes):
                # Faults move the part off the connections it was accepted on: those of the
                # structure it was judged against (with the later parts of its step, if it hangs).
                yield from _faults(judged_on, local, backend, config, standing, step.index, index,
                                   finished[step.assembly], joint_axes)
            if v.collision and not v.ok:
                # Drawn where it overlaps the parts before it, whatever its verdict names first (a
                # Technic pin pushed 3 LDU too deep into its hole: `unsupported-connection`).
                wrong.setdefault(step.assembly, set()).add(len(structure))
            structure.add(local, v.links(len(structure)))
    return structures.get("main")


WAITS_FOR_LATER = ("no-connection", "unstable", "unsupported-connection")
"""Reasons a part may be judged again with the later parts of its step, then of the next step, in
place: nothing holds it yet, it tips, or it is held by no joint the checker finds yet (a Technic
block whose pins are pushed through it after it)."""

RIGHT_REASONS = {"shift": {"collision", "no-connection"}, "lift": {"no-connection"},
                 "turn": {"collision", "no-connection"}, TURN_FINISHED: {"collision", "no-connection"}}


@dataclass(frozen=True)
class Verification:
    """What `verify` found in one design: a record per placed part, sub-assembly attachment and
    (with faults) injected fault, in build order (`verify_model`'s), and their summary."""

    model: str
    records: tuple[dict, ...]
    finished_stands: bool | None = None
    """Whether the finished main model stands on the table (`stands`): steps accepted held in hand
    while it was built must end in a model that stands. None where it has no parts."""

    @property
    def summary(self) -> dict:
        """`summarize` of the records: acceptance, stud-connected fidelity, faults rejected, and
        whether the finished model stands."""
        return {**summarize(list(self.records)), "finished_stands": self.finished_stands}

    @property
    def placements(self) -> list[dict]:
        """The records of the design's own placements (no injected faults)."""
        return [r for r in self.records if "fault" not in r]

    @property
    def rejected(self) -> list[dict]:
        """The placements the checks reject (a reason other than an unmodelled connection or no volume)."""
        return [r for r in self.placements if r["reason"] not in (None, "unsupported-connection", NO_VOLUME)]

    def to_json(self) -> dict:
        return {"model": self.model, "summary": self.summary, "records": list(self.records)}


def verify(model_path, ldraw=None, backend: str = "cpu", faults: bool = False, config: CheckConfig = REPLAY_CONFIG,
           on_record: Callable[[dict], None] | None = None) -> Verification:
    """Replay a design through the physics checks (`verify_model`): its `Verification`.
    `on_record` sees each record as it is made (a long replay's progress)."""
    records = []
    replay = verify_model(model_path, ldraw, backend, config, faults)
    while True:
        try:
            record = next(replay)
        except StopIteration as end:
            finished = end.value
            break
        records.append(record)
        if on_record is not None:
            on_record(record)
    return Verification(str(model_path), tuple(records), stands(finished, backend, config))


def stands(structure: Structure | None, backend: str = "cpu", config: CheckConfig = REPLAY_CONFIG) -> bool | None:
    """Whether a finished model stands on the table: its last part judged again on the rest, by
    the loads alone (it neither tips nor overloads a connection); None for no parts."""
    if structure is None or not len(structure):
        return None
    last = len(structure) - 1
    (v,) = check_units(_first(structure, last), [[structure.placed[last]]], backend, config,
                       require_connection=False)
    return v.reason not in ("unstable", "overload")


def summarize(records: list[dict]) -> dict:
    """Fidelity (share of stud-connected placements accepted) and fault rejection rates."""
    plain = [r for r in records if "fault" not in r]
    judged = [r for r in plain if r["reason"] not in ("unsupported-connection", NO_VOLUME, DUPLICATE)]
    studded = [r for r in judged if r.get("stud_pairs", 0) > 0]
    out = {
        "placements": len(plain),
        "unsupported_connection": sum(r["reason"] == "unsupported-connection" for r in plain),
        # ... by the most specific kind of joint that may hold each (`held_joints`)
        "unsupported_by_joint": dict(Counter((r.get("joints") or ["?"])[0] for r in plain
                                             if r["reason"] == "unsupported-connection")),
        # Placements held by joints (not only studs), accepted or not, by their most specific kind.
        "by_joint": dict(Counter(r["joints"][0] for r in judged if r.get("joints"))),
        "by_joint_accepted": dict(Counter(r["joints"][0] for r in judged if r.get("joints") and r["reason"] is None)),
        "no_volume": sum(r["reason"] == NO_VOLUME for r in plain),
        "duplicates": sum(r["reason"] == DUPLICATE for r in plain),
        # Accepted held in hand: the model tipped on the table while built (`verify_model`).
        "held_in_hand": sum(bool(r.get("held_in_hand")) for r in plain),
        # Accepted held in hand until a part of a later step held them (`held_for_parts`).
        "held_until_later": sum("held_for_parts" in r for r in plain),
        # Judged seated on the connection they were drawn beside (`seat.SEAT_LDU`), and of those accepted.
        "seated": sum("seated_ldu" in r for r in plain),
        "seated_accepted": sum("seated_ldu" in r and r["reason"] is None for r in plain),
        # Accepted judged without earlier parts drawn where no part can be (`drawn_wrong`).
        "judged_without": sum("judged_without" in r for r in plain),
        "accepted": sum(r["reason"] is None for r in judged),
        "fidelity": (sum(r["reason"] is None for r in judged) / len(judged)) if judged else None,
        # The same over the placements the design connects by studs (`stud_pairs`): a part with
        # none (a tyre on a rim, cloth, a part laid loose) is judged above but not here.
        "stud_connected": len(studded),
        "stud_accepted": sum(r["reason"] is None for r in studded),
        "stud_fidelity": (sum(r["reason"] is None for r in studded) / len(studded)) if studded else None,
        "rejections": dict(Counter(r["reason"] for r in judged if r["reason"])),
        # Of those, the ones the design draws off the stud grid of the parts they meet
        # (`drawn_wrong.off_grid_ldu`): no real part goes where they are drawn.
        "off_grid": sum(r["reason"] is not None and "off_grid_ldu" in r for r in judged),
        # Steps a person built in this order that the sweep finds unbuildable, and those whose
        # approach was not judged (connections on two axes).
        "not_buildable": sum(r.get("buildable") is False for r in judged),
        "approach_not_judged": dict(Counter(r["approach"] for r in judged
                                            if r.get("buildable") is None and r.get("approach"))),
        "faults": {},
    }
    for name in (*FAULTS, TURN_FINISHED):
        rs = [r for r in records if r.get("fault") == name]
        if rs:
            out["faults"][name] = {
                "injected": len(rs),
                "rejected": sum(r["reason"] is not None for r in rs) / len(rs),
                "right_reason": sum(r["reason"] in RIGHT_REASONS[name] for r in rs) / len(rs),
                "reasons": dict(Counter(str(r["reason"]) for r in rs)),
            }
    return out
