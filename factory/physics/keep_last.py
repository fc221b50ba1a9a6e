"""A one-entry cache for work done once per structure or unit but asked for in several calls."""

from __future__ import annotations

from typing import Any, Callable


class KeepLast:
    """The value built for the last key. Keys name objects by `id`, so the objects themselves are
    held (`held`) as long as the entry is: no id in the key can be reused meanwhile."""

    def __init__(self) -> None:
        self._entry: tuple[Any, Any, Any] | None = None

    def get(self, key, held, build: Callable[[], Any]):
        if self._entry is None or self._entry[0] != key:
            self._entry = (key, held, build())
        return self._entry[2]
