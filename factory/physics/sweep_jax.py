"""Buildability sweeps of many candidates at once, exactly, in JAX (backend 'jax').

`sweep.sweep` asks MuJoCo for contacts at poses stepped along the approach. Here the same question
is answered without stepping. Two convex pieces A and B overlap by depth = min over axes n of
min(max A.n - min B.n, max B.n - min A.n), n over the separating-axis candidates (face normals of
both, cross products of their edge directions): each value is how far A must move along +-n to
clear B, any direction's value bounds the depth from above, and the Minkowski difference's facets
have normals among these candidates, so the minimum is the penetration depth (the translation
MuJoCo's EPA reports); where the pieces are apart some candidate separates them and the minimum is
<= 0. Moving A back by s along d shifts A.n by -s (d.n): each of those values is linear in s, so
{s : depth(s) > tau} = {s : every one of them > tau} is one open interval, found per piece pair in
one pass (`_pair_interval`). Requires tau >= 0 (overlap = depth + both insets, so a tolerance of at
least both insets, 0.5 LDU by default); with tau < 0 the minimum is not the distance, and the
whole call is swept on the CPU instead.

**Rules** (`CollisionScene.penetration`), per pair of a unit piece and a structure part's piece:
- not connected, body-body or stud-stud: counted where depth + insets > tolerance; exact;
- connected, body-body: depth + insets - CONNECTED_SLACK_LDU, and either piece's centre inside the
  other deeper than the tolerance (the scene's coincidence test, which has no slack; for other
  pairs it never exceeds the depth), both only on the stretches of s the CPU sweep queries at all
  (where the unit's box overlaps a part it is not connected to: `sweep._overlap_intervals`);
- connected, with a stud: never counted;
- not connected, stud-body: the scene ignores a stud standing in the other part's hollow
  (`collide.stud_crosses`, a probe of the real surface at each pose), which is not written here.
  Such a pair is **undecided**: a candidate blocked by a decided pair is blocked whatever it does;
  one that only an undecided pair could block is swept by `sweep.sweep` on the CPU (counted: `CheckState.sweep_counts`).
- not connected, decided, but never deeper than `solid_overlap.REFINE_LDU` on the path (its
  stretch at that threshold, found in the same launch, is empty): **undecided** too, since the CPU
  sweep measures such overlaps again in the parts themselves and may clear them.

A unit is blocked when a counted interval meets s > 0 (s = 0, the final pose, is the collision
check's). One blocked only further out than `sweep.PRESS_LDU` is swept by `sweep.sweep` on the
CPU, which then asks whether it comes in from the side and is pressed on only over that last
stretch (`sweep._pressed_last`): the same rule on both backends; one blocked within that
stretch but clear over the fingertip's end (`sweep.PRESS_MIN_LDU`) is rare and swept on the CPU. The blocking pose reported (`at_ldu`) is the outer end of the outermost interval, where
the unit coming from outside first overlaps beyond the tolerance; `blocked_by` names the parts
whose decided intervals hold a pose just inside it (`MIN_STEP_LDU` / 4 in, or the interval's middle
if shorter). The depth there is not computed (`depth_ldu` is nan); no contact query is made.

**Guarantee** vs the stepped reference: every pose on the path is judged, so every overlap beyond
the tolerance is found, where the reference finds those beyond tolerance + `MIN_STEP_LDU` / 2 and
may miss shallower ones between its poses; depths are those of the pieces' hulls in float64
(MuJoCo's agree to its solver tolerance). Verdicts differ only where the deepest overlap on the path
lies within that band of the tolerance, or where MuJoCo's depth and the exact one fall on two sides
of it.

**Device layout**: the pieces and the pairs near each candidate are `piece_sets`'s (pieces
precomputed once per collision shape, placed in the world once per structure and in the unit's
frame once per call; pairs chosen on the host by boxes swept along d, parts' boxes with the
reference's margin, then pieces' boxes), the intervals of the pairs `pair_kernels`'s (grouped by
the size buckets of both pieces, vertices, normals, edges; each group in one jitted vmap over
pairs, its counts padded to powers of two, at most `pair_kernels.MAX_WORK` projections per
launch: so a run compiles once per shape met, `pair_kernels.COMPILES`, never per call).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from factory.parts import Part
from factory.physics.check_state import current
from factory.physics.collide import CONNECTED_SLACK_LDU, CollisionScene
from factory.physics.geometry import INSET_LDU
from factory.physics.pair_kernels import intervals_many
from factory.physics.solid_overlap import REFINE_LDU
from factory.physics.piece_sets import PieceSet, in_chunks, near_pairs, structure_set, unit_set
from factory.physics.structure import Structure
from factory.physics.sweep import (PRESS_LDU, PRESS_MIN_LDU, MIN_STEP_LDU, SweepResult, _boxes, _overlap_intervals, across,
                                   approaches_from, seating_directions, sweep)
from factory.pose import Pose

_CLEAR, _BLOCKED, _UNDECIDED = 0, 1, 2
"""States of a side sweep's unit (`_SweepJob.states`)."""
# Candidates are counted by how they were judged in the current checker's
# `CheckState.sweep_counts` ('device', 'referred': swept on the CPU, only an undecided stud-body
# pair could block them; 'not-judged': no approach; 'cpu': tolerance below the insets).


