"""The configuration of a dataset build: what goes into the rows, and how objects map to shards.

Everything that changes a byte of the data files is in `DatasetConfig` and in its hash; how the
build is run (backend, workers, output folder) is not. A build folder remembers the hash of the
config it was started with (`OUT/meta/config.json`); resuming it with another config is refused.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import asdict, dataclass, field, fields

from factory.dataset.schema import SCHEMA_VERSION

SOURCES = ("synthetic", "design")


class ConfigMismatchError(RuntimeError):
    """An output folder was started with another config; its message names the differences."""


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


@dataclass(frozen=True)
class DatasetConfig:
    """What a build produces. Object `i` (0-based) belongs to shard `i // objects_per_shard`."""

    source: str
    """'synthetic' (objects from `factory.sampler`) or 'design' (human LDraw models)."""
    n_objects: int
    seed: int = 0
    """Seed of the sampler (object i draws from `default_rng([seed, i])`) and of the split."""
    dataset_id: str = ""
    """Name written in every row; default `brick-factory-synth` / `brick-factory-designs`."""
    size: int = 256
    """Pixels per rendered view (the six-view composites are about 3 x 2 views)."""
    tile: int = 128
    """Pixels per catalog tile."""
    objects_per_shard: int = 4
    train_fraction: float = 0.8
    """Share of objects in the train split, decided per object from (seed, object id)."""
    png_compress_level: int = 6
    """Deflate level of the PNG images (0-9; `pipelines.dataset.png`)."""
    sampler: dict = field(default_factory=dict)
    """`SamplerConfig.to_json()` (synthetic only; its seed equals `seed`)."""
    models: tuple = ()
    """Design only: one dict per model, {"object_id", "path", "sha256"}, in object order."""
    ldraw: str | None = None
    """LDraw library folder (absolute), or None for the embedded library."""
    physics: bool = True
    """Design only: replay each model through the physics checks (`pipelines.verify`) and store
    the verdicts in the rows; without it the rows' physics record says it was not run."""

    def __post_init__(self):
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        if isinstance(self.n_objects, bool) or not isinstance(self.n_objects, int) or self.n_objects < 1:
            raise ValueError(f"the number of objects must be an integer >= 1, got {self.n_objects!r}")
        if self.n_objects > MAX_OBJECTS:
            raise ValueError(f"the number of objects must be at most {MAX_OBJECTS:,}, got {self.n_objects:,} "
                             "(split a larger dataset into several)")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2 ** 63:
            raise ValueError(f"seed must be an integer in 0..2**63-1 (stored as int64), got {self.seed!r}")
        if not 32 <= self.size <= 2048 or not 32 <= self.tile <= 1024:
            raise ValueError("size must be in 32..2048 and tile in 32..1024")
        if not isinstance(self.objects_per_shard, int) or self.objects_per_shard < 1:
            raise ValueError(f"objects_per_shard must be an integer >= 1, got {self.objects_per_shard!r}")
        if not 0.0 <= self.train_fraction <= 1.0:
            raise ValueError(f"train_fraction must be in [0, 1], got {self.train_fraction}")
        if not 0 <= self.png_compress_level <= 9:
            raise ValueError(f"png_compress_level must be in 0..9, got {self.png_compress_level}")
        if not self.dataset_id:
            default = "brick-factory-synth" if self.source == "synthetic" else "brick-factory-designs"
            object.__setattr__(self, "dataset_id", default)
        check_name(self.dataset_id, "dataset_id")
        object.__setattr__(self, "models", tuple(dict(m) for m in self.models))
        if self.source == "design" and len(self.models) != self.n_objects:
            raise ValueError("a design config needs one model entry per object")

    # -- identity ---------------------------------------------------------------------------------
    def to_json(self) -> dict:
        out = asdict(self)
        out["models"] = [dict(m) for m in self.models]
        out["schema_version"] = SCHEMA_VERSION
        return json.loads(_canonical(out))

    @classmethod
    def from_json(cls, data: dict) -> "DatasetConfig":
        names = {f.name for f in fields(cls)}
        return cls(**{k: (tuple(v) if k == "models" else v) for k, v in data.items() if k in names})

    @property
    def hash(self) -> str:
        """sha256 (hex, first 16 digits) of the canonical JSON of `to_json()`."""
        return hashlib.sha256(_canonical(self.to_json()).encode()).hexdigest()[:16]

    # -- layout -----------------------------------------------------------------------------------
    @property
    def num_shards(self) -> int:
        return max(1, math.ceil(self.n_objects / self.objects_per_shard))

    def shard_objects(self, shard: int) -> range:
        if not 0 <= shard < self.num_shards:
            raise ValueError(f"shard {shard} out of range 0..{self.num_shards - 1}")
        lo = shard * self.objects_per_shard
        return range(lo, min(self.n_objects, lo + self.objects_per_shard))

    def split(self, index: int) -> str:
        """The split of object `index` (see `split_of`)."""
        oid = self.object_id(index)
        if self.source == "design":
            return split_of(self.seed, oid, self.train_fraction)
        return split_of(self.seed, oid, self.train_fraction, index=index)

    def object_id(self, index: int) -> str:
        if self.source == "design":
            return str(self.models[index]["object_id"])
        return f"synth-s{self.seed}-{index:06d}"

    def shard_file(self, split: str, shard: int) -> str:
        """`data/{split}-NNNNN-of-NNNNN.parquet`, relative to the output folder."""
        return f"data/{split}-{shard:05d}-of-{self.num_shards:05d}.parquet"


