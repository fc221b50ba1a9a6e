"""Shared fixtures: the real LDraw subset beside the checkout, and builders of small files."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from factory.ldraw import Library, Reader

SHARED = Path(os.environ.get("BRICK_FACTORY_SHARED") or Path(__file__).resolve().parents[2] / "shared")
"""The real LDraw data the tests read (`ldraw/`, `ldraw_models/`, `designs/`, `ldraw_library.zip`):
`$BRICK_FACTORY_SHARED`, else `../shared` beside the checkout."""
LDRAW = SHARED / "ldraw"
MODELS = SHARED / "ldraw_models"
LIBRARY_ZIP = SHARED / "ldraw_library.zip"
DESIGNS = SHARED / "designs"

needs_ldraw = pytest.mark.needs_ldraw
"""Marks a test that reads the real LDraw data: skipped, with the reason, where it is absent
(`pytest -m needs_ldraw` selects them, `-m "not needs_ldraw"` leaves them out)."""


def pytest_collection_modifyitems(config, items):
    skip = pytest.mark.skipif(not (LDRAW / "parts").is_dir(), reason=f"the real LDraw subset is not at {LDRAW} "
                              "(CI has it; a user's clone may not; set BRICK_FACTORY_SHARED)")
    for item in items:
        if item.get_closest_marker("needs_ldraw"):
            item.add_marker(skip)


@pytest.fixture
def isolated_cache(tmp_path_factory, monkeypatch):
    """Collision decompositions cached in the test session's temporary folder, not the user's."""
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def part(name: str):
    """A part of the embedded library."""
    from factory import get_reader, load_part

    return load_part(get_reader(), name)


def at(name: str, x: float, y: float, z: float, R=None, colour: int = 4):
    """An embedded part placed at (x, y, z) LDU, turned by R (identity by default)."""
    import numpy as np

    from factory import Pose
    from factory.physics.structure import Placed

    return Placed(part(name), colour, Pose(np.eye(3) if R is None else R, [x, y, z]))


@pytest.fixture(scope="session")
def real_reader() -> Reader:
    if not (LDRAW / "parts").is_dir():
        pytest.skip(f"the real LDraw subset is not at {LDRAW}")
    return Reader(Library.from_dir(LDRAW))


@pytest.fixture(scope="session")
def embedded_reader() -> Reader:
    return Reader(Library.embedded())


@pytest.fixture
def write(tmp_path):
    """Write a file under tmp_path (text as given, or bytes) and return its path."""

    def _write(name: str, content: str | bytes) -> Path:
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content, newline="")
        return path

    return _write


@pytest.fixture
def mini_library(tmp_path) -> Path:
    """A tiny LDraw library on disk: a closed unit cube primitive and a 'brick' using it."""
    root = tmp_path / "lib"
    (root / "parts" / "s").mkdir(parents=True)
    (root / "p" / "48").mkdir(parents=True)
    (root / "p" / "box.dat").write_text(BOX)
    (root / "parts" / "Cube.dat").write_text(
        "0 Test Cube\n0 Name: cube.dat\n0 !LDRAW_ORG Part\n0 BFC CERTIFY CCW\n"
        "1 16 0 0 0 10 0 0 0 10 0 0 0 10 box.dat\n"
    )
    (root / "parts" / "s" / "cubes01.dat").write_text("0 Subpart\n0 BFC CERTIFY CCW\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n")
    (root / "LDConfig.ldr").write_text(
        "0 !COLOUR Black CODE 0 VALUE #1B2A34 EDGE #808080\n"
        "0 !COLOUR Red CODE 4 VALUE #B40000 EDGE #333333\n"
        "0 !COLOUR Trans_Clear CODE 47 VALUE #FCFCFC EDGE #C9C9C9 ALPHA 128\n"
    )
    return root


def _box_text() -> str:
    """A closed cube [-1, 1]^3 wound counter-clockwise seen from outside (LDraw axes)."""
    # Faces as (normal axis, sign); corners ordered so that (b - a) x (c - a) points outward in a
    # right-handed x, y, z frame.
    lines = ["0 Box", "0 BFC CERTIFY CCW"]
    faces = [
        [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)],
        [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
        [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)],
        [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
        [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)],
        [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)],
    ]
    for f in faces:
        lines.append("4 16 " + " ".join(f"{c}" for p in f for c in p))
    return "\n".join(lines) + "\n"


BOX = _box_text()


def tiny_dataset_config(n_objects: int = 3, min_steps: int = 2, max_steps: int = 3, **fields):
    """The config of the session's tiny synthetic dataset: 3 sampled objects of 2-3 steps, 128 px
    views, one object per shard (`fields` override further `DatasetConfig` fields). The same
    build as `test_dataset.CLI_ARGS` on the command line."""
    from factory.sampler import SamplerConfig
    from pipelines.dataset import DatasetConfig

    sampler = SamplerConfig(min_steps=min_steps, max_steps=max_steps, candidates_per_step=16)
    return DatasetConfig.synthetic(n_objects, seed=0, sampler=sampler,
                                   **{"size": 128, "tile": 64, "objects_per_shard": 1, **fields})


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """A real dataset folder built once per session (embedded library): 3 objects, 2-3 steps each,
    train and test splits. Read-only: tests that change a dataset copy it first."""
    from pipelines.dataset import build

    out = tmp_path_factory.mktemp("ds") / "synth"
    summary = build(tiny_dataset_config(), out, progress=False)
    assert summary["shards_built"] == 3
    return out


@pytest.fixture(scope="session")
def tiny_model(tiny_dataset, tmp_path_factory) -> Path:
    """The tiny Qwen2-VL (`train.tiny`, seed 0) built from the tiny dataset's texts, once per session."""
    from train.tiny import build_tiny_model, dataset_texts

    return build_tiny_model(tmp_path_factory.mktemp("tiny") / "base", dataset_texts([tiny_dataset]), seed=0)


