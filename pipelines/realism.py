"""How far a set of objects is from real designs: the tables and distances of `pipelines.distance`.

A `Collection` is what a set of objects places, part by part: a folder of LDraw models (real
designs, or the `.ldr` files `pipelines.sample` writes) or a dataset folder (its Parquet rows'
`bricks`). `compare` puts two side by side, one table per statistic, each with one distance:

- part usage: the share of the real placements whose part family the objects use at all
  (coverage), the real families they miss (by placements), and the total variation distance
  between the two family distributions;
- category (LDraw's: `Plate`, `Brick`, `Slope`, `Technic`, ...), colour, connection kind (of the
  part, as the prior counts them: `factory.prior.fit.connection_kind`) and orientation (upright,
  on its side, upside down): total variation distance, 0 (same shares) to 1 (disjoint);
- connection directions: each stud of one part in a socket of another (as the checks match them:
  `factory.physics.structure.match`), by the stud's direction in the object's frame: up (a part
  on another), down (a part upside down) or sideways (brackets, headlight bricks); total variation;
- parts per object and density (summed part volume over the hull's, as the sampler's reward
  scores it: `factory.sampler.density`): the 1-Wasserstein distance, in parts and in density.

Connections and density need each part's geometry: a part the library lacks is left out of them.

Families fold printed variants, revisions and renumbered parts (`factory.prior.families`), so an
embedded `3023` and a real `3023b` count as one part.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from factory.errors import LDrawError
from factory.ldraw import Reader
from factory.parts import load_part
from factory.physics.structure import connectors, match
from factory.pose import Pose
from factory.sampler.density import density
from factory.prior.families import family
from factory.prior.fit import connection_kind, resolved_name
from factory.prior.placements import Use, read_design

MODEL_SUFFIXES = (".ldr", ".mpd", ".lcad")
UPRIGHT, SIDEWAYS, UPSIDE_DOWN = "upright", "on its side", "upside down"
UP_COS = 0.9
"""A part is upright when its up direction is within ~26 degrees of the world's up (cos > 0.9),
upside down when within that of down, on its side otherwise."""


@dataclass
class Placement:
    part: str
    """Resolved part name (past `~Moved to`, unprinted where the library has it)."""
    family: str
    colour: int
    up: float
    matrix: np.ndarray | None = None
    """Rotation in the object's frame (LDraw's), None where not known."""
    pos: np.ndarray | None = None
    """Position in the object's frame (LDU)."""


@dataclass
class Collection:
    """The placements of a set of objects, object by object."""

    name: str
    objects: list[list[Placement]] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    """Files that could not be read, with why."""

    @property
    def placements(self) -> list[Placement]:
        return [p for obj in self.objects for p in obj]


def _placement(reader: Reader, use: Use) -> Placement:
    name = resolved_name(reader, use)
    return Placement(name, family(name), use.colour, use.up, use.matrix, use.pos)


def read_collection(path: str | os.PathLike, reader: Reader, name: str | None = None) -> Collection:
    """The objects in `path`: a dataset folder (has `data/*.parquet`), a folder of LDraw models,
    or one model file. A model that cannot be read is skipped and listed."""
    path = Path(path)
    out = Collection(name or path.name)
    if (path / "data").is_dir() and any((path / "data").glob("*.parquet")):
        return _read_dataset(path, reader, out)
    files = [path] if path.is_file() else sorted(
        f for f in path.iterdir() if f.is_file() and f.suffix.lower() in MODEL_SUFFIXES)
    if not files:
        raise FileNotFoundError(f"{path}: no LDraw models ({', '.join(MODEL_SUFFIXES)}) and no dataset (data/*.parquet)")
    for f in files:
        try:
            design = read_design(reader, f)
        except LDrawError as exc:
            out.skipped.append(f"{f.name}: {exc}")
            continue
        if design.uses:
            out.objects.append([_placement(reader, u) for u in design.uses])
    return out


def _read_dataset(path: Path, reader: Reader, out: Collection) -> Collection:
    objects: dict[str, list[Placement]] = {}
    for f in sorted((path / "data").glob("*.parquet")):
        table = pq.read_table(f, columns=["object_id", "step_kind", "bricks"])
        for oid, kind, bricks in zip(*(table.column(c).to_pylist() for c in ("object_id", "step_kind", "bricks"))):
            for b in bricks or ():
                name = b["part"].lower().removesuffix(".dat")
                found = reader.library.lookup(name + ".dat") is not None
                R = np.asarray(b["R"], dtype=np.float64)  # maps the part's frame into the model's
                use = Use(name, int(b["colour"]), reader.part(name) if found else None, float(R[1, 1]), R,
                          np.asarray(b["T"], dtype=np.float64))
                objects.setdefault(oid, []).append(_placement(reader, use))
    out.objects = [objects[k] for k in sorted(objects)]
    return out


