"""The collision rule of many candidates at once, on the device (backend 'jax').

`CollisionScene.penetration` asks MuJoCo for the contacts of one candidate pose at a time and
walks them in Python. Here every candidate of every request of a lockstep round is judged
together: the piece pairs near each candidate are picked on the host by boxes, and one jitted
vmap per piece-bucket shape (`pair_kernels`, kind 'still') gives each pair's separating-axis depth and
the depth of each piece's centre inside the other. The rule applied to them is the scene's:

- a stud piece and a part the candidate is stud-connected to never collide;
- overlap = depth + both insets, less `CONNECTED_SLACK_LDU` for a connected part; the deepest
  positive overlap, or a body piece's centre inside another's (the scene's coincidence test), is
  the candidate's penetration; the ground counts by the lowest vertex of its pieces;
- a stud crossing into another part's body (not connected) is probed against that part's real
  surface (`collide.studs_cross`, on the host, once per stud and part, all of a round at once; only
  where it can deepen the candidate's overlap, and not for a candidate already colliding by
  another pair): a stud standing in the part's hollow touches it without overlapping;
- a structure part with overlap > -`NEAR_LDU` touches the candidate.

**What may differ from MuJoCo.** Where pieces overlap, the separating-axis minimum is the
penetration depth (`sweep_jax`'s docstring), MuJoCo's to its solver tolerance. Where they are
apart, it bounds the gap from below: a part whose closest features are two vertices or a vertex
and an edge may count as touching here at a gap MuJoCo measures just over `NEAR_LDU`. Touching
decides a verdict only for a candidate with no stud connection (`unsupported-connection` against
`no-connection`); the sampler checks candidates at connection points.
"""

from __future__ import annotations

from functools import partial
from typing import Sequence

import numpy as np

from factory.parts import Part
from factory.physics.collide import CONNECTED_SLACK_LDU, NEAR_LDU, Penetration, _deepest, probe_frame, studs_cross
from factory.physics.geometry import collision_shape
from factory.physics.structure import Structure
from factory.physics.pair_kernels import intervals_many
from factory.physics.piece_sets import PieceSet, near_pairs_threaded, structure_set, unit_set
from factory.pose import Pose

MARGIN_LDU = NEAR_LDU + 0.5
"""Pieces farther apart than this (their boxes, along some axis) are not paired: the scene's
contact margin."""


