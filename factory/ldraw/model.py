"""A model file into its ordered build steps, with submodels expanded in place.

Where a parent step places a submodel, the submodel's own steps come first, in order, with its parts
at their final poses in the model frame and tagged with the sub-assembly instance they build
(`main/wing.ldr#1`); the parent's step follows with the parts it places itself. Every part of the
flattened model is placed exactly once.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from factory.errors import LDrawLimitError, LDrawPlacementError, LDrawSyntaxError
from factory.ldraw.colours import RULE as COLOUR_RULE
from factory.ldraw.parse import LDrawFile, Ref, Step
from factory.ldraw.reader import MAX_DEPTH, Model, Reader, Resolved
from factory.pose import Pose, nearest_rotation_matrix

NO_PARTS = "places no parts (an empty model, or an MPD whose main block references no part or submodel)"
"""What the command lines say of a model that gives no build step."""

MAX_MODEL_PARTS = 200_000
"""Most part placements a model may expand to; the largest real sets have about 10,000."""

MAIN_ASSEMBLY = "main"


@dataclass(frozen=True)
class PlacedPart:
    """One part placed by a step: its file name, colour and pose in the model frame."""

    part: str
    colour: int
    pose: Pose
    source: str
    """`file:line` of the type 1 line that placed it."""
    model: str | None = None
    """The path of the model whose MPD blocks or folder hold the part (an unofficial part shipped
    with the model); None for a part of the library. `load_part(reader, placed)` finds the same
    file `build_steps` did."""


@dataclass(frozen=True)
class BuildStep:
    index: int
    assembly: str
    """The sub-assembly instance the step builds: `main`, `main/wing.ldr#1`, ..."""
    parts: tuple[PlacedPart, ...]
    frame: Pose = Pose.identity()
    """Where the sub-assembly's own frame sits in the model frame (identity for `main`)."""
    block: int = 0
    """How many STEP lines of its assembly's file come before it: its parts and the sub-assemblies
    that file references in the same block go in together (`build_steps`' `blocks`)."""

    def to_json(self) -> dict:
        return {
            "step": self.index,
            "assembly": self.assembly,
            "parts": [
                {
                    "part": p.part,
                    "color": p.colour,
                    "R": p.pose.R.tolist(),
                    "T": p.pose.t.tolist(),
                }
                for p in self.parts
            ],
        }


def is_submodel(res: Resolved) -> bool:
    """A reference to a model (expanded into steps) rather than to a part (placed whole)."""
    if res.origin == "library":
        return False
    f = res.file
    if f.is_part:
        return False
    has_faces = any(getattr(it, "kind", 0) in (3, 4) for it in f.items)
    return not (f.name.lower().endswith(".dat") and has_faces)


def build_steps(reader: Reader, model: Model, frames: dict[str, Pose] | None = None,
                blocks: dict[str, int] | None = None, flexible: set[str] | None = None) -> list[BuildStep]:
    """The model's build steps in order; steps that place no part are dropped.

    `frames`, when given, receives every sub-assembly instance's frame (also those with no part
    of their own), keyed by tag; `blocks` the STEP block of its parent's file that references it
    (as `BuildStep.block`); `flexible` the tags of sub-assemblies drawn as a flexible element
    (`LDrawFile.flexible`: a chain's links, a hose's segments).
    """
    main = Resolved(model.main, f"{model.path}#{model.main.name.lower()}", "mpd", model)
    _count_parts(reader, main, (), {})
    steps: list[BuildStep] = []
    _expand(reader, main, Pose.identity(), 16, MAIN_ASSEMBLY, steps, (), frames if frames is not None else {},
            blocks if blocks is not None else {}, flexible if flexible is not None else set())
    return steps


def count_parts(reader: Reader, model: Model) -> int:
    """Parts the model places in all, its submodels expanded, counted without expanding them
    (refused past `MAX_MODEL_PARTS`): a checker bounds its own work by it before `build_steps`."""
    main = Resolved(model.main, f"{model.path}#{model.main.name.lower()}", "mpd", model)
    return _count_parts(reader, main, (), {})


def _count_parts(reader: Reader, res: Resolved, stack: tuple[str, ...], memo: dict[str, int]) -> int:
    if res.key in memo:
        return memo[res.key]
    reader._check_stack(res, stack)
    total = 0
    for ref in res.file.refs:
        child = reader.resolve(ref, res.file, res.model)
        total += _count_parts(reader, child, stack + (res.key,), memo) if is_submodel(child) else 1
        if total > MAX_MODEL_PARTS:
            raise LDrawLimitError(
                f"model expands to more than {MAX_MODEL_PARTS:,} parts; refusing it",
                res.file.path,
                ref.line,
            )
    memo[res.key] = total
    return total


