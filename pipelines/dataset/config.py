"""The configuration of a dataset build: what goes into the rows, and how objects map to shards.

Everything that changes a byte of the data files is in `DatasetConfig` and in its hash; how the
build is run (runner, workers, output folder, and the physics checks' backend and batch sizes:
`factory.sampler.RUN_SETTINGS`) is not. A build folder remembers the hash of the config it was
started with (`OUT/meta/config.json`); resuming it with another config is refused. A folder
started by schema version 1, whose hash still held the run settings, resumes under its own hash
(`version1_record`, `started_hash`).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field, replace

from factory.config import ConfigError, config_from_dict, config_to_dict
from factory.dataset.schema import SCHEMA_VERSION, SCHEMA_VERSIONS
from factory.dataset.tasks import FEEDBACK_IMAGES, SPLITS
from factory.sampler import RUN_SETTINGS, SamplerConfig

SOURCES = ("synthetic", "design", "feedback")


class ConfigMismatchError(RuntimeError):
    """An output folder was started with another config; its message names the differences."""


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def record_hash(record: dict) -> str:
    """sha256 (hex, first 16 digits) of the canonical JSON of a config record (every schema version
    hashes its record this way; what the record holds is what changed)."""
    return hashlib.sha256(_canonical(record).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class FeedbackSpec:
    """Where the rows of a world-feedback dataset come from: a dataset split and a model's answers
    to it (`pipelines.feedback`). Object i of the feedback dataset is object `objects[i]` of the
    split; its rows are that object's wrong pose answers turned into correction conversations."""

    dataset: str
    """The dataset folder the predictions answer (absolute)."""
    dataset_id: str
    """That dataset's id (`meta/info.json`)."""
    config_hash: str | None
    """That dataset's config hash (None for folders not made by the builder, e.g. a BC-Bench import)."""
    split: str
    """The split of `dataset` the predictions answer (the recipe uses train)."""
    predictions: str
    """The predictions file (`eval.predict` output; absolute)."""
    predictions_sha256: str
    """sha256 of the predictions file: other answers make another dataset."""
    objects: tuple[str, ...]
    """The object ids of the split, in the dataset's order (its files, then its row groups)."""
    physics: bool = True
    """Execute each wrong prediction in the simulator (`eval.feedback.settle_answer`): the feedback
    shows and says where each brick ended up. False: the static feedback, the prediction drawn where
    it was put (what every feedback folder written before this field holds: a record without the
    key reads as False, and False is left out of the record, so such folders keep their hash)."""

    def __post_init__(self):
        if self.split not in SPLITS:
            raise ConfigError(f"feedback.split must be one of {', '.join(SPLITS)}, got {self.split!r}")
        object.__setattr__(self, "objects", tuple(self.objects))
        if len(set(self.objects)) != len(self.objects):
            raise ConfigError("feedback.objects: an object id is listed twice")


