"""The batched JAX LP solver (`factory.physics.lp_jax`, its kernel `interior_point_jax`) against HiGHS:
random LPs with every kind of bound, load programs of the kind it is for (generated, and real ones
from a grown structure, with their verdicts near s = 1, also written straight from their models by
`loads_jax`), a cantilever worked by hand, batching and compiles."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("jax")

from factory.physics import interior_point_jax, loads_jax, lp_jax  # noqa: E402
from factory.physics.lp import LinearProgram, solve_highs  # noqa: E402
from pipelines.bench_solver import statics_like_lp  # noqa: E402


def assert_agrees(lp: LinearProgram, res, ref) -> None:
    """Same objective as HiGHS within 1e-7 * max(1, |objective|), and x feasible: equalities and
    inequalities within 1e-6 of the right-hand side's size, bounds exact."""
    assert ref.status == "optimal" and res.status == "optimal"
    assert abs(res.objective - ref.objective) <= 1e-7 * max(1.0, abs(ref.objective))
    eq, ub, bd = lp.residuals(res.x)
    scale = 1 + np.linalg.norm(np.r_[lp.b_eq, lp.b_ub])
    assert eq <= 1e-6 * scale and ub <= 1e-6 * scale and bd == 0


def random_lp(rng: np.random.Generator, n: int = 40, m_eq: int = 12, m_ub: int = 20) -> LinearProgram:
    """A feasible, bounded LP. Variables cycle through free, lower-bounded, upper-bounded, boxed
    and fixed; x0 within the bounds satisfies every row (b_eq = A x0, b_ub = A_ub x0 + slack, half
    the rows active), and c = A_eq^T u + A_ub^T v + lam with v <= 0 and lam of the bounds' signs is
    dual feasible, so the optimum is finite. Two equality entries per column and three per
    inequality row (distinct columns, none fixed, each column in at most two rows) keep every such
    LP of one size in one shape bucket; every such row is of the general kind the solver turns into an
    equality row and a new variable."""
    eq_at = (rng.integers(0, m_eq, 2 * n), np.repeat(np.arange(n), 2))
    a_eq = sp.csr_matrix((rng.standard_normal(2 * n), eq_at), shape=(m_eq, n))
    free = np.flatnonzero(np.arange(n) % 5 != 4)  # not the fixed variables
    ub_at = (np.repeat(np.arange(m_ub), 3), rng.permutation(free)[np.arange(3 * m_ub) % len(free)])
    a_ub = sp.csr_matrix((rng.standard_normal(3 * m_ub), ub_at), shape=(m_ub, n))
    kind = np.arange(n) % 5
    lower = np.where(np.isin(kind, (1, 3, 4)), rng.uniform(-2, 0, n), -np.inf)
    upper = np.where(kind == 2, rng.uniform(0, 2, n), np.where(kind == 3, lower + rng.uniform(0.5, 2, n), np.inf))
    upper = np.where(kind == 4, lower, upper)
    lo, up = np.where(np.isfinite(lower), lower, 0.0), np.where(np.isfinite(upper), upper, 0.0)
    x0 = np.select(
        [kind == 0, kind == 1, kind == 2, kind == 3],
        [rng.standard_normal(n), lo + rng.exponential(1, n), up - rng.exponential(1, n),
         lo + rng.random(n) * (up - lo)],
        lo,
    )
    active = rng.random(m_ub) < 0.5
    b_ub = a_ub @ x0 + np.where(active, 0.0, rng.exponential(1, m_ub))
    v = np.where(active, -rng.exponential(1, m_ub), 0.0)
    lam = np.select([kind == 1, kind == 2, kind >= 3],
                    [rng.exponential(1, n), -rng.exponential(1, n), rng.standard_normal(n)], 0.0)
    c = a_eq.T @ rng.standard_normal(m_eq) + a_ub.T @ v + lam
    return LinearProgram(c, a_eq, a_eq @ x0, a_ub, b_ub, lower, upper)


