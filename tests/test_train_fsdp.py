"""`torchrun --nproc_per_node 2 -m train --shard fsdp` on the CPU (two gloo processes, FSDP2's
`fully_shard`, the tiny Qwen2-VL, full fine-tuning with gradient checkpointing and 2 passes per
step): two sharded processes at batch 1 train as one process at batch 2 (the same losses, clipped
gradient norms and final weights up to float rounding); a checkpoint holds the whole model and
each process's optimizer slice, and an interrupted sharded run resumes to the same result; which
modules become FSDP units in every family; the settings FSDP refuses."""

from __future__ import annotations

import json

import pytest
from process_support import torchrun
from training_support import assert_resumed_run_is_the_same, interrupted_copy, run_weights, train_argv, train_log

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

MORE = ("--lora", "0", "--gradient-checkpointing", "--grad-accum", "2", "--no-eval")


def _two_sharded_processes(argv):
    done = torchrun("train", *argv, "--shard", "fsdp")
    assert done.returncode == 0, done.stderr[-3000:]
    return done


@pytest.fixture(scope="module")
def runs(tiny_dataset, tiny_model, tmp_path_factory):
    """3 steps of 4 examples (2 passes of 2): one process at batch 2, and two sharded by FSDP at
    batch 1; (one, two)."""
    from train.__main__ import main

    root = tmp_path_factory.mktemp("fsdp")
    one, two = root / "one", root / "two"
    assert main(train_argv(tiny_dataset, tiny_model, one, *MORE, "--batch-size", "2")) == 0
    _two_sharded_processes(train_argv(tiny_dataset, tiny_model, two, *MORE, "--batch-size", "1"))
    return one, two


@pytest.mark.slow
def test_two_sharded_processes_train_as_one_with_their_global_batch(runs, tiny_model):
    from safetensors.torch import load_file

    one, two = runs
    a, b = train_log(one), train_log(two)
    assert [r["step"] for r in b] == [1, 2, 3] and [r["examples"] for r in b] == [4, 8, 12]
    assert [r["examples"] for r in a] == [r["examples"] for r in b]
    for ra, rb in zip(a, b):
        assert rb["loss"] == pytest.approx(ra["loss"], abs=1e-4)
        # the norm of the sharded gradient (DTensors) before clipping, the same as one process's
        assert rb["grad_norm"] == pytest.approx(ra["grad_norm"], rel=1e-4)
    assert min(r["grad_norm"] for r in b) > 1.0  # above --max-grad-norm 1: every step was clipped
    wa, wb, w0 = run_weights(one), run_weights(two), load_file(str(tiny_model / "model.safetensors"))
    assert wa.keys() == wb.keys() == w0.keys()
    for k in wa:
        assert wb[k].dtype == wa[k].dtype == torch.float32
        torch.testing.assert_close(wb[k], wa[k], atol=1e-5, rtol=0, msg=k)
    assert max(float((wa[k] - w0[k]).abs().max()) for k in wa) > 1e-3  # 100 times the tolerance


def test_a_sharded_checkpoint_holds_the_whole_model_and_each_process_optimizer_slice(runs):
    from train import checkpoint as ckpt

    one, two = runs
    assert [s for s, _ in ckpt.checkpoints(two)] == [2, 3]
    assert not [p.name for p in two.iterdir() if p.name.startswith(".")]  # no temporary folder left
    folder = two / "checkpoint-000003"
    state = ckpt.load_state(folder)
    assert state["shard"] == "fsdp" and state["processes"] == 2 and "optimizer" not in state
    assert len(state["rng_ranks"]) == 2
    files = sorted(p.name for p in (folder / ckpt.OPTIMIZER_DIR).iterdir())
    assert files == [".metadata", "__0_0.distcp", "__1_0.distcp"]  # one file per process
    # the gathered weights are the final model's (nothing trained after the last checkpoint)
    from safetensors.torch import load_file

    saved, final = load_file(str(folder / "model.safetensors")), run_weights(two)
    assert saved.keys() == final.keys() and all(torch.equal(saved[k], final[k]) for k in saved)
    assert json.loads((two / "train_summary.json").read_text())["processes"] == 2


@pytest.mark.slow
def test_an_interrupted_sharded_run_resumes_to_the_same_result(runs, tmp_path):
    _, two = runs
    run, config, log_before, weights_before = interrupted_copy(two, tmp_path)
    _two_sharded_processes(train_argv(config["data"][0], config["model"], run, *MORE, "--batch-size", "1"))
    assert_resumed_run_is_the_same(run, log_before, weights_before)


