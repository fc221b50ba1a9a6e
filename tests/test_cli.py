"""The command line the acceptance checks call: JSON out, one-line errors, non-zero exit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ldraw_support import LDRAW, MODELS, needs_ldraw

ROOT = Path(__file__).resolve().parents[1]


def run(*args, env_extra=None):
    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    env.update(env_extra or {})
    return subprocess.run(
        [sys.executable, "-m", "factory.ldraw", *args], cwd=ROOT, capture_output=True, text=True, env=env, timeout=120
    )


@needs_ldraw
def test_steps_json_lines():
    out = run("steps", str(MODELS / "car.ldr"), "--ldraw", str(LDRAW), "--json")
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["step"] for r in rows] == list(range(len(rows)))
    assert set(rows[0]) == {"step", "assembly", "parts"}
    assert set(rows[0]["parts"][0]) == {"part", "color", "R", "T"}


@needs_ldraw
def test_part_json_from_ldrawdir():
    out = run("part", "3001", "--json", env_extra={"LDRAWDIR": str(LDRAW)})
    assert out.returncode == 0, out.stderr
    part = json.loads(out.stdout)
    assert {"part", "bbox_ldu", "volume_ldu3", "mass_g", "studs", "sockets", "symmetry"} <= set(part)
    assert part["part"] == "3001.dat" and len(part["studs"]) == 8 and len(part["sockets"]) == 11
    assert part["symmetry"] == {"order": 2, "continuous_axis": None}


def test_embedded_library_is_used_without_ldraw():
    out = run("part", "3001.dat", "--json")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["bbox_ldu"] == [[-40, -4, -20], [40, 24, 20]]


@pytest.mark.parametrize(
    "content, expected",
    [
        ("1 4 0 0 0 1 0 0 0 1 0 0 0 1 nosuchpart.dat\n", "bad.ldr:2: cannot find 'nosuchpart.dat'"),
        ("1 4 0 0 0 1 0 0 0 1 0 0\n", "bad.ldr:2: type 1 (reference) needs"),
        ("1 4 0 0 0 1 0 0 0 1 0 0 0 1 ../../etc/passwd\n", "bad.ldr:2: reference '../../etc/passwd'"),
        (b"\x00\x01\x02binary", "binary data"),
    ],
)
@pytest.mark.slow
def test_bad_input_is_one_line_error_and_nonzero_exit(tmp_path, content, expected):
    bad = tmp_path / "bad.ldr"
    if isinstance(content, bytes):
        bad.write_bytes(content)
    else:
        bad.write_text("0 Bad model\n" + content)
    out = run("steps", str(bad), "--json")
    assert out.returncode != 0
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0]
    assert "Traceback" not in out.stderr


def test_missing_model_and_unknown_part(tmp_path):
    out = run("steps", str(tmp_path / "none.ldr"))
    assert out.returncode != 0 and "does not exist" in out.stderr
    out = run("part", "30011")
    assert out.returncode != 0 and "cannot find '30011.dat'" in out.stderr and "did you mean" in out.stderr


def test_bad_library_folder(tmp_path):
    out = run("part", "3001", "--ldraw", str(tmp_path))
    assert out.returncode != 0 and "is not an LDraw library" in out.stderr


@pytest.mark.parametrize("name, content", [
    ("empty.ldr", "0 an empty model\n0 STEP\n"),
    ("empty-main.mpd", "0 FILE main.ldr\n0 nothing here\n0 FILE b.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n"),
])
@pytest.mark.slow
def test_a_model_that_places_no_parts_is_an_error(tmp_path, name, content):
    path = tmp_path / name
    path.write_text(content)
    for cmd in ([sys.executable, "-m", "factory.ldraw", "steps", str(path)],
                [sys.executable, "-m", "pipelines.verify", str(path)]):
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and name in lines[0] and "places no parts" in lines[0], r.stderr


# -- the console script ------------------------------------------------------------------------------


def test_console_script_lists_commands_and_refuses_unknown_ones(capsys):
    from pipelines.commands import COMMANDS, main

    assert main([]) == 2 and "commands:" in capsys.readouterr().out
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {name} " in out for name in COMMANDS)
    assert main(["synthesise"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'synthesise'" in err and "synth" in err and err.count("\n") == 1


@pytest.mark.slow
def test_console_script_runs_each_command_as_its_module():
    """`brick-factory NAME ARGS` is `python -m MODULE ARGS`: same output, same exit status."""
    from pipelines.commands import COMMANDS

    env = {k: v for k, v in os.environ.items() if k != "LDRAWDIR"}
    for name in ("ldraw", "score", "verify"):
        module = COMMANDS[name][0]
        via = subprocess.run([sys.executable, "-m", "pipelines.commands", name, "--help"], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=120)
        direct = subprocess.run([sys.executable, "-m", module, "--help"], cwd=ROOT, env=env, capture_output=True,
                                text=True, timeout=120)
        assert via.returncode == direct.returncode == 0 and via.stdout.split("\n", 1)[1] == direct.stdout.split("\n", 1)[1]
    bad = subprocess.run([sys.executable, "-m", "pipelines.commands", "score", "--data", "/nonexistent", "--pred", "x"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "not a dataset folder" in bad.stderr