def _expand(
    reader: Reader,
    res: Resolved,
    pose: Pose,
    colour: int,
    assembly: str,
    out: list[BuildStep],
    stack: tuple[str, ...],
    frames: dict[str, Pose],
    blocks: dict[str, int],
    flexible: set[str],
) -> None:
    if len(stack) > MAX_DEPTH:
        raise LDrawLimitError(f"submodels nest more than {MAX_DEPTH} levels deep", res.file.path)
    frames[assembly] = pose
    current: list[PlacedPart] = []
    instances: dict[str, int] = defaultdict(int)
    block = 0

    def close_step() -> None:
        if current:
            out.append(BuildStep(len(out), assembly, tuple(current), pose, block))
            current.clear()

    for item in res.file.items:
        if isinstance(item, Step):
            close_step()
            block += 1
            continue
        if not isinstance(item, Ref):
            continue
        if not reader.colours.allows(item.colour):
            raise LDrawSyntaxError(f"unknown colour code {item.colour}; expected {COLOUR_RULE}", res.file.path,
                                   item.line)
        child = reader.resolve(item, res.file, res.model)
        mirror = None if is_submodel(child) else (lambda c=child: _mirror_plane(reader, c))
        child_pose = pose @ Pose(_placement_rotation(item, res.file.path, mirror), item.pos)
        child_colour = colour if item.colour == 16 else item.colour
        if is_submodel(child):
            label = _label(child.file, item)
            instances[label.lower()] += 1
            sub = f"{assembly}/{label}#{instances[label.lower()]}"
            blocks[sub] = block
            if child.file.flexible:
                flexible.add(sub)
            _expand(reader, child, child_pose, child_colour, sub, out, stack + (res.key,), frames, blocks, flexible)
        else:
            current.append(
                PlacedPart(item.name, child_colour, child_pose, f"{res.file.path}:{item.line}",
                           child.model.path if child.origin != "library" else None)
            )
    close_step()


ROTATION_TOL = 1e-3
"""How far a placement's rows may be from orthonormal and still be used as written: files write
matrices to a few decimals (0.707107 for a 45-degree turn is 1e-6 off)."""

NEAR_ROTATION = 0.05
"""Placements whose stretch (singular values) is within 5 % of 1 are turned into the nearest
rotation: hand-edited real files turn parts by approximate matrices (10156's minifig arms,
rows (1, 0.17, 0) and (-0.17, 1, 0): 1.4 % stretch). Anything further is refused."""


MIRROR_MATCH_LDU = 0.01
"""How close a part's mirrored vertices must lie to its own for the part to count as its own mirror
image (`_mirror_plane`)."""


def _mirror_plane(reader: Reader, res: Resolved) -> np.ndarray | None:
    """A reflection through one of the part's axis planes (diagonal, one -1) that maps the part's
    geometry onto itself, or None: a part placed by a mirroring matrix is then placed by that
    matrix times this reflection, a rotation that puts the same shape in the same place."""
    points = np.unique(np.round(reader.flatten(res).triangles.reshape(-1, 3), 4), axis=0)
    if not len(points):
        return None
    tree = cKDTree(points)
    for k in range(3):
        flip = np.ones(3)
        flip[k] = -1.0
        gap, _ = tree.query(points * flip)
        if float(gap.max()) <= MIRROR_MATCH_LDU:
            return np.diag(flip)
    return None


def _placement_rotation(ref: Ref, path: str, mirror=None) -> np.ndarray:
    """The rotation a part or submodel is placed by: its matrix when orthonormal within
    `ROTATION_TOL`, the nearest rotation when it stretches by at most `NEAR_ROTATION`; a part
    placed by a mirroring matrix that is its own mirror image (`mirror()`: the reflection, or None)
    by that matrix times the reflection (a hinge brick mirrored in a design's other half); a zero,
    rank-deficient, scaled, sheared, or otherwise mirrored matrix is refused
    (`LDrawPlacementError`, with the file and line). (Primitives inside a part may be scaled or
    mirrored, as the LDraw spec allows; they are not placed here.)"""
    m = np.asarray(ref.matrix, dtype=np.float64)
    if np.isfinite(m).all():
        stretch = np.linalg.svd(m, compute_uv=False)
        det = float(np.linalg.det(m))
        if det < 0 and mirror is not None and float(np.abs(stretch - 1.0).max()) <= NEAR_ROTATION:
            plane = mirror()
            if plane is not None:
                m, det = m @ plane, -det
        if det > 0 and float(np.abs(stretch - 1.0).max()) <= NEAR_ROTATION:
            if float(np.abs(m @ m.T - np.eye(3)).max()) <= ROTATION_TOL:
                return m
            return nearest_rotation_matrix(m)
        kind = "mirrors" if det < 0 else "scales or shears"
    else:
        det, kind = float("nan"), "is not finite and so scales"
    rows = "; ".join(" ".join(f"{v:g}" for v in row) for row in m)
    raise LDrawPlacementError(
        f"{ref.name} is placed by a matrix that {kind} it ({rows}; determinant {det:.3g}); a part or "
        f"submodel placement must be a rotation (orthonormal rows, determinant +1; within "
        f"{NEAR_ROTATION:.0%} it is taken as the nearest rotation), or mirror a part that is its own mirror image",
        path, ref.line)


def _label(f: LDrawFile, ref: Ref) -> str:
    name = f.name if f.name else ref.name
    return name.replace("\\", "/")
