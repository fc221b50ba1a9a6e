"""The sampler: physics-verified synthetic objects grown with a density reward, reproducible from a
seed. See `docs/concepts/sampler.md`.

    from factory.sampler import Sampler, SamplerConfig
    a = Sampler(SamplerConfig(seed=7)).sample(0)     # an Assembly
    a.to_ldr("object_00000.ldr")
    objects = grow(8, SamplerConfig(seed=7))         # objects 0..7 of that seed
"""

from factory.sampler.assembly import Assembly, AssemblyStep
from factory.sampler.config import (DEFAULT_COLOURS, DEFAULT_PARTS, RUN_SETTINGS, SamplerConfig, SamplerConfigError,
                                    default_check_batch)
from factory.sampler.density import density
from factory.sampler.sampler import Sampler, grow

__all__ = [
    "DEFAULT_COLOURS",
    "DEFAULT_PARTS",
    "RUN_SETTINGS",
    "Assembly",
    "AssemblyStep",
    "Sampler",
    "SamplerConfig",
    "SamplerConfigError",
    "default_check_batch",
    "density",
    "grow",
]
