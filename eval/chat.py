"""A row's task as a chat for a vision-language model: clean messages plus the PIL images in order.

The one conversion from our Parquet rows (TRL vision `messages` with null-padded content parts) to
what `processor.apply_chat_template` takes; the predictor (prompt only) and the trainer (prompt and
answer) both use it, so a model is evaluated on exactly the prompts it was trained on.
"""

from __future__ import annotations

import io

from PIL import Image

from factory.dataset.tasks import check_task, image_columns


def clean_messages(messages) -> list[dict]:
    """Content parts without their null keys: {"type": "image"} and {"type": "text", "text": ...}."""
    out = []
    for m in messages:
        parts = []
        for p in m["content"]:
            if p["type"] == "image":
                parts.append({"type": "image"})
            else:
                parts.append({"type": "text", "text": p["text"] or ""})
        out.append({"role": m["role"], "content": parts})
    return out


def decode_image(value) -> Image.Image:
    """An `Image` feature value ({"bytes", "path"}), PNG bytes or a PIL image, as an RGB image."""
    if isinstance(value, Image.Image):
        return value.convert("RGB")
    data = value["bytes"] if isinstance(value, dict) else value
    with Image.open(io.BytesIO(data)) as im:
        return im.convert("RGB")


def columns_for(task: str) -> list[str]:
    """The Parquet columns `task_chat` reads for `task`."""
    return ["step_id", f"{task}_messages", f"{task}_images", f"{task}_answer", *image_columns(task)]


def task_chat(row: dict, task: str, with_answer: bool = False) -> tuple[list[dict], list[Image.Image], str]:
    """(messages, images, answer) of `task` in `row`; the assistant turn is kept only when
    `with_answer` (training), so a predictor's prompt ends where the model must answer."""
    check_task(task)
    messages = clean_messages(row[f"{task}_messages"])
    if not with_answer and messages and messages[-1]["role"] == "assistant":
        messages = messages[:-1]
    images = [decode_image(row[col]) for col in row[f"{task}_images"]]
    return messages, images, row[f"{task}_answer"]
