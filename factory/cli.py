"""What every command line of the project shares: one `error: ...` line for bad input (no
traceback), flags generated from a config dataclass (so a default lives only in the dataclass),
renamed flags that keep working with a note, and the one progress switch (`--no-progress`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import typing
from typing import Callable

from factory import _startup
from factory.config import field_docs, field_types, nested_config, optional_of
from factory.errors import LDrawError
from factory.mps import MODES


def run_guarded(body: Callable[[], int | None], extra: dict[type[BaseException], int] | None = None) -> int:
    """Run a command's body; known failures print one line to stderr and give an exit status.

    LDraw errors and runaway nesting exit 2; `extra` maps further exception types to their status.
    A closed output pipe (`| head`) is a normal end.
    """
    handled: dict[type[BaseException], int] = {LDrawError: 2, **(extra or {})}
    try:
        _startup.started()  # from here Ctrl-C raises KeyboardInterrupt, caught below
        try:
            return body() or 0
        except BrokenPipeError:
            return 0
        except KeyboardInterrupt:
            _startup.finishing()
            print("error: interrupted; what was finished is kept (re-run the same command to resume where it can)",
                  file=sys.stderr)
            return 130
        except RecursionError:
            print("error: input nests too deeply to read", file=sys.stderr)
            return 2
        except tuple(handled) as exc:
            status = next(code for kind, code in handled.items() if isinstance(exc, kind))
            print(f"error: {exc}", file=sys.stderr)
            return status
    finally:
        _startup.finishing()  # a command's status is known: a late Ctrl-C does not change it


class ArgumentParser(argparse.ArgumentParser):
    """The parser of every command line: a bad flag or value ends in one line, `error: ...` and
    exit 2, like every other input error (argparse prints its whole usage first: 15 lines for
    `pipelines.sample`); `--help` still shows the usage."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (`{self.prog} --help` lists the flags)\n")


# -- flags generated from config dataclasses -------------------------------------------------------
def add_config_args(ap, cls: type, *, skip=(), prefix: str = "") -> None:
    """One flag per field of the config dataclass `cls` (nested configs' fields too, their dests
    prefixed `field.`): `--field-name`, the field's default, and its docstring with the default as
    help. `skip` names fields (dests) the command sets otherwise.

    Field types map to flags as: bool -> `--x/--no-x`; int, float, str (or `X | None`) -> one
    value; tuples -> comma-separated values (the flag may repeat; names listed twice count once,
    numbers are kept as given); tuples of (name, weight) pairs -> `name[:weight],...`. A field's
    metadata may say more: `choices` (its valid values), `flag` (another name, e.g. `check-backend`
    where `--backend` would be ambiguous; False: no flag, the command sets the field itself),
    `aliases` (more spellings, e.g. `("--candidates",)`) and `type` (the flag's own parser of its
    text, run before `choices` is checked: `--check-backend` maps former names to new ones).
    """
    docs, types = field_docs(cls), field_types(cls)
    for f in dataclasses.fields(cls):
        key = prefix + f.name
        if key in skip or not f.init or f.metadata.get("flag") is False:
            continue
        sub = nested_config(types[f.name])
        if sub is not None:
            add_config_args(ap, sub, skip=skip, prefix=key + ".")
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = dataclasses.MISSING
        names = ["--" + f.metadata.get("flag", f.name.replace("_", "-")), *f.metadata.get("aliases", ())]
        kw = _flag(optional_of(types[f.name]), f.metadata.get("choices"))
        if "type" in f.metadata:
            kw["type"] = f.metadata["type"]
        kw.setdefault("metavar", None if "choices" in kw or "action" in kw else names[0][2:].upper().replace("-", "_"))
        text = docs.get(f.name, "").replace("%", "%%")
        if default is dataclasses.MISSING:
            kw["required"] = True
        else:
            kw["default"] = default
            if isinstance(default, tuple):
                text += f" (default: {_show(default)})".replace("%", "%%")
            else:
                text += " (default: %(default)r)"  # (argparse fills it in, after any set_defaults)
        action = ap.add_argument(*names, dest=key, help=text, **kw)
        action.help = text  # (some Pythons' BooleanOptionalAction appends its default a second time)


