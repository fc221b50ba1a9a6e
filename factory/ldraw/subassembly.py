"""Walking a model's build steps the way a printed manual shows sub-assemblies.

A sub-assembly is built in its own frame (as its author built it), then attached to its parent as
one unit. `walk` turns `build_steps` output into that order of events: each build step with the
pose that takes model-frame poses into its assembly's frame (`PartsStep`), and, when a
sub-assembly is finished (the next step builds neither it nor one of its descendants), the pose
that takes it into its parent's frame (`UnitDone`). The physics replay of a design
(`factory.replay`) and the design dataset source (`pipelines.dataset.sources`) both walk through
here, so what is checked is what the rows show.

Frames are inverted exactly (`frame_inverse`): `Pose.inverse` transposes, which is off by about
1e-5 LDU for the rounded, not quite orthonormal matrices of real files (such as 0.707107).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from factory.ldraw.model import BuildStep
from factory.pose import Pose


def frame_inverse(frame: Pose) -> Pose:
    """The exact inverse of a frame (see the module docstring)."""
    inv = np.linalg.inv(frame.R)
    return Pose(inv, -inv @ frame.t)


def relative_frame(frames: Mapping[str, Pose], parent: str, child: str) -> Pose:
    """The pose that takes poses in sub-assembly `child`'s frame into `parent`'s frame."""
    return frame_inverse(frames.get(parent, Pose.identity())) @ frames.get(child, Pose.identity())


def to_local(frames: Mapping[str, Pose], tag: str) -> Pose:
    """The pose that takes model-frame poses into assembly `tag`'s frame."""
    return frame_inverse(frames.get(tag, Pose.identity()))


def parent_of(tag: str) -> str:
    """`main/a.ldr#1/b.ldr#2` -> `main/a.ldr#1`."""
    return tag.rsplit("/", 1)[0]


@dataclass(frozen=True)
class PartsStep:
    """A build step, with `to_local` taking its parts' model-frame poses into its assembly's frame."""

    step: BuildStep
    to_local: Pose


@dataclass(frozen=True)
class UnitDone:
    """Sub-assembly `tag` is finished: attach it, as one unit, to `parent` (`to_parent` takes poses
    in its frame into the parent's). `last_step`: the index of the last build step it took
    directly (0 when all of its parts came in sub-assemblies of its own)."""

    tag: str
    parent: str
    to_parent: Pose
    last_step: int


class _Open:
    __slots__ = ("tag", "parts", "last_step")

    def __init__(self, tag: str):
        self.tag, self.parts, self.last_step = tag, 0, 0


def walk(steps: Iterable[BuildStep], frames: Mapping[str, Pose]) -> Iterator[PartsStep | UnitDone]:
    """The manual's order of `steps` (see the module docstring). `frames`: every sub-assembly's
    frame in the model frame, as `build_steps(..., frames)` fills it. A sub-assembly that holds no
    part when it is finished is not attached (no `UnitDone`); the main model is never attached."""
    open_: list[_Open] = []

    def close_until(tag: str) -> Iterator[UnitDone]:
        while open_ and not (tag == open_[-1].tag or tag.startswith(open_[-1].tag + "/")):
            done = open_.pop()
            if not open_ or not done.parts:
                continue
            parent = open_[-1]
            parent.parts += done.parts
            yield UnitDone(done.tag, parent.tag, relative_frame(frames, parent.tag, done.tag), done.last_step)

    for step in steps:
        yield from close_until(step.assembly)
        # Open the step's sub-assembly and any ancestor not yet open (one with no part of its own
        # before this child's steps).
        path = step.assembly.split("/")
        for depth in range(1, len(path) + 1):
            tag = "/".join(path[:depth])
            if not any(a.tag == tag for a in open_):
                open_.append(_Open(tag))
        asm = open_[-1]
        asm.last_step = step.index
        asm.parts += len(step.parts)
        yield PartsStep(step, to_local(frames, asm.tag))
    yield from close_until("")