def test_a_sharded_run_is_resumed_sharded_by_as_many_processes_only(runs, tiny_dataset, tiny_model, capsys):
    from train.__main__ import main

    _, two = runs
    argv = train_argv(tiny_dataset, tiny_model, two, *MORE, "--batch-size", "1")
    capsys.readouterr()
    assert main(argv) == 2  # DDP settings (the default) in the sharded run's folder
    assert "shard: 'fsdp' -> 'ddp'" in capsys.readouterr().err
    assert main([*argv, "--shard", "fsdp"]) == 2  # one process
    err = capsys.readouterr().err
    assert "checkpoint-000003 was trained by 2 process(es)" in err and "this run has 1" in err


def test_fsdp_refuses_lora_and_unknown_modes(tiny_dataset, tiny_model, tmp_path, capsys):
    from train.__main__ import main
    from train.config import ConfigError, TrainConfig

    with pytest.raises(ConfigError, match=r"shard='zero' is not valid; valid: ddp, fsdp"):
        TrainConfig(data=("d",), outdir="o", lora=False, shard="zero")
    with pytest.raises(ConfigError, match=r"shard=fsdp trains every weight.*--lora 0.*--shard ddp"):
        TrainConfig(data=("d",), outdir="o", lora=True, shard="fsdp")
    with pytest.raises(ConfigError, match=r"applies with shard=fsdp only; give --shard fsdp"):
        TrainConfig(data=("d",), outdir="o", lora=False, fsdp_keep_gathered=True)
    # --lora auto is LoRA for a given --model: refused, naming --lora 0
    assert main(train_argv(tiny_dataset, tiny_model, tmp_path / "run", "--shard", "fsdp")) == 2
    assert "--lora 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(train_argv(tiny_dataset, tiny_model, tmp_path / "run", "--shard", "zero"))
    assert "invalid choice: 'zero' (choose from ddp, fsdp)" in capsys.readouterr().err.replace("'ddp', 'fsdp'",
                                                                                              "ddp, fsdp")


FAMILY_UNITS = {
    # family: (the language model's blocks, the vision tower's), as the tiny configs have them
    "qwen2-vl": ("model.language_model.layers", "model.visual.blocks"),
    "qwen2.5-vl": ("model.language_model.layers", "model.visual.blocks"),
    "qwen3-vl": ("model.language_model.layers", "model.visual.blocks"),
    "gemma3": ("model.language_model.layers", "model.vision_tower.encoder.layers"),
    "internvl3": ("model.language_model.layers", "model.vision_tower.encoder.layer"),
}


@pytest.mark.parametrize("name", list(FAMILY_UNITS))
def test_every_transformer_block_is_an_fsdp_unit(name, tiny_dataset):
    """`shard_units` of each family's tiny model (built on the meta device): each decoder layer and
    vision block, nothing else (embeddings, LM head, projector and norms stay in the root unit)."""
    from transformers import AutoModelForImageTextToText

    from train.distributed import shard_units
    from train.tiny import dataset_texts, family, tiny_config, train_tokenizer

    fam = family(name)
    tok = train_tokenizer(dataset_texts([tiny_dataset]), 1024, fam)
    with torch.device("meta"):
        model = AutoModelForImageTextToText.from_config(tiny_config(tok, 1024, fam, "tiny"))
    lm, vision = FAMILY_UNITS[name]
    n_lm, n_vision = len(model.get_submodule(lm)), len(model.get_submodule(vision))
    assert n_lm >= 2 and n_vision >= 2
    expected = [f"{lm}.{i}" for i in range(n_lm)] + [f"{vision}.{i}" for i in range(n_vision)]
    assert sorted(shard_units(model)) == sorted(expected)


