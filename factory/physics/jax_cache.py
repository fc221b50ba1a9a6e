"""JAX's persistent compilation cache, in the factory's cache folder (`factory.cache`).

The batched checks compile one kernel per padded shape (`pair_kernels`, `lp_jax`); a run meets tens
of them, each 0.3-2 s to compile, and every grower process and every run met them again. With the
cache each shape compiles once per machine: later processes load it. `JAX_COMPILATION_CACHE_DIR`,
when set, wins (JAX reads it itself)."""

from __future__ import annotations

import os
from functools import cache

from factory import gpus
from factory.cache import cache_root

MIN_COMPILE_SECONDS = 0.1
"""Kernels that compile faster than this are not written (loading costs about as much)."""


@cache
def enable() -> str:
    """Point JAX at the cache (once per process, before the first compile); returns the folder.
    A numbered worker also takes its share of the GPUs here (`factory.gpus`)."""
    import jax  # optional: the [jax] extra; the 'cpu' backend needs none

    gpus.choose_jax_device(jax)
    path = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(cache_root() / "jax")
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