def config_from_args(cls: type, args: argparse.Namespace, prefix: str = "", **given):
    """`cls` from arguments parsed with `add_config_args`: the `given` values, else the flags, else
    the fields' defaults (fields the parser has no flag for)."""
    types, present = field_types(cls), vars(args)
    kw = {}
    for f in dataclasses.fields(cls):
        key = prefix + f.name
        sub = nested_config(types[f.name])
        if f.name in given:
            kw[f.name] = given[f.name]
        elif sub is not None and any(k.startswith(key + ".") for k in present):
            kw[f.name] = config_from_args(sub, args, key + ".")
        elif key in present:
            kw[f.name] = present[key]
    return cls(**kw)


def _flag(tp, choices) -> dict:
    if tp is bool:
        return {"action": argparse.BooleanOptionalAction}
    if typing.get_origin(tp) is tuple:
        item = typing.get_args(tp)[0]
        if typing.get_origin(item) is tuple:  # (name, weight) pairs
            key = typing.get_args(item)[0]
            return {"action": _ListAction, "item": lambda s: _pair(s, key), "metavar": "NAME[:WEIGHT],..."}
        return {"action": _ListAction, "item": item, "valid": choices, "metavar": "A,B,...",
                "unique": item not in (int, float)}
    kw: dict = {"type": tp}
    if choices:
        kw["choices"] = tuple(choices)
    return kw


def _pair(text: str, key) -> tuple:
    name, _, weight = text.partition(":")
    try:
        return key(name), float(weight) if weight else 1.0
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME or NAME:WEIGHT (a number), got {text!r}") from None


class _ListAction(argparse.Action):
    """Comma-separated values; a repeated flag adds to the list (the default is replaced, not
    extended). `unique`: a value given twice is kept once (names, paths; not numbers)."""

    def __init__(self, option_strings, dest, item=str, valid=None, unique=True, **kw):
        self.item, self.valid, self.unique = item, valid, unique
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        items = []
        for text in (x.strip() for x in values.split(",")):
            if not text:
                continue
            try:
                value = self.item(text)
            except argparse.ArgumentTypeError as e:
                parser.error(f"{option_string}: {e}")
            except (TypeError, ValueError):
                parser.error(f"{option_string}: invalid value {text!r}")
            if self.valid and value not in self.valid:
                parser.error(f"{option_string}: {value!r} is not valid; valid: {', '.join(map(str, self.valid))}")
            items.append(value)
        before = getattr(namespace, self.dest, None)
        start = list(before) if before is not self.default and before is not None else []
        values = start + items
        setattr(namespace, self.dest, tuple(dict.fromkeys(values) if self.unique else values))


def _show(value: tuple) -> str:
    text = ",".join(":".join(f"{x:g}" if isinstance(x, float) else str(x) for x in v) if isinstance(v, tuple)
                        else str(v) for v in value)
    return text if len(text) <= 72 else f"{text[:60]}... ({len(value)} entries)"


# -- renamed flags and the progress switch ---------------------------------------------------------
class _Renamed(argparse.Action):
    def __init__(self, option_strings, dest, new: str, **kw):
        self.new = new
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"warning: {option_string} is deprecated, use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)


def renamed_flag(ap, old: str, new: str, dest: str, **kw) -> None:
    """Keep the old spelling `old` of the flag `new` (storing into `dest`) working, with a warning
    on stderr; hidden from --help. `kw` as for the new flag (`choices`, or `nargs=0, const=...`)."""
    ap.add_argument(old, dest=dest, action=_Renamed, new=new, default=argparse.SUPPRESS, help=argparse.SUPPRESS,
                    **kw)


def add_mps_flag(ap) -> None:
    """`--mps auto|off`: whether a job whose processes share a GPU starts an NVIDIA MPS daemon of
    its own (`factory.mps`; default `$BRICK_FACTORY_MPS`, else auto)."""
    ap.add_argument("--mps", choices=MODES, default=None,
                    help="processes that share a GPU through NVIDIA MPS, a daemon of this job's own where "
                         "nvidia-cuda-mps-control is there (auto, the default unless $BRICK_FACTORY_MPS "
                         "says otherwise) or not (off)")


def add_progress_flag(ap) -> None:
    """`--no-progress`: no progress bars (the one spelling; `--quiet` is its old name)."""
    ap.add_argument("--no-progress", action="store_true", help="no progress bars")
    renamed_flag(ap, "--quiet", "--no-progress", "no_progress", nargs=0, const=True)
