"""The batched checks' kernels exported once per machine (`jax.export`), so that a process calls a
shape it has not met without tracing it.

The persistent compilation cache (`jax_cache`) spares the XLA compile of a shape a process meets
for the first time, but not the tracing and lowering before it: about 0.37 s of a load program's
first launch of 0.55 s in a fresh process with the cache warm (0.21 s through an export, this
2-core CPU, docs/sampler.md), and a grower process meets tens of shapes. `call(name, fn, *args)`
runs `fn(*args)` through the kernel's export for those argument shapes, read from this folder
when an earlier process wrote it, else exported (traced once) and written; either way the
exported module is compiled through `jax.jit` and the compilation cache. The results are those
of `jax.jit(fn)` (the same module; `tests/test_jax_export.py`).

A file is named by the kernel, the argument shapes and dtypes, the platform, the JAX and jaxlib
versions and a digest of the kernel's source file, so changed code never loads an old export. A
file that does not load is exported again. Without the `flatbuffers` package (JAX's
serialisation needs it; the [mjx] extra installs it) kernels are called directly, as before.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from functools import cache
from pathlib import Path

import numpy as np

from factory.atomic import write_atomic
from factory.cache import cache_root

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
    import jax  # optional: the [mjx] extra

    if not _available():
        return fn(*args)
    leaves, tree = jax.tree_util.tree_flatten(args)
    specs = tuple((tuple(np.shape(a)), str(_dtype(a))) for a in leaves)
    key = (name, str(tree), specs, bool(jax.config.jax_enable_x64))
    kernel = _LOADED.get(key)
    if kernel is None:
        kernel = _LOADED[key] = jax.jit(_exported(name, fn, args, key, source).call)
    return kernel(*args)


def _exported(name: str, fn, args, key: tuple, source: str):
    """The export of `fn` at `args`' shapes: from its file, else made and written."""
    import jax
    from jax import export

    path = folder() / f"{name}-{_digest(key, source)}.jaxexport"
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
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, bytes(exp.serialize()))
    return exp


def _dtype(a):
    """An argument's dtype without copying a device array to the host."""
    dtype = getattr(a, "dtype", None)
    return dtype if dtype is not None else np.result_type(a)


def _digest(key: tuple, source: str) -> str:
    import jax
    import jaxlib

    text = repr((key, jax.__version__, jaxlib.__version__, jax.default_backend(), _source_digest(source)))
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@cache
def _source_digest(path: str) -> str:
    """A digest of the kernel's source file. Only that file counts: the kernels exported here call
    nothing of the factory's outside their own file, only JAX."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "no-source"


@cache
def _available() -> bool:
    try:
        import flatbuffers  # noqa: F401  (JAX's export serialisation imports it)
    except ModuleNotFoundError:
        warnings.warn("flatbuffers is not installed: the batched checks' kernels are traced in every "
                      "process (pip install -e '.[mjx]' installs it)", stacklevel=3)
        return False
    return True