@pytest.fixture(scope="module")
def load_programs() -> list[LinearProgram]:
    """Five load programs of ~150 variables that run in one launch (several structures are drawn,
    the largest group with the same equality rows' and slots' buckets kept: the file then compiles
    few shapes)."""
    rng = np.random.default_rng(1)
    lps = [statics_like_lp(rng, 150) for _ in range(16)]
    buckets = [lp_jax.bucket_of(lp)[1::2] for lp in lps]
    common = max(set(buckets), key=buckets.count)
    group = [lp for lp, b in zip(lps, buckets) if b == common]
    assert len(group) >= 5 and len({lp.n for lp in group}) > 1
    return group[:5]


def test_random_lps_match_highs():
    rng = np.random.default_rng(0)
    lps = [random_lp(rng) for _ in range(8)]
    assert len({lp_jax.bucket_of(lp) for lp in lps}) == 1
    for lp, res, ref in zip(lps, lp_jax.solve_batch(lps), [solve_highs(lp) for lp in lps]):
        assert_agrees(lp, res, ref)


def test_load_programs_match_highs(load_programs):
    results = lp_jax.solve_batch(load_programs[:4])
    for lp, res in zip(load_programs, results):
        assert_agrees(lp, res, solve_highs(lp))
    # Both verdicts are among them: the structure holds (s <= 1) and is overloaded (s > 1).
    assert min(r.objective for r in results) < 1 < max(r.objective for r in results)


def test_load_programs_with_random_loads_match_highs(load_programs):
    """The load programs' matrices and bounds with random right-hand sides: x0 within the bounds
    (free forces, nonnegative ground forces and s), b_eq = A_eq x0, b_ub = A_ub x0 + slack (half the
    rows active); minimising s >= 0 stays bounded."""
    rng = np.random.default_rng(2)
    lps = []
    for lp in load_programs[:4]:
        x0 = np.where(np.isfinite(lp.lower), np.abs(rng.normal(0, 0.1, lp.n)), rng.normal(0, 0.1, lp.n))
        rows = lp.a_ub.shape[0]
        slack = np.where(rng.random(rows) < 0.5, 0.0, rng.exponential(0.1, rows))
        lps.append(LinearProgram(lp.c, lp.a_eq, lp.a_eq @ x0, lp.a_ub, lp.a_ub @ x0 + slack, lp.lower, lp.upper))
    for lp, res in zip(lps, lp_jax.solve_batch(lps)):
        assert_agrees(lp, res, solve_highs(lp))


def cantilever(w_n: float = 1.5, x_c: float = 50.0, a: float = 20.0, clutch: float = 1.0,
               shear: float = 10.0) -> LinearProgram:
    """A beam (one rigid body, 2-D: x along it, y up) of weight w_n with its centre of mass at x_c,
    on two studs at x = 0 and x = a. Each stud pushes up with f_i >= -s clutch (tension up to its
    clutch, scaled by s) and holds shear |t_i| <= s shear. Variables: s, f1, f2, t1, t2; rows: the
    horizontal and vertical balance, the moments about the first stud."""
    a_eq = sp.csr_matrix([[0, 0, 0, 1, 1], [0, 1, 1, 0, 0], [0, 0, a, 0, 0]])
    a_ub = sp.csr_matrix([
        [-clutch, -1, 0, 0, 0], [-clutch, 0, -1, 0, 0],
        [-shear, 0, 0, 1, 0], [-shear, 0, 0, -1, 0], [-shear, 0, 0, 0, 1], [-shear, 0, 0, 0, -1],
    ])
    lower = np.r_[0.0, np.full(4, -np.inf)]
    b_eq = np.array([0.0, w_n, x_c * w_n])
    return LinearProgram(np.eye(5)[0], a_eq, b_eq, a_ub, np.zeros(6), lower, np.full(5, np.inf))


