"""The command line: `python -m pipelines.bcbench import SRC OUT [--ldraw DIR|embedded] [--dataset-id ID]
[--default-split test|train]` (also `brick-factory bcbench import ...`): `import_bcbench`, its summary
line printed; input not in the layout exits with status 2. Its help is the package's docstring.
"""

from __future__ import annotations

import argparse
import sys

from factory.cli import ArgumentParser, run_guarded
from pipelines import bcbench
from pipelines.bcbench.importer import import_bcbench, summary_line
from pipelines.bcbench.layout import BCBenchError


def main(argv: list[str] | None = None) -> int:
    """`python -m pipelines.bcbench import SRC OUT [--ldraw DIR|embedded] [--dataset-id ID]
    [--default-split test|train]`."""
    ap = ArgumentParser(prog="python -m pipelines.bcbench", description=bcbench.__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    imp = sub.add_parser("import", help="BC-Bench's layout -> our dataset format")
    imp.add_argument("src", help="a folder holding BC-Bench's files (pose ShareGPT JSON, step folders, tasks.json)")
    imp.add_argument("out", help="dataset folder to write (absent or empty)")
    imp.add_argument("--ldraw", help="LDraw library (or 'embedded') for part symmetry; default: no symmetry")
    imp.add_argument("--dataset-id", default="bcbench", help="dataset_id of the rows (default bcbench)")
    imp.add_argument("--default-split", default="test", choices=("train", "test"),
                     help="split of steps no split list or file name places (default test)")
    args = ap.parse_args(argv)

    def body() -> int:
        summary = import_bcbench(args.src, args.out, ldraw=args.ldraw, dataset_id=args.dataset_id,
                                 default_split=args.default_split)
        print(summary_line(summary))
        return 0

    return run_guarded(body, {BCBenchError: 2, ValueError: 2, OSError: 2})


if __name__ == "__main__":
    sys.exit(main())