def _pairs(uset: PieceSet, sset: PieceSet, sboxes, rel, R, t, d, conn, tol: float, margin: float, a: int, b: int):
    """The piece pairs of candidates a..b-1 whose boxes meet somewhere along the approach
    (`near_pairs`: parts' boxes shrunk by the reference's margin, the parts it connects to kept:
    their pieces count too, with the slack), with their thresholds: (candidate, unit piece,
    structure piece, part, connected, thr, thr_c, undecided)."""
    k, u, s, j, is_conn = near_pairs(uset, sset, sboxes, rel, R[a:b], t[a:b], d[a:b], conn[a:b], margin)
    thr = tol - uset.inset[u] - sset.inset[s] + np.where(is_conn, CONNECTED_SLACK_LDU, 0.0)
    thr_c = np.where(is_conn, tol, np.inf)
    undecided = ~is_conn & (uset.stud[u] != sset.stud[s])
    return k + a, u, s, j, is_conn, thr, thr_c, undecided


def _pairs_threaded(uset, sset, sboxes, rel, R, t, d, conn, tol, margin):
    """`_pairs` of all candidates, in chunks on threads (`in_chunks`)."""
    return in_chunks(lambda a, b: _pairs(uset, sset, sboxes, rel, R, t, d, conn, tol, margin, a, b), len(R))


def sweep_many(
    scene: CollisionScene | None,
    structure: Structure,
    units: Sequence[Sequence[tuple[Part, Pose]]],
    connected: Sequence[set[int]],
    max_penetration_ldu: float = 0.5,
    directions: Sequence[np.ndarray] | None = None,
) -> list[SweepResult]:
    """`sweep.sweep` for every unit (module docstring for the method and what may differ).

    The units share their parts and relative layout up to one rigid motion (as `check.check_units`
    requires), each placed in world poses, its pose that of its first part; `scene` is their
    collision scene as `check_units` builds it, or a function building it on first need (None: built
    here if a candidate is referred to the CPU). `directions`: each unit's seating directions (`sweep.seating_directions`), if known.
    """
    return sweep_groups([(scene, structure, units, connected, max_penetration_ldu, directions)])[0]


def sweep_groups(groups: Sequence[tuple]) -> list[list[SweepResult]]:
    """`sweep_many(*group)` of every group (each its own structure: objects grown in lockstep),
    with the pairs of all groups in one launch per piece-bucket shape (`intervals_many`). Units
    blocked on their axis only further out than `sweep.PRESS_LDU` are then swept from the side
    (`_SweepJob.sides`), every group's in one more launch."""
    jobs = [_SweepJob(*g) for g in groups]
    _launch_all(jobs)
    sides = [(j, j.sides()) for j in jobs]
    sides = [(j, sj) for j, sj in sides if sj is not None]
    _launch_all([sj for _, sj in sides])
    for j, sj in sides:
        j.after_sides(sj)
    return [j.results for j in jobs]  # type: ignore[misc]


def _launch_all(jobs: Sequence[_SweepJob]) -> None:
    live = [j for j in jobs if j.pairs is not None]
    for j, res in zip(live, intervals_many([j.launch_args() for j in live])):
        j.finish(res)


