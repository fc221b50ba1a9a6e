"""How far two placed parts overlap in their own solids (`solid_depth`): the checks' second look at
an overlap of collision pieces too shallow to tell from a piece reaching past a curved face.

A part's collision pieces are convex hulls checked to hold only the part where sampled (`faithful`:
every 1.5 LDU), so across a curve a hull may reach past the surface by about that much unseen
(a wing on the curved mudguards under it, a chain link round another). The pieces' overlap is
exact between hulls, not between parts. Here the parts' own triangles decide: a point is inside a
part's solid where a ray from it along each of the six axis directions of the part's frame meets
one of its triangles (closed on every side: a socket's hollow or a hollow stud's bore, open on one
side, is not solid, where the pieces fill them). Points on a grid of `PITCH_LDU` where two pieces
of the two parts (grown by their inset and a pitch) meet are tested; the overlap's depth is the
thickness of the points inside both parts, as twice the deepest one's distance from the rest.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt

from factory.parts import Part
from factory.physics.check_state import current
from factory.physics.geometry import INSET_LDU, collision_shape
from factory.physics.structure import MATCH_LDU
from factory.physics.ray_grid import _RayGrid
from factory.pose import Pose

PITCH_LDU = 0.25
"""The grid the solids are sampled on (half the collision tolerance): an overlap is measured to
within a pitch, from below."""

REFINE_LDU = 2.0
"""Overlaps of the pieces up to this deep are measured again in the solids: past the faithfulness
test's sample spacing (1.5 LDU) and the pieces' insets, the overlap is the parts'."""

MAX_POINTS = 4_000_000
"""Most grid points one measure spans (64 MB of flags); a larger overlap is left to the pieces."""

_DIRECTIONS = ((1, 1.0), (1, -1.0), (0, 1.0), (0, -1.0), (2, 1.0), (2, -1.0))
"""Down first: a point in a socket's hollow, open below, is out after one cast."""


def _grids(part: Part) -> tuple[_RayGrid, _RayGrid, _RayGrid]:
    """The part's triangles sorted for ray casts along each axis of its frame, kept per part."""
    return current().solids.get(id(part), part, lambda: tuple(_RayGrid(part.flat.triangles, a) for a in range(3)))


def inside(part: Part, local: np.ndarray) -> np.ndarray:
    """Whether each point (in the part's frame) is inside its solid: closed on all six sides."""
    grids = _grids(part)
    out = np.ones(len(local), bool)
    for axis, sign in _DIRECTIONS:
        if not out.any():
            break
        out[out] = grids[axis].blocked(local[out], sign)
    return out


def _piece_boxes(part: Part, pose: Pose, mated: np.ndarray) -> np.ndarray:
    """(n, 2, 3) world boxes of the part's body pieces and of its studs not in a socket (`mated`:
    world stud bases), grown by their inset and a pitch (the solid reaches that far past an inset
    piece). A stud in a socket is the connection's, as for the pieces (`collide`)."""
    shape = collision_shape(part)
    boxes = []
    for verts in shape.body:
        world = pose.apply(verts)
        boxes.append((world.min(0) - shape.body_inset - PITCH_LDU, world.max(0) + shape.body_inset + PITCH_LDU))
    for verts, (at, _) in zip(shape.studs, shape.stud_at):
        if len(mated) and np.min(np.linalg.norm(mated - pose.apply(np.asarray(at)[None])[0], axis=1)) <= MATCH_LDU:
            continue
        world = pose.apply(verts)
        boxes.append((world.min(0) - INSET_LDU - PITCH_LDU, world.max(0) + INSET_LDU + PITCH_LDU))
    return np.array(boxes, float).reshape(-1, 2, 3)


def solid_depth(a: Part, a_pose: Pose, b: Part, b_pose: Pose, mated=()) -> float | None:
    """How deep part `a` and part `b`, placed, overlap in their solids (LDU, 0 where they do not),
    measured where their pieces meet (leaving out the studs whose bases are in `mated`, (k, 3)
    world points: studs in sockets); None where that spans more than `MAX_POINTS` grid points."""
    mated = np.asarray(mated, float).reshape(-1, 3)
    ba, bb = _piece_boxes(a, a_pose, mated), _piece_boxes(b, b_pose, mated)
    if not len(ba) or not len(bb):
        return 0.0
    lo = np.maximum(ba[:, None, 0], bb[None, :, 0])
    hi = np.minimum(ba[:, None, 1], bb[None, :, 1])
    meet = np.all(hi > lo, axis=2)
    if not meet.any():
        return 0.0
    lo, hi = lo[meet], hi[meet]
    # Cell centres at odd multiples of half a pitch: never on a face at a whole or half LDU.
    origin = np.floor(lo.min(0) / PITCH_LDU) * PITCH_LDU
    shape = np.ceil((hi.max(0) - origin) / PITCH_LDU).astype(np.int64) + 1
    if int(np.prod(shape)) > MAX_POINTS:
        return None
    where = np.zeros(tuple(shape), bool)
    first = np.floor((lo - origin) / PITCH_LDU).astype(np.int64)
    last = np.ceil((hi - origin) / PITCH_LDU).astype(np.int64)
    for f, l in zip(first, last):
        where[f[0]:l[0], f[1]:l[1], f[2]:l[2]] = True
    cells = np.argwhere(where)
    points = origin + (cells + 0.5) * PITCH_LDU
    both = inside(a, (points - a_pose.t) @ a_pose.R)
    both[both] = inside(b, (points[both] - b_pose.t) @ b_pose.R)
    if not both.any():
        return 0.0
    overlap = np.zeros(tuple(shape + 2), bool)
    c = cells[both] + 1
    overlap[c[:, 0], c[:, 1], c[:, 2]] = True
    deepest = float(distance_transform_edt(overlap).max())
    return (2.0 * deepest - 1.0) * PITCH_LDU
