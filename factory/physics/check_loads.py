"""The last stage of the checks, the whole structure's loads, for the candidates of many calls
(`_judge_loads`): a call that takes its first survivor (the sampler's) has its programs solved one
at a time, each started from the structure's own, up to the first candidate that stands
(`_until_standing`, `_started_solver`); the others' go to HiGHS one at a time (backend 'cpu') or to
the batched solver together ('jax'). What a structure keeps of its solved programs for the
structure after it (`_LoadStarts`, at most `KEPT_BASES` candidates)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

from factory.physics.check_call import _Call, _load_base
from factory.physics.load_model import Link, LoadBase, LoadConfig, LoadModel
from factory.physics.started_loads import solve_from
from factory.physics.statics import judge_many, judge_on_bases
from factory.physics.structure import Placed, Structure


def _judge_loads(calls: Sequence[_Call], loads_jax) -> None:
    """The load programs of every call's pending candidates: a call with `judge_first` (the
    sampler's) up to its first candidate that stands (`_until_standing`); otherwise HiGHS one at a
    time for the reference, and with the batched solver one-part candidates on a connected
    structure by its shared columns (`judge_on_bases`: the programs of every call in shared
    launches), the rest in one `judge_many`."""
    general: list[tuple[_Call, list]] = []
    on_base: dict = {}
    for c in calls:
        if not c.pending:
            continue
        cfg = c.config.loads
        loads = _load_base(c.structure, c.floor_y, cfg)
        links = [l.moved(c.base_n) for l in c.unit_links]
        if c.judge_first is not None:
            # The asker takes the first survivor in the request's order (the sampler): the programs
            # one at a time, each started from the structure's own, up to the first that stands.
            c.loaded(_until_standing(c, loads, links))
            continue
        if loads_jax is not None and not links and not c.joint_links and loads.shared() and all(len(u) == 1 for _, u, _ in c.pending):
            # One part on a connected structure: its columns written once per structure, the
            # programs of every such call in shared launches (`solve_on_bases`).
            on_base.setdefault((cfg, c.explain), []).append((c, loads))
        else:
            general.append((c, [loads.model(unit, conns, links + c.joint_links.get(k, [])) for k, unit, conns in c.pending]))
    for (cfg, explain), members in on_base.items():
        groups = [(loads, [u for _, u, _ in c.pending], [cs for *_, cs in c.pending]) for c, loads in members]
        for (c, _), results in zip(members, judge_on_bases(groups, cfg, loads_jax.solve_on_bases, explain)):
            c.loaded(results)
    if not general:
        return
    if loads_jax is None:
        for c, models in general:
            units = [unit for _, unit, _ in c.pending]
            c.loaded(judge_many(models, c.config.loads, _started_solver(c, models, units), explain=c.explain))
        return
    # The batched solver takes programs of any structures together; calls share one constant set
    # and one `explain` when they come from one `check_many` (else each goes alone).
    by_kind: dict = {}
    for c, models in general:
        by_kind.setdefault((c.config.loads, c.explain), []).append((c, models))
    for (cfg, explain), members in by_kind.items():
        results = judge_many([m for _, ms in members for m in ms], cfg, loads_jax.solve_loads, explain=explain)
        at = 0
        for c, models in members:
            c.loaded(results[at:at + len(models)])
            at += len(models)


KEPT_BASES = 16
"""Candidates' final bases kept per structure and length (the first solved; 0.46 MB for the program
of a 90-part sampled structure, by tracemalloc). The sampler's reference solves one or two programs
a step; a caller judging thousands of candidates against one structure (`bench_physics`) keeps no
more than these. Which are kept depends only on the order the structure's candidates were solved
in, so it is deterministic too."""


@dataclass
class _LoadStarts:
    """What a structure keeps of its load programs (`Structure.solved_loads`), for one length."""

    length: int
    start: dict
    """(floor_y, cfg) -> `started_loads.Solved`: the program its last part ended at as a candidate."""
    candidates: dict = field(default_factory=dict)
    """(unit key, floor_y, cfg) -> `started_loads.Solved` of the candidates solved at this length."""


def _unit_key(unit: Sequence[Placed]) -> tuple:
    return tuple((p.part.name, p.pose.R.tobytes(), p.pose.t.tobytes()) for p in unit)


def _load_starts(structure: Structure) -> _LoadStarts:
    """The structure's `_LoadStarts` for its length: when it has grown by one part since, the
    programs kept for that part as a candidate become the starts."""
    kept, n = structure.solved_loads, len(structure)
    if kept is None or kept.length != n:
        last = _unit_key(structure.placed[-1:])
        before = kept.candidates if kept is not None and kept.length == n - 1 else {}
        kept = structure.solved_loads = _LoadStarts(n, {key[1:]: s for key, s in before.items() if key[0] == last})
    return kept


def _until_standing(call: "_Call", loads: LoadBase, links: Sequence[Link]) -> list:
    """The load verdicts of `call`'s pending candidates, up to the first that stands (the rest are
    left unjudged: `_Call.loaded`), each program solved by `_started_solver`: the request's first
    candidate first, then the others in the asker's order (`CheckRequest.order`, asked only
    when the first does not stand; else the request's). With an order, the programs also stop
    before the first candidate in it whose verdict the asker cannot know yet (one `judge_first`
    left unjudged, or one that needs no program), and where the order ends: the asker takes that
    one, or asks again, before it would take any after it. `call.pending` is left in the order
    solved. For an asker that takes the first survivor (`CheckRequest.judge_first`): a
    candidate's program, started from the structure's, takes a few simplex iterations, so solving
    them one by one and stopping there costs less than any batch of the programs after it
    (docs/concepts/batched-checks.md)."""
    first = [e for e in call.pending if e[0] == 0]
    rest = [e for e in call.pending if e[0] != 0]
    solved: list[tuple] = []  # (pending entry, its load verdict), in the order solved

    def one_stands(entries) -> bool:
        for entry in entries:
            k, unit, conns = entry
            model = loads.model(unit, conns, [*links, *call.joint_links.get(k, [])])
            (verdict,) = judge_many([model], call.config.loads, _started_solver(call, [model], [unit]),
                                    explain=call.explain)
            solved.append((entry, verdict))
            if verdict.stands:
                return True
        return False

    if not one_stands(first) and rest:
        if call.order is None:
            one_stands(rest)
        else:
            # Candidates not rejected and not pending: left unjudged, or judged without a program.
            # The walk stops at them (their programs would be solved for nothing if it took one).
            pending = {e[0] for e in call.pending}
            stops = [k for k, v in enumerate(call.verdicts) if k != 0 and k not in pending and (v is None or v.ok)]
            one_stands(_in_order(call.order, rest, stops))
    judged = {id(e) for e, _ in solved}
    call.pending = [e for e, _ in solved] + [e for e in call.pending if id(e) not in judged]
    return [v for _, v in solved]


def _in_order(order: Callable[[list[int]], list[int]], entries: list, stops: Sequence[int] = ()) -> list:
    """`entries` (pending candidates, each led by its position) in the asker's `order`, up to the
    first of the positions `stops` in it or where it ends (`CheckRequest.order`)."""
    by_position = {e[0]: e for e in entries}
    given = list(by_position) + list(stops)
    positions = list(order(list(given)))
    if len(set(positions)) != len(positions) or not set(positions) <= set(given):
        raise ValueError(f"CheckRequest.order gave {positions} for the positions {given}; "
                         "expected some of the same positions, each once, reordered")
    out = []
    for k in positions:
        if k not in by_position:
            break
        out.append(by_position[k])
    return out


def _started_solver(call: "_Call", models: Sequence[LoadModel], units: Sequence[Sequence[Placed]]):
    """HiGHS for pending candidates of `call` (`models`, of `units`), each program started from
    the one the structure's last part ended at when it was a candidate on the structure before it
    (`started_loads.solve_from`); each candidate's own final basis is kept on the structure for the
    structure after it. What starts a program depends only on the structure's own parts, in
    their order, so a candidate's answer does not depend on what else was asked before it."""
    kept = _load_starts(call.structure)
    start = kept.start.get((call.floor_y, call.config.loads))
    keys = {id(m): _unit_key(unit) for m, unit in zip(models, units)}

    def solve(todo: Sequence[LoadModel], cfg: LoadConfig) -> list:
        out = []
        for m in todo:
            result, solved = solve_from(m, cfg, start)
            if solved is not None and len(kept.candidates) < KEPT_BASES:
                kept.candidates[(keys[id(m)], call.floor_y, cfg)] = solved
            out.append(result)
        return out

    return solve
