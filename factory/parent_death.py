"""A child process that ends with the process that started it (Linux: `prctl(PR_SET_PDEATHSIG)`).

The factory's worker processes (`pipelines.workers`) and its MPS daemon (`factory.mps`) ask for it,
so that a killed job leaves none of them running."""

from __future__ import annotations

import ctypes
import ctypes.util
import signal
import sys
from typing import Callable

_PR_SET_PDEATHSIG = 1


def sigterm_on_parent_death() -> Callable[[], None]:
    """A function that, called in a process, makes it get SIGTERM when its parent dies (on Linux;
    elsewhere it does nothing). libc is loaded here, by the caller, so the function makes a single
    call and can run between fork and exec (`subprocess.Popen(preexec_fn=...)`)."""
    if not sys.platform.startswith("linux"):
        return lambda: None
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    return lambda: libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
