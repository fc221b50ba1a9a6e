"""Minifigure pieces and where they join: each piece's role (told by its LDraw title), where a
piece of one role sits on a piece of another (`SLOTS`: the neck, the shoulders, the wrists, the
hips, headgear on the head), and the holes under the feet that stand on studs (`FEET`).

Minifigure joints are not drawn with connector primitives, and most of their pieces have no
studs or sockets, so their places are given here as dimensions, in the parent piece's LDraw
frame (LDU, -Y up): every minifigure drawn in LDraw's library shares them (a torso's origin is at
its neck; hips sit 32 LDU below it, legs 12 below the hips, the head 24 above; an arm hangs
15.6 LDU to the side, 9 down, turned 10 degrees out, and swings about its own X axis; a hand sits
in its arm turned 45 degrees and turns about its own Z axis). The figures of three designs in
`../shared/designs` (6861, 889, 10156) sit so to 1.5 LDU and 3 degrees about each slot's axis
(`tests/test_minifig.py`); a head is placed 3 LDU higher as often. A piece with no
role here (a tool, a weapon, a plume, a visor: where a hand or a helmet holds it differs per
piece) is not attached by the sampler.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from factory.symmetry import rotation_about

_TITLES = (
    ("torso", r"Torso\b"),
    ("hips-legs", r"Hips and Legs\b"),
    ("hips", r"Hips\b"),
    ("leg-left", r"Legs? Left\b"),
    ("leg-right", r"Legs? Right\b"),
    ("arm-left", r"Arm Left\b"),
    ("arm-right", r"Arm Right\b"),
    ("hand", r"Hand\b"),
    ("head", r"Head\b"),
)
"""Roles told by the title's first words (after "Minifig ")."""
_WORN = (
    ("headgear", r"\b(Hat|Cap|Helmet|Hair|Hood|Headdress|Headgear|Crown|Beanie|Turban|Tiara|Cowl)\b"),
    ("neckwear", r"\b(Airtanks|Quiver|Armour|Armor|Cape|Epaulette|Neck Bracket|Life Jacket|Scarf|Backpack)\b"),
)
"""Roles told by a word of the title's name (before " with "): "Forestman Cap", "Arrow Quiver". A
visor or a plume goes on a helmet, not a head, and a bandana on a head or at the neck (6716): no
role."""


@lru_cache(maxsize=None)
def role(description: str) -> str | None:
    """The role of a piece (torso, hips, hips-legs, leg-left, leg-right, arm-left, arm-right,
    hand, head, headgear, neckwear; kept per title: the checker asks it of every pair of touching
    pieces) by its LDraw title ("Minifig Torso ...", "~Minifig Leg Left
    (Obsolete)", "Minifig Helmet Classic with ... Visor Dimples"); None for anything else,
    minifigure accessories held in a hand included."""
    title = description.lstrip("~_=| ")
    if not title.startswith("Minifig "):
        return None
    rest = title[len("Minifig "):]
    for name, pattern in _TITLES:
        if re.match(pattern, rest):
            return name
    name_part = rest.split(" with ")[0]
    if re.search(r"\b(Visor|Plume)\b", name_part):
        return None
    for name, pattern in _WORN:
        if re.search(pattern, name_part):
            return name
    return None


def _turn(axis: int, degrees: float) -> np.ndarray:
    """The rotation by `degrees` about the X (0), Y (1) or Z (2) axis."""
    return rotation_about(np.eye(3)[axis], degrees)


@dataclass(frozen=True)
class Slot:
    """Where a `child` piece sits on a `parent` piece: at `offset` in the parent's frame, turned
    by `base` and then by one of `angles` (degrees) about its own `axis` (0 X, 1 Y, 2 Z; None for a
    piece that does not turn there)."""

    parent: str
    child: str
    offset: tuple[float, float, float]
    base: np.ndarray
    axis: int | None
    angles: tuple[float, ...]
    """The turns the sampler tries (a joint that turns is held at any angle: these are a few)."""

    def rotations(self) -> list[np.ndarray]:
        """The child's rotations in the parent's frame, one per angle."""
        if self.axis is None:
            return [self.base]
        return [self.base @ _turn(self.axis, a) for a in self.angles]


