"""PNG encoding of the dataset's images: no row filter, libdeflate.

Why not Pillow's encoder: on one sampled 40-step object (six images a step, 256 px views), Pillow
at compress level 6 took 62 ms a step for 212 KB; this writer took 18.6 ms for 171 KB (this
repository's 2-core CPU). Renders are flat colour and edge lines, which deflate's matches catch
better raw than after Pillow's adaptive row filters. libdeflate gives the same bytes for the same
pixels and level on every machine (one library version, no platform-dependent match search).
"""

from __future__ import annotations

import struct
import zlib

import deflate
import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"
LEVELS = range(0, 10)
"""Compress levels accepted (zlib's range; libdeflate's own levels 0-9 of its 0-12)."""

_COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}
"""Channels -> PNG colour type: grey, grey + alpha, RGB, RGBA."""


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def png_bytes(image, level: int = 6) -> bytes:
    """`image` (a PIL image, or an H x W or H x W x C uint8 array, C in 1-4) as PNG bytes at
    compress `level` (0-9). PIL modes other than L, LA, RGB and RGBA are converted to RGB."""
    if int(level) not in LEVELS:
        raise ValueError(f"PNG compress level must be in 0..9, got {level}")
    if not isinstance(image, np.ndarray):
        if image.mode not in ("L", "LA", "RGB", "RGBA"):
            image = image.convert("RGB")
        image = np.asarray(image)
    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise ValueError(f"PNG pixels must be uint8, got {a.dtype}")
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in _COLOUR_TYPE or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"PNG image must be H x W or H x W x C with C in 1..4, got shape {a.shape}")
    h, w, c = a.shape
    rows = np.zeros((h, w * c + 1), np.uint8)  # each row: filter byte 0 (none), then its pixels
    rows[:, 1:] = a.reshape(h, w * c)
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPE[c], 0, 0, 0)
    data = deflate.zlib_compress(rows.tobytes(), int(level))
    return SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")
