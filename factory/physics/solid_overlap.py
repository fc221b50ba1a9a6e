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

A grid measures to within about a pitch either way, where the pieces' depth is exact. So the same
grid also measures the overlap of the two parts' pieces (grown back by their insets), and the
parts' depth is the pieces' exact depth less what the pieces reach past the solids on that grid
(`solid_depth`, `corrected`): where the pieces are the part (a box-like part, cut along its own
faces) both grid measures agree and the pieces' depth stands, so a real overlap just past the
tolerance is never cleared by the grid's rounding.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import ConvexHull

from factory.parts import Part
from factory.physics.check_state import current
from factory.physics.geometry import INSET_LDU, collision_shape
from factory.physics.structure import MATCH_LDU
from factory.physics.ray_grid import _RayGrid
from factory.pose import Pose

PITCH_LDU = 0.25
"""The grid the solids are sampled on (half the collision tolerance): an overlap's thickness is
measured to within about a pitch either way (`corrected` says why that is enough)."""

REFINE_LDU = 2.0
"""Overlaps of the pieces up to this deep are measured again in the solids: past the faithfulness
test's sample spacing (1.5 LDU) and the pieces' insets, the overlap is the parts'."""

MAX_POINTS = 2_000_000
"""Most grid points one measure spans (32 MB of points; a 2x4 brick on another, its studs counted,
spans 1.05 million); a larger one is left to the pieces."""

_AXES = (1, 0, 2)
"""Vertical first: a point in a socket's hollow, open below, is out after one axis."""


def _grids(part: Part) -> tuple[tuple[_RayGrid, _RayGrid, _RayGrid], list[np.ndarray], list[np.ndarray]]:
    """The part's triangles sorted for ray casts along each axis of its frame, and the face planes
    of its body pieces and of its stud pieces (each (k, 4), its frame), kept per part."""
    def build():
        shape = collision_shape(part)

        def faces(pieces, grown):
            # Each piece's planes, moved out by its inset, and its box grown as much.
            return [(eq - np.r_[0.0, 0.0, 0.0, grown], v.min(0) - grown, v.max(0) + grown)
                    for v, eq in ((v, ConvexHull(v).equations) for v in pieces)]

        return (tuple(_RayGrid(part.flat.triangles, a) for a in range(3)),
                faces(shape.body, shape.body_inset), faces(shape.studs, INSET_LDU))
    return current().solids.get(id(part), part, build)


def inside(part: Part, local: np.ndarray) -> np.ndarray:
    """Whether each point (in the part's frame) is inside its solid: closed on all six sides."""
    grids = _grids(part)[0]
    out = np.ones(len(local), bool)
    for axis in _AXES:
        if not out.any():
            break
        out[out] = grids[axis].enclosed(local[out])
    return out


def in_pieces(part: Part, pose: Pose, local: np.ndarray, mated: np.ndarray) -> np.ndarray:
    """Whether each point (in the part's frame) is inside one of its pieces grown back by its inset
    (studs whose bases are at `mated`, world points, left out)."""
    _, body, studs = _grids(part)
    free = [f for f, keep in zip(studs, _free_studs(part, pose, mated)) if keep]
    out = np.zeros(len(local), bool)
    if not len(local):
        return out
    top, bottom = local.max(0), local.min(0)
    # Sorted along x once, each piece's box takes its slice of the points by two binary searches,
    # not a pass over all of them (a part has hundreds of pieces with its studs).
    order = np.argsort(local[:, 0], kind="stable")
    xs = local[order, 0]
    for planes, lo, hi in body + free:
        if np.any(lo > top) or np.any(hi < bottom):
            continue
        rows = np.sort(order[np.searchsorted(xs, lo[0], "left"):np.searchsorted(xs, hi[0], "right")])
        rows = rows[~out[rows]]
        rows = rows[np.all((local[rows, 1:] >= lo[1:]) & (local[rows, 1:] <= hi[1:]), axis=1)]
        if len(rows):
            out[rows] = (local[rows] @ planes[:, :3].T + planes[:, 3]).max(axis=1) <= 0.0
    return out


def _free_studs(part: Part, pose: Pose, mated: np.ndarray) -> np.ndarray:
    """Per stud piece of the part placed at `pose`: whether it is not in a socket (its base not at
    one of `mated`, world points). A stud in a socket is the connection's, as for the pieces."""
    at = np.array([a for a, _ in collision_shape(part).stud_at], float).reshape(-1, 3)
    if not len(mated) or not len(at):
        return np.ones(len(at), bool)
    base = pose.apply(at)
    return np.linalg.norm(base[:, None] - mated[None], axis=2).min(axis=1) > MATCH_LDU


