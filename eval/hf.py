"""A Hugging Face vision-language model as a predictor: chat messages and images in, answer text out.

`HFPredictor.from_path` loads a local checkpoint folder (no hub access is assumed): a full model
(`AutoModelForImageTextToText` + `AutoProcessor`), or a PEFT LoRA adapter folder (one with
`adapter_config.json`), whose base model is loaded from the adapter config's
`base_model_name_or_path` and the adapter applied on top. `HFPredictor(model, processor)` wraps a
model already in memory (the trainer's evaluation during training).

Decoding is greedy (no sampling, one beam), so the same model gives the same text for the same
prompt: evaluation files are reproducible. Only the new tokens are decoded, special tokens skipped.
torch and transformers are imported inside the functions that need them (optional heavy
dependencies, the `train` extra), so the baselines run without them. The processor is loaded through
`eval.processor.load_processor`, which also loads Qwen2-VL processors without torchvision.
"""

from __future__ import annotations

import json
from pathlib import Path

from eval.processor import load_processor, pad_token_id


class CheckpointError(ValueError):
    """A path that is not a loadable checkpoint folder."""


def _torch_dtype(dtype, device: str):
    import torch  # optional: the [train] extra (module docstring)

    if dtype is None:
        return torch.bfloat16 if device.startswith("cuda") else torch.float32
    if isinstance(dtype, str):
        value = getattr(torch, dtype, None)
        if not isinstance(value, torch.dtype):
            raise CheckpointError(f"unknown dtype {dtype!r} (e.g. bfloat16, float16, float32)")
        return value
    return dtype


def _has_processor(path: Path) -> bool:
    return any((path / name).is_file() for name in
               ("processor_config.json", "preprocessor_config.json", "tokenizer_config.json"))


class HFPredictor:
    """Greedy answers of an image-text-to-text model; `predict` for one chat, `predict_batch` for several."""

    def __init__(self, model, processor):
        self.model = model
        self.processor = processor

    @classmethod
    def from_path(cls, path, device: str | None = None, dtype=None) -> HFPredictor:
        """Load a checkpoint folder (full model or LoRA adapter, see the module docstring).

        `device`: default cuda when available, else cpu. `dtype`: a torch dtype or its name;
        default bfloat16 on cuda, float32 on cpu.
        """
        import torch  # optional: the [train] extra (module docstring)
        from transformers import AutoModelForImageTextToText

        path = Path(path)
        if not path.is_dir():
            raise CheckpointError(f"{path}: no such checkpoint folder")
        device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        dtype = _torch_dtype(dtype, device)
        adapter = path / "adapter_config.json"
        if adapter.is_file():
            from peft import PeftModel  # optional: the [train] extra

            base = json.loads(adapter.read_text()).get("base_model_name_or_path")
            if not base:
                raise CheckpointError(f"{adapter}: no base_model_name_or_path to load the base model from")
            model = AutoModelForImageTextToText.from_pretrained(base, dtype=dtype)
            model = PeftModel.from_pretrained(model, str(path))
            processor = load_processor(path if _has_processor(path) else base)
        else:
            if not (path / "config.json").is_file():
                raise CheckpointError(f"{path}: neither a model (config.json) nor an adapter (adapter_config.json)")
            model = AutoModelForImageTextToText.from_pretrained(str(path), dtype=dtype)
            processor = load_processor(path)
        model.to(device)
        model.eval()
        return cls(model, processor)

    @property
    def _tokenizer(self):
        return getattr(self.processor, "tokenizer", self.processor)

    def _generate(self, texts: list[str], images: list, max_new_tokens: int) -> list[str]:
        import torch  # optional: the [train] extra (module docstring)

        tok = self._tokenizer
        side = getattr(tok, "padding_side", "right")
        tok.padding_side = "left"  # new tokens must follow every prompt directly
        try:
            # the chat template rendered the special tokens (Gemma's <bos> too): none added again
            inputs = self.processor(text=texts, images=images or None, padding=True, return_tensors="pt",
                                    add_special_tokens=False)
        finally:
            tok.padding_side = side
        device = getattr(self.model, "device", None) or next(self.model.parameters()).device
        inputs = inputs.to(device)
        pad = pad_token_id(tok)
        with torch.inference_mode():
            out = self.model.generate(**inputs, max_new_tokens=int(max_new_tokens), do_sample=False, num_beams=1,
                                      pad_token_id=pad)
        new = out[:, inputs["input_ids"].shape[1]:]
        return self.processor.batch_decode(new, skip_special_tokens=True)

    def _prompt(self, messages) -> str:
        return self.processor.apply_chat_template(messages, add_generation_prompt=True, tokenize=False)

    def predict(self, messages: list[dict], images: list, max_new_tokens: int = 256) -> str:
        """The model's answer to one chat (`eval.chat.task_chat` or `eval.feedback` messages)."""
        return self._generate([self._prompt(messages)], list(images), max_new_tokens)[0]

    def predict_batch(self, chats, max_new_tokens: int = 256) -> list[str]:
        """Answers to several (messages, images) chats in one padded batch (left padding).

        Greedy on a padded batch can differ from one-by-one decoding in the last bits of the
        logits; use `predict` where results must match single-prompt runs exactly.
        """
        chats = list(chats)
        if not chats:
            return []
        texts = [self._prompt(m) for m, _ in chats]
        images = [im for _, ims in chats for im in ims]
        return self._generate(texts, images, max_new_tokens)
