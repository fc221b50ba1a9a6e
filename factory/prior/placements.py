"""The parts a design places, with their colours: every type 1 line of its main model, submodels
expanded (a submodel placed twice counts twice), without judging the placement matrices.

Usage is counted here, not in `factory.ldraw.build_steps`, which refuses a mirrored placement (a
design's left wing placed as the mirror image of its right one): a mirrored part is still a use of
that part.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from factory.errors import LDrawLimitError
from factory.ldraw import Reader
from factory.ldraw.colours import MAIN
from factory.ldraw.model import MAX_MODEL_PARTS, is_submodel
from factory.ldraw.reader import Resolved


@dataclass(frozen=True)
class Use:
    """One part placed by a design."""

    part: str
    """The file name as the design references it, lower case, without `.dat`."""
    colour: int
    """The colour it is placed with (16 resolved through the submodels that place it; 16 where
    the main model leaves it to the viewer)."""
    resolved: Resolved | None
    """The file the name resolved to (None where no library or model holds it)."""
    up: float = 1.0
    """How the part's up (-y) lies in the design's frame: the cosine between them (1 upright,
    -1 upside down, near 0 on its side), through every submodel that places it; a mirrored or
    scaled placement counts by its direction."""
    matrix: np.ndarray | None = field(default=None, compare=False, repr=False)
    """Its rotation in the design's frame (through every submodel), None where not known."""
    pos: np.ndarray | None = field(default=None, compare=False, repr=False)
    """Its position in the design's frame (LDU)."""


@dataclass(frozen=True)
class Design:
    """What one design file places."""

    path: str
    licence: str
    """Its `0 !LICENSE` line's text ('' when it has none)."""
    uses: tuple[Use, ...]
    missing: tuple[str, ...]
    """Names no library or model block holds (counted in `uses` with `resolved` None)."""
    primitives: int = 0
    """Placements of library primitives (`p/`: a cylinder or a disc placed as if a part), left
    out of `uses`: no one builds with them."""


def read_design(reader: Reader, path: str | os.PathLike) -> Design:
    """Every part the design places (LDraw errors other than a missing part propagate, naming the
    file and line)."""
    model = reader.open_model(path)
    main = Resolved(model.main, f"{model.path}#{model.main.name.lower()}", "mpd", model)
    uses: list[Use] = []
    missing: set[str] = set()
    primitives = [0]
    _walk(reader, main, MAIN, np.eye(3), np.zeros(3), uses, missing, primitives, ())
    licence = _licence(path)
    return Design(str(path), licence, tuple(uses), tuple(sorted(missing)), primitives[0])


def _is_primitive(reader: Reader, res: Resolved, name: str) -> bool:
    """A library file found outside `parts/` (in `p/`, LDraw's primitives)."""
    return res.origin == "library" and reader.library.source.lookup("parts/" + name) is None \
        and reader.library.source.lookup("parts/s/" + name) is None


def _walk(reader: Reader, res: Resolved, colour: int, matrix: np.ndarray, offset: np.ndarray, out: list[Use],
          missing: set[str], primitives: list, stack: tuple) -> None:
    reader._check_stack(res, stack)
    for ref in res.file.refs:
        c = colour if ref.colour == MAIN else ref.colour
        m = matrix @ np.asarray(ref.matrix, dtype=np.float64)
        at = offset + matrix @ np.asarray(ref.pos, dtype=np.float64)
        name = ref.name.replace("\\", "/").lower()
        child = reader.find(ref, res.file, res.model)  # None: counted by name
        if child is not None and is_submodel(child):
            _walk(reader, child, c, m, at, out, missing, primitives, stack + (res.key,))
            continue
        if child is not None and _is_primitive(reader, child, name):
            primitives[0] += 1
            continue
        if child is None:
            missing.add(name[:-4] if name.endswith(".dat") else name)
        up = m[:, 1]  # the part's y axis in the design's frame; up is -y on both sides
        norm = float(np.linalg.norm(up))
        out.append(Use(name[:-4] if name.endswith(".dat") else name, c, child,
                       float(up[1] / norm) if norm > 0 and np.isfinite(norm) else 0.0, m, at))
        if len(out) > MAX_MODEL_PARTS:
            raise LDrawLimitError(f"design places more than {MAX_MODEL_PARTS:,} parts; refusing it", res.file.path,
                                  ref.line)


def _licence(path) -> str:
    """The text after the file's first `0 !LICENSE` (the file was read and size-checked already)."""
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("utf-8", errors="replace").strip()
            if line.startswith("0 !LICENSE"):
                return line[len("0 !LICENSE"):].strip()
    return ""
