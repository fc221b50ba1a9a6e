"""The axis-aligned ray casts of the faithfulness test: triangles sorted into cells once per part
give the answers of testing every triangle."""

from __future__ import annotations

import numpy as np

from factory.parts import load_part
from factory.physics import faithful, ray_grid


def _brute(points, tris, axis, sign):
    """Whether a ray along +-axis from each point meets a triangle: every triangle, no cells."""
    a, b = [k for k in range(3) if k != axis]
    hit = np.zeros(len(points), bool)
    for t in tris:
        t2 = t[:, [a, b]]
        area = (t2[1, 0] - t2[0, 0]) * (t2[2, 1] - t2[0, 1]) - (t2[2, 0] - t2[0, 0]) * (t2[1, 1] - t2[0, 1])
        if abs(area) <= 1e-9:
            continue
        q = points[:, [a, b]]
        w1 = ((q[:, 0] - t2[0, 0]) * (t2[2, 1] - t2[0, 1]) - (t2[2, 0] - t2[0, 0]) * (q[:, 1] - t2[0, 1])) / area
        w2 = ((t2[1, 0] - t2[0, 0]) * (q[:, 1] - t2[0, 1]) - (q[:, 0] - t2[0, 0]) * (t2[1, 1] - t2[0, 1])) / area
        w0 = 1 - w1 - w2
        inside = (w0 >= -1e-7) & (w1 >= -1e-7) & (w2 >= -1e-7)
        depth = w0 * t[0, axis] + w1 * t[1, axis] + w2 * t[2, axis]
        hit |= inside & (sign * (depth - points[:, axis]) > 1e-6)
    return hit


def test_rays_cast_through_the_cells_meet_what_every_triangle_would(real_reader):
    """Points in and around a headlight brick, a round brick and a bracket (and far outside the
    part, in cells no triangle covers), cast along each axis both ways."""
    rng = np.random.default_rng(0)
    for name in ("4070", "3062b", "99781"):
        tris = load_part(real_reader, name).flat.triangles
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        points = rng.uniform(lo - 10, hi + 10, size=(3000, 3))
        for axis in range(3):
            grid = ray_grid._RayGrid(tris, axis)
            for sign in (1.0, -1.0):
                got = grid.blocked(points, sign)
                assert np.array_equal(got, _brute(points, tris, axis, sign)), (name, axis, sign)
                assert 0 < got.sum() < len(points)


def test_points_on_a_grid_share_each_lines_crossings_and_get_every_triangles_answer(real_reader):
    """A grid's points lie many to a line along each axis (the solid-overlap measure's grids):
    the crossings found once per line give each point the answer of testing every triangle, on
    the triangles' own coordinates too (points exactly on a face or an edge)."""
    for name in ("3701", "3062b"):
        tris = load_part(real_reader, name).flat.triangles
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        axes = [np.arange(np.floor(l) - 2, h + 2, 1.0) for l, h in zip(lo, hi)]
        grid_points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points = np.concatenate([grid_points + 0.25, grid_points[::7]])  # off and on whole LDU
        for axis in range(3):
            grid = ray_grid._RayGrid(tris, axis)
            lines = len(np.unique(points[:, [k for k in range(3) if k != axis]], axis=0))
            assert lines * 10 < len(points)
            for sign in (1.0, -1.0):
                got = grid.blocked(points, sign)
                assert np.array_equal(got, _brute(points, tris, axis, sign)), (name, axis, sign)
                assert 0 < got.sum() < len(points)


def test_triangles_kilometres_across_keep_the_grid_and_the_samples_bounded():
    """Hostile input may draw a triangle 100,000 LDU across: listed under every 4 LDU cell it
    would take 6e8 entries; the cells grow instead, with the same answers. A hull that large
    holds more sample points than the faithfulness test takes: the part is refused, at once."""
    import pytest

    from factory.errors import LDrawLimitError

    big = np.array([[[-5e4, 0, -5e4], [5e4, 0, -5e4], [0, 0, 5e4]],
                    [[0, -8, 0], [20, -8, 0], [0, -8, 20]]], dtype=np.float64)
    points = np.random.default_rng(1).uniform([-6e4, -20, -6e4], [6e4, 20, 6e4], size=(2000, 3))
    grid = ray_grid._RayGrid(big, 1)
    assert len(grid.keys) <= ray_grid.MAX_GRID_ENTRIES and grid.cell > ray_grid._BUCKET_LDU
    for sign in (1.0, -1.0):
        assert np.array_equal(grid.blocked(points, sign), _brute(points, big, 1, sign))
    test = faithful._Faithfulness(big, 1.5, None)
    with pytest.raises(LDrawLimitError, match="sample points"):
        test.escapes(np.concatenate([big.reshape(-1, 3), [[0, 40, 0]]]))
