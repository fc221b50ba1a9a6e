"""The sampler: reproducible, physics-verified objects, their LDraw form, config validation, CLI."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from factory import Pose, get_reader, load_part, read_steps
from factory.physics.check import check_units
from factory.physics.structure import Placed, Structure
from factory.sampler import Assembly, Sampler, SamplerConfig, SamplerConfigError, density

ROOT = Path(__file__).resolve().parents[1]
PARTS = {"3001": 1.0, "3003": 1.0, "3004": 1.0, "3020": 1.0, "3022": 0.5, "3039": 0.5, "3068b": 0.3}
SMALL = dict(parts=PARTS, colours=[4, 1, 15], min_steps=3, max_steps=6, candidates_per_step=12, check_batch=4)


@pytest.fixture(scope="module")
def sampler() -> Sampler:
    return Sampler(SamplerConfig(seed=11, **SMALL))


@pytest.fixture(scope="module")
def objects(sampler) -> list[Assembly]:
    return [sampler.sample(i) for i in range(3)]


def test_objects_grow_within_bounds(objects):
    for a in objects:
        assert 1 <= len(a) <= 6
        assert a.end_reason == "target" and len(a) == a.target_steps and 3 <= a.target_steps <= 6
        assert a.steps[0].pose.allclose(Pose.identity())  # first part at the origin, canonical
        assert all(s.verdict is not None and s.verdict.ok for s in a.steps)
        assert all(s.part[:-4] in PARTS and s.colour in (4, 1, 15) for s in a.steps)
        assert 0 < a.density < 1 and a.density == pytest.approx(a.steps[-1].density)
        assert set(a.rejected) <= {"below-ground", "collision", "no-connection", "clutch", "unstable",
                                   "unsupported-connection", "no-attachment"}


def test_same_seed_and_index_give_the_same_object_in_any_order_and_batch(objects, tmp_path):
    other = Sampler(SamplerConfig(seed=11, **{**SMALL, "check_batch": 1}))
    again = {i: other.sample(i) for i in (2, 0, 1)}  # another order, another check batch size
    for i, a in enumerate(objects):
        b = again[i]
        assert a.same_as(b, atol=0) and a.density == b.density
        pa = a.to_ldr(tmp_path / "a" / f"object_{i:05d}.ldr")
        pb = b.to_ldr(tmp_path / "b" / f"object_{i:05d}.ldr")
        assert pa.read_bytes() == pb.read_bytes()
    assert not Sampler(SamplerConfig(seed=12, **SMALL)).sample(0).same_as(objects[0])


def test_to_ldr_reads_back_to_the_same_steps(objects, tmp_path):
    a = max(objects, key=len)
    path = a.to_ldr(tmp_path / "object_00001.ldr")
    text = path.read_text()
    lines = text.splitlines()
    assert lines[1] == "0 Name: object_00001.ldr" and lines[2].startswith("0 Author: ")
    assert "0 !LDRAW_ORG Model" in lines and text.count("0 STEP") == len(a)
    assert not list(tmp_path.glob("*.tmp"))
    steps = read_steps(path)
    assert [len(s.parts) for s in steps] == [1] * len(a)
    for s, mine in zip(steps, a.steps):
        p = s.parts[0]
        assert (p.part, p.colour) == (mine.part, mine.colour) and p.pose.allclose(mine.pose)
    back = Assembly.from_ldr(path)
    assert back.same_as(a) and (back.seed, back.index, back.end_reason) == (a.seed, a.index, a.end_reason)
    assert back.density == pytest.approx(a.density, rel=1e-9)
    assert back.to_ldr(tmp_path / "again" / path.name).read_bytes() == path.read_bytes()


def test_sampled_objects_pass_the_checks_independently(objects, tmp_path):
    from factory.replay import verify_model

    reader = get_reader()
    for a in objects:
        path = a.to_ldr(tmp_path / f"object_{a.index:05d}.ldr")
        records = list(verify_model(path))  # the project's own replay of a model file
        assert len(records) == len(a) and all(r["reason"] is None for r in records), records
        # Every step after the first reaches its pose along its studs' axis from outside.
        assert all(r["buildable"] is True for r in records[1:]), [r for r in records if not r["buildable"]]
        # And step by step on a fresh structure, ground fixed at the first part's lowest point.
        parts = [load_part(reader, s.part) for s in read_steps(path) for s in s.parts]
        placed = [Placed(p, s.colour, s.pose) for p, s in zip(parts, a.steps)]
        floor = Structure(placed[:1]).floor_y()
        structure = Structure()
        for p in placed:
            (v,) = check_units(structure, [[p]], floor_y=floor)
            assert v.ok and (v.connected or not len(structure)), v
            assert Structure([p]).floor_y() <= floor + 0.5
            structure.add(p)


def test_density_prefers_compact():
    brick = load_part(get_reader(), "3001")
    up = Pose(np.eye(3), [0, -24, 0])
    side = Pose(np.eye(3), [60, -24, 0])
    assert density([(brick, Pose.identity()), (brick, up)]) > density([(brick, Pose.identity()), (brick, side)])


def test_reward_raises_density(sampler):
    on = Sampler(SamplerConfig(seed=5, **{**SMALL, "min_steps": 8, "max_steps": 8}))
    off = Sampler(SamplerConfig(seed=5, **{**SMALL, "min_steps": 8, "max_steps": 8, "density_weight": 0.0}))
    d_on = [on.sample(i).density for i in range(2)]
    d_off = [off.sample(i).density for i in range(2)]
    assert np.mean(d_on) > np.mean(d_off)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(parts=["3001", "nosuch"]), "unknown part 'nosuch'"),
        (dict(colours=[4, 9999]), "unknown colour code 9999"),
        (dict(colours=[16]), "unknown colour code 16"),
    ],
)
def test_library_validation_lists_choices(kwargs, message):
    with pytest.raises(SamplerConfigError) as err:
        Sampler(SamplerConfig(**{**SMALL, **kwargs}))
    text = str(err.value)
    assert message in text and "valid choices" in text
    assert ("3001" in text and "3068b" in text) if "part" in message else ("71" in text and "15" in text)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(backend="cuda"), "unknown check backend 'cuda'; valid choices: cpu, jax"),
        (dict(min_steps=10, max_steps=5), "max_steps (5) must be >= min_steps (10)"),
        (dict(parts={"3001": -1}), "weight of '3001' must be a finite number > 0"),
        (dict(parts=[]), "parts: the set is empty"),
        (dict(temperature=0), "temperature must be"),
        (dict(candidates_per_step=0), "candidates_per_step must be >= 1"),
        (dict(judge_first=0), "judge_first must be >= 1"),
        (dict(judge_first=2.5), "judge_first must be an integer"),
        (dict(parts=["3001", "3001.dat"]), "'3001' is listed twice"),
    ],
)
def test_config_validation(kwargs, message):
    with pytest.raises(SamplerConfigError, match=None) as err:
        SamplerConfig(**kwargs)
    assert message in str(err.value)


def test_config_is_frozen_and_normalised():
    c = SamplerConfig(parts=["3001.DAT", ("3003", 2)], colours={"4": 1, 15: 3})
    assert c.parts == (("3001", 1.0), ("3003", 2.0)) and c.colours == ((4, 1.0), (15, 3.0))
    with pytest.raises(Exception):
        c.seed = 3  # type: ignore[misc]
    assert SamplerConfig().min_steps == 20 and SamplerConfig().max_steps == 90
    # judge_first only changes the cost: left out of the recorded settings at its default, kept
    # when set otherwise, and read back to the same config either way.
    batched = SamplerConfig(backend="jax")
    assert (batched.check_batch, batched.judge_first) == (16, 4) and SamplerConfig().judge_first == 1
    assert "judge_first" not in batched.to_dict() and SamplerConfig.from_dict(batched.to_dict()) == batched
    two = SamplerConfig(backend="jax", judge_first=2)
    assert two.to_dict()["judge_first"] == 2 and SamplerConfig.from_dict(two.to_dict()) == two


@pytest.mark.slow
def test_cli_tiny_run(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "pipelines.sample", "--n", "2", "--seed", "3", "--out", str(out),
           "--min-steps", "3", "--max-steps", "4", "--candidates", "8", "--start", "1"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    files = sorted(p.name for p in out.iterdir())
    assert files == ["object_00001.ldr", "object_00002.ldr", "summary.json"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["totals"]["objects"] == 2 and summary["config"]["seed"] == 3
    assert summary["totals"]["objects_per_minute"] > 0
    for rec in summary["objects"]:
        assert {"steps", "density", "rejected", "seconds", "end_reason", "file"} <= set(rec)
        assert len(read_steps(out / rec["file"])) == rec["steps"]
    # The same object from the API, byte for byte.
    cfg = SamplerConfig(seed=3, min_steps=3, max_steps=4, candidates_per_step=8)
    mine = Sampler(cfg).sample(2).to_ldr(tmp_path / "object_00002.ldr")
    assert mine.read_bytes() == (out / "object_00002.ldr").read_bytes()

    # Two worker processes: the same files.
    par = tmp_path / "par"
    cmd2 = [str(par) if c == str(out) else c for c in cmd] + ["--workers", "2"]
    res = subprocess.run(cmd2, cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    for name in ("object_00001.ldr", "object_00002.ldr"):
        assert (par / name).read_bytes() == (out / name).read_bytes()

    bad = subprocess.run([*cmd[:-2], "--temperature", "-1"], cwd=ROOT, capture_output=True, text=True,
                         env=env, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("error: temperature must be")


def test_a_capped_object_ends_stuck_and_says_why():
    # 1x1 plates stack in a column until a 1x1 tile caps it: nothing can go on, nothing under.
    s = Sampler(SamplerConfig(parts={"3024": 1.0, "3070b": 1.0}, colours=[4], min_steps=30, max_steps=30,
                              max_redraws=2, candidates_per_step=8))
    a = s.sample(0)
    assert a.end_reason == "stuck" and len(a) < 30 and a.steps[-1].part == "3070b.dat"
    assert a.stuck_rejected and set(a.stuck_rejected) <= {"below-ground", "no-attachment", "collision"}


def _growing_tracker(sampler, index: int, parts: int):
    """The density tracker and structure of a sampled object's first `parts` parts."""
    from factory.sampler.density import DensityTracker

    a = sampler.sample(index)
    tracker, structure = DensityTracker(), Structure()
    by_name = {p.name: p for p in sampler.parts}
    for s in a.steps[:parts]:
        tracker.add(by_name[s.part], s.pose)
        structure.add(Placed(by_name[s.part], s.colour, s.pose))
    return tracker, structure


