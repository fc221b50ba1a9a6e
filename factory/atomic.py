"""Atomic file writes: a reader sees the old file or the whole new one, never a part.

Whole files (dataset metadata, gallery, sampled models, reports, training summaries) go through
`write_atomic`; streamed ones are written to a temporary name and renamed where they are made.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a uniquely named temporary file in the same folder, fsynced,
    then `os.replace`; the temporary file is removed if anything fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
