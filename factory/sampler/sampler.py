"""Grow physics-verified objects one checked attachment at a time, with a density reward.

Object `i` under seed `s`: every random choice comes from `np.random.default_rng([s, i])`, in a
fixed order, so the object is the same whatever the batch, order, worker or machine.

Growth, per step:
1. draw a part and a colour (config weights; the first part among parts with studs);
2. enumerate its feasible attachments on the structure (`factory.physics.attach`); drop those reaching below the ground (counted 'below-ground');
3. take a random subset of at most `candidates_per_step` of them; score each by the density of
   the assembly after placing it (`density.DensityTracker`);
4. choose among those that pass the physics checks (`factory.physics.check.check`, ground fixed at
   the first part's lowest point) by a softmax of `density_weight * n * ln(density) / temperature`
   (n = parts after placement; see `SamplerConfig.temperature`). The softmax is drawn by the
   Gumbel-max trick: key = logit + Gumbel noise, candidates are walked in decreasing key order,
   and the first survivor is the choice. That is exactly the softmax over all survivors of the
   subset (the argmax of logit + Gumbel over the survivors), and it spares checking the
   candidates after it. When the walk reaches a candidate not checked yet, one request asks it
   and, after it, the next unasked candidates by their keys' upper bounds, up to `check_batch`
   (so densities are computed only as far as the walk goes); within a request only the first
   `judge_first` candidates past the clutch rule get the sweep and the loads, and a later request
   judges more if the walk reaches an unjudged one. Neither changes the object, only the cost;
5. if none survives, draw another part (and colour), at most `max_redraws` times, then end the
   object ('stuck', with the rejections of that step). A step whose first draw is a part held by
   joints alone (a pin, an axle, a beam: no studs, no sockets) draws its redraws from those parts
   (they attach only where the structure offers a mating connector: redrawn from all parts, they
   would be placed less often than drawn) `JOINT_REDRAWS` times, among those with a connector that
   mates a kind the structure's parts bring; where none has, among the parts placed by studs that
   bring such a kind (a Technic brick's holes, a plate's bar: `provider_p`), and the joint draw is
   owed: the next step where a joint part can mate draws its first part among those. Then, if none
   goes on, `max_redraws` more from all; so does a step whose first draw is a minifigure piece, among
   those that have a place on the structure (most go on only in a free slot of a figure's piece
   placed before: drawn among all of them, a hand would rarely meet a free arm). A first draw
   that is a minifigure piece is itself drawn again among the pieces with a free slot on the
   structure, where any has one, and goes in such a slot: a figure being built takes its next
   piece before another figure is started, as figures in designs are whole.
An object stuck before `min_steps` parts is grown again from a stream of its own, at most
`RESTARTS` times, and the longest attempt is kept (`Assembly.attempt`); the first attempt is the
object as it always was.
The first part is placed at the origin with the identity rotation (its lowest point fixes the
ground) and is checked like any other (it must stand on its own).
"""

from __future__ import annotations

import difflib
import os
from collections import Counter
from dataclasses import replace
from typing import Generator, Iterable, Iterator

import numpy as np

from factory.errors import LDrawError
from factory.ldraw import ColourTable, Reader, get_reader
from factory.ldraw.colours import EDGE, MAIN
from factory.parts import Part, load_part
from factory.physics.check import CheckRequest, Verdict
from factory.physics.checker import Checker
from factory.physics.structure import Placed, Structure
from factory.pose import Pose
from factory.sampler.assembly import Assembly, AssemblyStep
from factory.physics.attach import attachment_arrays, lowest_y
from factory.joints import GENDERS, held_by_joints_alone, joint_ends, mates
from factory.minifig import role
from factory.physics.joint_attach import attach_ends, joint_attachment_arrays
from factory.physics.minifig_attach import minifig_attachment_arrays
from factory.sampler.config import SamplerConfig, SamplerConfigError
from factory.sampler.density import CandidateDensities, DensityTracker
from factory.sampler.lockstep import grow_together

LIST_LIMIT = 80
"""Valid choices listed in full in an error up to this many; beyond, close matches and a count."""