@pytest.fixture(scope="module")
def twelve_parts():
    sampler = Sampler(SamplerConfig(seed=0, min_steps=12, max_steps=12))
    return sampler, _growing_tracker(sampler, 0, 12)


@pytest.mark.slow
@pytest.mark.parametrize("weight", [30.0, 0.0, -30.0])
def test_candidate_order_computes_only_the_densities_it_needs(twelve_parts, weight):
    """`KeyOrder` gives the candidates in exactly the order of the keys computed from every
    candidate's density (ties by index), and the upper bounds hold; with the reward on, the first
    eight come with fewer densities computed than there are candidates."""
    from factory.physics.attach import attachment_arrays
    from factory.sampler.sampler import KeyOrder

    sampler, (tracker, structure) = twelve_parts
    rng = np.random.default_rng(5)
    computed = total = 0
    for part in sampler.parts[::3]:
        r, t = attachment_arrays(structure, part)
        if len(t) > 64:
            pick = np.sort(rng.choice(len(t), 64, replace=False))
            r, t = r[pick], t[pick]
        if not len(t):
            continue
        exact = tracker.densities_with(part, r, t)
        for trial in range(3):
            noise = rng.gumbel(size=len(t))
            cands = tracker.candidates(part, r, t)
            assert np.all(cands.upper >= exact)
            keys = weight * np.log(np.maximum(exact, 1e-12)) / 0.3 + noise
            assert list(KeyOrder(cands, weight, 0.3, noise)) == [int(i) for i in np.argsort(-keys, kind="stable")]
            first = tracker.candidates(part, r, t)
            order = KeyOrder(first, weight, 0.3, noise)
            list(itertools.islice(order, 8))
            computed += len(first._exact)
            total += len(t)
    assert total > 300
    if weight > 0:
        assert computed < total


