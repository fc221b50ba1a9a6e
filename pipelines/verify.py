"""Replay a human-designed model's build steps through the physics checks.

`python -m pipelines.verify MODEL [--ldraw DIR] [--check-backend cpu|jax] --json`

The replay is `factory.verify` (`factory.replay`: see its module docstring for how parts and
sub-assemblies are judged). One JSON object per placed part, and one with `"unit": true` per
sub-assembly attachment; with `--faults`, also the injected faults and a summary line.
"""

from __future__ import annotations

import argparse
import json
import sys

from factory.cli import ArgumentParser, renamed_flag, run_guarded
from factory.physics.check import BACKENDS, backend_arg
from factory.replay import verify


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.verify", description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("--ldraw", help="LDraw library: a folder or LDraw's complete.zip (default: "
                    "$LDRAWDIR, else the embedded library)")
    ap.add_argument("--check-backend", dest="backend", choices=BACKENDS, default="cpu", type=backend_arg,
                    help="physics checks one candidate at a time on the CPU (cpu, default: MuJoCo's C "
                         "collision and NumPy/SciPy) or batched in JAX kernels (jax, on a GPU where there is one)")
    renamed_flag(ap, "--backend", "--check-backend", "backend", choices=BACKENDS, type=backend_arg)
    ap.add_argument("--json", action="store_true", help="print JSON lines (the only format)")
    ap.add_argument("--faults", action="store_true",
                    help="also inject faults into accepted parts and end with a summary line")
    args = ap.parse_args(argv)

    def body() -> None:
        found = verify(args.model, args.ldraw, args.backend, faults=args.faults,
                       on_record=lambda r: print(json.dumps(r), flush=True))
        if args.faults:
            print(json.dumps({"summary": found.summary}), flush=True)

    return run_guarded(body)


if __name__ == "__main__":
    sys.exit(main())
