"""`--prior FILE` for the commands that grow objects (`pipelines.sample`, `pipelines.synth`): where
the sampler's parts and colours come from when the user does not list them."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from tqdm import tqdm

from factory.ldraw import get_reader
from factory.sampler import DEFAULT_COLOURS, DEFAULT_PARTS, SamplerConfig
from factory.sampler.from_prior import configure, is_embedded, report


def add_prior_flag(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--prior", dest="prior_file", metavar="FILE",
                    help="usage prior the parts and colours are drawn from where --parts or --colours is not "
                         "given (written by `python -m pipelines.prior`; default: the shipped prior, fitted on 90 "
                         "real designs). With a library, its parts the library has and the factory can connect")


def apply_prior(args, config: SamplerConfig, ldraw: str | None, prefix: str = "", progress: bool = True
                ) -> SamplerConfig:
    """`config` with parts and colours from `--prior` where the user gave none (the parsed
    `parts`/`colours` values are the defaults themselves then), and one line on stderr saying
    what the library left out."""
    parts_given = getattr(args, prefix + "parts") is not DEFAULT_PARTS
    colours_given = getattr(args, prefix + "colours") is not DEFAULT_COLOURS
    if parts_given and colours_given:
        if args.prior_file:
            print("note: --prior is not used: --parts and --colours are both given", file=sys.stderr)
        return replace(config, prior="")
    reader = get_reader(ldraw)
    if not args.prior_file and is_embedded(reader):
        return config  # the defaults are the shipped prior on the embedded library
    bar = tqdm(total=0, unit="part", desc="choosing parts", dynamic_ncols=True, disable=not progress,
               file=sys.stderr)

    def step(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        config, choice = configure(config, reader, args.prior_file, parts=not parts_given, colours=not colours_given,
                                   progress=step)
    finally:
        bar.close()
    if choice is not None:
        print(report(choice, config, reader.library.description), file=sys.stderr)
    return config
