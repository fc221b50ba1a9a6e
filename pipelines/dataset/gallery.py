"""`OUT/gallery/`: a contact sheet PNG and a static HTML page of sample steps (no server, no JS)."""

from __future__ import annotations

import html
import io
from pathlib import Path

import pyarrow.parquet as pq
from PIL import Image

from factory.atomic import write_atomic
from factory.dataset.tasks import SPLITS
from pipelines.dataset.png import png_bytes

MAX_SAMPLES = 12
SHOWN = ("before", "after", "isometric", "part", "axes", "catalog")
COLUMNS = ["object_id", "step_id", "step_index", "num_steps", "split", "step_kind", "assembly",
           "selection_messages", "selection_answer", "pose_messages", "pose_answer", *SHOWN]


def sample_rows(config, out, limit: int = MAX_SAMPLES) -> list[dict]:
    """The middle step of the first objects, in shard order, train and test alike (deterministic)."""
    rows = []
    for shard in range(config.num_shards):
        for split in SPLITS:
            pf = pq.ParquetFile(Path(out) / config.shard_file(split, shard))
            for g in range(pf.num_row_groups):
                t = pf.read_row_group(g, columns=COLUMNS)
                rows.append(t.slice(t.num_rows // 2, 1).to_pylist()[0])
                if len(rows) >= limit:
                    return sorted(rows, key=lambda r: r["step_id"])
    return sorted(rows, key=lambda r: r["step_id"])


def _user_text(messages) -> str:
    for m in messages:
        if m["role"] == "user":
            return "\n".join(c["text"] for c in m["content"] if c["type"] == "text")
    return ""


def contact_sheet(rows, width: int = 320) -> Image.Image:
    from factory.render import compose  # lazy: factory.render sets up GL at import

    tiles = []
    for r in rows:
        img = Image.open(io.BytesIO(r["after"]["bytes"])).convert("RGB")
        img = img.resize((width, max(1, round(img.height * width / img.width))), Image.LANCZOS)
        tiles.append(compose.labelled(img, f"{r['object_id']} step {r['step_index'] + 1}/{r['num_steps']}"))
    if not tiles:
        return Image.new("RGB", (width, width), (255, 255, 255))
    h = max(t.height for t in tiles)
    padded = []
    for t in tiles:
        canvas = Image.new("RGB", (t.width, h), (255, 255, 255))
        canvas.paste(t, (0, 0))
        padded.append(canvas)
    return compose.grid(padded, cols=min(4, len(padded)))


def write_gallery(config, out, info: dict) -> None:
    out = Path(out)
    gal = out / "gallery"
    rows = sample_rows(config, out)
    write_atomic(gal / "contact_sheet.png", png_bytes(contact_sheet(rows), 6))
    e = html.escape
    parts = [
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(config.dataset_id)}: sample steps</title>",
        "<style>body{font-family:sans-serif;margin:1em 2em}img{max-width:100%;border:1px solid #ccc}"
        "td{vertical-align:top;padding:4px}pre{background:#f4f4f4;padding:6px;white-space:pre-wrap;"
        "font-size:12px}h2{border-top:2px solid #888;padding-top:8px}</style></head><body>",
        f"<h1>{e(config.dataset_id)}</h1>",
        f"<p>{info['total']['objects']} objects, {info['total']['steps']} steps "
        f"(train {info['counts']['train']['steps']}, test {info['counts']['test']['steps']}); "
        f"source {e(config.source)}, seed {config.seed}, config {e(info['config_hash'])}. "
        'Overview: <a href="contact_sheet.png">contact sheet</a>.</p>',
    ]
    for r in rows:
        stem = f"{r['object_id']}-{r['step_index']:03d}"
        parts.append(f"<h2>{e(r['step_id'])} &middot; step {r['step_index'] + 1} of {r['num_steps']} &middot; "
                     f"{e(r['split'])} &middot; {e(r['step_kind'])} step of {e(r['assembly'])}</h2>")
        parts.append("<table><tr>")
        for name in SHOWN:
            file = f"img/{stem}-{name}.png"
            write_atomic(gal / file, r[name]["bytes"])
            parts.append(f'<td><div>{name}</div><a href="{e(file)}"><img src="{e(file)}" alt="{name}" '
                         'width="360"></a></td>')
            if name == "isometric":
                parts.append("</tr><tr>")
        parts.append("</tr></table>")
        parts.append("<table><tr><td><b>Brick selection</b><pre>" + e(_user_text(r["selection_messages"]))
                     + "</pre><b>Answer</b><pre>" + e(r["selection_answer"]) + "</pre></td>")
        parts.append("<td><b>Pose estimation</b><pre>" + e(_user_text(r["pose_messages"]))
                     + "</pre><b>Answer</b><pre>" + e(r["pose_answer"]) + "</pre></td></tr></table>")
    parts.append("</body></html>\n")
    write_atomic(gal / "index.html", "\n".join(parts).encode())
