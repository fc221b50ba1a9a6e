"""The check backends' names (`cpu`, `jax`; the former `mujoco` and `mjx` still accepted) and the
dataset identity without them (schema version 2): the hash is the same for either backend, and a
folder the version-1 code started, whose hash held the backend, resumes without rebuilding."""

from __future__ import annotations

import filecmp
import hashlib
import json
import shutil
import warnings
from pathlib import Path

import pytest

from dataset_support import tiny_dataset_config
from factory.dataset.info import json_bytes
from factory.physics.check import BACKENDS, backend_name, check
from factory.sampler import SamplerConfig, SamplerConfigError
from pipelines.dataset import ConfigMismatchError, DatasetConfig, build
from pipelines.dataset.config import version1_record


# -- the backends' names ---------------------------------------------------------------------------
def test_backends_are_cpu_and_jax_and_the_old_names_warn():
    assert BACKENDS == ("cpu", "jax")
    with pytest.warns(FutureWarning, match="check backend 'mjx' is deprecated; use 'jax'"):
        assert SamplerConfig(backend="mjx").backend == "jax"
    with pytest.warns(FutureWarning, match="check backend 'mujoco' is deprecated; use 'cpu'"):
        old = SamplerConfig(backend="mujoco")
    assert old.backend == "cpu" and old == SamplerConfig()
    with pytest.warns(FutureWarning, match="'mjx' is deprecated") as caught:
        batched = SamplerConfig(backend="mjx")
    assert caught[0].filename == __file__  # the warning names the caller's line
    assert batched.check_batch == 16 == SamplerConfig(backend="jax").check_batch  # the batched path's default
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new names do not warn
        assert backend_name("cpu") == "cpu" and SamplerConfig(backend="jax").backend == "jax"


def test_an_unknown_backend_lists_the_choices():
    with pytest.raises(SamplerConfigError, match=r"unknown check backend 'cuda'; valid choices: cpu, jax"):
        SamplerConfig(backend="cuda")
    with pytest.raises(ValueError, match=r"valid choices: cpu, jax"):
        backend_name("mujoco-mjx")


def test_check_takes_the_old_names_too():
    from factory import Pose, get_reader, load_part
    from factory.physics.structure import Structure

    brick = load_part(get_reader(), "3001")
    with pytest.warns(FutureWarning, match="'mujoco' is deprecated; use 'cpu'"):
        (old,) = check(Structure(), brick, [Pose.identity()], backend="mujoco")
    (new,) = check(Structure(), brick, [Pose.identity()], backend="cpu")
    assert old.reason == new.reason


# -- the dataset's identity ------------------------------------------------------------------------
def test_the_dataset_hash_is_the_same_for_every_backend():
    cpu, jax = (DatasetConfig.synthetic(3, seed=0, sampler=SamplerConfig(min_steps=2, max_steps=3, backend=b))
                for b in ("cpu", "jax"))
    assert cpu.sampler.check_batch != jax.sampler.check_batch  # a run setting that follows the backend
    assert cpu.hash == jax.hash and cpu.to_json() == jax.to_json()
    assert "backend" not in cpu.to_json()["sampler"] and cpu.to_json()["schema_version"] == 2
    # A worker gets the whole config, the backend included; the JSON record reads back without it.
    assert DatasetConfig.from_any(jax.to_dict()) == jax and DatasetConfig.from_any(jax.to_json()) == cpu
    assert DatasetConfig.from_json(jax.to_json()).sampler.backend == "cpu"


def _canonical_hash(record: dict) -> str:
    """The version-1 code's hash of a record, written out here (not the library's)."""
    text = json.dumps(record, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _as_version_1(out: Path, config: DatasetConfig, backend: str, check_batch: int) -> tuple[str, dict]:
    """Rewrite a finished folder's meta/config.json and shard markers as the version-1 code wrote
    them for `config` built with `backend` (its name then): the record with `schema_version` 1 and
    the sampler's backend and check_batch, its hash over all of that."""
    record = config.to_json()
    record["sampler"] = {**record["sampler"], "backend": backend, "check_batch": check_batch}
    record["schema_version"] = 1
    old_hash = _canonical_hash(record)
    assert old_hash != config.hash
    (out / "meta" / "config.json").write_bytes(json_bytes({"config_hash": old_hash, "config": record}))
    for marker in sorted((out / "meta" / "shards").glob("*.json")):
        rec = json.loads(marker.read_text())
        rec["config_hash"] = old_hash
        marker.write_bytes(json_bytes(rec))
    return old_hash, record


def _snapshot(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes()
            for p in sorted(out.rglob("*")) if p.is_file() and p.relative_to(out).parts[0] in ("data", "meta")
            and p.name not in ("info.json", "timings.json")}


@pytest.mark.parametrize("backend, check_batch", [("mjx", 16), ("mujoco", 1)])
def test_a_folder_started_by_version_1_resumes_without_rebuilding(tiny_dataset, tmp_path, backend, check_batch):
    """A folder the version-1 code finished (its hash over a record naming the backend 'mjx' or
    'mujoco') resumed by this code with the same settings, on the CPU backend: nothing is built
    again, the data files and markers are the same bytes, and the folder keeps its hash and
    record in meta/info.json; the backend this run used is in meta/timings.json."""
    out = tmp_path / "v1"
    shutil.copytree(tiny_dataset, out)
    config = tiny_dataset_config()
    assert config.sampler.backend == "cpu"
    old_hash, record = _as_version_1(out, config, backend, check_batch)
    assert version1_record(config, record) == record  # the rule the code keeps
    before = _snapshot(out)

    summary = build(config, out, progress=False)
    assert summary["shards_built"] == 0 and summary["shards_skipped"] == config.num_shards
    after = _snapshot(out)
    assert after.keys() == before.keys() and [k for k in before if before[k] != after[k]] == []
    for name in before:
        if name.startswith("data/"):
            assert filecmp.cmp(tiny_dataset / name, out / name, shallow=False), name
    info = json.loads((out / "meta" / "info.json").read_text())
    assert (info["config_hash"], info["schema_version"], info["config"]) == (old_hash, 1, record)
    assert old_hash in (out / "README.md").read_text()
    timings = json.loads((out / "meta" / "timings.json").read_text())
    assert timings["checks_last_run"]["backend"] == "cpu" and timings["runner_last_run"] == "local"
    # The folder's record reads back (the old backend name dropped, no warning).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert DatasetConfig.from_json(info["config"]) == config


def test_a_version_1_folder_with_other_settings_is_refused_naming_them(tiny_dataset, tmp_path):
    out = tmp_path / "v1"
    shutil.copytree(tiny_dataset, out)
    _as_version_1(out, tiny_dataset_config(), "mjx", 16)
    before = _snapshot(out)
    with pytest.raises(ConfigMismatchError, match=r"size: 128 -> 96\. Resume"):  # that difference alone
        build(tiny_dataset_config(size=96), out, progress=False)
    assert _snapshot(out) == before
