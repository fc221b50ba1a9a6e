"""Attachments of minifigure pieces: a leg (or hips and legs) standing with a foot on a free stud
pointing up, at each quarter turn about it; any piece in a slot of a placed piece it joins
(`factory.minifig.SLOTS`: a torso on hips, an arm on a torso, a hand in an arm, a head on a
torso, a hat on a head), or a placed lower body piece in a slot of it (a torso put on hips from
above, hips put on a leg). The checker judges them like any candidate: minifigure pieces that meet hold one
another (`unmodelled.joints_between`), a foot on a stud is held by it.

The checker leaves out the overlap of two minifigure pieces in a slot of one another (their files
overlap by design), and of pieces whose roles have no slot between them (a hand and a torso); so
these attachments keep two figures from sharing a place themselves: a piece goes nowhere a piece
of its role already is, and a figure stands on its feet only where no other figure's legs are
within `APART_LDU`.
"""

from __future__ import annotations

import numpy as np

from factory.minifig import FEET, LOWER_BODY, SLOTS, role
from factory.parts import Part
from factory.physics.attach import distinct_poses
from factory.physics.structure import Structure
from factory.symmetry import rotation_about

SAME_PLACE_LDU = 1.0
"""Two pieces of one role whose origins are this close are in one place."""
APART_LDU = 50.0
"""Least distance between the leg origins (the hips' axis) of two standing figures: their arms,
which reach 25 LDU to either side, do not meet."""
_LEGS = {"leg-left": 0.0, "leg-right": 0.0, "hips-legs": 12.0, "hips": 12.0}
"""Where a piece puts its figure's leg origin, along its own Y axis (legs are drawn from 12 LDU
below the hips' origin; hips and legs in one piece have the hips' origin)."""


def _roles(structure: Structure) -> list[tuple[int, str]]:
    out = []
    for i, p in enumerate(structure.placed):
        r = role(p.part.description)
        if r is not None:
            out.append((i, r))
    return out


def _leg_origin(r: str, pose) -> np.ndarray:
    return pose.t + pose.R @ np.array([0.0, _LEGS[r], 0.0])


def minifig_attachment_arrays(structure: Structure, part: Part, in_slots_only: bool = False
                              ) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and translations (n, 3) of a minifigure piece's attachments (module
    docstring); empty for a part with no role. Deterministic order: feet, then placed pieces in
    order, slots in `SLOTS` order, angles; poses equal under the part's symmetry dropped.
    `in_slots_only`: only those in a slot of a placed piece (a figure being built), not on feet."""
    mine = role(part.description)
    if mine is None:
        return distinct_poses(part, [])
    placed = _roles(structure)
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    if mine in FEET and not in_slots_only:
        sp, sa, _ = structure.studs
        busy, _ = structure.occupied()
        up = np.array([0.0, -1.0, 0.0])
        figures = [_leg_origin(r, structure.placed[i].pose) for i, r in placed if r in _LEGS]
        for k in np.flatnonzero(~busy & (sa @ up > 1 - 1e-6)):
            for q in range(4):
                rot = np.round(rotation_about(up, 90.0 * q), 12)
                for foot in FEET[mine]:
                    t = sp[k] - rot @ np.asarray(foot)
                    legs = t + rot @ np.array([0.0, _LEGS[mine], 0.0])
                    if all(np.linalg.norm(legs - f) >= APART_LDU for f in figures):
                        poses.append((rot, t))
    for i, r in placed:
        at = structure.placed[i].pose
        for slot in SLOTS:
            if slot.parent == r and slot.child == mine:
                for rel in slot.rotations():
                    poses.append((at.R @ rel, at.t + at.R @ np.asarray(slot.offset)))
            elif slot.child == r and slot.parent == mine and r in LOWER_BODY:
                for rel in slot.rotations():
                    rot = at.R @ rel.T
                    poses.append((rot, at.t - rot @ np.asarray(slot.offset)))
    same = [structure.placed[i].pose.t for i, r in placed if r == mine]
    return distinct_poses(part, [(rot, t) for rot, t in poses
                                 if all(np.linalg.norm(t - s) >= SAME_PLACE_LDU for s in same)])
