"""The batched checks' kernels through their exports (`factory.physics.jax_export`): the results of
the kernels called directly, a later process loading the file instead of tracing, a bad file
exported again, changed source never loading an old export."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("flatbuffers")

from factory.cache import source_digest  # noqa: E402
from factory.physics import jax_export, lp_jax  # noqa: E402
from test_lp_jax import random_lp  # noqa: E402


@pytest.fixture
def exports(tmp_path, monkeypatch):
    """An empty export folder, and this process's loaded kernels forgotten before and after."""
    monkeypatch.setenv("BRICK_FACTORY_JAX_EXPORT_DIR", str(tmp_path / "exports"))
    jax_export._LOADED.clear()
    yield tmp_path / "exports"
    jax_export._LOADED.clear()


def _programs(n=6, seed=0):
    rng = np.random.default_rng(seed)
    return [random_lp(rng) for _ in range(n)]


def _solve(lps, monkeypatch, direct: bool):
    with monkeypatch.context() as m:
        if direct:
            m.setattr(jax_export, "_available", lambda: False)
        return lp_jax.solve_batch(lps, fallback=False)


def test_exported_solver_gives_the_direct_kernels_results_and_a_later_process_loads_it(exports, monkeypatch):
    lps = _programs()
    direct = _solve(lps, monkeypatch, direct=True)
    made, loaded = list(jax_export.EXPORTS)
    first = _solve(lps, monkeypatch, direct=False)
    assert jax_export.EXPORTS[0] == made + 1 and jax_export.EXPORTS[1] == loaded  # exported here, once
    files = sorted(exports.glob("lp-*.jaxexport"))
    assert len(files) == 1
    for a, b in zip(direct, first):
        assert a.status == b.status == "optimal" and np.array_equal(a.x, b.x)

    # A later process: nothing loaded yet, the file there; it must not trace (export) again.
    jax_export._LOADED.clear()

    def no_export(*_, **__):
        raise AssertionError("exported again though the file was there")

    monkeypatch.setattr("jax.export.export", no_export)
    again = _solve(lps, monkeypatch, direct=False)
    assert jax_export.EXPORTS[1] == loaded + 1
    for a, b in zip(direct, again):
        assert np.array_equal(a.x, b.x)


def test_a_bad_export_file_is_exported_again(exports, monkeypatch):
    lps = _programs(3, seed=1)
    want = _solve(lps, monkeypatch, direct=False)
    (path,) = exports.glob("lp-*.jaxexport")
    path.write_bytes(path.read_bytes()[:100])  # cut short, as by a full disk
    jax_export._LOADED.clear()
    made = jax_export.EXPORTS[0]
    with pytest.warns(UserWarning, match="not a readable export"):
        got = _solve(lps, monkeypatch, direct=False)
    assert jax_export.EXPORTS[0] == made + 1 and path.stat().st_size > 100
    assert all(np.array_equal(a.x, b.x) for a, b in zip(want, got))


def test_changed_source_or_shape_names_another_export(exports, tmp_path):
    src = tmp_path / "kernel.py"
    src.write_text("x = 1\n")
    key = ("lp", "tree", ((("8", "256"), "float64"),), True)
    one = jax_export._digest(key, str(src))
    assert jax_export._digest(key, str(src)) == one
    assert jax_export._digest((*key[:2], ((("16", "256"), "float64"),), True), str(src)) != one
    src.write_text("x = 2\n")
    source_digest.cache_clear()  # a file is read once per process; a new process reads it anew
    assert jax_export._digest(key, str(src)) != one


def _first_launch(barrier) -> list[int]:
    """In a new process: wait for the other, then launch the solver on programs of a shape neither
    has met; this process's (exported, loaded) counts."""
    lps = _programs(4, seed=7)
    barrier.wait()
    assert all(r.status == "optimal" for r in lp_jax.solve_batch(lps, fallback=False))
    return list(jax_export.EXPORTS)


@pytest.mark.slow
def test_processes_meeting_a_new_shape_at_once_export_it_once(exports, tmp_path, monkeypatch):
    """Two processes launch the same new shape at the same moment: one exports and compiles it, the
    other waits on its lock and then reads the export (without the lock both would export it)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "jax"))
    spawn = multiprocessing.get_context("spawn")
    with spawn.Manager() as manager, ProcessPoolExecutor(2, mp_context=spawn) as pool:
        barrier = manager.Barrier(2, timeout=600)
        counts = list(pool.map(_first_launch, [barrier, barrier]))
    assert sorted(counts) == [[0, 1], [1, 0]], counts
    assert len(list(exports.glob("lp-*.jaxexport"))) == 1