def test_cantilever_on_two_studs_by_hand():
    """With x_c > a the first stud pulls. Balance: t_1 + t_2 = 0, f_1 + f_2 = W, a f_2 = x_c W, so
    f_2 = W x_c / a and the first stud's tension is W (x_c - a) / a: s = W (x_c - a) / (a C)."""
    w_n, x_c, a, clutch = 1.5, 50.0, 20.0, 1.0
    lp = cantilever(w_n, x_c, a, clutch)
    by_hand = w_n * (x_c - a) / (a * clutch)
    (res,) = lp_jax.solve_batch([lp])
    ref = solve_highs(lp)
    assert by_hand == pytest.approx(2.25)
    assert ref.objective == pytest.approx(by_hand, rel=1e-9)
    assert_agrees(lp, res, ref)
    assert res.x[1:3] == pytest.approx([-(x_c - a) / a * w_n, x_c / a * w_n], rel=1e-5)


def test_dependent_and_empty_equality_rows():
    """The moment balance written twice (once scaled) and an empty row: the same program."""
    lp = cantilever()
    a_eq = sp.vstack([lp.a_eq, 3 * lp.a_eq[2], sp.csr_matrix((1, lp.n))], format="csr")
    doubled = LinearProgram(lp.c, a_eq, np.r_[lp.b_eq, 3 * lp.b_eq[2], 0.0], lp.a_ub, lp.b_ub, lp.lower, lp.upper)
    (res,) = lp_jax.solve_batch([doubled])
    assert_agrees(doubled, res, solve_highs(lp))


def test_a_batch_solves_as_its_members_alone(load_programs):
    """The same answers, to the solver's tolerance: a batch of 4 and a batch of 1 are different
    compiled programs (padded to different widths), whose reductions may round differently in the
    last bits, and such a difference can move the last check by an iteration. x itself is not
    unique (the load programs are degenerate: the iterate stops near the optimal face's centre, at
    the tolerance), so each x is checked for feasibility, not against the other."""
    together, its_together = lp_jax._solve(load_programs[:4], 1e-8, lp_jax.MAX_ITERATIONS)
    for lp, t, it in zip(load_programs, together, its_together):
        (a,), (it_alone,) = lp_jax._solve([lp], 1e-8, lp_jax.MAX_ITERATIONS)
        assert t.status == a.status == "optimal"
        assert abs(t.objective - a.objective) <= 1e-7 * max(1.0, abs(a.objective))
        assert_agrees(lp, t, a)
        assert abs(it - it_alone) <= 1


def _lp_kernels() -> int:
    """The solver kernels this process has made ready: through exports (`jax_export`) when they
    are available, else `_SOLVE`'s own jit cache."""
    from factory.physics import jax_export

    if jax_export._available():
        return sum(1 for key in jax_export._LOADED if key[0] == "lp")
    return interior_point_jax._SOLVE._cache_size()


def test_one_compile_per_bucket():
    """Two calls with different problem counts (9, then 10: both padded to 10) and sizes
    (40 and 42 variables) inside one shape bucket compile once; an iteration cap is a traced value
    (no compile), and a member stopped by it is "error", not a guess (without the fallback to
    HiGHS; with it, HiGHS's answer)."""
    rng = np.random.default_rng(1)
    first = [random_lp(rng) for _ in range(9)]
    second = [random_lp(rng, n=42) for _ in range(10)]
    buckets = [lp_jax.bucket_of(lp) for lp in first + second]
    assert len({b[1:] for b in buckets}) == 1  # same rows and slots: run in the largest n and w
    before, cached = len(lp_jax.COMPILES), _lp_kernels()
    lp_jax.solve_batch(first)
    assert len(lp_jax.COMPILES) == before + 1 and _lp_kernels() == cached + 1
    assert lp_jax.COMPILES[-1] == (lp_jax._pow2(10, lp_jax.min_launch()), *(max(b[j] for b in buckets) for j in range(4)))
    capped = lp_jax.solve_batch(second, max_iterations=2, fallback=False)
    fallen_back = lp_jax.FALLBACKS[0]
    rescued = lp_jax.solve_batch(second, max_iterations=2)
    results = lp_jax.solve_batch(second)
    assert len(lp_jax.COMPILES) == before + 1 and _lp_kernels() == cached + 1
    assert all(r.status == "optimal" for r in results + rescued)
    assert all(r.status == "error" and r.x is None for r in capped)
    assert lp_jax.FALLBACKS[0] == fallen_back + len(second)
    for lp, r, h in zip(second, results, rescued):
        assert_agrees(lp, r, h)


