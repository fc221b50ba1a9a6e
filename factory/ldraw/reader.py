"""Resolve references and flatten LDraw files into triangle meshes with their stud primitives.

A `Reader` holds one library and caches every parsed file and every flattened mesh, so a part is
resolved once per process however many models use it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factory.errors import (
    LDrawCycleError,
    LDrawLimitError,
    LDrawMissingFileError,
    LDrawReadError,
)
from factory.ldraw.colours import ColourTable
from factory.ldraw.library import LIBRARY_SEARCH, DirSource, Library, Located, _read_file, check_reference
from factory.ldraw.other_connectors import (axis_segment, bar_cylinder, connector_kind, facing_out, is_other_connector,
                                             place_connectors)
from factory.ldraw.parse import LDrawFile, Poly, Ref, decode, parse_lines, split_mpd

MAX_DEPTH = 64
"""Deepest reference nesting accepted; real parts nest under 10 levels."""

MAX_TRIANGLES = 2_000_000
"""Most triangles a flattened file may expand to; a 48x48 baseplate has about 250,000."""

MAX_EDGES = 4_000_000
"""Most edge lines (types 2 and 5) a flattened file may expand to: twice the triangles' budget (the
312 parts of the real subset draw 0.88 edges per triangle at the median, 1.38 at most); without
it, nine tiny files could expand to 2 x 10^8 edges."""

KEEP_MODELS = 16
"""Opened models a reader keeps for `Reader.model` (an older one is opened again when asked for)."""

_STUD = re.compile(r"^(?:.*/)?stud(|2|2a|6|6a|10|13|15|16|17a|18a|20|22a|p\d+[a-z]?)(-logo\d*)?\.dat$")
"""Stud primitives (and logo variants). Not stud3*/stud4*: those are underside bars and tubes."""


def is_stud_primitive(name: str) -> bool:
    return _STUD.match(name) is not None


_HOLLOW_STUD = re.compile(r"^(?:.*/)?stud(2|2a|6|6a)(-logo\d*)?\.dat$")
"""Open (hollow) stud primitives ('Stud Open', with or without base edges, round 2x2 kin)."""


def is_hollow_stud(name: str) -> bool:
    return _HOLLOW_STUD.match(name) is not None


@dataclass
class Model:
    """A model file opened for reading: its MPD blocks (the first is the main model) and folder."""

    path: str
    blocks: dict[str, LDrawFile]
    main: LDrawFile
    folder: DirSource


@dataclass(frozen=True)
class Resolved:
    """A reference resolved to a parsed file, with the model context its own references use."""

    file: LDrawFile
    key: str
    origin: str
    """'library', 'model' (the model's folder) or 'mpd' (a block of the model's MPD file)."""
    model: Model | None


@dataclass(frozen=True)
class Flat:
    """A file flattened into its own frame: CCW triangles, edges and the studs it contains."""

    triangles: np.ndarray
    """(n, 3, 3) float64 vertices in LDU, counter-clockwise seen from outside where certified."""
    colours: np.ndarray
    """(n,) int64 colour codes; 16 means the colour the part is placed with."""
    edges: np.ndarray
    """(m, 2, 3) float64 type 2 edge lines, for outlines in renders."""
    studs: np.ndarray
    """(k, 2, 3) float64: each stud's base centre and unit axis (pointing out of the part)."""
    certified: bool
    """Whether every triangle came from a BFC-certified file (winding known)."""
    in_stud: np.ndarray
    """(n,) bool: the triangle belongs to a stud primitive (studs collide only where unconnected)."""
    other_connectors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """(j, 3, 3) float64: for each primitive of a non-stud connection (Technic hole, pin or axle,
    clip, click hinge, wheel pin), the two ends of the stretch of its axis that it spans and the
    unit axis. Kept with positions, not as a count, so the checker can tell whether two parts'
    connectors meet."""
    other_kinds: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    """(j,) int8 for `other_connectors`: what each is, an index in `other_connectors.CONNECTOR_KINDS`
    (a pin hole, an axle, a click hinge...)."""
    other_refs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(j, 3) float64 for `other_connectors`: the unit direction of each primitive's own Z axis in
    this frame, which marks its turn about its axis (two click hinge halves are straight, in line,
    where their Z axes agree: `joints.click_angle`)."""
    bores: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """(b, 3, 3) float64, like `other_connectors`: the bore of each hollow stud (its stretch of the
    stud's axis). A bore holds a bar (a torch, an antenna, an exhaust pipe's pin), a connection
    the checker does not model; unlike the other connectors it does not hold its own part up."""
    bars: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """(c, 3, 3) float64, like `other_connectors`: every cylinder of a bar's radius the part is drawn
    with (`other_connectors.BAR_RADIUS`, 4 LDU) outside its hollow studs (whose bores are
    `bores`): a bar or a handle, the grip of a clip, a hinge finger's rounded end, the solid pin
    under a 1xN plate."""
    bar_out: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(c,) float64 for `bars`: +1 where the cylinder's faces look away from its axis (solid: a bar,
    a pin, a finger), -1 where they look at it (hollow: a clip's grip), 0 where the part's winding
    is not known (not BFC-certified)."""


