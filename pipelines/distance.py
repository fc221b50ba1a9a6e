"""How far a set of objects is from real designs: side-by-side tables, plots and one distance each.

    python -m pipelines.distance OBJECTS REAL [--ldraw LIB] [--out DIR] [--json]

OBJECTS and REAL are each a dataset folder (`pipelines.synth`'s), a folder of LDraw models
(`pipelines.sample`'s `.ldr` files, or real designs) or one model. Both are read with one
library (`--ldraw`; default $LDRAWDIR, else the embedded library; give the library the real
designs need). With `--out`, writes `report.json` (one row per table), `report.md` and a plot per
table. The tables and distances: `pipelines.realism`; docs/prior.md.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from factory.atomic import write_atomic, write_figure
from factory.cli import ArgumentParser, run_guarded
from factory.ldraw import get_reader
from pipelines.realism import Table, compare, read_collection


def markdown(tables: list[Table], objects: str, real: str) -> str:
    lines = [f"# {objects} beside {real}", ""]
    for t in tables:
        lines += [f"## {t.name}: {t.distance_name} {t.distance:.3f}", ""]
        if "coverage" in t.extra:
            e = t.extra
            lines += [f"Coverage: {e['coverage']:.1%} of the real placements ({e['covered_placements']} of "
                      f"{e['real_placements']}) are of part families the objects use; families used: "
                      f"{e['families_objects']} (objects), {e['families_real']} (real).", ""]
        lines += [f"| {t.name} | {objects} | {real} |", "|---|---:|---:|"]
        lines += [f"| {k} | {a:.1%} | {b:.1%} |" for k, a, b in t.rows]
        if t.extra.get("most_missed"):
            lines += ["", "Real part families the objects never use, most placed first:", "",
                      "| family | description | placements | share |", "|---|---|---:|---:|"]
            lines += [f"| {m['family']} | {m['description']} | {m['placements']} | {m['share']:.1%} |"
                      for m in t.extra["most_missed"]]
        lines.append("")
    return "\n".join(lines)


def plot(table: Table, objects: str, real: str, path: Path) -> None:
    import matplotlib  # the bench extra's: only when plots are asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = table.rows[:25]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(rows) + 2), 4))
    ax.bar(x - 0.2, [r[1] for r in rows], 0.4, label=objects)
    ax.bar(x + 0.2, [r[2] for r in rows], 0.4, label=real)
    ax.set_xticks(x, [r[0] for r in rows], rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("share")
    ax.set_title(f"{table.name}: {table.distance_name} {table.distance:.3f}")
    ax.legend()
    fig.tight_layout()
    write_figure(fig, path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.distance", description=__doc__.split("\n\n")[0])
    ap.add_argument("objects", help="dataset folder, folder of LDraw models, or one model")
    ap.add_argument("real", help="real designs: a folder of LDraw models (or a dataset folder)")
    ap.add_argument("--ldraw", help="LDraw library both are read with: a folder or LDraw's complete.zip")
    ap.add_argument("--out", help="folder for report.json, report.md and the plots")
    ap.add_argument("--top", type=int, default=25, help="rows per table (default 25)")
    ap.add_argument("--json", action="store_true", help="print the report rows as JSON lines")
    args = ap.parse_args(argv)

    def body() -> None:
        reader = get_reader(args.ldraw)
        objects = read_collection(args.objects, reader)
        real = read_collection(args.real, reader)
        for c in (objects, real):
            for s in c.skipped:
                print(f"note: {c.name}: left out {s}", file=sys.stderr)
        tables = compare(objects, real, reader, args.top)
        rows = [t.to_json() for t in tables]
        if args.out:
            out = Path(args.out)
            write_atomic(out / "report.json", (json.dumps({"objects": str(args.objects), "real": str(args.real),
                                                            "tables": rows}, indent=1) + "\n").encode())
            write_atomic(out / "report.md", markdown(tables, objects.name, real.name).encode())
            for t in tables:
                plot(t, objects.name, real.name, out / f"{t.name.replace(' ', '_')}.png")
        if args.json:
            for r in rows:
                print(json.dumps(r))
        else:
            cov = tables[0].extra
            print(f"{objects.name} ({len(objects.objects)} objects) beside {real.name} ({len(real.objects)} designs): "
                  f"coverage {cov['coverage']:.1%} ({cov['covered_placements']} of {cov['real_placements']} "
                  "placements); " + "; ".join(f"{t.name} {t.distance_name} {t.distance:.3f}" for t in tables))

    return run_guarded(body, {FileNotFoundError: 2})


if __name__ == "__main__":
    sys.exit(main())
