"""Seating a design's part on the connection it was drawn beside (`seat_offset`).

Designs are drawn by hand in CAD programs, and some place parts a little off their connections:
`Gearbox.ldr` (drawn in MLCad) sets its axles and gears 2 LDU above the holes of the Technic bricks
they pass through, and some bricks 1 LDU above the studs under them. A real part there sits on the
studs or in the hole. The design replay (`factory.replay`) judges a part rejected where it is drawn
again where its nearest connection seats it, when that connection is within `SEAT_LDU`.

World feedback's snapping (`snap.SnapTargets`) is the same idea for one predicted part and stud
connections alone, with a tolerance for a part dropped from above; a design's parts are seated
here instead because they are also sub-assemblies and parts held by pins and axles.
"""

from __future__ import annotations

import numpy as np

from factory.joints import mates, part_connectors, part_stretches, stretch_overlap
from factory.ldraw.other_connectors import place_connectors
from factory.physics.structure import MATCH_LDU, Placed, Structure, connectors
from factory.physics.unmodelled import boxes_near, world_box

SEAT_LDU = 3.5
"""How far off a connection a design's part may be drawn and still be judged seated on it. It is
below the moves of the replay's faults (lift 8 LDU, shift 10 LDU: `replay._faults`), so a fault is
never seated back, and below a plate's height less its studs (4 LDU), so a part is never seated
onto a layer it was not drawn at. Drawn that near, a stud still reaches into its socket's mouth (a
stud is 4 LDU high and 6 LDU in radius), so a press seats the part: the X-wing Mini's 1x1 plate
drawn 3 LDU off its bracket's side stud."""

PARALLEL_COS = float(np.cos(np.radians(1.0)))
"""Two joint connectors this close to parallel can be seated by a move alone (no turn)."""


def facing(structure: Structure, unit: list[Placed]):
    """For each part of the unit and each way round (its sockets against the structure's studs,
    its studs against the structure's sockets): (which of the unit's, their positions, their axes,
    the structure's positions, axes and k-d tree of the other kind). Nothing for an empty kind."""
    for which, theirs in (("sockets", "studs"), ("studs", "sockets")):
        pos, axis, _ = getattr(structure, theirs)
        if not len(pos):
            continue
        tree = structure.tree(theirs)
        for placed in unit:
            cp, ca = connectors(placed.part, placed.pose, which)
            if len(cp):
                yield which, cp, ca, pos, axis, tree


def _stud_offsets(structure: Structure, unit: list[Placed]) -> list[np.ndarray]:
    """Moves (3,) that would mate a stud or socket of the unit with one of the structure within
    `SEAT_LDU` (including ones already mated: a zero move)."""
    out = []
    for _, cp, ca, pos, axis, tree in facing(structure, unit):
        for i, js in enumerate(tree.query_ball_point(cp, SEAT_LDU)):
            for j in js:
                if ca[i] @ axis[j] > 0.999:
                    out.append(pos[j] - cp[i])
    return out


def _joint_offsets(structure: Structure, unit: list[Placed]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(move across the axis (3,), axis (3,)) that would put a joint connector of the unit on the
    axis of a mating one of the structure (a pin or an axle in its hole, a gear on its axle) within
    `SEAT_LDU`, where the two overlap along it."""
    out = []
    for placed in unit:
        mine = part_connectors(placed.part)
        if not mine:
            continue
        pa = place_connectors(part_stretches(placed.part), placed.pose.R, placed.pose.t)
        box = world_box(placed.part, placed.pose)
        for other in structure.placed:
            theirs = part_connectors(other.part)
            if not theirs or not boxes_near(box, world_box(other.part, other.pose), SEAT_LDU):
                continue
            pb = place_connectors(part_stretches(other.part), other.pose.R, other.pose.t)
            for i, a in enumerate(pa):
                for j, b in enumerate(pb):
                    u = b[2]
                    if abs(float(a[2] @ u)) < PARALLEL_COS or mates(mine[i].kind, theirs[j].kind) is None:
                        continue
                    d = b[0] - a[:2].mean(0)
                    across = d - (d @ u) * u
                    if np.linalg.norm(across) <= SEAT_LDU and stretch_overlap(a, b) > 0:
                        out.append((across, u))
    return out


def seat_offset(structure: Structure, unit: list[Placed]) -> np.ndarray | None:
    """The move (3,) that seats the unit (a part, or a sub-assembly's parts) on the connections it
    was drawn beside, or None where it needs none.

    Every stud or socket of the unit within `SEAT_LDU` of a mating one of the structure, and every
    joint connector within `SEAT_LDU` of a mating one's axis, proposes the move that mates it; the
    move that mates the most (a joint mates wherever it slides along its axis) wins, the shortest
    of those tied. None where that is no move at all (the unit is seated on most of what it meets
    already) or nothing is near."""
    studs = _stud_offsets(structure, unit)
    joints = _joint_offsets(structure, unit)
    if not studs and not joints:
        return None
    proposals = [np.zeros(3)] + studs + [a for a, _ in joints]

    def mated(move: np.ndarray) -> int:
        n = sum(np.linalg.norm(s - move) <= MATCH_LDU for s in studs)
        return n + sum(np.linalg.norm(a - (move - (move @ u) * u)) <= MATCH_LDU for a, u in joints)

    best = max(proposals, key=lambda m: (mated(m), -float(np.linalg.norm(m))))
    return None if np.linalg.norm(best) <= MATCH_LDU else best
