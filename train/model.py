"""The model being trained: the base loaded from a folder, LoRA adapters on its language model,
and the trained weights restored from a checkpoint or merged for the final model.

LoRA targets only Linear layers of the language model (named in `lora_targets`), never the vision
tower or its merger: the explicit module list is computed here, so a name shared with the vision
encoder (or absent from an architecture) cannot slip in or be silently ignored.
"""

from __future__ import annotations

from pathlib import Path

import torch


class ModelError(ValueError):
    """A model folder or LoRA setting that cannot be used."""


def load_base(path, dtype: torch.dtype = torch.float32):
    """`AutoModelForImageTextToText.from_pretrained(path)` with a clear error for a bad folder."""
    from transformers import AutoModelForImageTextToText  # optional: the [train] extra, seconds to import

    path = Path(path)
    if not (path / "config.json").is_file():
        raise ModelError(f"{path}: not a model folder (no config.json)")
    return AutoModelForImageTextToText.from_pretrained(str(path), dtype=dtype)


def _language_prefix(model) -> str | None:
    names = [n for n, _ in model.named_modules() if n.split(".")[-1] in ("language_model", "text_model")]
    return min(names, key=len) if names else None


def lora_modules(model, targets) -> list[str]:
    """Full names of the language model's Linear layers whose last name part is in `targets`."""
    prefix = _language_prefix(model)
    vision = ("visual", "vision_tower", "vision_model", "multi_modal_projector", "merger")
    out = []
    for name, mod in model.named_modules():
        if not isinstance(mod, torch.nn.Linear) or name.split(".")[-1] not in targets:
            continue
        if prefix is not None and not name.startswith(prefix + "."):
            continue
        if prefix is None and any(v in name.split(".") for v in vision):
            continue
        out.append(name)
    if not out:
        linear = sorted({n.split(".")[-1] for n, m in model.named_modules() if isinstance(m, torch.nn.Linear)})
        raise ModelError(f"no Linear layer of the language model is named {', '.join(targets)}; "
                         f"Linear layer names in this model: {', '.join(linear)}")
    return out


def add_lora(model, config):
    """Wrap `model` with fresh LoRA adapters (initialised from the current torch RNG)."""
    from peft import LoraConfig, get_peft_model  # optional: LoRA alone needs peft

    lc = LoraConfig(r=config.lora_r, lora_alpha=config.lora_alpha, lora_dropout=config.lora_dropout,
                    target_modules=lora_modules(model, config.lora_targets), bias="none")
    return get_peft_model(model, lc)


def load_adapter_weights(model, folder) -> None:
    """Load a saved adapter (`adapter_model.safetensors`) into a model wrapped by `add_lora`."""
    from peft import set_peft_model_state_dict  # optional: LoRA alone needs peft
    from safetensors.torch import load_file

    result = set_peft_model_state_dict(model, load_file(str(Path(folder) / "adapter_model.safetensors")))
    unexpected = list(getattr(result, "unexpected_keys", []))
    if unexpected:
        raise ModelError(f"{folder}: adapter weights that do not fit the model: {unexpected[:5]}")


def trainable(model) -> tuple[int, int]:
    """(trainable parameters, all parameters)."""
    n = sum(p.numel() for p in model.parameters())
    t = sum(p.numel() for p in model.parameters() if p.requires_grad)
    return t, n


def merged(model):
    """The plain transformers model with LoRA merged in (the model itself when not LoRA)."""
    if hasattr(model, "merge_and_unload"):
        return model.merge_and_unload()
    return model
