"""Part families: the printed variants, revisions and renumbered (`~Moved to`) files of one part
folded into one name, so that usage counted in real designs is usage of a shape.

`3068bp01` (a printed tile) and `3068b` are one shape; `3062a` and `3062b` (two moulds of the round
brick) are one shape to a model that places it; `3023.dat` is a `~Moved to 3023b` stub. The
family is the part number without its pattern suffix and without its revision letter: `3068`,
`3062`, `3023`. A composite (`3829c01`, a part number with `c` and two digits) is its own family:
it is a different object from its base part.
"""

from __future__ import annotations

import re

_PATTERN = re.compile(r"^(.*?\d[a-z]?)(?:p[0-9a-z]{2,4}|pr\d{3,4}|pat\d{3,4}|d\d{2,3})$")
"""A printed or stickered variant: a part number (with its revision letter), then `p` and 2-4 letters or digits (LDraw's
pattern codes), `pr` or `pat` and a four-digit number (newer prints), or `d` and two or three
digits (a decorated sticker assembly)."""

_REVISION = re.compile(r"^(u?\d+)[a-e]$")
"""A revision letter after a plain part number (`3794a`, `3062b`, `4085c`)."""


def part_name(name: str) -> str:
    """A placed file name as a family key is made from: lower case, '/' separators, no `.dat`,
    no folder (`parts/3001.dat` and `3001` are one part)."""
    s = str(name).strip().replace("\\", "/").lower().rsplit("/", 1)[-1]
    return s[:-4] if s.endswith(".dat") else s


def unprinted(name: str) -> str:
    """The part without its pattern suffix: `3068bp01` -> `3068b`; other names unchanged."""
    name = part_name(name)
    m = _PATTERN.match(name)
    return m.group(1) if m else name


def family(name: str) -> str:
    """The family of a part name (already resolved past `~Moved to` stubs, see `MovedParts`):
    unprinted, then without a revision letter. `3068bp01` -> `3068`, `3062b` -> `3062`,
    `3829c01` -> `3829c01`, `u9057` -> `u9057`."""
    name = unprinted(name)
    m = _REVISION.match(name)
    return m.group(1) if m else name
