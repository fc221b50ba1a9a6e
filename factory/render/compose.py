"""Composites with PIL: labelled tiles, grids, dashed boxes, tick-labelled axis views, arrows.

Only PIL's built-in font is used (`ImageFont.load_default(size)`), so the same input gives the
same pixels on any machine with the same Pillow.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

WHITE = (255, 255, 255)
INK = (20, 20, 20)
RED = (255, 0, 0)
AXIS_RGB = {"X": (220, 30, 30), "Y": (20, 150, 40), "Z": (30, 70, 220)}
LIGHT_BG = (240, 243, 247)
GRID = (214, 220, 228)


@lru_cache(maxsize=32)
def font(size: int) -> ImageFont.ImageFont:
    return ImageFont.load_default(size=max(8, int(size)))


def font_size(tile: int) -> int:
    return int(np.clip(round(tile / 16), 10, 28))


@lru_cache(maxsize=4096)
def text_width(text: str, size: int) -> int:
    box = font(size).getbbox(text)
    return int(box[2] - box[0])


@lru_cache(maxsize=4096)
def _glyphs(text: str, size: int):
    """The coverage mask of `text` at `size` and its offset from the anchor, as `ImageDraw.text`
    computes it for a whole-pixel position. A step draws about 100 labels, mostly the same tick
    values and titles, and rasterising them was 13% of a step's render time on a GPU machine."""
    return font(size).getmask2(text, "L", start=(0.0, 0.0))


def text(d: ImageDraw.ImageDraw, xy: tuple[int, int], s: str, size: int, fill=INK) -> None:
    """`d.text(xy, s, fill, font(size))` for a single line at a whole-pixel position, with the
    glyph mask kept (`_glyphs`): the same blend of the same mask, so the same pixels."""
    mask, (ox, oy) = _glyphs(s, size)
    ink, _ = d._getink(fill)
    d.draw.draw_bitmap((int(xy[0]) + ox, int(xy[1]) + oy), mask, ink)


def label_strip_height(tile: int) -> int:
    return font_size(tile) + 8


