"""The image set of an assembly step, and the catalog, part and feedback renders.

Every render takes a `Renderer` first (its reader gives the parts and colours; its GL context and
kept scenes draw them) and `PlacedPart`s (part file name, colour code, pose in LDU). `bounds_of` and
`framing_for` need no renderer: a `Reader` (default: `get_reader()`, i.e. `$LDRAWDIR` or the embedded
library).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from PIL import Image, ImageDraw

from factory.ldraw import PlacedPart, Reader, get_reader
from factory.parts import Part, load_part
from factory.pose import Pose, nearest_rotation_matrix
from factory.render import compose
from factory.render.cameras import (
    ALL_VIEWS,
    AXIS_NAMES,
    ISOMETRIC,
    ORTHO_VIEWS,
    VIEWS,
    Framing,
)
from factory.render.geometry import part_geometry
from factory.render.renderer import Renderer
from factory.render.scene import BACKGROUND, Item, Scene
from factory.render.views import render_rgb, render_seg

EDGE_PX = 0.9
"""Edge prism radius in pixels of the axis views (outlines are about 1.4 to 1.6 px wide)."""
BOX_PAD = 2
"""Pixels between a part's segmentation bounds and its red dashed box."""
FEEDBACK_RGBA = (0.93, 0.06, 0.06, 1.0)
FEEDBACK_EDGE = (0.35, 0.0, 0.0, 1.0)
FEEDBACK_OUTLINE_RGBA = (0.93, 0.06, 0.06, 0.3)
"""The predicted placement when the settled one is drawn too: translucent red, its edges dark red."""


def _reader(reader: Reader | None) -> Reader:
    return reader if reader is not None else get_reader()


def _items(placed: Sequence[PlacedPart], reader: Reader) -> list[Item]:
    return [Item(load_part(reader, p), p.colour, p.pose) for p in placed]


def _scene(renderer: Renderer, items: Sequence[Item], framing_height: float, size: int,
           universe: Sequence[PlacedPart] | None) -> Scene:
    uni = [load_part(renderer.reader, p) for p in universe] if universe is not None else None
    return renderer.scene_for([it.part for it in items], EDGE_PX * framing_height / size, universe=uni)


def framing_for(placed: Sequence[PlacedPart], reader: Reader | None = None, margin: float = 0.08) -> Framing:
    """The framing of an assembly: its exact bounds (mesh vertices), with `margin` each side."""
    reader = _reader(reader)
    return Framing.from_bounds(bounds_of(placed, reader), margin=margin)


def bounds_of(placed: Sequence[PlacedPart], reader: Reader | None = None) -> np.ndarray:
    """Axis-aligned bounds [[min xyz], [max xyz]] (LDU) of placed parts (zeros when empty)."""
    reader = _reader(reader)
    pts = []
    for p in placed:
        v = part_geometry(load_part(reader, p)).vertices
        if len(v):
            pts.append(p.pose.apply(v))
    if not pts:
        return np.zeros((2, 3))
    allp = np.concatenate(pts)
    return np.stack([allp.min(0), allp.max(0)])


# -- composites ------------------------------------------------------------------------------
def _views(scene: Scene, items, colours, framing, size, views=ORTHO_VIEWS, background=compose.WHITE):
    return [render_rgb(scene, items, colours, v, framing, size, background=background) for v in views]


def six_view_composite(tiles: Sequence[Image.Image]) -> Image.Image:
    """Six labelled views, 3 x 2, in the fixed order Top, Front, Right / Bottom, Back, Left."""
    return compose.grid([compose.labelled(t, name) for t, name in zip(tiles, ORTHO_VIEWS)], cols=3)


@dataclass
class StepRender:
    """Everything `render_step` made: the images, and the red boxes and framing behind them."""

    images: dict[str, Image.Image]
    boxes: dict[str, list[tuple[int, int, int, int] | None]]
    """Per view (the six and Isometric): one inclusive pixel box per new part, None where unseen."""
    framing: Framing
    segmentation: dict[str, np.ndarray] = field(default_factory=dict)
    """Per view: index into before + new of the part seen at each pixel, -1 for background."""
    after_views: list[np.ndarray] = field(default_factory=list)
    """The six orthographic views after the step, plain (no boxes): the next step's `before_views`
    when it renders the same assembly, framing and scene."""
    after_isometric: np.ndarray | None = None
    """The isometric view after the step, plain: with `after_views` and `segmentation`, the next
    step's axes views (`before_views`, `before_isometric`, `before_segmentation`)."""