@dataclass
class Reader:
    """Reads models and parts from one library, caching parsed files and flattened meshes."""

    library: Library
    _parsed: dict[str, LDrawFile] = field(default_factory=dict)
    _flat: dict[str, Flat] = field(default_factory=dict)
    _counts: dict[str, tuple[int, int]] = field(default_factory=dict)
    parts: dict[str, object] = field(default_factory=dict)
    """`factory.parts.Part` objects by resolved key, filled by `load_part`. A part found in a
    model's MPD blocks or folder has a key of its own (`MODEL#name`, `MODEL|file`), so it never
    stands in for the library's part of the same name in another model."""
    models: dict[str, Model] = field(default_factory=dict)
    """The models opened last (`open_model`, the `KEEP_MODELS` latest), by path, for `model()`."""
    _colours: ColourTable | None = None

    @property
    def colours(self) -> ColourTable:
        """The library's `LDConfig.ldr` colours (read once; an empty table where it has none)."""
        if self._colours is None:
            cfg = self.library.config()
            self._colours = ColourTable({}) if cfg is None else ColourTable.parse(
                cfg.read().decode("utf-8", errors="replace"), cfg.display)
        return self._colours

    # -- reading -----------------------------------------------------------------------------
    def parse_located(self, loc: Located) -> LDrawFile:
        """Parse a file found by a lookup (its first block, if it happens to be an MPD file)."""
        if loc.key not in self._parsed:
            text = decode(loc.read(), loc.display)
            blocks = split_mpd(text)
            block = blocks[0]
            name = os.path.basename(loc.display).lower()
            self._parsed[loc.key] = parse_lines(block.lines, loc.display, name, block.first_line)
        return self._parsed[loc.key]

    def open_model(self, path: str | os.PathLike) -> Model:
        """Open a model (.ldr, .mpd or a .dat) from disk."""
        path = Path(path)
        if not path.exists():
            raise LDrawMissingFileError(f"model file {path} does not exist")
        if not path.is_file():
            raise LDrawReadError("not a regular file", str(path))
        folder = DirSource(path.parent, label=str(path.parent), origin="model")
        text = decode(_read_file(str(path)), str(path))
        blocks = split_mpd(text)
        parsed: dict[str, LDrawFile] = {}
        main: LDrawFile | None = None
        for block in blocks:
            if block.name.startswith("!data:"):
                continue
            display = str(path) if not block.name else f"{path}#{block.name}"
            name = block.name or path.name
            f = parse_lines(block.lines, display, name.lower(), block.first_line)
            f.name = name  # keep the author's spelling for sub-assembly tags
            parsed.setdefault(name.replace("\\", "/").lower(), f)
            if main is None:
                main = f
        if main is None:
            raise LDrawReadError("file has no model in it (no lines outside 0 !DATA blocks)", str(path))
        model = Model(str(path), parsed, main, folder)
        self.models.pop(model.path, None)
        self.models[model.path] = model
        while len(self.models) > KEEP_MODELS:
            del self.models[next(iter(self.models))]
        return model

    def model(self, path: str | os.PathLike) -> Model:
        """The model at `path` as last opened by this reader (opened now if it was not)."""
        return self.models.get(str(path)) or self.open_model(path)

    def find(self, ref: Ref, parent: LDrawFile, model: Model | None) -> Resolved | None:
        """What `ref` names (MPD blocks, then the model's folder, then the library), or None where
        nothing holds it (an unsafe name still raises)."""
        name = check_reference(ref.name, parent.path, ref.line)
        if model is not None:
            block = model.blocks.get(name)
            if block is not None:
                return Resolved(block, f"{model.path}#{name}", "mpd", model)
            loc = model.folder.lookup(name)
            if loc is not None:
                return Resolved(self.parse_located(loc), f"{model.path}|{loc.key}", "model", model)
        loc = self.library.lookup(name)
        if loc is not None:
            return Resolved(self.parse_located(loc), loc.key, "library", None)
        return None

    def resolve(self, ref: Ref, parent: LDrawFile, model: Model | None) -> Resolved:
        """Find what `ref` names: MPD blocks, then the model's folder, then the library; a missing
        file raises `LDrawMissingFileError` with where it looked and close names."""
        found = self.find(ref, parent, model)
        if found is not None:
            return found
        name = check_reference(ref.name, parent.path, ref.line)
        looked = []
        if model is not None:
            looked += ["the model's MPD blocks", f"the model's folder {model.folder.root}"]
        looked.append(f"{self.library.description} ({', '.join(LIBRARY_SEARCH)})")
        close = self.library.suggest(name, list(model.blocks) if model else [])
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise LDrawMissingFileError(
            f"cannot find {ref.name!r} (looked in {'; '.join(looked)}){hint}", parent.path, ref.line
        )

    def part(self, name: str, model: str | os.PathLike | Model | None = None) -> Resolved:
        """A part by name (`3001`, `3001.dat`, `s/3001s01.dat`): of the library, or, with `model`
        (a `Model` or its path), found as the model's own references are (`resolve`: its MPD
        blocks, its folder, then the library), as `PlacedPart.model` asks."""
        norm = name if name.lower().endswith((".dat", ".ldr")) else name + ".dat"
        fake = Ref(0, 16, np.eye(3), np.zeros(3), norm.replace("\\", "/").lower())
        if model is not None and not isinstance(model, Model):
            model = self.model(model)
        holder = LDrawFile(path="<command line>" if model is None else model.path, name="")
        return self.resolve(fake, holder, model)

    # -- flattening --------------------------------------------------------------------------
    def triangle_count(self, res: Resolved, stack: tuple[str, ...] = ()) -> int:
        """Triangles `res` expands to, computed without expanding (guards against blow-ups)."""
        return self._records(res, stack)[0]

    def _records(self, res: Resolved, stack: tuple[str, ...] = ()) -> tuple[int, int]:
        """(triangles, edge lines) `res` expands to, computed without expanding; either past its
        budget (`MAX_TRIANGLES`, `MAX_EDGES`) is refused with the line that crossed it."""
        if res.key in self._counts:
            return self._counts[res.key]
        self._check_stack(res, stack)
        polys = [it.kind for it in res.file.items if isinstance(it, Poly)]
        tris = sum(1 if k == 3 else 2 for k in polys if k in (3, 4))
        edges = sum(1 for k in polys if k in (2, 5))
        for ref in res.file.refs:
            t, e = self._records(self.resolve(ref, res.file, res.model), stack + (res.key,))
            tris, edges = tris + t, edges + e
            for count, limit, what in ((tris, MAX_TRIANGLES, "triangles"), (edges, MAX_EDGES, "edge lines")):
                if count > limit:
                    raise LDrawLimitError(f"expands to more than {limit:,} {what}; refusing to flatten it",
                                          res.file.path, ref.line)
        self._counts[res.key] = (tris, edges)
        return tris, edges

    def flatten(self, res: Resolved) -> Flat:
        """The file's geometry in its own frame, with every reference expanded (cached)."""
        self.triangle_count(res)
        return self._flatten(res, ())

    def _check_stack(self, res: Resolved, stack: tuple[str, ...]) -> None:
        if res.key in stack:
            names = [k.rsplit("/", 1)[-1].rsplit("#", 1)[-1] for k in stack[stack.index(res.key):]]
            chain = " -> ".join(names + [names[0]])
            raise LDrawCycleError(f"reference cycle: {chain}", res.file.path)
        if len(stack) >= MAX_DEPTH:
            raise LDrawLimitError(
                f"references nest more than {MAX_DEPTH} levels deep", res.file.path
            )

    def _flatten(self, res: Resolved, stack: tuple[str, ...]) -> Flat:
        cached = self._flat.get(res.key)
        if cached is not None:
            return cached
        self._check_stack(res, stack)
        tris, cols, edges, studs, in_stud, others, bores = [], [], [], [], [], [], []
        kinds, refs = [], []
        bars, bar_out = [], []
        certified = res.file.certified
        for it in res.file.items:
            if isinstance(it, Poly):
                if it.kind == 3:
                    tris.append(it.points[None])
                    cols.append([it.colour])
                    in_stud.append(np.zeros(1, bool))
                elif it.kind == 4:
                    p = it.points
                    tris.append(np.stack([p[[0, 1, 2]], p[[0, 2, 3]]]))
                    cols.append([it.colour, it.colour])
                    in_stud.append(np.zeros(2, bool))
                elif it.kind == 2:
                    edges.append(it.points[None])
            elif isinstance(it, Ref):
                child_res = self.resolve(it, res.file, res.model)
                child = self._flatten(child_res, stack + (res.key,))
                t, c, e, s = _place(child, it)
                tris.append(t)
                cols.append(c)
                edges.append(e)
                studs.append(s)
                certified = certified and child.certified
                if is_other_connector(it.name):
                    # The connector as a whole; the primitives it is drawn with (a beam hole's peg
                    # holes) are parts of it, not connectors of their own.
                    others.append(place_connectors(axis_segment(it.name, child.triangles)[None], it.matrix, it.pos))
                    kinds.append([connector_kind(it.name)])
                    refs.append(_turned(np.array([[0.0, 0.0, 1.0]]), it.matrix))
                elif len(child.other_connectors):
                    others.append(place_connectors(child.other_connectors, it.matrix, it.pos))
                    kinds.append(child.other_kinds)
                    refs.append(_turned(child.other_refs, it.matrix))
                if is_hollow_stud(it.name):
                    bores.append(place_connectors(axis_segment(it.name, child.triangles)[None], it.matrix, it.pos))
                elif len(child.bores):
                    bores.append(place_connectors(child.bores, it.matrix, it.pos))
                cylinder = bar_cylinder(it.name, it.matrix, it.pos)
                if cylinder is not None:
                    # `t` is wound as this file draws it (mirrors and INVERTNEXT applied).
                    bars.append(cylinder[None])
                    bar_out.append([facing_out(t, cylinder) if child.certified else 0.0])
                elif len(child.bars) and not is_hollow_stud(it.name):
                    bars.append(place_connectors(child.bars, it.matrix, it.pos))
                    # INVERTNEXT turns the child inside out (a mirror does not: `_place` keeps
                    # its faces looking out).
                    bar_out.append(-child.bar_out if it.invert else child.bar_out)
                stud_ref = is_stud_primitive(it.name)
                in_stud.append(np.ones(len(t), bool) if stud_ref else child.in_stud)
                if stud_ref:
                    # The connection point is 4 LDU (a stud's height) below the stud's top, on its
                    # axis: a stud primitive drawn taller and sunk into the part (as some slopes do)
                    # connects where a plain stud on the top face would.
                    reach = it.matrix @ np.array([0.0, -4.0, 0.0])
                    n = np.linalg.norm(reach)
                    if n > 1e-9:
                        axis = reach / n
                        studs.append(np.stack([it.pos + reach - 4.0 * axis, axis])[None])
        flat = Flat(
            triangles=np.concatenate(tris) if tris else np.zeros((0, 3, 3)),
            colours=np.concatenate([np.asarray(c, dtype=np.int64) for c in cols]) if cols else np.zeros(0, np.int64),
            edges=np.concatenate(edges) if edges else np.zeros((0, 2, 3)),
            studs=_unique_studs(np.concatenate(studs)) if studs else np.zeros((0, 2, 3)),
            certified=certified,
            in_stud=np.concatenate(in_stud) if in_stud else np.zeros(0, bool),
            **_with_kinds(np.concatenate(others), np.concatenate(kinds).astype(np.int8), np.concatenate(refs))
            if others else {},
            bores=_unique_connectors(np.concatenate(bores)) if bores else np.zeros((0, 3, 3)),
            **_bars(bars, bar_out, certified),
        )
        for arr in (flat.triangles, flat.colours, flat.edges, flat.studs, flat.in_stud,
                    flat.other_connectors, flat.other_kinds, flat.other_refs, flat.bores, flat.bars, flat.bar_out):
            arr.setflags(write=False)
        self._flat[res.key] = flat
        return flat


