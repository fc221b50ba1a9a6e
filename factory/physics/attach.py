"""Feasible attachments: every pose that puts one of a part's sockets on a free stud of the
structure, or one of its studs into a free socket, at each of the 4 turns about the stud axis, with
poses equal under the part's symmetry dropped. Deterministic order: connector, target, turn.

Vectorised: a pose's rotation depends only on the part connector, the target's axis and the turn,
so rotations (and their symmetry-aware keys) are computed once per (connector, axis, turn) and the
translations of all targets at once; duplicates go with one `np.unique` keeping first occurrences.
A 60-part structure gives ~14,000 poses; a pose-by-pose loop took seconds per step.
`tests/test_physics.py` checks the result against that plain loop (connectors on several axes
included)."""

from __future__ import annotations

import math

import numpy as np

from factory.parts import Part, box_corners
from factory.physics.structure import Structure, align
from factory.pose import Pose
from factory.symmetry import rotation_about

_TURNS = [rotation_about((0.0, 1.0, 0.0), 90.0 * k) for k in range(4)]


def _rotation_key(part: Part, r: np.ndarray) -> tuple:
    # As `structure.canonical_key`, rotation half.
    return min(tuple(np.round(r @ s, 4).ravel().tolist()) for s in part.symmetry.rotations)


def _translation_key(t: np.ndarray) -> np.ndarray:
    """Translations (n, 3) as integers of 1e-3 LDU (poses within that are one)."""
    return np.round(np.round(t, 3) * 1000).astype(np.int64)


def pose_key(part: Part, r: np.ndarray, t: np.ndarray) -> tuple:
    """One pose's key: equal for poses equal under the part's symmetry (as the rows deduplicated
    below), for callers that enumerate poses one at a time (`distinct_poses`)."""
    return _rotation_key(part, r), tuple(_translation_key(np.asarray(t)[None])[0].tolist())


