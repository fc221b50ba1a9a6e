"""Parts a design draws where no part can be, counted once (`judged_past`).

A design's part rejected while it overlaps the parts before it, even seated (`physics.seat`), is
drawn where nothing could put it: a hand-drawn CAD file sets a Technic brick 3 LDU into the plates
under it, say. That holds whatever reason its verdict names first: a Technic pin pushed 3 LDU too
deep into its hole, or a gear drawn 2 LDU into the brick beside its axle, is
`unsupported-connection` (on a connector's axis, with no joint there the checker can judge) while
it overlaps, and as misplaced. The replay keeps it where drawn, since later parts may rest on it.
But the parts drawn beside it afterwards, in their right places, then overlap it too, and each
would be rejected for the one drawing error. So a part rejected only for meeting such parts
(overlapping them, or blocked by them on its way in) is judged again without them; accepted so,
its record names them (`judged_without`). Nothing else is given up: it must still be held, stand and get in past every
other part, and its faults are judged against all the parts, drawn wrong or not.

A flexible element's segments count the same way (`LDrawFile.flexible`: a sub-model LDCad
generated from a path or a spring, or keyworded `flexible`): a chain, a hose or a string is drawn
as rigid links or segments along a curve, and bends aside for the parts it hooks onto or lies over
(Showdown Canyon's chain ends, pressed onto their studs through the chain's first links).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from factory.physics.check import Verdict, check_units
from factory.physics.seat import SEAT_LDU, facing
from factory.physics.structure import Placed, Structure
from factory.physics.unmodelled import boxes_near, world_box

WRONG = "collision"
"""The reason of a part rejected for an overlap alone."""

PAST = ("collision", "blocked", "clamped")
"""Reasons judged again without the parts drawn wrong: an overlap, or no way in."""


def without(structure: Structure, drop: set[int]) -> tuple[Structure, list[int]]:
    """(`structure` less the parts `drop`, with the links among the rest; the index in
    `structure` of each of its parts)."""
    keep = [i for i in range(len(structure)) if i not in drop]
    new_of = {old: new for new, old in enumerate(keep)}
    out = Structure([structure.placed[i] for i in keep])
    out.links.extend(replace(l, a=new_of[l.a], b=new_of[l.b]) for l in structure.links
                     if l.a in new_of and l.b in new_of)
    return out, keep


def _renumbered(v: Verdict, keep: list[int]) -> Verdict:
    """`v`, judged on a structure of the parts `keep`, with its part numbers those of the whole."""
    return replace(v, held_by=tuple(keep[j] for j in v.held_by), blocked_by=tuple(keep[j] for j in v.blocked_by),
                   joints=tuple(replace(l, b=keep[l.b]) for l in v.joints))


def judged_past(structure: Structure, wrong: set[int], unit: list[Placed], v: Verdict, backend, config,
                require_connection: bool, standing: bool) -> tuple[Verdict, list[int]]:
    """(verdict, the parts drawn wrong it was judged without): `v` and [] unless `v` rejects the
    unit for an overlap or no way in and, judged without the parts of `structure` drawn wrong
    (`wrong`), it is accepted; then that verdict, numbered as `structure`."""
    if v.reason not in PAST or not wrong:
        return v, []
    drop = set(v.blocked_by) & wrong
    if v.reason == WRONG:  # the parts drawn wrong whose boxes its own touch
        boxes = [world_box(p.part, p.pose) for p in unit]
        drop |= {i for i in wrong if any(boxes_near(b, world_box(structure.placed[i].part, structure.placed[i].pose),
                                                    0.0) for b in boxes)}
    if not drop:
        return v, []
    rest, keep = without(structure, drop)
    (w,) = check_units(rest, [unit], backend, config, require_connection=require_connection, standing=standing)
    if not w.ok:
        return v, []
    return _renumbered(w, keep), sorted(drop)


OFF_GRID_ACROSS_LDU = (1.0, 10.5)
"""Offsets across a stud's axis (LDU) `off_grid_ldu` counts: more than a fit's play, and up to
half a stud pitch (a stud that far from every socket stands under the part's walls or tubes)."""

OFF_GRID_ALONG_LDU = SEAT_LDU
"""How far along its axis a stud may be from a socket's plane and still be pushed into the part
(`seat.SEAT_LDU`: a stud is 4 LDU high)."""


def off_grid_ldu(structure: Structure, unit: list[Placed]) -> float | None:
    """How far off the stud grid a design draws a unit: of the studs of `structure` that reach
    into a socket plane of the unit (and of the unit's studs into the structure's), the largest
    distance across the axis to the nearest socket of that plane, where it lies between a fit's
    play and half a stud pitch (`OFF_GRID_ACROSS_LDU`); None where no stud is so placed. A wedge
    plate drawn 5 LDU along from the studs under it, or a plate half a stud across from a Technic
    brick's studs, is a drawing no real part can take: a diagnosis for a rejected part, not a
    verdict (`replay` records it as `off_grid_ldu`)."""
    lo, hi = OFF_GRID_ACROSS_LDU
    worst = None
    for which, cp, ca, pos, axis, tree in facing(structure, unit):
        near = sorted({j for js in tree.query_ball_point(cp, hi + OFF_GRID_ALONG_LDU) for j in js})
        if which == "sockets":  # the structure's studs against the unit's sockets
            studs_p, studs_a, socks_p, socks_a = pos[near], axis[near], cp, ca
        else:  # the unit's studs against the structure's sockets
            studs_p, studs_a, socks_p, socks_a = cp, ca, pos[near], axis[near]
        for p, a in zip(studs_p, studs_a):
            same = socks_a @ a > 0.999
            if not same.any():
                continue
            d = p - socks_p[same]
            along = d @ a
            across = np.linalg.norm(d - along[:, None] * a, axis=1)
            plane = np.abs(along) <= OFF_GRID_ALONG_LDU
            if not plane.any():
                continue
            nearest = float(across[plane].min())
            if lo < nearest <= hi and (worst is None or nearest > worst):
                worst = nearest
    return None if worst is None else round(worst, 3)
