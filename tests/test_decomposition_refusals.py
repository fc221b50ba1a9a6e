"""A decomposition refused once (past its time or memory limit) is not tried again under the same
limits, and the part gets its convex hull's pieces instead of being left out."""

from __future__ import annotations

import pytest


def test_a_refused_decomposition_is_kept_and_not_tried_again_under_the_same_limits(monkeypatch, tmp_path):
    """A part whose decomposition ran past its limit (LDraw's 2573 took more than 300 s here) cost
    that time again in every process that met it, and stopped a run of the prior's parts; the
    refusal is kept in the cache and not tried again until a wider limit is set. Meanwhile the
    part has its hull's pieces (LDraw's dome 24947, with studs, and 3 wheels were left out of
    every library so)."""
    import json

    import numpy as np

    from factory.ldraw import Library, Reader
    from factory.parts import load_part
    from factory.physics import decompose, geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.05")
    monkeypatch.setattr(decompose, "_faithful_pieces", lambda part, cfg: None)  # the way to coacd
    part = lambda: load_part(Reader(Library.embedded()), "3001")  # noqa: E731 (a fresh part: nothing in memory)
    first = geometry.collision_shape(part())
    (kept,) = (p for p in (tmp_path / "coacd").glob("*.json") if not p.name.endswith(".slow.json"))
    assert "more than 0.05 s" in json.loads(kept.read_text())["message"]
    # The hull's pieces: inside the brick's box, filling it but for its open underside.
    lo, hi = np.array([-40.0, -0.01, -20.0]), np.array([40.0, 24.01, 20.0])
    assert first.body and all(((p >= lo) & (p <= hi)).all() for p in first.body)
    real = decompose._decompose
    monkeypatch.setattr(decompose, "_decompose", lambda *a, **k: pytest.fail("a decomposition was started"))
    again = geometry.collision_shape(part())
    assert again.key == first.key and all(np.array_equal(a, b) for a, b in zip(again.body, first.body))
    tried = []
    monkeypatch.setattr(decompose, "_decompose", lambda *a, **k: tried.append(1) or real(*a, **k))
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.1")  # a wider limit tries again
    geometry.collision_shape(part())
    assert len(tried) == 2 and "more than 0.1 s" in json.loads(kept.read_text())["message"]


@pytest.mark.slow
def test_a_decomposition_past_its_time_limit_is_tried_again_at_coarser_settings(monkeypatch, tmp_path):
    """LDraw's 6061, 48169 and 4746 took more than 300 s at the default settings and were left out
    of every library; a decomposition that runs past its limit is tried again at `COARSE`
    settings, and only if that runs past the limit too does the part get its hull's pieces."""
    from factory.errors import LDrawLimitError
    from factory.ldraw import Library, Reader
    from factory.parts import load_part
    from factory.physics import decompose, geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    monkeypatch.setattr(decompose, "_faithful_pieces", lambda part, cfg: None)  # the way to coacd
    real, tried = decompose._decompose, []

    def slow_at_defaults(vertices, faces, cfg, name=""):
        tried.append(cfg.preprocess_resolution)
        if cfg.preprocess_resolution != decompose.COARSE["preprocess_resolution"]:
            raise decompose.DecompositionTooSlow(f"decomposing {name} took more than 300 s", name)
        return real(vertices, faces, cfg, name)

    monkeypatch.setattr(decompose, "_decompose", slow_at_defaults)
    shape = geometry.collision_shape(load_part(Reader(Library.embedded()), "3001"))
    assert tried == [50, 30] and len(shape.body) >= 1
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.01")  # real coacd, too slow both times
    monkeypatch.setattr(decompose, "_decompose", real)
    brick = load_part(Reader(Library.embedded()), "3003")
    with pytest.raises(LDrawLimitError, match=r"more than 0.01 s of CPU time; .*again at coarser settings: "
                                              r".*more than 0.01 s of CPU time"):
        decompose._decomposed(brick, *decompose._body_mesh(brick), decompose.DecompositionConfig())
    assert geometry.collision_shape(load_part(Reader(Library.embedded()), "3003")).body  # its hull's pieces