@dataclass(frozen=True)
class DatasetConfig:
    """What a build produces. Object `i` (0-based) belongs to shard `i // objects_per_shard`."""

    source: str
    """'synthetic' (objects from `factory.sampler`), 'design' (human LDraw models) or 'feedback'
    (a model's wrong pose answers as correction rows, `pipelines.feedback`)."""
    n_objects: int = field(metadata={"flag": "n"})
    """Objects in the dataset (synthetic: objects 0..n-1 of the sampler; design: one per model;
    feedback: one per object of the answered split)."""
    seed: int = 0
    """Seed of the sampler (object i draws from `default_rng([seed, i])`) and of the split."""
    dataset_id: str = ""
    """Name written in every row; default `brick-factory-synth` / `brick-factory-designs`."""
    size: int = 256
    """Pixels per rendered view (the six-view composites are about 3 x 2 views)."""
    tile: int = 128
    """Pixels per catalog tile."""
    objects_per_shard: int = 4
    """Objects per shard (a shard is the unit of work and of resume)."""
    train_fraction: float = 0.8
    """Share of objects in the train split, decided per object from (seed, object id)."""
    png_compress_level: int = field(default=6, metadata={"aliases": ("--png-level",)})
    """Deflate level of the PNG images (0-9; `pipelines.dataset.png`)."""
    sampler: SamplerConfig | None = None
    """Synthetic only: how objects are grown (default `SamplerConfig(seed=seed)`; its seed must
    equal `seed`). None for designs."""
    models: tuple[dict, ...] = ()
    """Design only: one dict per model, {"object_id", "path", "sha256"}, in object order."""
    ldraw: str | None = None
    """LDraw library folder or zip archive (absolute), or None for the embedded library (the command lines take
    $LDRAWDIR when --ldraw is not given)."""
    physics: bool = True
    """Design only: replay each model through the physics checks (`pipelines.verify`) and store
    the verdicts in the rows; without it the rows' physics record says it was not run."""
    feedback: FeedbackSpec | None = field(default=None, metadata={"flag": False})
    """Feedback only: the dataset split and predictions the rows come from (set by
    `pipelines.feedback`, not a flag). None for the other sources, and then left out of the
    config's JSON and hash."""

    def __post_init__(self):
        if self.source not in SOURCES:
            raise ConfigError(f"source must be one of {', '.join(SOURCES)}, got {self.source!r}")
        if isinstance(self.n_objects, bool) or not isinstance(self.n_objects, int) or self.n_objects < 1:
            raise ConfigError(f"the number of objects must be an integer >= 1, got {self.n_objects!r}")
        if self.n_objects > MAX_OBJECTS:
            raise ConfigError(f"the number of objects must be at most {MAX_OBJECTS:,}, got {self.n_objects:,} "
                              "(split a larger dataset into several)")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2 ** 63:
            raise ConfigError(f"seed must be an integer in 0..2**63-1 (stored as int64), got {self.seed!r}")
        if not 32 <= self.size <= 2048 or not 32 <= self.tile <= 1024:
            raise ConfigError("size must be in 32..2048 and tile in 32..1024")
        if not isinstance(self.objects_per_shard, int) or self.objects_per_shard < 1:
            raise ConfigError(f"objects_per_shard must be an integer >= 1, got {self.objects_per_shard!r}")
        if not 0.0 <= self.train_fraction <= 1.0:
            raise ConfigError(f"train_fraction must be in [0, 1], got {self.train_fraction}")
        if not 0 <= self.png_compress_level <= 9:
            raise ConfigError(f"png_compress_level must be in 0..9, got {self.png_compress_level}")
        if not self.dataset_id:
            default = {"synthetic": "brick-factory-synth", "design": "brick-factory-designs",
                       "feedback": "brick-factory-feedback"}[self.source]
            object.__setattr__(self, "dataset_id", default)
        check_name(self.dataset_id, "dataset_id")
        object.__setattr__(self, "models", tuple(dict(m) for m in self.models))
        if self.source == "design" and len(self.models) != self.n_objects:
            raise ConfigError("a design config needs one model entry per object")
        if self.source == "synthetic" and self.sampler is None:
            object.__setattr__(self, "sampler", SamplerConfig(seed=self.seed))
        if self.source == "synthetic" and not isinstance(self.sampler, SamplerConfig):
            raise ConfigError(f"sampler must be a SamplerConfig for a synthetic dataset, got {type(self.sampler).__name__}")
        if self.source == "synthetic" and self.sampler.seed != self.seed:
            raise ConfigError(f"sampler.seed ({self.sampler.seed}) must equal seed ({self.seed}): object i of the "
                              "dataset is object i of the sampler (DatasetConfig.synthetic sets it)")
        if self.source != "synthetic" and self.sampler is not None:
            raise ConfigError(f"a {self.source} dataset has no sampler (give sampler=None)")
        if (self.source == "feedback") != (self.feedback is not None):
            raise ConfigError("a feedback dataset needs its FeedbackSpec, and only a feedback dataset has one")
        if self.feedback is not None and len(self.feedback.objects) != self.n_objects:
            raise ConfigError(f"a feedback config needs one object per object of its split: n_objects is "
                              f"{self.n_objects}, feedback.objects has {len(self.feedback.objects)}")

    @classmethod
    def synthetic(cls, n_objects: int, seed: int = 0, sampler: SamplerConfig | None = None,
                  **fields) -> "DatasetConfig":
        """A synthetic dataset of `n_objects` objects grown by `sampler` (default settings when
        None), its seed set to `seed`; `fields` are further `DatasetConfig` fields."""
        sampler = replace(sampler or SamplerConfig(), seed=seed)
        return cls("synthetic", n_objects, seed=seed, sampler=sampler, **fields)

    # -- (de)serialisation and identity -------------------------------------------------------------
    def to_dict(self) -> dict:
        """Every field as JSON values (`factory.config`)."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "DatasetConfig":
        """The inverse of `to_dict`; unknown keys are refused, naming the valid ones."""
        return config_from_dict(cls, data, ConfigError)

    def to_json(self) -> dict:
        """`to_dict()` plus `schema_version`, less the sampler's run settings (`RUN_SETTINGS`: the
        checks' backend, `check_batch`, `judge_first`, which change no byte of the data): the
        dataset's identity, hashed and written to `meta/`. A design's sampler is `{}` there, as in
        folders written before the field was typed, and `feedback` is there only for a feedback
        dataset. To send a whole config, run settings included, to a worker: `to_dict`."""
        out = self.to_dict()
        out["sampler"] = {k: v for k, v in (out["sampler"] or {}).items() if k not in RUN_SETTINGS}
        if out["feedback"] is None:
            del out["feedback"]
        elif not out["feedback"].get("physics", True):
            del out["feedback"]["physics"]
        out["schema_version"] = SCHEMA_VERSION
        return json.loads(_canonical(out))

    @classmethod
    def from_json(cls, data: dict) -> "DatasetConfig":
        """The inverse of `to_json`, the sampler's run settings at their defaults. A record of
        schema version 1 is read too, its sampler's run settings (the backend, as 'mujoco' or
        'mjx', and the batch sizes) dropped; a record of a version this code does not know is
        refused."""
        data = dict(data)
        version = data.pop("schema_version", SCHEMA_VERSION)
        if version not in SCHEMA_VERSIONS:
            raise ConfigError(f"config of row schema version {version!r}; this code reads versions "
                              f"{', '.join(map(str, SCHEMA_VERSIONS))}")
        if isinstance(data.get("feedback"), dict) and "physics" not in data["feedback"]:
            data["feedback"] = {**data["feedback"], "physics": False}
        if data.get("sampler") == {}:
            data["sampler"] = None
        elif version == 1 and isinstance(data.get("sampler"), dict):
            data["sampler"] = {k: v for k, v in data["sampler"].items() if k not in RUN_SETTINGS}
        return cls.from_dict(data)

    @classmethod
    def from_any(cls, data: dict) -> "DatasetConfig":
        """A config sent as `to_dict()` (every setting, as the builder sends it to its workers) or
        as `to_json()` (a record with `schema_version`: the run settings at their defaults)."""
        return cls.from_json(data) if "schema_version" in data else cls.from_dict(data)

    @property
    def hash(self) -> str:
        """`record_hash` of `to_json()`: the same for every run setting (`RUN_SETTINGS`)."""
        return record_hash(self.to_json())

    # -- layout -----------------------------------------------------------------------------------
    @property
    def num_shards(self) -> int:
        return max(1, math.ceil(self.n_objects / self.objects_per_shard))

    def shard_objects(self, shard: int) -> range:
        if not 0 <= shard < self.num_shards:
            raise ValueError(f"shard {shard} out of range 0..{self.num_shards - 1}")
        lo = shard * self.objects_per_shard
        return range(lo, min(self.n_objects, lo + self.objects_per_shard))

    @property
    def extra_images(self) -> tuple[str, ...]:
        """Image columns beyond the row schema's (`factory.dataset.schema.arrow_schema`): a feedback
        dataset's `feedback` render."""
        return FEEDBACK_IMAGES if self.source == "feedback" else ()

    @property
    def extra_fields(self) -> tuple[str, ...]:
        """Columns of `factory.dataset.schema.EXTRA_FIELDS` the rows carry: `settled` for a feedback
        dataset whose predictions are executed (`FeedbackSpec.physics`)."""
        return ("settled",) if self.source == "feedback" and self.feedback is not None and self.feedback.physics else ()

    def split(self, index: int) -> str:
        """The split of object `index` (see `split_of`); a feedback dataset's rows are all train."""
        if self.source == "feedback":
            return "train"
        oid = self.object_id(index)
        if self.source == "design":
            return split_of(self.seed, oid, self.train_fraction)
        return split_of(self.seed, oid, self.train_fraction, index=index)

    def object_id(self, index: int) -> str:
        if self.source == "design":
            return str(self.models[index]["object_id"])
        if self.source == "feedback":
            return self.feedback.objects[index]
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