def test_sharding_makes_each_block_and_the_root_a_unit(tiny_model):
    """`shard_model` in this process (a gloo group of one): the blocks and the root become FSDP
    modules whose weights are DTensors, nothing else does; then a forward and backward pass runs."""
    import torch.distributed as dist
    from torch.distributed.tensor import DTensor

    from train.distributed import Group, is_sharded, shard_model, shard_units
    from train.model import load_base

    model = load_base(tiny_model)
    units = set(shard_units(model))
    dist.init_process_group("gloo", store=dist.HashStore(), rank=0, world_size=1)
    try:
        shard_model(model, Group(processes=1))
        sharded = {name for name, m in model.named_modules() if is_sharded(m)}
        assert sharded == units | {""}  # "" is the root
        assert all(isinstance(p, DTensor) for p in model.parameters())
        ids = torch.randint(0, 100, (1, 8))
        model(input_ids=ids, labels=ids).loss.backward()
        assert all(isinstance(p.grad, DTensor) for p in model.parameters() if p.grad is not None)
    finally:
        dist.destroy_process_group()


@pytest.mark.parametrize("keep", [False, True])
def test_kept_gathered_weights_stay_gathered_from_forward_to_backward(tiny_model, keep):
    """`shard_model(keep_gathered=...)` in this process (a gloo group of one): after a forward pass
    a block's weights are its sharded DTensors again (freed, to be gathered for the backward), or
    with `keep_gathered` still the gathered plain tensors; both then train the same step."""
    import torch.distributed as dist
    from torch.distributed.tensor import DTensor

    from train.distributed import Group, shard_model, shard_units
    from train.model import load_base

    torch.manual_seed(0)
    model = load_base(tiny_model)
    block = next(u for u in shard_units(model) if "language_model" in u)  # a text-only pass skips the vision blocks
    dist.init_process_group("gloo", store=dist.HashStore(), rank=0, world_size=1)
    try:
        shard_model(model, Group(processes=1), keep_gathered=keep)
        ids = torch.randint(0, 100, (1, 8))
        loss = model(input_ids=ids, labels=ids).loss
        weights = list(model.get_submodule(block).parameters())
        assert all(isinstance(w, DTensor) != keep for w in weights)
        loss.backward()
        assert all(isinstance(w, DTensor) for w in model.get_submodule(block).parameters())  # resharded
    finally:
        dist.destroy_process_group()


@pytest.mark.slow
def test_two_processes_keeping_gathered_weights_train_as_the_sharded_run(runs, tiny_dataset, tiny_model, tmp_path):
    """`--fsdp-keep-gathered` (python -m train under torchrun): the same losses and final weights as
    the sharded run that gathers each block twice."""
    _, two = runs
    kept = tmp_path / "kept"
    _two_sharded_processes(train_argv(tiny_dataset, tiny_model, kept, *MORE, "--batch-size", "1",
                                      "--fsdp-keep-gathered"))
    assert json.loads((kept / "train_config.json").read_text())["fsdp_keep_gathered"] is True
    for ra, rb in zip(train_log(two), train_log(kept), strict=True):
        assert rb["loss"] == pytest.approx(ra["loss"], abs=1e-6)
    wa, wb = run_weights(two), run_weights(kept)
    for k in wa:
        torch.testing.assert_close(wb[k], wa[k], atol=1e-6, rtol=0, msg=k)


def test_a_sharded_gemma3_saves_its_tied_lm_head_once(tiny_dataset, tmp_path):
    """Gemma 3 ties its LM head to the embeddings: gathered from the shards (a gloo group of one
    here), the state dict names one tensor twice as the model's own does, so the saved files hold
    the unsharded model's keys and values (not a second copy of the embeddings)."""
    import torch.distributed as dist
    from safetensors.torch import load_file

    from train import checkpoint as ckpt
    from train.distributed import Group, shard_model
    from train.model import load_base
    from train.tiny import build_tiny_model, dataset_texts

    base = build_tiny_model(tmp_path / "gemma3", dataset_texts([tiny_dataset]), seed=0, family_name="gemma3")
    model = load_base(base)
    assert model.lm_head.weight is model.get_input_embeddings().weight
    model.save_pretrained(str(tmp_path / "plain"))
    dist.init_process_group("gloo", store=dist.HashStore(), rank=0, world_size=1)
    try:
        shard_model(model, Group(processes=1))
        state = ckpt.full_model_state(model)
        assert state["lm_head.weight"] is state["model.language_model.embed_tokens.weight"]
        ckpt.save_model(model, tmp_path / "sharded", state)
    finally:
        dist.destroy_process_group()
    plain, sharded = load_file(str(tmp_path / "plain" / "model.safetensors")), load_file(
        str(tmp_path / "sharded" / "model.safetensors"))
    assert sharded.keys() == plain.keys() and "lm_head.weight" not in sharded
    assert all(torch.equal(sharded[k], plain[k]) for k in plain)
