"""An `Assembly` as plain JSON data and back, exactly: what a build keeps of a grown object.

A file that a build or a user can have written is read as data only, never as code (a pickle
runs whatever its author put in it). So a grown object is written as JSON whose objects name
one of a few known value types (`TYPES`) and their fields; reading builds only those types from
numbers, strings, lists and the like, and anything else is refused with `RecordError`.
Floats round-trip exactly (JSON carries Python's shortest repr; NaN and infinities as the
`NaN`/`Infinity` tokens), so an object read back renders to the same bytes as the one grown.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from factory.physics.check import Verdict
from factory.physics.statics import Failure
from factory.pose import Pose
from factory.sampler.assembly import Assembly, AssemblyStep

FORMAT = "brick-factory.assembly"
"""The `format` field of a record: a JSON file without it is not one."""

TYPES = {cls.__name__: cls for cls in (Assembly, AssemblyStep, Verdict, Failure, Pose)}
"""The only types a record can hold, besides None, bools, ints, floats, strings, lists, tuples,
dicts with string keys and float64/int64/bool arrays."""

_ARRAY_DTYPES = ("float64", "int64", "bool")


class RecordError(ValueError):
    """A record that is not one this module wrote (unknown type, field or value)."""


def dumps(assembly: Assembly) -> bytes:
    """The record of `assembly` (UTF-8 JSON)."""
    return json.dumps(to_json(assembly), separators=(",", ":")).encode("utf-8")


def loads(data: bytes) -> Assembly:
    """The `Assembly` of a record written by `dumps`; `RecordError` for anything else."""
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise RecordError(f"not JSON: {e}") from None
    return from_json(doc)


def to_json(assembly: Assembly) -> dict:
    """The record of `assembly` as a JSON-ready dict (to embed in a larger document)."""
    return {"format": FORMAT, "value": _encode(assembly)}


def from_json(doc) -> Assembly:
    """The `Assembly` of a parsed record (`to_json`'s form); `RecordError` for anything else."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise RecordError(f"not a record: expected a JSON object with format {FORMAT!r}")
    try:
        value = _decode(doc.get("value"))
    except RecursionError:
        raise RecordError("nested too deeply") from None
    if not isinstance(value, Assembly):
        raise RecordError(f"expected an Assembly, got {type(value).__name__}")
    return value


def _encode(v):
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    if isinstance(v, np.ndarray):
        if v.dtype.name not in _ARRAY_DTYPES:
            raise RecordError(f"cannot record an array of {v.dtype}")
        return {"$array": v.dtype.name, "shape": list(v.shape), "data": v.ravel().tolist()}
    if isinstance(v, tuple):
        return {"$tuple": [_encode(x) for x in v]}
    if isinstance(v, list):
        return [_encode(x) for x in v]
    if isinstance(v, dict):
        if not all(isinstance(k, str) for k in v):
            raise RecordError("cannot record a dict with keys that are not strings")
        return {"$dict": {k: _encode(x) for k, x in v.items()}}
    name = type(v).__name__
    if TYPES.get(name) is type(v):
        return {"$type": name, "fields": {f.name: _encode(getattr(v, f.name)) for f in dataclasses.fields(v)}}
    raise RecordError(f"cannot record a {name}; recordable types: {', '.join(TYPES)}")


def _decode(v):
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, list):
        return [_decode(x) for x in v]
    if not isinstance(v, dict) or len(v) not in (1, 2, 3):
        raise RecordError(f"unexpected value {type(v).__name__}")
    if "$tuple" in v and len(v) == 1 and isinstance(v["$tuple"], list):
        return tuple(_decode(x) for x in v["$tuple"])
    if "$dict" in v and len(v) == 1 and isinstance(v["$dict"], dict):
        return {k: _decode(x) for k, x in v["$dict"].items()}
    if "$array" in v and set(v) == {"$array", "shape", "data"}:
        return _array(v)
    if "$type" in v and set(v) == {"$type", "fields"} and isinstance(v["fields"], dict):
        cls = TYPES.get(v["$type"]) if isinstance(v["$type"], str) else None
        if cls is None:
            raise RecordError(f"unknown type {v['$type']!r}; known: {', '.join(TYPES)}")
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        extra = set(v["fields"]) - names
        if extra:
            raise RecordError(f"{cls.__name__} has no field {sorted(extra)[0]!r}")
        try:
            return cls(**{k: _decode(x) for k, x in v["fields"].items()})
        except (TypeError, ValueError) as e:
            raise RecordError(f"bad {cls.__name__}: {e}") from None
    raise RecordError(f"unexpected object with keys {sorted(v)[:4]}")


def _array(v) -> np.ndarray:
    dtype, shape, data = v["$array"], v["shape"], v["data"]
    if dtype not in _ARRAY_DTYPES or not isinstance(shape, list) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise RecordError(f"bad array header {dtype!r} {shape!r}")
    if not isinstance(data, list) or len(data) != math.prod(shape):
        raise RecordError("array data does not match its shape")
    if not all(isinstance(x, (bool, int, float)) for x in data):
        raise RecordError("array data must be numbers")
    return np.array(data, dtype=dtype).reshape(shape)
