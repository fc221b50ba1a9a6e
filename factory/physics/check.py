"""The physics checks of a candidate placement, cheapest first, with the rule that failed.

For each candidate: (1) **connection** (numpy: does a stud meet a socket?), (2) **collision**
(MuJoCo contacts between inset convex pieces, one `mj_fwdPosition`), (3) **clutch** (the
candidate's own connections hold it with the rest fixed: `statics.holds_alone`), (4)
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
"""

from __future__ import annotations

import sys
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from factory.parts import Part
from factory.physics.collide import CollisionScene, Penetration
from factory.physics.collide_jax import penetrations  # numpy at import; JAX at the first launch
from factory.physics.keep_last import KeepLast
from factory.physics.mass import part_mass_properties
from factory.physics.statics import (Failure, Link, LoadBase, LoadConfig, LoadModel, holds_alone_many, judge_many,
                                     judge_on_bases, solve_from, support_points)
from factory.physics.sweep import seating_from_connections, sweep
from factory.physics.sweep_jax import sweep_groups
from factory.physics.structure import Placed, Structure, connections_at, lowest_point
from factory.physics.unmodelled import bar_joints, may_hold
from factory.pose import Pose

BACKENDS = ("cpu", "jax")
"""The physics checks' backends: 'cpu', the reference (MuJoCo's C collision and NumPy/SciPy, one
candidate at a time, on the CPU), and 'jax', the batched JAX kernels of this project
(`collide_jax`, `sweep_jax`, `lp_jax`: every candidate of a round at once, on a GPU where there is
one). Both give the same verdicts."""

OLD_BACKEND_NAMES = {"mujoco": "cpu", "mjx": "jax"}
"""The backends' former names (the batched one never used MuJoCo MJX), still accepted with a
`FutureWarning` by `backend_name`."""


def backend_name(name: str, stacklevel: int = 2) -> str:
    """The check backend `name` as `BACKENDS` spells it: a former name (`OLD_BACKEND_NAMES`) gives
    its new one with a `FutureWarning` (at `stacklevel` as `warnings.warn` counts it); any other
    name not in `BACKENDS` raises ValueError listing the valid choices. Every entry point that
    takes a backend goes through here."""
    if name in BACKENDS:
        return name
    if isinstance(name, str) and name in OLD_BACKEND_NAMES:
        new = OLD_BACKEND_NAMES[name]
        warnings.warn(f"check backend {name!r} is deprecated; use {new!r}", FutureWarning, stacklevel=stacklevel + 1)
        return new
    raise ValueError(f"unknown check backend {name!r}; valid choices: {', '.join(BACKENDS)}")


def backend_arg(text: str) -> str:
    """`backend_name` as an argparse `type` for `--check-backend`: a former name gives its new one
    with a warning line on stderr (as a renamed flag does); other text is left for the flag's
    `choices` to accept or refuse (a command may add its own, as `auto`)."""
    if text not in OLD_BACKEND_NAMES:
        return text
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        name = backend_name(text)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return name


@dataclass(frozen=True)
class CheckConfig:
    """Thresholds of the checks."""

    max_penetration_ldu: float = 0.5
    """Deepest overlap accepted (LDU); the collision pieces are inset by half of it each."""
    loads: LoadConfig = field(default_factory=LoadConfig)
    """The whole-structure load model's constants (clutch per stud, shear, ground friction)."""


@dataclass(frozen=True)
class Verdict:
    """The checks of one candidate placement; a field is None where its check did not run."""

    pose: Pose
    connected: bool
    connections: int
    collision: bool | None = None
    max_penetration_ldu: float | None = None
    touching: bool | None = None
    clutch: bool | None = None
    """Whether the candidate's own connections hold it with the rest of the structure fixed."""
    stable: bool | None = None
    """Whether the whole structure stands with it: nothing tips, no connection overloaded."""
    buildable: bool | None = None
    """Whether it reaches its pose along its connection axis from clear space (`sweep.py`); None
    where that is not judged: connections on two axes (`approach` says so) or no stud connection."""
    approach: str | None = None
    """Why buildability was not judged, or 'clamped'/'blocked' when it failed."""
    blocked_by: tuple[int, ...] = ()
    """Structure parts in the way of the approach."""
    load: float | None = None
    """The largest share of any connection's capacity used in the whole structure (<= 1 stands)."""
    failing: tuple[Failure, ...] = ()
    """The connections at that load, when it is over capacity."""
    held_by: tuple[int, ...] = ()
    """For 'unsupported-connection': the structure parts that may hold it by a connection the
    checker does not model (they become rigid links once it is placed)."""
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.reason is None


