"""Command line: `python -m factory.ldraw steps MODEL` and `python -m factory.ldraw part NAME`."""

from __future__ import annotations

import argparse
import json
import sys

from factory.cli import ArgumentParser, run_guarded
from factory.errors import LDrawError
from factory.ldraw import NO_PARTS, get_reader, read_steps
from factory.parts import load_part


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m factory.ldraw", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    steps = sub.add_parser("steps", help="print a model's build steps, one JSON object per step")
    steps.add_argument("model", help="an .ldr, .mpd or .dat model file")
    part = sub.add_parser("part", help="print a part's geometry, connection points and symmetry")
    part.add_argument("name", help="a part name such as 3001 or 3001.dat")
    for p in (steps, part):
        p.add_argument("--ldraw", help="LDraw library: a folder or LDraw's complete.zip (default: "
                       "$LDRAWDIR, else the embedded library)")
        p.add_argument("--json", action="store_true", help="print JSON (the only format)")
    args = parser.parse_args(argv)

    def body() -> None:
        if args.command == "steps":
            steps = read_steps(args.model, args.ldraw)
            if not steps:
                raise LDrawError(NO_PARTS, args.model)
            for step in steps:
                print(json.dumps(step.to_json()))
        else:
            print(json.dumps(load_part(get_reader(args.ldraw), args.name).to_json()))

    return run_guarded(body)

if __name__ == "__main__":
    sys.exit(main())
