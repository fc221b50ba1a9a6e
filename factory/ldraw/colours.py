"""LDraw colours from `LDConfig.ldr`: codes to RGBA, with edge colours and direct colours."""

from __future__ import annotations

import re
from dataclasses import dataclass

from factory.errors import LDrawSyntaxError

MAIN = 16
"""The colour code that means 'the colour this part is placed with'."""
EDGE = 24
"""The colour code that means 'the edge colour of the colour this part is placed with'."""


@dataclass(frozen=True)
class Colour:
    code: int
    name: str
    rgba: tuple[float, float, float, float]
    edge: tuple[float, float, float, float]


_FALLBACK = Colour(-1, "Unknown", (0.6, 0.6, 0.6, 1.0), (0.2, 0.2, 0.2, 1.0))

MAX_CODE = 0x7FFFFFF
"""The largest code an LDraw file may write: direct colours are 0x2RRGGBB and 0x3RRGGBB, and the
spec's older dithered direct colours run up to 0x7FFFFFF. A larger code is a syntax error."""

RULE = ("a colour of the library's LDConfig.ldr, 16 or 24, a dithered code 256-511, or a direct "
        "colour 0x2RRGGBB/0x3RRGGBB")
"""What `ColourTable.allows` accepts, as error messages say it."""


def _hex(value: str, file: str, line: int) -> tuple[float, float, float]:
    m = re.fullmatch(r"(?:#|0x)([0-9a-fA-F]{6})", value)
    if not m:
        raise LDrawSyntaxError(f"expected a colour value #RRGGBB, got {value!r}", file, line)
    h = m.group(1)
    return tuple(int(h[i : i + 2], 16) / 255.0 for i in (0, 2, 4))  # type: ignore[return-value]


class ColourTable:
    """Colour codes to colours; codes not in the table fall back to a neutral grey."""

    def __init__(self, colours: dict[int, Colour]):
        self.colours = colours

    @classmethod
    def parse(cls, text: str, file: str = "LDConfig.ldr") -> "ColourTable":
        colours: dict[int, Colour] = {}
        for lineno, raw in enumerate(text.splitlines(), 1):
            tokens = raw.split()
            if len(tokens) < 3 or tokens[0] != "0" or tokens[1].upper() != "!COLOUR":
                continue
            fields: dict[str, str] = {}
            i = 3
            while i < len(tokens):
                key = tokens[i].upper()
                if key in ("CODE", "VALUE", "EDGE", "ALPHA", "LUMINANCE") and i + 1 < len(tokens):
                    fields[key] = tokens[i + 1]
                    i += 2
                else:
                    i += 1
            if "CODE" not in fields or "VALUE" not in fields:
                raise LDrawSyntaxError(
                    "!COLOUR line needs CODE n and VALUE #RRGGBB", file, lineno
                )
            try:
                code = int(fields["CODE"])
                alpha = int(fields.get("ALPHA", "255")) / 255.0
            except ValueError:
                raise LDrawSyntaxError("!COLOUR CODE and ALPHA must be integers", file, lineno) from None
            rgb = _hex(fields["VALUE"], file, lineno)
            edge_value = fields.get("EDGE", "#333333")
            edge = _hex(edge_value, file, lineno) if not edge_value.isdigit() else (0.2, 0.2, 0.2)
            colours[code] = Colour(code, tokens[2], (*rgb, alpha), (*edge, 1.0))
        return cls(colours)

    def get(self, code: int) -> Colour:
        """The colour for a code, including direct colours 0x2RRGGBB (opaque) and 0x3RRGGBB."""
        if code in self.colours:
            return self.colours[code]
        if code >> 24 in (2, 3):
            rgb = tuple(((code >> s) & 0xFF) / 255.0 for s in (16, 8, 0))
            alpha = 1.0 if code >> 24 == 2 else 0.5
            edge = tuple(c * 0.5 for c in rgb)
            return Colour(code, f"Direct_0x{code:07X}", (*rgb, alpha), (*edge, 1.0))  # type: ignore[arg-type]
        return _FALLBACK

    def allows(self, code: int) -> bool:
        """Whether a model may place a part in colour `code` (`RULE`): a code of this table, the
        inherited colours 16 and 24, the spec's dithered codes 256-511 and direct colours. A table
        read from no LDConfig.ldr (empty) has nothing to check against and allows every code up to
        `MAX_CODE`."""
        if not 0 <= code <= MAX_CODE:
            return False
        if not self.colours or code in self.colours or code in (MAIN, EDGE):
            return True
        return 256 <= code < 512 or 2 <= code >> 24 <= 7

    def rgba(self, code: int) -> tuple[float, float, float, float]:
        return self.get(code).rgba

    def __contains__(self, code: int) -> bool:
        return code in self.colours or code >> 24 in (2, 3)
