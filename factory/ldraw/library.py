"""Where LDraw files come from: a library folder or zip archive, the embedded default library, a
model's folder.

Lookups are case-insensitive and accept `\\` or `/`. A reference can never leave the place it is
looked up in: `..` components, absolute paths and symbolic links that point outside are refused.
"""

from __future__ import annotations

import difflib
import os
import zipfile
import zlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Callable, Protocol

from factory.embedded import generate_library
from factory.errors import LDrawError, LDrawLimitError, LDrawReadError, LDrawUnsafePathError
from factory.ldraw import parse
from factory.ldraw.parse import normalize_name

LIBRARY_SEARCH = ("parts/", "p/", "parts/s/", "p/48/", "p/8/")
"""LDraw's search order inside a library, after the model's MPD blocks and the model's folder."""


@dataclass(frozen=True)
class Located:
    """A file found by a lookup: `key` identifies it for caching, `display` names it in messages."""

    key: str
    display: str
    read: Callable[[], bytes]
    origin: str
    """'library' for the part library, 'model' for a model's folder."""


class Source(Protocol):
    """A tree of files that can be looked up by a safe, normalised relative path."""

    label: str

    def lookup(self, relpath: str) -> Located | None: ...

    def names(self) -> list[str]: ...

    def part_files(self) -> list[str]:
        """Lower-case names of the `.dat` files directly in `parts/` (the library's parts)."""


def check_reference(name: str, file: str | None = None, line: int | None = None) -> str:
    """Normalise a reference name and refuse ones that could leave the library or model folder."""
    norm = normalize_name(name)
    parts = norm.split("/")
    if not norm or norm.startswith("/") or (len(parts[0]) == 2 and parts[0][1] == ":"):
        raise LDrawUnsafePathError(
            f"reference {name!r} is an absolute path; references must be relative to the library "
            "or the model's folder",
            file,
            line,
        )
    if any(p in ("..", ".") for p in parts) or "" in parts:
        raise LDrawUnsafePathError(
            f"reference {name!r} contains '..', '.' or an empty component; references must stay "
            "inside the library or the model's folder",
            file,
            line,
        )
    return norm


class DirSource:
    """Files under a folder on disk, looked up case-insensitively, confined to that folder."""

    def __init__(self, root: Path, label: str, origin: str):
        self.root = Path(root)
        self.real_root = os.path.realpath(self.root)
        self.label = label
        self.origin = origin
        self._listings: dict[str, dict[str, str]] = {}
        # What each path named, found once as the listings are: resolving its links for every ask
        # (a renderer asks for each part of a scene at every view) was a quarter of rendering real parts.
        self._found: dict[str, Located | None] = {}

    def _listing(self, folder: str) -> dict[str, str]:
        if folder not in self._listings:
            try:
                with os.scandir(folder) as it:
                    self._listings[folder] = {e.name.lower(): e.name for e in it}
            except OSError:
                self._listings[folder] = {}
        return self._listings[folder]

    def lookup(self, relpath: str) -> Located | None:
        if relpath not in self._found:
            self._found[relpath] = self._lookup(relpath)
        return self._found[relpath]

    def _lookup(self, relpath: str) -> Located | None:
        folder = str(self.root)
        for part in relpath.split("/"):
            real = self._listing(folder).get(part)
            if real is None:
                return None
            folder = os.path.join(folder, real)
        real_path = os.path.realpath(folder)
        if os.path.commonpath([real_path, self.real_root]) != self.real_root:
            raise LDrawUnsafePathError(
                f"{folder} is a link to {real_path}, outside {self.root}; refusing to read it"
            )
        if not os.path.isfile(real_path):
            return None
        return Located(
            key=f"file:{real_path}",
            display=folder,
            read=lambda p=folder: _read_file(p),
            origin=self.origin,
        )

    def names(self) -> list[str]:
        """Names of the files under the searched folders that `lookup` would read: entries (or
        folders) linked to somewhere outside the root are left out, so that a 'did you mean'
        message never shows what lies outside the library."""
        out = []
        for sub in ("", *LIBRARY_SEARCH):
            folder = os.path.join(self.root, sub)
            if not self._inside(folder):
                continue
            for low, real in self._listing(folder).items():
                if self._inside(os.path.join(folder, real)):
                    out.append(low)
        return out

    def part_files(self) -> list[str]:
        folder = self._listing(str(self.root)).get("parts")
        if folder is None or not self._inside(os.path.join(self.root, folder)):
            return []
        path = os.path.join(self.root, folder)
        return sorted(low for low, real in self._listing(path).items()
                      if low.endswith(".dat") and self._inside(os.path.join(path, real)))

    def _inside(self, path: str) -> bool:
        return os.path.commonpath([os.path.realpath(path), self.real_root]) == self.real_root