# -- statistics ----------------------------------------------------------------------------------
def _shares(counter: Counter) -> dict:
    total = sum(counter.values())
    return {k: v / total for k, v in counter.items()} if total else {}


def total_variation(a: Counter, b: Counter) -> float:
    """Half the L1 distance between the two normalised distributions (0 same, 1 disjoint)."""
    pa, pb = _shares(a), _shares(b)
    return 0.5 * sum(abs(pa.get(k, 0.0) - pb.get(k, 0.0)) for k in set(pa) | set(pb))


def wasserstein(a: list[float], b: list[float]) -> float:
    """1-Wasserstein distance between two samples of numbers (the area between their CDFs)."""
    if not a or not b:
        return float("nan")
    xs = np.sort(np.concatenate([a, b]))
    ca = np.searchsorted(np.sort(a), xs[:-1], side="right") / len(a)
    cb = np.searchsorted(np.sort(b), xs[:-1], side="right") / len(b)
    return float(np.sum(np.abs(ca - cb) * np.diff(xs)))


STUDS_UP, STUDS_DOWN, STUDS_SIDEWAYS = "stud up", "stud down", "stud sideways"


def stud_direction(axis: np.ndarray) -> str:
    """A connection's direction by its stud's axis in the object's frame (up is -y)."""
    up = -float(axis[1])
    return STUDS_UP if up > UP_COS else STUDS_DOWN if up < -UP_COS else STUDS_SIDEWAYS


class PartShapes:
    """Each part's geometry, loaded once (None for a part the library lacks or cannot give)."""

    def __init__(self, reader: Reader):
        self.reader, self.parts = reader, {}

    def __call__(self, name: str):
        if name not in self.parts:
            try:
                found = self.reader.library.lookup(name + ".dat") is not None
                self.parts[name] = load_part(self.reader, name) if found else None
            except LDrawError:
                self.parts[name] = None
        return self.parts[name]


def _gather(placed: list, which: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, axes and owning part (index) of every stud or socket of the placed parts."""
    pos, axis, owner = [np.zeros((0, 3))], [np.zeros((0, 3))], [np.zeros(0, np.int64)]
    for k, (part, pose) in enumerate(placed):
        p, a = connectors(part, pose, which)
        pos.append(p)
        axis.append(a)
        owner.append(np.full(len(p), k))
    return np.concatenate(pos), np.concatenate(axis), np.concatenate(owner)


def connection_directions_and_density(objects: "Collection", shapes: PartShapes) -> tuple[Counter, list[float]]:
    """The directions of every stud-in-socket connection between two parts of an object, and each
    object's density (objects with fewer than two known parts have none)."""
    directions: Counter = Counter()
    densities: list[float] = []
    for obj in objects.objects:
        placed = [(shapes(p.part), Pose(p.matrix, p.pos)) for p in obj if p.matrix is not None]
        placed = [(part, pose) for part, pose in placed if part is not None]
        if len(placed) < 2:
            continue
        densities.append(density(placed))
        sp, sa, so = _gather(placed, "studs")
        kp, ka, ko = _gather(placed, "sockets")
        for i, j in match(sp, sa, kp, ka):
            if so[i] != ko[j]:
                directions[stud_direction(sa[i])] += 1
    return directions, densities


def orientation(up: float) -> str:
    return UPRIGHT if up > UP_COS else UPSIDE_DOWN if up < -UP_COS else SIDEWAYS


@dataclass
class Table:
    """One statistic of both collections, side by side."""

    name: str
    distance_name: str
    distance: float
    rows: list[tuple[str, float, float]]
    """(key, share in the objects, share in the real designs), largest real share first."""
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"table": self.name, "distance": self.distance_name, "value": round(self.distance, 4),
                "rows": [{"key": k, "objects": round(a, 4), "real": round(b, 4)} for k, a, b in self.rows],
                **self.extra}


def _table(name: str, a: Counter, b: Counter, top: int | None = None) -> Table:
    pa, pb = _shares(a), _shares(b)
    keys = sorted(set(pa) | set(pb), key=lambda k: (-pb.get(k, 0.0), -pa.get(k, 0.0), str(k)))
    rows = [(str(k), pa.get(k, 0.0), pb.get(k, 0.0)) for k in keys[:top]]
    return Table(name, "total variation", total_variation(a, b), rows)