def test_candidate_density_is_the_hull_volume_convex_hull_gives(twelve_parts):
    """A candidate's exact density reads qhull's volume without `ConvexHull`'s facet arrays
    (`density._volume`): the same number, bit for bit, on real candidates of a 12-part object, and
    0 for a flat point set."""
    from scipy.spatial import ConvexHull

    from factory.physics.attach import attachment_arrays
    from factory.sampler.density import _Qhull, _volume

    assert _Qhull is not None  # the pinned scipy has it; the fallback is ConvexHull itself
    sampler, (tracker, structure) = twelve_parts
    compared = 0
    for part in sampler.parts[::4]:
        r, t = attachment_arrays(structure, part)
        cands = tracker.candidates(part, r[:40], t[:40])
        for i in range(len(cands.points)):
            points = np.concatenate([tracker.points, cands.points[i][cands.outside[i]]])
            assert _volume(points) == ConvexHull(points).volume
            compared += 1
    assert compared > 100
    assert _volume(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])) == 0.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; the parent-death signal is Linux's")
def test_sample_workers_end_with_a_killed_command(tmp_path):
    """`kill -9` of `pipelines.sample --workers 2` ends its worker processes too."""
    from process_support import assert_workers_end_with_killed_parent

    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, "-m", "pipelines.sample", "--n", "8", "--out", str(tmp_path / "o"),
           "--min-steps", "90", "--max-steps", "90", "--workers", "2"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # (an object of 90 parts takes far longer than the grace: a worker that ends in time was ended)
    assert_workers_end_with_killed_parent(proc, b"pipelines.sample", settle=1.0, grace=10.0)


