"""Many objects grown together: each step's checks of every object in one `check_many` call.

Each object is a coroutine (`Sampler.growth`) that yields a batch of candidates to check and takes
their verdicts back; its random choices come from its own stream, so it grows the same whatever
objects share its rounds. A round asks every live object's pending batch at once; an object that
ends leaves and the next index takes its slot, so the batch stays full until the indices run out.
With the 'jax' backend the round's collision tests and sweeps go to the device together
(`Checker.check_many`, the sampler's checker, which holds its caches for the whole batch); each object's load programs are solved on the host, up to its first
candidate that stands.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING, Iterable, Iterator


if TYPE_CHECKING:
    from factory.sampler.assembly import Assembly
    from factory.sampler.sampler import Sampler


def grow_together(sampler: "Sampler", indices: Iterable[int], batch: int = 1) -> Iterator["Assembly"]:
    """The objects `indices` of `sampler`, at most `batch` growing at once, each yielded as it ends
    (so not in index order when batch > 1). An object's `check_seconds` is its share of each
    round's checking time, by its candidates' count."""
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}")
    checker = sampler.checker
    todo = iter(indices)
    live: list[list] = []  # [coroutine, pending request, check seconds]

    def admit() -> Iterator["Assembly"]:
        """Start objects until `batch` are waiting for verdicts (an object that ends without
        asking anything is yielded at once)."""
        while len(live) < batch:
            index = next(todo, None)
            if index is None:
                return
            gen = sampler.growth(index)
            try:
                live.append([gen, next(gen), 0.0])
            except StopIteration as end:
                yield end.value

    # Each object's collision scene, load base and sweep pieces stay cached between its rounds.
    with checker.holding(batch):
        yield from admit()
        while live:
            t0 = time.perf_counter()
            answers = checker.check_many([slot[1] for slot in live], explain=False)
            seconds = time.perf_counter() - t0
            total = sum(len(slot[1].poses) for slot in live) or 1
            still = []
            for slot, verdicts in zip(live, answers):
                slot[2] += seconds * len(slot[1].poses) / total
                try:
                    slot[1] = slot[0].send(verdicts)
                    still.append(slot)
                except StopIteration as end:
                    yield replace(end.value, check_seconds=slot[2])
            live[:] = still
            yield from admit()