def _uniform(*key) -> float:
    h = hashlib.sha256("/".join(["brick-factory-split", *map(str, key)]).encode()).digest()
    return int.from_bytes(h[:8], "big") / 2.0**64


MAX_OBJECTS = 10_000_000
"""Objects one dataset folder holds: 2.5 million shards of 4 and hundreds of millions of steps,
far past BC-Bench's 40K-step synthetic set; the shard list of a start stays about 100 MB."""

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")
"""A dataset or object id: it names files (export, the Hub) and the card's YAML, so letters,
digits, '.', '_' and '-', starting with a letter or digit, at most 128 characters."""


def check_name(value, what: str, where: str = "") -> str:
    """`value` when it is a plain name (`NAME`), else a ValueError naming `what` (and `where`)."""
    if not isinstance(value, str) or not NAME.fullmatch(value):
        raise ValueError(f"{where}{what} must be letters, digits, '.', '_' or '-' (starting with a letter or "
                         f"digit, at most 128 characters), got {value!r}")
    return value


def split_of(seed: int, object_id: str, train_fraction: float = 0.8, index: int | None = None) -> str:
    """'train' or 'test' for one object, from (seed, object id) alone (not N, order or shard).

    Synthetic objects (`index` given: the number in their id) are split systematically: with
    q = 1 - train_fraction and a phase u drawn from the seed, object i is in test when
    floor((i + 1) q + u) > floor(i q + u). Every run of consecutive objects then holds q of them in
    test up to one object (N = 8: 1 or 2; N = 700: exactly 140), so small builds get both splits.
    Human designs (named, in no particular order) are split by a uniform number drawn from
    sha256(seed, object id) against `train_fraction`, so adding a model moves no other model.
    """
    q = 1.0 - float(train_fraction)
    if index is not None:
        u = _uniform(int(seed), "phase")
        return "test" if math.floor((index + 1) * q + u) > math.floor(index * q + u) else "train"
    return "train" if _uniform(int(seed), object_id) < train_fraction else "test"


def diff_configs(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Human-readable differences between two config JSONs (`key: old -> new`)."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<absent>"), new.get(k, "<absent>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += diff_configs(a, b, f"{prefix}{k}.")
        elif a != b:
            sa, sb = json.dumps(a), json.dumps(b)
            if len(sa) > 60:
                sa = sa[:57] + "..."
            if len(sb) > 60:
                sb = sb[:57] + "..."
            out.append(f"{prefix}{k}: {sa} -> {sb}")
    return out