def test_target_steps_is_the_length_an_object_grows_to(objects):
    from factory.sampler.sampler import target_steps

    cfg = SamplerConfig(seed=11, **SMALL)
    assert [target_steps(cfg, i) for i in range(3)] == [a.target_steps for a in objects]
    assert all(3 <= target_steps(cfg, i) <= 6 for i in range(50))


def test_an_object_stuck_before_its_fewest_parts_is_grown_again_from_a_stream_of_its_own(monkeypatch, tmp_path):
    """An object that gets stuck before `min_steps` parts (6 of 64 library objects ended before 6
    parts) is grown again from a stream of its own, and the longest attempt is kept; an object that
    reaches `min_steps` at its first attempt is the object it always was."""
    import factory.sampler.sampler as sampler_module

    cfg = SamplerConfig(seed=1, min_steps=12, max_steps=12, candidates_per_step=2, max_redraws=0)
    grown = list(Sampler(cfg).sample_many(range(6)))
    monkeypatch.setattr(sampler_module, "RESTARTS", 0)
    first = list(Sampler(cfg).sample_many(range(6)))
    assert all(f.attempt == 0 for f in first)
    for a, f in zip(grown, first):
        if len(f) >= cfg.min_steps:
            assert a.same_as(f) and a.attempt == 0
        else:
            assert len(a) >= len(f) and (a.attempt == 0) == a.same_as(f)
    assert any(len(f) < len(a) == cfg.min_steps for a, f in zip(grown, first))  # one reached its length
    again = next(a for a in grown if a.attempt)
    assert Assembly.from_ldr(again.to_ldr(tmp_path / "o.ldr")).attempt == again.attempt
    monkeypatch.undo()
    assert Sampler(cfg).sample(again.index).same_as(again)  # reproducible
