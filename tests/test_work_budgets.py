"""Hostile input the readers accept but the checks could not finish (issue: hostile input): socket
finding's work budget, a flat part in verify, verify's parts budget. Budgets are proven on scaled
down inputs with the constant lowered, never on a real bomb."""

from __future__ import annotations

import json

import numpy as np
import pytest

import factory.connections as connections
from factory.errors import LDrawLimitError
from factory.ldraw import Library, Reader
from factory.parts import load_part


def _grid_part(k: int, levels: int) -> str:
    """A part of k x k stud cells, each with a downward rim and a wall, at `levels` heights."""
    out = ["0 Hostile grid\n0 Name: grid.dat\n0 !LDRAW_ORG Unofficial_Part\n"]
    for level in range(levels):
        y = -4.0 * level
        for i in range(k):
            for j in range(k):
                x, z = i * 20.0, j * 20.0
                out.append(f"4 16 {x-10} {y} {z-10} {x+10} {y} {z-10} {x+10} {y} {z-9} {x-10} {y} {z-9}\n")
                out.append(f"4 16 {x-10} {y} {z-10} {x-10} {y-4} {z-10} {x+10} {y-4} {z-10} {x+10} {y} {z-10}\n")
    return "".join(out)


def test_socket_finding_past_its_budget_is_refused_naming_the_file(mini_library, monkeypatch):
    path = mini_library / "parts" / "grid.dat"
    path.write_text(_grid_part(3, 2))
    monkeypatch.setattr(connections, "MAX_SOCKET_WORK", 100)
    part = load_part(Reader(Library.from_dir(mini_library)), "grid.dat")
    with pytest.raises(LDrawLimitError) as err:
        part.sockets
    assert str(path) in str(err.value) and "100 ray-triangle tests" in str(err.value)


