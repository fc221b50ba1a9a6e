"""Whether a part may be held by a connection the checker does not model (Technic pins and axles,
clips, click hinges, wheel pins, tyres on rims), so that its placement is not judged on studs.

Two sides can say so. A part's connector primitives, where it has them, say where such a
connection can be: it holds only if a connector of the new part lies on the axis of a connector of
the part it touches (a pin in a hole, a hinge finger between the other half's fingers). A part
drawn without such primitives can only be judged by its shape: a new part with no sockets cannot
sit on studs (a hinge top, a tyre, a rim), a placed part without studs or sockets offers something
else (a hinge base, a rim); there is no position to compare then, so touching is enough.
Minifigure pieces hold one another by joints of their own (`is_minifig`).
"""

from __future__ import annotations

import numpy as np

from factory.ldraw.other_connectors import place_connectors
from factory.parts import Part
from factory.pose import Pose

NEAR_LDU = 2.0
"""How far apart two connector axes may run, and how far apart along them the two stretches may
end, for the connectors to be one connection. Measured on the two real models (car.ldr, 4915): the
mated hinges are within 0.53 LDU of each other's axis (model files round rotated sub-assemblies)
and their stretches overlap; the faults the old count-based rule excused are 31 LDU or more off
any axis, and a fault moves a part 8-10 LDU. A move along the shared axis (a pin slid in its hole)
keeps the connectors on one line: only sliding past the end is caught."""
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


def may_hold(new: Part, new_pose: Pose, placed: Part, placed_pose: Pose) -> bool:
    """Whether `placed` (touched by `new`) may hold `new` by a connection not modelled. When both
    have connectors with a position, their positions decide; otherwise the shapes (see the
    module). A hollow stud's bore counts as a position on either side, but not towards the new
    part's shape: a round brick off its studs is not held by its own bore."""
    if is_minifig(new) and is_minifig(placed):
        # Minifigure pieces join by their own joints (neck, shoulders, wrists, hips, headgear on
        # the head's stud, which sits inside it), none of them a stud connection: the LDraw
        # files place a head and a helmet, or a neck and a head, overlapping by design.
        return True
    a, b = _connectors(new), _connectors(placed)
    if len(a) and len(b):
        return connectors_meet(place_connectors(a, new_pose.R, new_pose.t),
                               place_connectors(b, placed_pose.R, placed_pose.t))
    return held_otherwise(new) and offers_other(placed)


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


def connectors_meet(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether any connector of `a` (j, 3, 3) lies on the axis of one of `b` (k, 3, 3), both in
    one frame, within the tolerances above."""
    for s in a:
        for t in b:
            angle, radial, gap = separation(s, t)
            if angle <= PARALLEL_DEG and radial <= NEAR_LDU and gap <= NEAR_LDU:
                return True
    return False
