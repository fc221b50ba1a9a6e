"""Reading JSON-lines files that people and other programs write (predictions, result rows): one
object a line, blank lines skipped, the first bad line an error naming `path:line` and what was
expected."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from pathlib import Path


def json_objects(path: Path, error: type[Exception], required: Iterable[str] = (),
                 what: str = "a JSON object") -> Iterator[tuple[str, dict]]:
    """`(where, object)` for each non-blank line of `path` (`where` is `path:line`). A line that is
    not JSON, not an object (`what` says what one line should be), or lacks a key of `required`
    raises `error` naming `where`."""
    required = tuple(required)
    with Path(path).open(encoding="utf-8", errors="replace") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            where = f"{path}:{n}"
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as exc:
                raise error(f"{where}: not JSON ({exc.msg})") from None
            if not isinstance(rec, dict):
                raise error(f"{where}: expected {what}")
            missing = [k for k in required if k not in rec]
            if missing:
                raise error(f"{where}: missing key(s) {', '.join(missing)}")
            yield where, rec
