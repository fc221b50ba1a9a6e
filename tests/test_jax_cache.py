"""Where the JAX compilation cache lives (`factory.physics.jax_cache.cache_folder`)."""

from __future__ import annotations

from types import SimpleNamespace

from factory.physics import jax_cache


def test_workers_of_different_gpus_keep_separate_compilation_caches(monkeypatch, tmp_path):
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path))
    # A kernel stored by a worker of GPU 1 names device id 1; a worker of GPU 0 must not load it.
    gpu0, gpu1 = (jax_cache.cache_folder(SimpleNamespace(id=k)) for k in (0, 1))
    assert gpu0 != gpu1 and gpu0.startswith(str(tmp_path)) and gpu1.startswith(str(tmp_path))
    # One GPU, or none chosen (a process outside a pool): the folder itself.
    assert jax_cache.cache_folder(None) == str(tmp_path)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR")
    assert jax_cache.cache_folder(None).endswith("jax")
