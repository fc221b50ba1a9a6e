"""Where objects come from: the sampler (synthetic) and human LDraw designs, as `ObjectSpec`s;
world feedback (a model's wrong pose answers on another dataset) is a third source, given to the
builder by `pipelines.feedback` (it reads answers through `eval`, which the builder does not import).

An `ObjectSpec` is what the row builder needs: per step the parts already placed (`before`), the
parts the step places (`new`), the bricks the catalog offers, every part of the assembly the step
builds (framing and render scene), and the physics record of the step.

Human designs are shown the way a printed manual shows sub-assemblies: the sub-assembly's own
steps on their own (in its own frame, as its author built it, with only its own parts in view),
then one "module" step that attaches the finished sub-assembly to its parent, a multi-brick step
whose bricks are every part of the sub-assembly at its pose in the parent's frame. Nested
sub-assemblies nest the same way. The catalog of a step holds the bricks still in the box (every
brick of the model not yet placed), plus, for a module step, the module's own bricks.
"""

from __future__ import annotations

import hashlib
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from factory.ldraw import PlacedPart, build_steps, get_reader
from factory.ldraw.subassembly import UnitDone, walk
from factory.pose import Pose
from factory.replay import verify_model
from factory.sampler import Sampler, SamplerConfig


@dataclass
class Step:
    assembly: str
    """The assembly the step builds: `main`, or a sub-assembly tag such as `main/roof.ldr#1`."""
    kind: str
    """'part' (bricks from the catalog) or 'module' (a finished sub-assembly attached at once)."""
    before: tuple
    """`PlacedPart`s already in the assembly, in its frame."""
    new: tuple
    """`PlacedPart`s this step places, in the same frame."""
    catalog: tuple
    """(part, colour, model) of every brick offered by the catalog (any order; the row builder
    sorts); `model` as `PlacedPart.model` (None: the library's part). Synthetic steps give
    (part, colour)."""
    physics: dict
    scene: tuple = ()
    """Every part of the finished assembly (frames every step of it alike; one render scene)."""


@dataclass
class ObjectSpec:
    object_id: str
    source: str
    steps: list
    info: dict = field(default_factory=dict)
    """JSON-able facts about the object (kept in the shard's completion marker)."""
    stats: dict = field(default_factory=dict)
    """Counters summed into `info.json`: 'rejections' (synthetic), 'physics_flags' (design)."""
    timings: dict = field(default_factory=dict)
    """Seconds per stage spent making the object ('sample', 'check'; feedback: 'render', 'encode')."""
    rows: list | None = None
    """Finished rows, written as they are instead of rendered from `steps` (world feedback: rows
    derived from another dataset's rows, with the `feedback` image column)."""


def _py(v):
    """numpy scalars and arrays into plain JSON values."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not np.isfinite(v):
        return None  # JSON has no NaN or infinity
    if isinstance(v, np.ndarray):
        return _py(v.tolist())
    if isinstance(v, dict):
        return {str(k): _py(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_py(x) for x in v]
    return v


def verdict_json(verdict) -> dict | None:
    if verdict is None:
        return None
    keys = ("connected", "connections", "collision", "max_penetration_ldu", "touching", "clutch", "stable",
            "load", "reason")
    return {k: _py(getattr(verdict, k)) for k in keys}


# -- synthetic ---------------------------------------------------------------------------------------
class SyntheticSource:
    """Objects from `factory.sampler.Sampler`: one step per placed part, its sampler verdict."""

    def __init__(self, config, ldraw: str | None = None):
        self.sampler = Sampler(config, ldraw)

    def object(self, index: int, object_id: str, grown=None) -> ObjectSpec:
        """Object `index`, sampled here, or `grown` = (assembly, seconds) when it was grown ahead
        (`spool`: the same object)."""
        if grown is None:
            t0 = time.perf_counter()
            a = self.sampler.sample(index)
            total = time.perf_counter() - t0
        else:
            a, total = grown
        check = a.check_seconds
        placed = [PlacedPart(s.part, s.colour, s.pose, f"sampler:{k}") for k, s in enumerate(a.steps)]
        scene = tuple(placed)
        steps = []
        for k, s in enumerate(a.steps):
            record = {key: v for key, v in s.to_json().items() if key not in ("part", "colour", "R", "t")}
            physics = {"source": "sampler", "verdict": verdict_json(s.verdict), **_py(record)}
            steps.append(Step("main", "part", tuple(placed[:k]), (placed[k],),
                              tuple((p.part, p.colour) for p in placed[k:]), physics, scene))
        rejections = Counter(a.rejected)
        info = {"end_reason": a.end_reason, "target_steps": a.target_steps, "density": _py(a.density),
                "stuck_rejected": _py(dict(getattr(a, "stuck_rejected", {}) or {})),
                **({"attempt": a.attempt} if a.attempt else {})}
        return ObjectSpec(object_id, "synthetic", steps, info,
                          {"rejections": dict(rejections), "end_reasons": {str(a.end_reason): 1}},
                          {"sample": total - check, "check": check})


# -- human designs -----------------------------------------------------------------------------------
def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _physics_records(path, ldraw, enabled: bool):
    """verify_model's records, keyed by (build step, part index) and by sub-assembly tag."""
    if not enabled:
        return None, None, 0.0
    t = time.perf_counter()
    parts, units = {}, {}
    for r in verify_model(path, ldraw, "cpu"):  # the reference checks, one part at a time
        r = _py(r)
        if r.get("unit"):
            units[r["assembly"]] = r
        else:
            parts[(r["step"], r["index"])] = r
    return parts, units, time.perf_counter() - t


