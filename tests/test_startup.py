"""Ctrl-C in a command's body (`factory._startup._interrupt`): a KeyboardInterrupt, but never in
the middle of an import, where a library may swallow or print it; there it comes again a moment
later. (Whole builds interrupted at many moments: tests/test_dataset.py, tests/hostile/interrupt.py.)"""

from __future__ import annotations

import signal
from types import SimpleNamespace

import pytest

from factory import _startup


def _frames(*files):
    """A chain of fake frames, innermost first."""
    frame = None
    for name in reversed(files):
        frame = SimpleNamespace(f_code=SimpleNamespace(co_filename=name), f_back=frame)
    return frame


def test_an_interrupt_outside_imports_raises_at_once(monkeypatch):
    monkeypatch.setattr(_startup, "_retries", 0)
    with pytest.raises(KeyboardInterrupt):
        _startup._interrupt(signal.SIGINT, _frames("/work/factory/render/scene.py", "<frozen runpy>"))


def test_an_interrupt_inside_an_import_comes_again_later(monkeypatch):
    sent = []

    class Timer:
        def __init__(self, seconds, fn, args):
            sent.append((seconds, fn, args))
            self.daemon = False

        def start(self):
            assert self.daemon

    monkeypatch.setattr(_startup.threading, "Timer", Timer)
    monkeypatch.setattr(_startup, "_retries", 0)
    inside = _frames("/venv/trimesh/base.py", "<frozen importlib._bootstrap>", "/work/factory/parts.py")
    _startup._interrupt(signal.SIGINT, inside)  # deferred: no exception
    assert len(sent) == 1 and sent[0][0] == _startup.RETRY_SECONDS and sent[0][2][1] == signal.SIGINT
    monkeypatch.setattr(_startup, "_retries", _startup.MAX_RETRIES)  # an import that never ends
    with pytest.raises(KeyboardInterrupt):
        _startup._interrupt(signal.SIGINT, inside)


def test_the_library_outside_a_command_leaves_sigint_alone():
    """Imported by pytest (not one of the project's command lines), nothing was installed."""
    assert not _startup._COMMAND
    assert signal.getsignal(signal.SIGINT) not in (_startup._quit_loudly, _startup._quit_quietly, _startup._interrupt)