class Sampler:
    """Grows objects under one configuration and library (`ldraw`: see `get_reader`), checked by
    `checker` (a `Checker` of the config's `check` and `backend`; default one on the process's
    default state, `Checker.shared`, whose caches and counters the module-level checks share)."""

    def __init__(self, config: SamplerConfig = SamplerConfig(), ldraw: str | os.PathLike | None = None,
                 checker: Checker | None = None):
        self.config = config
        if checker is None:
            checker = Checker.shared(config.check, config.backend)
        elif (checker.config, checker.backend) != (config.check, config.backend):
            raise ValueError(f"the checker's config and backend ({checker.backend!r}) are not the sampler config's "
                             f"check and backend ({config.backend!r}): objects would not be those of the config")
        self.checker = checker
        self.reader = get_reader(ldraw)
        self.parts: list[Part] = _load_parts(self.reader, config)
        self.part_p = _probabilities([w for _, w in config.parts])
        # The first part must carry studs (something has to be able to go on top of it), and be
        # no minifigure piece (a head's stud is no base for an object).
        roles = [role(p.description) for p in self.parts]
        studded = [w if p.studs and r is None else 0.0 for p, r, (_, w) in zip(self.parts, roles, config.parts)]
        self.first_p = _probabilities(studded) if any(studded) else self.part_p
        # Parts held by joints alone and minifigure pieces: the groups a step redraws within
        # (`JOINT_REDRAWS`), and each group's draw among its parts (none where the group is empty,
        # or is all the parts).
        self.group = ["minifig" if r is not None else "joints" if held_by_joints_alone(p) else None
                      for p, r in zip(self.parts, roles)]
        self.group_p = {}
        for g in ("joints", "minifig"):
            w = [w if pg == g else 0.0 for pg, (_, w) in zip(self.group, config.parts)]
            if any(w) and not all(pg == g for pg in self.group):
                self.group_p[g] = _probabilities(w)
        # The joint connector kinds each part brings to a structure, and those the parts held by
        # joints alone go onto (`joints.mates`): whether one of them can go on is known from the
        # structure's kinds without enumerating a pose. Providers: the other parts (placed by
        # their studs) that bring a kind a joint part goes onto (a Technic brick, a plate with
        # holes, a bar holder), drawn in a step whose joint part has nowhere to go.
        self.kinds = [frozenset(c.kind for c in attach_ends(p)) for p in self.parts]
        self.mating = [frozenset(k for k in GENDERS if any(mates(e, k) for e in kinds)) if g == "joints"
                       else frozenset() for kinds, g in zip(self.kinds, self.group)]
        wanted = frozenset().union(*self.mating)
        w = [w if pg is None and kinds & wanted else 0.0
             for pg, kinds, (_, w) in zip(self.group, self.kinds, config.parts)]
        self.provider_p = _probabilities(w) if "joints" in self.group_p and any(w) else None
        self.colours = [c for c, _ in config.colours]
        _check_colours(self.reader, self.colours)
        self.colour_p = _probabilities([w for _, w in config.colours])
        for part in self.parts:  # derive each part's connectors, symmetry and hull once, up front
            part.symmetry, part.hull_points

    def _can_mate(self, offered: set[str]) -> np.ndarray | None:
        """The joint parts' draw (`group_p`) among those with a connector that mates a kind the
        structure offers (`offered`), or None where none has."""
        p = self.group_p["joints"].copy()
        for i in np.flatnonzero(p):
            if not self.mating[i] & offered:
                p[i] = 0.0
        return _probabilities(p) if p.any() else None

    def _with_a_place(self, structure: Structure, in_slots_only: bool = False) -> np.ndarray | None:
        """The minifigure pieces' draw (`group_p`) among those that have an attachment on the
        structure (on their feet, or in a free slot of a placed piece; `in_slots_only`: in a
        slot), or None where none has."""
        p = self.group_p["minifig"].copy()
        for i in np.flatnonzero(p):
            if not len(minifig_attachment_arrays(structure, self.parts[i], in_slots_only)[1]):
                p[i] = 0.0
        return _probabilities(p) if p.any() else None

    # -- public -----------------------------------------------------------------------------------
    def sample(self, index: int) -> Assembly:
        """Object `index` (an integer >= 0) of this configuration."""
        return next(self.grow([index], batch=1))

    def sample_many(self, indices: Iterable[int], batch: int = 1) -> Iterator[Assembly]:
        """`sample(i)` for each index, in the given order (each object is independent of it and of
        `batch`: objects grown together in lockstep, see `grow`)."""
        indices = list(indices)
        left = Counter(indices)
        ready: dict[int, Assembly] = {}
        at = 0
        for a in self.grow(list(dict.fromkeys(indices)), batch):
            ready[a.index] = a
            while at < len(indices) and indices[at] in ready:
                i = indices[at]
                left[i] -= 1
                yield ready[i] if left[i] else ready.pop(i)
                at += 1

    def grow(self, indices: Iterable[int], batch: int = 1) -> Iterator[Assembly]:
        """Objects `indices`, `batch` of them grown together in lockstep (their checks of a step
        asked in one `check_many` call), each yielded when it ends (a finished object's slot goes to
        the next index). Every object is the one `sample` gives alone."""
        return grow_together(self, [_index(i) for i in indices], batch)

    def growth(self, index: int) -> Generator[CheckRequest, list, Assembly]:
        """Object `index` as a coroutine: it yields each batch of candidates to check (a
        `CheckRequest`), takes their verdicts back (`send`), and returns the `Assembly`. Every
        random choice comes from the object's own stream, in a fixed order."""
        cfg = self.config
        rng, target = _stream(cfg, index)
        best = None
        for restart in range(RESTARTS + 1):
            if restart:  # a fresh stream of its own: the first attempt is the object it always was
                rng = np.random.default_rng([cfg.seed, _index(index), restart])
            grown = yield from self._attempt(index, rng, target)
            if best is None or len(grown) > len(best):
                best = replace(grown, attempt=restart)
            if grown.end_reason != "stuck" or len(grown) >= cfg.min_steps:
                return best
        return best

    def _attempt(self, index: int, rng: np.random.Generator, target: int
                 ) -> Generator[CheckRequest, list, Assembly]:
        """One attempt at object `index`, growing towards `target` parts from `rng` (`growth`)."""
        cfg = self.config
        structure = Structure()
        tracker = DensityTracker()
        floor: float | None = None
        steps: list[AssemblyStep] = []
        end, stuck = "target", {}
        offered: set[str] = set()  # the joint connector kinds of the parts placed
        owed = 0  # joint draws that found nowhere to go, made again where a joint part can mate
        while len(steps) < target:
            rejected: Counter = Counter()
            checked = 0
            chosen = None
            group = None  # the group of the step's first draw, if it is in one
            within_p = None  # the redraws' draw within that group (None: none has a place)
            repaid = False  # the step's first draw is an owed joint draw
            for draw in range(cfg.max_redraws + 1 + JOINT_REDRAWS):
                first = not steps
                if draw > cfg.max_redraws and group is None:
                    break
                p = self.first_p if first else self.part_p
                if draw == 0 and owed and not first:
                    mating_p = self._can_mate(offered)
                    if mating_p is not None:
                        owed -= 1
                        p, repaid = mating_p, True
                if group is not None and draw <= JOINT_REDRAWS:
                    if within_p is None:
                        continue  # no minifigure piece has a place on the structure: draw from all
                    p = within_p
                part_i = int(rng.choice(len(self.parts), p=p))
                slotting = False
                if draw == 0 and not first and self.group[part_i] in self.group_p:
                    group = self.group[part_i]
                    within_p = self.group_p[group]
                    if group == "joints":
                        # Redraws among the joint parts that mate a kind the structure offers; where
                        # none does, among the parts that bring one (the joint draw is owed).
                        within_p = self._can_mate(offered)
                        if within_p is None:
                            within_p = self.provider_p
                    if group == "minifig":
                        # A figure being built takes its next piece: of the pieces with a free slot
                        # on the structure, where any has one, into such a slot.
                        slot_p = self._with_a_place(structure, in_slots_only=True)
                        if slot_p is not None:
                            part_i = int(rng.choice(len(self.parts), p=slot_p))
                            slotting = True
                        within_p = self._with_a_place(structure)
                part = self.parts[part_i]
                colour = self.colours[int(rng.choice(len(self.colours), p=self.colour_p))]
                if first:
                    ground = Structure([Placed(part, colour, Pose.identity())]).floor_y()
                    r, t = np.eye(3)[None], np.zeros((1, 3))
                    feasible = 1
                else:
                    ground = floor
                    if slotting:  # the next piece of a figure being built goes in a free slot
                        r, t = minifig_attachment_arrays(structure, part, in_slots_only=True)
                    else:
                        r, t = attachment_arrays(structure, part)
                        jr, jt = joint_attachment_arrays(structure, part)
                        if len(jt):  # through joints too (pins, axles, wheels, clips, open studs)
                            r, t = np.concatenate([r, jr]), np.concatenate([t, jt])
                        mr, mt = minifig_attachment_arrays(structure, part)
                        if len(mt):  # a minifigure piece: on its feet, or in a slot of a piece it joins
                            r, t = np.concatenate([r, mr]), np.concatenate([t, mt])
                    feasible = len(t)
                    if not feasible:
                        rejected["no-attachment"] += 1
                        continue
                    keep = lowest_y(part, r, t) <= ground + cfg.check.max_penetration_ldu
                    below = int(feasible - np.count_nonzero(keep))
                    if below:
                        rejected["below-ground"] += below
                    r, t = r[keep], t[keep]
                    if len(t) > cfg.candidates_per_step:
                        pick = np.sort(rng.choice(len(t), cfg.candidates_per_step, replace=False))
                        r, t = r[pick], t[pick]
                if not len(t):
                    continue
                poses = [Pose(ri, ti) for ri, ti in zip(r, t)]
                # Softmax over the survivors by the Gumbel-max trick: the survivor with the largest
                # logit + Gumbel noise. Checking candidates in decreasing order of that key and taking
                # the first survivor chooses exactly as a softmax over all survivors would, whatever
                # the batch size, and spares the checks of the candidates after it. `KeyOrder` gives
                # that order computing a candidate's density only where it can change it.
                n = len(steps) + 1  # parts after placement
                order = KeyOrder(tracker.candidates(part, r, t), cfg.density_weight * n, cfg.temperature,
                                 rng.gumbel(size=len(poses)))
                # Each candidate's verdict, once asked (it does not depend on the others asked with
                # it), and those asked whose sweep and loads were left for later (`judge_first`).
                verdict_of: dict[int, Verdict] = {}
                unjudged: set[int] = set()
                for i in order:  # exact key order; the walk stops at the first survivor
                    checked += 1
                    if i not in verdict_of:
                        if i in unjudged:
                            # Past the clutch rule but not judged: it and the next unjudged ones go
                            # again with every check.
                            ask = [i] + [j for j in order.rest() if j in unjudged][:cfg.judge_first - 1]
                        else:
                            # It and, after it, the next candidates not asked yet in the order of
                            # their keys' bounds, up to `check_batch` in one request: their
                            # densities are computed only if the walk reaches them.
                            ask = [i] + [j for j in order.rest() if j not in verdict_of and j not in unjudged
                                         ][:cfg.check_batch - 1]
                        # A rejected candidate's reason is counted, never its failing connections.
                        # Only the first `judge_first` candidates past the clutch rule are swept
                        # and load-judged (the dearest checks); the rest come back None.
                        verdicts = yield CheckRequest(structure, part, tuple(poses[j] for j in ask), colour, ground,
                                                      judge_first=cfg.judge_first, order=order.positions_by_key(ask))
                        for j, w in zip(ask, verdicts):
                            if w is None:
                                unjudged.add(j)
                            else:
                                verdict_of[j] = w
                                unjudged.discard(j)
                        if i not in verdict_of:
                            raise RuntimeError(f"object {index}: the checker left the first candidate of a "
                                               f"request unjudged (judge_first={cfg.judge_first})")
                    v = verdict_of[i]
                    if v.ok:
                        chosen = (part_i, part, colour, v, ground, draw + 1, feasible)
                        break
                    rejected[v.reason] += 1
                if chosen is not None:
                    break
            if chosen is None:
                end, stuck = "stuck", dict(sorted(rejected.items()))
                break
            part_i, part, colour, verdict, ground, draws, feasible = chosen
            if group == "joints" and not repaid and not held_by_joints_alone(part):
                owed += 1  # a joint part was drawn first but none went on: drawn again later
            offered |= self.kinds[part_i]
            floor = ground
            # Its joints go in as links (studs are found from the parts): later parts hung on it
            # are carried to the ground through them.
            structure.add(Placed(part, colour, verdict.pose), verdict.links(len(structure)))
            d = tracker.add(part, verdict.pose)
            steps.append(AssemblyStep(
                part=part.name, colour=colour, pose=verdict.pose, verdict=verdict,
                rejected=dict(sorted(rejected.items())), checked=checked, feasible=feasible,
                draws=draws, density=d,
            ))
        return Assembly(
            steps=tuple(steps), density=tracker.density() if steps else 0.0, seed=cfg.seed,
            index=int(index), target_steps=target, end_reason=end, stuck_rejected=stuck,
        )


