"""Axis-aligned ray casts against a part's triangles (`_RayGrid`): whether a ray along an axis
from each point meets one of them, for the faithfulness test of its collision pieces (`faithful`)."""

from __future__ import annotations

import numpy as np

_BUCKET_LDU = 4.0
"""Cell size of the grid that sorts triangles for the axis-aligned ray casts."""
MAX_GRID_ENTRIES = 1 << 22
"""Most (triangle, cell) entries of a `_RayGrid` (a 32x32 baseplate's top alone covers 25,600
cells of 4 LDU)."""


class _RayGrid:
    """The triangles of a part sorted for axis-aligned ray casts along one axis.

    A ray along the axis can only meet a triangle whose shadow on the plane across the axis holds
    the ray's origin, so each triangle is listed under every cell (`_BUCKET_LDU` square) of that
    plane its shadow's bounding box touches, once for all the casts of a part: a point is tested
    against the triangles of its own cell only. (Scanning every triangle for each cell of each
    cast took 111 of the 198 s that LDraw's boat hull 2560 took to prepare.)"""

    def __init__(self, tris: np.ndarray, axis: int):
        self.axis = axis
        self.a, self.b = [k for k in range(3) if k != axis]
        t2 = tris[:, :, [self.a, self.b]]
        # Signed doubled area in the plane: triangles seen edge-on cannot be met.
        area = ((t2[:, 1, 0] - t2[:, 0, 0]) * (t2[:, 2, 1] - t2[:, 0, 1])
                - (t2[:, 2, 0] - t2[:, 0, 0]) * (t2[:, 1, 1] - t2[:, 0, 1]))
        keep = np.abs(area) > 1e-9
        self.t2, self.t3, self.area = t2[keep], tris[keep], area[keep]
        self.origin = self.t2.reshape(-1, 2).min(0) if len(self.t2) else np.zeros(2)
        # Cells grow where the list would pass `MAX_GRID_ENTRIES` (triangles hundreds of LDU
        # across, as hostile input may draw): more triangles a cell, the same answers.
        self.cell = _BUCKET_LDU
        while True:
            lo = np.floor((self.t2.min(1) - self.origin) / self.cell).astype(np.int64)
            hi = np.floor((self.t2.max(1) - self.origin) / self.cell).astype(np.int64)
            nb = hi[:, 1] - lo[:, 1] + 1
            n = (hi[:, 0] - lo[:, 0] + 1) * nb
            if n.sum() <= MAX_GRID_ENTRIES:
                break
            self.cell *= 2
        tri = np.repeat(np.arange(len(n)), n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        ca = lo[tri, 0] + k // nb[tri]
        cb = lo[tri, 1] + k % nb[tri]
        keys = self._key(ca, cb)
        order = np.argsort(keys, kind="stable")
        self.keys, self.tris = keys[order], tri[order]

    @staticmethod
    def _key(ca: np.ndarray, cb: np.ndarray) -> np.ndarray:
        return ca * (1 << 32) + cb  # cells are a few thousand across at most: no collisions

    def blocked(self, points: np.ndarray, sign: float) -> np.ndarray:
        """For each point, whether a ray along +-axis (`sign`) from it meets one of the triangles."""
        ahead, behind = self._both(points)
        return ahead if sign > 0 else behind

    def enclosed(self, points: np.ndarray) -> np.ndarray:
        """For each point, whether rays along the axis both ways from it meet triangles."""
        ahead, behind = self._both(points)
        return ahead & behind

    def _both(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`blocked` along +axis and along -axis."""
        if not len(points) or not len(self.keys):
            return np.zeros(len(points), bool), np.zeros(len(points), bool)
        # Points of one line along the axis (a grid's column) share their shadow, so the triangles
        # over it are tested once per line: a ray from a point meets one exactly when the farthest
        # crossing ahead lies past the point (rounding keeps the order: the same answers). (The
        # pair viewed as one complex number sorts several times faster than as rows.)
        pairs = np.ascontiguousarray(points[:, [self.a, self.b]]).view(np.complex128).ravel()
        lines, inverse = np.unique(pairs, return_inverse=True)
        low, high = self._crossings(np.stack([lines.real, lines.imag], axis=1))
        along = points[:, self.axis]
        inverse = inverse.ravel()
        return high[inverse] - along > 1e-6, -(low[inverse] - along) > 1e-6

    def _crossings(self, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each point of the plane across the axis, the nearest and farthest coordinate along
        the axis where its line crosses a triangle (+inf, -inf where it crosses none)."""
        low = np.full(len(p2), np.inf)
        high = np.full(len(p2), -np.inf)
        cell = np.floor((p2 - self.origin) / self.cell).astype(np.int64)
        keys, inverse = np.unique(self._key(cell[:, 0], cell[:, 1]), return_inverse=True)
        inverse = inverse.ravel()
        starts = np.searchsorted(self.keys, keys, side="left")
        stops = np.searchsorted(self.keys, keys, side="right")
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(len(keys) + 1))
        axis, t2, t3, area = self.axis, self.t2, self.t3, self.area
        for c in range(len(keys)):
            if starts[c] == stops[c]:
                continue
            near = self.tris[starts[c]:stops[c]]
            idx = order[bounds[c]:bounds[c + 1]]
            q = p2[idx][:, None, :]  # (points, 1, 2)
            v0, v1, v2 = t2[near, 0][None], t2[near, 1][None], t2[near, 2][None]
            # Barycentric coordinates of each point in each triangle's shadow.
            w1 = ((q[..., 0] - v0[..., 0]) * (v2[..., 1] - v0[..., 1])
                  - (v2[..., 0] - v0[..., 0]) * (q[..., 1] - v0[..., 1])) / area[near][None]
            w2 = ((v1[..., 0] - v0[..., 0]) * (q[..., 1] - v0[..., 1])
                  - (q[..., 0] - v0[..., 0]) * (v1[..., 1] - v0[..., 1])) / area[near][None]
            w0 = 1.0 - w1 - w2
            inside = (w0 >= -1e-7) & (w1 >= -1e-7) & (w2 >= -1e-7)
            depth = (w0 * t3[near, 0, axis][None] + w1 * t3[near, 1, axis][None]
                     + w2 * t3[near, 2, axis][None])
            low[idx] = np.where(inside, depth, np.inf).min(axis=1)
            high[idx] = np.where(inside, depth, -np.inf).max(axis=1)
        return low, high