def test_launches_of_programs_with_many_rows_are_smaller():
    """`_group`: 4,096 programs of 30-brick rows (128) run in one launch; of 90-brick rows (576,
    whose launch of 4,096 asked an H100 for 32 GiB more than it had) in launches of 1,024, in equal
    chunks (one launch size), every program in exactly one launch."""
    small = lp_jax._group([(64, 128, 4, 2)] * 4096)
    assert [(shape[0], len(chunk)) for shape, chunk in small] == [(4096, 4096)]
    big = lp_jax._group([(1024, 576, 4, 2)] * 4096 + [(1024, 576, 4, 2)] * 5)
    assert [shape[0] for shape, _ in big] == [1024] * 5
    assert sorted(i for _, chunk in big for i in chunk) == list(range(4101))
    for shape, chunk in big:
        assert shape[0] * shape[2] ** 2 <= lp_jax.MAX_LAUNCH_ENTRIES and len(chunk) <= shape[0]


@pytest.fixture(scope="module")
def real_models():
    """The load models (those that do not tip; every third) of the distinct attachments of a 2x4
    brick to a grown 8-brick structure, as `check` builds them for the sampler's candidates."""
    from pipelines.bench_structures import candidates, grow, load_models

    from factory.physics.statics import tips

    s = grow(8)
    seen, poses = set(), []
    for p in candidates(s, 600):
        key = (p.R.round(6).tobytes(), p.t.round(6).tobytes())
        if key not in seen:
            seen.add(key)
            poses.append(p)
    return [m for m in load_models(s, poses) if not tips(m)][::3]


@pytest.mark.slow
def test_real_load_programs_and_their_verdicts_near_the_limit_match_highs(real_models):
    """At least 1,000 real load programs in one call: each model at the default clutch, at clutches
    that put its s near 1 (s scales as 1 / clutch where shear does not bind: s = 1/u for clutch
    u s_1, u from 0.9 to 1.1 and 1 +- 1e-5), and with a rigid link (free force columns) between
    the new brick and the first. Objectives within 1e-7 of HiGHS's, every verdict s <= 1 + 1e-6
    the same, and `judge_many` gives the same verdicts through either solver."""
    from dataclasses import replace

    from factory.physics.load_model import LoadConfig
    from factory.physics.load_program import to_lp
    from factory.physics.statics import judge_many

    base = [solve_highs(to_lp(m)).objective for m in real_models]
    programs = []
    for m, s1 in zip(real_models, base):
        programs.append((m, LoadConfig()))
        if s1 > 0.05:
            programs += [(m, LoadConfig(clutch_n=s1 * u)) for u in (0.9, 0.95, 0.99, 1 - 1e-5, 1 + 1e-5, 1.01, 1.05, 1.1)]
        linked = replace(m, link_a=np.array([m.n_bodies - 1]), link_b=np.array([0]), link_pos=m.com[[0]],
                         link_axis=np.array([[0.0, -1.0, 0.0]]), link_cap=np.full((1, 6), np.inf),
                         link_kind=np.array(["rigid"], dtype=object))
        programs.append((linked, LoadConfig()))
    lps = [to_lp(m, cfg) for m, cfg in programs]
    assert len(lps) >= 1000
    results, iterations = lp_jax._solve(lps, 1e-8, lp_jax.MAX_ITERATIONS)
    ref = np.array([solve_highs(lp).objective for lp in lps])
    got = np.array([r.objective if r.status == "optimal" else np.nan for r in results])
    assert np.all(np.isfinite(got)), f"{np.isnan(got).sum()} not solved"
    assert np.abs(got - ref).max() <= 1e-7 * max(1.0, np.abs(ref).max())
    near = np.abs(ref - 1) <= 0.1
    assert near.sum() >= 500 and (np.abs(ref - 1) <= 2e-5).sum() >= 100
    assert ((got <= 1 + 1e-6) == (ref <= 1 + 1e-6)).all()
    assert iterations.max() <= 40
    # The same programs written straight from the models (`solve_loads`), per load constants: the
    # default's and those of the first 40 others (a call each; all 450 took 33 s for no more cover).
    checked = [LoadConfig(), *[c for c in dict.fromkeys(c for _, c in programs) if c != LoadConfig()][:40]]
    direct = np.full(len(programs), np.nan)
    for cfg in checked:
        at = [i for i, (_, c) in enumerate(programs) if c == cfg]
        for i, r in zip(at, loads_jax.solve_loads([programs[i][0] for i in at], cfg, fallback=False)):
            direct[i] = r.objective if r.status == "optimal" else np.nan
    done = np.array([c in checked for _, c in programs])
    assert done.sum() >= 300 and np.all(np.isfinite(direct[done])), f"{np.isnan(direct[done]).sum()} not solved"
    assert np.abs(direct[done] - ref[done]).max() <= 1e-7 * max(1.0, np.abs(ref).max())
    assert ((direct[done] <= 1 + 1e-6) == (ref[done] <= 1 + 1e-6)).all()
    # judge_many through either solver: every program at the default clutch (one call), and those
    # of the first model at its eight clutches around s = 1 (one call each: a kernel each).
    near_limit = [c for c in dict.fromkeys(c for _, c in programs) if c != LoadConfig()][:8]
    for cfg in [LoadConfig(), *near_limit]:
        models = [m for m, c in programs if c == cfg]
        a = judge_many(models, cfg)
        b = judge_many(models, cfg, loads_jax.solve_loads)
        assert [(v.stands, v.reason) for v in a] == [(v.stands, v.reason) for v in b]


