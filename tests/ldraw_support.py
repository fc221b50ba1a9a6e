"""Where the real LDraw data lies and how tests reach it or build their own: the data location
constants (`SHARED`, `LDRAW`, `MODELS`, `LIBRARY_ZIP`, `DESIGNS`; `$BRICK_FACTORY_SHARED`, else
`../shared` beside the checkout) and the `needs_ldraw` marker (its skip is `conftest`'s collection
hook); embedded parts placed by hand (`part`, `at`); the readers of the real and embedded libraries
(`real_reader`, `embedded_reader`), file builders (`write`, `mini_library` with its closed cube
`BOX`), and `isolated_cache`, which keeps collision decompositions in the session's temporary
folder. `conftest` imports the fixtures so that every test finds them by name."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from factory.ldraw import Library, Reader

SHARED = Path(os.environ.get("BRICK_FACTORY_SHARED") or Path(__file__).resolve().parents[2] / "shared")
"""The real LDraw data the tests read (`ldraw/`, `ldraw_models/`, `designs/`, `ldraw_library.zip`):
`$BRICK_FACTORY_SHARED`, else `../shared` beside the checkout."""
LDRAW = SHARED / "ldraw"
MODELS = SHARED / "ldraw_models"
LIBRARY_ZIP = SHARED / "ldraw_library.zip"
DESIGNS = SHARED / "designs"

needs_ldraw = pytest.mark.needs_ldraw
"""Marks a test that reads the real LDraw data: skipped, with the reason, where it is absent
(`pytest -m needs_ldraw` selects them, `-m "not needs_ldraw"` leaves them out)."""


@pytest.fixture
def isolated_cache(tmp_path_factory, monkeypatch):
    """Collision decompositions cached in the test session's temporary folder, not the user's."""
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def part(name: str):
    """A part of the embedded library."""
    from factory import get_reader, load_part

    return load_part(get_reader(), name)


def at(name: str, x: float, y: float, z: float, R=None, colour: int = 4):
    """An embedded part placed at (x, y, z) LDU, turned by R (identity by default)."""
    import numpy as np

    from factory import Pose
    from factory.physics.structure import Placed

    return Placed(part(name), colour, Pose(np.eye(3) if R is None else R, [x, y, z]))


@pytest.fixture(scope="session")
def real_reader() -> Reader:
    if not (LDRAW / "parts").is_dir():
        pytest.skip(f"the real LDraw subset is not at {LDRAW}")
    return Reader(Library.from_dir(LDRAW))


@pytest.fixture(scope="session")
def embedded_reader() -> Reader:
    return Reader(Library.embedded())


@pytest.fixture
def write(tmp_path):
    """Write a file under tmp_path (text as given, or bytes) and return its path."""

    def _write(name: str, content: str | bytes) -> Path:
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content, newline="")
        return path

    return _write


@pytest.fixture
def mini_library(tmp_path) -> Path:
    """A tiny LDraw library on disk: a closed unit cube primitive and a 'brick' using it."""
    root = tmp_path / "lib"
    (root / "parts" / "s").mkdir(parents=True)
    (root / "p" / "48").mkdir(parents=True)
    (root / "p" / "box.dat").write_text(BOX)
    (root / "parts" / "Cube.dat").write_text(
        "0 Test Cube\n0 Name: cube.dat\n0 !LDRAW_ORG Part\n0 BFC CERTIFY CCW\n"
        "1 16 0 0 0 10 0 0 0 10 0 0 0 10 box.dat\n"
    )
    (root / "parts" / "s" / "cubes01.dat").write_text("0 Subpart\n0 BFC CERTIFY CCW\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n")
    (root / "LDConfig.ldr").write_text(
        "0 !COLOUR Black CODE 0 VALUE #1B2A34 EDGE #808080\n"
        "0 !COLOUR Red CODE 4 VALUE #B40000 EDGE #333333\n"
        "0 !COLOUR Trans_Clear CODE 47 VALUE #FCFCFC EDGE #C9C9C9 ALPHA 128\n"
    )
    return root


def _box_text() -> str:
    """A closed cube [-1, 1]^3 wound counter-clockwise seen from outside (LDraw axes)."""
    # Faces as (normal axis, sign); corners ordered so that (b - a) x (c - a) points outward in a
    # right-handed x, y, z frame.
    lines = ["0 Box", "0 BFC CERTIFY CCW"]
    faces = [
        [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)],
        [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
        [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)],
        [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
        [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)],
        [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)],
    ]
    for f in faces:
        lines.append("4 16 " + " ".join(f"{c}" for p in f for c in p))
    return "\n".join(lines) + "\n"


BOX = _box_text()
