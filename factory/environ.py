"""Environment variables set for a block of work and put back after it (`kept`)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager


@contextmanager
def kept(keys: Iterable[str]) -> Iterator[None]:
    """The variables `keys` as they were before the block, after it: set again to their values,
    or unset where they were not set. The processes started inside the block see what it sets."""
    before = {k: os.environ.get(k) for k in keys}
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
