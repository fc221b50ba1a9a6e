"""A structure rebuilt from placed parts alone (a dataset's rows, a file) with the joints its parts
make kept as links, as the sampler and a replay keep them when they place each part.

A `Structure` finds its stud connections from the parts themselves; joints (a pin in a hole, hips
on a leg) are what the checker found when a part was placed (`Verdict.links`), and a structure
built from parts alone has none: a part held only by a pin is then a body with no way to the
ground, and every later part that hangs on it is judged `unstable`. `linked` finds them again: a
part with no stud connection to the parts before it is linked to each of them that holds it by a
joint as it stands (`unmodelled.joints_between`). A part held by studs is not asked (the checker
asks joints of a candidate only where it has no stud connection or overlaps: a part pinned and
on studs at once carries its loads through its studs here).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from factory.physics.load_model import Link
from factory.physics.structure import Placed, Structure
from factory.physics.unmodelled import joints_between, world_box

NEAR_LDU = 2.0
"""How far apart two parts' boxes may be for a joint between them to be looked for (a joint's parts
touch; the checker's own touching distance)."""


def linked(placed: Iterable[Placed]) -> Structure:
    """The structure of `placed` (in order), each part with no stud connection to the parts before
    it linked to those that hold it by a joint (module docstring)."""
    out = Structure()
    boxes: list[np.ndarray] = []
    for p in placed:
        idx = len(out)
        before = len(out.connections)
        out.add(p)
        box = world_box(p.part, p.pose)
        if idx and not any(a == idx or b == idx for a, b, *_ in out.connections[before:]):
            links = []
            for j, other in enumerate(boxes):
                if np.all(box[0] <= other[1] + NEAR_LDU) and np.all(other[0] <= box[1] + NEAR_LDU):
                    q = out.placed[j]
                    links += [Link(idx, j, jt.point, jt.kind, jt.axis)
                              for jt in joints_between(p.part, p.pose, q.part, q.pose)]
            out.links.extend(links)
        boxes.append(box)
    return out
