"""Brick Factory: physics-verified synthetic data for LEGO-style assembly, from real LDraw parts.

The public API is the names below; modules not listed here are internal.
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
from factory.sampler import Assembly, AssemblyStep, Sampler, SamplerConfig, SamplerConfigError
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
    "build_steps",
    "get_reader",
    "load_part",
    "read_steps",
]