def test_the_limit_is_cpu_time_not_wall_time(tmp_path):
    """A child waiting (a busy machine: it is not run) is not stopped at the limit, only at
    `WALL_FACTOR` times it; a child computing is stopped once its CPU time passes the limit."""
    import sys
    import time

    from factory.physics import decompose

    with open(tmp_path / "err", "w") as err:
        t = time.monotonic()
        assert decompose._run_limited([sys.executable, "-c", "import time; time.sleep(1.0)"], err, 0.6) == 0
        assert time.monotonic() - t >= 1.0
        t = time.monotonic()
        assert decompose._run_limited([sys.executable, "-c", "while True: pass"], err, 0.6) is None
        assert time.monotonic() - t < decompose.WALL_FACTOR * 0.6


def test_the_faithfulness_test_walks_its_sample_grid_in_chunks_with_the_same_answers(monkeypatch, real_reader):
    """A raised 32x32 baseplate's hull holds about 20 million sample points: tested at once they
    took more than 15 GB and the preparation of LDraw's library was killed for memory. The grid is
    walked in chunks; the answers do not depend on the chunk's size."""
    import numpy as np

    from factory.parts import load_part
    from factory.physics import decompose, faithful

    cfg = decompose.DecompositionConfig()
    cases = []
    for name in ("99781", "3062b", "4070", "3001"):  # bracket, round brick, headlight brick, brick
        part = load_part(real_reader, name)
        test = faithful._faithfulness(part, cfg)
        body = part.flat.triangles[~part.flat.in_stud].reshape(-1, 3)
        lo, hi = body.min(0), body.max(0)
        halves = [body[body[:, 0] <= (lo[0] + hi[0]) / 2], body[body[:, 1] <= (lo[1] + hi[1]) / 2], body]
        cases += [(test, h) for h in halves if len(h) >= 4]
    whole = [test.escapes(points) for test, points in cases]
    monkeypatch.setattr(faithful, "SAMPLE_CHUNK", 4096)
    assert [test.escapes(points) for test, points in cases] == whole
    assert True in whole and False in whole


def test_a_refusal_kept_before_the_coarser_try_existed_is_tried_again(monkeypatch, tmp_path):
    """A cache packed on another machine held refusals made with one try only (LDraw's wheel
    18976, past 300 s): kept as they were, they stopped the coarser second try for good. A kept
    refusal names the settings of its second try, and its message no file in front (the error
    names the file where it is read)."""
    import json

    from factory.ldraw import Library, Reader
    from factory.parts import load_part
    from factory.physics import decompose, geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "0.05")
    monkeypatch.setattr(decompose, "_faithful_pieces", lambda part, cfg: None)  # the way to coacd
    part = lambda: load_part(Reader(Library.embedded()), "3001")  # noqa: E731
    geometry.collision_shape(part())
    (kept,) = (p for p in (tmp_path / "coacd").glob("*.json") if not p.name.endswith(".slow.json"))
    record = json.loads(kept.read_text())
    assert record["coarse"] == decompose.COARSE and record["message"].startswith("decomposing")  # no file before
    del record["coarse"]  # as a refusal was kept before the second try existed
    kept.write_text(json.dumps(record))
    for marker in (tmp_path / "coacd").glob("*.slow.json"):  # nor was a first try's end kept then
        marker.unlink()
    tried = []
    real = decompose._decompose
    monkeypatch.setattr(decompose, "_decompose", lambda *a, **k: tried.append(1) or real(*a, **k))
    geometry.collision_shape(part())
    assert len(tried) == 2  # tried again, both ways
    assert json.loads(kept.read_text())["coarse"] == decompose.COARSE


