"""Reading LDraw: files, libraries, flattened parts and build steps."""

from __future__ import annotations

import os
from functools import lru_cache

from factory.ldraw.colours import Colour, ColourTable
from factory.ldraw.library import Library
from factory.ldraw.model import NO_PARTS, BuildStep, PlacedPart, build_steps
from factory.ldraw.reader import Flat, Model, Reader

__all__ = [
    "NO_PARTS",
    "BuildStep",
    "Colour",
    "ColourTable",
    "Flat",
    "Library",
    "Model",
    "PlacedPart",
    "Reader",
    "build_steps",
    "get_reader",
    "read_steps",
]


@lru_cache(maxsize=8)
def _reader_for(key: str | None) -> Reader:
    return Reader(Library.resolve(key))


def get_reader(ldraw: str | os.PathLike | None = None) -> Reader:
    """The process-wide reader for `ldraw` (else `$LDRAWDIR`, else the embedded library).

    One reader per library, so every part is parsed and flattened once per process.
    """
    key = ldraw or os.environ.get("LDRAWDIR") or None
    if key is not None:
        key = os.path.realpath(os.path.expanduser(str(key)))
    return _reader_for(key)


def read_steps(model_path: str | os.PathLike, ldraw: str | os.PathLike | None = None) -> list[BuildStep]:
    """The build steps of a model file, read with the library `ldraw` (see `get_reader`)."""
    reader = get_reader(ldraw)
    return build_steps(reader, reader.open_model(model_path))
