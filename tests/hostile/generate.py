"""Write the hostile-input corpus into a folder: `python tests/hostile/generate.py OUT [--quick]`.

Layout written under OUT:

  ldraw/        an LDraw library: the embedded default library's files (real bricks, stud
                primitives, LDConfig.ldr) plus the hostile parts and primitives below
  models/       one model file per case (`<case>.ldr` or `.mpd`)
  outside/      a file outside the library, for the `..` and symbolic link cases

Every file is small except the ones a case is about (the 50 MB line, the 200,000-triangle part,
the 20,000-part model), and those are generated here, never committed; the million-triangle part
is a few nested lines. The bombs are written as
a few lines that nest, sized just past the product's caps (`MAX_MODEL_PARTS`, `MAX_EDGES`,
`MAX_TRIANGLES`, `MAX_DEPTH`) so that a product that counts before expanding refuses them at once.

`generate(out)` returns {case name: model path}; `CASES` lists every case with one line on what it
is, in the order the runner runs them; `QUICK` is the subset the test suite runs.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
from pathlib import Path

ID = "1 0 0 0 1 0 0 0 1"
"""An identity placement matrix as an LDraw type 1 line writes it."""

CASES: dict[str, str] = {
    "cycle": "a part that references a part that references the first (a -> b -> a)",
    "self_cycle": "a part that references itself",
    "mpd_cycle": "MPD submodels that place each other",
    "mpd_bomb": "MPD: 6 nested submodels each placing the next 10 times (10^6 parts, cap 200,000)",
    "deep_nesting": "MPD: 100 submodels each placing the next once (past MAX_DEPTH 64)",
    "edge_bomb": "a part whose nested primitives expand to 10^7 edge lines (cap 4,000,000)",
    "triangle_bomb": "a part whose nested primitives expand to 10^7 triangles (cap 2,000,000)",
    "long_line_50mb": "a model file of one 50 MB line",
    "long_line_1mb": "a model file with a 1 MB comment line (under the file size cap)",
    "long_line_part": "a model placing a part with a 1 MB line",
    "binary_model": "a model file of random bytes",
    "binary_part": "a model placing a part of random bytes",
    "nan_position": "a placement at x = nan",
    "inf_matrix": "a placement matrix with inf in it",
    "huge_coord": "a placement at x = 1e300",
    "nan_vertex_part": "a model placing a part with a nan triangle vertex",
    "dotdot_ref": "a reference to ../../outside/secret.dat",
    "absolute_ref": "a reference to /etc/passwd",
    "drive_ref": "a reference to C:\\secret.dat",
    "symlink_library": "a library part that is a symbolic link to a file outside the library",
    "symlink_model_folder": "a file in the model's folder that is a symbolic link outside it",
    "zero_matrix": "a part placed by the zero matrix",
    "rank_deficient": "a part placed by a rank-1 matrix",
    "scaled": "a part placed by a matrix scaling it by 2",
    "sheared": "a part placed by a shearing matrix",
    "mirrored": "a part placed by a mirroring matrix (determinant -1)",
    "flat_part": "a part whose triangles all lie in one plane (zero volume), with a brick on it",
    "empty_model": "a model file of zero bytes",
    "comments_only": "a model of comments and STEPs only",
    "mpd_empty_main": "an MPD whose main block is empty (the parts are in a later block)",
    "mpd_part_inside": "an MPD that defines a part in its own blocks and places it",
    "missing_part": "a model placing a part missing from the library",
    "syntax_garbage": "truncated and unknown line types",
    "huge_colour": "a part placed in colour 10^40",
    "unknown_colour": "a part placed in colour 600 (in no LDConfig.ldr, not a direct colour)",
    "many_triangles": "two stacked copies of a part of about 200,000 triangles",
    "million_triangles": "a part of 1,000,000 triangles (50 nested grids of 20,000; a small file)",
    "many_parts": "a model of 20,000 bricks (50 layers of 20 x 20, one STEP per layer)",
}

LAYER_COLOURS = (1, 2, 4, 5, 14, 15, 0, 7, 8, 10, 19, 25, 27, 28)
"""The many_parts layers' colours: codes of the embedded library's LDConfig.ldr (a code it lacks is
an input error, which is another case)."""

QUICK = ("cycle", "mpd_bomb", "edge_bomb", "binary_model", "mirrored", "missing_part", "huge_colour")
"""The subset `run.py --quick` (and tests/test_hostile.py) runs: each refused before expanding."""


def _line(colour: int, pos: tuple[float, float, float], matrix: str, name: str) -> str:
    return f"1 {colour} {pos[0]:g} {pos[1]:g} {pos[2]:g} {matrix} {name}"


def _part(name: str, body: list[str], org: str = "Part") -> str:
    head = [f"0 Hostile {name}", f"0 Name: {name}", "0 Author: tests/hostile/generate.py",
            f"0 !LDRAW_ORG {org}", ""]
    return "\n".join(head + body) + "\n"


def _write(path: Path, text: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def _symlink(link: Path, target: Path) -> None:
    if link.is_symlink() or link.exists():
        link.unlink()
    os.symlink(target, link)


def _nest_chain(lib: Path, stem: str, leaf: list[str], levels: int, fan: int, org: str) -> str:
    """Primitives p/<stem>0.dat (the `leaf` lines) .. p/<stem><levels>.dat, each placing the one
    below `fan` times; returns the top's name."""
    _write(lib / "p" / f"{stem}0.dat", _part(f"{stem}0.dat", leaf, "Primitive"))
    for k in range(1, levels + 1):
        body = [_line(16, (0, 0, 0), ID, f"{stem}{k - 1}.dat") for _ in range(fan)]
        _write(lib / "p" / f"{stem}{k}.dat", _part(f"{stem}{k}.dat", body, org if k == levels else "Primitive"))
    return f"{stem}{levels}.dat"