def render_step(renderer: Renderer, before: Sequence[PlacedPart], new: Sequence[PlacedPart], size: int = 256, *,
                bounds=None, scene_parts: Sequence[PlacedPart] | None = None,
                axes_state: str = "before") -> dict[str, Image.Image]:
    """The BC-Bench images of one step, as {name: image}.

    `before`: the assembly before the step; `new`: the parts the step places. Images: `before` and
    `after` (six labelled orthographic views; in `after` each new part in a red dashed box),
    `isometric` (after, with the boxes), `part_1`.. (each new part alone with its axes), `axes`
    (7 views of the `axes_state` assembly, 'before' or 'after', with LDU ticks).

    `bounds` ([[min xyz], [max xyz]] LDU) fixes the framing, e.g. the whole model's bounds so every
    step of a model is framed alike; default: the bounds of before + new. `scene_parts` (e.g. every
    part of the model) lets one compiled scene serve all steps.
    """
    return render_step_full(renderer, before, new, size, bounds=bounds, scene_parts=scene_parts,
                            axes_state=axes_state).images


def render_step_full(renderer: Renderer, before: Sequence[PlacedPart], new: Sequence[PlacedPart],
                     size: int = 256, *, bounds=None,
                     scene_parts: Sequence[PlacedPart] | None = None, axes_state: str = "before",
                     parts: bool = True, before_views: Sequence[np.ndarray] | None = None,
                     before_isometric: np.ndarray | None = None,
                     before_segmentation: dict[str, np.ndarray] | None = None) -> StepRender:
    """`render_step`, also returning the red boxes, the framing and the segmentation renders.

    `before_views`: the previous step's `after_views`, when that step rendered exactly `before`
    with the same bounds, scene parts and size; the same pixels, without rendering them again.
    With its `after_isometric` and `segmentation` too, the 'before' axes views are made from them
    (`_axes_composite`) instead of seven more renders.
    """
    if axes_state not in ("before", "after"):
        raise ValueError("axes_state must be 'before' or 'after'")
    reader, colours = renderer.reader, renderer.colours
    b_items, n_items = _items(before, reader), _items(new, reader)
    after = b_items + n_items
    framing = Framing.from_bounds(bounds if bounds is not None else bounds_of([*before, *new], reader))
    scene = _scene(renderer, after, framing.height, size, scene_parts)

    if before_views is None:
        before_views = _views(scene, b_items, colours, framing, size)
    before_tiles = [Image.fromarray(a) for a in before_views]
    boxes: dict[str, list] = {}
    segs: dict[str, np.ndarray] = {}
    after_tiles, after_views = [], []
    for v in ALL_VIEWS:
        arr = render_rgb(scene, after, colours, v, framing, size)
        if v != ISOMETRIC:
            after_views.append(arr.copy())
        else:
            after_iso = arr.copy()
        rgb = Image.fromarray(arr)
        seg = render_seg(scene, after, colours, v, framing, size)
        segs[v] = seg
        boxes[v] = []
        for j in range(len(n_items)):
            box = compose.box_from_mask(seg == len(b_items) + j, BOX_PAD)
            boxes[v].append(box)
            if box is not None:
                compose.dashed_rect(rgb, box)
        after_tiles.append(rgb)
    images = {
        "before": six_view_composite(before_tiles),
        "after": six_view_composite(after_tiles[:6]),
        "isometric": compose.labelled(after_tiles[6], ISOMETRIC),
    }
    if parts:
        for j, p in enumerate(new, 1):
            key = (p.model, p.part.lower(), int(p.colour), size)
            image = renderer.part_images.get(reader, key)
            if image is None:
                image = render_part(renderer, load_part(reader, p), p.colour, size=size)
                renderer.part_images.put(reader, key, image)
                image = image.copy()
            images[f"part_{j}"] = image
    shown = b_items if axes_state == "before" else after
    given = None
    if axes_state == "before" and before_isometric is not None and before_segmentation is not None:
        given = ({**dict(zip(ORTHO_VIEWS, before_views)), ISOMETRIC: before_isometric}, before_segmentation)
    images["axes"] = _axes_composite(scene, shown, colours, framing, size,
                                     title=f"{axes_state} this step", given=given)
    return StepRender(images, boxes, framing, segs, after_views, after_iso)


