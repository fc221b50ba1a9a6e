"""Model outputs into answers, never raising: a benchmark must score every string a model can emit.

Two answer formats (docs: bc-bench brief):

- selection, one line per brick: ``3023.dat, row 6, col 3``
- pose, one block per brick::

      Brick 1:
      Translation:
      x=-10.0, y=-8.0, z=-20.0
      Rotation:
      [0.0, 0.0, -1.0]
      [0.0, 1.0, 0.0]
      [1.0, 0.0, 0.0]

Before parsing, the text is cleaned the same way for both tasks (`clean`): reasoning in
``<think>...</think>`` is removed (nested tags by depth; text before a stray ``</think>`` is reasoning
whose opening tag was in the prompt; an unclosed ``<think>`` drops the rest, as the model never left
its reasoning), code-fence lines and markdown emphasis are dropped, and unicode is NFKC-normalised
(full-width digits, the minus sign U+2212). An answer only inside reasoning does not count.

Parsing is tolerant of wording, case, whitespace and order of the labels, but never guesses numbers:
a pose block with a missing or non-finite number is absent, not completed. Every regular expression
is linear in the input (possessive quantifiers, bounded look-behind windows), so a 10^6-character
answer costs milliseconds, not a hang.
"""

from __future__ import annotations

import itertools
import math
import re
import unicodedata
from dataclasses import dataclass

import numpy as np

from factory.dataset.answers import normalise_part

MAX_CHARS = 2_000_000
"""Longer outputs are cut here: no real answer is this long, and it bounds the work."""


@dataclass(frozen=True)
class Selection:
    """One chosen catalog cell; `part` is the label the model wrote (normalised, may be "")."""

    part: str
    row: int
    col: int


@dataclass(frozen=True, eq=False)
class PoseAnswer:
    """One brick's predicted pose: translation (3,) in LDU and the 3x3 matrix as written (rows)."""

    t: np.ndarray
    R: np.ndarray


# -- cleaning ---------------------------------------------------------------------------------

_THINK = re.compile(r"<\s*+(/?)\s*+think\s*+>", re.IGNORECASE)
_FENCE_LINE = re.compile(r"^[ \t]*+(?:```|~~~)[^\n]*+$", re.MULTILINE)


def strip_think(text: str) -> str:
    """Remove reasoning blocks (see the module docstring for stray and unclosed tags)."""
    keep: list[str] = []
    depth = 0
    pos = 0  # start of the text not yet decided
    for m in _THINK.finditer(text):
        if m.group(1):  # closing tag
            if depth > 0:
                depth -= 1
            else:
                keep.clear()  # everything so far was reasoning opened in the prompt
            if depth == 0:
                pos = m.end()
        else:
            if depth == 0:
                keep.append(text[pos : m.start()])
            depth += 1
    if depth == 0:
        keep.append(text[pos:])
    return "".join(keep)


def clean(text) -> str:
    """The text both parsers read: reasoning removed, fences and emphasis dropped, NFKC."""
    if not isinstance(text, str):
        return ""
    text = text[:MAX_CHARS]
    try:
        text = unicodedata.normalize("NFKC", text)
    except Exception:  # pragma: no cover - normalize accepts every str; belt and braces
        pass
    text = text.replace("\u2212", "-").replace("\r\n", "\n").replace("\r", "\n")
    text = strip_think(text)
    text = _FENCE_LINE.sub("", text)
    return text.replace("*", "").replace("`", "")


# -- selection --------------------------------------------------------------------------------