class _Job:
    """One request: a unit (its parts in its own frame) at candidate poses against a structure."""

    def __init__(self, structure: Structure, rel: Sequence[tuple[Part, Pose]], poses: Sequence[Pose],
                 connected: Sequence[set[int]], floor_y: float | None, tol: float | None = None):
        self.structure, self.rel, self.poses, self.connected = structure, list(rel), list(poses), connected
        self.floor_y, self.tol = floor_y, tol
        self.uset: PieceSet = unit_set(self.rel)
        self.sset, sboxes = structure_set(structure)
        K = len(poses)
        self.R = np.stack([p.R for p in poses])
        self.t = np.stack([p.t for p in poses])
        conn = np.zeros((K, len(structure)), bool)
        for i, c in enumerate(connected):
            conn[i, list(c)] = True
        self.pairs = _pairs_at(self.uset, self.sset, sboxes, self.rel, self.R, self.t, conn)

    def launch_args(self) -> tuple:
        k, u, s, _, _ = self.pairs
        zero = np.zeros(len(k))
        return (self.uset, self.sset, self.R, self.t, np.zeros_like(self.t), k, u, s, zero, zero)

    def finish(self, res: np.ndarray) -> list[Penetration]:
        uset, sset, K = self.uset, self.sset, len(self.poses)
        k, u, s, j, conn = self.pairs
        overlap = res[:, 0] + uset.inset[u] + sset.inset[s] - np.where(conn, CONNECTED_SLACK_LDU, 0.0)
        # Coincidence: a body piece's centre inside another body piece (no slack, no insets).
        body = ~uset.stud[u] & ~sset.stud[s]
        centre = np.where(body, np.maximum(res[:, 1], res[:, 2]), -np.inf)
        # A stud in another part's body, not connected, is undecided until probed against that
        # part's real surface; the rest decide the depth at once.
        undecided = (overlap > 0) & (uset.stud[u] != sset.stud[s])
        ground = self._below_ground() if self.floor_y is not None else np.zeros(K)
        deepest = ground.copy()
        np.maximum.at(deepest, k, np.where(undecided, 0.0, np.maximum(overlap, 0.0)))
        np.maximum.at(deepest, k, np.maximum(centre, 0.0))
        # Probed: only where it can change the depth, and (with `tol`) not for a candidate that
        # collides by a decided pair already (its depth is then the deepest decided overlap).
        need = undecided & (overlap > deepest[k])
        if self.tol is not None:
            need &= deepest[k] <= self.tol
        probe = np.flatnonzero(need)
        if len(probe):
            # One probe per stud and part (whichever of the part's pieces it meets), all of them
            # against each part's surface at once.
            keys, which = np.unique(self._probe_keys(probe), axis=0, return_inverse=True)
            crossing = self._studs_cross(keys)[which.reshape(-1)]
            np.maximum.at(deepest, k[probe[crossing]], overlap[probe[crossing]])
        touching = (overlap > -NEAR_LDU) | (centre > 0)
        near: list[list[int]] = [[] for _ in range(K)]
        for a, b in zip(k[touching].tolist(), j[touching].tolist()):
            near[a].append(b)
        # Kept for `_apart`: a candidate that collides where it meets parts at joints is judged
        # again, its overlap with every other part from these results.
        self._overlap, self._centre, self._undecided, self._ground = overlap, centre, undecided, ground
        self._crossing = dict(zip(probe.tolist(), crossing.tolist())) if len(probe) else {}
        return [Penetration(d, frozenset(n), partial(self._apart, c))
                for c, (d, n) in enumerate(zip(deepest.tolist(), near))]

    def _apart(self, c: int, owners: set[int]) -> float:
        """Candidate `c`'s depth with its overlap with the structure parts `owners` left out (the
        ground and every other part as in `finish`), from the same pair results; its studs in a
        body asked deepest first, as the scene asks them (`collide._deepest`), probes reused."""
        k, j = self.pairs[0], self.pairs[3]
        sel = np.flatnonzero((k == c) & ~np.isin(j, list(owners)))
        overlap, undecided = self._overlap[sel], self._undecided[sel]

        def crosses(i: int) -> bool:
            p = int(sel[i])
            if p not in self._crossing:
                self._crossing[p] = bool(self._studs_cross(self._probe_keys(np.array([p])))[0])
            return self._crossing[p]

        contacts = _deepest(overlap, ~undecided & (overlap > 0), np.flatnonzero(undecided), crosses)
        return max(float(self._ground[c]), float(self._centre[sel].max(initial=0.0)), contacts)

    def _probe_keys(self, pairs: np.ndarray) -> np.ndarray:
        """(candidate, stud piece: unit piece u, or -1 - structure piece s, structure part, unit
        member) of each pair of a stud and a body (`_studs_cross`)."""
        k, u, s, j, _ = self.pairs
        stud_piece = np.where(self.uset.stud[u[pairs]], u[pairs], -1 - s[pairs])
        return np.stack([k[pairs], stud_piece, j[pairs], self.uset.owner[u[pairs]]], axis=1)

    def _below_ground(self) -> np.ndarray:
        """Per candidate: how far its pieces (plus their inset) reach below the ground."""
        uset = self.uset
        if not uset.n:
            return np.zeros(len(self.poses))
        # Every bucket's padded vertices: padding repeats a vertex of the piece.
        verts = np.concatenate([v.reshape(-1, 3) for v, _ in uset.verts])
        inset = np.concatenate([np.repeat(i, v.shape[1]) for v, i in uset.verts])
        y = np.einsum("kj,vj->kv", self.R[:, 1], verts) + self.t[:, 1:2]  # LDraw y points down
        return np.maximum((y - self.floor_y + inset).max(axis=1), 0.0)

    def _studs_cross(self, keys: np.ndarray) -> np.ndarray:
        """For each (candidate, stud piece: unit piece u, or -1 - structure piece s, structure part,
        unit member):
        whether the stud crosses the other part's surface (`collide.studs_cross`, in the body
        part's frame; a stud that does not stands in its hollow)."""
        uset, sset = self.uset, self.sset
        by_surface: dict[int, list] = {}
        for row, (k, piece, j, m) in enumerate(keys):
            pose = self.poses[k]
            placed = self.structure.placed[j]
            if piece >= 0:
                stud_part, stud_pose, index = self.rel[m][0], pose @ self.rel[m][1], piece - uset.start[m]
                body_part, body_pose = placed.part, placed.pose
            else:
                stud_part, stud_pose, index = placed.part, placed.pose, -1 - piece - sset.start[j]
                body_part, body_pose = self.rel[m][0], pose @ self.rel[m][1]
            shape = collision_shape(stud_part)
            pos, axis, surface = probe_frame(shape.stud_at[index - len(shape.body)], stud_pose, body_part, body_pose)
            entry = by_surface.setdefault(id(surface), [surface, [], [], []])
            entry[1].append(row)
            entry[2].append(pos)
            entry[3].append(axis)
        out = np.zeros(len(keys), bool)
        for surface, rows, pos, axis in by_surface.values():
            out[rows] = studs_cross(np.array(pos), np.array(axis), surface)
        return out


def _pairs_at(uset: PieceSet, sset: PieceSet, sboxes: np.ndarray, rel, R, t, conn):
    """Piece pairs within `MARGIN_LDU` of each other by their boxes at each candidate's pose
    (`piece_sets.near_pairs` with no motion, chunks on threads), the stud pieces of connected parts left out:
    (candidate, unit piece, structure piece, part, connected)."""
    if not len(sboxes) or not uset.n:
        return (np.zeros(0, np.int64),) * 4 + (np.zeros(0, bool),)
    return near_pairs_threaded(uset, sset, sboxes, rel, R, t, np.zeros_like(t), conn, -MARGIN_LDU, -MARGIN_LDU)


def penetrations(requests: Sequence[tuple]) -> list[list[Penetration]]:
    """For each request (structure, unit parts in the unit's frame, candidate poses of the unit,
    each candidate's connected structure parts, ground height or None, and optionally the
    collision tolerance): each candidate's `Penetration`, all requests' pairs in one launch per
    piece-bucket shape. With a tolerance, a candidate deeper than it by a pair that needs no
    probe is not probed further: its depth is that pair's (at most MuJoCo's)."""
    jobs = [_Job(*r) for r in requests]
    live = [j for j in jobs if len(j.pairs[0])]
    results = dict(zip(map(id, live), intervals_many([j.launch_args() for j in live], "still")))
    return [j.finish(results.get(id(j), np.zeros((0, 3)))) for j in jobs]