def _place(child: Flat, ref: Ref) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Transform a flattened child by a type 1 line: p' = M p + t, winding fixed for mirrors."""
    m, t = ref.matrix, ref.pos
    tris = child.triangles @ m.T + t
    if (np.linalg.det(m) < 0) != ref.invert:
        tris = tris[:, ::-1, :]
    cols = child.colours.copy()
    if ref.colour != 16:
        cols[cols == 16] = ref.colour
    edges = child.edges @ m.T + t
    studs = child.studs.copy()
    if len(studs):
        studs[:, 0] = studs[:, 0] @ m.T + t
        axes = studs[:, 1] @ m.T
        studs[:, 1] = axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-12)
    return tris, cols, edges, studs


def _bars(bars: list, bar_out: list, certified: bool) -> dict:
    """`Flat.bars` and `Flat.bar_out`: each cylinder once (the same stretch of axis drawn twice
    is one; solid one time and hollow another, it is left undecided), no side where the winding is
    not known."""
    if not bars:
        return {}
    conns, out = np.concatenate(bars), np.concatenate(bar_out)
    sides: dict[tuple, set] = {}
    first: dict[tuple, int] = {}
    for i, key in enumerate(_connector_key(c) for c in conns):
        first.setdefault(key, i)
        sides.setdefault(key, set()).add(float(out[i]))
    keep = list(first.values())
    side = [s.pop() if len(s) == 1 and certified else 0.0 for s in sides.values()]
    return {"bars": conns[keep], "bar_out": np.array(side)}


