"""The renderer: one object owning a GL context, the scenes compiled for it and the images cached on them.

    with Renderer(reader) as renderer:
        res = render_step_full(renderer, before, new, 256, bounds=bounds, scene_parts=every)

Everything that holds GL resources (the context, each scene's MuJoCo render contexts) belongs to one
`Renderer` and is freed by `close()` (or leaving the `with` block); nothing lives in module globals.
A renderer's lifetime is the scope whose renders may share scenes: the dataset builder makes one per
object, so a row's pixels do not depend on which objects the process rendered before (a resumed run
writes the same bytes as an uninterrupted one). Part images (`PartImages`) are plain pictures that
do not depend on what was rendered before (each part is drawn in a scene of that part alone), so a
caller may keep one `PartImages` across renderers.
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from collections.abc import Sequence

from PIL import Image

from factory.errors import LDrawLimitError
from factory.ldraw import ColourTable, Reader, get_reader
from factory.parts import Part
from factory.render import gl
from factory.render.scene import MAX_SCENE_PARTS, Scene, colour_table, quantize_radius

MAX_SCENES = 8
"""Scenes of several slots (assemblies, catalogs) a renderer keeps, least recently used first."""
MAX_SINGLES = 64
"""One-slot scenes (part renders) a renderer keeps: cheap, many, kept apart so they never evict
assemblies."""
MAX_PART_IMAGES = 256
"""Part renders a `PartImages` keeps (about 0.2 MB each at 256 px)."""


class PartImages:
    """Part renders by (reader, model, part, colour, size), least recently used first.

    A part is drawn in a scene of that part alone, so its image is the same whatever was rendered
    before: one `PartImages` may outlive many renderers (the dataset builder keeps one per shard, so
    each object need not compile its parts' scenes again: 38 of a 40-step object's 40 part images
    were compiled afresh when they were dropped per object).
    """

    def __init__(self, limit: int = MAX_PART_IMAGES):
        self.limit = limit
        self._images: OrderedDict[tuple, tuple[Reader, Image.Image]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._images)

    def get(self, reader: Reader, key: tuple) -> Image.Image | None:
        """A copy of the image stored for `key` rendered with `reader`, or None."""
        hit = self._images.get((id(reader), *key))
        if hit is None or hit[0] is not reader:  # the reader is held, so its id stays its own
            return None
        self._images.move_to_end((id(reader), *key))
        return hit[1].copy()

    def put(self, reader: Reader, key: tuple, image: Image.Image) -> None:
        self._images[(id(reader), *key)] = (reader, image)
        self._images.move_to_end((id(reader), *key))
        while len(self._images) > self.limit:
            self._images.popitem(last=False)


class Renderer:
    """A GL context (started on the first render), the scenes compiled for `reader`'s parts, the
    catalog tiles and the part images; a context manager that frees them on exit.

    `max_scenes`, `max_singles`: compiled scenes kept (assemblies and catalogs; one-part scenes);
    `max_scene_parts`: the most parts one scene holds (`LDrawLimitError` past it); `part_images`: a
    `PartImages` shared with other renderers (default: the renderer's own).
    """

    def __init__(self, reader: Reader | None = None, *, max_scenes: int = MAX_SCENES,
                 max_singles: int = MAX_SINGLES, max_scene_parts: int = MAX_SCENE_PARTS,
                 part_images: PartImages | None = None):
        self.reader = reader if reader is not None else get_reader()
        self.colours: ColourTable = colour_table(self.reader)
        self.max_scenes = max_scenes
        self.max_singles = max_singles
        self.max_scene_parts = max_scene_parts
        self.part_images = part_images if part_images is not None else PartImages()
        self.tiles: dict[tuple, Image.Image] = {}
        """Catalog tiles by (part, model, colour, common height, tile size): a catalog shrinks by a
        brick per step and keeps its scale until its tallest part is used up, so most tiles repeat."""
        self._gl: gl.Context | None = None
        self._scenes: OrderedDict[int, Scene] = OrderedDict()
        self._singles: OrderedDict[int, Scene] = OrderedDict()
        self._serial = 0
        self._closed = False

    # -- lifetime --------------------------------------------------------------------------------
    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.close()
            return
        # Leaving on an error or a Ctrl-C: a GL call cut short can leave the context unusable, and
        # an error from freeing it must not replace the one that is on its way out.
        try:
            self.close()
        except Exception:  # noqa: BLE001 - the first error is the one to report
            self._gl, self._closed = None, True

    def gl_context(self) -> gl.Context:
        """The renderer's GL context, started on first use and made current."""
        if self._closed:
            raise RuntimeError("this Renderer is closed")
        if self._gl is None:
            self._gl = gl.Context()
        self._gl.make_current()
        return self._gl

    def close(self) -> None:
        """Free every scene's render contexts, then the GL context; the renderer cannot render again."""
        if self._gl is not None:
            self._gl.close()  # frees the scenes it adopted first, while the context is current
            self._gl = None
        self._closed = True
        self.tiles.clear()
        self._scenes.clear()
        self._singles.clear()

    # -- scenes ----------------------------------------------------------------------------------
    def scene_for(self, parts: Sequence[Part], edge_radius: float, universe: Sequence[Part] | None = None,
                  alone: bool = False) -> Scene:
        """A scene with a slot for each of `parts` (kept; built for `universe` when one must be built).

        `universe`, a superset of `parts` (e.g. every part of a model), lets one compiled scene serve
        every step of an assembly. `alone`: a scene of exactly `parts`, never a larger kept one, so
        what it renders does not depend on which scenes the renderer built before.
        """
        if self._closed:
            raise RuntimeError("this Renderer is closed")
        r = quantize_radius(edge_radius)
        need = Counter(id(p) for p in parts)
        for cache in ((self._singles,) if alone else (self._scenes, self._singles)):
            for key, scene in cache.items():
                if scene.edge_radius == r:
                    have = scene.counts()
                    if have == need if alone else all(have[k] >= n for k, n in need.items()):
                        cache.move_to_end(key)
                        return scene
        pool = list(universe) if universe is not None and not alone else []
        if max(len(pool), len(parts)) > self.max_scene_parts:
            raise LDrawLimitError(f"a render scene of {max(len(pool), len(parts)):,} parts; at most "
                                  f"{self.max_scene_parts:,} are rendered")
        have = Counter(id(p) for p in pool)
        for p in parts:  # whatever the universe lacks
            if have[id(p)] < need[id(p)]:
                pool.append(p)
                have[id(p)] += 1
        scene = Scene(pool, r, self.gl_context)
        self._serial += 1
        cache, limit = (self._singles, self.max_singles) if len(pool) == 1 else (self._scenes, self.max_scenes)
        cache[self._serial] = scene
        while len(cache) > limit:
            _, old = cache.popitem(last=False)
            if old.has_contexts():
                self.gl_context()
                old.free()
        return scene
