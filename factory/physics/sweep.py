"""Buildability: can a part reach its pose along its connection axis from outside the structure
(or from the side, pressed on along the axis only at the end)?

The collision check judges only the final pose, so it accepts parts in places no hand can reach: a
brick under a roof, a tile slid into a one-plate-high slot under an overhang. A builder presses a
part onto studs along the stud axis, so this module sweeps the unit backwards along that axis, from
clear space to its pose, and asks the collision scene at each step whether it passes.

**Direction** (`approach`). Each stud connection the unit makes fixes the direction it must move in
to seat: against the stud axis a when a structure stud enters one of its sockets (it comes down
onto the stud), along a when one of its studs enters a structure socket (its stud leads). All
directions agree (within 2.6 degrees, as `structure.match`): that is the approach. Two opposite:
the unit sits on studs and under sockets at once, **clamped**, not buildable along any line. Other
disagreements (connections on two axes, e.g. a bracket's side studs and its bottom): `two-axes`,
not judged here.

**Range** (`sweep`). The unit is moved back by s along the direction, s from where its box lies
beyond every structure part's box (clear space) down to the final pose, which is not swept (the
collision check judges it). Contacts are queried only where the unit's box overlaps a structure
part's box deeply enough to matter: a contact's overlap (depth between inset pieces plus both
insets) never exceeds the overlap of the two parts' boxes along any axis, and a piece centre inside
another piece needs the boxes to overlap by both insets, so below `min(tolerance, 2 x INSET_LDU)`
along some axis nothing can exceed the tolerance. Those intervals of s are computed from the boxes;
the rest of the path costs nothing. Parts the unit connects to are left out of the filter (the unit
backs away from them along the axis; a connected part that reaches round over the unit's path, as a
bracket could, is not swept).

**Pressed on last** (`PRESS_LDU`). A hand brings a part near along any line and presses it along
the axis only at the end, with a fingertip behind it. So a unit blocked further out on its axis is
still buildable when the last `PRESS_LDU` of the axis is clear (or, failing that, the last
`PRESS_MIN_LDU`: a fingertip's end in a recess) and, from there (studs out of their sockets:
nothing connected), it reaches clear space along one of four directions square to the axis
(`across`), swept the same way: the LEGO Truck's lights, pressed onto side studs of its front with
the wheel holders 100 LDU further out on their axis. A brick in a gap under a roof, or a tile slid
into a one-plate slot under an overhang, meets the roof within that stretch: blocked.

**Steps** (why a blocker cannot slip between them). Each interval is cut into equal segments of at
most `step_ldu` and the poses between them are queried; the interval's own ends are not (there the
boxes overlap by at most the margin, which bounds the overlap without a query; s = 0 is the final
pose, judged by the collision check). The overlap g(s) is 1-Lipschitz in s (moving the unit by x
changes a penetration depth or a clearance by at most x), so over a segment of length L whose ends
have overlaps at most g1 and g2 it stays below (g1 + g2 + L) / 2. A query with no contact bounds g
by -NEAR_LDU (the scene reports every pair closer than that), one with contacts within tolerance by
its depth (0 when only touching). Where the bound exceeds the tolerance the segment is halved, down
to `MIN_STEP_LDU`. So every overlap deeper than tolerance + MIN_STEP_LDU / 2 on the path is found
(to the accuracy of MuJoCo's depths), however thin the blocker or long the step: an interval
shorter than a step still gets its midpoint, and more where contacts are near. A clear stretch at
2 LDU steps needs no halving ((-1 - 1 + 2) / 2 = 0); the segments at an interval's ends and next to
touching parts do. A pose whose overlap lies between the tolerance and `solid_overlap.REFINE_LDU`
is measured again in the parts themselves, as the collision check does (a piece may reach past a
curved face: `solid_overlap`); that depth, where it clears the pose, is the pose's overlap.

**The ground** is not swept: the question is whether the structure leaves a path, and a builder
lifts a model off the table to press a part on from below (in the sampler, which fixes the ground,
every part hanging under an overhang would otherwise come up through the table). The scene's floor
is switched off for the sweep and restored after.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Sequence

import mujoco
import numpy as np

from factory.parts import Part, box_corners
from factory.physics.collide import NEAR_LDU, CollisionScene
from factory.physics.geometry import INSET_LDU
from factory.physics.solid_overlap import REFINE_LDU, deepest_solid
from factory.physics.structure import Structure, connectors, match
from factory.pose import Pose

SAME_AXIS = 0.999
"""Cosine within which two approach directions agree (2.6 degrees, as `structure.match`)."""

PRESS_LDU = 40.0
"""How far straight back along its approach a unit must be clear: a fingertip's width (16 mm),
the room behind a part that a hand needs to press it on (the part's own path stands for the
finger's). Further out, a hand brings the part in along any line (a light pressed onto a side
stud of a truck's front, whose wheel holders stand 100 LDU further out on its axis); a brick
slid into a gap with a roof 24 LDU above it cannot be pressed down."""

PRESS_MIN_LDU = 24.0
"""Where the fingertip's width is not clear behind a part, the room its end needs to push the part
in (a fingertip's thickness, about 10 mm): the LEGO Truck's round lights sit between its grille
plates and its front, 29 and 39 LDU clear on their axis. A tile in a one-plate slot, a brick in a
gap under a roof, or a round plate 16 LDU from a brick ahead still has no such room."""


MIN_STEP_LDU = 0.25
"""The finest step used next to contacts: overlaps deeper than the tolerance plus half of it are
always found."""


@dataclass(frozen=True)
class Approach:
    """The direction (unit vector, LDraw frame) the unit moves in to seat, or why there is none."""

    direction: np.ndarray | None
    reason: str | None
    """None when there is a direction; else 'clamped', 'two-axes' or 'no-connection'."""


@dataclass(frozen=True)
class SweepResult:
    """Whether the unit reaches its pose along its approach from clear space."""

    buildable: bool | None
    """None where not judged (no stud connection, or connections on two axes)."""
    reason: str | None
    """None when buildable; 'blocked', 'clamped', 'two-axes' or 'no-connection'."""
    blocked_by: tuple[int, ...]
    """Structure parts the unit runs into when blocked: those touching it at the blocking pose
    whose boxes overlap its box beyond the margin (a part merely touching there can be named too:
    the scene does not say which part overlaps)."""
    depth_ldu: float
    """The overlap at the blocking pose; when not blocked, the deepest overlap queried on the path."""
    at_ldu: float
    """How far from the final pose (LDU) that overlap lies; a blocking pose lies within a step of
    where the unit first overlaps the blocker beyond the tolerance, coming from outside."""
    poses_checked: int
    """Contact queries made."""


def seating_directions(structure: Structure, unit: Sequence[tuple[Part, Pose]]) -> np.ndarray:
    """(k, 3): for each stud connection of the unit (world poses) with the structure, the direction
    the unit moves in to seat it. Connections are found as `check_call._unit_connections` finds them."""
    sp, sa, _ = structure.studs
    kp, ka, _ = structure.sockets
    out = []
    for part, pose in unit:
        cp, ca = connectors(part, pose, "sockets")
        out += [-sa[i] for i, _ in match(sp, sa, cp, ca)]  # onto a structure stud: against its axis
        cp, ca = connectors(part, pose, "studs")
        out += [ca[i] for i, _ in match(cp, ca, kp, ka)]  # own stud into a socket: the stud leads
    return np.array(out).reshape(-1, 3)


def seating_from_connections(connections, n_structure: int) -> np.ndarray:
    """(k, 3): `seating_directions` read off the unit's stud connections with the structure, as
    `check_call._unit_connections` gives them (stud part, socket part, stud base, stud axis; parts below
    `n_structure` are the structure's), without matching connectors again."""
    return np.array([-axis if stud < n_structure else axis
                     for stud, _, _, axis in connections]).reshape(-1, 3)


def approach(structure: Structure, unit: Sequence[tuple[Part, Pose]]) -> Approach:
    """The unit's approach direction (module docstring), or 'clamped', 'two-axes', 'no-connection'."""
    return approach_from(seating_directions(structure, unit))


def approach_from(dirs: np.ndarray) -> Approach:
    """`approach` from the seating directions (k, 3) of the unit's stud connections (as
    `seating_directions` gives them, or as read off `check_call._unit_connections`)."""
    return approaches_from([dirs])[0]


def approaches_from(dirs: Sequence[np.ndarray]) -> list[Approach]:
    """The approach of each unit from its seating directions (each (k_i, 3)): 'no-connection'
    without any, 'clamped' where two point opposite ways, 'two-axes' unless all agree within
    `SAME_AXIS`, else their mean direction. The pairwise cosines of all units in one padded array."""
    counts = np.array([len(d) for d in dirs], np.int64)
    out: list[Approach] = [Approach(None, "no-connection")] * len(dirs)
    if not counts.any():
        return out
    k = int(counts.max())
    pad = np.zeros((len(dirs), k, 3))
    valid = np.arange(k)[None, :] < counts[:, None]
    pad[valid] = np.concatenate([np.asarray(d, float).reshape(-1, 3) for d in dirs])
    cos = np.einsum("uai,ubi->uab", pad, pad)
    both = valid[:, :, None] & valid[:, None, :]
    clamped = (both & (cos < -SAME_AXIS)).any(axis=(1, 2))
    one_axis = (~both | (cos > SAME_AXIS)).all(axis=(1, 2))
    mean = pad.sum(axis=1) / np.maximum(counts, 1)[:, None]
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    for i in np.flatnonzero(counts):
        out[i] = (Approach(None, "clamped") if clamped[i] else
                  Approach(None, "two-axes") if not one_axis[i] else Approach(mean[i].copy(), None))
    return out


def _boxes(items: Sequence[tuple[Part, Pose]]) -> np.ndarray:
    """(n, 2, 3) world axis-aligned boxes of placed parts (each part's box turned and re-boxed)."""
    if not items:
        return np.zeros((0, 2, 3))
    r = np.stack([pose.R for _, pose in items])
    t = np.stack([pose.t for _, pose in items])
    b = np.stack([part.bbox for part, _ in items])
    centre = np.einsum("nij,nj->ni", r, b.mean(axis=1)) + t
    half = np.einsum("nij,nj->ni", np.abs(r), (b[:, 1] - b[:, 0]) / 2)
    return np.stack([centre - half, centre + half], axis=1)


def box_interval(lo: np.ndarray, hi: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(start, end): the interval of s >= 0 with s d in (lo, hi) along every axis (the last
    dimension; broadcast), empty where start >= end. How far back along d two boxes overlap."""
    moving = np.abs(d) > 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        a, c = lo / d, hi / d
    still = (lo < 0) & (hi > 0)
    start = np.where(moving, np.minimum(a, c), np.where(still, -np.inf, np.inf)).max(axis=-1)
    end = np.where(moving, np.maximum(a, c), np.where(still, np.inf, -np.inf)).min(axis=-1)
    return np.maximum(start, 0.0), end


def _overlap_intervals(unit_boxes: np.ndarray, boxes: np.ndarray, d: np.ndarray, margin: float) -> np.ndarray:
    """(k, 2) disjoint, sorted open intervals of s > 0 where some unit box moved by -s d overlaps
    some of `boxes` by more than `margin` along every axis.

    Conservative: a box thinner than the margin is not dropped, so an interval may be wider than
    strictly needed, never narrower.
    """
    u = unit_boxes[:, None]  # (m, 1, 2, 3) against (1, n, 2, 3)
    b = boxes[None]
    # Overlap along axis k > margin  <=>  s d_k in (lo, hi) below.
    start, end = box_interval(u[..., 0, :] - b[..., 1, :] + margin, u[..., 1, :] - b[..., 0, :] - margin, d)
    start, end = start.ravel(), end.ravel()
    keep = start < end
    merged: list[list[float]] = []
    for s0, s1 in sorted(zip(start[keep], end[keep])):
        if merged and s0 <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], s1)
        else:
            merged.append([s0, s1])
    return np.array(merged).reshape(-1, 2)


@contextmanager
def _without_floor(scene: CollisionScene):
    """The scene with its ground plane out of collision (the ground is not swept: module docstring)."""
    g = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    saved = int(scene.model.geom_contype[g]), int(scene.model.geom_conaffinity[g])
    scene.model.geom_contype[g] = scene.model.geom_conaffinity[g] = 0
    try:
        yield
    finally:
        scene.model.geom_contype[g], scene.model.geom_conaffinity[g] = saved


def sweep(
    scene: CollisionScene,
    structure: Structure,
    unit: Sequence[tuple[Part, Pose]],
    connected: set[int],
    max_penetration_ldu: float = 0.5,
    step_ldu: float = 2.0,
    directions: np.ndarray | None = None,
    press_ldu: float | None = PRESS_LDU,
) -> SweepResult:
    """Sweep the unit (parts in world poses) along its approach from clear space to its pose, or,
    blocked further out than `press_ldu`, from the side to there (`_pressed_last`; None: along
    the approach all the way).

    `scene` is the unit's collision scene as `check.check_units` builds it (the unit's parts
    relative to its first part) and `connected` the structure parts the unit connects to, as the
    collision check passes them: studs entering those parts are ignored on the way in. The first
    pose from outside that overlaps beyond the tolerance blocks the unit (module docstring for the
    range, the steps and why the ground is left out). `directions`: the unit's seating directions
    where already known (`seating_from_connections`), else found here.
    """
    found = approach(structure, unit) if directions is None else approach_from(directions)
    if found.direction is None:
        return SweepResult(False if found.reason == "clamped" else None, found.reason, (), 0.0, 0.0, 0)
    d = found.direction
    straight = _along(scene, structure, unit, connected, d, max_penetration_ldu, step_ldu)
    if straight.buildable or press_ldu is None or straight.at_ldu <= min(press_ldu, PRESS_MIN_LDU):
        return straight
    return _pressed_last(scene, structure, unit, connected, d, max_penetration_ldu, step_ldu, straight, press_ldu)


def across(d: np.ndarray) -> np.ndarray:
    """(4, 3): the directions a unit may come in from before it is pressed on along `d`: both
    ways along two axes square to `d` (the principal axes, where `d` is one)."""
    k = int(np.argmax(np.abs(d)))
    u = np.cross(d, np.eye(3)[(k + 1) % 3])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    return np.array([u, -u, v, -v])


def _pressed_last(scene, structure, unit, connected, d, tol, step_ldu, straight: SweepResult,
                  press: float) -> SweepResult:
    """The unit blocked on its axis further out than `press` LDU: buildable if the last `press`
    LDU along the axis are clear and, from there (studs out of their sockets, so nothing
    is connected), it reaches clear space along one of the directions `across` the axis; else the
    straight sweep's verdict stands."""
    queries = straight.poses_checked
    for reach in (press, PRESS_MIN_LDU) if press > PRESS_MIN_LDU else (press,):
        found, queries = _from_the_side(scene, structure, unit, connected, d, tol, step_ldu, reach, queries)
        if found is not None:
            return found
    return replace(straight, poses_checked=queries)


def _from_the_side(scene, structure, unit, connected, d, tol, step_ldu, press, queries):
    """(the buildable verdict or None, queries so far): the last `press` LDU along the axis clear,
    and from there a way out `across` it."""
    near = _along(scene, structure, unit, connected, d, tol, step_ldu, reach=press)
    queries += near.poses_checked
    if not near.buildable:
        return None, queries
    anchor = unit[0][1]
    with _without_floor(scene):
        depth, _ = scene.penetration(Pose(anchor.R, anchor.t - press * d), set())
    queries += 1
    if depth <= tol:
        backed = [(part, Pose(pose.R, pose.t - press * d)) for part, pose in unit]
        for side in across(d):
            way = _along(scene, structure, backed, set(), side, tol, step_ldu)
            queries += way.poses_checked
            if way.buildable:
                return SweepResult(True, None, (), max(near.depth_ldu, way.depth_ldu), press, queries), queries
    return None, queries


JOINT_LINE_LDU = 1000.0
"""How far each way a joint's zone is drawn out along its axis for `sweep_joint`: the part slides
along the joint's axis all the way from clear space, and its overlap with the holder round that
axis is the joint's wherever it is."""


def sweep_joint(scene: CollisionScene, structure: Structure, unit: Sequence[tuple[Part, Pose]],
                joints: dict, max_penetration_ldu: float = 0.5, step_ldu: float = 2.0) -> SweepResult:
    """Buildability of a unit held by joints alone: it reaches its pose along the joints' shared
    axis, from either end (a pin goes into its hole, a wheel onto its axle, from the side that is
    open), from where it is off the joint's stretch that way and `PRESS_MIN_LDU` past it
    (`_off_the_joint`), its overlap with each holder round the joint's axis left out
    (`joints`: holder -> (stretches (k, 3, 3), radii), as `CollisionScene.penetration` takes them;
    None: all its overlap left out, a gear it meshes with, whose teeth it slides along).
    Not judged (None, 'two-axes') where the joints' axes are not parallel: a part on two joints
    at an angle cannot slide onto both."""
    held = {h: z for h, z in joints.items() if z is not None}
    axes = np.concatenate([z[:, 2] for z, _ in held.values()]) if held else np.zeros((0, 3))
    if not len(axes) or (np.abs(axes @ axes[0]) < SAME_AXIS).any():
        return SweepResult(None, "two-axes", (), 0.0, 0.0, 0)
    lines = {h: None for h, z in joints.items() if z is None}
    for holder, (zones, radii) in held.items():
        u = zones[:, 2]
        length = ((zones[:, 1] - zones[:, 0]) * u).sum(axis=1)[:, None]
        lo, hi = np.minimum(length, 0.0) - JOINT_LINE_LDU, np.maximum(length, 0.0) + JOINT_LINE_LDU
        lines[holder] = (np.stack([zones[:, 0] + lo * u, zones[:, 0] + hi * u, u], axis=1), radii)
    found = []
    for d in (axes[0], -axes[0]):
        reach = _off_the_joint(unit, held, d)
        way = _along(scene, structure, unit, set(), d, max_penetration_ldu, step_ldu, reach=reach, joints=lines)
        if way.buildable:
            return way
        found.append(way)
    # Blocked both ways: the nearer blocking, with what blocks each way (`check_call._Call._threaded`
    # asks whether an axle goes through all of them).
    near = min(found, key=lambda w: w.at_ldu)
    return replace(near, blocked_by=tuple(sorted({b for w in found for b in w.blocked_by})))


def held_in_place(scene: CollisionScene, structure: Structure, unit: Sequence[tuple[Part, Pose]],
                  through: set[int], axis, max_penetration_ldu: float = 0.5, step_ldu: float = 2.0) -> bool:
    """Whether the unit reaches its place from clear space along one of the directions `across`
    `axis`, with the structure parts `through` (the pins or axles that go through its holes)
    left out: a builder holds it there and pushes them through it after (a replay's rule,
    `CheckConfig.threaded`)."""
    lines = {h: None for h in through}
    for side in across(np.asarray(axis, float)):
        if _along(scene, structure, unit, set(), side, max_penetration_ldu, step_ldu, joints=lines).buildable:
            return True
    return False


def _off_the_joint(unit: Sequence[tuple[Part, Pose]], held: dict, d: np.ndarray) -> float:
    """How far the unit backs out against `d` until it is off every joint's stretch (the part's
    and its holder's connectors together), and `PRESS_MIN_LDU` more: only that much is swept.
    Off the axle's end a hand brings the part in along any line (as `PRESS_MIN_LDU` for studs): a
    bush at the middle of a long axle slides off the nearer end, past nothing beyond it. The
    unit's extent along the axis is its boxes' (an upper bound of its connectors')."""
    back = -np.asarray(d, float)
    trailing = min(float((pose.apply(box_corners(part.bbox)) @ back).min()) for part, pose in unit)
    far = max(float((z[:, :2] @ back).max()) for z, _ in held.values())
    return max(far - trailing, 0.0) + PRESS_MIN_LDU


def _along(scene, structure, unit, connected, d, tol, step_ldu, reach: float | None = None,
           joints: dict | None = None) -> SweepResult:
    """The sweep of the unit along `d` from clear space to its pose (module docstring), or only
    over the last `reach` LDU of it (the pose at `reach` queried too); `joints` as
    `CollisionScene.penetration` takes them."""
    margin = min(tol, 2 * INSET_LDU)
    unit_boxes = _boxes(unit)
    boxes = _boxes([(p.part, p.pose) for p in structure.placed])
    others = [i for i in range(len(structure)) if i not in connected]
    intervals = _overlap_intervals(unit_boxes, boxes[others], d, margin)
    anchor = unit[0][1]
    queries = 0
    deepest, deepest_at = 0.0, 0.0

    def probe(s: float) -> tuple[float, tuple[int, ...] | None]:
        """An upper bound of the overlap at s (module docstring), and the blockers when beyond
        the tolerance."""
        nonlocal queries, deepest, deepest_at
        queries += 1
        at = Pose(anchor.R, anchor.t - s * d)
        depth, near = scene.penetration(at, connected, joints)
        if depth > deepest:
            deepest, deepest_at = depth, s
        if tol < depth <= REFINE_LDU and near:
            # Shallow: the parts themselves decide, as for the collision check (`check_call`). The
            # overlap round every joint stays left out (parts whose overlap is all a joint's are
            # not `near`).
            parts = sorted(near)
            depths = scene.depths_alone(at, connected, parts, joints)
            solid = deepest_solid([(part, Pose(pose.R, pose.t - s * d)) for part, pose in unit],
                                  [(structure.placed[i].part, structure.placed[i].pose) for i in parts], depths, tol)
            if solid is not None and solid <= tol:
                depth = solid
        if depth > tol:
            # `penetration` names the parts touching the unit, not the one overlapping it: keep
            # those whose boxes overlap the unit's beyond the margin, as an overlapping part's must.
            moved = unit_boxes - s * d
            return depth, tuple(sorted(i for i in near if _boxes_overlap(moved, boxes[i], margin)))
        return (depth if depth > 0 else 0.0 if near else -NEAR_LDU), None

    def first_block(hi: float, g_hi: float, lo: float, g_lo: float) -> tuple | None:
        """(s, depth, blockers) of a blocked pose strictly between hi and lo, the outer half searched
        first, halving while the segment's bound leaves room for an overlap beyond the tolerance."""
        if (g_hi + g_lo + hi - lo) / 2 <= tol or hi - lo <= MIN_STEP_LDU:
            return None
        mid = (hi + lo) / 2
        g, blockers = probe(mid)
        if blockers is not None:
            return mid, g, blockers
        return first_block(hi, g_hi, mid, g) or first_block(mid, g, lo, g_lo)

    with _without_floor(scene):
        # Outermost interval first, outside in: the blocker reported is the one the unit meets on
        # its way. A blocked grid pose is reported without searching the segment before it: that
        # would only say more precisely where, at 3-4 more queries.
        for lo, hi in intervals[::-1]:
            if reach is not None and lo >= reach:
                continue
            # At the interval's ends the box bound holds (the margin); at s = 0, the final pose,
            # the collision check has judged it within tolerance. An interval cut at `reach` has
            # its end there queried.
            g_prev = margin
            if reach is not None and hi > reach:
                hi = reach
                g_prev, blockers = probe(hi)
                if blockers is not None:
                    return SweepResult(False, "blocked", blockers, round(float(g_prev), 4), round(float(hi), 4), queries)
            n = max(1, math.ceil((hi - lo) / step_ldu - 1e-9))
            grid = hi - (hi - lo) * np.arange(n + 1) / n
            for k in range(1, n + 1):
                g, blockers = probe(grid[k]) if k < n else ((tol if lo == 0.0 else margin), None)
                hit = (grid[k], g, blockers) if blockers is not None else first_block(grid[k - 1], g_prev, grid[k], g)
                if hit is not None:
                    s, depth, by = hit
                    return SweepResult(False, "blocked", by, round(float(depth), 4), round(float(s), 4), queries)
                g_prev = g
    return SweepResult(True, None, (), round(deepest, 4), round(deepest_at, 4), queries)


def _boxes_overlap(unit_boxes: np.ndarray, box: np.ndarray, margin: float) -> bool:
    """Whether some unit box overlaps `box` by more than `margin` along every axis."""
    over = np.minimum(unit_boxes[:, 1], box[1]) - np.maximum(unit_boxes[:, 0], box[0])
    return bool((over > margin).all(axis=1).any())
