"""`meta/info.json`, typed: what a dataset folder holds, where it came from, and how many rows.

Every writer of a dataset folder (the builder, the BC-Bench import, world-feedback datasets) builds
a `DatasetInfo` and writes it with `write_info`; every reader gets one from `read_info`, which
checks the file and names the key and the file of any fault. The JSON is the one that builds have
always written (sorted keys, 1-space indent), so a folder written before this module loads as is.

One policy for keys: every key of the file is a field here, or a fact of its source listed in
`DETAILS` (kept in `details`, written back at the top level); any other key is refused, naming
the keys that are valid for that source.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

from factory.atomic import write_atomic
from factory.config import config_from_dict
from factory.dataset.schema import SCHEMA_VERSION
from factory.dataset.tasks import SPLITS, TASKS

INFO_SOURCES = ("synthetic", "design", "bcbench", "feedback")
"""Where a dataset's rows come from: the sampler, human LDraw designs (both through the builder),
BC-Bench's released tasks (`pipelines.bcbench`) and a model's wrong pose answers (`train.feedback`)."""

DETAILS = {
    "synthetic": (),
    "design": (),
    "bcbench": ("blank_steps_skipped", "bcbench_import"),
    "feedback": ("source_dataset", "source_dataset_id", "source_config_hash", "source_split",
                 "predictions", "predictions_sha256", "reasons"),
}
"""Facts a source adds at the top level of info.json, beside `DatasetInfo`'s fields."""

EXTRA_IMAGES_KEY = "schema_extra_columns"
"""The info.json key of `DatasetInfo.extra_images` (the name feedback folders have always used)."""

_LEGACY_KIND = "kind"
"""Feedback folders written before `source` named them said ``"kind": "feedback"`` instead."""


class InfoError(ValueError):
    """A meta/info.json that is missing, not JSON, or not a dataset's info; the message names the file."""


def json_bytes(obj) -> bytes:
    """Deterministic, readable JSON (sorted keys, 1-space indent, trailing newline)."""
    return (json.dumps(obj, sort_keys=True, indent=1, ensure_ascii=False, allow_nan=False) + "\n").encode()


@dataclass(frozen=True)
class Counts:
    """Objects and steps (rows) of a split or of the whole dataset; `bytes` of its Parquet files,
    where the writer counted them (None: not counted, as in feedback folders)."""

    objects: int
    steps: int
    bytes: int | None = None

    @classmethod
    def from_dict(cls, data, where: str) -> Counts:
        """The configs' key policy (`factory.config.config_from_dict`), then counts that are
        integers >= 0."""
        counts = config_from_dict(cls, data, InfoError, where)
        for key in ("objects", "steps", "bytes"):
            v = getattr(counts, key)
            if key == "bytes" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise InfoError(f"{where}.{key} must be an integer >= 0, got {v!r}")
        return counts

    def to_dict(self) -> dict:
        out = {"objects": self.objects, "steps": self.steps}
        if self.bytes is not None:
            out["bytes"] = self.bytes
        return out


