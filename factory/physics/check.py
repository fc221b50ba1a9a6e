"""The physics checks of a candidate placement, cheapest first, with the rule that failed.

For each candidate: (1) **connection** (numpy: does a stud meet a socket?), (2) **collision**
(MuJoCo contacts between inset convex pieces, one `mj_fwdPosition`), (3) **clutch** (the
candidate's own connections hold it with the rest fixed: `clutch.holds_alone`), (4)
**buildability** (it reaches its pose along its connection axis from clear space: `sweep`), (5) **loads**
(the whole structure with it: nothing tips, every stud connection within its capacity, a linear
program per structure: `statics`). A candidate that fails a cheap rule never reaches the
expensive ones; its later fields are None (not evaluated).

Reasons, in the order they are reported: `unsupported-connection` (no stud connection, but the
candidate touches or overlaps a structure part that may hold it by a connection the checker does
not model: Technic pins and axles, clips, hinges, tyres on rims; or, on studs or not, it overlaps
a part only round the axis of a clip, bar or hinge joint with it; `factory.physics.unmodelled`
says when), `collision`, `no-connection` (floating), `clutch` (its own connections cannot hold
it), `clamped` (it sits on studs and under sockets at once: no approach reaches it), `blocked`
(a part placed earlier is in the way of its approach), `unstable` (the part's component tips: its centre of mass is not over its support polygon),
`overload` (some connection of the structure would carry more than its capacity).

Here the checks are asked (`check`, `check_units`, `check_many` with its `CheckRequest`s) and their
calls run, stage by stage (`_run_calls`). One call's walk through the rules is `check_call._Call`;
the loads stage, `check_loads`; the thresholds and verdicts, `verdict` (`CheckConfig`, `Verdict`);
the backends' names, `backends` (`BACKENDS`, `backend_name`). All of these are importable from here.
Called here, the checks keep their caches and counters in the process's default state; a
`checker.Checker` runs them in its own (`check_state`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

from factory.parts import Part
from factory.physics.backends import BACKENDS, OLD_BACKEND_NAMES, backend_arg, backend_name
from factory.physics.check_call import _Call
from factory.physics.check_state import current
from factory.physics.check_call import _unit_connections  # noqa: F401  (imported from here by tests and benchmarks)
from factory.physics.check_loads import _judge_loads
from factory.physics.clutch import holds_alone_many
from factory.physics.collide_jax import penetrations  # numpy at import; JAX at the first launch
from factory.physics.load_model import Link
from factory.physics.structure import Placed, Structure
from factory.physics.sweep_jax import sweep_groups
from factory.physics.verdict import CheckConfig, Verdict
from factory.pose import Pose

__all__ = ["BACKENDS", "OLD_BACKEND_NAMES", "CheckConfig", "CheckRequest", "Verdict", "backend_arg",
           "backend_name", "check", "check_many", "check_units"]


def check_units(
    structure: Structure,
    units: Sequence[Sequence[Placed]],
    backend: str = "cpu",
    config: CheckConfig = CheckConfig(),
    require_connection: bool = True,
    floor_y: float | None = None,
    standing: bool = True,
    unit_links: Sequence[Link] = (),
    explain: bool = True,
    sweep: bool = True,
) -> list[Verdict]:
    """Check rigid units (each a list of placed parts, in world poses) against the structure.

    All units must share their parts and relative layout up to one rigid motion when many are
    given (the sampler's case: one part type at many poses); each unit's pose is that of its
    first part. With `floor_y` (LDraw height) the ground is fixed there and nothing may go below
    it (the sampler's case). Without it the object rests on its own lowest point with the unit
    added (a human build: a car body waits for its wheels, held above the table). With
    `standing=False` the structure is held in hand (a sub-assembly being built): only the clutch of
    the new connection is judged, not whether the whole stands. `unit_links`: rigid connections
    among a unit's own parts (numbered within the unit) that the checker does not model.
    `explain=False` leaves `failing` empty on overloads (it costs a second program each; the
    sampler only counts the reason of a candidate it rejects).
    `sweep=False` leaves the way in unjudged (`approach` 'held'): a part put in place before what
    holds it (a gear set between beams, then the axle pushed through it), whose holder's own
    sweep finds the way.
    """
    backend = backend_name(backend)
    if not units:
        return []
    (verdicts,) = _run_calls([_Call(structure, units, backend, config, require_connection, floor_y, standing,
                                    unit_links, explain, sweep=sweep)], backend)
    return verdicts


@dataclass(frozen=True)
class CheckRequest:
    """One object's question to the checker (`check_many`): one part type at candidate poses on
    its structure, the ground at `floor_y` (the sampler's case of `check`)."""

    structure: Structure
    part: Part
    poses: tuple[Pose, ...]
    colour: int = 16
    floor_y: float | None = None
    judge_first: int | None = None
    """Of the candidates that pass connection, collision and clutch, only the first this many (in
    `poses`' order) go on to the sweep and the loads, the two dearest checks; the others' verdicts
    are None (not judged). For an asker that takes the first survivor of an order, as the sampler
    does: their load programs are solved one at a time in that order, each started from the
    structure's own, and stop at the first candidate that stands, so those after it come back
    None too. A later request judges them if it needs to. None judges every candidate (with
    'jax', their load programs together on the device)."""
    order: Callable[[list[int]], list[int]] | None = field(default=None, compare=False)
    """With `judge_first`: the asker's own order of candidates, given their positions in `poses`
    (a list) and giving them back in the order it would take them, first the one it would take
    first; it may end early, before a candidate that one outside the request might precede. When
    the first candidate of `poses` does not stand, the load programs of the others go in this
    order, up to the first that stands, so that is the one the asker takes (the sampler orders
    them by their exact keys, where `poses` holds them by their keys' upper bounds). The
    positions given include the candidates left unjudged: the programs stop at the first of
    them, whose verdict the asker needs first. None: `poses`' order."""


def check_many(requests: Sequence[CheckRequest], backend: str = "cpu", config: CheckConfig = CheckConfig(),
               explain: bool = True) -> list[list[Verdict]]:
    """`check` of every request, each against its own structure (objects grown in lockstep:
    `factory.sampler.lockstep`). The verdicts are those `check` gives each request alone, except
    None for the candidates a request's `judge_first` leaves unjudged; with 'jax' the collision
    rule, the clutch rule's programs and the sweeps of all requests go to the device together
    (`collide_jax`, `sweep_jax`), and so do the load programs of requests that judge every
    candidate (`loads_jax.solve_on_bases`); those of a request with `judge_first` are solved on
    the host up to its first candidate that stands (`check_loads._until_standing`)."""
    backend = backend_name(backend)
    calls = [_Call(r.structure, [[Placed(r.part, r.colour, p)] for p in r.poses], backend, config,
                   floor_y=r.floor_y, explain=explain, judge_first=r.judge_first, order=r.order)
             for r in requests if r.poses]
    done = iter(_run_calls(calls, backend))
    return [next(done) if r.poses else [] for r in requests]


def _run_calls(calls: "Sequence[_Call]", backend: str) -> list[list[Verdict]]:
    """Collision (for 'jax'; the reference's ran at construction), the sweeps, then the load
    programs of every call: for 'jax' on the device, each stage of all calls together
    (`collide_jax.penetrations`, `sweep_jax.sweep_groups`, `_judge_loads`)."""
    seconds = current().stage_seconds
    t0 = time.perf_counter()
    if backend == "jax":
        todo = [c for c in calls if c.to_collide]
        found_all = penetrations([c.collide_group() for c in todo])
        seconds["collide"] += time.perf_counter() - t0
        for c, found in zip(todo, found_all):
            c.collided(found)  # counted as 'rules'
        # The clutch rule of every call: the closed form, else one body's program (6 rows) solved
        # by HiGHS on the host, as the reference does: about 1.7 ms a program on the 2-core
        # machine, where a batched launch of a round's few programs cost 73 ms (a profiled build
        # of 40 real parts, 16 workers sharing a lent H200).
        cases = [c.clutch_cases() for c in calls]
        t0 = time.perf_counter()
        # One config for every call: check_many passes its own to each.
        holds = iter(holds_alone_many([x for cs in cases for x in cs], calls[0].config.loads))
        seconds["clutch"] += time.perf_counter() - t0
        for c, cs in zip(calls, cases):
            c.clutched([next(holds) for _ in cs])
        t0 = time.perf_counter()

        todo = [(c, g) for c in calls if (g := c.sweep_group()) is not None]
        for (c, _), built in zip(todo, sweep_groups([g for _, g in todo])):
            c.swept(built)
    t1 = time.perf_counter()
    seconds["sweep"] += t1 - t0
    _judge_loads(calls, _loads_jax(backend))
    seconds["loads"] += time.perf_counter() - t1
    return [c.verdicts for c in calls]  # type: ignore[misc]


def _lp_jax(backend: str):
    """None for the CPU reference (HiGHS, one program at a time); the batched JAX solver's module
    (`factory.physics.lp_jax`) for 'jax'."""
    if backend != "jax":
        return None
    try:
        from factory.physics import lp_jax  # JAX is an optional dependency (the jax extra)
    except ModuleNotFoundError as e:
        raise RuntimeError(f"backend 'jax' needs the batched load solver factory.physics.lp_jax and JAX "
                           f"(pip install -e '.[jax]'); not available: {e.name}") from None
    return lp_jax


def _loads_jax(backend: str):
    """None for the CPU reference; the load programs on the JAX device (`factory.physics.loads_jax`,
    through the batched solver `_lp_jax` gives) for 'jax'."""
    if _lp_jax(backend) is None:
        return None
    from factory.physics import loads_jax  # optional: JAX (the jax extra); `_lp_jax` said if it is missing

    return loads_jax


def check(
    structure: Structure,
    part: Part,
    poses: Sequence[Pose],
    backend: str = "cpu",
    config: CheckConfig = CheckConfig(),
    colour: int = 16,
    floor_y: float | None = None,
    explain: bool = True,
) -> list[Verdict]:
    """Check one part type at many candidate poses against the structure (a batch); see
    `check_units` for the ground (`floor_y`) and `explain`."""
    backend = backend_name(backend)
    return check_units(structure, [[Placed(part, colour, p)] for p in poses], backend, config,
                       floor_y=floor_y, explain=explain)