def torchrun(module: str, *argv: str, processes: int = 2, timeout: float = 600):
    """`torchrun --standalone --nproc_per_node PROCESSES -m MODULE ARGV` from the checkout (one
    torch thread per process; --standalone: a free port, so concurrent test runs do not meet);
    the finished process (stdout and stderr as text; the processes' lines may interleave)."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(processes),
           "-m", module, *argv]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(root)}
    return subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)


def children_of(pid: int) -> list[int]:
    """Live (not zombie) processes whose parent is `pid`, from /proc."""
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                found.append(int(d.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _cmdline(pid: int) -> bytes:
    """A process's command line; empty when it ended meanwhile (a short-lived child of the command)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except (FileNotFoundError, ProcessLookupError):
        return b""


def assert_workers_end_with_killed_parent(proc, marker: bytes, workers: int = 2, settle: float = 0.0,
                                          grace: float = 10.0) -> None:
    """Wait for `workers` children of `proc` whose command line holds `marker`, kill `proc` with
    SIGKILL (after `settle` seconds), and assert that they end within `grace` seconds."""
    import os
    import signal
    import time

    found: list[int] = []
    try:
        deadline = time.time() + 120
        while len(found) < workers:
            found = [p for p in children_of(proc.pid) if marker in _cmdline(p)]
            assert proc.poll() is None, "the command ended before its workers started"
            assert time.time() < deadline, f"no {workers} workers within 120 s"
            time.sleep(0.05)
        time.sleep(settle)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.time() + grace
    while any(alive(p) for p in found) and time.time() < deadline:
        time.sleep(0.1)
    left = [p for p in found if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"


def train_log(run: Path) -> list[dict]:
    """The trainer's per-step log of run folder `run`."""
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


def run_weights(run: Path) -> dict:
    """The weights of run folder `run`'s `final/`, from all its safetensors files."""
    from safetensors.torch import load_file

    return {k: v for f in sorted((run / "final").glob("*.safetensors")) for k, v in load_file(str(f)).items()}


def train_argv(dataset, model, outdir, *more) -> list[str]:
    """`python -m train` arguments of the several-process tests: 3 steps on the CPU from `model`,
    a checkpoint every 2, no data workers, then `more`."""
    return ["--data", str(dataset), "--model", str(model), "--outdir", str(outdir), "--steps", "3", "--lr", "1e-3",
            "--warmup", "1", "--save-every", "2", "--keep-checkpoints", "0", "--workers", "0", "--device", "cpu",
            "--no-progress", *map(str, more)]


def interrupted_copy(run: Path, into: Path) -> tuple[Path, dict, list[dict], dict]:
    """A copy of the finished 3-step run `run` (a checkpoint every 2) in `into`, as if killed
    after step 3 was logged but before its checkpoint (checkpoint 2 the last whole one), its config
    pointing at the copy: (copy, its config, the run's log, the run's final weights)."""
    copy = into / run.name
    shutil.copytree(run, copy)
    log_before, weights_before = train_log(copy), run_weights(copy)
    shutil.rmtree(copy / "checkpoint-000003")
    shutil.rmtree(copy / "final")
    (copy / "last").write_text("checkpoint-000003\n")
    config = json.loads((copy / "train_config.json").read_text())
    config["outdir"] = str(copy)  # the copy is another run folder
    (copy / "train_config.json").write_text(json.dumps(config))
    return copy, config, log_before, weights_before


def assert_resumed_run_is_the_same(run: Path, log_before: list[dict], weights_before: dict) -> None:
    """A run resumed from a checkpoint logged the same losses step for step and ended with the
    same final weights as the uninterrupted run (`log_before`, `weights_before`)."""
    import torch
    from safetensors.torch import load_file

    log_after = train_log(run)
    assert [r["step"] for r in log_after] == [r["step"] for r in log_before]
    for a, b in zip(log_before, log_after):
        assert a["loss"] == pytest.approx(b["loss"], abs=1e-5)
    resumed = load_file(str(run / "final" / "model.safetensors"))
    assert resumed.keys() == weights_before.keys()
    for k in resumed:
        torch.testing.assert_close(resumed[k], weights_before[k], atol=1e-6, rtol=1e-5)
