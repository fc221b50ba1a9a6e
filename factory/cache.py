"""Where the factory keeps what it computes once per machine: `$BRICK_FACTORY_CACHE`, else
`~/.cache/brick-factory` (convex decompositions under `coacd/`, JAX's compiled kernels under `jax/`)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """The cache folder (not created here)."""
    root = os.environ.get("BRICK_FACTORY_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "brick-factory")
    return Path(root)
