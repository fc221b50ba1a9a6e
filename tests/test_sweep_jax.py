"""The batched exact sweep (`sweep_jax`, JAX on the CPU here) against the stepped CPU reference
(`sweep.sweep`): the hand-built cases of test_sweep, verdict parity on over a thousand candidates of
grown structures and of structures with off-grid blockers (overlaps near the tolerance), and the
intervals themselves against dense stepping of an independent depth (the Minkowski difference's
hull) for random convex pairs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

pytest.importorskip("jax")

from factory import Pose, get_reader, load_part  # noqa: E402
from factory.ldraw import Library, Reader  # noqa: E402
from factory.physics import pair_kernels, piece_sets, sweep_jax  # noqa: E402
from factory.physics.attach import feasible_poses, lowest_y  # noqa: E402
from factory.physics.check import CheckConfig, _unit_connections  # noqa: E402
from factory.physics.geometry import collision_shape  # noqa: E402
from factory.physics.collide import CollisionScene  # noqa: E402
from factory.physics.geometry import stud_prism  # noqa: E402
from factory.physics.structure import Placed, Structure  # noqa: E402
from factory.physics.sweep import sweep  # noqa: E402
from factory.symmetry import rotation_about  # noqa: E402
from factory.physics.check_state import DEFAULT
from ldraw_support import LDRAW  # noqa: E402
from test_sweep import (COLUMN, DIAMOND, GAP_BRICK, GAP_WALLS, HANGING, ROOF, SLOT, TOPS, TOWER,  # noqa: E402
                        at, scene_for)

TOL = CheckConfig().max_penetration_ldu


pytestmark = pytest.mark.usefixtures("isolated_cache")


def exact(parts, unit, floor_y=None):
    structure = Structure(parts)
    scene, world, touched = scene_for(structure, unit, floor_y)
    return sweep_jax.sweep_many(scene, structure, [world], [touched], TOL)[0]


# --- The hand-built cases of test_sweep -------------------------------------------------------------


def test_the_hand_built_cases_give_the_reference_verdicts():
    wall = [at("3001", -80, 0, 0), at("3001", 0, 0, 0), at("3001", 80, 0, 0),
            at("3001", -40, -24, 0), at("3001", 40, -24, 0)]
    assert exact(wall, [at("3001", 0, -48, 0)]).buildable
    r = exact(GAP_WALLS + [ROOF], [GAP_BRICK])
    # The roof, met where the brick's walls reach its top face (y = -56; the brick's inset bottom
    # meets the roof's inset top 55.5 above the seat); its studs before that stand in the hollow.
    # The roof lies within the fingertip's width (`sweep.PRESS_LDU`) but not its end
    # (`sweep.PRESS_MIN_LDU`): such a unit is swept on the CPU, which steps to within 2 LDU.
    assert r.buildable is False and r.reason == "blocked" and r.blocked_by == (5,)
    assert r.at_ldu == pytest.approx(55.5, abs=2.0)
    assert exact(GAP_WALLS, [GAP_BRICK]).buildable
    assert exact(GAP_WALLS + [GAP_BRICK], [ROOF]).buildable
    r = exact(SLOT, [at("3068b", 20, -8, 0)])
    assert r.buildable is False and r.blocked_by == (2,)
    r = exact(SLOT, [at("3022", 20, -8, 0)])
    assert r.buildable is False and r.reason == "clamped"
    for floor_y in (None, 24.0):
        assert exact(TOWER + [DIAMOND], [HANGING], floor_y).buildable
    r = exact(TOWER + [at("3020", 40, 24, 0)], [HANGING])
    assert r.buildable is False and r.blocked_by == (3,)
    for top in TOPS.values():
        # Blocked on its axis only 140 LDU up: whether it comes in from the side (it does) is
        # asked of the device too, in a second launch.
        before = DEFAULT.sweep_counts.copy()
        assert exact(COLUMN + [top], [at("3003", 0, -24, 0)]).buildable
        assert DEFAULT.sweep_counts - before == {"device": 1}
    assert exact(COLUMN, [at("3003", 0, -24, 0)]).buildable
    # The same, with 1x1 bricks beside the brick's way up at the height it would come in from the
    # side (2 LDU clear of its straight path): every side is blocked, so the straight verdict
    # stands, decided on the device as by the reference.
    walled = COLUMN + [TOPS["plate"], at("3005", -32, -72, 0), at("3005", 0, -72, 32), at("3005", 0, -72, -32)]
    unit = [at("3003", 0, -24, 0)]
    scene, world, touched = scene_for(Structure(walled), unit)
    reference = sweep(scene, Structure(walled), world, touched, max_penetration_ldu=TOL)
    before = DEFAULT.sweep_counts.copy()
    r = exact(walled, unit)
    assert DEFAULT.sweep_counts - before == {"device": 1}
    assert reference.buildable is False and reference.reason == "blocked"
    assert (r.buildable, r.reason, r.blocked_by) == (False, "blocked", reference.blocked_by)
    side = rotation_about((0, 0, 1), 90)
    parts = [at("3001", 0, 0, 0), at("3001", 200, 0, 0, R=side)]
    r = exact(parts, [at("3001", 0, -24, 0), at("3001", 224, 0, 0, R=side)])
    assert r.buildable is None and r.reason == "two-axes"


# --- Verdict parity on real candidates --------------------------------------------------------------


def _touched(s, world):
    return {min(c[0], c[1]) for c in _unit_connections(s, world) if min(c[0], c[1]) < len(s)}


def _grow(parts: dict, base, n: int, seed: int) -> Structure:
    """n parts attached at random where the collision check lets them (loads are not the point)."""
    rng = np.random.default_rng(seed)
    s = Structure([Placed(base, 4, Pose.identity())])
    floor = s.floor_y()
    names = sorted(parts)
    for _ in range(4 * n):
        if len(s) >= n:
            break
        part = parts[names[rng.integers(len(names))]]
        poses = [p for p in feasible_poses(s, part) if lowest_y(part, p.R[None], p.t[None])[0] <= floor + TOL]
        if not poses:
            continue
        scene = CollisionScene(s, [(part, Pose.identity())], floor)
        for i in rng.permutation(len(poses))[:12]:
            if scene.penetration(poses[i], _touched(s, [(part, poses[i])]))[0] <= TOL:
                s.add(Placed(part, 4, poses[i]))
                break
    return s


def _with_blockers(plate, blockers: list, seed: int, n: int = 14) -> Structure:
    """A plate with parts floating 40-80 LDU above it (most within the stretch a part is pressed along,
    `sweep.PRESS_LDU`, where its way is straight), off the grid, turned about the vertical or tilted: their
    edges lie within about a unit of the lines the candidates' sides sweep along, so overlaps on the
    way down fall on both sides of the tolerance (the reference's depths there are printed)."""
    rng = np.random.default_rng(seed)
    s = Structure([Placed(plate, 4, Pose.identity())])
    for _ in range(n):
        part = blockers[rng.integers(len(blockers))]
        kind = rng.integers(3)
        if kind == 0:
            R = rotation_about((0, 1, 0), float(rng.choice([0, 90])))
        elif kind == 1:
            R = rotation_about((0, 1, 0), float(rng.uniform(0, 90)))
        else:
            R = rotation_about((1, 0, 0), float(rng.uniform(-30, 30))) @ rotation_about((0, 1, 0), float(rng.choice([0, 90])))
        half = (part.bbox[1] - part.bbox[0]) / 2
        x = 20 * rng.integers(-4, 5) + 10 * rng.integers(0, 2) + rng.normal(0, 0.6) + rng.choice([-1, 1]) * half[0]
        z = 20 * rng.integers(-3, 4) + rng.normal(0, 0.6)
        s.add(Placed(part, 4, Pose(R, [x, float(rng.uniform(-80, -40)), z])))
    return s


def _compare(s: Structure, part, limit: int, rng) -> list:
    floor = s.floor_y()
    poses = [p for p in feasible_poses(s, part) if lowest_y(part, p.R[None], p.t[None])[0] <= floor + TOL]
    scene = CollisionScene(s, [(part, Pose.identity())], floor)
    cases = []
    for i in rng.permutation(len(poses)):
        world = [(part, poses[i])]
        touched = _touched(s, world)
        if scene.penetration(poses[i], touched)[0] <= TOL:  # the sweep judges what collision accepts
            cases.append((world, touched))
        if len(cases) == limit:
            break
    if not cases:
        return []
    ref = [sweep(scene, s, w, c, TOL) for w, c in cases]
    got = sweep_jax.sweep_many(scene, s, [w for w, _ in cases], [c for _, c in cases], TOL)
    return [(part.name, w[0][1].t.round(2).tolist(), a, b) for (w, _), a, b in zip(cases, ref, got)]


@pytest.mark.slow
def test_verdicts_agree_with_the_stepped_reference_on_over_a_thousand_candidates(capsys):
    reader = get_reader()
    emb = {n: load_part(reader, n) for n in
           ["3001", "3003", "3005", "3010", "3022", "3020", "3023", "3024", "3710", "3068b", "3069b",
            "3039", "3040b", "3660", "3665"]}
    round_ = {}
    if (LDRAW / "parts").is_dir():  # round parts are not in the embedded library
        real = Reader(Library.from_dir(LDRAW))
        round_ = {n: load_part(real, n) for n in ["6141", "3062b", "98138", "3941"]}
    rng = np.random.default_rng(0)
    before = DEFAULT.sweep_counts.copy()
    rows = []
    grown = _grow({**emb, **round_}, load_part(reader, "3958"), 30, seed=1)
    for name in ["3001", "3003", "3022", "3068b", "3039", "3660", "3024", *round_]:
        rows += _compare(grown, {**emb, **round_}[name], 50, rng)
    near_start = len(rows)
    rng = np.random.default_rng(1)  # the near-edge draws: the same with or without the round parts
    blockers = [emb[n] for n in ["3024", "3005", "3023", "3040b", "3022"]]
    for seed in range(6):
        s = _with_blockers(load_part(reader, "3036"), blockers, seed)
        for name in ["3005", "3003", "3024", "3023", "3039", "3040b", "3068b"]:
            rows += _compare(s, emb[name], 40, rng)
    judged = [r for r in rows if r[2].buildable is not None]
    agree = sum(a.buildable == b.buildable for _, _, a, b in rows)
    near = [r for r in rows[near_start:] if abs(r[2].depth_ldu - TOL) <= 0.25]
    counts = DEFAULT.sweep_counts - before
    with capsys.disabled():
        print(f"\n{len(rows)} candidates ({len(judged)} judged, {sum(r[2].buildable is False for r in rows)} "
              f"blocked), {agree} same verdict; {len(near)} with the reference's depth within 0.25 LDU "
              f"of the tolerance; judged by {dict(counts)}; compiles so far {len(pair_kernels.COMPILES)}")
        for name, t, a, b in rows:
            if a.buildable != b.buildable:
                print(f"  differs: {name} at {t}: reference {a}, exact {b}")
    assert len(judged) >= 1000 and len(near) >= 50
    assert agree >= 0.999 * len(rows)


# --- The intervals themselves -----------------------------------------------------------------------


def _depth_line(a: np.ndarray, b: np.ndarray, d: np.ndarray):
    """depth(s) of a moved by -s d into b from the facets of the Minkowski difference's hull (qhull):
    min over facets of -(offset + s n.d); <= 0 when apart."""
    hull = ConvexHull((a[:, None] - b[None]).reshape(-1, 3))
    eq = hull.equations
    return lambda s: np.min(-(eq[:, 3][None] + np.outer(s, eq[:, :3] @ d)), axis=1)


def _random_pair(rng):
    kind = rng.integers(4)
    turn = rotation_about(rng.normal(size=3), float(rng.uniform(0, 360)))
    if kind == 0:  # random convex clouds
        a = rng.normal(size=(10, 3)) * rng.uniform(2, 12, 3)
        b = rng.normal(size=(10, 3)) * rng.uniform(2, 12, 3) @ turn.T
    elif kind == 1:  # boxes standing as built, the second turned about the vertical
        box = lambda h: np.array([[x, y, z] for x in (-h[0], h[0]) for y in (-h[1], h[1]) for z in (-h[2], h[2])])
        a = box(rng.uniform(2, 20, 3))
        b = box(rng.uniform(2, 20, 3)) @ rotation_about((0, 1, 0), float(rng.uniform(0, 90))).T
    elif kind == 2:  # a stud against a box, both upright (no edge-edge axes needed)
        a = stud_prism([0, 0, 0], [0, -1, 0])
        b = np.array([[x, y, z] for x in (-10, 10) for y in (0, 8) for z in (-10, 10)], float)
    else:  # a stud against a tilted one
        a = stud_prism([0, 0, 0], [0, -1, 0])
        b = stud_prism([0, 0, 0], turn @ [0, -1, 0])
    d = rng.normal(size=3) if rng.random() < 0.5 else np.array([0.0, 1.0, 0.0])
    d /= np.linalg.norm(d)
    # b near a's path: its centre about s0 back along d, off it by up to a few LDU.
    b = b - b.mean(0) + a.mean(0) - rng.uniform(5, 40) * d + rng.normal(size=3) * 3
    return a, b, d


@pytest.mark.slow
def test_intervals_match_dense_stepping_of_the_minkowski_depth():
    rng = np.random.default_rng(3)
    pairs = [_random_pair(rng) for _ in range(160)]
    thr = rng.choice([0.0, 0.3, 1.5, 4.0], size=len(pairs))
    got = pair_kernels.exact_intervals([p[0] for p in pairs], [p[1] for p in pairs], np.array([p[2] for p in pairs]),
                                       thr)
    s = np.linspace(-20, 80, 20001)  # 0.005 LDU apart
    nonempty = 0
    for (a, b, d), th, (lo, hi) in zip(pairs, thr, got):
        depth = _depth_line(a, b, d)(s)
        inside = (s > lo) & (s < hi)
        # Wherever the depth is not at thr itself, inside the interval <=> deeper than thr.
        clear = np.abs(depth - th) > 1e-7
        assert np.array_equal(inside[clear], (depth > th)[clear])
        if hi > lo:
            nonempty += 1
            f = _depth_line(a, b, d)
            for end in (lo, hi):
                if -20 < end < 80:
                    assert f(np.array([end]))[0] == pytest.approx(th, abs=1e-6)
    assert nonempty >= 60


def test_a_stud_reaching_into_the_path_is_referred_to_the_reference():
    # A 1x1 brick on its side beside the 2x2 brick's way down (within the stretch it is pressed
    # along, `sweep.PRESS_LDU`), its stud 4 LDU into the path and its
    # body clear of it: only a stud-body pair overlaps, which the device leaves to `sweep.sweep`
    # (the stud crosses the brick's walls: blocked).
    side = rotation_about((0, 0, 1), -90)
    probe = Placed(load_part(get_reader(), "3005"), 4, Pose(side, [0, -50, 0]))
    box = probe.pose.apply(np.array([[x, y, z] for x in probe.part.bbox[:, 0] for y in probe.part.bbox[:, 1]
                                     for z in probe.part.bbox[:, 2]]))
    assert np.isclose(box[:, 0].max() - box[:, 0].min(), 28)  # 24 of body and 4 of stud, along x
    stud_at_low_x = probe.pose.apply(np.array([probe.part.studs[0].pos]))[0][0] < box[:, 0].mean()
    shift = 16 - box[:, 0].min() if stud_at_low_x else -16 - box[:, 0].max()
    blocker = Placed(probe.part, 4, Pose(side, [shift, -50, 0]))
    parts = [at("3034", 0, 0, 0), blocker]
    structure = Structure(parts)
    scene, world, touched = scene_for(structure, [at("3003", 0, -24, 0)])
    ref = sweep(scene, structure, world, touched, TOL)
    before = DEFAULT.sweep_counts["referred"]
    got = sweep_jax.sweep_many(scene, structure, [world], [touched], TOL)[0]
    assert DEFAULT.sweep_counts["referred"] == before + 1
    assert ref.buildable is False and ref.blocked_by == (1,)
    assert got == ref


def test_a_launch_takes_only_the_rows_its_pairs_name_packed_in_one_table():
    """`_gathered`: the named rows of one bucket's tables of several sets (counted one after the
    other), each row its vertices, normals, edges and centre side by side, padded by repeating the
    first row."""
    brick = load_part(get_reader(None), "3001")
    sets = [piece_sets.structure_set(Structure([Placed(brick, 4, Pose(np.eye(3), np.array([x, 0.0, 0.0])))]))[0]
            for x in (0.0, 40.0)]
    b = int(np.argmax([len(t[0]) for t in sets[0].tables]))  # the studs' bucket: 8 pieces
    tables = [sets[0].tables[b], sets[1].tables[b]]  # one bucket of two structures
    n0 = len(tables[0][0])
    assert n0 >= 3
    rows = np.array([1, n0, n0 + 2])
    got = pair_kernels._gathered(tables, rows, 8)
    v, nn, e = (tables[0][i].shape[1] for i in range(3))
    assert got.shape == (8, v + nn + e + 1, 3) and got.dtype == np.float64
    for i, (which, row) in enumerate([(0, 1), (1, 0), (1, 2)]):
        t = tables[which]
        np.testing.assert_array_equal(got[i], np.concatenate([t[0][row], t[1][row], t[2][row], t[3][row][None]]))
    assert (got[3:] == got[0]).all()  # padding repeats the first row


def _job(rng, count):
    """A job of `exact_intervals`' form: `count` random convex pairs, each its own candidate."""
    pairs = [_random_pair(rng) for _ in range(count)]
    ua = piece_sets.PieceSet.of_pieces([piece_sets.convex_piece(a, False, 0.0) for a, _, _ in pairs],
                                       np.array([a.mean(0) for a, _, _ in pairs]), np.arange(count), count)
    sb = piece_sets.PieceSet.of_pieces([piece_sets.convex_piece(b, False, 0.0) for _, b, _ in pairs],
                                       np.array([b.mean(0) for _, b, _ in pairs]), np.arange(count), count)
    idx = np.arange(count)
    return (ua, sb, np.repeat(np.eye(3)[None], count, 0), np.zeros((count, 3)), np.array([d for *_, d in pairs]), idx,
            idx, idx, rng.choice([0.0, 0.3, 1.5], size=count), np.full(count, np.inf))


def test_a_rounds_jobs_go_to_the_device_in_one_call_and_come_back_in_one_copy(monkeypatch):
    """Several jobs in one `intervals_many` (a lockstep round): their tables and poses go to the
    device in one call and every launch's results come back in one copy, and each job's intervals
    are those it gets alone."""
    rng = np.random.default_rng(11)
    jobs = [_job(rng, 7), _job(rng, 12), _job(rng, 5)]
    alone = [pair_kernels.intervals_many([j])[0] for j in jobs]
    calls = {"_on_device": 0, "_results": 0}
    for name in calls:
        real = getattr(pair_kernels, name)

        def counted(*a, _real=real, _name=name, **k):
            calls[_name] += 1
            return _real(*a, **k)

        monkeypatch.setattr(pair_kernels, name, counted)
    together = pair_kernels.intervals_many(jobs)
    assert calls == {"_on_device": 1, "_results": 1}
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)