def coverage(objects: Collection, real: Collection) -> tuple[float, int, int]:
    """(share, covered, total): the real placements whose family the objects place at all."""
    used = {p.family for p in objects.placements}
    fams = [p.family for p in real.placements]
    covered = sum(f in used for f in fams)
    return (covered / len(fams) if fams else float("nan")), covered, len(fams)


def compare(objects: Collection, real: Collection, reader: Reader, top: int = 25) -> list[Table]:
    """The side-by-side tables of `objects` and `real` (read with the same library)."""
    a, b = objects.placements, real.placements
    share, covered, total = coverage(objects, real)
    fa, fb = Counter(p.family for p in a), Counter(p.family for p in b)
    parts = _table("part families", fa, fb, top)
    missed = Counter({f: n for f, n in fb.items() if f not in fa})
    parts.extra = {
        "coverage": round(share, 4), "covered_placements": covered, "real_placements": total,
        "families_objects": len(fa), "families_real": len(fb),
        "most_missed": [{"family": f, "placements": n, "share": round(n / total, 4),
                         "description": _description(reader, f, b)} for f, n in missed.most_common(top)],
    }
    kinds: dict[str, str] = {}
    cats: dict[str, str] = {}

    def kind(p: Placement) -> str:
        if p.part not in kinds:
            kinds[p.part] = connection_kind(reader, p.part)[0] if reader.library.lookup(p.part + ".dat") else \
                "not in the library"
        return kinds[p.part]

    def category(p: Placement) -> str:
        if p.part not in cats:
            loc = reader.library.lookup(p.part + ".dat")
            cats[p.part] = reader.part(p.part).file.part_category or "?" if loc else "not in the library"
        return cats[p.part]

    tables = [
        parts,
        _table("categories", Counter(map(category, a)), Counter(map(category, b)), top),
        _table("colours", Counter(p.colour for p in a), Counter(p.colour for p in b), top),
        _table("connection kinds", Counter(map(kind, a)), Counter(map(kind, b))),
        _table("orientation", Counter(orientation(p.up) for p in a), Counter(orientation(p.up) for p in b)),
    ]
    na, nb = [len(o) for o in objects.objects], [len(o) for o in real.objects]
    edges = [0, 10, 20, 30, 45, 60, 90, 120, 200, 500, 1000, 10 ** 9]
    hist = lambda n: Counter(next(f"{lo}-{hi - 1}" if hi < 10 ** 9 else f"{lo}+" for lo, hi in zip(edges, edges[1:])
                                  if lo <= x < hi) for x in n)
    per = _table("parts per object", hist(na), hist(nb))
    per.distance_name, per.distance = "1-Wasserstein (parts)", wasserstein(na, nb)
    per.rows = sorted(per.rows, key=lambda r: int(r[0].split("-")[0].rstrip("+")))
    per.extra = {"objects": len(na), "real_designs": len(nb), "median_objects": float(np.median(na)) if na else None,
                 "median_real": float(np.median(nb)) if nb else None}
    tables.append(per)
    shapes = PartShapes(reader)
    (da, dens_a), (db, dens_b) = (connection_directions_and_density(c, shapes) for c in (objects, real))
    dirs = _table("connection directions", da, db)
    dirs.extra = {"connections_objects": sum(da.values()), "connections_real": sum(db.values())}
    tables.append(dirs)
    bins = [0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1.01]
    dhist = lambda d: Counter(next(f"{lo:.2f}-{hi:.2f}" for lo, hi in zip(bins, bins[1:]) if lo <= x < hi)  # noqa: E731
                              for x in d if 0 <= x < bins[-1])
    dens = _table("density", dhist(dens_a), dhist(dens_b))
    dens.distance_name, dens.distance = "1-Wasserstein (density)", wasserstein(dens_a, dens_b)
    dens.rows = sorted(dens.rows, key=lambda r: float(r[0].split("-")[0]))
    dens.extra = {"median_objects": float(np.median(dens_a)) if dens_a else None,
                  "median_real": float(np.median(dens_b)) if dens_b else None}
    tables.append(dens)
    return tables


def _description(reader: Reader, fam: str, placements: list[Placement]) -> str:
    name = next((p.part for p in placements if p.family == fam), fam)
    try:
        return reader.part(name).file.description if reader.library.lookup(name + ".dat") else ""
    except LDrawError:  # a description is a courtesy: a part that cannot be parsed has none
        return ""
