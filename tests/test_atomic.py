"""Atomic writes: the old file or the whole new one, and no temporary file left behind."""

from __future__ import annotations

import os

import pytest

from factory.atomic import write_atomic


def test_write_replaces_and_creates_folders(tmp_path):
    path = tmp_path / "a" / "b" / "f.json"
    write_atomic(path, b"one")
    write_atomic(path, b"two")
    assert path.read_bytes() == b"two"
    assert os.listdir(path.parent) == ["f.json"]


def test_a_failed_write_keeps_the_old_file_and_cleans_up(tmp_path, monkeypatch):
    path = tmp_path / "f.json"
    write_atomic(path, b"old")

    def broken(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(OSError, match="disk full"):
        write_atomic(path, b"new")
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["f.json"]


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_written_files_follow_the_umask(tmp_path, umask, mode):
    """A teammate or a Ray worker under another uid reads what a run wrote (not mkstemp's 0600)."""
    old = os.umask(umask)
    try:
        path = tmp_path / f"f{umask:o}.json"
        write_atomic(path, b"x")
        write_atomic(path, b"y")  # replacing keeps it too
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == mode


def test_a_figure_is_written_whole_as_savefig_would(tmp_path):
    matplotlib = pytest.importorskip("matplotlib")  # the `bench` extra
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from factory.atomic import write_figure

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "plain.png", dpi=50)
    write_figure(fig, tmp_path / "plots" / "atomic.png", dpi=50)
    plt.close(fig)
    assert (tmp_path / "plots" / "atomic.png").read_bytes() == (tmp_path / "plain.png").read_bytes()
    assert os.listdir(tmp_path / "plots") == ["atomic.png"]