def _axes_margins(size: int) -> tuple[int, int]:
    fs = max(9, compose.font_size(size) - 2)
    return compose.text_width("-0000", fs) + max(4, size // 48) + 8, 2 * fs + max(4, size // 48) + 8


def _axes_composite(scene: Scene, items: Sequence[Item], colours, framing: Framing, size: int,
                    title: str = "", given: tuple[dict, dict] | None = None) -> Image.Image:
    """The seven axis views of `items` on the light background. `given` = (plain views on white,
    segmentations) of exactly these items, framing and size, by view name: the views are made from
    them, the background (white where no part is seen) turned light, instead of rendered again."""
    ml, mb = _axes_margins(size)
    tiles = []
    light = np.array(compose.LIGHT_BG, np.uint8)
    for v in ALL_VIEWS:
        if given is None:
            arr = render_rgb(scene, items, colours, v, framing, size, background=compose.LIGHT_BG)
            mask = compose.colour_mask(arr, light)
        else:
            arr = given[0][v]
            # Only pure background: outlines and antialiased edges outside the faces (where the
            # segmentation, drawn without outlines or multisampling, sees nothing) keep their pixels.
            mask = (given[1][v] < 0) & compose.colour_mask(arr, BACKGROUND)
        if v == ISOMETRIC:
            tile = compose.tick_tile(arr, v, {}, None, ml, mb, mask)
            _triad(tile, framing, size, ml)
        else:
            (hi, _), (vi, _) = VIEWS[v].axes()  # type: ignore[misc]
            ticks = framing.ticks(v, size)
            tile = compose.tick_tile(arr, v, ticks, (AXIS_NAMES[hi], AXIS_NAMES[vi]), ml, mb, mask)
        tiles.append(tile)
    legend = [
        "LDraw frame, units LDU",
        "1 LDU = 0.4 mm; stud pitch 20,",
        "brick height 24, plate 8",
        "+X right, +Y DOWN (up is -Y),",
        "+Z away in the Front view",
        "Front looks along +Z",
    ]
    if title:
        legend.insert(0, f"Assembly {title}")
    fs = max(9, compose.font_size(size) - 3)
    tiles.append(compose.text_tile(legend, tiles[0].size, fs=fs))
    return compose.grid(tiles, cols=4)


def _triad(tile: Image.Image, framing: Framing, size: int, ml: int) -> None:
    """A small X/Y/Z axis triad in the isometric tile's top-left corner."""
    d = ImageDraw.Draw(tile)
    strip = compose.label_strip_height(size)
    origin = np.array([ml + size * 0.14, strip + size * 0.13])
    length = size * 0.09
    for i, name in enumerate(AXIS_NAMES):
        vec = np.zeros(3)
        vec[i] = 1
        p = framing.project(ISOMETRIC, np.asarray(framing.center) + vec, size) - size / 2
        p = p / np.linalg.norm(p) * length
        compose.arrow(d, origin, origin + p, compose.AXIS_RGB[name], max(1, size // 128))
        fs = max(9, compose.font_size(size) - 3)
        d.text(tuple(origin + p * 1.35 - fs / 2), f"+{name}", fill=compose.AXIS_RGB[name], font=compose.font(fs))


# -- single renders --------------------------------------------------------------------------
def render_axes(renderer: Renderer, placed: Sequence[PlacedPart], size: int = 256, *, bounds=None,
                scene_parts: Sequence[PlacedPart] | None = None) -> Image.Image:
    """7 views (six orthographic and isometric) with LDU tick labels on a light background."""
    items = _items(placed, renderer.reader)
    framing = Framing.from_bounds(bounds if bounds is not None else bounds_of(placed, renderer.reader))
    scene = _scene(renderer, items, framing.height, size, scene_parts)
    return _axes_composite(scene, items, renderer.colours, framing, size)


def render_views(renderer: Renderer, placed: Sequence[PlacedPart], size: int = 256, *, bounds=None,
                 views: Sequence[str] = ORTHO_VIEWS, scene_parts=None) -> list[np.ndarray]:
    """Plain RGB arrays of `placed` in the given views (a common framing from `bounds`)."""
    items = _items(placed, renderer.reader)
    framing = Framing.from_bounds(bounds if bounds is not None else bounds_of(placed, renderer.reader))
    scene = _scene(renderer, items, framing.height, size, scene_parts)
    return _views(scene, items, renderer.colours, framing, size, views)


def render_part(renderer: Renderer, part: str | Part, colour: int = 16, size: int = 256) -> Image.Image:
    """The part alone in its own LDraw frame (isometric), its axes drawn from its origin and labelled."""
    p = part if isinstance(part, Part) else load_part(renderer.reader, part)
    item = Item(p, colour, Pose.identity())
    bb = np.asarray(p.bbox, float)
    ext = float((bb[1] - bb[0]).max()) or 20.0
    tips = np.diag(np.maximum(bb[1], 0) + 0.35 * ext + 6)  # +X, +Y, +Z tips beyond the part
    lo = np.minimum(bb[0], 0)
    hi = np.maximum(bb[1], tips.max(0))
    framing = Framing.from_bounds(np.stack([lo, hi]), margin=0.1)
    scene = renderer.scene_for([p], EDGE_PX * framing.iso_height / size, alone=True)
    img = Image.fromarray(render_rgb(scene, [item], renderer.colours, ISOMETRIC, framing, size))
    d = ImageDraw.Draw(img)
    o = framing.project(ISOMETRIC, np.zeros(3), size)
    fs = max(10, compose.font_size(size))
    for i, name in enumerate(AXIS_NAMES):
        tip = framing.project(ISOMETRIC, tips[i], size)
        compose.arrow(d, o, tip, compose.AXIS_RGB[name], max(2, size // 100))
        direction = (tip - o) / max(1e-6, np.linalg.norm(tip - o))
        at = tip + direction * fs * 0.9 - np.array([fs * 0.6, fs * 0.55])
        d.text(tuple(at), f"+{name}", fill=compose.AXIS_RGB[name], font=compose.font(fs))
    return compose.labelled(img, f"{p.name} in its LDraw frame (origin, +X red, +Y green, +Z blue)"
                            if size >= 384 else f"{p.name}: own LDraw frame")


def render_catalog(renderer: Renderer, parts: Sequence[tuple[str, int] | tuple[str, int, str | None] | PlacedPart],
                   tile: int = 128, cols: int = 6) -> tuple[Image.Image, list[tuple[int, int]]]:
    """A grid of candidate parts (part name, colour), one tile each at a common scale.

    Tiles run left to right, top to bottom, `cols` to a row; each shows the part alone (isometric, in
    its own frame, centred) with its file name above. Identical parts get separate tiles. A third
    item, the model's path, names a part the model ships (`PlacedPart.model`). Returns the
    image and, for each input, its (row, col), both 1-indexed from the top-left.
    """
    reader, colours = renderer.reader, renderer.colours
    entries = [(p.part, p.colour, p.model) if isinstance(p, PlacedPart)
               else (p[0], int(p[1]), p[2] if len(p) > 2 else None) for p in parts]
    if not entries:
        raise ValueError("render_catalog needs at least one part")
    loaded = [load_part(reader, name, model) for name, _, model in entries]
    distinct = list({id(p): p for p in loaded}.values())
    heights = [Framing.from_bounds(p.bbox, margin=0.06).iso_height for p in distinct]
    height = max(heights)
    scene = None
    tiles, cells = [], []
    for i, (p, (_name, colour, model)) in enumerate(zip(loaded, entries)):
        key = (model, p.name.lower(), colour, height, tile)
        if key not in renderer.tiles:
            if scene is None:
                scene = renderer.scene_for(distinct, EDGE_PX * height / tile)
            bb = np.asarray(p.bbox, float)
            f = Framing(tuple(((bb[0] + bb[1]) / 2).tolist()), height, height)  # type: ignore[arg-type]
            arr = render_rgb(scene, [Item(p, colour, Pose.identity())], colours, ISOMETRIC, f, tile)
            renderer.tiles[key] = compose.labelled(Image.fromarray(arr), p.name)
        tiles.append(renderer.tiles[key])
        r, c = divmod(i, cols)
        cells.append((r + 1, c + 1))
    return compose.grid(tiles, cols=cols), cells


FEEDBACK_REACH_LDU = 10_000.0
"""How far from the assembly a predicted part is drawn (LDU, 4 m; the scoring's translation cap):
an answer farther away (x = 1e308 happens) is drawn at this distance in its direction, and the
image says so; MuJoCo refuses non-finite coordinates, and a farther part shrinks the assembly to
nothing."""


def within_reach(pose: Pose, centre) -> Pose:
    """`pose`, or, when its translation is more than `FEEDBACK_REACH_LDU` from `centre` (or not
    finite), the same rotation at that distance in its direction (+x where it has none)."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.asarray(pose.t, float) - np.asarray(centre, float)
        scale = np.max(np.abs(np.nan_to_num(d, nan=0.0, posinf=1.0, neginf=-1.0)))
        unit = np.nan_to_num(d, nan=0.0, posinf=1.0, neginf=-1.0) / scale if scale > 0 else np.zeros(3)
        n = np.linalg.norm(d) if np.all(np.isfinite(d)) else np.inf
    if n <= FEEDBACK_REACH_LDU:
        return pose
    norm = np.linalg.norm(unit)
    direction = unit / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
    return Pose(pose.R, np.asarray(centre, float) + FEEDBACK_REACH_LDU * direction)


def nearest_rotation(pose: Pose) -> Pose:
    """The pose with its matrix replaced by the nearest rotation (a model's answer may not be one)."""
    if pose.is_rotation(1e-6):
        return pose
    rot = nearest_rotation_matrix(np.nan_to_num(np.asarray(pose.R, float)))
    return Pose(rot, np.nan_to_num(np.asarray(pose.t, float)))


def _muted(colours, code: int) -> tuple[float, float, float, float]:
    """A part's colour washed out towards light grey, so the red prediction stands out."""
    r, g, b, a = colours.get(int(code)).rgba
    grey = 0.5 * (r + g + b) / 3 + 0.45
    return (0.35 * r + 0.65 * grey, 0.35 * g + 0.65 * grey, 0.35 * b + 0.65 * grey, a)


def render_feedback(renderer: Renderer, before: Sequence[PlacedPart], predicted: Sequence[PlacedPart],
                    size: int = 256, *, bounds=None,
                    scene_parts: Sequence[PlacedPart] | None = None,
                    settled: Sequence[PlacedPart] | None = None) -> Image.Image:
    """The assembly with predicted (possibly wrong) placements drawn in red: 7 labelled views.

    With `settled` (where the predicted parts ended up when the prediction was executed,
    `factory.physics.settle`) the predicted placements are drawn as a red outline (translucent,
    dark red edges) and the settled ones in solid red.

    The assembly is drawn in muted colours so the bright red prediction stands out whatever the
    assembly's colours. Framed on `bounds` grown to include the predicted parts, so a far-off
    prediction stays in view. A predicted matrix that is not a rotation (scaled, mirrored, as models
    sometimes answer) is drawn with the nearest rotation.
    """
    reader, colours = renderer.reader, renderer.colours
    b_items = [Item(it.part, _muted(colours, it.colour), it.pose) for it in _items(before, reader)]
    predicted = [replace(p, pose=nearest_rotation(p.pose)) for p in predicted]
    centre = np.zeros(3) if not before else bounds_of(before, reader).mean(axis=0)
    reached = [within_reach(p.pose, centre) for p in predicted]
    far = any(r is not p.pose for r, p in zip(reached, predicted))
    predicted = [replace(p, pose=r) for p, r in zip(predicted, reached)]
    ended = [replace(p, pose=within_reach(p.pose, centre)) for p in settled or ()]
    far = far or any(e.pose is not p.pose for e, p in zip(ended, settled or ()))
    outline = FEEDBACK_OUTLINE_RGBA if settled is not None else FEEDBACK_RGBA
    p_items = [Item(load_part(reader, p), outline, p.pose, FEEDBACK_EDGE) for p in predicted]
    p_items += [Item(load_part(reader, p), FEEDBACK_RGBA, p.pose, FEEDBACK_EDGE) for p in ended]
    bb = bounds_of([*before, *predicted, *ended], reader)
    if bounds is not None:
        b = np.asarray(bounds, float)
        bb = np.stack([np.minimum(bb[0], b[0]), np.maximum(bb[1], b[1])])
    framing = Framing.from_bounds(bb)
    scene = _scene(renderer, b_items + p_items, framing.height, size, scene_parts)
    arrs = _views(scene, b_items + p_items, colours, framing, size, ALL_VIEWS)
    tiles = [compose.labelled(Image.fromarray(a), v) for a, v in zip(arrs, ALL_VIEWS)]
    fs = max(9, compose.font_size(size) - 3)
    lines = (["Predicted placement: red outline", "Where it ended up: solid red", "Assembly: muted colours"]
             if settled is not None else ["Predicted placement: bright red", "Assembly: muted colours"])
    if far:
        lines.append(f"(beyond {FEEDBACK_REACH_LDU:,.0f} LDU: drawn there)")
    tiles.append(compose.text_tile(lines, tiles[0].size, bg=compose.WHITE, fs=fs))
    return compose.grid(tiles, cols=4)
