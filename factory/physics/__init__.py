"""Physics checks of placements: connections, collision, clutch, buildability, whole-structure loads.
`Checker` asks them with its own caches and counters (`checker.py`).

Many processes of one run share a GPU (the grower and shard workers of `pipelines.synth`, the
workers of `pipelines.sample`, and the parent that asks JAX which backend it has). JAX takes 75% of
a GPU's memory at its first use by default, so the first process starved the others: a 16-worker
`synth` on one H100 ended in `CUDA_ERROR_OUT_OF_MEMORY` in every other process (2026-11-25). The
factory's JAX processes allocate as they need instead, unless the user set it.
"""

import os

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

from factory.physics.checker import Checker  # noqa: E402  (after the setting: JAX may load below)

__all__ = ["Checker"]
