"""The dataset's PNG writer (pipelines.dataset.png): pixels come back exactly through Pillow for
every colour type, bytes depend only on pixels and level, bad input is refused."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from pipelines.dataset.png import png_bytes


def _decoded(data: bytes) -> np.ndarray:
    img = Image.open(io.BytesIO(data))
    img.load()
    assert img.format == "PNG"
    return np.asarray(img)


def _render_like(h: int, w: int, c: int, seed: int) -> np.ndarray:
    """Flat background, a few filled rectangles, and noise in one corner (worst case for deflate)."""
    rng = np.random.default_rng(seed)
    a = np.full((h, w, c), 255, np.uint8)
    for _ in range(5):
        y, x = rng.integers(0, h - 2), rng.integers(0, w - 2)
        a[y:y + rng.integers(1, h - y), x:x + rng.integers(1, w - x)] = rng.integers(0, 256, c)
    a[: h // 4, : w // 4] = rng.integers(0, 256, (h // 4, w // 4, c))
    return a


@pytest.mark.parametrize("mode,channels", [("L", 1), ("LA", 2), ("RGB", 3), ("RGBA", 4)])
@pytest.mark.parametrize("level", [0, 1, 6, 9])
def test_pixels_round_trip_through_pillow(mode, channels, level):
    a = _render_like(37, 53, channels, seed=level * 10 + channels)
    img = Image.fromarray(a[:, :, 0] if channels == 1 else a, mode)
    back = _decoded(png_bytes(img, level))
    assert back.shape == (a[:, :, 0] if channels == 1 else a).shape
    assert np.array_equal(back.reshape(a.shape), a)
    assert np.array_equal(_decoded(png_bytes(a, level)).reshape(a.shape), a)  # arrays as well


def test_same_pixels_same_bytes_and_levels_trade_size():
    a = _render_like(200, 300, 3, seed=1)
    b = a.copy()
    assert png_bytes(a, 6) == png_bytes(Image.fromarray(b), 6)
    b[100, 150, 0] ^= 1
    assert png_bytes(a, 6) != png_bytes(b, 6)
    assert len(png_bytes(a, 9)) <= len(png_bytes(a, 1)) < len(png_bytes(a, 0))


def test_palette_images_are_written_as_rgb():
    rgb = _render_like(20, 30, 3, seed=2)
    pal = Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE, colors=16)
    assert np.array_equal(_decoded(png_bytes(pal)), np.asarray(pal.convert("RGB")))


@pytest.mark.parametrize("bad,match", [
    (np.zeros((4, 4, 3), np.float32), "uint8"),
    (np.zeros((4, 4, 5), np.uint8), "C in 1..4"),
    (np.zeros((0, 4, 3), np.uint8), "shape"),
    (np.zeros((2, 2, 2, 2), np.uint8), "shape"),
])
def test_bad_pixels_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        png_bytes(bad)


def test_bad_level_is_refused():
    with pytest.raises(ValueError, match="0..9"):
        png_bytes(np.zeros((2, 2, 3), np.uint8), 10)