def manual_steps(model_path, ldraw=None, physics: bool = True) -> tuple[list[Step], dict, float]:
    """A human design's steps in manual order (see the module docstring; `factory.ldraw.subassembly.walk`),
    the count of physics flags by reason, and the seconds the physics replay took."""
    reader = get_reader(ldraw)
    frames: dict[str, Pose] = {}
    build = build_steps(reader, reader.open_model(model_path), frames)
    part_rec, unit_rec, seconds = _physics_records(model_path, ldraw, physics)
    inventory = Counter((p.part, p.colour, p.model) for s in build for p in s.parts)
    out: list[Step] = []
    flags: Counter = Counter()
    placed: dict[str, list[PlacedPart]] = {}
    """The parts of every open assembly, in its own frame."""
    not_run = {"source": "none", "note": "physics replay not run"}

    def emit(tag, kind, before, new, record):
        offered = list(inventory.elements())
        if kind == "module":
            offered += [(p.part, p.colour, p.model) for p in new]
        out.append(Step(tag, kind, tuple(before), tuple(new), tuple(offered), record))

    for event in walk(build, frames):
        if isinstance(event, UnitDone):
            new = [PlacedPart(p.part, p.colour, event.to_parent @ p.pose, p.source, p.model)
                   for p in placed.pop(event.tag)]
            if unit_rec is None:
                record = dict(not_run)
            else:
                unit = unit_rec.get(event.tag)
                record = {"source": "verify", "unit": unit, "bricks": []}
                if unit and unit.get("reason"):
                    flags[unit["reason"]] += 1
            parent = placed.setdefault(event.parent, [])
            emit(event.parent, "module", parent, new, record)
            parent.extend(new)
            continue
        step = event.step
        new = [PlacedPart(p.part, p.colour, event.to_local @ p.pose, p.source, p.model) for p in step.parts]
        if part_rec is None:
            record = dict(not_run)
        else:
            bricks = [part_rec.get((step.index, i)) for i in range(len(new))]
            record = {"source": "verify", "unit": None, "bricks": bricks}
            flags.update(b["reason"] for b in bricks if b and b.get("reason"))
        asm = placed.setdefault(step.assembly, [])
        emit(step.assembly, "part", asm, new, record)
        for p in step.parts:
            inventory[(p.part, p.colour, p.model)] -= 1
        asm.extend(new)
    # Every assembly's final parts (its last step's before + new), for framing.
    last: dict[str, tuple] = {}
    for s in out:
        last[s.assembly] = s.before + s.new
    for s in out:
        s.scene = last[s.assembly]
    return out, dict(flags), seconds


class DesignSource:
    """Human LDraw models, one object each (`config.models`)."""

    def __init__(self, models, ldraw: str | None = None, physics: bool = True):
        self.models, self.ldraw, self.physics = list(models), ldraw, physics

    def object(self, index: int, object_id: str) -> ObjectSpec:
        m = self.models[index]
        t = time.perf_counter()
        steps, flags, check = manual_steps(m["path"], self.ldraw, self.physics)
        total = time.perf_counter() - t
        info = {"model": m["path"], "sha256": m["sha256"], "physics": self.physics,
                "modules": sum(s.kind == "module" for s in steps)}
        return ObjectSpec(object_id, "design", steps, info, {"physics_flags": flags},
                          {"sample": total - check, "check": check})


class SourceError(ValueError):
    """A config whose object source the builder cannot make by itself."""


def make_source(config):
    """The object source of a `DatasetConfig` (a feedback dataset's is given to `build` by
    `pipelines.feedback`)."""
    if config.source == "synthetic":
        return SyntheticSource(config.sampler, config.ldraw)
    if config.source == "design":
        return DesignSource(config.models, config.ldraw, config.physics)
    raise SourceError(f"a {config.source} dataset's object source is given to the builder by its command "
                      "(world feedback: pipelines.feedback.build_feedback, `python -m train.feedback`)")
