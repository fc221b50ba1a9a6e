"""Where the factory keeps what it computes once per machine: `$BRICK_FACTORY_CACHE`, else
`~/.cache/brick-factory` (convex decompositions under `coacd/`, sockets under `sockets/`, outline
segments under `outlines/`, JAX's compiled kernels under `jax/`)."""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path
from typing import Callable, TypeVar

from factory.atomic import write_atomic

T = TypeVar("T")


def cache_root() -> Path:
    """The cache folder (not created here)."""
    root = os.environ.get("BRICK_FACTORY_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "brick-factory")
    return Path(root)


def source_digest(path: str | os.PathLike) -> str:
    """A source file's sha256: part of the keys of what that file computes, so that a change to
    the code never reuses an older answer."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


_UNWRITABLE: set[str] = set()
"""Cache folders this process could not write to (said once each)."""


def kept(folder: str, name: str, read: Callable[[bytes], T | None], make: Callable[[], T],
         write: Callable[[T], bytes]) -> T:
    """The entry `name` of `folder` in the cache folder, `read` from its bytes; when it is missing
    or `read` refuses it (None: damaged, truncated or foreign), `make()`, kept as `write(value)`
    (atomically: two processes writing one entry leave one whole file). A folder that cannot be
    written is worked without, said once on stderr."""
    path = cache_root() / folder / name
    try:
        value = read(path.read_bytes())
    except OSError:  # missing or unreadable
        value = None
    if value is not None:
        return value
    value = make()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, write(value))
    except OSError as exc:
        if str(path.parent) not in _UNWRITABLE:
            _UNWRITABLE.add(str(path.parent))
            print(f"warning: cannot write the cache folder {path.parent} ({exc.strerror or exc}); working "
                  "without it (set BRICK_FACTORY_CACHE to a writable folder)", file=sys.stderr)
    return value
