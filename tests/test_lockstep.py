"""Objects grown in lockstep: the same objects whatever the batch, and one checker call per round
that answers every object as `check` answers it alone."""

from __future__ import annotations

import numpy as np
import pytest

from factory.physics.check import CheckRequest, check, check_many
from factory.physics.structure import Placed, Structure
from factory.sampler import Sampler, SamplerConfig

PARTS = {"3001": 1.0, "3003": 1.0, "3004": 1.0, "3020": 1.0, "3022": 0.5, "3039": 0.5, "3068b": 0.3}
TINY = dict(parts=PARTS, colours=[4, 1, 15], min_steps=2, max_steps=4, candidates_per_step=8, check_batch=4)


@pytest.fixture(scope="module")
def alone() -> dict[int, bytes]:
    """Each of 64 objects grown on its own (batch 1), as LDraw bytes."""
    s = Sampler(SamplerConfig(seed=3, **TINY))
    return {a.index: a.ldr_text(f"object_{a.index:05d}.ldr").encode() for a in s.sample_many(range(64))}


@pytest.mark.slow
@pytest.mark.parametrize("batch", [4, 64])
def test_objects_are_byte_identical_whatever_the_batch(alone, batch, tmp_path):
    s = Sampler(SamplerConfig(seed=3, **TINY))
    got = {}
    for a in s.grow(range(64), batch=batch):
        got[a.index] = a.to_ldr(tmp_path / f"object_{a.index:05d}.ldr").read_bytes()
    assert sorted(got) == list(range(64))
    assert got == alone
    assert len(set(alone.values())) == 64  # 64 different objects, not one repeated


def test_objects_are_the_same_whatever_judge_first(alone):
    """Judging only the first candidate past the clutch rule per request (more requests, fewer
    sweeps and load programs) grows the objects byte for byte as judging all of them does."""
    s = Sampler(SamplerConfig(seed=3, **{**TINY, "check_batch": 8, "judge_first": 1}))
    got = {a.index: a.ldr_text(f"object_{a.index:05d}.ldr").encode() for a in s.grow(range(64), batch=8)}
    assert got == alone


def _rounds(s: Sampler, index: int) -> int:
    """How many check requests object `index` makes (each answered by `check_many` alone, so
    `judge_first` holds)."""
    gen, n = s.growth(index), 0
    req = next(gen)
    while True:
        n += 1
        (verdicts,) = check_many([req], s.config.backend, s.config.check, explain=False)
        try:
            req = gen.send(verdicts)
        except StopIteration:
            return n


def test_a_finished_object_gives_its_slot_to_the_next_index():
    s = Sampler(SamplerConfig(seed=3, **{**TINY, "min_steps": 1, "max_steps": 6}))
    rounds = {i: _rounds(s, i) for i in range(8)}
    assert len(set(rounds.values())) > 1  # objects of different lengths, so the order says something
    # Two slots: each round answers every live object; an object leaves after its last request and
    # the next index joins at the end, so the order they end in follows from their request counts.
    live, waiting, expected = [], list(range(8)), []
    while live or waiting:
        while len(live) < 2 and waiting:
            i = waiting.pop(0)
            live.append([i, rounds[i]])
        for slot in live:
            slot[1] -= 1
        expected += [i for i, left in live if left == 0]
        live = [slot for slot in live if slot[1] > 0]
    order = [a.index for a in s.grow(range(8), batch=2)]
    assert order == expected and sorted(order) == list(range(8))
    # sample_many gives the caller's order whatever the batch.
    assert [a.index for a in s.sample_many([5, 1, 7, 1], batch=3)] == [5, 1, 7, 1]
    # Indices may come from an iterator (read once).
    assert sorted(a.index for a in s.grow(iter([2, 0]), batch=2)) == [0, 2]


def test_batch_must_be_a_positive_integer():
    s = Sampler(SamplerConfig(seed=3, **TINY))
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match="batch must be an integer >= 1"):
            list(s.grow(range(2), batch=bad))


def _requests(n_objects: int = 6, per: int = 48) -> list[CheckRequest]:
    """Real questions of the sampler: the structures of six grown objects, each asked about the
    next part at the feasible attachments the sampler would consider (near-limit ones included:
    most are rejected, by every rule)."""
    from factory.physics.attach import attachment_arrays
    from factory.pose import Pose

    s = Sampler(SamplerConfig(seed=5, **{**TINY, "min_steps": 6, "max_steps": 10}))
    rng = np.random.default_rng(0)
    out = []
    for a in s.sample_many(range(n_objects)):
        parts = {p.name: p for p in s.parts}
        structure = Structure([Placed(parts[st.part], st.colour, st.pose) for st in a.steps])
        part = s.parts[int(rng.integers(len(s.parts)))]
        r, t = attachment_arrays(structure, part)
        pick = rng.choice(len(t), min(per, len(t)), replace=False)
        out.append(CheckRequest(structure, part, tuple(Pose(r[i], t[i]) for i in pick), 4,
                                structure.floor_y()))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["cpu", "jax"])
