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

from factory.physics.check import Verdict, check_units
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
