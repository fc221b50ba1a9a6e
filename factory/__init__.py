"""Brick Factory: physics-verified synthetic data for LEGO-style assembly, from real LDraw parts.

    import factory
    objects = factory.grow(8, factory.SamplerConfig(seed=7))         # grow objects: Assemblies
    objects[0].to_ldr("object_00000.ldr")
    found = factory.verify("model.mpd", ldraw="complete.zip", faults=True)   # verify a design
    found.summary["stud_fidelity"], found.rejected, found.to_json()
    factory.build_dataset(factory.DatasetConfig.synthetic(8, seed=0), "out/synth")  # build a dataset
    checker = factory.Checker(factory.CheckConfig(), "cpu")            # check placements yourself
    checker.check(structure, part, poses)                               # -> [Verdict]

`build_dataset` and `DatasetConfig` are the dataset builder's (`pipelines.dataset.build` and
its config), loaded on first use: the builder sits above the dataset contract (`factory.dataset`),
and no module of `factory` imports it. The public API is the names below; modules not listed here
are internal.
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
from factory.physics import Checker
from factory.physics.structure import Placed, Structure
from factory.physics.verdict import CheckConfig, Verdict
from factory.pose import LDU_M, Pose
from factory.replay import Verification, verify
from factory.sampler import Assembly, AssemblyStep, Sampler, SamplerConfig, SamplerConfigError, grow
from factory.symmetry import Symmetry

def __getattr__(name: str):
    """The dataset builder's names (`build_dataset`, `DatasetConfig`), imported on first use."""
    if name in ("build_dataset", "DatasetConfig"):
        # The one import up the layers, and only here: a facade over pipelines.dataset, loaded when
        # asked for (tests/test_imports.py allows it in this file only).
        from pipelines.dataset import DatasetConfig, build

        return build if name == "build_dataset" else DatasetConfig
    raise AttributeError(f"module 'factory' has no attribute {name!r}")


__all__ = [
    "LDU_M",
    "Assembly",
    "AssemblyStep",
    "BuildStep",
    "CheckConfig",
    "Checker",
    "Colour",
    "ColourTable",
    "Connector",
    "DatasetConfig",
    "LDrawCycleError",
    "LDrawError",
    "LDrawLimitError",
    "LDrawMissingFileError",
    "LDrawReadError",
    "LDrawSyntaxError",
    "LDrawUnsafePathError",
    "Library",
    "Part",
    "Placed",
    "PlacedPart",
    "Pose",
    "Reader",
    "Sampler",
    "SamplerConfig",
    "SamplerConfigError",
    "Structure",
    "Symmetry",
    "Verdict",
    "Verification",
    "build_dataset",
    "build_steps",
    "get_reader",
    "grow",
    "load_part",
    "read_steps",
    "verify",
]