def test_check_many_answers_each_request_as_check_does(backend):
    if backend == "jax":
        pytest.importorskip("jax")
    requests = _requests()
    many = check_many(requests, backend, explain=False)
    reasons = set()
    total = 0
    for r, got in zip(requests, many):
        want = check(r.structure, r.part, list(r.poses), "cpu", colour=r.colour, floor_y=r.floor_y,
                     explain=False)
        assert [v.reason for v in got] == [v.reason for v in want]
        assert [v.buildable for v in got] == [v.buildable for v in want]
        assert [v.load for v in got] == pytest.approx([v.load for v in want], abs=1e-6)
        reasons |= {v.reason for v in got}
        total += len(got)
    assert total >= 200
    assert {None, "collision"} <= reasons and len(reasons) >= 3  # accepted and rejected, several rules


@pytest.mark.parametrize("given, expected", [(None, "false"), ("true", "true")])
def test_jax_processes_share_the_gpu_memory(given, expected):
    """Every JAX process of a run (parent, growers, shard workers) allocates GPU memory as it needs
    it, unless the user chose: with JAX's default the first process takes 75% of the card and the
    others fail (seen with 16 synth workers on one H100)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "XLA_PYTHON_CLIENT_PREALLOCATE"}
    if given is not None:
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = given
    code = ("import os, factory.physics.check, jax; jax.default_backend(); "
            "print(os.environ['XLA_PYTHON_CLIENT_PREALLOCATE'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected


@pytest.mark.parametrize("backend", ["cpu", "jax"])
def test_judge_first_leaves_only_later_survivors_unjudged(backend):
    """With `judge_first=2` the sweep and the loads judge the first two candidates of each request
    that pass the clutch rule; every later one comes back None, and so does one of those two that
    reached the loads after the first that stands (the asker takes the first survivor). Every
    other verdict is `check`'s."""
    if backend == "jax":
        pytest.importorskip("jax")
    from dataclasses import replace

    requests = _requests()
    many = check_many([replace(r, judge_first=2) for r in requests], backend, explain=False)
    unjudged = stopped = 0
    for r, got in zip(requests, many):
        want = check(r.structure, r.part, list(r.poses), "cpu", colour=r.colour, floor_y=r.floor_y,
                     explain=False)
        past_clutch = [i for i, v in enumerate(want) if v.clutch]
        judged = past_clutch[:2]
        standing = [i for i in judged if want[i].ok]
        after = [i for i in judged if standing and i > standing[0] and want[i].buildable is not False]
        assert [i for i, v in enumerate(got) if v is None] == sorted(after + past_clutch[2:])
        stopped += len(after)
        for v, w in zip(got, want):
            if v is not None:
                assert (v.reason, v.buildable, v.clutch) == (w.reason, w.buildable, w.clutch)
                assert v.load == pytest.approx(w.load, abs=1e-6)
        unjudged += len(past_clutch[2:])
    assert unjudged >= 10  # requests with more survivors than two: the limit was exercised
    assert stopped >= 3  # requests whose loads stopped at a standing candidate before the second
    with pytest.raises(ValueError, match="judge_first must be None or >= 1"):
        check_many([replace(requests[0], judge_first=0)], backend)


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["cpu", "jax"])
def test_loads_after_the_first_candidate_go_in_the_askers_order(backend):
    """With `CheckRequest.order`, when a request's first candidate does not stand, the load programs
    of the others go in the asker's order up to the first that stands, and stop before the first
    candidate left unjudged (`judge_first`) or where the order ends: those it does not reach come
    back None. Here the asker's order is the reverse of the request's, then one that ends at once."""
    if backend == "jax":
        pytest.importorskip("jax")
    from dataclasses import replace

    def solved(want, reach, walk):
        seq = [i for i in reach if i == 0]
        if not (seq and want[0].ok):
            seq += walk
        out = []
        for i in seq:
            out.append(i)
            if want[i].ok:
                break
        return out

    def until(walk, stops):
        """`walk` up to its first position in `stops`."""
        cut = next((j for j, i in enumerate(walk) if i in stops), len(walk))
        return walk[:cut]

    requests = _requests()
    reverse = lambda positions: sorted(positions, reverse=True)  # noqa: E731
    ends_at_once = lambda positions: []  # noqa: E731
    differs = stopped = ended = 0
    for order in (reverse, ends_at_once):
        many = check_many([replace(r, judge_first=4, order=order) for r in requests], backend, explain=False)
        for r, got in zip(requests, many):
            want = check(r.structure, r.part, list(r.poses), "cpu", colour=r.colour, floor_y=r.floor_y,
                         explain=False)
            past_clutch = [i for i, v in enumerate(want) if v.clutch]
            reach = [i for i in past_clutch[:4] if want[i].buildable is not False]
            rest = [i for i in reach if i != 0]
            unjudged = set(past_clutch[4:])
            walk = until(order(rest + sorted(unjudged)), unjudged)
            judged = solved(want, reach, walk)
            assert [i for i, v in enumerate(got) if v is None] == sorted(set(reach) - set(judged) | unjudged)
            for i in judged:
                assert (got[i].reason, got[i].load) == (want[i].reason, pytest.approx(want[i].load, abs=1e-6))
            alone = solved(want, reach, rest)
            differs += set(judged) != set(alone)
            stopped += order is reverse and bool(unjudged) and len(alone) > len(judged)
            ended += order is ends_at_once and len(alone) > len(judged)
    assert differs >= 2  # requests whose answer the order changed
    assert stopped >= 1  # programs the request's order would solve, not solved before an unjudged one
    assert ended >= 1  # nor those after the end of the asker's order
    with pytest.raises(ValueError, match="CheckRequest.order gave"):
        check_many([replace(r, judge_first=4, order=lambda p: [max(p) + 1]) for r in requests], backend)
    with pytest.raises(ValueError, match="CheckRequest.order gave"):
        check_many([replace(r, judge_first=4, order=lambda p: p + p) for r in requests], backend)