def _unit_connections(structure: Structure, unit: Sequence[tuple[Part, Pose]]) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """Stud connections of a unit with the structure and among its own parts, as
    (stud part, socket part, stud base, stud axis); the unit's parts are numbered after the
    structure's."""
    out = []
    base = len(structure)
    for j, (part, pose) in enumerate(unit):
        out += connections_at(structure, part, pose.R[None], pose.t[None], base + j)[0]
    if len(unit) > 1:
        inner = Structure([Placed(part, 16, pose) for part, pose in unit])
        out += [(base + a, base + b, p, n) for a, b, p, n in inner.connections]
    return out


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
    """
    backend = backend_name(backend)
    if not units:
        return []
    (verdicts,) = _run_calls([_Call(structure, units, backend, config, require_connection, floor_y, standing,
                                    unit_links, explain)], backend)
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
    candidate (`lp_jax.solve_on_bases`); those of a request with `judge_first` are solved on
    the host up to its first candidate that stands (`_until_standing`)."""
    backend = backend_name(backend)
    calls = [_Call(r.structure, [[Placed(r.part, r.colour, p)] for p in r.poses], backend, config,
                   floor_y=r.floor_y, explain=explain, judge_first=r.judge_first, order=r.order)
             for r in requests if r.poses]
    done = iter(_run_calls(calls, backend))
    return [next(done) if r.poses else [] for r in requests]


STAGE_SECONDS: Counter = Counter()
"""Seconds spent in this process by stage of `check_units`/`check_many`: 'rules' (connection,
clutch, and for the reference collision and the CPU sweep), 'collide' (the batched collision
rule, `collide_jax`), 'clutch' (for 'jax': the clutch rule of every call at once), 'sweep' (the
batched sweeps), 'loads'."""


def _run_calls(calls: "Sequence[_Call]", backend: str) -> list[list[Verdict]]:
    """Collision (for 'jax'; the reference's ran at construction), the sweeps, then the load
    programs of every call: for 'jax' on the device, each stage of all calls together
    (`collide_jax.penetrations`, `sweep_jax.sweep_groups`, `_judge_loads`)."""
    t0 = time.perf_counter()
    if backend == "jax":
        todo = [c for c in calls if c.to_collide]
        found_all = penetrations([c.collide_group() for c in todo])
        STAGE_SECONDS["collide"] += time.perf_counter() - t0
        for c, found in zip(todo, found_all):
            c.collided(found)  # counted as 'rules'
        # The clutch rule of every call: the closed form on the host, the programs in one launch.
        cases = [c.clutch_cases() for c in calls]
        t0 = time.perf_counter()
        # One config for every call: check_many passes its own to each.
        holds = iter(holds_alone_many([x for cs in cases for x in cs], calls[0].config.loads,
                                      _lp_jax(backend).solve_batch))
        STAGE_SECONDS["clutch"] += time.perf_counter() - t0
        for c, cs in zip(calls, cases):
            c.clutched([next(holds) for _ in cs])
        t0 = time.perf_counter()

        todo = [(c, g) for c in calls if (g := c.sweep_group()) is not None]
        for (c, _), built in zip(todo, sweep_groups([g for _, g in todo])):
            c.swept(built)
    t1 = time.perf_counter()
    STAGE_SECONDS["sweep"] += t1 - t0
    _judge_loads(calls, _lp_jax(backend))
    STAGE_SECONDS["loads"] += time.perf_counter() - t1
    return [c.verdicts for c in calls]  # type: ignore[misc]


