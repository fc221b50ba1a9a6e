"""Configs declared once: one to_dict/from_dict policy (`factory.config`) and command lines
generated from the dataclasses (`factory.cli.add_config_args`), so a default lives in one place."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dataset_support import tiny_dataset_config
from factory.dataset.tasks import TASKS
from factory.cli import config_from_args
from factory.config import ConfigError, config_from_dict, config_to_dict, field_docs
from factory.embedded.catalog import PARTS
from factory.physics.check import CheckConfig
from factory.physics.load_model import LoadConfig
from factory.sampler import SamplerConfig, SamplerConfigError
from pipelines import designs, sample, synth
from pipelines.dataset import DatasetConfig
from pipelines.dataset.config import SCHEMA_VERSION, started_hash
from train.__main__ import config_from_args as train_config_from_args, parser as train_parser
from train.config import ConfigError as TrainConfigError, TrainConfig

CONFIGS = (SamplerConfig, CheckConfig, LoadConfig, DatasetConfig, TrainConfig)
"""Every config dataclass of the project."""


def synth_parser() -> argparse.ArgumentParser:
    return synth.parser()


def sample_config(argv: list[str]) -> SamplerConfig:
    """The `SamplerConfig` `pipelines.sample` builds from `argv`."""
    return sample.sampler_config(sample.parser().parse_args(["--n", "1", "--out", "unused", *argv]))


def _json(d: dict) -> dict:
    return json.loads(json.dumps(d))


# -- one declaration per field ----------------------------------------------------------------------
@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_every_field_has_a_docstring(cls):
    docs = field_docs(cls)
    missing = [f.name for f in dataclasses.fields(cls) if not docs.get(f.name)]
    assert not missing, f"{cls.__name__} fields without a docstring: {missing}"


@pytest.mark.parametrize("cls", [SamplerConfig, CheckConfig, LoadConfig, DatasetConfig, TrainConfig],
                         ids=lambda c: c.__name__)
def test_configs_are_frozen(cls):
    assert cls.__dataclass_params__.frozen


# -- to_dict / from_dict ------------------------------------------------------------------------------
def _examples():
    loads = dataclasses.replace(LoadConfig(), clutch_n=0.7, support_points=4)
    sampler = SamplerConfig(parts=[("3001", 2.0), "3003"], colours={4: 1, 15: 3}, min_steps=3, max_steps=7,
                            candidates_per_step=9, backend="jax", seed=5,
                            check=CheckConfig(max_penetration_ldu=0.25, loads=loads))
    models = ({"object_id": "car", "path": "/x/car.ldr", "sha256": "ab"},)
    return [
        SamplerConfig(),
        sampler,
        CheckConfig(max_penetration_ldu=0.25, loads=loads),
        loads,
        DatasetConfig.synthetic(3, seed=5, sampler=sampler, size=96, train_fraction=0.5),
        DatasetConfig("design", 1, seed=2, models=models, physics=False, ldraw="/lib"),
        TrainConfig(data=("/a", "/b"), outdir="/run", tasks=("pose",), lr=1e-3, workers=0, eval_limit=3, lora=False),
    ]


@pytest.mark.parametrize("config", _examples(), ids=lambda c: type(c).__name__)
def test_to_dict_from_dict_round_trip_through_json(config):
    cls = type(config)
    d = config.to_dict() if hasattr(config, "to_dict") else config_to_dict(config)
    again = cls.from_dict(_json(d)) if hasattr(cls, "from_dict") else config_from_dict(cls, _json(d))
    assert again == config
    assert json.dumps(d, sort_keys=True) == json.dumps(_json(d), sort_keys=True)  # JSON values only


@pytest.mark.parametrize("config", _examples(), ids=lambda c: type(c).__name__)
def test_unknown_keys_are_refused_listing_the_valid_ones(config):
    cls = type(config)
    d = {**(config.to_dict() if hasattr(config, "to_dict") else config_to_dict(config)), "colour_set": 1}
    with pytest.raises(ValueError) as err:
        cls.from_dict(d) if hasattr(cls, "from_dict") else config_from_dict(cls, d)
    text = str(err.value)
    assert "'colour_set'" in text and "valid keys" in text
    assert all(f.name in text for f in dataclasses.fields(cls))


def test_errors_keep_each_config_s_own_type():
    with pytest.raises(SamplerConfigError):
        SamplerConfig.from_dict({"min_step": 3})
    with pytest.raises(TrainConfigError):
        TrainConfig.from_dict({"data": ["/a"], "outdir": "/r", "step": 3})
    with pytest.raises(ConfigError):
        DatasetConfig.from_dict({"source": "synthetic", "n_objects": 2, "sed": 1})
    with pytest.raises(TrainConfigError, match="missing required key.*'outdir'"):
        TrainConfig.from_dict({"data": ["/a"]})


def test_a_nested_unknown_key_names_its_place():
    d = SamplerConfig().to_dict()
    d["check"] = {"loads": {"clutch": 1.0}}
    with pytest.raises(SamplerConfigError, match=r"SamplerConfig\.check\.loads: unknown key.*'clutch'.*valid keys: clutch_n"):
        SamplerConfig.from_dict(d)


def test_dataset_json_record_is_versioned_and_refuses_another_version():
    cfg = tiny_dataset_config()
    record = cfg.to_json()
    assert record["schema_version"] == SCHEMA_VERSION == 2 and DatasetConfig.from_json(record) == cfg
    with pytest.raises(ConfigError, match="schema version 99"):
        DatasetConfig.from_json({**record, "schema_version": 99})
    design = DatasetConfig("design", 1, models=({"object_id": "m", "path": "/m.ldr", "sha256": "0"},))
    assert design.to_json()["sampler"] == {} and DatasetConfig.from_json(design.to_json()) == design


OLD_DEFAULT_PARTS = (
    "3005:1,3004:1,3622:1,3010:1,3009:1,3008:1,3003:1,3002:1,3001:1,2456:1,3007:1,3006:1,3024:1,3023:1,3623:1,"
    "3710:1,3666:1,3460:1,3022:1,3021:1,3020:1,3795:1,3034:1,3832:1,3031:1,3958:1,3035:1,3036:1,3030:1,3070b:0.5,"
    "63864:0.5,2431:0.5,3068b:0.5,3069b:0.5,3040b:0.5,3039:0.5,3038:0.5,3037:0.5,3665:0.5,3660:0.5"
)
OLD_DEFAULT_COLOURS = "0,1,2,4,14,15,19,25,70,71,72"
"""The sampler's defaults before the usage prior: the 40 box parts, tiles and slopes at half weight,
eleven colours alike."""


def test_hash_of_a_build_made_before_the_sampler_was_typed_is_unchanged(monkeypatch):
    """`pipelines.synth --n 2 --seed 0` wrote meta/config.json with hash 7128f1ff5ea58dd7 before
    `DatasetConfig.sampler` became a `SamplerConfig` (the sampler a dict of ordered [name, weight]
    lists, no `check`, no prior); the same config must keep it, or old folders would not resume.
    Its parts and colours were the defaults then; given as flags now (the defaults come from the
    usage prior), they make the same config, and one read back without a `prior` key has none."""
    monkeypatch.delenv("LDRAWDIR", raising=False)
    args = synth_parser().parse_args(["--n", "2", "--out", "unused", "--seed", "0", "--parts", OLD_DEFAULT_PARTS,
                                      "--colours", OLD_DEFAULT_COLOURS])
    config = synth.config_from_args(args)
    # Schema version 2 leaves the check backend out of the hash; the folder resumes under the hash it
    # recorded (the version-1 rule, with the run settings that version wrote: `version1_record`).
    old = {"config_hash": "7128f1ff5ea58dd7",
           "config": {**config.to_json(), "schema_version": 1,
                      "sampler": {**config.to_json()["sampler"], "backend": "mujoco", "check_batch": 1}}}
    assert config.sampler.prior == "" and started_hash(config, old) == "7128f1ff5ea58dd7" != config.hash
    assert type(config).from_json(config.to_json()) == config  # no `prior` key in the record: none
    # the default command now draws from the shipped prior: another config, which an old folder refuses
    default = synth.config_from_args(synth_parser().parse_args(["--n", "2", "--out", "unused", "--seed", "0"]))
    assert default.sampler.prior.startswith("default sha256:") and started_hash(default, old) is None


def test_check_thresholds_are_recorded_only_when_changed():
    assert "check" not in SamplerConfig().to_dict()
    changed = SamplerConfig(check=CheckConfig(max_penetration_ldu=0.25))
    assert changed.to_dict()["check"]["max_penetration_ldu"] == 0.25
    base = DatasetConfig.synthetic(2)
    assert DatasetConfig.synthetic(2, sampler=changed).hash != base.hash


def test_check_batch_default_follows_the_backend():
    assert SamplerConfig().check_batch == 1
    assert SamplerConfig(backend="jax", candidates_per_step=16).check_batch == 16
    assert SamplerConfig(backend="jax").check_batch == 16  # JAX_CHECK_BATCH, below the 64 candidates
    assert SamplerConfig(backend="jax", candidates_per_step=8).check_batch == 8
    assert SamplerConfig(backend="jax", candidates_per_step=16, check_batch=4).check_batch == 4
    with pytest.raises(SamplerConfigError, match="check_batch must be >= 1"):
        SamplerConfig(check_batch=0)


def test_dataset_sampler_is_typed_and_shares_the_seed():
    cfg = DatasetConfig.synthetic(4, seed=9, sampler=SamplerConfig(min_steps=3, max_steps=5))
    assert isinstance(cfg.sampler, SamplerConfig) and cfg.sampler.seed == 9 and cfg.sampler.min_steps == 3
    assert DatasetConfig("synthetic", 4, seed=9) == DatasetConfig.synthetic(4, seed=9)
    with pytest.raises(ConfigError, match=r"sampler.seed \(1\) must equal seed \(9\)"):
        DatasetConfig("synthetic", 4, seed=9, sampler=SamplerConfig(seed=1))
    with pytest.raises(ConfigError, match="a design dataset has no sampler"):
        DatasetConfig("design", 1, models=({"object_id": "m", "path": "/m", "sha256": "0"},), sampler=SamplerConfig())


# -- generated command lines --------------------------------------------------------------------------
def _flag_actions(ap: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {a.dest: a for a in ap._actions if a.help != argparse.SUPPRESS and a.option_strings}


@pytest.mark.parametrize("cls, prefix, ap, skip, own", [
    (DatasetConfig, "", synth_parser(), synth.NOT_FLAGS, {}),
    # The main job's checks take the GPU where there is one (`synth.AUTO`), the library's the reference.
    (SamplerConfig, "sampler.", synth_parser(), ("seed", "check"), {"backend": synth.AUTO}),
    (TrainConfig, "", train_parser(), ("lora",), {}),
], ids=["synth-dataset", "synth-sampler", "train"])
def test_the_command_line_has_a_flag_per_field_with_its_default_and_help(cls, prefix, ap, skip, own):
    actions = _flag_actions(ap)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        if (prefix + f.name in skip or f.name in skip or dataclasses.is_dataclass(f.type) or f.name == "sampler"
                or f.metadata.get("flag") is False):  # (set by the command itself)
            continue
        action = actions[prefix + f.name]
        assert docs[f.name].replace("%", "%%") in action.help
        if f.default is not dataclasses.MISSING:
            assert action.default == own.get(f.name, f.default), f.name
            rendered = ap._get_formatter()._expand_help(action)
            assert "(default: " in rendered, rendered
        else:
            assert action.required


def test_the_lora_flag_keeps_its_auto_choice():
    args = train_parser().parse_args(["--data", "/d", "--outdir", "/r"])
    assert train_config_from_args(args).lora is False  # a model built from a config: full fine-tuning
    args = train_parser().parse_args(["--data", "/d", "--outdir", "/r", "--model", "/m"])
    assert train_config_from_args(args).lora is True
    args = train_parser().parse_args(["--data", "/d", "--outdir", "/r", "--lora", "1"])
    assert train_config_from_args(args).lora is True


def test_no_flags_give_the_dataclass_defaults():
    args = synth_parser().parse_args(["--n", "2", "--out", "unused"])
    assert synth.config_from_args(args) == DatasetConfig.synthetic(2, ldraw=synth._ldraw(None))
    assert sample_config([]) == SamplerConfig()
    args = train_parser().parse_args(["--data", "/d", "--outdir", "/r"])
    assert train_config_from_args(args) == TrainConfig(data=("/d",), outdir="/r", lora=False)


def test_synth_command_line_and_the_factory_function_agree(monkeypatch):
    from test_dataset import CLI_ARGS

    monkeypatch.delenv("LDRAWDIR", raising=False)
    args = synth_parser().parse_args([*CLI_ARGS, "--out", "unused"])
    assert synth.config_from_args(args) == tiny_dataset_config()


def test_sample_and_synth_configure_the_sampler_alike(monkeypatch):
    monkeypatch.delenv("LDRAWDIR", raising=False)
    argv = ["--seed", "4", "--min-steps", "3", "--max-steps", "6", "--candidates", "12", "--check-backend", "jax",
            "--temperature", "0.5", "--parts", "3001:2,3003"]
    from_sample = sample_config(argv)
    from_synth = synth.config_from_args(synth_parser().parse_args(["--n", "1", "--out", "unused", *argv])).sampler
    assert from_sample == from_synth
    assert from_sample.check_batch == 12 and from_sample.parts == (("3001", 2.0), ("3003", 1.0))


def test_old_flag_spellings_still_work_with_a_warning(capsys):
    args = synth_parser().parse_args(["--n", "1", "--out", "o", "--backend", "ray", "--quiet"])
    assert args.runner == "ray" and args.no_progress
    err = capsys.readouterr().err
    assert "--backend is deprecated, use --runner" in err and "--quiet is deprecated, use --no-progress" in err
    assert sample_config(["--backend", "jax"]).backend == "jax"
    assert "--backend is deprecated, use --check-backend" in capsys.readouterr().err
    # The backends' former names: mapped to the new ones, with a warning line.
    assert sample_config(["--check-backend", "mjx"]).backend == "jax"
    assert "warning: check backend 'mjx' is deprecated; use 'jax'" in capsys.readouterr().err
    args = synth_parser().parse_args(["--n", "1", "--out", "o", "--check-backend", "mujoco"])
    assert getattr(args, "sampler.backend") == "cpu"
    assert "warning: check backend 'mujoco' is deprecated; use 'cpu'" in capsys.readouterr().err
    assert synth_parser().parse_args(["--n", "1", "--out", "o", "--png-level", "3"]).png_compress_level == 3


def test_auto_checks_take_the_gpu_only_with_an_nvidia_gpu_and_cudas_jax(tmp_path, monkeypatch):
    """`--check-backend auto` (synth's default) resolves per machine: the reference without an
    NVIDIA GPU or without JAX's CUDA build, the batched checks with both; the config holds the
    backend taken (its hash does not). The GPU is the driver's listing (`gpus._NVIDIA_GPUS`), here a folder."""
    from factory import gpus

    monkeypatch.delenv("LDRAWDIR", raising=False)
    args = synth_parser().parse_args(["--n", "2", "--out", "unused"])
    assert getattr(args, "sampler.backend") == synth.AUTO
    monkeypatch.setattr(gpus, "_NVIDIA_GPUS", str(tmp_path / "none"))
    assert synth.checks_backend(args) == ("cpu", "no NVIDIA GPU here")
    assert synth.config_from_args(args).sampler.backend == "cpu"
    (tmp_path / "gpus" / "0000:01:00.0").mkdir(parents=True)
    monkeypatch.setattr(gpus, "_NVIDIA_GPUS", str(tmp_path / "gpus"))
    monkeypatch.setattr(gpus, "cuda_jax", lambda: None)
    backend, why = synth.checks_backend(args)
    assert backend == "cpu" and "no CUDA build of JAX" in why
    monkeypatch.setattr(gpus, "cuda_jax", lambda: "jax-cuda13-plugin")
    assert synth.checks_backend(args) == ("jax", "1 NVIDIA GPU(s) and JAX's CUDA build (jax-cuda13-plugin)")
    cfg = synth.config_from_args(args)
    assert cfg.sampler.backend == "jax" and cfg.sampler.check_batch == 16  # the batched path's own default
    chosen = synth_parser().parse_args(["--n", "2", "--out", "unused", "--check-backend", "cpu"])
    assert synth.config_from_args(chosen).sampler.backend == "cpu"  # a chosen backend is kept
    assert synth.config_from_args(chosen).hash == cfg.hash  # the same dataset either way


def test_a_bad_choice_lists_the_valid_ones(capsys):
    with pytest.raises(SystemExit):
        synth_parser().parse_args(["--n", "1", "--out", "o", "--check-backend", "cuda"])
    assert "choose from 'cpu', 'jax'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_parser().parse_args(["--data", "/d", "--outdir", "/r", "--tasks", "pose,colour"])
    assert f"'colour' is not valid; valid: {', '.join(TASKS)}" in capsys.readouterr().err


def test_designs_command_line_sets_design_fields(tmp_path, monkeypatch):
    monkeypatch.delenv("LDRAWDIR", raising=False)
    model = tmp_path / "wall.ldr"
    model.write_text("1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    args = designs.parser().parse_args([str(model), "--out", "o", "--no-physics", "--seed", "3"])
    cfg = designs.config_from_args(args)
    assert cfg == designs.design_config([model], None, seed=3, physics=False, objects_per_shard=1)
    assert cfg.models[0]["object_id"] == "wall" and cfg.sampler is None


# -- properties ---------------------------------------------------------------------------------------
part_names = [p.number for p in PARTS]
floats = st.floats(0.01, 10, allow_nan=False, allow_infinity=False)


@st.composite
def synth_settings(draw):
    lo = draw(st.integers(1, 40))
    sampler = dict(min_steps=lo, max_steps=draw(st.integers(lo, 60)), density_weight=draw(floats),
                   temperature=draw(floats), candidates_per_step=draw(st.integers(1, 99)),
                   max_redraws=draw(st.integers(0, 9)), backend=draw(st.sampled_from(["cpu", "jax"])),
                   parts=tuple((p, draw(floats)) for p in draw(st.lists(st.sampled_from(part_names), min_size=1,
                                                                        max_size=5, unique=True))))
    if draw(st.booleans()):
        sampler["check_batch"] = draw(st.integers(1, 64))
    dataset = dict(n_objects=draw(st.integers(1, 10**6)), seed=draw(st.integers(0, 2**63 - 1)),
                   size=draw(st.integers(32, 2048)), tile=draw(st.integers(32, 1024)),
                   objects_per_shard=draw(st.integers(1, 64)), train_fraction=draw(st.floats(0, 1)),
                   png_compress_level=draw(st.integers(0, 9)))
    return dataset, sampler


def _argv(settings_: dict, names: dict[str, str]) -> list[str]:
    argv = []
    for k, v in settings_.items():
        flag = "--" + names.get(k, k.replace("_", "-"))
        if isinstance(v, tuple):
            v = ",".join(f"{a}:{w!r}" for a, w in v)
        argv += [flag, repr(v) if isinstance(v, float) else str(v)]
    return argv


@settings(max_examples=60, deadline=None)
@given(synth_settings())
def test_any_synth_config_survives_the_command_line_and_json(s):
    dataset, sampler = s
    # Parts and colours given (else they come from the usage prior and the library, which /lib is not).
    sampler = {"parts": (("3005", 1.0),), "colours": ((4, 1.0),), **sampler}
    expected = DatasetConfig.synthetic(sampler=SamplerConfig(**sampler, prior=""), **dataset)
    argv = _argv(dataset, {"n_objects": "n"}) + _argv(sampler, {"backend": "check-backend"})
    args = synth_parser().parse_args([*argv, "--out", "unused", "--ldraw", "/lib"])
    got = synth.config_from_args(args)
    assert dataclasses.replace(got, ldraw=None) == expected
    assert DatasetConfig.from_dict(_json(got.to_dict())) == got
    # The JSON record leaves the run settings out (the checks' backend, check_batch, judge_first).
    again = DatasetConfig.from_json(_json(got.to_json()))
    assert again.to_json() == got.to_json() and again.hash == got.hash and again.sampler.backend == "cpu"


@settings(max_examples=60, deadline=None)
@given(steps=st.integers(1, 10**5), lr=st.floats(1e-7, 1.0), tasks=st.lists(st.sampled_from(TASKS), min_size=1,
                                                                              unique=True),
       workers=st.one_of(st.none(), st.integers(0, 16)), evaluate=st.booleans(), gc=st.booleans(),
       dtype=st.sampled_from(["auto", "bf16", "fp32"]), targets=st.lists(st.sampled_from(["q_proj", "v_proj", "up_proj"]),
                                                                        min_size=1, unique=True))
def test_any_train_config_survives_the_command_line_and_json(steps, lr, tasks, workers, evaluate, gc, dtype, targets):
    expected = TrainConfig(data=("/d1", "/d2"), outdir="/run", model="/m", tasks=tuple(tasks), steps=steps, lr=lr,
                           workers=workers, eval=evaluate, gradient_checkpointing=gc, dtype=dtype,
                           lora_targets=tuple(targets), lora=True)
    argv = ["--data", "/d1", "--data", "/d2", "--outdir", "/run", "--model", "/m", "--tasks", ",".join(tasks),
            "--steps", str(steps), "--lr", repr(lr), "--dtype", dtype, "--lora-targets", ",".join(targets),
            "--eval" if evaluate else "--no-eval",
            "--gradient-checkpointing" if gc else "--no-gradient-checkpointing"]
    if workers is not None:
        argv += ["--workers", str(workers)]
    got = train_config_from_args(train_parser().parse_args(argv))
    assert got == expected
    assert TrainConfig.from_dict(_json(got.to_dict())) == got and TrainConfig.from_json(got.to_json()) == got


def test_train_config_saved_by_an_earlier_run_loads(tmp_path):
    """A checkpoint's train_config.json (lists for tuples, every field) loads back equal."""
    cfg = TrainConfig(data=(str(tmp_path),), outdir=str(tmp_path / "run"))
    path = cfg.save(tmp_path)
    assert TrainConfig.load(Path(path).parent) == cfg
    assert json.loads(path.read_text())["tasks"] == list(TASKS)
