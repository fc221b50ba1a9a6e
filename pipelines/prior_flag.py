"""`--prior FILE` for the commands that grow objects (`pipelines.sample`, `pipelines.synth`): where
the sampler's parts and colours come from when the user does not list them."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

from tqdm import tqdm

from factory.ldraw import get_reader
from factory.prior import load_prior
from factory.prior.choose import choose_parts
from factory.sampler import DEFAULT_COLOURS, DEFAULT_PARTS, SamplerConfig, SamplerConfigError
from factory.sampler.from_prior import configure, is_embedded, report
from pipelines.prepare import survey


def add_prior_flag(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--prior", dest="prior_file", metavar="FILE",
                    help="usage prior the parts and colours are drawn from where --parts or --colours is not "
                         "given (written by `python -m pipelines.prior`; default: the shipped prior, fitted on 90 "
                         "real designs). With a library, its parts the library has and the factory can connect")


ALL = "all"
"""`--parts all`: every part of the library the factory can connect."""


def every_part(config: SamplerConfig, ldraw: str | None, prior_file: str | None, progress: bool) -> SamplerConfig:
    """`config` drawing every usable part of the library (`pipelines.prepare.survey`, over every
    core: whether each part can be used is known without decomposing it): a part the prior has
    keeps the prior's weight, any other gets the smallest of those (rarely drawn, never left out)."""
    reader = get_reader(ldraw)
    names = reader.library.part_names()
    bar = tqdm(total=len(names), unit="part", desc="surveying the library", dynamic_ncols=True,
               disable=not progress, file=sys.stderr)
    statuses = survey(ldraw, names, prepare=False, n_workers=os.cpu_count() or 1, progress=lambda s: bar.update(1),
                      own_parts=True)
    bar.close()
    usable = [s.part for s in statuses if s.reason is None]
    if not usable:
        raise SamplerConfigError(f"--parts all: no part of the {reader.library.description} has studs or sockets")
    prior = load_prior(prior_file)
    weights = dict(choose_parts(prior, reader).parts)
    floor = min((weights[n] for n in usable if n in weights), default=1.0)
    print(f"--parts all: {len(usable)} of {len(names)} parts of the {reader.library.description} usable "
          "(`python -m pipelines.parts --all` lists the rest, with why)", file=sys.stderr)
    print(PREPARED_AS_DRAWN, file=sys.stderr)
    return replace(config, parts=tuple((n, weights.get(n, floor)) for n in usable), prior=prior.label(prior_file))


PREPARED_AS_DRAWN = ("collision pieces are made where a part is first drawn and kept in the cache "
                     "(`python -m pipelines.parts --prepare` makes them ahead, over every core)")
"""Said where the sampler draws from a library: the first objects of a cold cache wait on the
decompositions of the parts they draw, seconds to minutes each."""


def apply_prior(args, config: SamplerConfig, ldraw: str | None, prefix: str = "", progress: bool = True
                ) -> SamplerConfig:
    """`config` with parts and colours from `--prior` where the user gave none (the parsed
    `parts`/`colours` values are the defaults themselves then), and one line on stderr saying
    what the library left out; `--parts all` takes every part the factory can connect."""
    parts_given = getattr(args, prefix + "parts") is not DEFAULT_PARTS
    colours_given = getattr(args, prefix + "colours") is not DEFAULT_COLOURS
    if parts_given and [n for n, _ in config.parts] == [ALL]:
        config = every_part(config, ldraw, args.prior_file, progress)
        if colours_given:
            return config
        parts_given = True
    if parts_given and colours_given:
        if args.prior_file:
            print("note: --prior is not used: --parts and --colours are both given", file=sys.stderr)
        return replace(config, prior="")
    reader = get_reader(ldraw)
    if not args.prior_file and is_embedded(reader):
        return config  # the defaults are the shipped prior on the embedded library
    prior = load_prior(args.prior_file)  # a bad file is said before anything else
    bar = tqdm(total=0, unit="part", desc="choosing parts", dynamic_ncols=True,
               disable=not progress or is_embedded(reader), file=sys.stderr)

    def step(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        config, choice = configure(config, reader, args.prior_file, parts=not parts_given, colours=not colours_given,
                                   progress=step, loaded=prior)
    finally:
        bar.close()
    if choice is not None:
        if parts_given:  # the prior's parts line would name parts that are not drawn
            print(f"prior {config.prior}: its {len(config.colours)} colours the library holds", file=sys.stderr)
        else:
            print(report(choice, config, reader.library.description), file=sys.stderr)
            print(PREPARED_AS_DRAWN, file=sys.stderr)
    return config
