"""A sampled object: its ordered steps with their checks, and its LDraw form."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from factory.atomic import write_atomic
from factory.ldraw import get_reader, read_steps
from factory.parts import load_part
from factory.physics.check import Verdict
from factory.pose import Pose
from factory.sampler.density import density as _density

AUTHOR = "Brick Factory sampler"
_META = "0 // brick-factory"
_META_RE = re.compile(r"^0 // brick-factory (.*)$")


@dataclass(frozen=True, eq=False)
class AssemblyStep:
    """One placed part, with the checks of its placement."""

    part: str
    """Part file name as LDraw references it, e.g. `3001.dat`."""
    colour: int
    pose: Pose
    """World pose in LDU (LDraw axes, y down); the ground is at the first part's lowest point."""
    verdict: Verdict | None = None
    """The physics check of the chosen placement (None when read back from a file)."""
    rejected: dict[str, int] = field(default_factory=dict)
    """Candidates rejected in this step, by rule: the checker's reasons ('collision',
    'no-connection', 'clutch', 'unstable', ...) and 'below-ground' (feasible attachments reaching
    under the ground, dropped before the check), summed over the step's part draws."""
    checked: int = 0
    """Candidates the checker judged in this step, over all its part draws (in decreasing order of
    softmax key, up to the first survivor's batch: see `Sampler`)."""
    feasible: int = 0
    """Feasible attachments of the chosen part (before the ground filter and the subset)."""
    draws: int = 1
    """Part draws this step took (1 + redraws)."""
    density: float = 0.0
    """Density of the assembly after this step."""

    def same_placement(self, other: "AssemblyStep", atol: float = 1e-6) -> bool:
        return (self.part.lower() == other.part.lower() and self.colour == other.colour
                and self.pose.allclose(other.pose, atol))

    def to_json(self) -> dict:
        return {
            "part": self.part,
            "colour": self.colour,
            "R": self.pose.R.tolist(),
            "t": self.pose.t.tolist(),
            "rejected": dict(self.rejected),
            "checked": self.checked,
            "feasible": self.feasible,
            "draws": self.draws,
            "density": self.density,
            "load": None if self.verdict is None else self.verdict.load,
            "connections": None if self.verdict is None else self.verdict.connections,
        }


@dataclass(frozen=True, eq=False)
class Assembly:
    """An object grown by the sampler (or read back from its `.ldr`)."""

    steps: tuple[AssemblyStep, ...]
    density: float
    """Summed part volume / convex hull volume of the finished object (`factory.sampler.density`)."""
    seed: int | None = None
    index: int | None = None
    target_steps: int | None = None
    """The length drawn for this object in [min_steps, max_steps]."""
    end_reason: str | None = None
    """'target' (reached target_steps) or 'stuck' (none of the `max_redraws + 1` part draws of
    the next step had a surviving candidate; `stuck_rejected` says why)."""
    stuck_rejected: dict[str, int] = field(default_factory=dict)
    """For a stuck object: the candidates of the failed step rejected by rule (also
    'no-attachment': a drawn part had no feasible attachment at all)."""
    attempt: int = 0
    """Which attempt at the object this is: 0, the first, unless that one got stuck before
    `min_steps` parts; then the longest of the attempts made (`sampler.RESTARTS`)."""
    check_seconds: float = 0.0
    """Wall time spent in the physics checks while growing it (a measurement: not written to the
    `.ldr`, not part of the object)."""

    def __len__(self) -> int:
        return len(self.steps)

    @property
    def rejected(self) -> dict[str, int]:
        """Candidates rejected over the whole object, by rule."""
        out: dict[str, int] = {}
        for s in self.steps:
            for k, v in s.rejected.items():
                out[k] = out.get(k, 0) + v
        return dict(sorted(out.items()))

    def same_as(self, other: "Assembly", atol: float = 1e-6) -> bool:
        """Same parts, colours and poses in the same order."""
        return len(self) == len(other) and all(a.same_placement(b, atol) for a, b in zip(self.steps, other.steps))

    # -- LDraw ------------------------------------------------------------------------------------
    def ldr_text(self, name: str = "object.ldr") -> str:
        """The LDraw model: header, one part and one `0 STEP` per step (LF line endings)."""
        title = "Brick Factory sampled object"
        if self.index is not None:
            title += f" {self.index:05d}"
        lines = [f"0 {title}", f"0 Name: {name}", f"0 Author: {AUTHOR}", "0 !LDRAW_ORG Model"]
        meta = []
        if self.seed is not None:
            meta.append(f"seed {self.seed}")
        if self.index is not None:
            meta.append(f"index {self.index}")
        if self.target_steps is not None:
            meta.append(f"target_steps {self.target_steps}")
        meta.append(f"density {self.density:.6f}")
        if self.end_reason is not None:
            meta.append(f"end {self.end_reason}")
        if self.attempt:
            meta.append(f"attempt {self.attempt}")
        lines.append(f"{_META} {' '.join(meta)}")
        lines.append("")
        for s in self.steps:
            lines.append(s.pose.to_ldraw_line(s.colour, s.part))
            lines.append("0 STEP")
        return "\n".join(lines) + "\n"

    def to_ldr(self, path: str | os.PathLike) -> Path:
        """Write the model to `path` atomically (a temporary file beside it, then `os.replace`)."""
        path = Path(path)
        write_atomic(path, self.ldr_text(path.name).encode("utf-8"))
        return path

    @classmethod
    def from_ldr(cls, path: str | os.PathLike, ldraw: str | os.PathLike | None = None) -> "Assembly":
        """Read a model back: one step per placed part, in build order (checks not stored: the
        verdicts are None); the density is recomputed from the parts, seed and index are read
        from the sampler's comment line when present."""
        reader = get_reader(ldraw)
        steps = []
        for build_step in read_steps(path, ldraw):
            for p in build_step.parts:
                steps.append(AssemblyStep(p.part.replace("\\", "/").lower(), p.colour, p.pose))
        parts = [(load_part(reader, s.part), s.pose) for s in steps]
        meta = _read_meta(Path(path))
        return cls(
            steps=tuple(steps),
            density=_density(parts) if parts else 0.0,
            seed=int(meta["seed"]) if "seed" in meta else None,
            index=int(meta["index"]) if "index" in meta else None,
            target_steps=int(meta["target_steps"]) if "target_steps" in meta else None,
            end_reason=meta.get("end"),
            attempt=int(meta.get("attempt", 0)),
        )

    def to_json(self, steps: bool = False) -> dict:
        out = {
            "seed": self.seed,
            "index": self.index,
            "steps": len(self),
            "target_steps": self.target_steps,
            "end_reason": self.end_reason,
            "stuck_rejected": dict(self.stuck_rejected),
            "density": self.density,
            "rejected": self.rejected,
            "checked": sum(s.checked for s in self.steps),
            "redraws": sum(s.draws - 1 for s in self.steps),
            **({"attempt": self.attempt} if self.attempt else {}),
        }
        if steps:
            out["step_records"] = [s.to_json() for s in self.steps]
        return out


def _read_meta(path: Path) -> dict[str, str]:
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            m = _META_RE.match(line.strip())
            if m:
                tokens = m.group(1).split()
                return dict(zip(tokens[::2], tokens[1::2]))
    return {}


def steps_of(assembly: Assembly) -> Sequence[tuple[str, int, Pose]]:
    """(part, colour, pose) per step."""
    return [(s.part, s.colour, s.pose) for s in assembly.steps]