class _SweepJob:
    """One `sweep_many` call: approaches and piece pairs on the host at construction (`pairs` None
    when nothing is left for the device), the intervals from the device, then `finish`.

    With `ways` (one direction per unit) the units are swept along those as given, with nothing
    connected, and `finish` only records each unit's state (`states`): the side sweeps of
    `sides`, whose verdicts their parent job draws (`after_sides`)."""

    def __init__(self, scene, structure, units, connected, max_penetration_ldu=0.5, directions=None, ways=None):
        self.structure, self.units, self.connected = structure, units, connected
        self.tol = tol = max_penetration_ldu
        self.results: list[SweepResult | None] = [None] * len(units)
        self.pairs = None
        self.side_of = ways is not None
        self.pending: list[int] = []  # rows blocked only further out than PRESS_LDU: asked from the side
        if not units:
            return
        if ways is not None:
            dirs = list(enumerate(ways))
        else:
            dirs = []
            found_all = approaches_from([directions[i] if directions is not None else seating_directions(structure, unit)
                                         for i, unit in enumerate(units)])
            for i, found in enumerate(found_all):
                if found.direction is None:
                    current().sweep_counts["not-judged"] += 1
                    self.results[i] = SweepResult(False if found.reason == "clamped" else None, found.reason, (), 0.0,
                                                  0.0, 0)
                else:
                    dirs.append((i, found.direction))
        first = units[0]
        anchor = first[0][1]
        self.rel = rel = [(part, anchor.inverse() @ pose) for part, pose in first]
        self.scene = scene
        self.idx = np.array([i for i, _ in dirs], np.int64)
        self.states = np.zeros(len(self.idx), np.int8)  # side sweeps: _CLEAR until finished
        if not dirs:
            return
        self.sset, self.sboxes = sset, sboxes = structure_set(structure)
        self.uset = uset = unit_set(rel)
        if tol < uset.inset.max(initial=0.0) + sset.inset.max(initial=0.0):
            # Below both insets the separating-axis minimum is not the distance (module docstring).
            self.states[:] = _UNDECIDED
            if not self.side_of:
                for i, _ in dirs:
                    current().sweep_counts["cpu"] += 1
                    self.results[i] = self.cpu(i)
            return
        idx = self.idx
        self.d = d = np.array([v for _, v in dirs])
        self.R = R = np.stack([units[i][0][1].R for i in idx])
        self.t = t = np.stack([units[i][0][1].t for i in idx])
        self.margin = margin = min(tol, 2 * INSET_LDU)
        conn = np.zeros((len(idx), len(structure)), bool)
        sizes = [len(connected[i]) for i in idx]
        conn[np.repeat(np.arange(len(idx)), sizes), np.fromiter((q for i in idx for q in connected[i]), np.int64, sum(sizes))] = True
        self.pairs = _pairs_threaded(uset, sset, sboxes, rel, R, t, d, conn, tol, margin)

    def sides(self) -> _SweepJob | None:
        """The side sweeps of this job's pending units (`sweep._pressed_last`): each unit backed out
        `PRESS_LDU` along its axis, studs out of their sockets (nothing connected), swept along the
        four directions `across` the axis."""
        if not self.pending:
            return None
        units, ways = [], []
        for row in self.pending:
            back = PRESS_LDU * self.d[row]
            moved = [(part, Pose(pose.R, pose.t - back)) for part, pose in self.units[self.idx[row]]]
            for way in across(self.d[row]):
                units.append(moved)
                ways.append(way)
        return _SweepJob(self.scene, self.structure, units, [set()] * len(units), self.tol, ways=ways)

    def after_sides(self, side: _SweepJob) -> None:
        """Pending units' verdicts from their side sweeps: buildable when one side is clear; the
        straight verdict (kept in `results`) when every side is blocked; else swept on the CPU."""
        states = side.states.reshape(len(self.pending), 4)
        for row, st in zip(self.pending, states):
            i = self.idx[row]
            if (st == _CLEAR).any():
                current().sweep_counts["device"] += 1
                self.results[i] = SweepResult(True, None, (), float("nan"), PRESS_LDU, 0)
            elif (st == _BLOCKED).all():
                current().sweep_counts["device"] += 1
            else:
                current().sweep_counts["referred"] += 1
                self.results[i] = self.cpu(i)
        self.pending = []

    def cpu(self, i: int) -> SweepResult:
        if self.scene is None:
            self.scene = CollisionScene(self.structure, self.rel, 1e6)
        elif not isinstance(self.scene, CollisionScene):
            self.scene = self.scene()  # built on first need
        return sweep(self.scene, self.structure, self.units[i], self.connected[i], self.tol)

    def _deep(self) -> np.ndarray:
        """The pairs also launched at `solid_overlap.REFINE_LDU` (after all pairs, in this order):
        the decided ones not connected. One whose overlap on the path stays below that is one the
        CPU sweep measures again in the parts themselves (`finish`)."""
        _, _, _, _, is_conn, _, _, undecided = self.pairs
        return np.flatnonzero(~is_conn & ~undecided)

    def launch_args(self) -> tuple:
        k, u, s, j, is_conn, thr, thr_c, undecided = self.pairs
        deep = self._deep()
        thr_deep = REFINE_LDU - self.uset.inset[u[deep]] - self.sset.inset[s[deep]]
        return (self.uset, self.sset, self.R, self.t, self.d, np.concatenate([k, k[deep]]), np.concatenate([u, u[deep]]),
                np.concatenate([s, s[deep]]), np.concatenate([thr, thr_deep]),
                np.concatenate([thr_c, np.full(len(deep), np.inf)]))

    def finish(self, res: np.ndarray) -> None:
        structure, units, connected, idx, d = self.structure, self.units, self.connected, self.idx, self.d
        k, _, _, j, is_conn, _, _, undecided = self.pairs
        res, res_deep = res[:len(k)], res[len(k):]
        # A decided pair that overlaps beyond the tolerance on the path but never beyond
        # REFINE_LDU is undecided here: the CPU sweep's solids may clear it (`sweep._along`).
        shallow = np.zeros(len(k), bool)
        shallow[self._deep()] = ~(res_deep[:, 1] > np.maximum(res_deep[:, 0], 0.0))
        undecided = undecided | shallow
        results = self.results
        # Counted stretches of s > 0: (candidate, part, lo, hi, decided).
        hits = []
        for col in (0, 2, 4):
            lo_, hi_ = np.maximum(res[:, col], 0.0), res[:, col + 1]
            ok = hi_ > lo_
            if col:
                ok &= is_conn
            hits.append((k[ok], j[ok], lo_[ok], hi_[ok], ~undecided[ok], is_conn[ok]))
        hk, hj, hlo, hhi, hdec, hconn = (np.concatenate(x) for x in zip(*hits))
        # Parts the unit is connected to count only where the reference queries at all: where its box
        # overlaps a part it is not connected to. Rare (the unit backs away from them): a loop.
        plain = ~hconn
        clipped = []
        for e in np.flatnonzero(hconn):
            i = idx[hk[e]]
            others = [q for q in range(len(structure)) if q not in connected[i]]
            span = _overlap_intervals(_boxes(units[i]), self.sboxes[others], d[hk[e]], self.margin)
            for a, b in span:
                if min(b, hhi[e]) > max(a, hlo[e]):
                    clipped.append((hk[e], hj[e], max(a, hlo[e]), min(b, hhi[e])))
        ck, cj, clo, chi = (np.array(x).reshape(-1) for x in zip(*clipped)) if clipped else [np.zeros(0)] * 4
        dk = np.concatenate([hk[plain & hdec], ck.astype(np.int64)])
        dj = np.concatenate([hj[plain & hdec], cj.astype(np.int64)])
        dlo = np.concatenate([hlo[plain & hdec], clo])
        dhi = np.concatenate([hhi[plain & hdec], chi])
        top = np.full(len(idx), -np.inf)
        np.maximum.at(top, dk, dhi)
        # The pose just inside the outermost decided interval: who is in the way there.
        outer = dhi >= top[dk]
        floor_ = np.full(len(idx), -np.inf)
        np.maximum.at(floor_, dk[outer], dlo[outer])
        probe = np.maximum(top - MIN_STEP_LDU / 4, (top + floor_) / 2)
        there = (dlo < probe[dk]) & (probe[dk] < dhi)
        blockers: dict[int, set[int]] = {}
        for a, b in zip(dk[there], dj[there]):
            blockers.setdefault(int(a), set()).add(int(b))
        maybe = np.zeros(len(idx), bool)
        maybe[hk[~hdec & plain]] = True
        maybe_near = np.zeros(len(idx), bool)  # within the stretch pressed along: all a side entry needs
        maybe_near[hk[~hdec & plain & (hlo < PRESS_LDU)]] = True
        # Blocked within the stretch it is pressed along (`sweep.PRESS_LDU`): no side approach helps.
        pressed = np.zeros(len(idx), bool)
        pressed[dk[dlo < PRESS_LDU]] = True
        # ... but clear over the fingertip's end (`sweep.PRESS_MIN_LDU`): rare, swept on the CPU.
        pressed_min = np.zeros(len(idx), bool)
        pressed_min[dk[dlo < PRESS_MIN_LDU]] = True
        if self.side_of:
            self.states = np.where(np.isfinite(top), _BLOCKED, np.where(maybe, _UNDECIDED, _CLEAR)).astype(np.int8)
            return
        for row, i in enumerate(idx):
            if np.isfinite(top[row]) and not pressed[row]:
                # Blocked only further out: whether the unit comes in from the side instead
                # (`sweep._pressed_last`) is asked of the device too (`sides`), unless an undecided
                # pair may block it, when the CPU sweeps it.
                if maybe_near[row]:
                    current().sweep_counts["referred"] += 1
                    results[i] = self.cpu(i)
                else:
                    self.pending.append(row)
                    results[i] = SweepResult(False, "blocked", tuple(sorted(blockers.get(row, ()))), float("nan"),
                                             round(float(top[row]), 4), 0)
            elif np.isfinite(top[row]) and not pressed_min[row]:
                current().sweep_counts["referred"] += 1
                results[i] = self.cpu(i)
            elif np.isfinite(top[row]):
                current().sweep_counts["device"] += 1
                results[i] = SweepResult(False, "blocked", tuple(sorted(blockers.get(row, ()))), float("nan"),
                                         round(float(top[row]), 4), 0)
            elif maybe[row]:
                current().sweep_counts["referred"] += 1
                results[i] = self.cpu(i)
            else:
                current().sweep_counts["device"] += 1
                results[i] = SweepResult(True, None, (), float("nan"), 0.0, 0)