class _Call:
    """One `check_units` call: each candidate's connections at construction, then collision (the
    scene's contacts for the reference; for 'jax' `collide_group`/`collided`, where many calls share
    the device), the cheap rules after it (and the CPU sweep for the reference), then its sweeps
    (`sweep_group`, `swept`) and loads (`_judge_loads`)."""

    def __init__(self, structure: Structure, units: Sequence[Sequence[Placed]], backend: str, config: CheckConfig,
                 require_connection: bool = True, floor_y: float | None = None, standing: bool = True,
                 unit_links: Sequence[Link] = (), explain: bool = True, judge_first: int | None = None,
                 order: Callable[[list[int]], list[int]] | None = None):
        t0 = time.perf_counter()
        if judge_first is not None and judge_first < 1:
            raise ValueError(f"judge_first must be None or >= 1, got {judge_first}")
        self.judge_first, self.order = judge_first, order
        self.structure, self.config, self.floor_y, self.backend = structure, config, floor_y, backend
        self.standing, self.unit_links, self.explain = standing, unit_links, explain
        self.require_connection = require_connection
        first = units[0]
        anchor = first[0].pose
        self.rel = [(p.part, anchor.inverse() @ p.pose) for p in first]
        self._scene: CollisionScene | None = None
        self.base_n = base_n = len(structure)
        self.verdicts: list[Verdict | None] = [None] * len(units)
        self.pending: list[tuple[int, list[Placed], list]] = []
        self.to_sweep: list[tuple] = []
        self.to_collide: list[tuple] = []
        self.to_clutch: list[tuple] = []
        if len(first) == 1:  # one part at many poses: every candidate's connections in one query
            each = connections_at(structure, first[0].part, np.array([u[0].pose.R for u in units]),
                                  np.array([u[0].pose.t for u in units]))
        for k, unit in enumerate(units):
            world = [(p.part, p.pose) for p in unit]
            conns = each[k] if len(first) == 1 else _unit_connections(structure, world)
            outer = [c for c in conns if min(c[0], c[1]) < base_n]
            self.to_collide.append((k, unit, world, conns, outer, {min(c[0], c[1]) for c in outer}))
        STAGE_SECONDS["rules"] += time.perf_counter() - t0
        if backend != "jax":
            # The reference: MuJoCo's contacts, one candidate pose at a time.
            t0 = time.perf_counter()
            found = []
            for _, unit, *_, touched in self.to_collide:
                depth, near = self.scene.penetration(unit[0].pose, touched)
                found.append(Penetration(depth, frozenset(near)))
            STAGE_SECONDS["rules"] += time.perf_counter() - t0
            self.collided(found)

    @property
    def scene(self) -> CollisionScene:
        """The MuJoCo collision scene (the reference's; for 'jax' built only if a sweep is referred
        to the CPU)."""
        if self._scene is None:
            self._scene = _collision_scene(self.structure, self.rel, self.floor_y if self.floor_y is not None else 1e6)
        return self._scene

    def collide_group(self):
        """This call's candidates for `collide_jax.penetrations`."""
        return (self.structure, self.rel, [unit[0].pose for _, unit, *_ in self.to_collide],
                [touched for *_, touched in self.to_collide], self.floor_y, self.config.max_penetration_ldu)

    def collided(self, found: Sequence[Penetration]) -> None:
        """The rules after collision, given each candidate's `Penetration`: verdicts for those
        that collide or connect to nothing; the rest queued for the clutch rule (`clutch_cases`,
        `clutched`: for 'jax' the programs of every call go to the device together)."""
        t0 = time.perf_counter()
        structure, config, base_n = self.structure, self.config, self.base_n
        self.to_clutch = []
        for (k, unit, world, conns, outer, touched), pen in zip(self.to_collide, found):
            depth, near = pen.depth, pen.near
            pose = unit[0].pose
            connected = bool(outer) or (not self.require_connection) or base_n == 0
            collision = depth > config.max_penetration_ldu
            base = dict(pose=pose, connected=bool(outer), connections=len(outer), collision=collision,
                        max_penetration_ldu=round(depth, 4), touching=bool(near))
            # Joints matter only to a candidate that collides or has no stud connection.
            joints = self._joints(unit, near) if collision or not outer else {}
            if joints and collision and self.scene.penetration(pose, touched, joints)[0] > config.max_penetration_ldu:
                joints = {}  # it overlaps beyond the joints too: judged on that overlap
            if not outer and near:
                holders = tuple(sorted(set(joints) | {i for i in near if any(
                    may_hold(p.part, p.pose, structure.placed[i].part, structure.placed[i].pose) for p in unit)}))
                if holders:
                    # Held by a connection we do not model (Technic, clip, hinge, tyre): not judged here.
                    self.verdicts[k] = Verdict(**base, held_by=holders, reason="unsupported-connection")
                    continue
            if collision and joints:
                # On studs, and overlapping only where it is joined to a part by a clip, bar or
                # hinge (a hinge roof's fingers between its holder's): held by that joint too.
                self.verdicts[k] = Verdict(**base, held_by=tuple(sorted(joints)), reason="unsupported-connection")
                continue
            if collision:
                self.verdicts[k] = Verdict(**base, reason="collision")
                continue
            if not connected:
                self.verdicts[k] = Verdict(**base, reason="no-connection")
                continue
            self.to_clutch.append((k, base, unit, world, conns, outer, touched))
        self.to_collide = []
        STAGE_SECONDS["rules"] += time.perf_counter() - t0
        if self.backend != "jax":
            self.clutched(holds_alone_many(self.clutch_cases(), config.loads))

    def _joints(self, unit: Sequence[Placed], near) -> dict[int, np.ndarray]:
        """The structure parts among `near` that a part of the unit meets at a clip, bar, hinge or
        pin joint, with where (`unmodelled.bar_joints`: stretches of axis, world frame)."""
        if not any(len(p.part.flat.bars) + len(p.part.flat.bores) for p in unit):
            return {}  # nothing to be joined by (every part of the sampler's library)
        placed = self.structure.placed
        out = {}
        for i in sorted(near):
            found = [z for p in unit if len(z := bar_joints(p.part, p.pose, placed[i].part, placed[i].pose))]
            if found:
                out[i] = np.concatenate(found)
        return out

    def clutch_cases(self) -> list[tuple]:
        """`statics.holds_alone_many`'s cases for the connected candidates (mass, centre, the
        connections with the structure, ground support points)."""
        t0 = time.perf_counter()
        cfg, base_n = self.config.loads, self.base_n
        floor = None
        cases = []
        for k, base, unit, world, conns, outer, touched in self.to_clutch:
            if not outer:
                continue
            ground_y = None
            if self.standing:
                if self.floor_y is not None:
                    ground_y = self.floor_y
                else:
                    floor = self.structure.floor_y() if floor is None else floor
                    ground_y = max(floor, lowest_point(unit))
            cases.append(_alone_case(unit, outer, base_n, ground_y, cfg))
        STAGE_SECONDS["rules"] += time.perf_counter() - t0
        return cases

    def clutched(self, holds: Sequence[bool]) -> None:
        """The verdicts after the clutch rule (`holds`: one per candidate with a connection, in
        `clutch_cases`' order), then the CPU sweep for the reference or the queue for the batched
        sweeps."""
        t0 = time.perf_counter()
        structure, config = self.structure, self.config
        held = iter(holds)
        judged = 0
        for k, base, unit, world, conns, outer, touched in self.to_clutch:
            if outer and not next(held):
                self.verdicts[k] = Verdict(**base, clutch=False, reason="clutch")
                continue
            if self.judge_first is not None and judged >= self.judge_first:
                continue  # not judged: its verdict stays None (`CheckRequest.judge_first`)
            judged += 1
            dirs = seating_from_connections(outer, self.base_n)
            if outer and self.backend == "jax":
                # Swept later, with every call's candidates at once on the device (`sweep_jax`).
                self.to_sweep.append((k, base, unit, conns, world, touched, dirs))
                continue
            built = sweep(self.scene, structure, world, touched, config.max_penetration_ldu, directions=dirs) if outer else None
            self._after_sweep(k, base, built, unit, conns, outer)
        self.to_clutch = []
        STAGE_SECONDS["rules"] += time.perf_counter() - t0

    def sweep_group(self):
        """This call's sweeps for `sweep_jax.sweep_groups`, None if it has none."""
        if not self.to_sweep:
            return None
        return (lambda: self.scene, self.structure, [x[4] for x in self.to_sweep], [x[5] for x in self.to_sweep],
                self.config.max_penetration_ldu, [x[6] for x in self.to_sweep])

    def swept(self, built_all) -> None:
        for (k, base, unit, conns, *_), built in zip(self.to_sweep, built_all):
            self._after_sweep(k, base, built, unit, conns, True)
        self.to_sweep = []

    def _after_sweep(self, k, base, built, unit, conns, outer) -> None:
        """The verdict after buildability (`built`: None where not swept), or the candidate queued
        for the load check."""
        if built is not None:
            base.update(buildable=built.buildable, approach=built.reason, blocked_by=built.blocked_by)
            if built.buildable is False:
                self.verdicts[k] = Verdict(**base, clutch=True, reason=built.reason)
                return
        if self.standing and (outer or self.base_n == 0):
            self.verdicts[k] = Verdict(**base, clutch=True if outer else None)
            self.pending.append((k, list(unit), conns))
        else:
            # Held in hand (a sub-assembly), or laid on the table beside the structure with no
            # connection yet: nothing joins it to the structure to fall with.
            self.verdicts[k] = Verdict(**base, clutch=True if outer else None, stable=True)

    def loaded(self, results) -> None:
        """The verdicts after the loads (`results`: one per pending candidate, in order); pending
        candidates past the end of `results` are left unjudged (None: `_until_standing`)."""
        for (k, *_), lv in zip(self.pending, results):
            v = self.verdicts[k]
            self.verdicts[k] = replace(v, stable=lv.stands, load=None if lv.load is None else round(lv.load, 6),
                                       failing=lv.failing, reason=lv.reason)
        for k, *_ in self.pending[len(results):]:
            self.verdicts[k] = None
        self.pending = []


