"""One policy for every config of the project: frozen dataclasses, a docstring under each field,
and one way to and from plain JSON values.

A config is a dataclass whose fields each carry an attribute docstring (the string literal right
under the field); `field_docs` reads them, so the command lines (`factory.cli.add_config_args`)
and the docs say what the code says. `config_to_dict` gives JSON values (tuples as lists, nested
configs as dicts); `config_from_dict` is its inverse and refuses unknown keys with an error that
lists the valid ones, so a misspelt setting never passes silently.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from functools import lru_cache
from typing import Any


class ConfigError(ValueError):
    """A config value out of range, a missing field, or an unknown key; the message names it."""


@lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> its attribute docstring (whitespace collapsed), for a dataclass `cls` and its bases."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass) or klass is object:
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = tree.body[0].body
        for node, after in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr)
                    and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
                docs[node.target.id] = " ".join(after.value.value.split())
    return docs


@lru_cache(maxsize=None)
def field_types(cls: type) -> dict[str, Any]:
    """Field name -> its resolved annotation (`from __future__ import annotations` leaves strings)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def nested_config(tp) -> type | None:
    """The dataclass a field holds (`SamplerConfig` for `SamplerConfig` or `SamplerConfig | None`), else None."""
    args = optional_of(tp)
    return args if dataclasses.is_dataclass(args) else None


def optional_of(tp):
    """`X` for `X | None` (or `Optional[X]`), else `tp` itself."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _plain(value):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return value.to_dict() if hasattr(value, "to_dict") else config_to_dict(value)
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def config_to_dict(config) -> dict:
    """Every field of `config` as JSON values, in field order: tuples become lists, nested configs
    dicts (through their own `to_dict` where they have one)."""
    return {f.name: _plain(getattr(config, f.name)) for f in dataclasses.fields(config)}


def _tuples(value):
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def config_from_dict(cls: type, data, error: type[Exception] = ConfigError, where: str | None = None):
    """`cls` built from `config_to_dict`'s form. Unknown keys, missing required fields and a
    non-mapping are refused with `error`, naming the valid keys (and where the mapping sits:
    `where`, else the class name); lists become tuples and nested configs are built from their
    dicts (through their own `from_dict` where they have one)."""
    what = where or cls.__name__
    if not isinstance(data, dict):
        raise error(f"{what}: expected a mapping of settings, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise error(f"{what}: unknown key(s) {', '.join(map(repr, unknown))}; valid keys: {', '.join(fields)}")
    missing = [n for n, f in fields.items() if n not in data and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise error(f"{what}: missing required key(s) {', '.join(map(repr, missing))}")
    hints = field_types(cls)
    kw = {}
    for name, value in data.items():
        sub = nested_config(hints[name])
        if sub is not None and isinstance(value, dict):
            kw[name] = (sub.from_dict(value) if hasattr(sub, "from_dict")
                        else config_from_dict(sub, value, error, f"{what}.{name}"))
        else:
            kw[name] = _tuples(value)
    return cls(**kw)