def _piece_boxes(part: Part, pose: Pose, mated: np.ndarray) -> np.ndarray:
    """(n, 2, 3) world boxes of the part's body pieces and of its studs not in a socket
    (`_free_studs`), grown by their inset and a pitch (the solid reaches that far past an inset
    piece)."""
    shape = collision_shape(part)
    boxes = []
    for verts in shape.body:
        world = pose.apply(verts)
        boxes.append((world.min(0) - shape.body_inset - PITCH_LDU, world.max(0) + shape.body_inset + PITCH_LDU))
    for verts, keep in zip(shape.studs, _free_studs(part, pose, mated)):
        if not keep:
            continue
        world = pose.apply(verts)
        boxes.append((world.min(0) - INSET_LDU - PITCH_LDU, world.max(0) + INSET_LDU + PITCH_LDU))
    return np.array(boxes, float).reshape(-1, 2, 3)


def _thickness(cells: np.ndarray) -> float:
    """Twice the deepest of `cells` (grid indices) from the rest, less a cell, in LDU (0: none)."""
    if not len(cells):
        return 0.0
    c = cells - cells.min(0) + 1  # the cells' own box, a cell of margin round it
    grid = np.zeros(tuple(c.max(0) + 2), bool)
    grid[c[:, 0], c[:, 1], c[:, 2]] = True
    return (2.0 * float(distance_transform_edt(grid).max()) - 1.0) * PITCH_LDU


def solid_depth(a: Part, a_pose: Pose, b: Part, b_pose: Pose, mated=()) -> tuple[float, float] | None:
    """How deep part `a` and part `b`, placed, overlap on the grid where their pieces meet, (in their
    solids, in their pieces grown back by their insets), LDU, 0 where they do not; studs whose bases
    are in `mated` ((k, 3) world points: studs in sockets) left out; None where that spans more than
    `MAX_POINTS` grid points."""
    mated = np.asarray(mated, float).reshape(-1, 3)
    ba, bb = _piece_boxes(a, a_pose, mated), _piece_boxes(b, b_pose, mated)
    if not len(ba) or not len(bb):
        return 0.0, 0.0
    lo = np.maximum(ba[:, None, 0], bb[None, :, 0])
    hi = np.minimum(ba[:, None, 1], bb[None, :, 1])
    meet = np.all(hi > lo, axis=2)
    if not meet.any():
        return 0.0, 0.0
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
    la, lb = (points - a_pose.t) @ a_pose.R, (points - b_pose.t) @ b_pose.R
    pieces = in_pieces(a, a_pose, la, mated)
    pieces[pieces] = in_pieces(b, b_pose, lb[pieces], mated)
    solids = inside(a, la)
    solids[solids] = inside(b, lb[solids])
    return _thickness(cells[solids]), _thickness(cells[pieces])


def corrected(pieces_depth: float, measured: tuple[float, float]) -> float:
    """The parts' depth: the pieces' exact depth less what the pieces reach past the solids on the
    grid (`solid_depth`'s two measures), never below the solids' own measure (or the pieces')."""
    solid, grown = measured
    return max(min(solid, pieces_depth), pieces_depth - max(0.0, grown - solid))


def deepest_solid(unit, others, depths, tol: float, mated=()) -> float | None:
    """The parts' depth (`corrected`) of the parts of `unit` ((part, pose) pairs) with each of
    `others` ((part, pose) pairs), given the pieces' depth with each of `others` (`depths`), studs at
    `mated` left out. A part the pieces put within `tol` keeps that depth (the parts' is never
    deeper than the pieces' where they are faithful, and within it nothing is decided); past `tol`
    the search ends (that depth is returned). None where an overlap is too large to measure."""
    depths = list(depths)
    deepest = max([d for d in depths if d <= tol], default=0.0)
    for (b, b_pose), pieces_depth in zip(others, depths):
        if pieces_depth <= tol:
            continue
        solid = grown = 0.0
        for a, a_pose in unit:
            m = solid_depth(a, a_pose, b, b_pose, mated)
            if m is None:
                return None
            solid, grown = max(solid, m[0]), max(grown, m[1])
        deepest = max(deepest, corrected(pieces_depth, (solid, grown)))
        if deepest > tol:
            return deepest
    return deepest
