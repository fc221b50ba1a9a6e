"""The physics checks as one object (`factory.physics.Checker`): each checker owns its caches,
counters and capacity; two in one process share none of them, and the sampler's lockstep grower
widens only its own checker's caches."""

from __future__ import annotations

from dataclasses import replace

import pytest

from factory.physics import Checker
from factory.physics.check import CheckConfig, check
from factory.physics.check_state import CheckState
from factory.physics.structure import Structure
from factory.sampler import Sampler, SamplerConfig
from ldraw_support import at

PARTS = {"3001": 1.0, "3003": 1.0, "3004": 1.0, "3020": 1.0, "3022": 0.5, "3039": 0.5, "3068b": 0.3}
TINY = dict(parts=PARTS, colours=[4, 1, 15], min_steps=2, max_steps=4, candidates_per_step=8, check_batch=4)


def _tower(n: int = 2) -> Structure:
    return Structure([at("3001", 0, -24 * k, 0) for k in range(n)])


def _ask(checker: Checker, s: Structure) -> list:
    """The verdicts of a brick on top of the tower and one half a brick along (poses as bytes:
    `Pose` compares by identity)."""
    top = at("3001", 0, -24 * len(s.placed), 0)
    beside = at("3001", 20, -24 * len(s.placed), 0)
    return _plain(checker.check(s, top.part, [top.pose, beside.pose], floor_y=s.floor_y()))


def _plain(verdicts) -> list:
    return [(v.pose.R.tobytes(), v.pose.t.tobytes(), replace(v, pose=None)) for v in verdicts]


def _cached(state: CheckState) -> dict[str, int]:
    return {name: len(c) for name, c in state.caches().items()}


def test_two_checkers_keep_separate_counters_and_caches():
    a, b = Checker(), Checker()
    s = _tower()
    top = at("3001", 0, -48, 0)
    want = _plain(check(s, top.part, [top.pose, at("3001", 20, -48, 0).pose], floor_y=s.floor_y()))
    shared_before = Checker.shared().counters()
    got = _ask(a, s)
    assert got == want  # the module-level function's verdicts
    assert got[0][2].ok
    after_a = a.counters()
    assert after_a["stage_seconds"]["rules"] > 0 and after_a["stage_seconds"]["loads"] > 0
    assert sum(after_a["warm_counts"].values()) > 0
    assert _cached(a.state)["scenes"] == 1 and _cached(a.state)["bodies"] == len(s.placed)
    # b has asked nothing: no counter and no cache of its own moved.
    assert b.counters() == {"stage_seconds": {}, "sweep_counts": {}, "warm_counts": {"started": 0, "cold": 0,
                                                                                     "iterations": 0}}
    assert not any(_cached(b.state).values())
    # b asks the same: the same verdicts; a's counters and caches stay where they were.
    cached_a = _cached(a.state)
    assert _ask(b, s) == got
    assert a.counters() == after_a and _cached(a.state) == cached_a
    assert b.counters()["stage_seconds"].keys() == after_a["stage_seconds"].keys()
    # Neither touched the process's default state, the module-level functions'.
    shared_now = Checker.shared().counters()
    assert shared_now == shared_before


def test_counters_report_stage_seconds_and_reset():
    c = Checker(CheckConfig(), "cpu")
    _ask(c, _tower(3))
    stages = c.counters()["stage_seconds"]
    assert set(stages) <= {"rules", "collide", "clutch", "sweep", "loads"} and stages["rules"] > 0
    snapshot = c.counters()
    _ask(c, _tower(3))
    assert snapshot["stage_seconds"] == stages  # a snapshot, not a live view
    c.reset_counters()
    assert c.counters() == {"stage_seconds": {}, "sweep_counts": {}, "warm_counts": {"started": 0, "cold": 0,
                                                                                     "iterations": 0}}
    assert _cached(c.state)["scenes"] == 1  # counters reset, caches kept


def test_holding_widens_only_that_checkers_caches_and_restores_them():
    a, b = Checker(), Checker(capacity=2)
    towers = [_tower(n) for n in (1, 2, 3)]
    with a.holding(3) as held:
        assert held is a
        assert all(c.capacity == 3 for c in a.state.keep_last())
        assert all(c.capacity == 2 for c in b.state.keep_last())
        assert all(c.capacity == 1 for c in Checker.shared().state.keep_last())
        for s in towers:
            _ask(a, s)
        assert _cached(a.state)["scenes"] == 3 and _cached(a.state)["load_bases"] == 3
    assert all(c.capacity == 1 for c in a.state.keep_last())
    assert _cached(a.state)["scenes"] == 1 and _cached(a.state)["load_bases"] == 1  # the newest kept
    with b.holding(1):  # never below the checker's own capacity
        assert all(c.capacity == 2 for c in b.state.keep_last())


def test_clear_drops_the_checkers_caches_all_or_named():
    c = Checker()
    _ask(c, _tower())
    assert _cached(c.state)["alone"] and _cached(c.state)["bodies"]
    c.clear(["alone"])
    assert not _cached(c.state)["alone"] and _cached(c.state)["bodies"]
    c.clear()
    assert not any(_cached(c.state).values())
    with pytest.raises(ValueError, match="unknown caches"):
        c.clear(["nothing"])
    with pytest.raises(ValueError, match="capacity must be an integer"):
        Checker(capacity=0)
    with pytest.raises(ValueError, match="unknown check backend"):
        Checker(backend="gpu")


def test_lockstep_growth_with_its_own_checker_is_the_growth_alone():
    """Three small objects grown two at a time on a checker of their own (its caches held for the
    batch) are byte for byte those grown one at a time on the default one, and only that checker
    counts their checks."""
    config = SamplerConfig(seed=5, **TINY)
    alone = {a.index: a.ldr_text("o.ldr") for a in Sampler(config).sample_many(range(3))}
    own = Checker(config.check, config.backend)
    shared_before = Checker.shared().counters()
    together = Sampler(config, checker=own)
    assert together.checker is own
    got = {a.index: a.ldr_text("o.ldr") for a in together.grow(range(3), batch=2)}
    assert got == alone
    assert own.counters()["stage_seconds"]["rules"] > 0
    assert Checker.shared().counters() == shared_before
    assert all(c.capacity == 1 for c in own.state.keep_last())  # back after the growth
    with pytest.raises(ValueError, match="not the sampler config's"):
        Sampler(config, checker=Checker(CheckConfig(max_penetration_ldu=0.25), config.backend))


def test_the_batched_backends_counters_are_its_checkers():
    """With 'jax' the sweeps a checker sends to the device are counted on it alone (the threads
    that choose piece pairs run in its state too), and its verdicts are the reference's."""
    pytest.importorskip("jax")
    batched, reference = Checker(backend="jax"), Checker(backend="cpu")
    s = _tower()
    shared_before = Checker.shared().counters()
    assert _ask(batched, s) == _ask(reference, s)
    counts = batched.counters()
    assert counts["sweep_counts"].get("device", 0) >= 1, counts
    assert counts["stage_seconds"]["collide"] > 0 and counts["stage_seconds"]["clutch"] >= 0
    assert reference.counters()["sweep_counts"] == {}
    assert _cached(batched.state)["structure_pieces"] == 1 and _cached(reference.state)["structure_pieces"] == 0
    assert Checker.shared().counters() == shared_before