def _grid_primitive(n: int) -> list[str]:
    """A unit square in the y = 0 plane, x and z in [0, 1], as n x n quads (2 n^2 triangles)."""
    out = []
    for i in range(n):
        for j in range(n):
            x0, x1, z0, z1 = i / n, (i + 1) / n, j / n, (j + 1) / n
            out.append(f"4 16 {x0:.5g} 0 {z0:.5g} {x0:.5g} 0 {z1:.5g} {x1:.5g} 0 {z1:.5g} {x1:.5g} 0 {z0:.5g}")
    return out


def generate(out: str | os.PathLike, big: bool = True) -> dict[str, Path]:
    """Write the corpus under `out`; returns {case: model file}. With `big=False` the three large
    cases (50 MB line, 200,000 triangles, 20,000 parts) are left out, for quick runs."""
    from factory.embedded import generate_library

    out = Path(out)
    lib, models, outside = out / "ldraw", out / "models", out / "outside"
    for name, text in generate_library().items():
        _write(lib / name, text)
    (lib / "parts" / "s").mkdir(parents=True, exist_ok=True)
    secret = _write(outside / "secret.dat", _part("secret.dat", ["3 16 0 0 0 10 0 0 0 0 10"]))
    rng = random.Random(20240601)
    cases: dict[str, Path] = {}

    def model(case: str, lines: list[str] | str | bytes, ext: str = "ldr") -> None:
        if isinstance(lines, list):
            lines = "\n".join(lines) + "\n"
        cases[case] = _write(models / f"{case}.{ext}", lines)

    brick = _line(16, (0, 0, 0), ID, "3001.dat")
    on_top = _line(4, (0, -24, 0), ID, "3001.dat")

    # -- cycles and nesting ---------------------------------------------------------------------
    _write(lib / "parts" / "cycle_a.dat", _part("cycle_a.dat", [_line(16, (0, 0, 0), ID, "cycle_b.dat")]))
    _write(lib / "parts" / "cycle_b.dat", _part("cycle_b.dat", [_line(16, (0, 0, 0), ID, "cycle_a.dat")]))
    model("cycle", [_line(16, (0, 0, 0), ID, "cycle_a.dat")])
    _write(lib / "parts" / "self_cycle.dat",
           _part("self_cycle.dat", ["3 16 0 0 0 10 0 0 0 0 10", _line(16, (0, 0, 0), ID, "self_cycle.dat")]))
    model("self_cycle", [_line(16, (0, 0, 0), ID, "self_cycle.dat")])
    model("mpd_cycle", ["0 FILE main.ldr", _line(16, (0, 0, 0), ID, "sub_a.ldr"),
                        "0 FILE sub_a.ldr", brick, _line(16, (0, -24, 0), ID, "sub_b.ldr"),
                        "0 FILE sub_b.ldr", brick, _line(16, (0, -24, 0), ID, "sub_a.ldr")], "mpd")
    # 10^6 parts: 6 levels of submodels, each placing the next 10 times (MAX_MODEL_PARTS 200,000).
    levels = 6
    lines = ["0 FILE main.ldr", *[_line(16, (0, 0, 0), ID, "bomb1.ldr")] * 10]
    for k in range(1, levels + 1):
        child = f"bomb{k + 1}.ldr" if k < levels else "3001.dat"
        lines += [f"0 FILE bomb{k}.ldr", *[_line(16, (0, 0, 0), ID, child)] * 10]
    model("mpd_bomb", lines, "mpd")
    depth = 100
    lines = ["0 FILE main.ldr", _line(16, (0, 0, 0), ID, "deep1.ldr")]
    for k in range(1, depth + 1):
        lines += [f"0 FILE deep{k}.ldr", _line(16, (0, 0, 0), ID, f"deep{k + 1}.ldr" if k < depth else "3001.dat")]
    model("deep_nesting", lines, "mpd")

    # -- geometry bombs: 10 records x 10^6 placements = 10^7, past MAX_EDGES and MAX_TRIANGLES ----
    edge_leaf = [f"2 24 0 0 0 {k + 1} 0 0" for k in range(10)]
    top = _nest_chain(lib, "edgebomb", edge_leaf, 6, 10, "Primitive")
    _write(lib / "parts" / "edge_bomb.dat", _part("edge_bomb.dat", [_line(16, (0, 0, 0), ID, top), brick]))
    model("edge_bomb", [_line(16, (0, 0, 0), ID, "edge_bomb.dat")])
    tri_leaf = [f"3 16 0 0 0 {k + 1} 0 0 0 0 {k + 1}" for k in range(10)]
    top = _nest_chain(lib, "tribomb", tri_leaf, 6, 10, "Primitive")
    _write(lib / "parts" / "triangle_bomb.dat", _part("triangle_bomb.dat", [_line(16, (0, 0, 0), ID, top)]))
    model("triangle_bomb", [_line(16, (0, 0, 0), ID, "triangle_bomb.dat")])

    # -- long lines and binary ------------------------------------------------------------------
    if big:
        path = models / "long_line_50mb.ldr"
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as fh:
            fh.write(b"0 ")
            chunk = b"x" * (1 << 20)
            for _ in range(50):
                fh.write(chunk)
            fh.write(b"\n")
        cases["long_line_50mb"] = path
    model("long_line_1mb", ["0 " + "y" * (1 << 20), brick])
    _write(lib / "parts" / "long_line.dat", _part("long_line.dat", ["0 // " + "z" * (1 << 20),
                                                                   "3 16 0 0 0 10 0 0 0 0 10"]))
    model("long_line_part", [_line(16, (0, 0, 0), ID, "long_line.dat")])
    model("binary_model", rng.randbytes(64 * 1024))
    _write(lib / "parts" / "binary.dat", rng.randbytes(16 * 1024))
    model("binary_part", [_line(16, (0, 0, 0), ID, "binary.dat")])

    # -- numbers --------------------------------------------------------------------------------
    model("nan_position", [brick, f"1 16 nan -24 0 {ID} 3001.dat"])
    model("inf_matrix", [brick, "1 16 0 -24 0 inf 0 0 0 1 0 0 0 1 3001.dat"])
    model("huge_coord", [brick, f"1 16 1e300 -24 0 {ID} 3001.dat"])
    _write(lib / "parts" / "nan_vertex.dat", _part("nan_vertex.dat", ["3 16 0 0 0 nan 0 0 0 0 10",
                                                                     "3 16 0 0 0 10 0 0 0 0 -inf"]))
    model("nan_vertex_part", [_line(16, (0, 0, 0), ID, "nan_vertex.dat")])

    # -- paths ----------------------------------------------------------------------------------
    model("dotdot_ref", [brick, _line(16, (0, -24, 0), ID, "..\\..\\outside\\secret.dat")])
    model("absolute_ref", [brick, _line(16, (0, -24, 0), ID, "/etc/passwd")])
    model("drive_ref", [brick, _line(16, (0, -24, 0), ID, "C:\\secret.dat")])
    _symlink(lib / "parts" / "escape.dat", secret.resolve())
    model("symlink_library", [brick, _line(16, (0, -24, 0), ID, "escape.dat")])
    _symlink(models / "escape_model.dat", secret.resolve())
    model("symlink_model_folder", [brick, _line(16, (0, -24, 0), ID, "escape_model.dat")])

    # -- placement matrices ---------------------------------------------------------------------
    # A part that is not its own mirror image through any axis plane (one mirrored that is, a
    # plain brick, is placed by the rotation that gives the same shape).
    _write(lib / "parts" / "lopsided.dat", _part("lopsided.dat", ["3 16 0 0 0 10 0 0 0 5 10"]))
    for case, m in (("zero_matrix", "0 0 0 0 0 0 0 0 0"), ("rank_deficient", "1 0 0 1 0 0 1 0 0"),
                    ("scaled", "2 0 0 0 2 0 0 0 2"), ("sheared", "1 0.5 0 0 1 0 0 0 1"),
                    ("mirrored", "-1 0 0 0 1 0 0 0 1")):
        model(case, [brick, "0 STEP", f"1 4 0 -24 0 {m} {'lopsided' if case == 'mirrored' else '3001'}.dat"])

    # -- degenerate parts and models ------------------------------------------------------------
    _write(lib / "parts" / "flat.dat", _part("flat.dat", [
        "0 BFC CERTIFY CCW",
        "4 16 -40 0 -40 -40 0 40 40 0 40 40 0 -40",
        "4 16 -40 0 -40 40 0 -40 40 0 40 -40 0 40"]))
    model("flat_part", [_line(16, (0, 0, 0), ID, "flat.dat"), "0 STEP", on_top])
    model("empty_model", b"")
    model("comments_only", ["0 Nothing here", "0 Name: comments_only.ldr", "0 STEP", "0 // still nothing",
                            "0 STEP"])
    model("mpd_empty_main", ["0 FILE main.ldr", "0 Main block with no lines", "0 FILE sub.ldr", brick,
                             on_top], "mpd")
    model("mpd_part_inside", ["0 FILE main.ldr", _line(16, (0, 0, 0), ID, "inside.dat"), "0 STEP", on_top,
                              "0 FILE inside.dat", "0 Inside part", "0 Name: inside.dat",
                              "0 !LDRAW_ORG Part", "0 BFC CERTIFY CCW",
                              "4 16 -40 24 -20 40 24 -20 40 24 20 -40 24 20",
                              "4 16 -40 0 20 40 0 20 40 0 -20 -40 0 -20",
                              "4 16 -40 0 -20 40 0 -20 40 24 -20 -40 24 -20",
                              "4 16 -40 24 20 40 24 20 40 0 20 -40 0 20",
                              "4 16 -40 0 20 -40 0 -20 -40 24 -20 -40 24 20",
                              "4 16 40 24 20 40 24 -20 40 0 -20 40 0 20"], "mpd")
    model("missing_part", [brick, _line(16, (0, -24, 0), ID, "no_such_part_xyz.dat")])
    model("syntax_garbage", [brick, "1 16 0 -24", "9 what is this", "3 16 0 0", "1 16 a b c d e f g h i j k l 3001.dat"])
    # 50 layers of a 100 x 100 grid (20,000 triangles each) through a 40 x 24 x 20 box: under the
    # reader's 2,000,000 and the file size caps, over the render and collision budgets; 0.6 MB.
    _write(lib / "p" / "hostile_grid100.dat", _part("hostile_grid100.dat", _grid_primitive(100), "Primitive"))
    layers = [_line(16, (-20, 24 * k / 49, -10), "40 0 0 0 1 0 0 0 20", "hostile_grid100.dat") for k in range(50)]
    _write(lib / "parts" / "million_triangles.dat", _part("million_triangles.dat", layers))
    model("million_triangles", [_line(16, (0, 0, 0), ID, "million_triangles.dat")])
    model("huge_colour", [brick, "0 STEP", _line(10 ** 40, (0, -24, 0), ID, "3001.dat")])
    model("unknown_colour", [brick, "0 STEP", _line(600, (0, -24, 0), ID, "3001.dat")])

    # -- large but legal: the budgets for socket finding and the checker ------------------------
    if big:
        n = 130  # 6 faces x 2 n^2 = 202,800 triangles
        _write(lib / "p" / "hostile_grid.dat", _part("hostile_grid.dat", _grid_primitive(n), "Primitive"))
        faces = [  # (origin, matrix) mapping the unit square's (x, z) onto a face of a 40 x 24 x 20 box
            ((-20, 0, -10), "40 0 0 0 1 0 0 0 20"), ((-20, 24, -10), "40 0 0 0 1 0 0 0 20"),
            ((-20, 0, -10), "40 0 0 0 0 24 0 1 0"), ((-20, 0, 10), "40 0 0 0 0 24 0 1 0"),
            ((-20, 0, -10), "0 1 0 0 0 24 20 0 0"), ((20, 0, -10), "0 1 0 0 0 24 20 0 0"),
        ]
        body = [_line(16, o, m, "hostile_grid.dat") for o, m in faces]
        _write(lib / "parts" / "many_triangles.dat", _part("many_triangles.dat", body))
        model("many_triangles", [_line(16, (0, 0, 0), ID, "many_triangles.dat"), "0 STEP",
                                 _line(4, (0, -24, 0), ID, "many_triangles.dat")])

        lines = []
        for layer in range(50):
            for i in range(20):
                for j in range(20):
                    lines.append(_line(LAYER_COLOURS[layer % len(LAYER_COLOURS)], (40 * i, -24 * layer, 20 * j), ID,
                                       "3001.dat"))
            lines.append("0 STEP")
        model("many_parts", lines)
    return {case: cases[case] for case in CASES if case in cases}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", help="folder to write the corpus into (created)")
    parser.add_argument("--small", action="store_true", help="leave out the three large cases")
    args = parser.parse_args(argv)
    for case, path in generate(args.out, big=not args.small).items():
        print(f"{case}\t{path}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    sys.exit(main())