RESTARTS = 3
"""Times an object stuck before `SamplerConfig.min_steps` parts is started again, each from a
stream of its own (`default_rng([seed, index, k])`); the longest attempt is kept (`Assembly.
attempt`). An object of a few parts teaches little: first parts with few places for others ended 6
of 64 library objects before 6 parts (64 objects of the shipped prior, seed 11)."""

JOINT_REDRAWS = 2
"""Redraws among the parts held by joints alone in a step whose first draw is one, or among the
minifigure pieces in a step whose first draw is one (each failed draw checks up to
`candidates_per_step` candidates, so a few)."""


class KeyOrder:
    """A draw's candidates in decreasing Gumbel-max key, `weight * ln(density) / temperature +
    noise` (ties by index: `np.argsort(-key, kind="stable")`), as an iterator, computing a
    candidate's density (a qhull call) only when its upper bound (`CandidateDensities.upper`)
    could put it before the next one given. Keys are computed for all candidates at once, exactly
    as from the full density vector, so the order, and so every object, is the one computing all
    densities first gives."""

    def __init__(self, densities: CandidateDensities, weight: float, temperature: float, noise: np.ndarray):
        self.densities, self.weight, self.temperature, self.noise = densities, weight, temperature, noise
        self.values = densities.upper.copy()
        # Without the reward no density enters a key; with a negative weight an upper bound of the
        # density is a lower bound of the key, so every density is computed.
        self.exact = np.full(len(noise), weight == 0) | [densities.known(i) for i in range(len(noise))]
        if weight < 0:
            self._settle(np.flatnonzero(~self.exact))
        self.given = np.zeros(len(noise), dtype=bool)

    @property
    def left(self) -> int:
        return int(np.count_nonzero(~self.given))

    def _keys(self) -> np.ndarray:
        if self.weight == 0:  # 0 * ln(d) adds nothing to the noise
            return self.noise + 0.0
        return self.weight * np.log(np.maximum(self.values, 1e-12)) / self.temperature + self.noise

    def _settle(self, indices) -> None:
        for j in indices:
            self.values[j] = self.densities.exact(int(j))
            self.exact[j] = True

    def __iter__(self):
        return self

    def __next__(self) -> int:
        """The next candidate in key order."""
        open_ = ~self.given
        if not open_.any():
            raise StopIteration
        while True:
            keys = self._keys()
            known = np.where(open_ & self.exact, keys, -np.inf)
            bound = np.where(open_ & ~self.exact, keys, -np.inf)
            best = int(np.argmax(known))  # the first of equal keys: the lowest index
            if (open_ & self.exact)[best] and known[best] > bound.max():
                self.given[best] = True
                return best
            self._settle([int(np.argmax(bound))])

    def positions_by_key(self, ask: list[int]):
        """For a request of candidates `ask`: a function from positions in `ask` to the same
        positions in decreasing exact key (ties by index), the order the walk takes them in
        (`CheckRequest.order`), computing those of their densities not known yet. It ends before
        the first whose key does not exceed every other open candidate's key bound: a candidate
        outside the request could come first in the walk there."""
        def by_key(positions: list[int]) -> list[int]:
            self._settle([ask[p] for p in positions if not self.exact[ask[p]]])
            keys = self._keys()
            outside = np.ones(len(keys), dtype=bool)
            outside[ask] = False
            outside &= ~self.given
            bound = keys[outside].max() if outside.any() else -np.inf
            ordered = sorted(positions, key=lambda p: (-keys[ask[p]], ask[p]))
            cut = next((i for i, p in enumerate(ordered) if not keys[ask[p]] > bound), len(ordered))
            return ordered[:cut]

        return by_key

    def rest(self) -> list[int]:
        """The candidates not given yet, by their keys' bounds (the order of a request; the key
        order among them is then walked by iterating)."""
        keys = self._keys()
        return [int(i) for i in np.argsort(-keys, kind="stable") if not self.given[i]]


