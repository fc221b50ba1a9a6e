"""Brick Factory: physics-verified synthetic data for LEGO-style assembly, from real LDraw parts.

    import factory
    objects = factory.grow(8, factory.SamplerConfig(seed=7))         # grow objects: Assemblies
    objects[0].to_ldr("object_00000.ldr")
    found = factory.verify("model.mpd", ldraw="complete.zip", faults=True)   # verify a design
    found.summary["stud_fidelity"], found.rejected, found.to_json()

Building a dataset from them is `pipelines.dataset.build` (the builder sits above the dataset
contract, `factory.dataset`). The public API is the names below; modules not listed here are
internal.
"""

from factory import _startup  # noqa: F401  (first, before anything heavy: Ctrl-C while a command starts)
from factory.connections import Connector
from factory.errors import (
    LDrawCycleError,
    LDrawError,
    LDrawLimitError,
    LDrawMissingFileError,
    LDrawReadError,
    LDrawSyntaxError,
    LDrawUnsafePathError,
)
from factory.ldraw import (
    BuildStep,
    Colour,
    ColourTable,
    Library,
    PlacedPart,
    Reader,
    build_steps,
    get_reader,
    read_steps,
)
from factory.parts import Part, load_part
from factory.pose import LDU_M, Pose
from factory.replay import Verification, verify
from factory.sampler import Assembly, AssemblyStep, Sampler, SamplerConfig, SamplerConfigError, grow
from factory.symmetry import Symmetry

__all__ = [
    "LDU_M",
    "Assembly",
    "AssemblyStep",
    "BuildStep",
    "Colour",
    "ColourTable",
    "Connector",
    "LDrawCycleError",
    "LDrawError",
    "LDrawLimitError",
    "LDrawMissingFileError",
    "LDrawReadError",
    "LDrawSyntaxError",
    "LDrawUnsafePathError",
    "Library",
    "Part",
    "PlacedPart",
    "Pose",
    "Reader",
    "Sampler",
    "SamplerConfig",
    "SamplerConfigError",
    "Symmetry",
    "Verification",
    "build_steps",
    "get_reader",
    "grow",
    "load_part",
    "read_steps",
    "verify",
]
