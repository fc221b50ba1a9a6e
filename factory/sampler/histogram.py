"""A histogram PNG of object densities from `pipelines.sample` summaries, drawn with PIL only.

`python -m factory.sampler.histogram LABEL=DIR/summary.json ... --out docs/sampler_density.png`
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from factory.cli import ArgumentParser
from factory.atomic import write_atomic

COLOURS = [(200, 60, 50), (40, 100, 190), (60, 150, 70), (150, 90, 170)]


def draw_histogram(series: dict[str, list[float]], title: str, xlabel: str = "density",
                   bins: int = 20, size: tuple[int, int] = (900, 520)) -> Image.Image:
    """Side-by-side bars per bin for each series, with each series' median as a dashed line."""
    font = ImageFont.load_default(size=15)
    small = ImageFont.load_default(size=13)
    values = np.concatenate([np.asarray(v, float) for v in series.values()])
    lo, hi = 0.0, float(np.ceil(values.max() * 20) / 20) if len(values) else 1.0
    edges = np.linspace(lo, hi, bins + 1)
    counts = {k: np.histogram(v, bins=edges)[0] for k, v in series.items()}
    top = max(1, max(int(c.max()) for c in counts.values()))
    w, h = size
    left, right, upper, lower = 70, 20, 50, 60
    img = Image.new("RGB", size, "white")
    d = ImageDraw.Draw(img)
    d.text((left, 15), title, fill="black", font=font)
    x0, x1, y0, y1 = left, w - right, h - lower, upper
    d.line([(x0, y0), (x1, y0)], fill="black")
    d.line([(x0, y0), (x0, y1)], fill="black")

    def sx(x):
        return x0 + (x - lo) / (hi - lo) * (x1 - x0)

    def sy(c):
        return y0 - c / top * (y0 - y1)

    step = max(1, top // 6)
    for c in range(0, top + 1, step):
        d.line([(x0 - 4, sy(c)), (x0, sy(c))], fill="black")
        d.text((x0 - 30, sy(c) - 7), str(c), fill="black", font=small)
    for i, e in enumerate(edges):
        if i % 2 == 0:
            d.line([(sx(e), y0), (sx(e), y0 + 4)], fill="black")
            d.text((sx(e) - 14, y0 + 8), f"{e:.2f}", fill="black", font=small)
    d.text(((x0 + x1) / 2 - 25, h - 25), xlabel, fill="black", font=font)
    d.text((10, y1 - 30), "objects", fill="black", font=small)
    n = len(series)
    bw = (sx(edges[1]) - sx(edges[0])) / (n + 0.5)
    for k, (name, c) in enumerate(counts.items()):
        colour = COLOURS[k % len(COLOURS)]
        for i, cnt in enumerate(c):
            if cnt:
                xa = sx(edges[i]) + 0.25 * bw + k * bw
                d.rectangle([xa, sy(cnt), xa + bw - 1, y0], fill=colour)
    for k, name in enumerate(counts):  # medians over the bars, darker
        colour = COLOURS[k % len(COLOURS)]
        dark = tuple(int(v * 0.55) for v in colour)
        med = float(np.median(series[name]))
        for y in range(int(y1), int(y0), 10):
            d.line([(sx(med), y), (sx(med), y + 5)], fill=dark, width=2)
    d.rectangle([x1 - 348, upper + 2, x1, upper + 16 + 22 * len(counts)], fill="white", outline=(180, 180, 180))
    for k, name in enumerate(counts):
        colour = COLOURS[k % len(COLOURS)]
        med = float(np.median(series[name]))
        ly = upper + 10 + 22 * k
        d.rectangle([x1 - 340, ly, x1 - 326, ly + 14], fill=colour)
        d.text((x1 - 320, ly - 1), f"{name}: n={len(series[name])}, median {med:.3f} (dashed)",
               fill="black", font=small)
    return img


def main(argv=None) -> int:
    ap = ArgumentParser(prog="python -m factory.sampler.histogram")
    ap.add_argument("series", nargs="+", help="LABEL=path/to/summary.json")
    ap.add_argument("--out", required=True)
    ap.add_argument("--title", default="Object density (summed part volume / convex hull volume)")
    args = ap.parse_args(argv)
    series = {}
    for item in args.series:
        label, _, path = item.rpartition("=")
        summary = json.loads(Path(path).read_text())
        series[label] = [o["density"] for o in summary["objects"]]
    img = draw_histogram(series, args.title)
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    write_atomic(args.out, buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
