"""The physics checks as one object (`Checker`): a config, a backend, and the state the checks keep
between calls, its own.

    checker = Checker(CheckConfig(), "jax")
    verdicts = checker.check(structure, part, poses, floor_y=0.0)
    with checker.holding(8):                 # caches for 8 objects grown in lockstep
        answers = checker.check_many(requests)
    checker.counters()["stage_seconds"]
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Sequence

from factory.parts import Part
from factory.physics.backends import backend_name
from factory.physics.check import CheckRequest, check, check_many, check_units
from factory.physics.check_state import DEFAULT, CheckState, using
from factory.physics.load_model import Link
from factory.physics.structure import Placed, Structure
from factory.physics.verdict import CheckConfig, Verdict
from factory.pose import Pose


class Checker:
    """The checks of one config and backend (`backends.BACKENDS`, former names accepted by
    `backend_name`) with their own state (`check_state.CheckState`): the caches of work done per
    structure, unit and probe (collision scenes, load bases, sweep pieces, MJCF bodies, clutch and
    stud-probe answers, support points), kept for `capacity` objects at once (objects grown in
    lockstep ask about each of theirs in turn: `holding`), and the counters (seconds per stage,
    batched sweeps by how they were judged, load programs started from a basis). Two checkers in
    one process share none of it: each call makes its checker's state the current one
    (`check_state.using`) for as long as it runs. The module-level functions (`check.check`,
    `check_units`, `check_many`) run on the process's default state, which `shared` wraps.

    What stays per process, shared by every checker, is what depends only on part geometry or is a
    compiled program: the parts' collision surfaces (`collide._SURFACES`) and piece templates
    (`piece_sets._SHAPES`), the JAX kernels (`pair_kernels._KERNEL`, the exported ones loaded,
    `jax_export._LOADED`), the padded sizes they were compiled for (`pair_kernels._HIGH`) and
    whether they were readied (`pair_kernels._WARMED`). Those are functions of the part or the
    shape alone, so sharing them changes no answer; compiling them per checker would break the
    bound on compiles per run (each shape once per process). No checker resizes or empties them.
    The checks' verdicts do not depend on the state either: a cache only spares work.
    """

    def __init__(self, config: CheckConfig = CheckConfig(), backend: str = "cpu", capacity: int = 1) -> None:
        self.config = config
        self.backend = backend_name(backend)
        self._state = CheckState(capacity)

    @classmethod
    def shared(cls, config: CheckConfig = CheckConfig(), backend: str = "cpu") -> "Checker":
        """A checker on the process's default state: its caches and counters are those of the
        module-level functions' calls (and of every other `shared` checker)."""
        checker = cls(config, backend)
        checker._state = DEFAULT
        return checker

    @property
    def capacity(self) -> int:
        return self._state.capacity

    @property
    def state(self) -> CheckState:
        """This checker's caches and counters (read them; `counters`, `clear` and `holding` change
        them)."""
        return self._state

    def check(self, structure: Structure, part: Part, poses: Sequence[Pose], colour: int = 16,
              floor_y: float | None = None, explain: bool = True) -> list[Verdict]:
        """`check.check` with this checker's config, backend and state."""
        with using(self._state):
            return check(structure, part, poses, self.backend, self.config, colour, floor_y, explain)

    def check_units(self, structure: Structure, units: Sequence[Sequence[Placed]], require_connection: bool = True,
                    floor_y: float | None = None, standing: bool = True, unit_links: Sequence[Link] = (),
                    explain: bool = True) -> list[Verdict]:
        """`check.check_units` with this checker's config, backend and state."""
        with using(self._state):
            return check_units(structure, units, self.backend, self.config, require_connection, floor_y, standing,
                               unit_links, explain)

    def check_many(self, requests: Sequence[CheckRequest], explain: bool = True) -> list[list[Verdict]]:
        """`check.check_many` with this checker's config, backend and state."""
        with using(self._state):
            return check_many(requests, self.backend, self.config, explain)

    @contextmanager
    def holding(self, capacity: int):
        """This checker's per-structure caches keep at least `capacity` entries inside the block
        (objects grown in lockstep: `factory.sampler.lockstep`); back to its own capacity (and its
        newest entries) after."""
        with self._state.holding(capacity):
            yield self

    def counters(self) -> dict[str, dict]:
        """A snapshot of the counters: {'stage_seconds': seconds by stage ('rules', 'collide',
        'clutch', 'sweep', 'loads'), 'sweep_counts': batched sweeps' candidates by how they were
        judged ('device', 'referred', 'not-judged', 'cpu'), 'warm_counts': load programs solved
        started from a basis ('started'), from nothing ('cold'), and their 'iterations'}."""
        return self._state.counters()

    def reset_counters(self) -> None:
        self._state.reset_counters()

    def clear(self, only=None) -> None:
        """Drop this checker's caches, or only those named in `only` (e.g. `("crossed", "alone")`,
        the stud-probe and clutch answers kept by geometry, as a benchmark row that should find
        none of them drops; the names: `CheckState.caches`)."""
        self._state.clear(only)
