"""Load programs started from a solved one (`started_loads.solve_from`, `lp.solve_highs_from`): the same
optimum as a solve from nothing, in fewer simplex iterations, and the same sampled objects."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from factory.physics import started_loads
from factory.physics.check import check
from factory.physics.lp import Basis, solve_highs, solve_highs_from
from factory.physics.load_model import LoadBase, LoadConfig
from factory.physics.load_program import to_lp
from factory.physics.started_loads import Solved, solve_from, start_basis
from factory.physics.structure import Structure
from factory.sampler import Sampler, SamplerConfig
from factory.physics.check_state import DEFAULT
from ldraw_support import at

pytestmark = pytest.mark.usefixtures("isolated_cache")


def _grown(n: int = 2, steps: int = 24):
    sampler = Sampler(SamplerConfig(seed=3, min_steps=steps, max_steps=steps), None)
    by_name = {p.name.lower(): p for p in sampler.parts}
    return sampler, by_name, list(sampler.grow(range(n), batch=1))


def _structures(assembly, by_name):
    """The structure after each step of a sampled object, from its second part on."""
    from factory.physics.structure import Placed

    s = Structure()
    for k, step in enumerate(assembly.steps):
        s.add(Placed(by_name[step.part.lower()], step.colour, step.pose))
        if k:
            yield s


@pytest.fixture(scope="module")
def grown():
    return _grown()


def test_a_solve_from_nothing_is_linprogs_bit_for_bit_and_from_its_own_basis_takes_no_iteration(grown):
    _, by_name, objects = grown
    cfg = LoadConfig()
    checked = 0
    for s in list(_structures(objects[0], by_name))[::3]:
        lp = to_lp(LoadBase(s.placed, s.connections, s.floor_y(), s.links, cfg).alone(), cfg)
        want = solve_highs(lp)
        got, basis, iterations = solve_highs_from(lp)
        assert got.status == "optimal" and np.array_equal(got.x, want.x) and got.objective == want.objective
        assert iterations >= 0 and len(basis.cols) == lp.n and len(basis.rows) == lp.a_ub.shape[0] + lp.a_eq.shape[0]
        again, _, none = solve_highs_from(lp, basis)
        assert none == 0 and abs(again.objective - want.objective) <= 1e-12
        checked += 1
    assert checked >= 5


def test_each_structures_program_started_from_the_one_before_has_its_optimum_in_fewer_iterations(grown):
    """The sampler's chain: the program of each structure started from the basis the program of the
    structure one part smaller ended at (its parts numbered alike, its last part new)."""
    _, by_name, objects = grown
    cfg = LoadConfig()
    cold = warm = started = 0
    for a in objects:
        before = None
        for s in _structures(a, by_name):
            model = LoadBase(s.placed, s.connections, s.floor_y(), s.links, cfg).alone()
            lp = to_lp(model, cfg)
            want, _, n_cold = solve_highs_from(lp)
            got, solved = solve_from(model, cfg, before)
            if before is not None:
                started += start_basis(before, model, cfg) is not None
                assert abs(got.objective - want.objective) <= 1e-9 * max(1.0, abs(want.objective))
                cold += n_cold
                warm += DEFAULT.warm_counts["iterations"]
            DEFAULT.warm_counts["iterations"] = 0
            before = solved
    assert started >= 40
    assert warm * 3 < cold, (warm, cold)


def test_a_start_missing_a_body_or_a_support_point_is_refused():
    cfg = LoadConfig()
    s = Structure([at("3001", 0, 0, 0), at("3001", 0, -24, 0), at("3001", 40, -48, 0)])
    base = LoadBase(s.placed, s.connections, s.floor_y(), s.links, cfg)
    full = base.alone()
    _, basis, _ = solve_highs_from(to_lp(full, cfg))
    solved = Solved.of(full, basis)
    assert start_basis(solved, full, cfg) is not None
    # The tower without its top brick: a body of the solved program is missing.
    smaller = LoadBase(s.placed[:2], s.connections[:1], s.floor_y(), (), cfg).alone()
    assert start_basis(solved, smaller, cfg) is None
    # The same parts on a lower ground: no support point is found again.
    lower = LoadBase(s.placed, s.connections, s.floor_y() + 8, s.links, cfg).alone()
    assert start_basis(solved, lower, cfg) is None


def test_a_start_that_is_no_basis_of_the_program_gives_the_reference_answer():
    cfg = LoadConfig()
    s = Structure([at("3001", 0, 0, 0), at("3001", 0, -24, 0)])
    lp = to_lp(LoadBase(s.placed, s.connections, s.floor_y(), s.links, cfg).alone(), cfg)
    _, basis, _ = solve_highs_from(lp)
    short = Basis(basis.cols[:-1], basis.rows)
    got, final, iterations = solve_highs_from(lp, short)
    want = solve_highs(lp)
    assert final is None and iterations == -1
    assert np.array_equal(got.x, want.x) and got.objective == want.objective


def _digest(objects) -> str:
    h = hashlib.sha256()
    for a in objects:
        for st in a.steps:
            h.update(repr((st.part, st.colour, st.pose.R.tobytes(), st.pose.t.tobytes(), st.verdict.load,
                           st.verdict.reason, st.rejected)).encode())
    return h.hexdigest()


def test_sampled_objects_and_their_loads_are_the_same_with_started_programs_as_without(monkeypatch):
    DEFAULT.warm_counts.update(started=0, cold=0, iterations=0)
    started = _digest(_grown(2, 20)[2])
    counts = dict(DEFAULT.warm_counts)
    monkeypatch.setattr(started_loads, "WARM_START", False)
    DEFAULT.warm_counts.update(started=0, cold=0, iterations=0)
    cold = _digest(_grown(2, 20)[2])
    assert DEFAULT.warm_counts["started"] == 0
    assert counts["started"] >= 30 and counts["cold"] <= 4, counts
    assert counts["iterations"] * 3 < DEFAULT.warm_counts["iterations"], (counts, DEFAULT.warm_counts)
    assert started == cold


def test_a_structure_starts_only_from_the_program_of_the_part_it_placed_last():
    """`check` keeps each candidate's final basis on the structure; once a part is added, only that
    part's program starts the next candidates' programs."""
    s = Structure([at("3001", 0, 0, 0)])
    floor = s.floor_y()
    DEFAULT.warm_counts.update(started=0, cold=0, iterations=0)
    top = at("3001", 0, -24, 0)
    assert check(s, top.part, [top.pose], floor_y=floor)[0].ok
    assert (DEFAULT.warm_counts["started"], DEFAULT.warm_counts["cold"]) == (0, 1)
    s.add(top)
    asked = at("3001", 0, -48, 0)
    assert check(s, asked.part, [asked.pose], floor_y=floor)[0].ok
    assert (DEFAULT.warm_counts["started"], DEFAULT.warm_counts["cold"]) == (1, 1)
    # A part placed one stud along from the one asked: its program was never solved, so the
    # candidates on top of it start from nothing.
    s.add(at("3001", 20, -48, 0))
    nxt = at("3001", 20, -72, 0)
    assert check(s, nxt.part, [nxt.pose], floor_y=floor)[0].ok
    assert (DEFAULT.warm_counts["started"], DEFAULT.warm_counts["cold"]) == (1, 2)


def test_a_structure_keeps_the_bases_of_its_first_candidates_only(monkeypatch):
    """Judging many candidates against one structure keeps at most `KEPT_BASES` of their bases."""
    from factory.physics import check_loads

    monkeypatch.setattr(check_loads, "KEPT_BASES", 3)
    s = Structure([at("3001", 0, 0, 0)])
    poses = [at("3001", x, -24, z).pose for x in (-20, 0, 20) for z in (-20, 0, 20)]
    verdicts = check(s, at("3001", 0, 0, 0).part, poses, floor_y=s.floor_y())
    assert sum(v.stable is not None for v in verdicts) >= 5
    assert len(s.solved_loads.candidates) == 3


@pytest.mark.slow
def test_the_batched_path_solves_the_samplers_load_programs_one_by_one_started_too(monkeypatch):
    """With 'jax' the sampler's candidates (it takes the first survivor: `judge_first`) get their
    load programs one at a time, each started from the structure's own, up to the first that
    stands, as the reference does: none goes to the device solver, and the objects and their loads
    are the reference's."""
    pytest.importorskip("jax")
    from factory.physics import loads_jax

    sent = []
    for name in ("solve_on_bases", "solve_loads"):
        real = getattr(loads_jax, name)
        monkeypatch.setattr(loads_jax, name, lambda *a, real=real, name=name, **k: sent.append(name) or real(*a, **k))
    DEFAULT.warm_counts.update(started=0, cold=0, iterations=0)
    sampler = Sampler(SamplerConfig(seed=3, min_steps=20, max_steps=20, backend="jax"), None)
    batched = _digest(sorted(sampler.grow(range(2), batch=2), key=lambda a: a.index))
    assert sent == []
    assert DEFAULT.warm_counts["started"] >= 30, DEFAULT.warm_counts
    assert batched == _digest(_grown(2, 20)[2])
