"""Ctrl-C while a command line starts: one line and exit 130, never a traceback or an ignored key.

A command spends its first second or two importing numpy, MuJoCo, trimesh and the like. A
KeyboardInterrupt raised there either ended in a long traceback (nothing catches it before the
command's `run_guarded`) or was swallowed by a library that catches `BaseException` around an
import (trimesh does), and the build then ran to its end. Nothing is written before the command's
body runs, so until then SIGINT ends the process at once: this module is imported first by
`factory/__init__.py` (stdlib only, before anything heavy) and, in a process that runs one of
the project's command lines (`python -m pipelines.X`, `eval.X`, `train`, `factory.ldraw` or the
`brick-factory` script) or in a worker process such a command spawned, sets that handler.
`factory.cli.run_guarded` hands SIGINT back to a KeyboardInterrupt when the body starts
(`started`; raised outside imports only, `_interrupt`), and ignores it once the body has ended (`finishing`: a Ctrl-C during the shutdown
killed a finished build silently by SIGINT). Elsewhere (a notebook, pytest, a user's script
importing the library) nothing changes. A command also pins MuJoCo's GL backend
(`factory.gl_backend.pin`) before MuJoCo loads, for its workers too.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

from factory import gl_backend  # stdlib only

COMMAND_PACKAGES = ("pipelines", "eval", "train", "factory")
CHILD_ENV = "BRICK_FACTORY_COMMAND"
"""Set by a command for the processes it starts: their start-up is guarded too, quietly (the
command says once what happened)."""

MESSAGE = b"error: interrupted while starting; nothing was written\n"


def _is_command() -> bool:
    """Whether this process runs one of the project's command lines. Read from the interpreter's
    own command line: `python -m X` imports X's package before `__main__` says what it is."""
    argv = list(getattr(sys, "orig_argv", ()))
    if "-m" in argv[:-1]:
        module = argv[argv.index("-m") + 1]
        return module.split(".")[0] in COMMAND_PACKAGES
    return os.path.basename(sys.argv[0] or "") == "brick-factory"


def _quit_loudly(signum, frame) -> None:
    os.write(2, MESSAGE)
    os._exit(130)


def _quit_quietly(signum, frame) -> None:
    os._exit(130)


_COMMAND = False
"""Whether this process is a command (`guard` installed the loud handler)."""


def guard() -> None:
    """Install the start-up handler where this process is a command or one of its workers, unless
    SIGINT is ignored (a background job keeps ignoring it)."""
    try:
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            return
        if _is_command():
            global _COMMAND
            _COMMAND = True
            os.environ[CHILD_ENV] = "1"
            signal.signal(signal.SIGINT, _quit_loudly)
            gl_backend.pin()  # before MuJoCo loads: never GLFW, whose import starts a Python child
        elif os.environ.get(CHILD_ENV) == "1":
            signal.signal(signal.SIGINT, _quit_quietly)
    except ValueError:  # not the main thread: leave signals alone
        pass


RETRY_SECONDS = 0.05
"""How soon a Ctrl-C that arrived during an import is raised again."""
MAX_RETRIES = 100
"""After this many (5 s of an import that does not end), KeyboardInterrupt is raised anyway."""
_retries = 0


def _interrupt(signum, frame) -> None:
    """Ctrl-C while the command's body runs: KeyboardInterrupt, which `run_guarded` turns into its
    one line; but never inside an import (a library may catch `BaseException` round a lazy
    import, as trimesh does, or print it), where the signal is sent again a moment later, once the
    import is done."""
    global _retries
    f = frame
    while f is not None and _retries < MAX_RETRIES:
        if f.f_code.co_filename.startswith("<frozen importlib"):
            _retries += 1
            timer = threading.Timer(RETRY_SECONDS, os.kill, (os.getpid(), signal.SIGINT))
            timer.daemon = True
            timer.start()
            return
        f = f.f_back
    raise KeyboardInterrupt


def started() -> None:
    """The command's body starts (it may write from now on): Ctrl-C raises KeyboardInterrupt
    again (outside imports: `_interrupt`), which `run_guarded` turns into its one line."""
    try:
        if signal.getsignal(signal.SIGINT) in (_quit_loudly, _quit_quietly):
            signal.signal(signal.SIGINT, _interrupt)
    except ValueError:
        pass


def finishing() -> None:
    """The command's body has ended (its status is known, its line said): in a command process,
    a Ctrl-C from now on is ignored, so that it cannot turn a finished run into a silent death by
    SIGINT during the interpreter's shutdown."""
    if _COMMAND:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:
            pass


guard()