_ROW = r"(?<![a-z])row(?![a-z])[ \t]*+[:=#]?[ \t]*+(?P<{0}>\d{{1,6}})(?!\d)"
_COL = r"(?<![a-z])col(?:umn)?(?![a-z])[ \t]*+[:=#]?[ \t]*+(?P<{0}>\d{{1,6}})(?!\d)"
_JOIN = r"[ \t]*+[,;/|]?[ \t]*+(?:and[ \t]++)?"
_SEL = re.compile(
    _ROW.format("row") + _JOIN + _COL.format("col") + "|" + _COL.format("col2") + _JOIN + _ROW.format("row2"),
    re.IGNORECASE | re.ASCII,
)
# The part label right before "row": a bounded window, anchored at its end.
_PART_BEFORE = re.compile(
    r"([a-z0-9][\w\-]{0,63}?(?:\.dat)?)[ \t]*+[,;:\-(\[]?[ \t]*+(?:(?:at|in)[ \t]++)?[(\[]?[ \t]*+\Z",
    re.IGNORECASE | re.ASCII,
)
_LINE_PREFIX = re.compile(
    r"[ \t]*+(?:[-+>\u2022][ \t]*+|\d{1,3}[.)][ \t]++)?(?:[a-z][\w ]{0,40}:[ \t]*+)?\Z", re.IGNORECASE
)
_LINE_SUFFIX = re.compile(r"[ \t.,;)\]]*+\Z")


def parse_selection(text) -> list[Selection]:
    """Every `part, row R, col C` in the answer (also `col C, row R`), in order; [] when none parses.

    When some matches stand alone on their line (decorated at most by a bullet, a number or a
    label such as ``Answer:``), only those count: the answer format is one line per brick, and
    prose before it ("3001.dat, row 1, col 2 looked close, but...") must not add picks. Otherwise
    every match in the text counts. The part label is kept for reports; scoring uses the cell.
    """
    try:
        return _parse_selection(clean(text))
    except Exception:  # pragma: no cover - the parser must never raise; fuzz-tested
        return []


def _parse_selection(text: str) -> list[Selection]:
    found: list[tuple[bool, Selection]] = []
    for m in _SEL.finditer(text):
        row = m.group("row") if m.group("row") is not None else m.group("row2")
        col = m.group("col") if m.group("col") is not None else m.group("col2")
        lo = max(0, m.start() - 96)  # bounded, so that a long line costs no quadratic scan
        newline = text.rfind("\n", lo, m.start())
        window_start = newline + 1 if newline >= 0 else lo
        at_line_start = newline >= 0 or lo == 0 or text[lo - 1] == "\n"
        before = text[window_start : m.start()]
        pm = _PART_BEFORE.search(before)
        part = ""
        prefix = before
        if pm and any(c.isdigit() for c in pm.group(1)):
            part = normalise_part(pm.group(1))
            prefix = before[: pm.start()]
        line_end = text.find("\n", m.end(), m.end() + 200)
        suffix = text[m.end() : line_end if line_end >= 0 else m.end() + 200]
        alone = (
            at_line_start
            and _LINE_PREFIX.match(prefix) is not None
            and _LINE_SUFFIX.match(suffix) is not None
            and (line_end >= 0 or m.end() + 200 >= len(text))
        )
        found.append((alone, Selection(part, int(row), int(col))))
    if any(alone for alone, _ in found):
        return [s for alone, s in found if alone]
    return [s for _, s in found]


# -- pose -------------------------------------------------------------------------------------

_NUM = r"[-+]?+(?:\d++(?:\.\d*+)?+|\.\d++)(?:e[-+]?+\d++)?+"
_HEADER = re.compile(
    r"^[ \t>#\-]*+brick[ \t]*+(?:no\.?|number)?[ \t]*+#?[ \t]*+(\d{1,6})(?!\d)[ \t]*+"
    r"(?:\([^()\n]{0,80}\)[ \t]*+)?(?:[:.)\-]|$)",
    re.IGNORECASE | re.MULTILINE | re.ASCII,
)
_AXIS = re.compile(r"(?<![a-z])([xyz])[ \t]*+[=:][ \t]*+(" + _NUM + r")", re.IGNORECASE | re.ASCII)
_SEP = r"(?:[ \t]*+[,;][ \t]*+|[ \t]++)"
_TRIPLE_BODY = "(" + _NUM + ")" + _SEP + "(" + _NUM + ")" + _SEP + "(" + _NUM + ")"
_TRIPLE = re.compile(r"[\[(][ \t]*+" + _TRIPLE_BODY + r"[ \t]*+,?[ \t]*+[\])]", re.IGNORECASE | re.ASCII)
_TRANSLATION_KW = re.compile(r"translation|position|(?<![a-z])t(?=[ \t]*+[:=])", re.IGNORECASE)
_BARE_ROW = re.compile(r"^[ \t]*+" + _TRIPLE_BODY + r"[ \t,;]*+$", re.IGNORECASE | re.MULTILINE | re.ASCII)
_ROTATION_KW = re.compile(r"rotation|orientation", re.IGNORECASE)


