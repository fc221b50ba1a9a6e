"""Where the factory keeps what it computes once per machine: `$BRICK_FACTORY_CACHE`, else
`~/.cache/brick-factory` (convex decompositions under `coacd/`, sockets under `sockets/`, part
symmetries under `symmetry/`, hull points under `hulls/`, outline segments under `outlines/`, JAX's
compiled kernels under `jax/`). `python -m pipelines.parts --pack FILE` hands the part entries to
another machine."""

from __future__ import annotations

import fcntl
import hashlib
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Callable, TypeVar

from factory.atomic import write_atomic

T = TypeVar("T")


def cache_root() -> Path:
    """The cache folder (not created here)."""
    root = os.environ.get("BRICK_FACTORY_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "brick-factory")
    return Path(root)


@cache
def source_digest(path: str) -> str:
    """A source file's sha256 (read once per process; "no-source" where it cannot be read): part
    of the keys of what that file computes, so that a change to the code never reuses an older
    answer."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "no-source"


_UNWRITABLE: set[str] = set()
"""Cache folders this process could not write to (said once each)."""


def kept(folder: str, name: str, read: Callable[[bytes], T | None], make: Callable[[], T],
         write: Callable[[T], bytes]) -> T:
    """The entry `name` of `folder` in the cache folder, `read` from its bytes; when it is missing
    or `read` refuses it (None: damaged, truncated or foreign), `make()`, kept as `write(value)`
    (`keep`)."""
    path = cache_root() / folder / name
    try:
        value = read(path.read_bytes())
    except OSError:  # missing or unreadable
        value = None
    if value is not None:
        return value
    value = make()
    keep(path, write(value))
    return value


def keep(path: Path, data: bytes) -> None:
    """Write a cache entry atomically (two processes writing one entry leave one whole file); a
    folder that cannot be written is worked without, said once on stderr."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, data)
    except OSError as exc:
        if str(path.parent) not in _UNWRITABLE:
            _UNWRITABLE.add(str(path.parent))
            print(f"warning: cannot write the cache folder {path.parent} ({exc.strerror or exc}); working "
                  "without it (set BRICK_FACTORY_CACHE to a writable folder)", file=sys.stderr)


@contextmanager
def made_once(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on `path` (a lock file beside an entry) while an entry is made: a
    second process about to make the same entry waits, then finds it made (a part drawn by two
    workers at once is decomposed once). Where the lock file cannot be made (a read-only cache)
    the entry is made without it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