def test_a_structure_grown_part_by_part_has_the_pieces_of_one_built_at_once():
    """`structure_set` turns and moves only the parts it has not met (kept by part placed): after
    every part added, its pieces, boxes and tables equal those of `_set_of` over all the parts, and
    at the end each piece is its part's collision piece moved by the part's pose."""
    reader = get_reader(None)
    brick, plate, slope = (load_part(reader, name) for name in ("3001", "3020", "3039"))
    rng = np.random.default_rng(5)
    structure = Structure([])
    for i in range(12):
        part = (brick, plate, slope)[i % 3]
        R = rotation_about(np.array([0.0, 1.0, 0.0]), 90.0 * float(rng.integers(4)))
        structure.add(Placed(part, 4, Pose(R, rng.integers(-5, 6, 3) * np.array([20.0, 8.0, 20.0]))))
        got, boxes = piece_sets.structure_set(structure)
        want = piece_sets._set_of([(p.part, p.pose) for p in structure.placed])
        for name in ("stud", "inset", "prism", "centres", "owner", "box", "owner_box", "bucket_of", "local"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
        assert got.buckets == want.buckets
        for a, b in zip(got.tables, want.tables):
            for x, y in zip(a, b):
                np.testing.assert_array_equal(x, y)
        assert len(boxes) == len(structure)
    # And against the parts' collision shapes moved by their poses, not through `_part_pieces`:
    # each piece's hull vertices (its table row, before the padding), centre and box.
    for i in range(got.n):
        placed = structure.placed[got.owner[i]]
        shape = collision_shape(placed.part)
        local = (*shape.body, *shape.studs)[i - got.start[got.owner[i]]]
        world = local @ placed.pose.R.T + placed.pose.t
        hull = world[ConvexHull(local).vertices]
        row = got.tables[got.bucket_of[i]][0][got.local[i]]
        np.testing.assert_allclose(row[:len(hull)], hull, atol=1e-9)
        assert (row[len(hull):] == row[0]).all()
        np.testing.assert_allclose(got.centres[i], world.mean(axis=0), atol=1e-9)
        np.testing.assert_allclose(got.box[i], [world.min(axis=0), world.max(axis=0)], atol=1e-9)


def test_on_a_gpu_a_round_starts_at_the_working_sizes_with_the_same_intervals(monkeypatch):
    """On a GPU (`_on_gpu`, forced here: the kernels still run on the CPU) a launch's pairs and the
    structure-side tables are padded to at least `GPU_MIN_PAIRS` and `GPU_MIN_STRUCTURE_ROWS` from
    the first round, so a process meets fewer kernel shapes; the padding changes no interval."""
    rng = np.random.default_rng(3)
    jobs = [_job(rng, 9), _job(rng, 30)]
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    monkeypatch.setattr(pair_kernels, "COMPILES", [])
    on_cpu = pair_kernels.intervals_many(jobs)
    cpu_shapes = list(pair_kernels.COMPILES)
    monkeypatch.setattr(pair_kernels, "_on_gpu", lambda: True)
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    monkeypatch.setattr(pair_kernels, "COMPILES", [])
    on_gpu = pair_kernels.intervals_many(jobs)
    for a, b in zip(on_cpu, on_gpu):
        np.testing.assert_array_equal(a, b)
    # COMPILES rows: (kind, crosses, pairs, unit rows, structure rows, candidates, sizes...)
    assert cpu_shapes and all(s[2] == pair_kernels.MIN_ROWS and s[4] == pair_kernels.MIN_ROWS for s in cpu_shapes)
    assert pair_kernels.COMPILES and all(s[4] == pair_kernels.GPU_MIN_STRUCTURE_ROWS and s[3] == pair_kernels.MIN_ROWS
                                         for s in pair_kernels.COMPILES)
    for s in pair_kernels.COMPILES:
        assert s[2] == min(pair_kernels._chunk(bool(s[1]), s[6:9], s[9:12]), pair_kernels.GPU_MIN_PAIRS)


def test_a_gpu_process_readies_its_first_rounds_kernels_starting_at_its_worker_number(monkeypatch):
    """`warm_up` (a GPU forced here; the kernels compile for the CPU) readies every kernel of
    `warm_shapes` once per process, the first at this worker's number, and real rounds on grown
    structures of bricks, plates and a turned brick then meet no kernel shape it did not ready,
    with the same verdicts as without it."""
    from factory.physics import jax_export

    cases = [(TOWER + [DIAMOND], [HANGING]), (TOWER + [at("3020", 40, 24, 0)], [HANGING]),
             (COLUMN + [TOPS["plate"]], [at("3003", 0, -24, 0)]), (SLOT, [at("3068b", 20, -8, 0)])]
    want = [exact(parts, unit) for parts, unit in cases]
    monkeypatch.setattr(pair_kernels, "_on_gpu", lambda: True)
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    monkeypatch.setattr(pair_kernels, "_WARMED", False)
    monkeypatch.setattr(jax_export, "_LOADED", {})
    monkeypatch.setenv("BRICK_FACTORY_WORKER", "21")
    order = []
    real = jax_export.call

    def spy(name, *a, **k):
        order.append(name)
        return real(name, *a, **k)

    monkeypatch.setattr(jax_export, "call", spy)
    shapes = pair_kernels.warm_shapes()
    assert len(shapes) == 16
    assert pair_kernels.warm_up() == len(shapes)
    first = shapes[21 % len(shapes)]
    assert order[0] == f"{first[0]}-{int(first[1])}-{'.'.join(map(str, (*first[2], *first[3])))}"
    assert len(set(order)) == len(shapes)
    readied = set(jax_export._LOADED)
    assert len(readied) == len(shapes)
    assert pair_kernels.warm_up() == 0  # once per process
    warm_calls = len(order)
    got = [exact(parts, unit) for parts, unit in cases]
    assert len(order) > warm_calls + len(cases)  # the rounds launched kernels ...
    assert set(jax_export._LOADED) == readied  # ... all of them readied
    for a, b in zip(want, got):
        assert (a.buildable, a.reason, a.blocked_by) == (b.buildable, b.reason, b.blocked_by)


def test_a_process_without_a_worker_number_starts_its_warm_up_at_its_pid(monkeypatch):
    """Outside a numbered pool (a Ray task, a lone process) `warm_up` starts at the process's pid,
    so such processes on one machine do not all compile the same shape first."""
    import os

    monkeypatch.setattr(pair_kernels, "_on_gpu", lambda: True)
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    monkeypatch.setattr(pair_kernels, "_WARMED", False)
    monkeypatch.delenv("BRICK_FACTORY_WORKER", raising=False)
    seen = []

    def launch(crosses, ut, us, st, ss, *rest):
        seen.append((rest[-1], crosses, us, ss))  # the last argument is the kind
        return []

    monkeypatch.setattr(pair_kernels, "_launch", launch)
    shapes = pair_kernels.warm_shapes()
    assert pair_kernels.warm_up() == len(shapes)
    start = os.getpid() % len(shapes)
    assert seen == shapes[start:] + shapes[:start]


@pytest.mark.parametrize("gpu", [False, True])
def test_a_launch_keeps_its_projections_within_max_work_with_the_same_intervals(monkeypatch, gpu):
    """A launch held at least 256 pairs whatever its pieces: pieces of the largest buckets (128
    vertices, 128 x 128 edge axes) then made one 4 GiB buffer, and a 16-worker build of 40 real
    parts on one H200 ran out of memory in 37 of 40 shards. Pairs per launch keep a launch's
    vertex-axis projections within `MAX_WORK` (forced small here), padding included, and the
    intervals are those of launches of any size (to the last bit or so)."""
    from factory.physics.piece_sets import LEVELS

    rng = np.random.default_rng(5)
    jobs = [_job(rng, 40), _job(rng, 9)]
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    whole = pair_kernels.intervals_many(jobs)
    monkeypatch.setattr(pair_kernels, "_on_gpu", lambda: gpu)
    monkeypatch.setattr(pair_kernels, "MAX_WORK", 1 << 12)
    monkeypatch.setattr(pair_kernels, "_HIGH", {})
    monkeypatch.setattr(pair_kernels, "COMPILES", [])
    small = pair_kernels.intervals_many(jobs)
    for a, b in zip(whole, small):  # XLA may order a sum otherwise at another batch size: an ulp
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    assert pair_kernels.COMPILES
    for s in pair_kernels.COMPILES:  # (kind, crosses, pairs, unit rows, structure rows, candidates, sizes...)
        us, ss = s[6:9], s[9:12]
        work = (us[0] + ss[0]) * (us[1] + ss[1] + s[1] * us[2] * ss[2])
        assert s[2] < pair_kernels.MIN_ROWS and (s[2] == 1 or s[2] * work <= pair_kernels.MAX_WORK), s
    monkeypatch.undo()
    big = LEVELS[-1]
    work = (2 * big[0]) * (2 * big[1] + big[2] * big[2])
    assert pair_kernels._chunk(True, big, big) * work <= pair_kernels.MAX_WORK