def parse_pose(text) -> dict[int, PoseAnswer]:
    """Pose blocks by brick number; a block with a missing or non-finite number is absent.

    Blocks start at lines ``Brick N:`` (also ``### Brick 2 (3001.dat):``). Without any header the
    whole text is brick 1. When a number appears twice, the last block that parses wins (models
    revise). The translation is the first run of three ``x=.., y=.., z=..`` labels in any order
    (else a bracketed triple after the word Translation); the rotation is the first three bracketed
    triples after it (nested ``[[..],[..],[..]]`` works), else after the word Rotation, else three
    lines of three bare numbers. Keywords in prose cannot derail this: numbers anchor it.
    """
    try:
        return _parse_pose(clean(text))
    except Exception:  # pragma: no cover - the parser must never raise; fuzz-tested
        return {}


def _parse_pose(text: str) -> dict[int, PoseAnswer]:
    headers = list(_HEADER.finditer(text))
    if not headers:
        blocks = [(1, text)]
    else:
        blocks = []
        for i, h in enumerate(headers):
            end = headers[i + 1].start() if i + 1 < len(headers) else len(text)
            blocks.append((int(h.group(1)), text[h.end() : end]))
    out: dict[int, PoseAnswer] = {}
    for number, body in blocks:
        pose = _parse_block(body)
        if pose is not None:
            out[number] = pose
    return out


def _floats(strings) -> list[float] | None:
    try:
        vals = [float(s) for s in strings]
    except (ValueError, OverflowError):
        return None
    return vals if all(math.isfinite(v) for v in vals) else None


def _translation(body: str) -> tuple[list[str], int, int] | None:
    """(three number strings x, y, z; start; end) of the translation in a block, or None."""
    axes = list(_AXIS.finditer(body))
    for i in range(len(axes) - 2):
        run = axes[i : i + 3]
        if sorted(m.group(1).lower() for m in run) == ["x", "y", "z"]:
            by = {m.group(1).lower(): m.group(2) for m in run}
            return [by["x"], by["y"], by["z"]], run[0].start(), run[2].end()
    for kw in itertools.islice(_TRANSLATION_KW.finditer(body), 8):
        m = _TRIPLE.search(body, kw.end(), kw.end() + 120)  # "Translation: (x, y, z) = (1, 2, 3)"
        if m:
            return list(m.groups()), m.start(), m.end()
    return None


def _rotation_rows(body: str, starts: list[int], skip: tuple[int, int]) -> list[tuple] | None:
    """The first three number triples from one of `starts`, bracketed first, else bare lines."""
    for pattern in (_TRIPLE, _BARE_ROW):
        for start in starts:
            outside = (m for m in pattern.finditer(body, start) if m.end() <= skip[0] or m.start() >= skip[1])
            rows = [m.groups() for m in itertools.islice(outside, 3)]
            if len(rows) == 3:
                return rows
    return None


def _parse_block(body: str) -> PoseAnswer | None:
    found = _translation(body)
    if found is None:
        return None
    t_strings, t_start, t_end = found
    t = _floats(t_strings)
    if t is None:
        return None
    starts = [t_end] + [m.end() for m in itertools.islice(_ROTATION_KW.finditer(body), 8)]
    rows = _rotation_rows(body, starts, (t_start, t_end))
    if rows is None:
        return None
    r = _floats([v for row in rows for v in row])
    if r is None:
        return None
    return PoseAnswer(np.array(t, dtype=np.float64), np.array(r, dtype=np.float64).reshape(3, 3))
