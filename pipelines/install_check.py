"""Refuse to run from an installation whose `factory` package another distribution has overwritten.

The top-level package `factory` is also factory_boy's (its `factory/__init__.py` and
`factory/errors.py` have the same paths as ours). pip installs both into one `site-packages/factory`
folder: whichever is installed last overwrites the other's shared files, and uninstalling either
removes them from both. Our own `factory/__init__.py` cannot report that, since it is one of the
files overwritten; this check lives in `pipelines`, which no other distribution ships, and the
`brick-factory` console script (`pipelines.commands`) runs it before any command, `eval`'s and
`train`'s included. `python -m ...` runs are not checked.

It compares the installed files of our top-level packages with the hashes pip recorded in the
distribution's RECORD, and names any other installed distribution that claims the same top-level
names. A checkout or an editable install (the code is the repository's folders) is not checked.
"""

from __future__ import annotations

import base64
import hashlib
import json
from importlib import metadata
from pathlib import Path

DIST = "brick-factory"
TOP_LEVEL = ("factory", "pipelines", "train", "eval", "mjcf_templates")


class InstallClashError(ImportError):
    """Our installed files were overwritten or removed by another distribution's top-level package."""


def _installed(dist: metadata.Distribution) -> bool:
    """True for a normal (non-editable) install whose `pipelines` is this very file's package."""
    direct = dist.read_text("direct_url.json")
    if direct and json.loads(direct).get("dir_info", {}).get("editable"):
        return False
    return Path(dist.locate_file("pipelines/install_check.py")).resolve() == Path(__file__).resolve()


def _digest(path: Path) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(path.read_bytes()).digest()).rstrip(b"=").decode()


def problems(dist: metadata.Distribution) -> tuple[list[str], list[str]]:
    """(our recorded files that are missing or differ, other distributions claiming our top-level names)."""
    bad = []
    for f in dist.files or []:
        if f.parts[0] not in TOP_LEVEL or f.suffix != ".py" or f.hash is None or f.hash.mode != "sha256":
            continue
        path = Path(dist.locate_file(f))
        if not path.is_file():
            bad.append(f"{f} (missing)")
        elif _digest(path) != f.hash.value:
            bad.append(f"{f} (overwritten)")
    owners = metadata.packages_distributions()
    others = sorted({d for name in TOP_LEVEL for d in owners.get(name, []) if d.lower().replace("_", "-") != DIST})
    return bad, others


def check() -> None:
    """Raise `InstallClashError` when our installed files are not ours any more, or another
    installed distribution ships our top-level names; a checkout or editable install passes."""
    try:
        dist = metadata.distribution(DIST)
    except metadata.PackageNotFoundError:
        return  # run from a checkout
    if not _installed(dist):
        return
    bad, others = problems(dist)
    if not bad and not others:
        return
    who = ", ".join(others) if others else "an uninstalled distribution (factory_boy, say)"
    what = f"; {DIST}'s files changed: {', '.join(bad[:6])}{' ...' if len(bad) > 6 else ''}" if bad else ""
    raise InstallClashError(
        f"{DIST} shares the top-level package name 'factory' (or another of {', '.join(TOP_LEVEL)}) with {who}, "
        f"installed in {dist.locate_file('')}{what}. The two overwrite each other's files and cannot share one "
        f"environment: uninstall {who if others else 'it'} and reinstall {DIST} "
        f"(pip install --force-reinstall --no-deps {DIST}), or install them in separate virtual environments."
    )
