"""A checkpoint's processor, loaded and saved with or without torchvision.

In transformers 5.x the processors of Qwen2-VL, Qwen2.5-VL, Qwen3-VL and InternVL always carry a
video processor, and that needs torchvision: on a machine without it (our CPU machines: PyPI's
torchvision 0.28.0, the release made for torch 2.13.0, installs beside the CPU build of torch but
fails to import, "operator torchvision::nms does not exist") `AutoProcessor.from_pretrained`
fails for every such checkpoint (ImportError, or a ValueError naming torchvision), although we
never process video. `load_processor`
then builds the same processor class without its video part (`image_only_class`: identical text
and image handling; the image processor falls back to its PIL backend). Where torchvision is
installed (the GPU machines) it is plain `AutoProcessor.from_pretrained`. Processors without a
video part (Gemma 3) load the plain way everywhere.

`save_processor` is the processor's own `save_pretrained` plus the image processor's
`preprocessor_config.json`, as the hub repositories have it (the image-only class is named like
its full class, so the folder declares the real `processor_class`). A folder saved without
torchvision has no video processor config; `load_processor` loads it image-only on either kind
of machine.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path


def image_only_class(base):
    """A subclass of the processor class `base` without the video processor (see the module docstring)."""
    full = inspect.signature(base.__init__)
    sig = full.replace(parameters=[p for n, p in full.parameters.items() if n != "video_processor"])

    # Named parameters, not *args: ProcessorMixin.from_pretrained passes the saved settings that
    # `__init__`'s code names (image_seq_length is InternVL's; the other families have none).
    def __init__(self, image_processor=None, tokenizer=None, chat_template=None, image_seq_length=None, **kwargs):
        kwargs.pop("video_processor", None)  # a saved full processor's config may name its own
        if image_seq_length is not None:
            kwargs["image_seq_length"] = image_seq_length
        # `base.__init__` hands (image, tokenizer, video) on to ProcessorMixin, which pairs them with
        # this class's attributes (image, tokenizer): the video slot is dropped.
        base.__init__(self, image_processor, tokenizer, None, chat_template=chat_template, **kwargs)

    # ProcessorMixin reads the attributes and the settings to save off the signature: `base`'s
    # less the video processor
    __init__.__signature__ = sig
    # named like `base`, so `save_pretrained` records the real processor class
    return type(base.__name__, (base,), {"__init__": __init__, "__module__": __name__})


def has_video_processor(cls) -> bool:
    return "video_processor" in inspect.signature(cls.__init__).parameters


def make_processor(cls, image_processor, tokenizer, chat_template: str, **kwargs):
    """`cls(image_processor, tokenizer, video_processor)` where torchvision is there, else the
    image-only `cls` (for a class without a video processor: `cls(image_processor, tokenizer)`)."""
    if has_video_processor(cls):
        try:
            import torchvision  # noqa: F401  (optional: the video processor needs it)
        except ImportError:
            cls = image_only_class(cls)
        else:
            video = _video_processor_for(cls)
            return cls(image_processor=image_processor, tokenizer=tokenizer, video_processor=video,
                       chat_template=chat_template, **kwargs)
    return cls(image_processor=image_processor, tokenizer=tokenizer, chat_template=chat_template, **kwargs)


def _video_processor_for(cls):
    """The default video processor of the processor class `cls` (only where torchvision imports)."""
    import transformers  # optional: the [train] extra

    name = {"Qwen2VLProcessor": "Qwen2VLVideoProcessor", "Qwen2_5_VLProcessor": "Qwen2VLVideoProcessor",
            "Qwen3VLProcessor": "Qwen3VLVideoProcessor", "InternVLProcessor": "InternVLVideoProcessor"}[cls.__name__]
    return getattr(transformers, name)()


def declared_class(path: Path) -> str | None:
    """The `processor_class` a model folder's processor or tokenizer config names."""
    for name in ("processor_config.json", "preprocessor_config.json", "tokenizer_config.json"):
        f = path / name
        if f.is_file():
            cls = json.loads(f.read_text()).get("processor_class")
            if cls:
                return cls
    return None


def load_processor(path, max_pixels: int | None = None):
    """The processor of a checkpoint folder (see the module docstring); `max_pixels` caps each
    image's pixels (and so its image tokens) where the image processor resizes by pixel count."""
    import transformers  # optional: the [train] extra
    from transformers import AutoProcessor

    path = Path(path)
    try:
        processor = AutoProcessor.from_pretrained(str(path))
    except (ImportError, ValueError, OSError) as exc:
        # ImportError or ValueError naming torchvision: the video processor needs it; OSError: a
        # folder saved without torchvision has no video processor config
        name = declared_class(path)
        base = getattr(transformers, name, None) if name else None
        if base is None or not has_video_processor(base):
            raise
        if not isinstance(exc, OSError) and "torchvision" not in str(exc).lower():
            raise
        if isinstance(exc, OSError) and (path / "video_preprocessor_config.json").is_file():
            raise
        processor = image_only_class(base).from_pretrained(str(path))
    if max_pixels:
        set_max_pixels(processor, int(max_pixels))
    return processor


def set_max_pixels(processor, max_pixels: int) -> None:
    """Cap the pixels of each image (Qwen-VL image processors: `size["longest_edge"]`, a dict or
    a `SizeDict` dataclass depending on the transformers version). Image processors that resize
    to a fixed size (Gemma 3, InternVL) have no such cap and are left as they are."""
    ip = processor.image_processor
    size = getattr(ip, "size", None)
    if size is not None and size.get("longest_edge") is not None:
        cap = {"longest_edge": int(max_pixels),
               "shortest_edge": min(int(size.get("shortest_edge") or max_pixels), int(max_pixels))}
        ip.size = {**size, **cap} if isinstance(size, dict) else dataclasses.replace(size, **cap)
    if getattr(ip, "max_pixels", None) is not None:
        ip.max_pixels = int(max_pixels)
        if getattr(ip, "min_pixels", None) and ip.min_pixels > max_pixels:
            ip.min_pixels = int(max_pixels)


def save_processor(processor, path) -> None:
    """Save `processor` into the folder `path` (loadable by `load_processor` and, where
    torchvision is installed, by `AutoProcessor.from_pretrained`)."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    processor.save_pretrained(str(path))
    # the image processor's own file too, as the hub repositories have it (older loaders and
    # `AutoImageProcessor` read it there)
    processor.image_processor.save_pretrained(str(path))


def pad_token_id(tokenizer) -> int | None:
    """The id that pads a batch: the tokenizer's pad token, else its end-of-sequence token."""
    return tokenizer.pad_token_id if tokenizer.pad_token_id is not None else tokenizer.eos_token_id
