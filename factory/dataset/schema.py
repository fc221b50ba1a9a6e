"""The row layout: the Arrow schema of the Parquet files and the Hugging Face features behind it.

Images are Hugging Face `Image` features: a struct {bytes: PNG, path: null}, declared as such in
the Parquet schema metadata (key `huggingface`), so `datasets.load_dataset(OUT)` decodes them to
PIL images with no extra arguments. The features JSON is generated here from the Arrow schema (no
`datasets` import in the workers); a test checks it against `datasets.Features`.
"""

from __future__ import annotations

import json

import pyarrow as pa

SCHEMA_VERSION = 2
"""Version of the row layout (this module), of `meta/info.json` (`factory.dataset.info`) and of a
build's config record (`meta/config.json`, `pipelines.dataset.config.DatasetConfig.to_json`); part
of a build's config hash. Folders of every version are read (`SCHEMA_VERSIONS`).

1. The first layout.
2. The physics checks' backend left the config record and its hash, with the sampler's other
   settings that change only how the checks run (`check_batch`, `judge_first`): both backends
   write the same files, so a dataset no longer depends on which one built it (the build records
   it in `meta/timings.json`). Rows and info.json keys unchanged; a folder started at version 1
   keeps its record and hash when resumed (`pipelines.dataset.config.version1_record`)."""

SCHEMA_VERSIONS = (1, 2)
"""The versions this code reads."""

IMAGE_COLUMNS = ("before", "after", "isometric", "part", "axes", "catalog")

IMAGE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
CONTENT = pa.struct([("type", pa.string()), ("text", pa.string()), ("index", pa.int64())])
MESSAGES = pa.list_(pa.struct([("role", pa.string()), ("content", pa.list_(CONTENT))]))
MATRIX = pa.list_(pa.list_(pa.float64()))
BRICK = pa.struct([
    ("part", pa.string()),
    ("colour", pa.int32()),
    ("colour_name", pa.string()),
    ("row", pa.int32()),
    ("col", pa.int32()),
    ("cells", pa.list_(pa.list_(pa.int32()))),
    ("R", MATRIX),
    ("T", pa.list_(pa.float64())),
    ("size_cm", pa.list_(pa.float64())),
    ("symmetry_order", pa.int32()),
    ("symmetry_continuous_axis", pa.list_(pa.float64())),
    ("symmetry_rotations", pa.list_(MATRIX)),
])
CATALOG_ENTRY = pa.struct([("part", pa.string()), ("colour", pa.int32()), ("row", pa.int32()),
                           ("col", pa.int32())])

FIELDS = [
    # identity
    ("dataset_id", pa.string()),
    ("object_id", pa.string()),
    ("step_id", pa.string()),
    ("step_index", pa.int32()),
    ("num_steps", pa.int32()),
    ("split", pa.string()),
    ("source", pa.string()),
    ("seed", pa.int64()),
    ("assembly", pa.string()),
    ("step_kind", pa.string()),
    # images
    *[(name, IMAGE) for name in IMAGE_COLUMNS],
    # targets
    ("bricks", pa.list_(BRICK)),
    ("catalog_parts", pa.list_(CATALOG_ENTRY)),
    ("physics", pa.string()),
    # tasks
    ("system", pa.string()),
    ("selection_messages", MESSAGES),
    ("selection_images", pa.list_(pa.string())),
    ("selection_answer", pa.string()),
    ("pose_messages", MESSAGES),
    ("pose_images", pa.list_(pa.string())),
    ("pose_answer", pa.string()),
]


SETTLED = pa.struct([
    ("outcome", pa.string()),
    ("moved_ldu", pa.float64()),
    ("connections", pa.int32()),
    ("R", MATRIX),
    ("T", pa.list_(pa.float64())),
])
EXTRA_FIELDS = {"settled": pa.list_(SETTLED)}
"""Columns beyond `FIELDS` that a dataset may have, by name. `settled`: a world-feedback dataset whose
predictions were executed (`pipelines.feedback`): per target brick, what physics did with the
predicted brick (`factory.physics.settle.OUTCOMES`), how far it moved, its stud connections and
its settled pose (LDraw frame, LDU), in the order of `bricks`."""


def _feature(t: pa.DataType, image: bool = False) -> dict:
    if image:
        return {"_type": "Image"}
    if pa.types.is_struct(t):
        return {t.field(i).name: _feature(t.field(i).type) for i in range(t.num_fields)}
    if pa.types.is_list(t):
        return {"feature": _feature(t.value_type), "_type": "List"}
    names = {pa.string(): "string", pa.int32(): "int32", pa.int64(): "int64", pa.float64(): "float64",
             pa.binary(): "binary", pa.bool_(): "bool"}
    return {"dtype": names[t], "_type": "Value"}


def features_json(extra_images: tuple[str, ...] = (), extra_fields: tuple[str, ...] = ()) -> dict:
    """The Hugging Face `Features.to_dict()` of the rows (with `extra_images` image columns, then
    `extra_fields` (`EXTRA_FIELDS`), last)."""
    out = {name: _feature(t, name in IMAGE_COLUMNS) for name, t in FIELDS}
    out.update({name: _feature(IMAGE, True) for name in extra_images})
    out.update({name: _feature(EXTRA_FIELDS[name]) for name in extra_fields})
    return out


def arrow_schema(extra_images: tuple[str, ...] = (), extra_fields: tuple[str, ...] = ()) -> pa.Schema:
    """The rows' Arrow schema; `extra_images`: image columns added after the others (a world-feedback
    dataset's `feedback`), declared as HF `Image` features too; `extra_fields`: columns of
    `EXTRA_FIELDS` after those."""
    clash = [n for n in (*extra_images, *extra_fields) if n in dict(FIELDS)]
    if clash:
        raise ValueError(f"extra column {clash[0]!r} is already a row column")
    unknown = [n for n in extra_fields if n not in EXTRA_FIELDS]
    if unknown:
        raise ValueError(f"unknown extra column {unknown[0]!r}; known: {', '.join(EXTRA_FIELDS)}")
    meta = {"huggingface": json.dumps({"info": {"features": features_json(extra_images, extra_fields)}},
                                      sort_keys=False)}
    fields = ([pa.field(n, t) for n, t in FIELDS] + [pa.field(n, IMAGE) for n in extra_images]
              + [pa.field(n, EXTRA_FIELDS[n]) for n in extra_fields])
    return pa.schema(fields, metadata=meta)


SCHEMA = arrow_schema()