def labelled(img: Image.Image, label: str, bg=WHITE) -> Image.Image:
    """`img` with a strip above it holding `label`, centred."""
    fs = font_size(img.width)
    h = label_strip_height(img.width)
    out = Image.new("RGB", (img.width, img.height + h), bg)
    out.paste(img, (0, h))
    d = ImageDraw.Draw(out)
    text(d, ((img.width - text_width(label, fs)) // 2, 3), label, fs)
    return out


def grid(tiles: Sequence[Image.Image], cols: int, gap: int = 2, bg=(200, 200, 200)) -> Image.Image:
    """Tiles (all the same size) in rows of `cols`, left to right, top to bottom."""
    w, h = tiles[0].size
    rows = -(-len(tiles) // cols)
    out = Image.new("RGB", (cols * w + (cols - 1) * gap, rows * h + (rows - 1) * gap), bg)
    for i, t in enumerate(tiles):
        r, c = divmod(i, cols)
        out.paste(t, (c * (w + gap), r * (h + gap)))
    return out


def dashed_rect(img: Image.Image, box: tuple[int, int, int, int], colour=RED, width: int | None = None,
                dash: int | None = None) -> None:
    """Draw a dashed rectangle: box = (x0, y0, x1, y1), inclusive pixel coordinates."""
    d = ImageDraw.Draw(img)
    size = max(img.width, img.height)
    width = width or max(2, size // 128)
    dash = dash or max(4, size // 40)
    gap = max(3, dash * 2 // 3)
    x0, y0, x1, y1 = box

    def run(a0: int, a1: int, fixed: int, horizontal: bool) -> None:
        p = a0
        while p <= a1:
            q = min(p + dash - 1, a1)
            if horizontal:
                d.rectangle([p, fixed, q, fixed + width - 1], fill=colour)
            else:
                d.rectangle([fixed, p, fixed + width - 1, q], fill=colour)
            p += dash + gap

    run(x0, x1, y0, True)
    run(x0, x1, y1 - width + 1, True)
    run(y0, y1, x0, False)
    run(y0, y1, x1 - width + 1, False)


def colour_mask(arr: np.ndarray, rgb) -> np.ndarray:
    """(H, W) bool: the pixels of an (H, W, 3) image that are exactly `rgb` (channel by channel:
    ten times faster than `(arr == rgb).all(-1)` at 256 px)."""
    return (arr[..., 0] == rgb[0]) & (arr[..., 1] == rgb[1]) & (arr[..., 2] == rgb[2])


def fill(arr: np.ndarray, mask: np.ndarray, rgb) -> None:
    """Set the `mask` pixels of an (H, W, 3) uint8 image to `rgb`, in place."""
    for k in range(3):  # a boolean assignment per channel: 5x faster than copyto(where=)
        arr[..., k][mask] = rgb[k]


def box_from_mask(mask: np.ndarray, pad: int) -> tuple[int, int, int, int] | None:
    """Inclusive pixel box around the True pixels of `mask`, padded and clamped; None if empty."""
    rows = np.flatnonzero(mask.any(axis=1))  # the occupied rows and columns: 7x faster than
    if len(rows) == 0:                        # listing every True pixel (np.nonzero) at 256 px
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    return (max(0, int(cols[0]) - pad), max(0, int(rows[0]) - pad),
            min(w - 1, int(cols[-1]) + pad), min(h - 1, int(rows[-1]) + pad))


def arrow(d: ImageDraw.ImageDraw, p0, p1, colour, width: int) -> None:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d.line([tuple(p0), tuple(p1)], fill=colour, width=width)
    v = p1 - p0
    n = np.linalg.norm(v)
    if n < 1e-6:
        return
    v /= n
    perp = np.array([-v[1], v[0]])
    head = max(6.0, 3.5 * width)
    a = p1 - v * head + perp * head * 0.45
    b = p1 - v * head - perp * head * 0.45
    d.polygon([tuple(p1), tuple(a), tuple(b)], fill=colour)


def tick_tile(img: Image.Image | np.ndarray, title: str, ticks: dict[str, list[tuple[float, float]]],
              axis_names: tuple[str, str] | None, margin_left: int, margin_bottom: int,
              bg_mask: np.ndarray | None = None, bg=LIGHT_BG) -> Image.Image:
    """An axis view (an image, or its (H, W, 3) uint8 pixels, left as they are) with faint grid
    lines on its background, tick marks and LDU labels.

    The render sits at (margin_left, strip) in the tile; `ticks` are in the render's pixels.
    """
    arr = np.array(img, dtype=np.uint8)  # a copy: the grid lines and background are drawn on it
    size = arr.shape[1]
    fs = max(9, font_size(size) - 2)
    strip = label_strip_height(size)
    if bg_mask is not None:
        fill(arr, bg_mask, bg)
        for _v, x in ticks.get("h", []):
            xi = min(size - 1, int(np.floor(x)))
            col = bg_mask[:, xi]
            arr[col, xi] = GRID
        for _v, y in ticks.get("v", []):
            yi = min(size - 1, int(np.floor(y)))
            row = bg_mask[yi, :]
            arr[yi, row] = GRID
    out = Image.new("RGB", (size + margin_left, size + strip + margin_bottom), bg)
    out.paste(Image.fromarray(arr), (margin_left, strip))
    d = ImageDraw.Draw(out)
    text(d, (margin_left + (size - text_width(title, fs + 2)) // 2, 3), title, fs + 2)
    tick_len = max(4, size // 48)
    y_axis = strip + size
    d.line([(margin_left, y_axis), (margin_left + size, y_axis)], fill=INK, width=1)
    d.line([(margin_left - 1, strip), (margin_left - 1, strip + size)], fill=INK, width=1)
    for v, x in ticks.get("h", []):
        xi = margin_left + min(size - 1, int(np.floor(x)))
        d.line([(xi, y_axis), (xi, y_axis + tick_len)], fill=INK, width=1)
        s = _fmt(v)
        x_text = xi - text_width(s, fs) // 2
        if x_text + text_width(s, fs) <= out.width - 1:  # a label that would spill over is left out
            text(d, (x_text, y_axis + tick_len + 1), s, fs)
    for v, y in ticks.get("v", []):
        yi = strip + min(size - 1, int(np.floor(y)))
        d.line([(margin_left - 1 - tick_len, yi), (margin_left - 1, yi)], fill=INK, width=1)
        s = _fmt(v)
        if yi - fs // 2 - 1 >= strip - 2:
            text(d, (margin_left - tick_len - 3 - text_width(s, fs), yi - fs // 2 - 1), s, fs)
    if axis_names is None:
        return out
    h_name, v_name = axis_names
    cap = f"{h_name} (LDU)"
    text(d, (margin_left + size - text_width(cap, fs), y_axis + tick_len + fs + 3), cap, fs)
    text(d, (2, strip - fs - 2 if strip > fs + 2 else 2), f"{v_name} (LDU)", fs)
    return out


def _fmt(v: float) -> str:
    r = round(v, 3)
    return str(int(r)) if r == int(r) else f"{r:g}"


def text_tile(lines: Sequence[str], size: tuple[int, int], bg=LIGHT_BG, fs: int = 12) -> Image.Image:
    out = Image.new("RGB", size, bg)
    d = ImageDraw.Draw(out)
    y = 8
    for line in lines:
        text(d, (8, y), line, fs)
        y += fs + 5
    return out