def test_part_command_refuses_it_in_one_line(mini_library, monkeypatch, capsys):
    from factory.ldraw.__main__ import main

    (mini_library / "parts" / "grid.dat").write_text(_grid_part(3, 2))
    monkeypatch.setattr(connections, "MAX_SOCKET_WORK", 100)
    assert main(["part", "grid.dat", "--ldraw", str(mini_library)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "grid.dat" in err[0] and "refusing" in err[0]


def test_ray_casts_go_in_bounded_chunks_with_the_same_answer(monkeypatch, embedded_reader):
    tris = load_part(embedded_reader, "3001").flat.triangles
    whole = connections.find_sockets(tris)
    seen = []
    inner = connections._first_hits

    def spy(t, o, d):
        seen.append(len(t) * len(o))
        return inner(t, o, d)

    monkeypatch.setattr(connections, "CHUNK_PAIRS", 64)
    monkeypatch.setattr(connections, "_first_hits", spy)
    assert connections.find_sockets(tris) == whole and len(whole) > 0
    assert seen and max(seen) <= 64


def test_first_hits_chunked_equals_unchunked(monkeypatch):
    rng = np.random.default_rng(0)
    tris = rng.uniform(-10, 10, (300, 3, 3))
    origins = rng.uniform(-10, 10, (20, 3))
    dirs = rng.normal(size=(20, 3))
    full = connections._first_hits(tris, origins, dirs)
    monkeypatch.setattr(connections, "CHUNK_PAIRS", 50)
    assert np.array_equal(connections.first_hits(tris, origins, dirs), full)


FLAT = ("0 Flat thing\n0 Name: flat.dat\n0 !LDRAW_ORG Unofficial_Part\n"
        "3 16 -40 0 -20 40 0 -20 40 0 20\n3 16 -40 0 -20 40 0 20 -40 0 20\n")


def test_verify_reports_a_part_with_no_volume_and_goes_on(write, capsys, isolated_cache):
    """A flat part (a sticker in a real design) is reported as not checked and left out of the
    structure; the model's other parts are judged as without it, and verify ends normally."""
    from pipelines.verify import main

    path = write("flat.mpd", "0 FILE main.ldr\n0 Main\n1 1 0 0 0 1 0 0 0 1 0 0 0 1 flat.dat\n0 STEP\n"
                 "1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"
                 "1 4 100 0 0 1 0 0 0 1 0 0 0 1 flat.dat\n1 4 100 -5 0 1 0 0 0 1 0 0 0 1 flat.dat\n0 STEP\n"
                 "1 4 0 -48 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"
                 f"0 NOFILE\n0 FILE flat.dat\n{FLAT}0 NOFILE\n")
    assert main([str(path), "--json", "--faults"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    lines = [json.loads(line) for line in out.splitlines()]
    plain = [r for r in lines if "fault" not in r and "summary" not in r]
    assert [(r["part"], r["reason"]) for r in plain] == [
        ("flat.dat", "no-volume"), ("3001.dat", None), ("flat.dat", "no-volume"), ("flat.dat", "no-volume"),
        ("3001.dat", None)]
    # The second brick is judged on the first: connected, as if the stickers were not there.
    assert plain[-1]["connected"] and plain[-1]["connections"] > 0
    summary = lines[-1]["summary"]
    assert summary["no_volume"] == 3 and summary["accepted"] == 2 and summary["fidelity"] == 1.0


def _nested(levels: int, fan: int) -> str:
    """An MPD whose every submodel places the next `fan` times: fan ** levels bricks."""
    out = []
    for i in range(levels):
        child = f"m{i + 1}.ldr" if i + 1 < levels else "3001.dat"
        out.append(f"0 FILE m{i}.ldr\n0 m{i}\n" + "".join(
            f"1 16 {20 * k} 0 0 1 0 0 0 1 0 0 0 1 {child}\n" for k in range(fan)) + "0 NOFILE\n")
    return "".join(out)


def test_verify_refuses_a_model_past_its_parts_budget_up_front(write, capsys, monkeypatch):
    import factory.replay as replay
    import pipelines.verify as verify

    path = write("nested.mpd", _nested(3, 4))  # 64 bricks
    monkeypatch.setattr(replay, "MAX_VERIFY_PARTS", 50)
    monkeypatch.setattr(replay, "build_steps", lambda *a, **k: pytest.fail("expanded before refusing"))
    assert verify.main([str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "64 parts" in err[0] and "at most 50" in err[0], err


def _box_mesh():
    v = np.array([[x, y, z] for x in (0.0, 40.0) for y in (0.0, 24.0) for z in (0.0, 20.0)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def test_coacd_runs_bounded_in_a_child_and_gives_its_own_pieces(monkeypatch):
    """coacd (native code) ran in the checking process with no bound: a soup of 12,000 random
    triangles ran past 200 s, one of 1.2 million was killed for memory at 24 GB. It runs in a child
    under a time and a memory limit (scaled down here), with the pieces coacd gives in-process."""
    import coacd

    from factory.errors import LDrawLimitError
    from factory.physics import decompose

    v, f = _box_mesh()
    cfg = decompose.DecompositionConfig()
    pieces = decompose._decompose(v, f, cfg, "box.dat")
    coacd.set_log_level("error")
    ref = coacd.run_coacd(coacd.Mesh(v, f), threshold=cfg.threshold, max_convex_hull=cfg.max_convex_hull,
                          preprocess_mode="auto", preprocess_resolution=cfg.preprocess_resolution,
                          mcts_iterations=cfg.mcts_iterations, mcts_nodes=cfg.mcts_nodes,
                          mcts_max_depth=cfg.mcts_max_depth, seed=cfg.seed)
    assert len(pieces) == len(ref) >= 1
    assert all(np.array_equal(np.asarray(a, float), b) for (a, _), b in zip(ref, pieces))
    monkeypatch.setattr(decompose, "COACD_SECONDS", 0.01)
    with pytest.raises(LDrawLimitError, match=r"box.dat: decomposing box.dat \(12 triangles\).*more than 0.01 s"):
        decompose._decompose(v, f, cfg, "box.dat")
    # The environment's limit wins over the module's, and is named in the refusal.
    monkeypatch.setattr(decompose, "COACD_SECONDS", 60)
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.02")
    with pytest.raises(LDrawLimitError, match=r"more than 0.02 s of CPU time; .*BRICK_FACTORY_COACD_SECONDS=SECONDS"):
        decompose._decompose(v, f, cfg, "box.dat")
    for bad in ("soon", "0", "-5", "inf", "nan"):
        monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", bad)
        with pytest.raises(ValueError, match=f"BRICK_FACTORY_COACD_SECONDS must be a number of seconds > 0, got '{bad}'"):
            decompose._decompose(v, f, cfg, "box.dat")
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "60")
    assert len(decompose._decompose(v, f, cfg, "box.dat")) == len(pieces)
    monkeypatch.delenv("BRICK_FACTORY_COACD_SECONDS")
    monkeypatch.setattr(decompose, "COACD_MEMORY_BYTES", 32 << 20)  # too little to start Python with numpy
    with pytest.raises(LDrawLimitError, match="failed within 32 MB of memory"):
        decompose._decompose(v, f, cfg, "box.dat")


def test_collision_geometry_refuses_a_part_past_its_triangle_budget(monkeypatch, tmp_path):
    """A part of 1.2 million triangles (under the reader's 2,000,000 cap) was killed for memory at
    24 GB in `pipelines.verify`, inside the collision decomposition: parts past
    `MAX_COLLISION_TRIANGLES` are refused by the physics, naming the part (a scaled-down budget)."""
    from factory.physics import geometry

    part = load_part(Reader(Library.embedded()), "3001.dat")
    monkeypatch.setattr(geometry, "MAX_COLLISION_TRIANGLES", 10)
    with pytest.raises(LDrawLimitError, match=r"part 3001.dat has [\d,]+ triangles outside its studs; .* at most 10"):
        geometry.collision_shape(part, geometry.DecompositionConfig(inset_ldu=0.25 + 1e-9))  # not memoised



def test_a_part_past_the_triangle_budget_is_listed_unusable_without_decomposing_it(monkeypatch):
    """Whether a part can be used is known before its collision pieces are made (they are made where
    it is first drawn): a part past `MAX_COLLISION_TRIANGLES` is left out with that reason, so a
    sampler never meets it mid-growth."""
    from factory.physics import geometry
    from factory.prior.choose import TOO_MANY_TRIANGLES, why_unusable

    reader = Reader(Library.embedded())
    assert why_unusable(reader, "3001.dat") is None
    monkeypatch.setattr(geometry, "MAX_COLLISION_TRIANGLES", 10)
    reason = why_unusable(reader, "3001.dat")
    assert reason.startswith(TOO_MANY_TRIANGLES) and "at most 10" in reason
