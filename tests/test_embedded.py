"""The embedded default library, read through the project's reader, against the real library."""

from __future__ import annotations

import numpy as np
import pytest

from factory.embedded import generate_library
from factory.ldraw import ColourTable, get_reader
from factory.parts import load_part

from ldraw_support import LDRAW, LIBRARY_ZIP, needs_ldraw

EMBEDDED_PARTS = sorted(
    k.rsplit("/", 1)[-1] for k in generate_library() if k.startswith("parts/") and k.count("/") == 1
)


def test_embedded_library_has_the_fifty_nine_parts():
    assert len(EMBEDDED_PARTS) == 59
    assert {"3001.dat", "3070b.dat", "3039.dat", "3665.dat", "3958.dat", "4070.dat", "3659.dat", "3032.dat",
            "2420.dat", "4589.dat", "3941.dat", "3700.dat"} <= set(EMBEDDED_PARTS)


STUDLESS = {"3070b.dat", "3069b.dat", "63864.dat", "2431.dat", "6636.dat", "4162.dat", "3068b.dat", "2412b.dat",
            "54200.dat", "85984.dat"}
"""The tiles (the grille tile among them) and the cheese slopes."""


@pytest.mark.parametrize("name", EMBEDDED_PARTS)
def test_embedded_part_loads_with_connections(embedded_reader, name):
    part = load_part(embedded_reader, name)
    assert part.flat.certified and part.volume_ldu3 > 0
    assert part.sockets, f"{name} has no socket"
    assert bool(part.studs) == (name not in STUDLESS)


@needs_ldraw
@pytest.mark.parametrize("name", EMBEDDED_PARTS)
def test_embedded_part_matches_the_real_one(embedded_reader, real_reader, name):
    # A part the 312-part subset lacks (4477) is read from LDraw's library zip beside it
    reader = real_reader if (LDRAW / "parts" / name).is_file() else get_reader(str(LIBRARY_ZIP))
    ours, real = load_part(embedded_reader, name), load_part(reader, name)
    assert np.allclose(ours.bbox, real.bbox, atol=0.5)
    assert {c.pos + c.axis for c in ours.studs} == {c.pos + c.axis for c in real.studs}
    assert {(c.pos, c.kind) for c in ours.sockets} == {(c.pos, c.kind) for c in real.sockets}
    assert ours.symmetry.order == real.symmetry.order
    assert ours.symmetry.continuous_axis == real.symmetry.continuous_axis


def test_embedded_colours(embedded_reader):
    loc = embedded_reader.library.config()
    assert loc is not None
    table = ColourTable.parse(loc.read().decode(), "LDConfig.ldr")
    assert table.get(4).name == "Red" and len(table.colours) >= 40
