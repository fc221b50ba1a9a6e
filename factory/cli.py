"""What every command line of the project does with bad input: one `error: ...` line, no traceback."""

from __future__ import annotations

import sys
from typing import Callable

from factory.errors import LDrawError


def run_guarded(body: Callable[[], int | None], extra: dict[type[BaseException], int] | None = None) -> int:
    """Run a command's body; known failures print one line to stderr and give an exit status.

    LDraw errors and runaway nesting exit 2; `extra` maps further exception types to their status.
    A closed output pipe (`| head`) is a normal end.
    """
    handled: dict[type[BaseException], int] = {LDrawError: 2, **(extra or {})}
    try:
        return body() or 0
    except BrokenPipeError:
        return 0
    except KeyboardInterrupt:
        print("error: interrupted; what was finished is kept (re-run the same command to resume where it can)",
              file=sys.stderr)
        return 130
    except RecursionError:
        print("error: input nests too deeply to read", file=sys.stderr)
        return 2
    except tuple(handled) as exc:
        status = next(code for kind, code in handled.items() if isinstance(exc, kind))
        print(f"error: {exc}", file=sys.stderr)
        return status