def _connector_key(conn: np.ndarray) -> tuple:
    """The same for a connector's stretch of axis drawn again (ends in either order, the axis
    either way round)."""
    a, b, axis = np.round(conn, 3) + 0.0
    nz = np.flatnonzero(axis)
    if len(nz) and axis[nz[0]] < 0:
        axis = -axis
    return (tuple(sorted([tuple(a), tuple(b)])), tuple(axis + 0.0))


def _unique_connectors(conns: np.ndarray) -> np.ndarray:
    """Drop connectors drawn twice at the same place (the same ends in either order, the same
    axis either way round)."""
    return conns[_first_of_each(conns)]


def _first_of_each(conns: np.ndarray) -> list[int]:
    seen, keep = set(), []
    for i, conn in enumerate(conns):
        key = _connector_key(conn)
        if key not in seen:
            seen.add(key)
            keep.append(i)
    return keep


def _with_kinds(conns: np.ndarray, kinds: np.ndarray, refs: np.ndarray) -> dict:
    """`Flat`'s other connectors, their kinds and turns, each drawn twice kept once
    (`_unique_connectors`)."""
    keep = _first_of_each(conns)
    return {"other_connectors": conns[keep], "other_kinds": kinds[keep], "other_refs": refs[keep]}


def _turned(directions: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Unit directions (k, 3) turned by a type 1 matrix (which may scale or mirror)."""
    out = np.asarray(directions, float) @ np.asarray(matrix, float).T
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def _unique_studs(studs: np.ndarray) -> np.ndarray:
    """Drop studs that sit at the same place (a stud drawn twice, e.g. with a logo overlay)."""
    if len(studs) == 0:
        return studs
    keys = np.round(studs.reshape(len(studs), 6), 3)
    _, idx = np.unique(keys, axis=0, return_index=True)
    return studs[np.sort(idx)]

