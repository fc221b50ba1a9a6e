"""Attachments through joints: every pose that pushes one of a part's joint connectors home on a
free mating connector of the structure (a pin into a pin hole, an axle through an axle hole, a
wheel onto its pin, a clip onto a bar, a plate's underside pin into an open stud, and the other
way round), at a few turns about the joint's axis. The joint analogue of `attach`'s stud
attachments; the checker judges them like any candidate (`unmodelled.joints_between`).

For a connector of the part and a target of the structure whose kinds mate (`joints.mates`), the
part's connector axis is laid on the target's axis both ways round, turned by `TURNS` quarter
turns about it (a joint that turns is held at any angle: these are a few of them), and slid along
it so that the shorter of the two lies on the other: its ends aligned with the other's ends, and
centred on it. Click hinge halves, whose fingers sit between the other's, are centred on each
other and turned to each of the hinge's steps (`joints.CLICK_STEP_DEG` from straight). Poses equal
under the part's symmetry (to 1e-3 LDU) are dropped, first kept. Deterministic order: connector,
target, way round, turn, slide.
"""

from __future__ import annotations

import numpy as np

from factory.joints import CLICK_STEP_DEG, JointConnector, click_angle, joint_ends, mates, stretches
from factory.ldraw.other_connectors import place_connectors
from factory.parts import Part
from factory.physics.attach import distinct_poses
from factory.physics.structure import Structure, align
from factory.physics.unmodelled import is_minifig
from factory.symmetry import rotation_about

TURNS = 4
"""Quarter turns about a joint's axis tried for each way round."""


def attach_ends(part: Part) -> list[JointConnector]:
    """The connectors a part is attached through and offers to later parts: `joints.joint_ends`,
    minifigure pieces having none (their joints are their own)."""
    return [] if is_minifig(part) else joint_ends(part)


def _targets(structure: Structure) -> tuple[np.ndarray, list[str], list]:
    """The structure's joint connectors in the world frame (k, 3, 3), their kinds and turns (a
    primitive's Z axis in the world frame, None where it has none)."""
    segs, kinds, refs = [], [], []
    for p in structure.placed:
        conns = attach_ends(p.part)
        if conns:
            segs.append(place_connectors(stretches(conns), p.pose.R, p.pose.t))
            kinds += [c.kind for c in conns]
            refs += [None if c.ref is None else p.pose.R @ np.array(c.ref) for c in conns]
    return (np.concatenate(segs) if segs else np.zeros((0, 3, 3))), kinds, refs


def _turns(c: JointConnector, base: np.ndarray, u: np.ndarray, ref, stepped: bool) -> list[float]:
    """The turns (degrees about `u`, after `base`) to try: a click hinge's steps from straight
    against the target's turn `ref`, else `TURNS` quarter turns."""
    if not stepped:
        return [90.0 * k for k in range(TURNS)]
    if c.ref is None or ref is None:
        return []
    straight = click_angle(base @ np.array(c.ref), ref, u)
    return [straight + CLICK_STEP_DEG * k for k in range(round(360 / CLICK_STEP_DEG))]


def joint_attachment_arrays(structure: Structure, part: Part) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and translations (n, 3) of the part's attachments through joints
    (module docstring); empty where it or the structure has no connector that mates."""
    mine = attach_ends(part)
    targets, kinds, refs = _targets(structure)
    poses = []
    for c in mine:
        a0, a1, ua = (np.array(v, float) for v in (c.start, c.end, c.axis))
        for g, kind, ref in zip(targets, kinds, refs):
            freedom = mates(c.kind, kind)
            if freedom is None:
                continue
            u = g[2]
            b = float((g[1] - g[0]) @ u)
            b_lo, b_hi = min(0.0, b), max(0.0, b)
            for way in (1.0, -1.0):
                base = align(ua, way * u)
                for turn in _turns(c, base, u, ref, freedom.stepped):
                    r = np.round(rotation_about(u, turn) @ base, 12)
                    d = float((r @ (a1 - a0)) @ u)
                    c_lo, c_hi = min(0.0, d), max(0.0, d)
                    centred = (b_lo + b_hi) / 2 - (c_lo + c_hi) / 2
                    slides = {centred} if freedom.stepped else {b_lo - c_lo, b_hi - c_hi, centred}
                    poses += [(r, g[0] + x * u - r @ a0) for x in sorted(slides)]
    return distinct_poses(part, poses)