def version1_record(config: DatasetConfig, recorded: dict) -> dict:
    """The config record the schema-version-1 code wrote for `config` built with the run settings
    that `recorded` (the `config` of a version-1 `meta/config.json`) holds.

    The version-1 rule: `to_json()` with `schema_version` 1 and the sampler's run settings
    (`RUN_SETTINGS`: `backend` as 'mujoco' or 'mjx', `check_batch`, and `judge_first` where not at
    its default) inside, hashed by `record_hash`. Version 2 leaves the run settings out, so they
    are put back here as recorded (any backend resumes the folder: both write the same files);
    every other setting comes from `config`, so the hash equals the recorded one only when they
    are the same."""
    record = config.to_json()
    sampler = recorded.get("sampler") if isinstance(recorded, dict) else None
    if record["sampler"] and isinstance(sampler, dict):
        record["sampler"] = {**record["sampler"], **{k: sampler[k] for k in RUN_SETTINGS if k in sampler}}
    record["schema_version"] = 1
    return record


def started_hash(config: DatasetConfig, stored) -> str | None:
    """The hash under which a folder whose `meta/config.json` holds `stored` (`{"config_hash",
    "config"}`) was started with `config`, or None when it was started with another config: its
    own recorded hash, checked by the rule of the version that wrote it (`config.hash` for version
    2, that of `version1_record` for version 1). A folder keeps its hash for good: its shard
    markers and `meta/info.json` carry it."""
    if not isinstance(stored, dict) or not isinstance(stored.get("config"), dict):
        return None
    recorded, known = stored["config"], stored.get("config_hash")
    if recorded.get("schema_version") == 1:
        return known if known == record_hash(version1_record(config, recorded)) else None
    return known if known == config.hash else None


def started_record(config: DatasetConfig, stored) -> dict:
    """`config`'s record in the form of the version that wrote `stored` (see `started_hash`), to
    name the differences from it."""
    recorded = stored.get("config") if isinstance(stored, dict) else None
    if isinstance(recorded, dict) and recorded.get("schema_version") == 1:
        return version1_record(config, recorded)
    return config.to_json()