def _judge_loads(calls: Sequence[_Call], lp_jax) -> None:
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
        links = [Link(l.a + c.base_n, l.b + c.base_n, l.point) for l in c.unit_links]
        if c.judge_first is not None:
            # The asker takes the first survivor in the request's order (the sampler): the programs
            # one at a time, each started from the structure's own, up to the first that stands.
            c.loaded(_until_standing(c, loads, links))
            continue
        if lp_jax is not None and not links and loads.shared() and all(len(u) == 1 for _, u, _ in c.pending):
            # One part on a connected structure: its columns written once per structure, the
            # programs of every such call in shared launches (`solve_on_bases`).
            on_base.setdefault((cfg, c.explain), []).append((c, loads))
        else:
            general.append((c, [loads.model(unit, conns, links) for _, unit, conns in c.pending]))
    for (cfg, explain), members in on_base.items():
        groups = [(loads, [u for _, u, _ in c.pending], [cs for *_, cs in c.pending]) for c, loads in members]
        for (c, _), results in zip(members, judge_on_bases(groups, cfg, lp_jax.solve_on_bases, explain)):
            c.loaded(results)
    if not general:
        return
    if lp_jax is None:
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
        results = judge_many([m for _, ms in members for m in ms], cfg, lp_jax.solve_loads, explain=explain)
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
    """(floor_y, cfg) -> `statics.Solved`: the program its last part ended at as a candidate."""
    candidates: dict = field(default_factory=dict)
    """(unit key, floor_y, cfg) -> `statics.Solved` of the candidates solved at this length."""


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
            _, unit, conns = entry
            model = loads.model(unit, conns, links)
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
    (`statics.solve_from`); each candidate's own final basis is kept on the structure for the
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


