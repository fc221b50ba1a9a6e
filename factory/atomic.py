"""Atomic file writes: a reader sees the old file or the whole new one, never a part.

Whole files (dataset metadata, gallery, sampled models, reports, training summaries) go through
`write_atomic`; streamed ones are written to a temporary name and renamed where they are made.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path


def umask() -> int:
    """The process's file mode creation mask (read without changing it where Linux says it)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    old = os.umask(0o022)  # elsewhere: set and restore (not thread-safe, hence the above first)
    os.umask(old)
    return old


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a uniquely named temporary file in the same folder, fsynced,
    then `os.replace`; the temporary file is removed if anything fails. The file gets the mode a
    plain `open` would give (0666 less the umask), not `mkstemp`'s 0600, so teammates and workers
    under another uid can read the outputs."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~umask())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_figure(fig, path: str | os.PathLike, **savefig) -> None:
    """A matplotlib figure saved to `path` through `write_atomic` (format from the file's suffix)."""
    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", **savefig)
    write_atomic(path, buf.getvalue())
