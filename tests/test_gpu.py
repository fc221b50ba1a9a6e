"""The batched checks on an NVIDIA GPU (marker `gpu`): run where JAX's CUDA build sees a GPU,
skipped with the reason elsewhere. The same comparisons run on JAX's CPU backend in every run
(`test_lockstep`, `test_sweep_jax`, `test_collide_jax`); these say that a GPU gives the CPU
reference's objects too, and that the checks really ran there."""

from __future__ import annotations

import pytest

jax = pytest.importorskip("jax")

from factory import Sampler, SamplerConfig  # noqa: E402


def _gpus() -> list:
    try:
        return jax.devices("gpu")
    except RuntimeError:  # no CUDA build, or no device it can open
        return []


pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not _gpus(), reason="no GPU that JAX's CUDA build can use")]


def test_objects_grown_with_the_gpu_checks_are_the_cpu_references():
    """Objects of 10-14 parts grown one at a time and in lockstep with the 'jax' checks on the
    GPU are the objects the CPU reference grows, part for part."""
    from factory.sampler.lockstep import grow_together

    cfg = dict(seed=5, min_steps=10, max_steps=14)
    reference = [Sampler(SamplerConfig(**cfg, backend="cpu")).sample(i).ldr_text() for i in range(3)]
    gpu = Sampler(SamplerConfig(**cfg, backend="jax"))
    assert [gpu.sample(i).ldr_text() for i in range(3)] == reference
    together = sorted(grow_together(gpu, range(3), batch=3), key=lambda a: a.index)
    assert [a.ldr_text() for a in together] == reference
    assert jax.default_backend() == "gpu"
