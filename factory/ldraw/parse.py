"""LDraw text into typed lines: line types 0-5, BFC state, steps, MPD blocks.

Parsing is strict about geometry lines (a malformed type 1-5 line is an error naming the file and
line) and lenient about meta-commands (unknown `0 ...` lines are comments, as the format intends).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from factory.errors import LDrawReadError, LDrawSyntaxError
from factory.ldraw.colours import MAX_CODE

MAX_FILE_BYTES = 32 * 1024 * 1024
"""Largest file accepted. The biggest official LDraw files are a few MB; larger input is hostile."""

MAX_LINE_CHARS = 4096
"""Longest line accepted; real lines are under 200 characters."""

MAX_COORD = 1.0e7
"""Largest absolute coordinate or matrix entry accepted (LDU); real models stay under 1e5."""

_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x1a\x1c-\x1f]")


@dataclass(frozen=True, slots=True)
class Ref:
    """A type 1 line: place `name` with `colour` at `pos` with `matrix` (rows a b c / d e f / g h i)."""

    line: int
    colour: int
    matrix: np.ndarray
    pos: np.ndarray
    name: str
    invert: bool = False


@dataclass(frozen=True, slots=True)
class Poly:
    """A type 2-5 line: an edge (2), triangle (3), quad (4) or optional line (5).

    Triangles and quads are stored counter-clockwise when the file's winding is known.
    """

    line: int
    kind: int
    colour: int
    points: np.ndarray


@dataclass(frozen=True, slots=True)
class Step:
    """A `0 STEP` or `0 ROTSTEP` line: the end of a build step."""

    line: int
    rotstep: bool = False


@dataclass
class LDrawFile:
    """One parsed LDraw file (or one block of an MPD file)."""

    path: str
    """Where it came from, for messages: a file path, or `container.mpd#block name`."""
    name: str
    """The name it is referenced by (lower-case, `/`-separated)."""
    description: str = ""
    ldraw_org: str = ""
    category: str = ""
    """The `0 !CATEGORY` meta's text ('' when absent: LDraw then takes the title's first word,
    `part_category`)."""
    moved_to: str | None = None
    certified: bool = False
    flexible: bool = False
    """Drawn as a flexible element bent to a path (a chain, a hose, a string, a spring): LDCad's
    generated content (`0 !LDCAD CONTENT [type=path]` or `[type=spring]`), or keyworded `flexible`
    (`0 !KEYWORDS ..., flexible`). Its drawn segments stand for a part that bends."""
    items: list[Ref | Poly | Step] = field(default_factory=list)
    first_line: int = 1

    @property
    def part_category(self) -> str:
        """LDraw's category of a part: `!CATEGORY`, else the title's first word (without the
        `~`, `_`, `=` and `|` prefixes of moved, alias and sub-parts)."""
        if self.category:
            return self.category
        words = self.description.lstrip("~_=| ").split()
        return words[0] if words else ""

    @property
    def refs(self) -> list[Ref]:
        return [it for it in self.items if isinstance(it, Ref)]

    @property
    def is_part(self) -> bool:
        """Whether the file declares itself a part (official or unofficial, incl. subparts)."""
        org = self.ldraw_org.lower()
        return "part" in org or "primitive" in org or "shortcut" in org or "alias" in org


def normalize_name(name: str) -> str:
    """A reference name as LDraw compares them: lower-case with `/` separators."""
    return name.strip().replace("\\", "/").lower()


def decode(data: bytes, path: str) -> str:
    """Bytes of an LDraw file into text, refusing binary and oversized input."""
    if len(data) > MAX_FILE_BYTES:
        raise LDrawReadError(
            f"file is {len(data):,} bytes; LDraw files over {MAX_FILE_BYTES:,} bytes are refused",
            path,
        )
    if b"\x00" in data or len(_CONTROL.findall(data[:65536])) > 8:
        raise LDrawReadError("binary data, not LDraw text (expected lines of text)", path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def parse_colour(token: str, path: str, line: int) -> int:
    """A colour code: decimal, or a direct colour `0x2RRGGBB` / `#2RRGGBB`."""
    try:
        if token[:2].lower() == "0x":
            return int(token[2:], 16)
        if token.startswith("#"):
            return int(token[1:], 16)
        value = int(token)
    except ValueError:
        raise LDrawSyntaxError(
            f"expected a colour code (integer or 0x2RRGGBB), got {token!r}", path, line
        ) from None
    if value < 0:
        raise LDrawSyntaxError(f"expected a non-negative colour code, got {token!r}", path, line)
    if value > MAX_CODE:
        raise LDrawSyntaxError(f"expected a colour code up to 0x{MAX_CODE:X} (LDraw's codes and direct colours), "
                               f"got {token[:40]!r}", path, line)
    return value


def _numbers(tokens: list[str], path: str, line: int, what: str) -> np.ndarray:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise LDrawSyntaxError(f"{what}: expected a number, got {bad!r}", path, line) from None
    if not all(math.isfinite(v) and abs(v) <= MAX_COORD for v in values):
        raise LDrawSyntaxError(
            f"{what}: numbers must be finite and within ±{MAX_COORD:g}", path, line
        )
    return np.array(values, dtype=np.float64)


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


_FIELDS = {
    2: (6, "type 2 (line) needs a colour and 2 points (6 numbers)"),
    3: (9, "type 3 (triangle) needs a colour and 3 points (9 numbers)"),
    4: (12, "type 4 (quad) needs a colour and 4 points (12 numbers)"),
    5: (12, "type 5 (optional line) needs a colour and 4 points (12 numbers)"),
}


def parse_lines(lines: list[str], path: str, name: str, first_line: int = 1) -> LDrawFile:
    """Parse the lines of one file (or MPD block); `first_line` is the number of `lines[0]`."""
    out = LDrawFile(path=path, name=name, first_line=first_line)
    winding: str | None = None  # "CCW" or "CW" once certified
    invert_next = False
    seen_geometry = False
    titled = False
    for offset, raw in enumerate(lines):
        lineno = first_line + offset
        if len(raw) > MAX_LINE_CHARS:
            raise LDrawSyntaxError(
                f"line is {len(raw)} characters long; at most {MAX_LINE_CHARS} expected", path, lineno
            )
        text = raw.strip()
        if not text:
            continue
        tokens = text.split()
        kind = tokens[0]
        if kind != "0":
            titled = True
        if kind == "0":
            body = tokens[1:]
            if not titled:
                titled = True  # the first non-empty line is the title, when it is a comment
                if body and not _is_meta(body):
                    out.description = text[1:].strip()
                    moved = re.match(r"~moved\s+to\s+(\S.*)$", out.description, re.IGNORECASE)
                    if moved:
                        target = normalize_name(moved.group(1))
                        out.moved_to = target if "." in target else target + ".dat"
            if not body:
                continue
            head = body[0].upper()
            if head in ("STEP", "ROTSTEP"):
                out.items.append(Step(lineno, rotstep=head == "ROTSTEP"))
            elif head == "!LDRAW_ORG":
                out.ldraw_org = " ".join(body[1:])
            elif head == "!CATEGORY":
                out.category = " ".join(body[1:])
            elif head == "!KEYWORDS":
                out.flexible |= "flexible" in {w.strip().lower() for w in " ".join(body[1:]).split(",")}
            elif head == "!LDCAD" and len(body) > 1 and body[1].upper() == "CONTENT":
                out.flexible |= bool(_FLEXIBLE_CONTENT.search(" ".join(body[2:])))
            elif head == "BFC":
                words = [w.upper() for w in body[1:]]
                known = {"CERTIFY", "NOCERTIFY", "CW", "CCW", "CLIP", "NOCLIP", "INVERTNEXT"}
                unknown = [w for w in words if w not in known]
                if unknown:
                    raise LDrawSyntaxError(
                        f"unknown BFC option {unknown[0]!r}; expected one of "
                        "CERTIFY, NOCERTIFY, CW, CCW, CLIP, NOCLIP, INVERTNEXT",
                        path,
                        lineno,
                    )
                if "CERTIFY" in words:
                    if seen_geometry:
                        raise LDrawSyntaxError(
                            "0 BFC CERTIFY must come before the first geometry line", path, lineno
                        )
                    out.certified = True
                    winding = "CW" if "CW" in words else "CCW"
                elif "NOCERTIFY" in words:
                    out.certified = False
                    winding = None
                else:
                    invert_next = invert_next or "INVERTNEXT" in words
                    if out.certified and ("CW" in words or "CCW" in words):
                        winding = "CW" if "CW" in words else "CCW"
            continue
        if kind == "1":
            if len(tokens) < 15:
                raise LDrawSyntaxError(
                    "type 1 (reference) needs colour, x y z, a b c d e f g h i and a file name; "
                    f"got {len(tokens) - 1} fields",
                    path,
                    lineno,
                )
            colour = parse_colour(tokens[1], path, lineno)
            values = _numbers(tokens[2:14], path, lineno, "type 1 (reference)")
            ref_name = text.split(None, 14)[14]
            matrix = values[3:].reshape(3, 3)
            out.items.append(
                Ref(lineno, colour, matrix, values[:3], normalize_name(ref_name), invert_next)
            )
            invert_next = False
            seen_geometry = True
            continue
        if kind in ("2", "3", "4", "5"):
            k = int(kind)
            count, message = _FIELDS[k]
            if len(tokens) != count + 2:
                raise LDrawSyntaxError(f"{message}; got {len(tokens) - 1} fields", path, lineno)
            colour = parse_colour(tokens[1], path, lineno)
            pts = _numbers(tokens[2:], path, lineno, f"type {k}").reshape(-1, 3)
            if k in (3, 4) and winding == "CW":
                pts = pts[::-1].copy()
            out.items.append(Poly(lineno, k, colour, pts))
            if k in (3, 4):
                seen_geometry = True
            invert_next = False
            continue
        raise LDrawSyntaxError(
            f"unknown line type {kind!r}; expected 0 (meta), 1 (reference), 2 (line), "
            "3 (triangle), 4 (quad) or 5 (optional line)",
            path,
            lineno,
        )
    if winding is None:
        out.certified = False
    return out


_FLEXIBLE_CONTENT = re.compile(r"\[type=(path|spring)\]", re.IGNORECASE)
"""LDCad's generated content of a flexible element: a path (chains, hoses, strings, rubber bands)
or a spring."""


def _is_meta(body: list[str]) -> bool:
    head = body[0]
    return head.startswith("!") or head.upper() in ("BFC", "STEP", "ROTSTEP", "NAME:", "AUTHOR:", "//")


@dataclass(frozen=True)
class Block:
    """One `0 FILE` block of an MPD file (or the whole of a plain file)."""

    name: str
    lines: list[str]
    first_line: int


def split_mpd(text: str) -> list[Block]:
    """Split text into its MPD blocks; a file with no `0 FILE` line is one block named ''.

    `0 !DATA` blocks (embedded images) are returned too; nothing references them as geometry.
    """
    lines = text.splitlines()
    blocks: list[Block] = []
    current: tuple[str, int, list[str]] | None = None
    has_file = any(_file_header(ln) is not None for ln in lines)
    if not has_file:
        return [Block("", lines, 1)]
    for i, raw in enumerate(lines):
        header = _file_header(raw)
        if header is not None:
            if current is not None:
                blocks.append(Block(current[0], current[2], current[1]))
            current = (header, i + 2, [])
            continue
        if raw.strip().upper() == "0 NOFILE":
            if current is not None:
                blocks.append(Block(current[0], current[2], current[1]))
            current = None
            continue
        if current is not None:
            current[2].append(raw)
    if current is not None:
        blocks.append(Block(current[0], current[2], current[1]))
    return blocks


def _file_header(raw: str) -> str | None:
    m = re.match(r"^\s*0\s+(FILE|!DATA)\s+(\S.*?)\s*$", raw, re.IGNORECASE)
    if not m:
        return None
    name = m.group(2)
    return name if m.group(1).upper() == "FILE" else "!data:" + name
