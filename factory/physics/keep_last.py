"""Small caches for work done once per structure or unit but asked for in several calls.

One object grown at a time asks about one structure in a row (batches, redraws of one part), so
one entry is enough. Objects grown in lockstep (`factory.sampler.lockstep`) ask about each of
theirs in turn, so the grower widens these caches to its batch for as long as it runs
(`widened`)."""

from __future__ import annotations

from collections import OrderedDict
from contextlib import contextmanager
from typing import Any, Callable

_ALL: list["KeepLast"] = []


class KeepLast:
    """The values built for the last `capacity` keys (least recently used first out). Keys name
    objects by `id`, so the objects themselves are held (`held`) as long as the entry is: no id in
    the key can be reused meanwhile."""

    def __init__(self, capacity: int = 1) -> None:
        self.capacity = capacity
        self._entries: OrderedDict[Any, tuple[Any, Any]] = OrderedDict()
        _ALL.append(self)

    def get(self, key, held, build: Callable[[], Any]):
        entry = self._entries.get(key)
        if entry is None:
            entry = (held, build())
            self._entries[key] = entry
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)
        else:
            self._entries.move_to_end(key)
        return entry[1]


@contextmanager
def widened(capacity: int):
    """Every cache keeps at least `capacity` entries inside the block; back to its own size (and
    its newest entries) after."""
    old = [(c, c.capacity) for c in _ALL]
    for c, cap in old:
        c.capacity = max(cap, capacity)
    try:
        yield
    finally:
        for c, cap in old:
            c.capacity = cap
            while len(c._entries) > cap:
                c._entries.popitem(last=False)
