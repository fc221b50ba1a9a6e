"""What one checker (`checker.Checker`) keeps between calls: its per-structure caches, its counters
and its capacity (`CheckState`), and which state the checks running now use (`current`).

A `Checker` makes its state current for the length of each of its calls (`using`, a context
variable, so another thread or a generator suspended in between never sees it); the modules of the
checks read their caches and counters through `current()`. Calls made without a checker (the
module-level `check.check`, `check_units`, `check_many`) use the process's default state
(`DEFAULT`), the one `Checker.shared` wraps.
"""

from __future__ import annotations

import weakref
from collections import Counter
from contextlib import contextmanager
from contextvars import ContextVar

from factory.physics.keep_last import KeepLast


HOLDER_SCENES = 256
"""Most scenes of a joint's holding part a checker keeps (`CheckState.holder_scenes`)."""

SOLIDS = 512
"""Most parts whose ray grids a checker keeps (`CheckState.solids`)."""


class CheckState:
    """One checker's caches of work done per structure, unit or probe, its counters, and the number
    of objects whose caches it keeps at once (`capacity`: objects grown in lockstep ask about each
    of theirs in turn)."""

    def __init__(self, capacity: int = 1) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        self.capacity = capacity
        # Kept for the last `capacity` structures or units (`KeepLast`).
        self.scenes = KeepLast(capacity)
        """The last collision scenes (`check_call`): building one is most of a call's time."""
        self.load_bases = KeepLast(capacity)
        """The last structures' `LoadBase`s (`check_call`)."""
        self.structure_pieces = KeepLast(capacity)
        """The last structures' pieces in the world (`piece_sets.structure_set`)."""
        self.unit_sets = KeepLast(capacity)
        """The last units' pieces in their own frame (`piece_sets.unit_set`)."""
        # Kept by object or by exact inputs, each emptied past its own bound.
        self.meshes: dict = {}
        """`collide._placed_pieces`: a collision shape's pieces as MJCF meshes."""
        self.crossed: dict = {}
        """`collide.studs_cross`: stud probe answers by surface and exact stud."""
        self.bodies: dict = {}
        """`collide._structure_body`: each placed structure part's MJCF body and pieces."""
        self.unit_pieces: dict = {}
        """`collide._unit_pieces`: a candidate unit's pieces by its shapes and layout."""
        self.alone: dict = {}
        """`clutch.holds_alone_many`: answers by case relative to its centre of mass."""
        self.supports: dict = {}
        """`load_model.support_points`: a placed part's ground support points."""
        self.holder_scenes = KeepLast(HOLDER_SCENES)
        """`check_call`: a scene of one part holding a unit by joints, in that part's frame, by
        part and unit (the batched checks' joints, met again across structures)."""
        self.solids = KeepLast(SOLIDS)
        """`solid_overlap`: a part's triangles sorted for ray casts along each axis, by part."""
        self.placed_pieces: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        """`piece_sets.structure_set`: each placed part's pieces turned and moved."""
        # Counters: changed in place only, so that a name bound to one stays its state's.
        self.stage_seconds: Counter = Counter()
        """Seconds by stage of the checks: 'rules', 'collide', 'clutch', 'sweep', 'loads'
        (`check_call`)."""
        self.sweep_counts: Counter = Counter()
        """Batched sweeps' candidates by how they were judged (`sweep_jax`)."""
        self.warm_counts: dict[str, int] = {"started": 0, "cold": 0, "iterations": 0}
        """Load programs solved by `started_loads.solve_from`: started, from nothing, iterations."""

    def keep_last(self) -> tuple[KeepLast, ...]:
        return (self.scenes, self.load_bases, self.structure_pieces, self.unit_sets)

    @contextmanager
    def holding(self, capacity: int):
        """Every `KeepLast` cache keeps at least `capacity` entries inside the block; back to its
        own size (and its newest entries) after."""
        old = [(c, c.capacity) for c in self.keep_last()]
        for c, cap in old:
            c.capacity = max(cap, capacity)
        try:
            yield
        finally:
            for c, cap in old:
                c.capacity = cap
                c.trim()

    def counters(self) -> dict[str, dict]:
        return {"stage_seconds": dict(self.stage_seconds), "sweep_counts": dict(self.sweep_counts),
                "warm_counts": dict(self.warm_counts)}

    def reset_counters(self) -> None:
        self.stage_seconds.clear()
        self.sweep_counts.clear()
        for k in self.warm_counts:
            self.warm_counts[k] = 0

    def caches(self) -> dict:
        """The caches by name (their attribute's)."""
        return {"scenes": self.scenes, "load_bases": self.load_bases, "structure_pieces": self.structure_pieces,
                "unit_sets": self.unit_sets, "meshes": self.meshes, "crossed": self.crossed, "bodies": self.bodies,
                "unit_pieces": self.unit_pieces, "alone": self.alone, "supports": self.supports,
                "placed_pieces": self.placed_pieces, "holder_scenes": self.holder_scenes}

    def clear(self, only=None) -> None:
        """Empty the caches in place, or only those named in `only` (`caches`' names)."""
        caches = self.caches()
        names = list(caches) if only is None else list(only)
        unknown = [n for n in names if n not in caches]
        if unknown:
            raise ValueError(f"unknown caches {unknown}; valid: {', '.join(caches)}")
        for name in names:
            caches[name].clear()

DEFAULT = CheckState()
"""The process's default state: the checks asked without a `Checker`, and `Checker.shared`."""

_CURRENT: ContextVar[CheckState] = ContextVar("factory_physics_check_state", default=DEFAULT)


def current() -> CheckState:
    """The state of the checks running now: their checker's, else `DEFAULT`."""
    return _CURRENT.get()


@contextmanager
def using(state: CheckState):
    """`state` is `current()` inside the block (in this thread and context only)."""
    token = _CURRENT.set(state)
    try:
        yield state
    finally:
        _CURRENT.reset(token)