def _alone_case(unit: Sequence[Placed], outer, base_n: int, ground_y: float | None, cfg: LoadConfig) -> tuple:
    """(mass, centre of mass, connections, ground support points) of a unit for `holds_alone_many`."""
    mass, weighted = 0.0, np.zeros(3)
    for p in unit:
        m, com, _ = part_mass_properties(p.part)
        mass += m
        weighted += m * p.pose.apply(com)
    conns = [(a >= base_n, pos, axis) for a, b, pos, axis in outer]
    ground = np.zeros((0, 3))
    if ground_y is not None:
        pts = [support_points(p, ground_y, cfg) for p in unit]
        ground = np.concatenate(pts) if pts else ground
    return mass, weighted / mass, conns, ground


_SCENE = KeepLast()
"""The last collision scene. The sampler checks one part against one structure in several calls
per step (batches, redraws of the same part); building the scene is most of a call's time."""
_LOADS = KeepLast()
"""The last structure's `LoadBase`, for the same reason."""


def _placed_key(structure: Structure, rel) -> tuple:
    return (tuple(id(p) for p in structure.placed),
            tuple((id(part), pose.R.tobytes(), pose.t.tobytes()) for part, pose in rel))


def _collision_scene(structure: Structure, rel, floor: float) -> CollisionScene:
    return _SCENE.get((_placed_key(structure, rel), float(floor)),
                      (list(structure.placed), [part for part, _ in rel]),
                      lambda: CollisionScene(structure, rel, floor))


def _load_base(structure: Structure, floor_y: float | None, cfg) -> LoadBase:
    return _LOADS.get((_placed_key(structure, ()), len(structure.links), floor_y, cfg), list(structure.placed),
                      lambda: LoadBase(structure.placed, structure.connections, floor_y, structure.links, cfg))


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