_TWO_MAKERS = """
import sys, time
from pathlib import Path
from factory.ldraw import Library, Reader
from factory.parts import load_part
from factory.physics import decompose, geometry

decompose._faithful_pieces = lambda part, cfg: None  # the way to coacd
real = decompose._decompose
def counted(*args, **kwargs):
    with open(sys.argv[1], "a") as f:
        f.write("coacd\\n")
    time.sleep(0.5)  # the other process asks meanwhile
    return real(*args, **kwargs)
decompose._decompose = counted
part = load_part(Reader(Library.embedded()), "3001")
while not Path(sys.argv[2]).exists():
    time.sleep(0.01)
print(len(geometry.collision_shape(part).body))
"""


def test_two_processes_needing_one_part_decompose_it_once(tmp_path):
    """Parts are decomposed where a sampler's worker first draws them, so two workers can meet one
    uncached part at once: the second waits for the first's pieces instead of running coacd again
    (minutes for some parts)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    # coacd refuses at once (a tiny CPU limit, its coarse try too): the part's hull pieces.
    env = {**os.environ, "BRICK_FACTORY_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(root),
           "BRICK_FACTORY_COACD_SECONDS": "0.05"}
    count, go = tmp_path / "count", tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", _TWO_MAKERS, str(count), str(go)], env=env, cwd=root,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    go.write_text("")
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err for _, err in outs]
    assert outs[0][0] == outs[1][0] and int(outs[0][0]) > 0  # the same pieces
    assert count.read_text().splitlines() == ["coacd"] * 2  # one process's two tries, not four


def test_a_run_cut_during_the_coarser_try_resumes_at_it(monkeypatch, tmp_path):
    """A part whose first try runs past its limit and whose coarser try is then cut (a lent
    machine's run ends; LDraw's 23421, 18976 and 44292 were cut so at every call of a library's
    preparation, each starting again at the first try) resumes at the coarser try, with the pieces
    an uncut run gives. A wider limit tries the first again."""
    import numpy as np

    from factory.ldraw import Library, Reader
    from factory.parts import load_part
    from factory.physics import decompose, geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path / "cut"))
    monkeypatch.setattr(decompose, "_faithful_pieces", lambda part, cfg: None)  # the way to coacd
    real, tried = decompose._decompose, []

    def slow_at_defaults(vertices, faces, cfg, name="", cut=False):
        coarse = cfg.preprocess_resolution == decompose.COARSE["preprocess_resolution"]
        tried.append("coarse" if coarse else "first")
        if not coarse:
            raise decompose.DecompositionTooSlow(f"decomposing {name} took more than 300 s", name)
        if cut:
            raise KeyboardInterrupt  # the run is stopped here
        return real(vertices, faces, cfg, name)

    part = lambda: load_part(Reader(Library.embedded()), "3001")  # noqa: E731 (a fresh part: nothing in memory)
    monkeypatch.setattr(decompose, "_decompose", lambda *a: slow_at_defaults(*a, cut=True))
    with pytest.raises(KeyboardInterrupt):
        geometry.collision_shape(part())
    assert tried == ["first", "coarse"]
    monkeypatch.setattr(decompose, "_decompose", slow_at_defaults)
    resumed = geometry.collision_shape(part())
    assert tried == ["first", "coarse", "coarse"] and resumed.body

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path / "whole"))  # the same part, never cut
    whole = geometry.collision_shape(part())
    assert tried[3:] == ["first", "coarse"]
    assert len(whole.body) == len(resumed.body) and all(np.array_equal(a, b) for a, b in zip(whole.body, resumed.body))

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path / "wider"))
    monkeypatch.setattr(decompose, "_decompose", lambda *a: slow_at_defaults(*a, cut=True))
    with pytest.raises(KeyboardInterrupt):
        geometry.collision_shape(part())
    monkeypatch.setenv("BRICK_FACTORY_COACD_SECONDS", "600")  # wider than the first try ran under
    monkeypatch.setattr(decompose, "_decompose", slow_at_defaults)
    geometry.collision_shape(part())
    assert tried[5:] == ["first", "coarse", "first", "coarse"]
