"""The batched checks' kernels exported once per machine (`jax.export`), so that a process calls a
shape it has not met without tracing it.

The persistent compilation cache (`jax_cache`) spares the XLA compile of a shape a process meets
for the first time, but not the tracing and lowering before it: about 0.37 s of a load program's
first launch of 0.55 s in a fresh process with the cache warm (0.21 s through an export, this
2-core CPU, docs/concepts/batched-checks.md), and a grower process meets tens of shapes. `call(name, fn, *args)`
runs `fn(*args)` through the kernel's export for those argument shapes, read from this folder
when an earlier process wrote it, else exported (traced once) and written; either way the
exported module is compiled through `jax.jit` and the compilation cache. The results are those
of `jax.jit(fn)` (the same module; `tests/test_jax_export.py`).

A process's first launch of a shape holds a lock on that shape's file (`fcntl`, beside it) while it
exports or reads it and compiles it, so processes that meet a new shape at once (lockstep growers
on a fresh machine: 16 of them compiled 133 kernels inside one H100 row, 2026-11-26) export and
compile it once; the others wait, read the export and load the kernel from the compilation cache.

A file is named by the kernel, the argument shapes and dtypes, the platform, the JAX and jaxlib
versions and a digest of the kernel's source file, so changed code never loads an old export. A
file that does not load is exported again. Without the `flatbuffers` package (JAX's
serialisation needs it; the [jax] extra installs it) kernels are called directly, as before.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import warnings
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

from factory.atomic import write_atomic
from factory.cache import cache_root, source_digest

FOLDER = "jax-export"
"""Sub-folder of the factory's cache folder (`factory.cache`) holding the exports."""

_LOADED: dict[tuple, object] = {}
"""This process's jitted exported kernels, by (name, argument shapes and dtypes, x64)."""

EXPORTS: list[int] = [0, 0]
"""This process's kernels (exported here, loaded from a file)."""


def folder() -> Path:
    """Where the exports are (`BRICK_FACTORY_JAX_EXPORT_DIR` wins, as `JAX_COMPILATION_CACHE_DIR`
    does for the compilation cache)."""
    return Path(os.environ.get("BRICK_FACTORY_JAX_EXPORT_DIR") or cache_root() / FOLDER)


def call(name: str, fn, *args, source: str):
    """`fn(*args)` through its export for these argument shapes (`fn` traceable by `jax.jit`;
    arguments arrays, NumPy scalars, or tuples of them); `source`: the file that defines the
    kernel (its digest names the export). `fn` is called directly when exports are not available."""
    import jax  # optional: the [jax] extra

    if not _available():
        return fn(*args)
    leaves, tree = jax.tree_util.tree_flatten(args)
    specs = tuple((tuple(np.shape(a)), str(_dtype(a))) for a in leaves)
    key = (name, str(tree), specs, bool(jax.config.jax_enable_x64))
    kernel = _LOADED.get(key)
    if kernel is not None:
        return kernel(*args)
    path = folder() / f"{name}-{_digest(key, source)}.jaxexport"
    # A process's first launch of a shape exports it (or reads its export) and compiles it. Many
    # processes meeting a new shape at once (lockstep growers, each a round behind the other) would
    # each do both; under a lock per shape one does, and the others then read its export and load
    # its compiled kernel from the compilation cache.
    with _first_use(path):
        kernel = jax.jit(_exported(fn, args, path).call)
        out = kernel(*args)  # compiled here, inside the lock
    _LOADED[key] = kernel
    return out


@contextmanager
def _first_use(path: Path):
    """An exclusive lock on `path`'s lock file while this process exports or loads it and compiles
    it (released when the process dies, too)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _exported(fn, args, path: Path):
    """The export of `fn` at `args`' shapes: from its file (`path`), else made and written."""
    import jax
    from jax import export

    if path.is_file():
        try:
            exp = export.deserialize(bytearray(path.read_bytes()))
            EXPORTS[1] += 1
            return exp
        except Exception as e:  # a file cut short, or from a JAX that reads it differently
            warnings.warn(f"{path}: not a readable export ({type(e).__name__}: {e}); exporting it again",
                          stacklevel=3)
    structs = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(np.shape(a), _dtype(a)), args)
    exp = export.export(fn if hasattr(fn, "lower") else jax.jit(fn))(*structs)
    EXPORTS[0] += 1
    write_atomic(path, bytes(exp.serialize()))
    return exp


def _dtype(a):
    """An argument's dtype without copying a device array to the host."""
    dtype = getattr(a, "dtype", None)
    return dtype if dtype is not None else np.result_type(a)


def _digest(key: tuple, source: str) -> str:
    import jax
    import jaxlib

    text = repr((key, jax.__version__, jaxlib.__version__, jax.default_backend(), source_digest(source)))
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@cache
def _available() -> bool:
    try:
        import flatbuffers  # noqa: F401  (JAX's export serialisation imports it)
    except ModuleNotFoundError:
        warnings.warn("flatbuffers is not installed: the batched checks' kernels are traced in every "
                      "process (pip install -e '.[jax]' installs it)", stacklevel=3)
        return False
    return True
