"""A checkpoint's processor, loaded and saved with or without torchvision.

In transformers 5.x a Qwen2-VL processor always carries a video processor, and that needs
torchvision: on a machine without it (our CPU machines: torchvision's PyPI wheels are CUDA builds
that do not load on the CPU build of torch) `AutoProcessor.from_pretrained` raises ImportError for
every Qwen2-VL checkpoint, although we never process video. `load_processor` then builds the same
processor without its video part (`ImageOnlyQwen2VLProcessor`: identical text and image handling,
images through the PIL backend of `Qwen2VLImageProcessor`). Where torchvision is installed (the GPU
machines) it is plain `AutoProcessor.from_pretrained`.

`save_processor` writes the layout of the Qwen2-VL hub repositories (tokenizer files,
`chat_template.jinja`, `preprocessor_config.json` naming `Qwen2VLProcessor`) for the image-only
processor, so a folder saved on either kind of machine loads on both.
"""

from __future__ import annotations

import json
from pathlib import Path

PROCESSOR_CLASS = "Qwen2VLProcessor"


def _image_only_class():
    from transformers import Qwen2VLProcessor

    class ImageOnlyQwen2VLProcessor(Qwen2VLProcessor):
        """`Qwen2VLProcessor` less the video processor (which needs torchvision)."""

        def __init__(self, image_processor=None, tokenizer=None, chat_template=None, **kwargs):
            # Qwen2VLProcessor.__init__ passes (image, tokenizer, video) on to ProcessorMixin, which
            # pairs them with this signature's attributes (image, tokenizer): the video slot is dropped.
            super().__init__(image_processor, tokenizer, None, chat_template=chat_template, **kwargs)

    return ImageOnlyQwen2VLProcessor


def image_only_processor(image_processor, tokenizer, chat_template: str | None = None):
    """A Qwen2-VL processor from its parts, without a video processor."""
    return _image_only_class()(image_processor=image_processor, tokenizer=tokenizer,
                               chat_template=chat_template or tokenizer.chat_template)


def make_qwen2vl_processor(image_processor, tokenizer, chat_template: str):
    """`Qwen2VLProcessor(image_processor, tokenizer)` where torchvision is there, else the image-only one."""
    try:
        import torchvision  # noqa: F401  (the video processor needs it)
        from transformers import Qwen2VLProcessor, Qwen2VLVideoProcessor
    except ImportError:
        return image_only_processor(image_processor, tokenizer, chat_template)
    return Qwen2VLProcessor(image_processor=image_processor, tokenizer=tokenizer,
                            video_processor=Qwen2VLVideoProcessor(), chat_template=chat_template)


def _declared_class(path: Path) -> str | None:
    for name in ("processor_config.json", "preprocessor_config.json", "tokenizer_config.json"):
        f = path / name
        if f.is_file():
            cls = json.loads(f.read_text()).get("processor_class")
            if cls:
                return cls
    return None


def load_processor(path, max_pixels: int | None = None):
    """The processor of a checkpoint folder (see the module docstring); `max_pixels` caps each
    image's pixels (and so its image tokens) when given."""
    from transformers import AutoProcessor

    path = Path(path)
    try:
        processor = AutoProcessor.from_pretrained(str(path))
    except ImportError as exc:
        if "torchvision" not in str(exc).lower() or _declared_class(path) != PROCESSOR_CLASS:
            raise
        from transformers import AutoImageProcessor, AutoTokenizer

        tokenizer = AutoTokenizer.from_pretrained(str(path))
        template = path / "chat_template.jinja"
        chat = template.read_text() if template.is_file() else None
        processor = image_only_processor(AutoImageProcessor.from_pretrained(str(path)), tokenizer, chat)
    if max_pixels:
        set_max_pixels(processor, int(max_pixels))
    return processor


def set_max_pixels(processor, max_pixels: int) -> None:
    """Cap the pixels of each image (Qwen2-VL image processors: `size["longest_edge"]`, a dict or
    a `SizeDict` dataclass depending on the transformers version)."""
    import dataclasses

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
    if type(processor).__name__ != "ImageOnlyQwen2VLProcessor":
        processor.save_pretrained(str(path))
        return
    tok = processor.tokenizer
    if processor.chat_template and not tok.chat_template:
        tok.chat_template = processor.chat_template
    tok.save_pretrained(str(path))
    processor.image_processor.save_pretrained(str(path))
    for name, key in (("preprocessor_config.json", "image_processor_type"), ("tokenizer_config.json", None)):
        f = path / name
        cfg = json.loads(f.read_text())
        cfg["processor_class"] = PROCESSOR_CLASS
        if key:
            cfg[key] = "Qwen2VLImageProcessor"
        f.write_text(json.dumps(cfg, indent=2, sort_keys=True) + "\n")
    if processor.chat_template and not (path / "chat_template.jinja").is_file():
        (path / "chat_template.jinja").write_text(processor.chat_template)