def distinct_poses(part: Part, poses) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and translations (n, 3) of `poses` ((r, t) pairs, in order), those equal
    under the part's symmetry to one before them dropped (`pose_key`); for callers that enumerate
    poses one at a time (`joint_attach`, `minifig_attach`)."""
    rots, ts, keys = [], [], set()
    for r, t in poses:
        key = pose_key(part, r, t)
        if key not in keys:
            keys.add(key)
            rots.append(r)
            ts.append(t)
    if not ts:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    return np.stack(rots), np.stack(ts)


def _first_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indices of each distinct row's first occurrence, ascending; each row's group: the rank of
    its row's first occurrence). Integer rows whose columns' ranges fit one int64 are packed into
    one number (a single sort: rows are 4 numbers and there are thousands of them at every draw);
    other rows go through a stable sort of the rows, which keeps equal rows in their order."""
    packed = _packed(keys)
    if packed is not None:
        _, first, inverse = np.unique(packed, return_index=True, return_inverse=True)
        rank = np.empty(len(first), np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        return np.sort(first), rank[inverse.reshape(-1)]
    order = np.lexsort(keys.T[::-1])
    k = keys[order]
    new = np.ones(len(k), bool)
    new[1:] = (k[1:] != k[:-1]).any(axis=1)
    firsts = order[new]
    rank = np.empty(len(firsts), np.int64)
    rank[np.argsort(firsts, kind="stable")] = np.arange(len(firsts))
    group = np.empty(len(k), np.int64)
    group[order] = rank[np.cumsum(new) - 1]
    return np.sort(firsts), group


def _packed(keys: np.ndarray) -> np.ndarray | None:
    """Each integer row as one int64, distinct rows as distinct numbers (each column's offset from
    its least value in a mixed radix of the columns' spans); None for float rows, no rows, or
    spans whose product does not fit."""
    if keys.dtype.kind not in "iu" or not len(keys):
        return None
    lo, hi = keys.min(axis=0), keys.max(axis=0)
    spans = [int(h) - int(l) + 1 for l, h in zip(lo.tolist(), hi.tolist())]
    if math.prod(spans) >= 1 << 62:
        return None
    packed = np.zeros(len(keys), np.int64)
    for j, span in enumerate(spans):
        packed = packed * span + (keys[:, j] - lo[j])
    return packed


def _axis_groups(axes: np.ndarray) -> list[np.ndarray]:
    """Target indices grouped by axis (rounded to 1e-9), groups in order of first occurrence."""
    if len(axes) == 0:
        return []
    _, group = _first_rows(np.round(axes, 9))
    return [np.flatnonzero(group == g) for g in range(int(group.max()) + 1)]


def attachment_arrays(structure: Structure, part: Part) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and translations (n, 3) of the feasible attachments (module docstring).

    Every plan (a part connector and the free targets it can take) of one family (sockets on free
    studs, studs into free sockets) shares the family's targets, so their axis groups are found
    once per family, and each (connector axis, target axis, turn) rotation once per call; the
    translations of all plans with one connector axis come in one array operation."""
    stud_busy, sock_busy = structure.occupied()
    sp, sa, _ = structure.studs
    kp, ka, _ = structure.sockets
    families = [(part.sockets, sp[~stud_busy], sa[~stud_busy], 0),
                (part.studs, kp[~sock_busy], ka[~sock_busy], len(part.sockets))]
    rot_ids: dict[tuple, int] = {}  # symmetry-aware rotation key -> id
    turned: dict[tuple, tuple[int, int]] = {}  # (connector axis, target axis, turn) -> (rotation, key id)
    rots: list[np.ndarray] = []
    chunks_order, chunks_rot, chunks_t, chunks_key = [], [], [], []
    for connectors, targets, axes, first_plan in families:
        if len(targets) == 0 or not connectors:
            continue
        groups = _axis_groups(axes)
        by_axis: dict[tuple, list[int]] = {}  # connector axis -> plan numbers in this family
        for i, c in enumerate(connectors):
            by_axis.setdefault(tuple(float(v) for v in c.axis), []).append(i)
        for b_key, members in by_axis.items():
            b = np.array(b_key)
            q = np.array([connectors[i].pos for i in members], dtype=float)  # (m, 3)
            plan = first_plan + np.array(members)
            for idx in groups:
                a = axes[idx[0]]
                base = align(b, a)
                vertical = np.allclose(a, [0, -1, 0]) or np.allclose(a, [0, 1, 0])
                n, m = len(idx), len(members)
                for k in range(4):
                    slot = (b_key, tuple(a.tolist()), k)
                    if slot not in turned:
                        twist = _TURNS[k] if vertical else rotation_about(a, 90.0 * k)
                        r = np.round(twist @ base, 12)
                        rots.append(r)
                        turned[slot] = (len(rots) - 1, rot_ids.setdefault(_rotation_key(part, r), len(rot_ids)))
                    ri, rid = turned[slot]
                    r = rots[ri]
                    t = targets[idx][None, :, :] - (q @ r.T)[:, None, :]  # (m, n, 3)
                    chunks_order.append(np.stack([np.repeat(plan, n), np.tile(idx, m), np.full(n * m, k)], axis=1))
                    chunks_rot.append(np.full(n * m, ri))
                    chunks_t.append(t.reshape(-1, 3))
                    chunks_key.append(np.full(n * m, rid))
    if not chunks_t:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    order = np.concatenate(chunks_order)
    rot_index = np.concatenate(chunks_rot)
    t = np.concatenate(chunks_t)
    rid = np.concatenate(chunks_key)
    # Order: plan (connector), target, turn.
    # (One stable sort of the rows packed into one number gives lexsort's order.)
    packed = _packed(order)
    perm = np.argsort(packed, kind="stable") if packed is not None else np.lexsort(order.T[::-1])
    rot_index, t, rid = rot_index[perm], t[perm], rid[perm]
    tkey = _translation_key(t)
    keys = np.concatenate([rid[:, None].astype(np.int64), tkey], axis=1)
    first, _ = _first_rows(keys)
    return np.stack(rots)[rot_index[first]], t[first]


def feasible_poses(structure: Structure, part: Part) -> list[Pose]:
    """Every feasible attachment of `part` on `structure`, as poses."""
    r, t = attachment_arrays(structure, part)
    return [Pose(ri, ti) for ri, ti in zip(r, t)]


def lowest_y(part: Part, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The lowest point (largest LDraw y) of the part's bounding box at each pose (n,)."""
    ys = np.einsum("nj,kj->nk", r[:, 1, :], box_corners(part.bbox)) + t[:, 1:2]
    return ys.max(axis=1)