def _stream(cfg: SamplerConfig, index) -> tuple[np.random.Generator, int]:
    """Object `index`'s random stream and its target length, the stream's first draw."""
    rng = np.random.default_rng([cfg.seed, _index(index)])
    return rng, int(rng.integers(cfg.min_steps, cfg.max_steps + 1))


def target_steps(cfg: SamplerConfig, index: int) -> int:
    """The length object `index` is grown towards (it may end sooner, stuck), known before it
    grows: a build schedules its largest shards first with it."""
    return _stream(cfg, index)[1]


def _index(index) -> int:
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"object index must be an integer >= 0, got {index!r}")
    return int(index)


# -- validation against the library ----------------------------------------------------------------
def library_parts(reader: Reader) -> list[str]:
    """Part names (no `.dat`) the library offers at its top level `parts/` folder."""
    return reader.library.part_names()


def library_colours(reader: Reader) -> list[int]:
    """Colour codes of the library's `LDConfig.ldr` (without 16 and 24, which are not colours)."""
    loc = reader.library.config()
    if loc is None:
        return []
    table = ColourTable.parse(loc.read().decode("utf-8", errors="replace"), loc.display)
    return sorted(c for c in table.colours if c not in (MAIN, EDGE))


def _choices(valid: list, wanted: str) -> str:
    if len(valid) <= LIST_LIMIT:
        return "valid choices: " + ", ".join(str(v) for v in valid)
    close = difflib.get_close_matches(wanted, [str(v) for v in valid], n=5, cutoff=0.5)
    hint = f"close matches: {', '.join(close)}; " if close else ""
    return f"{hint}{len(valid)} valid choices in the library (e.g. {', '.join(str(v) for v in valid[:10])})"


