"""Human designs as step-wise data: `python -m pipelines.designs MODEL... --out OUT [--ldraw DIR]`.

Each LDraw model (.ldr/.mpd with `0 STEP`s) becomes one object (source `design`), its id the file
name without extension. Sub-assemblies are shown as a printed manual shows them: their own steps on
their own, in their own frame, then one multi-brick "module" step attaching the finished
sub-assembly to its parent (see docs/concepts/dataset-contract.md). Each step's physics record is the replay of
`pipelines.verify` (skip it with --no-physics). Same layout, resume and summary as
`pipelines.synth`.
"""

from __future__ import annotations

import argparse
import os
import re
import sys

from factory import read_steps
from factory.cli import ArgumentParser, config_from_args as config_of
from pipelines.dataset.config import DatasetConfig
from pipelines.dataset.sources import file_sha256
from pipelines.synth import _ldraw, add_config_flags, add_run_args, guarded, run


def object_ids(paths) -> list[str]:
    """File stems, lower case, with characters outside [a-z0-9._-] as '-' (no leading '.' or '-', at
    most 120 characters: a plain name, `dataset.config.NAME`); repeats get '-2', '-3'."""
    seen: dict[str, int] = {}
    out = []
    for p in paths:
        stem = re.sub(r"[^a-z0-9._-]+", "-", os.path.splitext(os.path.basename(p))[0].lower()).strip("-.")[:120] or "model"
        seen[stem] = seen.get(stem, 0) + 1
        out.append(stem if seen[stem] == 1 else f"{stem}-{seen[stem]}")
    return out


def design_config(paths, ldraw: str | None = None, **fields) -> DatasetConfig:
    """The `DatasetConfig` of the LDraw model files `paths`, one object each (a missing file, a
    model that places no parts or a part missing from the library raise here); `ldraw` is a
    library folder or None (the embedded library); `fields` are further `DatasetConfig` fields."""
    ldraw = os.path.realpath(os.path.expanduser(ldraw)) if ldraw else None
    paths = [os.path.realpath(p) for p in paths]
    for p in paths:
        if not os.path.isfile(p):
            raise ValueError(f"no such model file: {p}")
        if not read_steps(p, ldraw):  # bad files and missing parts fail here, exit 2
            raise ValueError(f"{p} places no parts")
    models = [{"object_id": oid, "path": p, "sha256": file_sha256(p)} for oid, p in zip(object_ids(paths), paths)]
    return DatasetConfig("design", len(models), models=tuple(models), ldraw=ldraw, **fields)


def config_from_args(args) -> DatasetConfig:
    """The design `DatasetConfig` of parsed arguments (`--ldraw` defaults to $LDRAWDIR)."""
    config = design_config(args.models, _ldraw(args.ldraw))
    return config_of(DatasetConfig, args, source="design", n_objects=config.n_objects, models=config.models,
                     sampler=None, ldraw=config.ldraw)


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m pipelines.designs", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", help="LDraw model files")
    add_config_flags(ap, skip=("source", "n_objects", "models", "sampler"))
    add_run_args(ap)
    ap.set_defaults(objects_per_shard=1)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return guarded(lambda: run(config_from_args(args), args))


if __name__ == "__main__":
    sys.exit(main())
