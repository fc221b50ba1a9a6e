"""A structure rebuilt from placed parts alone (a dataset's rows, a file) with the joints its parts
make kept as links, as the sampler and a replay keep them when they place each part.

A `Structure` finds its stud connections from the parts themselves; joints (a pin in a hole, hips
on a leg) are what the checker found when a part was placed (`Verdict.links`), and a structure
built from parts alone has none: a part held only by a pin is then a body with no way to the
ground, and every later part that hangs on it is judged `unstable`. `linked` finds them again: a
part with no stud connection to the parts before it is linked to each of them that holds it by a
joint as it stands (`unmodelled.joints_between`). A part held by studs is not asked (the checker
asks joints of a candidate only where it has no stud connection or overlaps: a part pinned and
on studs at once carries its loads through its studs here). `links_by_joints` is the one
test of a part against those before it, also used where a replay judges parts together
(`replay._joined`).
"""

from __future__ import annotations

from typing import Iterable

from factory.physics.load_model import Link
from factory.physics.structure import Placed, Structure
from factory.physics.unmodelled import boxes_near, joints_between, world_box


def links_by_joints(before: list[Placed], part: Placed) -> list[Link]:
    """The links of `part`, placed after `before` (as part `len(before)`), to each of them that
    holds it by a joint as it stands (`unmodelled.joints_between`; parts whose boxes are not near
    are not asked)."""
    n, box = len(before), world_box(part.part, part.pose)
    return [Link(n, i, j.point, j.kind, j.axis) for i, p in enumerate(before)
            if boxes_near(box, world_box(p.part, p.pose))
            for j in joints_between(part.part, part.pose, p.part, p.pose)]


def linked(placed: Iterable[Placed]) -> Structure:
    """The structure of `placed` (in order), each part with no stud connection to the parts before
    it linked to those that hold it by a joint (module docstring)."""
    out = Structure()
    for p in placed:
        idx, before = len(out), len(out.connections)
        out.add(p)
        if idx and len(out.connections) == before:  # a part's new connections are all its own
            out.links.extend(links_by_joints(out.placed[:idx], p))
    return out
