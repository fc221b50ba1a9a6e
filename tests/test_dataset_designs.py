"""Human designs as dataset rows (pipelines.designs): manual order with sub-assembly 'module' steps,
physics records from the replay, and the real car model from ../shared/ldraw_models."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from factory import read_steps
from pipelines.dataset.sources import manual_steps

from ldraw_support import SHARED

ROOT = Path(__file__).resolve().parents[1]
TOWER = ROOT / "factory" / "data" / "examples" / "tower.mpd"
LDRAW = SHARED / "ldraw"
CAR = SHARED / "ldraw_models" / "car.ldr"
MINI = SHARED / "ldraw_models" / "4915-1-MiniConstruction.mpd"
needs_ldraw = pytest.mark.skipif(not (LDRAW / "parts").is_dir() or not CAR.is_file(),
                                 reason="the real LDraw subset ../shared/ldraw (and ../shared/ldraw_models) is absent")


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("MUJOCO_GL", "egl")
    return env


def _key(p):
    return (p.part.lower(), p.colour, tuple(np.round(p.pose.t, 6)), tuple(np.round(p.pose.R, 6).ravel()))


def test_tower_manual_order():
    """The roof sub-assembly: its 3 steps in its own frame with only its parts in view, then one
    module step placing its 4 bricks at their model poses on the 6 parts placed before."""
    steps, flags, _ = manual_steps(TOWER, physics=True)
    build = read_steps(TOWER)
    assert [(s.assembly, s.kind) for s in steps] == [("main", "part")] * 4 + [("main/roof.ldr#1", "part")] * 3 + [
        ("main", "module"), ("main", "part")]
    roof = [p for s in build if s.assembly == "main/roof.ldr#1" for p in s.parts]
    frame_t = np.array([0.0, -72.0, 0.0])  # the roof's type-1 line: 1 4 0 -72 0 (identity)
    assert steps[4].before == ()
    assert [tuple(p.pose.t) for s in steps[4:7] for p in s.new] == [tuple(p.pose.t - frame_t) for p in roof]
    module = steps[7]
    assert sorted(map(_key, module.new)) == sorted(map(_key, roof))  # model poses (main's frame is the model's)
    assert len(module.before) == 6 and len(steps[8].before) == 10
    # the catalog: bricks still in the box, plus the module's own bricks on the module step
    assert len(steps[0].catalog) == 11 and len(steps[4].catalog) == 5
    assert Counter(module.catalog) == Counter((p.part, p.colour, p.model) for p in roof) + Counter([("3020.dat", 14, None)])
    # physics: a verdict per placed brick, the unit verdict on the module step
    assert all(len(s.physics["bricks"]) == len(s.new) for s in steps if s.kind == "part")
    assert module.physics["unit"]["assembly"] == "main/roof.ldr#1"
    assert flags == {}


@needs_ldraw
def test_nested_submodels_place_every_part_once():
    """MiniConstruction (six files, nested): every part of the model is placed once by a part step
    and once more by each module that carries it up; module bricks land at the model's poses."""
    if not MINI.is_file():
        pytest.skip(f"{MINI} is absent")
    steps, _, _ = manual_steps(MINI, LDRAW, physics=False)
    build = read_steps(MINI, LDRAW)
    placed = [p for s in steps if s.kind == "part" for p in s.new]
    assert len(placed) == sum(len(s.parts) for s in build)
    modules = [s for s in steps if s.kind == "module"]
    assert modules and all(s.physics["source"] == "none" for s in steps)
    top = [s for s in steps if s.assembly == "main"]
    final = top[-1].before + top[-1].new
    assert sorted(map(_key, final)) == sorted(_key(p) for s in build for p in s.parts)


@pytest.mark.slow
@needs_ldraw
def test_designs_cli_on_the_car(tmp_path):
    """The car end to end through the command line (render only: coacd of its real parts is slow on
    a cold cache), loaded back with `datasets`."""
    out = tmp_path / "designs"
    r = subprocess.run([sys.executable, "-m", "pipelines.designs", str(CAR), "--out", str(out), "--ldraw",
                        str(LDRAW), "--size", "128", "--tile", "64", "--no-physics", "--no-progress"],
                       cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("brick-factory-designs: 1 objects") and "physics flags: none" in r.stdout
    info = json.loads((out / "meta" / "info.json").read_text())
    build = read_steps(CAR, LDRAW)
    assert info["total"]["steps"] == len(build) and info["source"] == "design"
    rows = []
    for f in sorted((out / "data").glob("*.parquet")):
        rows += pq.read_table(f).to_pylist()
    assert [r["step_index"] for r in rows] == list(range(len(build)))
    for row, step in zip(rows, build):
        assert row["source"] == "design" and row["object_id"] == "car"
        n = len(step.parts)
        assert len(row["bricks"]) == n
        assert len(row["selection_answer"].splitlines()) == n  # one line per brick
        assert row["pose_answer"].count("Brick ") == n and f"Brick {n}:" in row["pose_answer"]
        cells = [(b["row"], b["col"]) for b in row["bricks"]]
        assert len(set(cells)) == n  # identical bricks of a step get distinct cells
        assert np.allclose([b["T"] for b in row["bricks"]], [p.pose.t for p in step.parts])
        assert json.loads(row["physics"])["source"] == "none"
    datasets = pytest.importorskip("datasets")
    ds = datasets.load_dataset(str(out))
    split = rows[0]["split"]
    assert ds[split].num_rows == len(build) and ds[split][3]["part"].width > 128  # several bricks: a grid
