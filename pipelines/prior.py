"""Fit a usage prior to real designs: part, colour and connection-kind frequencies.

    python -m pipelines.prior DESIGN_OR_FOLDER... --out prior.json [--ldraw LIB] [--temper T]

Every design counts the same (`factory.prior.fit`); printed variants, revisions and renumbered
parts fold into their base part. The sampler draws from a prior with `--prior FILE` (default: the
shipped one, `factory/data/prior.json`). See docs/prior.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

from factory.atomic import write_atomic
from factory.cli import ArgumentParser, run_guarded
from factory.ldraw import get_reader
from factory.prior import DEFAULT_TEMPER, PriorError, fit_prior

DESIGN_SUFFIXES = (".ldr", ".mpd", ".lcad")
"""Files taken from a folder given as a design (a `.dat` is taken only when named)."""


def design_files(paths: list[str]) -> list[Path]:
    """The design files named, folders expanded to their LDraw models (sorted, not recursive)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in DESIGN_SUFFIXES)
            if not found:
                raise PriorError(f"{p}: no LDraw models ({', '.join(DESIGN_SUFFIXES)}) in this folder")
            out.extend(found)
        elif p.is_file():
            out.append(p)
        else:
            raise PriorError(f"{p}: no such file or folder")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.prior", description=__doc__.split("\n\n")[0])
    ap.add_argument("designs", nargs="+", help="LDraw models (.ldr, .mpd) or folders of them")
    ap.add_argument("--out", required=True, help="the prior file to write (JSON)")
    ap.add_argument("--ldraw", help="LDraw library the designs resolve against: a folder or LDraw's complete.zip "
                    "(default: $LDRAWDIR, else the embedded library)")
    ap.add_argument("--temper", type=float, default=DEFAULT_TEMPER,
                    help=f"weights are the designs' mean shares to this power, in (0, 1] (default {DEFAULT_TEMPER})")
    ap.add_argument("--skip-unreadable", action="store_true",
                    help="leave out a design that cannot be read (its error is printed) instead of stopping")
    ap.add_argument("--require-licence", action="store_true",
                    help="leave out a design whose file states no licence (no `0 !LICENSE` line)")
    ap.add_argument("--quiet", action="store_true", help="no line per design")
    args = ap.parse_args(argv)

    def body() -> None:
        files = design_files(args.designs)
        reader = get_reader(args.ldraw)
        done = [0]

        def progress(line: str) -> None:
            done[0] += 1
            if not args.quiet:
                print(f"[{done[0]}/{len(files)}] {line}", file=sys.stderr, flush=True)

        prior = fit_prior(files, reader, args.temper, progress, args.skip_unreadable, args.require_licence)
        write_atomic(Path(args.out), prior.dumps().encode())
        placements = sum(d.placements for d in prior.designs)
        top = ", ".join(f"{p.part} {p.weight:.3f}" for p in prior.parts[:8])
        print(f"wrote {args.out}: {len(prior.designs)} designs, {placements} placements, {len(prior.parts)} part "
              f"families, {len(prior.colours)} colours; top parts: {top}")

    return run_guarded(body, {PriorError: 2})


if __name__ == "__main__":
    sys.exit(main())
