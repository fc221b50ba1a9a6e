"""Parts a model ships itself (a `0 FILE x.dat` block of its MPD, or a file beside it) are found by
every stage as `build_steps` found them: the model's MPD blocks, its folder, then the library
(issue 19, item 3). Embedded library only: no --ldraw, no LDRAWDIR."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from factory.ldraw import build_steps
from factory.parts import LDU_CM, load_part

ROOT = Path(__file__).resolve().parents[1]

# An unofficial part: the embedded 2 x 4 brick with a flat roof 2 LDU above its studs (y = -30),
# so its box (54 LDU tall) is not the 3001's (28 LDU).
MYBRICK = (
    "0 Unofficial brick 2 x 4 with a roof\n0 Name: mybrick.dat\n0 !LDRAW_ORG Unofficial_Part\n"
    "1 16 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n"
    "4 16 -40 -30 -20 40 -30 -20 40 -30 20 -40 -30 20\n"
)
MAIN = (
    "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n"
    "1 1 0 -24 0 1 0 0 0 1 0 0 0 1 mybrick.dat\n0 STEP\n"
)
LOCAL_BBOX = [[-40, -30, -20], [40, 24, 20]]


def _mpd(write, name="packed.mpd", part="mybrick.dat", text=MYBRICK, main=MAIN):
    return write(name, f"0 FILE main.ldr\n0 Main\n{main}0 NOFILE\n0 FILE {part}\n{text}0 NOFILE\n")


def _beside(write, name="beside/model.ldr", part="mybrick.dat", text=MYBRICK, main=MAIN):
    write(str(Path(name).parent / part), text)
    return write(name, f"0 Main\n{main}")


LAYOUTS = {"mpd": _mpd, "folder": _beside}


def _env():
    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True,
                          env=_env(), timeout=timeout)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_placed_model_part_loads_as_build_steps_found_it(layout, write, embedded_reader):
    path = LAYOUTS[layout](write)
    steps = build_steps(embedded_reader, embedded_reader.open_model(path))
    placed = steps[1].parts[0]
    assert placed.part == "mybrick.dat" and placed.model == str(path)
    assert steps[0].parts[0].model is None  # the library's 3001
    part = load_part(embedded_reader, placed)
    assert part.name == "mybrick.dat"
    assert np.allclose(part.bbox, LOCAL_BBOX)
    # by name alone it is not a library part
    with pytest.raises(Exception, match="cannot find 'mybrick.dat'"):
        load_part(embedded_reader, "mybrick")


@pytest.mark.parametrize("layout", LAYOUTS)
def test_verify_finds_the_models_own_part(layout, write):
    path = LAYOUTS[layout](write)
    r = _cli("pipelines.verify", str(path), "--json")
    assert r.returncode == 0, r.stderr
    recs = [json.loads(line) for line in r.stdout.splitlines()]
    assert [x["part"] for x in recs] == ["3001.dat", "mybrick.dat"]
    assert recs[1]["connected"] and not recs[1]["collision"]


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_render_finds_the_models_own_part(layout, write, tmp_path):
    """`pipelines.render` refused a step placing the model's own part ("cannot find 'mybrick.dat'"):
    its feedback image drew the part again without saying whose it was."""
    path = LAYOUTS[layout](write)
    r = _cli("pipelines.render", str(path), "--step", "1", "--out", str(tmp_path / "out"), "--size", "64",
             "--tile", "32")
    assert r.returncode == 0, r.stderr
    meta = json.loads((tmp_path / "out" / "step.json").read_text())
    assert [p["part"] for p in meta["parts"]] == ["mybrick.dat"] and (tmp_path / "out" / "feedback.png").is_file()


def test_designs_finds_the_models_own_part(write, tmp_path):
    import pyarrow.parquet as pq

    paths = [_mpd(write), _beside(write)]
    out = tmp_path / "out"
    r = _cli("pipelines.designs", *map(str, paths), "--out", str(out), "--size", "64", "--tile", "32")
    assert r.returncode == 0, r.stderr
    rows = [row for f in sorted((out / "data").glob("*.parquet")) for row in pq.read_table(f).to_pylist()]
    assert sorted(row["object_id"] for row in rows) == ["model", "model", "packed", "packed"]
    for row in rows:
        (brick,) = row["bricks"]
        if brick["part"] == "mybrick.dat":
            # the local definition's size, not some other part's
            assert brick["size_cm"] == pytest.approx([80 * LDU_CM, 54 * LDU_CM, 40 * LDU_CM])
            assert row["step_index"] == 1
        else:
            assert brick["part"] == "3001.dat"
            assert brick["size_cm"] == pytest.approx([80 * LDU_CM, 28 * LDU_CM, 40 * LDU_CM])


@pytest.mark.parametrize("layout", LAYOUTS)
def test_model_part_shadowing_a_library_part_stays_with_its_model(layout, write, embedded_reader):
    # The model ships its own '3001.dat' (a 2 x 2 brick with a roof); another model, and a plain
    # load by name, still get the library's 2 x 4 brick, whichever is loaded first.
    own = ("0 Not the real 3001\n0 Name: 3001.dat\n0 !LDRAW_ORG Unofficial_Part\n"
           "1 16 0 0 0 1 0 0 0 1 0 0 0 1 3003.dat\n4 16 -20 -30 -20 20 -30 -20 20 -30 20 -20 -30 20\n")
    main = "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n"
    library = load_part(embedded_reader, "3001")
    lib_box = np.array(library.bbox)
    shadowing = LAYOUTS[layout](write, name=f"{layout}/shadow.{'mpd' if layout == 'mpd' else 'ldr'}",
                                part="3001.dat", text=own, main=main)
    other = write("other/plain.ldr", "0 Plain\n" + main)

    (step,) = build_steps(embedded_reader, embedded_reader.open_model(shadowing))
    (placed,) = step.parts
    assert placed.model == str(shadowing)
    mine = load_part(embedded_reader, placed)
    assert mine is not library and np.allclose(mine.bbox, [[-20, -30, -20], [20, 24, 20]])

    (step,) = build_steps(embedded_reader, embedded_reader.open_model(other))
    (placed,) = step.parts
    assert placed.model is None
    assert load_part(embedded_reader, placed) is library
    assert load_part(embedded_reader, "3001.dat") is library
    assert np.allclose(load_part(embedded_reader, "3001").bbox, lib_box)