_SHOULDER_OUT_DEG = 10.0
SLOTS = (
    Slot("torso", "hips", (0.0, 32.0, 0.0), np.eye(3), None, (0.0,)),
    Slot("torso", "hips-legs", (0.0, 32.0, 0.0), np.eye(3), None, (0.0,)),
    Slot("hips", "leg-left", (0.0, 12.0, 0.0), np.eye(3), 0, (0.0,)),
    Slot("hips", "leg-right", (0.0, 12.0, 0.0), np.eye(3), 0, (0.0,)),
    Slot("torso", "arm-left", (15.6, 9.0, 0.0), _turn(2, -_SHOULDER_OUT_DEG), 0, (0.0, -45.0, -90.0)),
    Slot("torso", "arm-right", (-15.6, 9.0, 0.0), _turn(2, _SHOULDER_OUT_DEG), 0, (0.0, -45.0, -90.0)),
    Slot("arm-left", "hand", (5.2, 18.76, -10.32), _turn(0, 45.0), 2, (0.0, 90.0)),
    Slot("arm-right", "hand", (-5.2, 18.76, -10.32), _turn(0, 45.0), 2, (0.0, 90.0)),
    Slot("torso", "head", (0.0, -24.0, 0.0), np.eye(3), 1, (0.0,)),
    # ... or 3 LDU higher, as LDraw authors place it as often (8 of the 14 heads of the designs);
    # the sampler puts it at -24 (no angles: no attachment of its own).
    Slot("torso", "head", (0.0, -27.0, 0.0), np.eye(3), 1, ()),
    Slot("head", "headgear", (0.0, 0.0, 0.0), np.eye(3), 1, (0.0,)),
    Slot("torso", "neckwear", (0.0, 0.0, 0.0), np.eye(3), 1, (0.0,)),
)
"""Every place a piece of one role sits on another (module docstring). Legs swing at the hips and
heads turn on the neck too; the sampler stands them straight."""

FEET = {
    "leg-left": ((10.0, 28.0, 0.0),),
    "leg-right": ((-10.0, 28.0, 0.0),),
    "hips-legs": ((10.0, 40.0, 0.0), (-10.0, 40.0, 0.0)),
}
"""The holes under a minifigure's feet, in the piece's frame: each takes a stud pointing up (-Y)
into it. The legs of the designs' standing minifigures sit so on their plates' studs."""

FOOT_AXIS = (0.0, -1.0, 0.0)
"""The way a stud goes into a foot, in the piece's frame (as a socket's axis)."""


LOWER_BODY = ("hips", "hips-legs", "leg-left", "leg-right")
"""Pieces a figure stands on: a parent may be put on one from above (hips on a leg, a torso on
hips); the other way round (a torso hung from an arm) the sampler does not build."""


def related(a: str, b: str) -> bool:
    """Whether pieces of roles `a` and `b` sit on one another only in a slot (or, of one role,
    never on one another)."""
    return a == b or any({s.parent, s.child} == {a, b} for s in SLOTS)


HOLD_LDU = 7.0
"""How far from its slot a piece may sit and still be held there (`in_a_slot`). Designs put hands
up to 6.3 LDU off their arm's slot (6716; 40448 4.7) and turn arms about more than their
shoulder's axis (40448, 6716): files drawn by hand, of figures that hold. A piece a slot's length
or more away (a torso on a head's stud, a second torso on the first) is in none."""


def _at_slot(slot: Slot, parent_pose, child_pose, tol_ldu: float) -> bool:
    rel_t = parent_pose.R.T @ (np.asarray(child_pose.t) - parent_pose.t)
    return bool(np.linalg.norm(rel_t - np.asarray(slot.offset)) <= tol_ldu)


def in_a_slot(a: str, a_pose, b: str, b_pose, tol_ldu: float = HOLD_LDU) -> bool:
    """Whether a piece of role `a` and one of role `b` sit in a slot of one another, either way
    round: the child's origin within `tol_ldu` of the slot's, however it is turned."""
    return any(_at_slot(s, a_pose, b_pose, tol_ldu) for s in SLOTS if (s.parent, s.child) == (a, b)) or \
        any(_at_slot(s, b_pose, a_pose, tol_ldu) for s in SLOTS if (s.parent, s.child) == (b, a))


def fits(slot: Slot, parent_pose, child_pose, tol_ldu: float = 1.5, tol_deg: float = 3.0) -> bool:
    """Whether a child piece at `child_pose` sits in `slot` of a parent at `parent_pose` (both
    `Pose`s, LDU), at any turn about the slot's axis: its origin within `tol_ldu` of the slot's,
    its rotation within `tol_deg` of the slot's base turned about that axis. 1.5 LDU: hand-edited
    files put pieces 1 LDU off (10156's arms)."""
    if not _at_slot(slot, parent_pose, child_pose, tol_ldu):
        return False
    turn = slot.base.T @ parent_pose.R.T @ child_pose.R  # the turn after the base: about `axis` only
    if slot.axis is None:
        angle = np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1)))
        return bool(angle <= tol_deg)
    a = np.zeros(3)
    a[slot.axis] = 1.0
    return bool(np.degrees(np.arccos(np.clip(turn @ a @ a, -1, 1))) <= tol_deg)
