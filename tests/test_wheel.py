"""The package installs: a wheel built from this checkout, installed non-editable in a fresh
virtual environment, samples an object and verifies a model from another folder through its console
script `brick-factory` (the physics templates and the example model travel as package data)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, cwd, env=None, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout,
                          check=False)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    tmp_path = tmp_path_factory.mktemp("wheel")
    # Built from a copy of the files git knows of (tracked, or new and not ignored): a build in the
    # checkout would reuse its `build/` folder, stale files included.
    src = tmp_path / "src"
    if shutil.which("git") is None or _run(["git", "rev-parse", "--git-dir"], cwd=ROOT).returncode != 0:
        pytest.skip("not a git checkout: the files of the package are listed by git")
    listed = _run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT).stdout.split("\0")
    for rel in filter(None, listed):
        if (ROOT / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, src / rel)
    wheels = tmp_path / "wheels"
    r = _run([sys.executable, "-m", "pip", "wheel", src, "--no-deps", "--no-build-isolation", "-q", "-w", wheels],
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (wheel,) = wheels.glob("*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"mjcf_templates/collision.xml", "factory/data/examples/tower.mpd", "pipelines/grown_3001.json"} <= names

    meta = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "License-Expression: MIT" in meta and any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    # Ranges, not pins, so the package installs beside other tools; only MuJoCo is exact.
    reqs = [line.split(":", 1)[1].split(";")[0].strip() for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    pinned = [r for r in reqs if "==" in r]
    assert pinned and all(r.startswith("mujoco") and r.endswith("==3.17.0") for r in pinned), pinned
    return wheel


def _fresh_venv(tmp_path: Path, wheel: Path) -> tuple[Path, Path]:
    """A virtual environment with the wheel installed non-editable; (its python, its site-packages)."""
    # A fresh environment: the dependencies come from this one (a path in a .pth file, whose own
    # .pth files, this checkout's editable install among them, are not read), the package from the wheel.
    venv = tmp_path / "venv"
    assert _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp_path).returncode == 0
    py = venv / "bin" / "python"
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp_path).stdout.strip())
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    r = _run([sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", "--no-index", wheel],
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    return py, site


def _env(tmp_path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LDRAWDIR")}
    env["BRICK_FACTORY_CACHE"] = str(tmp_path / "cache")
    return env


@pytest.mark.slow
def test_wheel_installs_and_runs_from_another_folder(tmp_path, wheel):
    py, site = _fresh_venv(tmp_path, wheel)
    env = _env(tmp_path)
    work = tmp_path / "elsewhere"
    work.mkdir()
    r = _run([py, "-c", "import factory, mjcf_templates; print(factory.__file__); print(mjcf_templates.__file__)"],
             cwd=work, env=env)
    assert r.returncode == 0, r.stderr
    assert all(Path(p).is_relative_to(site) for p in r.stdout.split()), r.stdout  # not this checkout

    names = zipfile.ZipFile(wheel).namelist()
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "brick-factory = pipelines.commands:main" in entry
    script = py.parent / "brick-factory"  # the console script; run by this environment's python
    r = _run([py, script, "sample", "--n", "1", "--seed", "0", "--min-steps", "3", "--max-steps", "3",
              "--out", "objects"], cwd=work, env=env)
    assert r.returncode == 0, r.stderr
    assert len(list((work / "objects").glob("*.ldr"))) == 1
    example = site / "factory" / "data" / "examples" / "tower.mpd"
    r = _run([py, script, "verify", example, "--json"], cwd=work, env=env)
    assert r.returncode == 0, r.stderr
    here = _run([sys.executable, "-m", "pipelines.verify", example, "--json"], cwd=ROOT,
                env={**env, "PYTHONPATH": str(ROOT)})
    assert here.returncode == 0, here.stderr
    verdicts = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(verdicts) > 3 and all("collision" in v and "stable" in v for v in verdicts)
    assert r.stdout == here.stdout  # the installed package judges as the checkout does


@pytest.mark.slow
def test_another_distribution_of_factory_is_refused_with_a_clear_error(tmp_path, wheel):
    """factory_boy also installs a top-level `factory` (with `__init__.py` and `errors.py`, like ours):
    pip merges the two into one folder, overwriting the shared files, and uninstalling it removes
    them from ours. A small distribution shipping those two files plays its part here; commands then
    refuse to run, naming it and the changed files, instead of failing on a missing name."""
    py, site = _fresh_venv(tmp_path, wheel)
    env = _env(tmp_path)
    script = py.parent / "brick-factory"
    example = site / "factory" / "data" / "examples" / "tower.mpd"
    assert _run([py, script, "verify", example, "--json"], cwd=tmp_path, env=env).returncode == 0

    other = tmp_path / "other"
    (other / "factory").mkdir(parents=True)
    (other / "factory" / "__init__.py").write_text("class Factory:\n    pass\n")
    (other / "factory" / "errors.py").write_text("class FactoryError(Exception):\n    pass\n")
    (other / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools>=77"]\nbuild-backend = "setuptools.build_meta"\n'
        '[project]\nname = "other-factory"\nversion = "1.0"\n[tool.setuptools]\npackages = ["factory"]\n')
    r = _run([sys.executable, "-m", "pip", "wheel", other, "--no-deps", "--no-build-isolation", "-q",
              "-w", tmp_path / "other-wheels"], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (other_wheel,) = (tmp_path / "other-wheels").glob("*.whl")
    pip = [sys.executable, "-m", "pip", "--python", py]
    assert _run([*pip, "install", "-q", "--no-deps", "--no-index", other_wheel], cwd=tmp_path).returncode == 0

    r = _run([py, script, "verify", example, "--json"], cwd=tmp_path, env=env)
    assert r.returncode != 0 and "InstallClashError" in r.stderr, r.stderr
    assert "other-factory" in r.stderr and "factory/__init__.py (overwritten)" in r.stderr
    assert "factory/errors.py (overwritten)" in r.stderr and "uninstall other-factory" in r.stderr

    assert _run([*pip, "uninstall", "-y", "-q", "other-factory"], cwd=tmp_path).returncode == 0
    r = _run([py, script, "verify", example, "--json"], cwd=tmp_path, env=env)
    assert r.returncode != 0 and "factory/errors.py (missing)" in r.stderr, r.stderr
    assert "reinstall brick-factory" in r.stderr

    r = _run([*pip, "install", "-q", "--no-deps", "--no-index", "--force-reinstall", wheel], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert _run([py, script, "verify", example, "--json"], cwd=tmp_path, env=env).returncode == 0
