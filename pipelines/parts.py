"""Which parts of a library the factory can use, per category, and why the others are left out;
with `--prepare`, their collision pieces computed over all cores and cached.

    python -m pipelines.parts --ldraw LIB [--all | --prior FILE | --designs DESIGN...] [--prepare] [--workers N] [--json]
    python -m pipelines.parts --pack FILE | --unpack FILE

Without `--all`, the parts of the usage prior (`--prior`, default the shipped one) as the sampler
would draw them from this library (`factory.prior.choose`); with `--all`, every part in the
library's `parts/` folder; with `--designs`, every library part the designs place (with
`--prepare`, also those the sampler cannot use: `pipelines.verify` needs the collision pieces of
each, and a design of a few hundred parts takes long to decompose on one core). `--prepare` computes what growing objects needs of each usable part
(connections, symmetry, collision pieces) once, into the cache: a run cut short and run again
does only what is left; `--shard I/N` takes every N-th part from the I-th, so that N machines
share one library. `--pack FILE` writes the cache's part entries into one zip for another
machine, `--unpack FILE` takes them in there. See docs/prior.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

from tqdm import tqdm

from factory.cli import ArgumentParser, add_progress_flag, run_guarded
from factory.ldraw import get_reader
from factory.prior import PriorError, load_prior
from factory.prior.choose import choose_parts
from factory.prior.placements import read_design
from pipelines.prepare import pack, survey, unpack

USABLE = "usable"


def design_parts(reader, designs) -> list[str]:
    """The distinct library parts the designs place, by the names they use, in order of first use."""
    names: dict[str, None] = {}
    for path in designs:
        for use in read_design(reader, path).uses:
            if use.resolved is not None and use.resolved.origin == "library":
                names.setdefault(use.part, None)
    return list(names)


def table(statuses) -> str:
    """Per category: parts, usable, and the reasons the others are left out (largest first)."""
    cats: dict[str, Counter] = defaultdict(Counter)
    for s in statuses:
        cats[s.category][USABLE if s.reason is None else _short(s.reason)] += 1
    lines = ["| category | parts | usable | left out (why) |", "|---|---:|---:|---|"]
    for cat, c in sorted(cats.items(), key=lambda kv: (-sum(kv[1].values()), kv[0])):
        why = "; ".join(f"{n} {r}" for r, n in c.most_common() if r != USABLE)
        lines.append(f"| {cat} | {sum(c.values())} | {c[USABLE]} | {why} |")
    return "\n".join(lines)


def _short(reason: str) -> str:
    """A reason without the part-specific details (file names, counts), for grouping."""
    for head in ("cannot be read", "collision pieces refused"):
        if reason.startswith(head):
            detail = reason.split(": ", 2)[-1]
            if "triangles" in detail:
                return f"{head}: too many triangles"
            if "took more than" in detail:
                return f"{head}: decomposition too slow"
            return f"{head}: " + detail.split(";")[0][:60]
    return reason.split(":")[0].split(" (")[0]


def _shard(text: str) -> tuple[int, int]:
    """`I/N` with 1 <= I <= N, for `--shard`."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        i = n = 0
    if not 1 <= i <= n:
        raise argparse.ArgumentTypeError(f"expected I/N with 1 <= I <= N (for example 2/4), got {text!r}")
    return i, n


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.parts", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ldraw", help="LDraw library: a folder or LDraw's complete.zip (default: $LDRAWDIR, else the "
                    "embedded library)")
    pick = ap.add_mutually_exclusive_group()
    pick.add_argument("--all", action="store_true", help="every part of the library (default: the prior's parts)")
    pick.add_argument("--prior", dest="prior_file", metavar="FILE", help="usage prior (default: the shipped one)")
    pick.add_argument("--designs", nargs="+", metavar="DESIGN",
                      help="the parts these LDraw models place (with --prepare: all of them, for pipelines.verify)")
    ap.add_argument("--prepare", action="store_true",
                    help="also compute each usable part's collision pieces (cached; resumable)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    ap.add_argument("--json", action="store_true", help="one JSON line per part, printed as each finishes, instead of the table")
    ap.add_argument("--shard", metavar="I/N", type=_shard,
                    help="only every N-th part, from the I-th (1-based): N machines share one library's "
                         "preparation, then each one's --pack is --unpack'ed into one cache")
    ap.add_argument("--pack", metavar="FILE", help="write the cache's part entries into one zip, and stop")
    ap.add_argument("--unpack", metavar="FILE", help="take a zip written by --pack into this cache, and stop")
    add_progress_flag(ap)
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error("--workers must be >= 1")

    def body() -> None:
        if args.pack:
            print(f"wrote {args.pack}: {pack(args.pack)} cache entries")
            return
        if args.unpack:
            print(f"{args.unpack}: {unpack(args.unpack)} cache entries added")
            return
        reader = get_reader(args.ldraw)
        ldraw = args.ldraw or os.environ.get("LDRAWDIR") or None
        left: list = []
        if args.all:
            names = reader.library.part_names()
        elif args.designs:
            names = design_parts(reader, args.designs)
        else:
            choice = choose_parts(load_prior(args.prior_file), reader)
            names = [n for n, _ in choice.parts]
            left = choice.left_out
        if args.shard:
            i, n = args.shard
            names = names[i - 1::n]
            left = left if i == 1 else []  # the prior's parts the library lacks: listed once, by the first
        if args.json:
            for lo in left:
                print(json.dumps({"part": lo.part, "family": lo.family, "usable": False, "reason": lo.reason,
                                  "prior_weight": lo.weight}), flush=True)
        t0 = time.perf_counter()
        bar = tqdm(total=len(names), unit="part", desc="preparing" if args.prepare else "surveying",
                   dynamic_ncols=True, disable=args.no_progress, file=sys.stderr)

        def done(s) -> None:
            bar.update(1)
            if args.json:  # as each part finishes: a run cut short keeps what it learnt
                print(json.dumps({"part": s.part, "category": s.category, "usable": s.reason is None,
                                  "reason": s.reason, "seconds": round(s.seconds, 3),
                                  **({"joints": s.joints} if s.joints else {})}), flush=True)

        statuses = survey(ldraw, names, args.prepare, args.workers, done, own_parts=args.all,
                          every=bool(args.designs))
        bar.close()
        wall = time.perf_counter() - t0
        usable = sum(s.reason is None for s in statuses)
        if not args.json:
            print(table(statuses))
            if left:
                why = Counter(lo.reason.split(":")[0] for lo in left)
                print(f"\nprior parts the library cannot give: {len(left)} ("
                      + "; ".join(f"{n} {r}" for r, n in why.most_common()) + ")")
        print(f"{usable} of {len(statuses)} parts usable; {'prepared' if args.prepare else 'surveyed'} in {wall:.1f} s "
              f"with {args.workers} worker{'s' if args.workers != 1 else ''}", file=sys.stderr)

    return run_guarded(body, {PriorError: 2, ValueError: 2, OSError: 2})


if __name__ == "__main__":
    sys.exit(main())