@pytest.mark.slow
def test_candidates_judged_on_the_structures_shared_columns_match_highs():
    """`judge_on_base` with `solve_on_base` (the structure's columns sent once, each candidate's
    own joined on the device) gives `judge_many`'s HiGHS verdicts, loads and failing connections
    for every other of the first 160 distinct attachments of a 2x4 brick to a grown 30-brick
    structure, those on the ground included, at the default clutch and at a weak one that overloads many."""
    from pipelines.bench_structures import candidates, grown

    from factory.physics.check import _unit_connections
    from factory.physics.load_model import LoadBase, LoadConfig, support_points
    from factory.physics.statics import judge_many, judge_on_base
    from factory.physics.structure import Placed

    s = grown(30)
    brick = s.placed[0].part
    poses = list({(p.R.round(6).tobytes(), p.t.round(6).tobytes()): p for p in candidates(s, 400)}.values())[:160:2]
    units = [[Placed(brick, 4, p)] for p in poses]
    conns = [_unit_connections(s, [(brick, p)]) for p in poses]
    # Some stand on the ground beside the first brick (their own supports widen the polygon).
    assert any(len(support_points(u[0], 24.0, LoadConfig())) for u in units)
    for cfg in (LoadConfig(), LoadConfig(clutch_n=0.25)):
        base = LoadBase(s.placed, s.connections, 24.0, s.links, cfg)
        assert base.shared()
        got = judge_on_base(base, units, conns, cfg, loads_jax.solve_on_base)
        ref = judge_many([base.model(u, c) for u, c in zip(units, conns)], cfg)
        assert [(v.stands, v.reason) for v in got] == [(v.stands, v.reason) for v in ref]
        for a, b in zip(got, ref):
            assert (a.load is None) == (b.load is None)
            if a.load is not None:
                assert abs(a.load - b.load) <= 1e-7 * max(1.0, b.load)
            assert [(f.stud_part, f.socket_part) for f in a.failing] == [(f.stud_part, f.socket_part) for f in b.failing]
        if cfg.clutch_n < 1:
            assert sum(v.reason == "overload" for v in ref) >= 20