def _load_parts(reader: Reader, config: SamplerConfig) -> list[Part]:
    out = []
    for name, _ in config.parts:
        try:
            part = load_part(reader, name)
        except LDrawError:
            raise SamplerConfigError(
                f"parts: unknown part {name!r} in the {reader.library.description}; "
                f"{_choices(library_parts(reader), name)}"
            ) from None
        # (also derives studs and sockets, once per reader)
        if held_by_joints_alone(part) and not joint_ends(part) and role(part.description) is None:
            raise SamplerConfigError(f"parts: {name!r} has no studs, no sockets, no joint connector and is no "
                                     "minifigure piece the sampler attaches; it cannot attach to anything")
        out.append(part)
    return out


def _check_colours(reader: Reader, codes: list[int]) -> None:
    valid = library_colours(reader)
    for code in codes:
        if code in (MAIN, EDGE) or (valid and code not in valid):
            raise SamplerConfigError(
                f"colours: unknown colour code {code} in the {reader.library.description}; "
                f"{_choices(valid, str(code))}"
            )


def _probabilities(weights: list[float]) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64)
    return w / w.sum()


def grow(n: int, config: SamplerConfig | None = None, ldraw: str | os.PathLike | None = None, start: int = 0,
         batch: int = 1) -> list[Assembly]:
    """Objects `start` .. `start + n - 1` of `config` (default settings), grown from the LDraw
    library `ldraw` (a folder or LDraw's complete.zip; default `$LDRAWDIR`, else the embedded
    library), `batch` of them in lockstep (the same objects whatever `batch`), in index order."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    return list(Sampler(config or SamplerConfig(), ldraw).sample_many(range(start, start + n), batch))