@dataclass(frozen=True)
class DatasetInfo:
    """The contents of `meta/info.json` (see the module docstring)."""

    dataset_id: str
    """Name written in every row."""
    source: str
    """One of `INFO_SOURCES`."""
    config: dict
    """The settings the rows were made with (the builder: `DatasetConfig.to_json()`; a feedback
    dataset: its source dataset's; BC-Bench: the library and view size)."""
    counts: dict
    """{split: `Counts`} for the splits the writer counted."""
    total: Counts
    """The sum of `counts`."""
    splits_present: tuple[str, ...]
    """The splits with at least one row, in `SPLITS` order."""
    schema_version: int = SCHEMA_VERSION
    """Version of the row layout and of this file (`factory.dataset.schema.SCHEMA_VERSION`)."""
    seed: int | None = None
    config_hash: str | None = None
    """The builder's `DatasetConfig.hash` (None for folders not made by the builder)."""
    num_shards: int | None = None
    statistics: dict | None = None
    """Counters over the objects, by group ('rejections', 'end_reasons', 'physics_flags')."""
    package_versions: dict | None = None
    tasks: tuple[str, ...] | None = None
    """The tasks the rows provide, when not all of `TASKS` (a feedback dataset: pose only)."""
    extra_images: tuple[str, ...] = ()
    """Image columns beyond the row schema's (a feedback dataset: `feedback`)."""
    details: dict = field(default_factory=dict)
    """The source's own facts (`DETAILS`), at the top level of the file."""

    def __post_init__(self):
        _check(self)

    @property
    def available_tasks(self) -> tuple[str, ...]:
        """`tasks`, or every task when the file names none."""
        return tuple(self.tasks) if self.tasks else TASKS

    # -- JSON ----------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The info.json object (None fields and empty optional ones left out)."""
        out = {
            "schema_version": self.schema_version,
            "dataset_id": self.dataset_id,
            "source": self.source,
            "config": self.config,
            "counts": {s: c.to_dict() for s, c in self.counts.items()},
            "total": self.total.to_dict(),
            "splits_present": list(self.splits_present),
        }
        for key in ("seed", "config_hash", "num_shards", "statistics", "package_versions"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        if self.tasks is not None:
            out["tasks"] = list(self.tasks)
        if self.extra_images:
            out[EXTRA_IMAGES_KEY] = list(self.extra_images)
        out.update(self.details)
        return out

    @classmethod
    def from_dict(cls, data, where: str = "info.json") -> DatasetInfo:
        """Check and type an info.json object; `where` names it in errors."""
        if not isinstance(data, Mapping):
            raise InfoError(f"{where}: expected a JSON object, got {type(data).__name__}")
        data = dict(data)
        source = data.get("source")
        if source is None and data.get(_LEGACY_KIND) == "feedback":
            source = "feedback"
            data.pop(_LEGACY_KIND)
        elif source == "feedback" and data.get(_LEGACY_KIND) == "feedback":
            data.pop(_LEGACY_KIND)
        if source not in INFO_SOURCES:
            raise InfoError(f"{where}: source must be one of {', '.join(INFO_SOURCES)}, got {source!r}")
        names = {f.name for f in fields(cls)} - {"details", "extra_images"}
        allowed = names | {EXTRA_IMAGES_KEY} | set(DETAILS[source])
        unknown = sorted(k for k in data if k not in allowed)
        if unknown:
            raise InfoError(f"{where}: unknown key {unknown[0]!r} for source {source!r}; valid: "
                            + ", ".join(sorted(allowed)))
        for key in ("dataset_id", "config", "counts", "total", "splits_present"):
            if key not in data:
                raise InfoError(f"{where}: missing {key!r}")
        counts = data["counts"]
        if not isinstance(counts, Mapping):
            raise InfoError(f"{where}: counts must be an object {{split: counts}}, got {counts!r}")
        kw = {k: data[k] for k in names if k in data}
        # Feedback folders written before the schema version was recorded have the first layout.
        kw["schema_version"] = data.get("schema_version", 1)
        kw["source"] = source
        kw["counts"] = {s: Counts.from_dict(c, f"{where}: counts.{s}") for s, c in counts.items()}
        kw["total"] = Counts.from_dict(data["total"], f"{where}: total")
        kw["splits_present"] = _names(data["splits_present"], f"{where}: splits_present")
        if data.get("tasks") is not None:
            kw["tasks"] = _names(data["tasks"], f"{where}: tasks")
        kw["extra_images"] = _names(data.get(EXTRA_IMAGES_KEY, []), f"{where}: {EXTRA_IMAGES_KEY}")
        kw["details"] = {k: data[k] for k in DETAILS[source] if k in data}
        try:
            return cls(**kw)
        except InfoError as exc:
            raise InfoError(f"{where}: {exc}") from None


def _names(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise InfoError(f"{where} must be a list of names, got {value!r}")
    return tuple(value)


def _check(info: DatasetInfo) -> None:
    """Raise `InfoError` naming the first field that is not what it must be."""
    v = info.schema_version
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= SCHEMA_VERSION:
        raise InfoError(f"schema_version must be an integer in 1..{SCHEMA_VERSION} (this code reads up to "
                        f"{SCHEMA_VERSION}), got {v!r}")
    if not isinstance(info.dataset_id, str) or not info.dataset_id:
        raise InfoError(f"dataset_id must be a non-empty string, got {info.dataset_id!r}")
    if info.source not in INFO_SOURCES:
        raise InfoError(f"source must be one of {', '.join(INFO_SOURCES)}, got {info.source!r}")
    if not isinstance(info.config, Mapping):
        raise InfoError(f"config must be an object, got {info.config!r}")
    bad = [s for s in info.counts if s not in SPLITS]
    if bad:
        raise InfoError(f"counts: unknown split {bad[0]!r}; valid: {', '.join(SPLITS)}")
    for s, c in info.counts.items():
        if not isinstance(c, Counts):
            raise InfoError(f"counts.{s} must be a Counts, got {c!r}")
    if not isinstance(info.total, Counts):
        raise InfoError(f"total must be a Counts, got {info.total!r}")
    for key in ("objects", "steps"):
        summed = sum(getattr(c, key) for c in info.counts.values())
        if getattr(info.total, key) != summed:
            raise InfoError(f"total.{key} is {getattr(info.total, key)} but the splits' counts sum to {summed}")
    bad = [s for s in info.splits_present if s not in SPLITS]
    if bad:
        raise InfoError(f"splits_present: unknown split {bad[0]!r}; valid: {', '.join(SPLITS)}")
    if info.tasks is not None:
        bad = [t for t in info.tasks if t not in TASKS]
        if bad or not info.tasks:
            raise InfoError(f"tasks: unknown task {bad[0] if bad else None!r}; valid: {', '.join(TASKS)}")
    for key, kind in (("seed", int), ("num_shards", int), ("config_hash", str), ("statistics", Mapping),
                      ("package_versions", Mapping)):
        value = getattr(info, key)
        if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
            raise InfoError(f"{key} must be {'an integer' if kind is int else 'a string' if kind is str else 'an object'}"
                            f" or absent, got {value!r}")
    allowed = DETAILS[info.source]
    bad = [k for k in info.details if k not in allowed]
    if bad:
        raise InfoError(f"details: {bad[0]!r} is not a fact of source {info.source!r}; valid: "
                        + (", ".join(allowed) or "none"))


def info_path(out) -> Path:
    return Path(out) / "meta" / "info.json"


def read_info(out) -> DatasetInfo:
    """The `DatasetInfo` of dataset folder `out`; `InfoError` naming the file when it is missing or wrong."""
    path = info_path(out)
    if not path.is_file():
        raise InfoError(f"{out}: not a dataset folder (no meta/info.json)")
    try:
        data = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise InfoError(f"{path}: not valid JSON ({exc})") from None
    return DatasetInfo.from_dict(data, str(path))


def write_info(out, info: DatasetInfo) -> Path:
    """Write `info` to `out/meta/info.json` (atomically); returns the path."""
    path = info_path(out)
    write_atomic(path, json_bytes(info.to_dict()))
    return path
