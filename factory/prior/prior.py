"""A usage prior: how often real designs use each part family, colour and connection kind, as
draw weights for the sampler, with what it was fitted on.

Stored as JSON (`Prior.save` / `load_prior`), with a format version; the shipped default
(`DEFAULT_PRIOR`, `factory/data/prior.json`) is fitted by `pipelines.prior` on redistributable
designs its `designs` list names (docs/prior.md).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from factory.config import ConfigError

FORMAT = "brick-factory prior"
VERSION = 1
"""Version of the JSON layout below; a file of another version is refused, naming both."""

DEFAULT_PRIOR = Path(__file__).resolve().parents[1] / "data" / "prior.json"
"""The prior shipped with the project (what `--prior` defaults to)."""

STUDS = "studs"
SIDE_STUDS = "side studs"
OTHER = "pins, axles, clips, hinges"
MINIFIG = "minifigure"
NONE = "no connector"
UNKNOWN = "not in the library"
CONNECTION_KINDS = (STUDS, SIDE_STUDS, OTHER, MINIFIG, NONE, UNKNOWN)
"""How a part connects, judged from the part alone (`factory.prior.fit.connection_kind`): studs
and sockets only; studs pointing sideways too (brackets, headlight bricks); connector primitives
of pins, axles, clips or hinges, or, on a part with no studs and no sockets, a bar, a grip or a
hole the sampler finds in its drawing (`joints.joint_ends`); a minifigure piece; none of these (a
tyre, held by its shape); a part no library held."""


class PriorError(ConfigError):
    """A prior file that cannot be used; the message names the file and what was expected."""


@dataclass(frozen=True)
class PartUse:
    """One part family of a prior."""

    family: str
    """The family key (`factory.prior.families.family`): `3023` for 3023, 3023a, 3023b."""
    part: str
    """The part to place for it: the family's member designs placed most, unprinted."""
    weight: float
    """Draw weight (the weights of a prior sum to 1)."""
    placements: int
    """Placements of the family in the designs fitted."""
    designs: int
    """Designs that place it."""
    alternatives: tuple[str, ...] = ()
    """Other members the designs placed, most placed first: used where a library lacks `part`."""
    description: str = ""
    connection: str = UNKNOWN
    """Its connection kind (`CONNECTION_KINDS`)."""


@dataclass(frozen=True)
class DesignSource:
    """A design a prior was fitted on."""

    file: str
    """Its file name (no folder)."""
    placements: int
    licence: str
    """Its `0 !LICENSE` line ('' if none)."""


@dataclass(frozen=True)
class Prior:
    """Part, colour and connection-kind weights fitted to real designs."""

    parts: tuple[PartUse, ...]
    colours: tuple[tuple[int, float], ...]
    """(LDraw colour code, weight), weights summing to 1."""
    connections: tuple[tuple[str, float], ...]
    """(connection kind, share of placements), shares summing to 1 (not tempered: a fact)."""
    designs: tuple[DesignSource, ...]
    temper: float
    """Weights are the designs' mean shares raised to this power, then normalised (1: the mean
    share itself; below 1 flattens them, so rarely used parts are drawn more than their share)."""
    library: str = ""
    """The library the designs were resolved against when fitted (its description)."""

    def __post_init__(self):
        if not self.parts:
            raise PriorError("a prior needs at least one part")
        for name, values in (("parts", [p.weight for p in self.parts]), ("colours", [w for _, w in self.colours])):
            if any(not (math.isfinite(w) and w >= 0) for w in values) or (values and sum(values) <= 0):
                raise PriorError(f"{name}: weights must be finite, >= 0 and not all 0")
        for p in self.parts:
            if p.connection not in CONNECTION_KINDS:
                raise PriorError(f"part {p.part!r}: unknown connection kind {p.connection!r}; valid: "
                                 f"{', '.join(CONNECTION_KINDS)}")

    # -- JSON -------------------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "temper": self.temper,
            "library": self.library,
            "designs": [{"file": d.file, "placements": d.placements, "licence": d.licence} for d in self.designs],
            "connections": {k: round(v, 6) for k, v in self.connections},
            "colours": [{"code": c, "weight": round(w, 8)} for c, w in self.colours],
            "parts": [{
                "family": p.family, "part": p.part, "weight": round(p.weight, 8), "placements": p.placements,
                "designs": p.designs, "alternatives": list(p.alternatives), "description": p.description,
                "connection": p.connection,
            } for p in self.parts],
        }

    @classmethod
    def from_json(cls, data, where: str = "prior") -> "Prior":
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise PriorError(f"{where}: not a prior (expected a JSON object with \"format\": \"{FORMAT}\")")
        if data.get("version") != VERSION:
            raise PriorError(f"{where}: prior format version {data.get('version')!r}; this code reads version {VERSION}")
        try:
            parts = tuple(PartUse(
                family=str(p["family"]), part=str(p["part"]), weight=float(p["weight"]),
                placements=int(p["placements"]), designs=int(p["designs"]),
                alternatives=tuple(str(a) for a in p.get("alternatives", ())),
                description=str(p.get("description", "")), connection=str(p.get("connection", UNKNOWN)),
            ) for p in data["parts"])
            colours = tuple((int(c["code"]), float(c["weight"])) for c in data["colours"])
            connections = tuple((str(k), float(v)) for k, v in data["connections"].items())
            designs = tuple(DesignSource(str(d["file"]), int(d["placements"]), str(d.get("licence", "")))
                            for d in data["designs"])
            return cls(parts, colours, connections, designs, float(data["temper"]), str(data.get("library", "")))
        except PriorError as exc:
            raise PriorError(f"{where}: {exc}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise PriorError(f"{where}: malformed prior ({type(exc).__name__}: {exc}); expected the layout "
                             "`pipelines.prior` writes") from None

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=1) + "\n"

    def digest(self) -> str:
        """sha256 of the JSON text: what a dataset records of the prior it drew from."""
        return hashlib.sha256(self.dumps().encode()).hexdigest()

    def label(self, path: str | os.PathLike | None = None) -> str:
        """`name sha256:...` for records (the file's name; `default` for the shipped prior)."""
        name = "default" if path is None or Path(path).resolve() == DEFAULT_PRIOR else Path(path).name
        return f"{name} sha256:{self.digest()[:16]}"


MAX_PRIOR_BYTES = 16 * 1024 * 1024
"""A prior file larger than this is refused (a prior of every part of LDraw is under 2 MB)."""


def load_prior(path: str | os.PathLike | None = None) -> Prior:
    """The prior in `path` (default: `DEFAULT_PRIOR`); a clear `PriorError` naming the file
    otherwise."""
    p = Path(path) if path is not None else DEFAULT_PRIOR
    try:
        if p.stat().st_size > MAX_PRIOR_BYTES:
            raise PriorError(f"{p}: larger than {MAX_PRIOR_BYTES // 2**20} MB; not a prior")
        text = p.read_bytes().decode("utf-8")
        data = json.loads(text)
    except OSError as exc:
        raise PriorError(f"{p}: cannot read the prior ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        line = getattr(exc, "lineno", None)
        raise PriorError(f"{p}{f':{line}' if line else ''}: not JSON ({exc}); expected a prior written by "
                         "`pipelines.prior`") from None
    return Prior.from_json(data, str(p))