def _read_file(path: str) -> bytes:
    try:
        size = os.path.getsize(path)
        if size > parse.MAX_FILE_BYTES:
            raise LDrawReadError(
                f"file is {size:,} bytes; LDraw files over {parse.MAX_FILE_BYTES:,} bytes are refused", path
            )
        with open(path, "rb") as fh:
            return fh.read(parse.MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise LDrawReadError(f"cannot read file: {exc.strerror or exc}", path) from None


class ZipSource:
    """Files inside a zip archive, read in place (LDraw's `complete.zip`, whose files sit under one
    `ldraw/` folder, or a zip of a library folder's contents): looked up case-insensitively, never
    extracted. The archive is checked when opened: a member named with `..`, an absolute path or a
    drive, or stored as a symbolic link, refuses the whole library (`LDrawUnsafePathError`); a
    member is read at most `parse.MAX_FILE_BYTES` uncompressed whatever its header says, so a
    decompression bomb costs no more than a large file."""

    MAX_MEMBERS = 500_000
    """Members an archive may list (LDraw's complete.zip has about 20,000)."""

    def __init__(self, path: Path, label: str, origin: str = "library"):
        self.path = Path(path)
        self.real_path = os.path.realpath(self.path)
        self.label = label
        self.origin = origin
        try:
            self._zip = zipfile.ZipFile(self.path)
            self._pid = os.getpid()
            infos = self._zip.infolist()
        except (OSError, zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
            raise LDrawReadError(f"cannot read the zip archive: {exc}", str(self.path)) from None
        if len(infos) > self.MAX_MEMBERS:
            raise LDrawLimitError(f"the archive lists {len(infos):,} members; libraries of at most "
                                  f"{self.MAX_MEMBERS:,} are read", str(self.path))
        members: dict[str, zipfile.ZipInfo] = {}
        for info in infos:
            name = info.filename.replace("\\", "/")
            parts = name.rstrip("/").split("/")
            if name.startswith("/") or (parts and len(parts[0]) == 2 and parts[0][1] == ":") or ".." in parts:
                raise LDrawUnsafePathError(f"member {info.filename!r} names a path outside the archive; "
                                           "refusing the library", str(self.path))
            if (info.external_attr >> 16) & 0o170000 == 0o120000:
                raise LDrawUnsafePathError(f"member {info.filename!r} is a symbolic link; refusing the library",
                                           str(self.path))
            if not info.is_dir():
                members[name.lower()] = info
        tops = {k.split("/", 1)[0] for k in members}
        self.prefix = ""
        if not any(k.startswith(("parts/", "p/")) for k in members) and len(tops) == 1:
            self.prefix = tops.pop() + "/"  # complete.zip: everything under ldraw/
        self._members = {k[len(self.prefix):]: v for k, v in members.items() if k.startswith(self.prefix)}

    def has_library_layout(self) -> bool:
        return any(k.startswith("parts/") for k in self._members) and any(k.startswith("p/") for k in self._members)

    def lookup(self, relpath: str) -> Located | None:
        info = self._members.get(relpath)
        if info is None:
            return None
        display = f"{self.path}!/{info.filename}"
        return Located(key=f"zip:{self.real_path}:{info.filename}", display=display,
                       read=lambda i=info, d=display: self._read(i, d), origin=self.origin)

    def _read(self, info: zipfile.ZipInfo, display: str) -> bytes:
        limit = parse.MAX_FILE_BYTES
        if info.file_size > limit:
            raise LDrawReadError(f"file is {info.file_size:,} bytes; LDraw files over {limit:,} bytes are refused",
                                 display)
        try:
            with self._archive().open(info) as fh:
                data = fh.read(limit + 1)
        except (OSError, zipfile.BadZipFile, EOFError, RuntimeError, NotImplementedError, zlib.error) as exc:
            raise LDrawReadError(f"cannot read the archive member: {exc}", display) from None
        if len(data) > limit:  # the header understated it
            raise LDrawReadError(f"file is over {limit:,} bytes uncompressed; LDraw files that large are refused",
                                 display)
        return data

    def _archive(self) -> zipfile.ZipFile:
        # A forked worker inherits the open file and with it the parent's file offset, which every
        # process then moves under the others' reads (zlib's "invalid distance too far back" on the
        # lent machine's 16 workers): each process opens the archive for itself.
        if self._pid != os.getpid():
            self._zip = zipfile.ZipFile(self.path)
            self._pid = os.getpid()
        return self._zip

    def part_files(self) -> list[str]:
        return sorted(k[6:] for k in self._members if k.startswith("parts/") and k.count("/") == 1
                      and k.endswith(".dat"))

    def names(self) -> list[str]:
        out = []
        for key in self._members:
            folder, _, base = key.rpartition("/")
            if folder == "" or folder + "/" in LIBRARY_SEARCH:
                out.append(base)
        return out


class MemorySource:
    """Files held in memory (the embedded default library), keyed by normalised relative path."""

    def __init__(self, files: dict[str, str], label: str):
        self.files = {normalize_name(k): v for k, v in files.items()}
        self.label = label

    def lookup(self, relpath: str) -> Located | None:
        text = self.files.get(relpath)
        if text is None:
            return None
        return Located(
            key=f"{self.label}:{relpath}",
            display=f"<{self.label}>/{relpath}",
            read=lambda t=text: t.encode("utf-8"),
            origin="library",
        )

    def names(self) -> list[str]:
        return [k.rsplit("/", 1)[-1] for k in self.files]

    def part_files(self) -> list[str]:
        return sorted(k[6:] for k in self.files if k.startswith("parts/") and k.count("/") == 1 and k.endswith(".dat"))


class Library:
    """An LDraw parts library: a folder or a zip archive on disk (`--ldraw`, `LDRAWDIR`) or the embedded
    default."""

    def __init__(self, source: Source, description: str):
        self.source = source
        self.description = description

    @classmethod
    def from_path(cls, path: str | os.PathLike) -> "Library":
        """The library in a folder, or in a zip archive read in place (LDraw's `complete.zip`)."""
        root = Path(path).expanduser()
        if root.is_file():
            return cls.from_zip(root)
        return cls.from_dir(root)

    @classmethod
    def from_zip(cls, path: str | os.PathLike) -> "Library":
        root = Path(path).expanduser()
        if not zipfile.is_zipfile(root):
            raise LDrawError(f"{root} is a file but not a zip archive; expected an LDraw library folder holding "
                             "'parts' and 'p', or LDraw's complete.zip")
        source = ZipSource(root, label=str(root))
        if not source.has_library_layout():
            raise LDrawError(f"{root} is not an LDraw library: expected folders 'parts' and 'p' in it (or under "
                             "one top folder, as 'ldraw/' in LDraw's complete.zip)")
        return cls(source, f"LDraw library in {root}")

    @classmethod
    def from_dir(cls, path: str | os.PathLike) -> "Library":
        root = Path(path).expanduser()
        if not root.exists():
            raise LDrawError(f"LDraw library folder {root} does not exist")
        if not root.is_dir():
            raise LDrawError(f"{root} is not a folder; expected an LDraw library folder holding 'parts' and 'p'")
        listing = {p.name.lower() for p in root.iterdir()}
        if "parts" not in listing or "p" not in listing:
            raise LDrawError(
                f"{root} is not an LDraw library: expected folders 'parts' and 'p' in it, "
                f"found {sorted(listing)[:10]}"
            )
        return cls(DirSource(root, label=str(root), origin="library"), f"LDraw library at {root}")

    @classmethod
    def embedded(cls) -> "Library":
        return cls(MemorySource(generate_library(), label="embedded"), "embedded default library")

    @classmethod
    def resolve(cls, ldraw: str | os.PathLike | None = None) -> "Library":
        """The library to use: `ldraw` if given, else `$LDRAWDIR`, else the embedded default."""
        if ldraw:
            return cls.from_path(ldraw)
        env = os.environ.get("LDRAWDIR")
        if env:
            return cls.from_path(env)
        return cls.embedded()

    def lookup(self, name: str) -> Located | None:
        """Find a normalised reference in the library, in LDraw's search order."""
        for prefix in LIBRARY_SEARCH:
            if prefix == "parts/s/" and name.startswith("s/"):
                continue
            found = self.source.lookup(prefix + name)
            if found is not None:
                return found
        return None

    def part_names(self) -> list[str]:
        """The library's parts: names (lower case, no `.dat`) of the files directly in `parts/`."""
        return [n[:-4] for n in self.source.part_files()]

    def config(self) -> Located | None:
        """The library's `LDConfig.ldr`, if it has one."""
        return self.source.lookup("ldconfig.ldr")

    @cached_property
    def _all_names(self) -> list[str]:
        return sorted(set(self.source.names()))

    def suggest(self, name: str, extra: list[str] = ()) -> list[str]:
        """Up to three existing names close to `name`, for 'did you mean' messages."""
        base = name.rsplit("/", 1)[-1]
        return difflib.get_close_matches(base, list(extra) + self._all_names, n=3, cutoff=0.6)
