"""A decomposition refused once (past its time or memory limit) is not tried again under the same
limits."""

from __future__ import annotations

import pytest


def test_a_refused_decomposition_is_kept_and_not_tried_again_under_the_same_limits(monkeypatch, tmp_path):
    """A part whose decomposition ran past its limit (LDraw's 2573 took more than 300 s here) cost
    that time again in every process that met it, and stopped a run of the prior's parts; the
    refusal is kept in the cache and given at once, until a wider limit is set."""
    from factory.errors import LDrawLimitError
    from factory.ldraw import Library, Reader
    from factory.parts import load_part
    from factory.physics import geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.05")
    monkeypatch.setattr(geometry, "_faithful_pieces", lambda part, cfg: None)  # the way to coacd
    part = lambda: load_part(Reader(Library.embedded()), "3001")  # noqa: E731 (a fresh part: nothing in memory)
    with pytest.raises(LDrawLimitError, match="more than 0.05 s") as first:
        geometry.collision_shape(part())
    assert "refused before" not in str(first.value)
    run = geometry.subprocess.run
    monkeypatch.setattr(geometry.subprocess, "run", lambda *a, **k: pytest.fail("a decomposition was started"))
    with pytest.raises(LDrawLimitError, match=r"more than 0.05 s.*\(refused before; kept in the cache\)"):
        geometry.collision_shape(part())
    monkeypatch.setattr(geometry.subprocess, "run", run)
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.1")  # a wider limit tries again
    with pytest.raises(LDrawLimitError, match="more than 0.1 s") as wider:
        geometry.collision_shape(part())
    assert "refused before" not in str(wider.value)
