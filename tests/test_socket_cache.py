"""Sockets kept on disk (`connections.sockets_cached`): found once per machine, the same answer
as finding them, found again when the entry is damaged or the part differs."""

from __future__ import annotations

import pytest

import factory.connections as connections
from factory import cache
from factory.ldraw import get_reader
from factory.ldraw.reader import Reader
from factory.parts import load_part

pytestmark = pytest.mark.usefixtures("isolated_cache")


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "sockets"


def _fresh(name):
    """The part from a reader of its own, so no socket is remembered in memory."""
    return load_part(Reader(get_reader().library), name)


def _counting(monkeypatch):
    calls = []
    inner = connections.sockets_facing

    def spy(tris, studs, where=None):
        calls.append(where)
        return inner(tris, studs, where)

    monkeypatch.setattr(connections, "sockets_facing", spy)
    return calls


def test_sockets_are_found_once_and_read_back_the_same(fresh_cache, monkeypatch):
    calls = _counting(monkeypatch)
    first = {n: _fresh(n).sockets for n in ("3001", "3020", "3039")}
    assert len(calls) == 3 and len(list(fresh_cache.glob("*.json"))) == 3
    again = {n: _fresh(n).sockets for n in ("3001", "3020", "3039")}
    assert len(calls) == 3  # all three read from the cache
    assert again == first
    for n in first:  # and equal to finding them, exactly (floats and order)
        p = _fresh(n)
        assert connections.sockets_facing(p.flat.triangles, p.studs) == first[n]
    assert all(len(s) > 0 for s in first.values())


def test_a_damaged_entry_is_found_again_and_rewritten(fresh_cache, monkeypatch):
    want = _fresh("3001").sockets
    (entry,) = fresh_cache.glob("*.json")
    damaged = (b"", b"[[1, 2", b'{"pos": 1}', b'[[[0, 0], [0, -1, 0], "stud"]]',
               b'[[[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], "peg"]]')
    for damage in damaged:
        entry.write_bytes(damage)
        calls = _counting(monkeypatch)
        assert _fresh("3001").sockets == want
        assert len(calls) == 1
        assert connections.json.loads(entry.read_bytes())[0][2] in ("stud", "tube")


def test_another_part_or_another_finder_makes_another_key(monkeypatch):
    a, b = _fresh("3001"), _fresh("3002")
    key = connections._sockets_key(a.flat.triangles, a.studs)
    assert key == connections._sockets_key(_fresh("3001").flat.triangles, a.studs)
    assert key != connections._sockets_key(b.flat.triangles, b.studs)
    assert key != connections._sockets_key(a.flat.triangles, a.studs[:-1])
    monkeypatch.setattr(connections, "source_digest", lambda path: "another way of finding sockets")
    assert key != connections._sockets_key(a.flat.triangles, a.studs)


def test_an_unwritable_cache_is_worked_without(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(blocker))
    cache._UNWRITABLE.clear()
    assert _fresh("3001").sockets == _fresh("3001").sockets
    err = capsys.readouterr().err
    assert err.count("cannot write the cache folder") == 1 and "sockets" in err
