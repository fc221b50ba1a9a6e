"""Which parts of a library the factory can use (python -m pipelines.parts), preparing them into the
cache, the cache as one file for another machine, and how far objects are from real designs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from factory.ldraw import Library, Reader, get_reader
from factory.parts import load_part
from factory.prior.choose import NO_CONNECTOR
from factory.symmetry import find_symmetry, symmetry_cached
from pipelines.prepare import pack, survey, unpack
from pipelines.realism import compare, coverage, read_collection

from ldraw_support import LDRAW, needs_ldraw

ROOT = Path(__file__).resolve().parents[1]


def _run(*args, env=None):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=ROOT, env=env)


def test_every_part_of_a_library_is_usable_or_listed_with_its_reason(real_reader):
    """The 312 parts of the shared subset: each one usable or left out for a property of the part."""
    names = real_reader.library.part_names()
    statuses = survey(str(LDRAW), names, own_parts=True)
    by = {s.part: s for s in statuses}
    assert len(statuses) == len(names) == 312
    assert by["3001"].reason is None and by["3001"].category == "Brick"
    assert by["3023"].reason.startswith("renumbered: moved to 3023b")  # a stub, not a part of its own
    assert by["3673"].reason is None  # a Technic pin: the sampler attaches it through its joints
    assert by["3673"].joints == {"pin": 2} and by["3700"].joints == {"bar": 1, "pin-hole": 2}
    assert by["3641"].reason == NO_CONNECTOR and by["3641"].joints == {}  # a tyre: held by its shape
    assert by["3820"].reason is None  # a hand: in its arm's slot (`factory.minifig`)
    assert by["2530"].reason.startswith("a minifigure piece held")  # a sword: its grip differs per piece
    usable = [s for s in statuses if s.reason is None]
    assert 150 < len(usable) < 312
    for s in statuses:
        assert s.reason is None or not s.reason.startswith(("cannot be read", "collision")), (s.part, s.reason)


@pytest.mark.slow
@needs_ldraw
def test_the_parts_command_tables_the_library_by_category(tmp_path):
    out = _run("pipelines.parts", "--ldraw", str(LDRAW), "--all", "--workers", "2", "--no-progress")
    assert out.returncode == 0, out.stderr
    assert "| Brick | 30 | 30 |" in out.stdout and "| Moved | 16 | 0 | 16 renumbered |" in out.stdout
    assert "parts usable; surveyed in" in out.stderr
    lines = [json.loads(x) for x in _run("pipelines.parts", "--ldraw", str(LDRAW), "--json", "--workers", "1",
                                          "--no-progress").stdout.splitlines()]
    # the shipped prior's parts on this library: those it holds, and those it cannot give, with why
    assert any(x["usable"] for x in lines) and any(x.get("prior_weight") for x in lines if not x["usable"])


def test_a_prepared_cache_travels_as_one_file_and_a_foreign_member_is_refused(tmp_path, monkeypatch):
    from factory.embedded import write_library

    src, dst = tmp_path / "a", tmp_path / "b"
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(src))
    # The embedded library written to a folder of its own: a reader no other test has loaded parts with
    library = write_library(tmp_path / "lib")
    statuses = survey(str(library), ["3001", "3023", "6141"], prepare=True)
    assert [s.reason for s in statuses] == [None, None, None]
    # a first try's end kept for a run cut during the second (`decompose._remember_slow`) travels too
    (src / "coacd" / "0123456789abcdef.slow.json").write_text("{}")
    n = pack(tmp_path / "cache.zip")
    names = zipfile.ZipFile(tmp_path / "cache.zip").namelist()
    assert n == len(names) and {m.split("/")[0] for m in names} >= {"coacd", "sockets", "symmetry", "hulls"}
    assert "coacd/0123456789abcdef.slow.json" in names
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(dst))
    assert unpack(tmp_path / "cache.zip") == n and unpack(tmp_path / "cache.zip") == 0  # kept, not rewritten
    for m in names:
        assert (dst / m).read_bytes() == (src / m).read_bytes()
    for bad in ("../evil.json", "jax/0123456789abcdef.bin", "coacd/not-hex.npz", "/abs/0123456789abcdef.npz",
                "coacd/0123456789abcdef.evil.json"):
        with zipfile.ZipFile(tmp_path / "bad.zip", "w") as z:
            z.writestr("coacd/0123456789abcdef.npz", b"x")
            z.writestr(bad, b"x")
        with pytest.raises(ValueError, match="is not a cache entry"):
            unpack(tmp_path / "bad.zip")
    assert not (dst / "coacd" / "0123456789abcdef.npz").exists()  # nothing unpacked from a refused file


def test_symmetry_kept_on_disk_is_the_symmetry_found(tmp_path, monkeypatch):
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    reader = get_reader(None)
    for name in ("3001", "6141", "3039"):
        v = load_part(reader, name).flat.triangles.reshape(-1, 3)
        found, first, again = find_symmetry(v), symmetry_cached(v), symmetry_cached(v)
        for s in (first, again):
            assert s.continuous_axis == found.continuous_axis and len(s.rotations) == len(found.rotations)
            assert all(np.array_equal(a, b) for a, b in zip(s.rotations, found.rotations))
    for entry in (tmp_path / "symmetry").iterdir():
        entry.write_bytes(b"{damaged")  # a damaged entry is found again
    assert symmetry_cached(v).continuous_axis == find_symmetry(v).continuous_axis


def test_coverage_counts_the_real_placements_of_families_the_objects_use(write):
    """Families fold revisions and prints: an embedded 3023 covers a real 3023b and its print."""
    write("objects/a.ldr", "0 a\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3023.dat\n1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    real = write("real/r.ldr", "0 r\n" + "".join(f"1 1 0 {-8 * i} 0 1 0 0 0 1 0 0 0 1 {n}.dat\n" for i, n in
                                                   enumerate(["3023b", "3023p01", "3001", "3068b"])))
    reader = get_reader(None)
    objects, designs = read_collection(real.parent.parent / "objects", reader), read_collection(real.parent, reader)
    assert coverage(objects, designs) == (0.75, 3, 4)
    tables = {t.name: t for t in compare(objects, designs, reader)}
    assert tables["part families"].extra["most_missed"][0]["family"] == "3068"
    assert tables["parts per object"].distance == pytest.approx(2.0)  # 2 parts against 4
    assert tables["orientation"].distance == 0.0 and tables["colours"].distance == 1.0


def test_the_distance_command_writes_tables_and_plots(write, tmp_path):
    write("objects/a.ldr", "0 a\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3023.dat\n")
    write("real/r.ldr", "0 r\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3023.dat\n1 4 0 0 0 -1 0 0 0 -1 0 0 0 1 3001.dat\n")
    out = _run("pipelines.distance", str(tmp_path / "objects"), str(tmp_path / "real"), "--out", str(tmp_path / "rep"))
    assert out.returncode == 0, out.stderr
    assert "coverage 50.0% (1 of 2 placements)" in out.stdout
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert [t["table"] for t in report["tables"]][:2] == ["part families", "categories"]
    orientation = next(t for t in report["tables"] if t["table"] == "orientation")
    assert {r["key"]: r["real"] for r in orientation["rows"]} == {"upright": 0.5, "upside down": 0.5}
    assert (tmp_path / "rep" / "part_families.png").stat().st_size > 1000 and (tmp_path / "rep" / "report.md").exists()


def test_a_dataset_folder_is_read_as_its_objects(tiny_dataset):
    """The distance report reads a dataset's rows: each object's bricks, as placed, step by step."""
    import pyarrow.parquet as pq

    reader = get_reader(None)
    objects = read_collection(tiny_dataset, reader)
    rows = [r for f in sorted((tiny_dataset / "data").glob("*.parquet"))
            for r in pq.read_table(f, columns=["object_id", "bricks"]).to_pylist()]
    ids = sorted({r["object_id"] for r in rows})
    assert len(objects.objects) == len(ids) == 3
    placed = sorted((b["part"].lower().removesuffix(".dat"), b["colour"]) for r in rows for b in r["bricks"])
    assert sorted((p.part, p.colour) for p in objects.placements) == placed
    assert len(placed) == len(rows)  # a synthetic step places one brick: a row's bricks are its step's
    assert coverage(objects, objects)[0] == 1.0
    # each brick's pose is read too: every part after an object's first sits on studs of the parts before
    from pipelines.realism import connection_directions_and_density, PartShapes

    directions, densities = connection_directions_and_density(objects, PartShapes(reader))
    assert sum(directions.values()) >= sum(len(o) - 1 for o in objects.objects) and len(densities) == 3



def test_connections_are_counted_by_direction_and_objects_by_density(write, tmp_path):
    """Two 2x4 bricks stacked: 8 studs up; the same stack upside down: 8 studs down; a 1x2 plate
    on a bracket's side studs: sideways. A stacked pair is denser than the same two apart."""
    from pipelines.realism import connection_directions_and_density, PartShapes

    reader = get_reader(None)
    shapes = PartShapes(reader)
    flip = "1 0 0 0 -1 0 0 0 -1"
    write("up/a.ldr", "0 a\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n1 1 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    write("down/a.ldr", f"0 a\n1 4 0 0 0 {flip} 3001.dat\n1 1 0 -24 0 {flip} 3001.dat\n")
    write("apart/a.ldr", "0 a\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n1 1 200 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    bracket, plate = shapes("99781"), shapes("3023")
    side = next(c for c in bracket.studs if abs(c.axis[1]) < 0.5)
    socket = next(c for c in plate.sockets if c.axis == (0.0, -1.0, 0.0))
    # turn the plate so that its socket's axis (-y) lies along the side stud's
    a, b = np.array(socket.axis), np.array(side.axis)
    v = np.cross(a, b)
    R = np.eye(3) + _skew(v) + _skew(v) @ _skew(v) / (1 + a @ b)
    t = np.array(side.pos) - R @ np.array(socket.pos)
    m = " ".join(f"{x:.6f}" for x in (*t, *R.ravel()))
    write("side/a.ldr", f"0 a\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 99781.dat\n1 1 {m} 3023.dat\n")
    got = {k: connection_directions_and_density(read_collection(tmp_path / k, reader), shapes)
           for k in ("up", "down", "apart", "side")}
    assert got["up"][0] == {"stud up": 8} and got["down"][0] == {"stud down": 8}
    assert got["apart"][0] == {} and set(got["side"][0]) == {"stud sideways"}
    assert got["up"][1][0] == pytest.approx(got["down"][1][0]) and got["up"][1][0] > 2 * got["apart"][1][0] > 0
    tables = {t.name: t for t in compare(read_collection(tmp_path / "up", reader),
                                           read_collection(tmp_path / "down", reader), reader)}
    assert tables["connection directions"].distance == 1.0 and tables["density"].distance == pytest.approx(0.0)


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


@needs_ldraw
def test_the_json_listing_streams_each_part_as_it_finishes_so_an_interrupted_run_keeps_them(monkeypatch, capsys):
    """`--json` prints a part's line when it is done, not the whole list at the end: a long
    preparation cut short (Ctrl-C while the third part is prepared) keeps the two parts before."""
    import pipelines.prepare
    from pipelines.parts import main

    real, seen = pipelines.prepare.part_status, []

    def status(ldraw, name, prepare, own_parts=False, every=False):
        seen.append(name)
        if len(seen) == 3:
            raise KeyboardInterrupt
        return real(ldraw, name, prepare, own_parts, every)

    monkeypatch.setattr(pipelines.prepare, "part_status", status)
    assert main(["--ldraw", str(LDRAW), "--all", "--json", "--workers", "1", "--no-progress"]) == 130
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["part"] for x in lines] == seen[:2]
    assert all({"category", "usable", "reason", "seconds"} <= set(x) for x in lines)


@needs_ldraw
def test_a_designs_parts_are_prepared_even_those_the_sampler_cannot_use(tmp_path, monkeypatch, capsys):
    """`--designs` lists the library parts a design places; with `--prepare` a tyre (no studs,
    sockets or joint connectors: the sampler cannot use it) gets its collision pieces too, since a
    replay needs them. (The small tyre 30028 decomposes in seconds; the tyre 3641 took minutes.)"""
    from pipelines.parts import main

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path / "cache"))
    design = tmp_path / "pinned.ldr"
    design.write_text("0 pinned\n0 Name: pinned.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n"
                      "1 0 0 -24 0 1 0 0 0 1 0 0 0 1 30028.dat\n1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    assert main(["--ldraw", str(LDRAW), "--designs", str(design), "--json", "--workers", "1", "--no-progress"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [(x["part"], x["reason"]) for x in lines] == [("3001", None), ("30028", NO_CONNECTOR)]
    assert not (tmp_path / "cache" / "coacd").exists()  # listed, not prepared
    assert main(["--ldraw", str(LDRAW), "--designs", str(design), "--prepare", "--json", "--workers", "1",
                 "--no-progress"]) == 0
    assert [json.loads(x)["reason"] for x in capsys.readouterr().out.splitlines()] == [None, NO_CONNECTOR]
    pieces = {p.name for p in (tmp_path / "cache" / "coacd").iterdir()}
    # A fresh process with a fresh cache: the tyre alone, prepared as the sampler would (not at all:
    # it cannot use it), then as a design's part
    env = {**os.environ, "BRICK_FACTORY_CACHE": str(tmp_path / "tyre")}
    assert survey(str(LDRAW), ["30028"])[0].reason == NO_CONNECTOR
    code = ("import sys; from pipelines.prepare import survey; "
            "print(survey(sys.argv[1], ['30028'], prepare=True, every=sys.argv[2] == '1')[0].reason)")
    for every in ("0", "1"):
        out = subprocess.run([sys.executable, "-c", code, str(LDRAW), every], capture_output=True, text=True,
                             cwd=ROOT, env=env)
        assert out.returncode == 0 and out.stdout.strip() == NO_CONNECTOR, out.stderr
        made = {p.name for p in (tmp_path / "tyre" / "coacd").iterdir()} if (tmp_path / "tyre" / "coacd").exists() else set()
        assert bool(made) == (every == "1") and made <= pieces


@needs_ldraw
def test_shards_of_a_library_cover_each_part_once_and_a_bad_shard_is_refused(capsys):
    """`--shard I/N` gives N machines disjoint parts of one library that together are all of it."""
    from pipelines.parts import main

    for which in (["--all"], []):  # every part; the prior's parts, those the library lacks listed too
        assert main(["--ldraw", str(LDRAW), *which, "--json", "--workers", "1", "--no-progress"]) == 0
        whole = [json.loads(x)["part"] for x in capsys.readouterr().out.splitlines()]
        shards = []
        for i in (1, 2, 3):
            assert main(["--ldraw", str(LDRAW), *which, "--json", "--workers", "1", "--no-progress",
                         "--shard", f"{i}/3"]) == 0
            shards.append([json.loads(x)["part"] for x in capsys.readouterr().out.splitlines()])
        assert sorted(sum(shards, [])) == sorted(whole)
        if which:
            assert len(whole) == 312 and all(abs(len(s) - 104) <= 1 for s in shards)
    for bad in ("0/3", "4/3", "2", "a/b"):
        with pytest.raises(SystemExit):
            main(["--ldraw", str(LDRAW), "--all", "--shard", bad])
        assert "expected I/N with 1 <= I <= N" in capsys.readouterr().err


def test_preparing_over_several_workers_gives_each_one_numeric_thread(monkeypatch):
    """coacd, run by each worker, starts a thread per core unless told otherwise (OpenMP's
    default), in every worker at once. Each worker (and the coacd child it starts, which inherits
    its environment) gets one."""
    import pipelines.prepare
    from pipelines.prepare import PartStatus
    from pipelines.workers import ONE_THREAD

    saved = {k: os.environ.pop(k, None) for k in ONE_THREAD}
    monkeypatch.setattr(pipelines.prepare, "part_status",  # forked workers see this one
                        lambda ldraw, name, *a: PartStatus(name, os.environ.get("OMP_NUM_THREADS", "unset"), None))
    try:
        assert {s.category for s in survey(None, ["3001", "3002", "3003"], n_workers=2)} == {"1"}
        assert "OMP_NUM_THREADS" not in os.environ  # this process keeps its own
    finally:
        for k, v in saved.items():
            os.environ.pop(k, None)
            if v is not None:
                os.environ[k] = v
