"""The physics checks' backends by name: `BACKENDS`, their former names, and `backend_name`, the one
way every entry point that takes a backend reads it (`backend_arg` for a command line's flag)."""

from __future__ import annotations

import sys
import warnings

BACKENDS = ("cpu", "jax")
"""The physics checks' backends: 'cpu', the reference (MuJoCo's C collision and NumPy/SciPy, one
candidate at a time, on the CPU), and 'jax', the batched JAX kernels of this project
(`collide_jax`, `sweep_jax`, `lp_jax` and `loads_jax`: every candidate of a round at once, on a GPU
where there is one). Both give the same verdicts."""


OLD_BACKEND_NAMES = {"mujoco": "cpu", "mjx": "jax"}
"""The backends' former names (the batched one never used MuJoCo MJX), still accepted with a
`FutureWarning` by `backend_name`."""


def backend_name(name: str, stacklevel: int = 2) -> str:
    """The check backend `name` as `BACKENDS` spells it: a former name (`OLD_BACKEND_NAMES`) gives
    its new one with a `FutureWarning` (at `stacklevel` as `warnings.warn` counts it); any other
    name not in `BACKENDS` raises ValueError listing the valid choices. Every entry point that
    takes a backend goes through here."""
    if name in BACKENDS:
        return name
    if isinstance(name, str) and name in OLD_BACKEND_NAMES:
        new = OLD_BACKEND_NAMES[name]
        warnings.warn(f"check backend {name!r} is deprecated; use {new!r}", FutureWarning, stacklevel=stacklevel + 1)
        return new
    raise ValueError(f"unknown check backend {name!r}; valid choices: {', '.join(BACKENDS)}")


def backend_arg(text: str) -> str:
    """`backend_name` as an argparse `type` for `--check-backend`: a former name gives its new one
    with a warning line on stderr (as a renamed flag does); other text is left for the flag's
    `choices` to accept or refuse (a command may add its own, as `auto`)."""
    if text not in OLD_BACKEND_NAMES:
        return text
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        name = backend_name(text)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return name