def _asked(s: Sampler, index: int) -> tuple[list[int], bytes]:
    """The sizes of object `index`'s check requests (each answered by `check_many` alone, so
    `judge_first` holds) and the object's LDraw bytes."""
    gen, sizes = s.growth(index), []
    req = next(gen)
    while True:
        sizes.append(len(req.poses))
        (verdicts,) = check_many([req], s.config.backend, s.config.check, explain=False)
        try:
            req = gen.send(verdicts)
        except StopIteration as end:
            return sizes, end.value.ldr_text(f"object_{index:05d}.ldr").encode()


def test_check_batch_bounds_each_request_and_smaller_requests_ask_fewer_candidates():
    """A request holds at most `check_batch` candidates: the walk's next one and the next unasked
    ones by their keys' bounds. Smaller requests check fewer candidates in all (the walk stops at
    the first survivor, usually long before a draw's last candidate) and grow the same objects."""
    cfg = {**TINY, "candidates_per_step": 16, "min_steps": 5, "max_steps": 5}
    asked = {}
    for k in (3, 16):
        s = Sampler(SamplerConfig(seed=5, **{**cfg, "check_batch": k}))
        asked[k] = [_asked(s, i) for i in range(3)]
        assert max(n for sizes, _ in asked[k] for n in sizes) <= k
    assert [ldr for _, ldr in asked[3]] == [ldr for _, ldr in asked[16]]
    assert sum(map(sum, (sizes for sizes, _ in asked[3]))) < sum(map(sum, (sizes for sizes, _ in asked[16])))
    assert max(n for sizes, _ in asked[16] for n in sizes) > 3  # the larger bound was used


@pytest.mark.slow
def test_the_batched_walk_solves_only_the_load_programs_the_reference_solves(monkeypatch):
    """Objects of the default config (of 10-12 steps) grown two at a time with the batched checks
    (requests of `check_batch` candidates, `judge_first` of them judged) solve exactly the load programs the
    reference solves asking one candidate at a time: none for a candidate the walk would not reach
    (one after a candidate left unjudged, or after one outside the request whose key bound is
    higher). The same objects."""
    pytest.importorskip("jax")
    import factory.physics.check_loads as chk

    solved = []
    real = chk.solve_from

    def counted(*args, **kwargs):
        solved.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(chk, "solve_from", counted)
    programs, objects = {}, {}
    for backend, batch in (("cpu", 1), ("jax", 2)):
        solved.clear()
        s = Sampler(SamplerConfig(seed=0, backend=backend, min_steps=10, max_steps=12))
        grown = sorted(s.grow(range(2), batch=batch), key=lambda a: a.index)
        objects[backend] = [a.ldr_text(f"object_{a.index:05d}.ldr") for a in grown]
        programs[backend] = len(solved)
    assert s.config.check_batch > 1 and s.config.judge_first > 1  # the batched walk's requests
    assert objects["jax"] == objects["cpu"]
    assert programs["jax"] == programs["cpu"] > 0