@pytest.mark.slow
def test_programs_of_several_structures_share_launches_and_match_highs(monkeypatch):
    """`judge_on_bases` (objects grown in lockstep): the candidates of three structures (12, 20 and
    30 bricks of one grown object) solved together give each structure's HiGHS verdicts and
    loads; the 12- and 20-brick programs (equality rows 78 and 126, one bucket) share a launch."""
    from pipelines.bench_structures import candidates, grown

    from factory.physics.check import _unit_connections
    from factory.physics.load_model import LoadBase, LoadConfig
    from factory.physics.statics import judge_many, judge_on_bases
    from factory.physics.structure import Placed, Structure

    full = grown(30)
    brick = full.placed[0].part
    cfg = LoadConfig(clutch_n=0.25)
    groups, refs = [], []
    for size in (12, 20, 30):
        s = Structure(list(full.placed[:size]))
        poses = list({(p.R.round(6).tobytes(), p.t.round(6).tobytes()): p for p in candidates(s, 200)}.values())[:40]
        units = [[Placed(brick, 4, p)] for p in poses]
        conns = [_unit_connections(s, [(brick, p)]) for p in poses]
        base = LoadBase(s.placed, s.connections, 24.0, s.links, cfg)
        assert base.shared()
        groups.append((base, units, conns))
        refs.append(judge_many([base.model(u, c) for u, c in zip(units, conns)], cfg))
    launches = []
    run = loads_jax._run
    monkeypatch.setattr(loads_jax, "_run", lambda arrays, *a: launches.append(arrays["b"].shape) or run(arrays, *a))
    got = judge_on_bases(groups, cfg, loads_jax.solve_on_bases)
    assert sorted(m for _, m in launches) == [128, 192]
    for g, r in zip(got, refs):
        assert [(v.stands, v.reason) for v in g] == [(v.stands, v.reason) for v in r]
        for a, b in zip(g, r):
            assert (a.load is None) == (b.load is None)
            if a.load is not None:
                assert abs(a.load - b.load) <= 1e-7 * max(1.0, b.load)
    assert {v.reason for r in refs for v in r} >= {None, "overload"}


def test_clutch_programs_on_the_device_give_the_verdicts_of_highs():
    # holds_alone_many with the batched solver (what the 'jax' checks use) against HiGHS, on the
    # cases the closed form leaves to the program: sitting on some studs while hanging from others,
    # hanging while resting on the ground, tilted studs; heavy and light parts, near the limit too.
    from factory.physics.clutch import _closed_form, holds_alone_many
    from factory.physics.load_model import LoadConfig

    rng = np.random.default_rng(11)
    cfg = LoadConfig()
    cases = []
    while len(cases) < 240:
        n = int(rng.integers(1, 5))
        studs = np.unique(np.column_stack([rng.integers(-2, 3, n) * 20.0, np.zeros(n),
                                           rng.integers(-2, 3, n) * 20.0]), axis=0)
        kind = len(cases) % 3
        axes = [np.array([0.0, -1.0, 0.0])] * len(studs)
        if kind == 2:
            tilt = np.array([rng.uniform(-0.3, 0.3), -1.0, rng.uniform(-0.3, 0.3)])
            axes = [tilt / np.linalg.norm(tilt)] * len(studs)
        holds = [bool(rng.integers(0, 2)) for _ in studs]
        ground = np.zeros((0, 3))
        if kind == 1:
            holds = [True] * len(studs)
            ground = np.array([[x, 24.0, z] for x in (-40.0, 40.0) for z in (-20.0, 20.0)])
        conns = [(h, p, a) for h, p, a in zip(holds, studs, axes)]
        com = np.array([rng.normal() * 30, -10.0, rng.normal() * 30])
        mass = float(10 ** rng.uniform(-3, -0.5))
        if _closed_form(mass, com, conns, ground, cfg) is None:
            cases.append((mass, com, conns, ground))
    device = holds_alone_many(cases, cfg, lp_jax.solve_batch)
    highs = holds_alone_many(cases, cfg)
    assert device == highs
    assert 0 < sum(highs) < len(highs)  # both verdicts occur


def test_the_arrays_cross_products_are_numpys_bit_for_bit():
    """`_load_arrays` takes its torques from `loads_jax._cross`, written out for (n, 3) rows: the
    same bits as `np.cross`, so the programs are unchanged."""
    from factory.physics.loads_jax import _cross

    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 500):
        a, b = rng.normal(size=(n, 3)) * 60, rng.normal(size=(n, 3))
        assert _cross(a, b).tobytes() == np.cross(a, b).tobytes()
