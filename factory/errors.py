"""Errors raised on bad LDraw input. Each names the file, the line and what was expected."""

from __future__ import annotations


class LDrawError(Exception):
    """Bad LDraw input: `file:line: message`."""

    def __init__(self, message: str, file: str | None = None, line: int | None = None):
        self.message = message
        self.file = file
        self.line = line
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.file is not None:
            where = f"{self.file}:{self.line}: " if self.line else f"{self.file}: "
        return f"{where}{self.message}"


class LDrawSyntaxError(LDrawError):
    """A line that does not have the fields its line type needs."""


class LDrawMissingFileError(LDrawError):
    """A referenced file that is found nowhere on the search path."""


class LDrawCycleError(LDrawError):
    """A file that references itself, directly or through others."""


class LDrawUnsafePathError(LDrawError):
    """A reference that would leave the library or the model's folder."""


class LDrawReadError(LDrawError):
    """A file that cannot be read as LDraw text (unreadable, binary, too large)."""


class LDrawLimitError(LDrawError):
    """Input whose expansion would exceed a safety limit (depth, triangles, parts)."""


class LDrawPlacementError(LDrawError):
    """A part or submodel placed by a matrix that is not a rotation (scaled, sheared, mirrored)."""
