"""Small caches for work done once per structure or unit but asked for in several calls.

One object grown at a time asks about one structure in a row (batches, redraws of one part), so
one entry is enough. Objects grown in lockstep (`factory.sampler.lockstep`) ask about each of
theirs in turn, so the grower has its checker hold as many (`checker.Checker.holding`) for as long
as it runs. Each checker owns its own caches (`check_state.CheckState`); nothing here is shared."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Callable


class KeepLast:
    """The values built for the last `capacity` keys (least recently used first out). Keys name
    objects by `id`, so the objects themselves are held (`held`) as long as the entry is: no id in
    the key can be reused meanwhile."""

    def __init__(self, capacity: int = 1) -> None:
        self.capacity = capacity
        self._entries: OrderedDict[Any, tuple[Any, Any]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key, held, build: Callable[[], Any]):
        entry = self._entries.get(key)
        if entry is None:
            entry = (held, build())
            self._entries[key] = entry
            self.trim()
        else:
            self._entries.move_to_end(key)
        return entry[1]

    def trim(self) -> None:
        """Drop the oldest entries past `capacity`."""
        while len(self._entries) > self.capacity:
            self._entries.popitem(last=False)

    def clear(self) -> None:
        self._entries.clear()
