"""Snapping a nearly connected part onto the valid connection it nearly makes (`settle` uses it).

The valid connections are the sampler's candidates: every pose that puts one of the part's sockets
on a free stud of the structure or one of its studs into a free socket, at the 4 turns about the
stud axis (`attach.attachment_arrays`), each with the stud connections it makes
(`structure.connections_at`: stud base and axis). A part at pose P is within snapping tolerance of
such a candidate C when

- its rotation is within `SnapRule.degrees` of C's, up to the part's symmetry (a pose R and R @ S
  look the same: the nearest S is taken, and the snapped pose is C turned by it, so that it stays
  close to P in its LDraw numbers too), and
- every connection point C makes (the stud base, a point of the part's frame) lies, with the part
  at P, within `SnapRule.plane_ldu` of where C puts it across the stud axis and within
  `SnapRule.axis_ldu` along it (either way: resting on the studs' tops, or pressed past the seat).

Candidates within tolerance come nearest first (the largest distance of their connection points,
then the sampler's order); the asker judges them with the checks and takes the first accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from factory.parts import Part
from factory.physics.attach import attachment_arrays
from factory.physics.structure import Structure, connections_at
from factory.pose import Pose


@dataclass(frozen=True)
class SnapRule:
    """When a part counts as landing on a valid stud connection."""

    plane_ldu: float = 3.0
    """Across the stud axis (LDU): under a stud's radius (6 LDU), so a part snaps only onto the stud
    it is over, never onto the neighbour 20 LDU away; a grid step is 20 LDU, so a part half way
    between two positions (10 LDU off each) does not snap."""
    axis_ldu: float = 4.5
    """Along the stud axis (LDU): a stud's height (4 LDU) and the two insets of the collision pieces
    (0.25 each): a part lying on the tops of the studs it fits is 4 LDU above its seat, and clicks."""
    degrees: float = 10.0
    """Rotation (degrees) from the candidate's, up to the part's symmetry: a part turned more is
    caught by its walls on the studs rather than guided onto them."""


@dataclass(frozen=True)
class SnapTargets:
    """The valid connected poses of one part on one structure, with their connection points."""

    rotations: np.ndarray
    """(n, S, 3, 3): each candidate's rotation times each of the part's symmetries."""
    symmetries: np.ndarray
    """(S, 3, 3)."""
    t: np.ndarray
    """(n, 3) translations (LDU)."""
    owner: np.ndarray
    """(k,) the candidate of each connection point."""
    local: np.ndarray
    """(k, S, 3): each connection point in the part's frame, as the part turned by each symmetry
    carries it (S^T q)."""
    world: np.ndarray
    """(k, 3) where the candidate puts it."""
    axis: np.ndarray
    """(k, 3) its stud axis."""

    @classmethod
    def of(cls, structure: Structure, part: Part) -> "SnapTargets":
        r, t = attachment_arrays(structure, part)
        sym = np.array(part.symmetry.rotations, float).reshape(-1, 3, 3)
        conns = connections_at(structure, part, r, t) if len(r) else []
        owner, world, axis = [], [], []
        for c, found in enumerate(conns):
            for _, _, base, ax in found:
                owner.append(c)
                world.append(base)
                axis.append(ax)
        owner_a = np.array(owner, np.int64)
        world_a = np.array(world, float).reshape(-1, 3)
        axis_a = np.array(axis, float).reshape(-1, 3)
        q = np.einsum("kij,ki->kj", r[owner_a], world_a - t[owner_a]) if len(owner_a) else np.zeros((0, 3))
        return cls(rotations=np.einsum("nij,sjk->nsik", r, sym), symmetries=sym, t=t, owner=owner_a,
                   local=np.einsum("kj,sjm->ksm", q, sym), world=world_a, axis=axis_a)

    def __len__(self) -> int:
        return len(self.t)

    @cached_property
    def _radius(self) -> float:
        """The farthest connection point from the part's origin (LDU)."""
        return float(np.linalg.norm(self.local, axis=-1).max()) if len(self.local) else 0.0

    def reach(self, rule: SnapRule) -> float:
        """How far a candidate within tolerance can have its translation from the pose's: its
        connection points lie within the tolerance box of theirs, turned by at most `degrees`
        about the part's origin."""
        return self._radius * 2.0 * np.sin(np.radians(rule.degrees) / 2.0) + np.hypot(rule.axis_ldu, rule.plane_ldu)

    def along(self, points: np.ndarray, rule: SnapRule) -> bool:
        """Whether any candidate may be within tolerance somewhere on the path through the part
        origin's `points` (k, 3), straight between them: its translation within `reach` of the
        path. False lets a caller skip the poses of that path."""
        if not len(self.owner) or not len(points):
            return False
        a, b = points[:-1], points[1:]
        if not len(a):
            a = b = points
        ab = b - a
        length2 = np.maximum(np.einsum("kd,kd->k", ab, ab), 1e-12)
        f = np.clip(np.einsum("nkd,kd->nk", self.t[:, None, :] - a[None], ab) / length2, 0.0, 1.0)
        gap = np.linalg.norm(self.t[:, None, :] - (a[None] + f[..., None] * ab[None]), axis=2)
        return bool((gap <= self.reach(rule) + 1e-6).any())

    def near(self, pose: Pose, rule: SnapRule) -> list[tuple[int, Pose, float]]:
        """(candidate, its pose turned by the symmetry nearest `pose`, largest connection point
        distance) of every candidate within the rule's tolerance of `pose`, nearest first."""
        return self.near_many(pose.R[None], pose.t[None], rule)[0]

    @cached_property
    def _points_of(self) -> tuple[np.ndarray, np.ndarray]:
        """(first connection point, number of them) of each candidate: `owner` runs in candidate
        order (`of`), so a candidate's points are one stretch of the arrays."""
        count = np.bincount(self.owner, minlength=len(self.t))
        return np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64), count

    def near_many(self, R: np.ndarray, t: np.ndarray, rule: SnapRule) -> list[list[tuple[int, Pose, float]]]:
        """`near` of m poses at once (`R` (m, 3, 3), `t` (m, 3)): one list per pose, the same
        test on every (pose, candidate) pair in a few array operations (a part's path is swept
        pose by pose, tens of poses a chunk)."""
        out: list[list[tuple[int, Pose, float]]] = [[] for _ in range(len(t))]
        if not len(self.owner) or not len(t):
            return out
        # The pairs whose candidate translation is beyond `reach` of the pose's are dropped before
        # the full test (i: the pose, c: the candidate of each pair left).
        gap = np.linalg.norm(self.t[None] - t[:, None], axis=2)
        i, c = np.nonzero(gap <= self.reach(rule) + 1e-6)
        if not len(i):
            return out
        trace = np.einsum("pij,psij->ps", R[i], self.rotations[c])
        best = trace.argmax(axis=1)
        cos = np.clip((trace[np.arange(len(c)), best] - 1.0) / 2.0, -1.0, 1.0)
        turned_ok = np.degrees(np.arccos(cos)) <= rule.degrees + 1e-9
        # Each pair's connection points (j: the pair of each point row).
        first, count = self._points_of
        n = count[c]
        j = np.repeat(np.arange(len(c)), n)
        points = first[c][j] + (np.arange(len(j)) - np.repeat(np.cumsum(n) - n, n))
        local = self.local[points, best[j]]
        off = np.einsum("kij,kj->ki", R[i][j], local) + t[i][j] - self.world[points]
        along = np.einsum("kd,kd->k", off, self.axis[points])
        across = np.linalg.norm(off - along[:, None] * self.axis[points], axis=1)
        fails = (np.abs(along) > rule.axis_ldu + 1e-9) | (across > rule.plane_ldu + 1e-9)
        bad = np.bincount(j, weights=fails, minlength=len(c)) > 0
        dist = np.zeros(len(c))
        np.maximum.at(dist, j, np.linalg.norm(off, axis=1))
        ok = np.flatnonzero(turned_ok & (n > 0) & ~bad)
        ok = ok[np.lexsort((c[ok], dist[ok], i[ok]))]  # by pose, then nearest, then the sampler's order
        for k in ok:
            out[i[k]].append((int(c[k]), Pose(self.rotations[c[k], best[k]], self.t[c[k]]), float(dist[k])))
        return out
