"""Renders: view table, pixel mapping, red boxes, ticks, catalog cells, outlines, determinism, CLI.

Small scenes built inline from the embedded library, at 128-256 px, so the file runs in well under a
minute on a 2-core CPU with Mesa's llvmpipe.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory import Pose, gl_backend
from factory.ldraw import PlacedPart

try:
    from factory import render
except Exception as exc:  # only a missing GL library skips; anything else is a failure
    if type(exc).__name__ != "RenderUnavailableError":
        raise
    pytest.skip(str(exc), allow_module_level=True)

from factory.render import (
    ALL_VIEWS,
    ORTHO_VIEWS,
    VIEWS,
    Framing,
    PartImages,
    RenderUnavailableError,
    Renderer,
    compose,
    gl,
    project,
    render_catalog,
    render_feedback,
    render_part,
    render_step,
    render_step_full,
)
from factory.parts import box_corners
from factory.render.images import _axes_margins, bounds_of
from factory.render.scene import Item
from factory.render.views import render_rgb, render_seg

ROOT = Path(__file__).resolve().parents[1]
TOWER = ROOT / "factory" / "data" / "examples" / "tower.mpd"
GAP = 2  # compose.grid's default gap


def placed(part: str, colour: int, t, R=None) -> PlacedPart:
    return PlacedPart(part, colour, Pose(np.eye(3) if R is None else R, np.asarray(t, float)), "test")


@pytest.fixture(scope="module")
def reader(embedded_reader):
    try:
        gl.Context().close()
    except RenderUnavailableError as exc:  # pragma: no cover - machines without GL
        pytest.skip(str(exc))
    return embedded_reader


@pytest.fixture(scope="module")
def renderer(reader):
    with Renderer(reader) as r:
        yield r


def six_tile(img, index: int, size: int) -> np.ndarray:
    """The render (without its label strip) of view `index` in a six-view composite."""
    arr = np.asarray(img)
    strip = compose.label_strip_height(size)
    r, c = divmod(index, 3)
    y0 = r * (size + strip + GAP) + strip
    x0 = c * (size + GAP)
    return arr[y0 : y0 + size, x0 : x0 + size]


# -- the view table ----------------------------------------------------------------------------
def test_views_have_fixed_names_order_and_ldraw_directions():
    assert ORTHO_VIEWS == ("Top", "Front", "Right", "Bottom", "Back", "Left")
    assert ALL_VIEWS == (*ORTHO_VIEWS, "Isometric")
    # Front is LDraw's standard view: camera on the -Z side, +X right, -Y (up) at the top.
    assert VIEWS["Front"].eye == (0, 0, -1) and VIEWS["Front"].right == (1, 0, 0) and VIEWS["Front"].up == (0, -1, 0)
    assert VIEWS["Top"].eye == (0, -1, 0)  # above: LDraw -Y is up
    assert VIEWS["Right"].eye == (1, 0, 0) and VIEWS["Left"].eye == (-1, 0, 0)
    for v in VIEWS.values():
        m = np.stack([v.right, v.up, v.eye], 1).astype(float)
        assert np.allclose(m.T @ m, np.eye(3)) and np.linalg.det(m) > 0
    with pytest.raises(ValueError):
        project("Sideways", (0, 0, 0), Framing((0, 0, 0), 100, 100))


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(ORTHO_VIEWS),
    st.tuples(*[st.floats(-500, 500)] * 3),
    st.floats(30, 2000),
    st.tuples(*[st.floats(-300, 300)] * 3),
)
def test_projection_round_trips_through_the_tick_mapping(view, center, height, point):
    f = Framing(center, height, height)
    px, py = project(view, point, f, 256)
    (hi, _), (vi, _) = VIEWS[view].axes()
    assert f.coordinate_at(view, px, "h", 256) == pytest.approx(point[hi], abs=1e-6)
    assert f.coordinate_at(view, py, "v", 256) == pytest.approx(point[vi], abs=1e-6)
    assert project(view, f.center, f, 256) == pytest.approx((128, 128))


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.lists(st.tuples(st.integers(0, 39), st.integers(0, 39)), max_size=12),
       st.integers(0, 5))
def test_a_box_from_a_mask_is_its_true_pixels_bounds_padded_and_clamped(h, w, pixels, pad):
    mask = np.zeros((h, w), bool)
    for y, x in pixels:
        mask[y % h, x % w] = True
    ys, xs = np.nonzero(mask)
    want = None if not len(xs) else (max(0, xs.min() - pad), max(0, ys.min() - pad),
                                      min(w - 1, xs.max() + pad), min(h - 1, ys.max() + pad))
    assert compose.box_from_mask(mask, pad) == want


# -- pixel mapping: a marker lands where project() says --------------------------------------------
def test_marker_lands_at_the_projected_pixels_in_every_view(reader, renderer):
    size = 128
    t = np.array([37.0, -23.0, 51.0])  # off-centre on all three axes, so a flipped sign shows
    part = render.images.load_part(reader, "3024")  # 1 x 1 plate: a small marker
    framing = Framing.from_bounds(np.array([[-100.0] * 3, [100.0] * 3]))
    scene = renderer.scene_for([part], render.images.EDGE_PX * framing.height / size)
    item = Item(part, 14, Pose(np.eye(3), t))
    corners = box_corners(np.asarray(part.bbox) + t)
    for view in ORTHO_VIEWS:
        seg = render_seg(scene, [item], renderer.colours, view, framing, size)
        ys, xs = np.nonzero(seg == 0)
        proj = framing.project(view, corners, size)
        # Pixel (i, j) is covered when its centre is: the mask spans floor(min+.5) .. ceil(max-.5).
        assert abs(xs.min() - proj[:, 0].min()) <= 1.0, view
        assert abs(xs.max() + 1 - proj[:, 0].max()) <= 1.0, view
        assert abs(ys.min() - proj[:, 1].min()) <= 1.0, view
        assert abs(ys.max() + 1 - proj[:, 1].max()) <= 1.0, view
        rgb = render_rgb(scene, [item], renderer.colours, view, framing, size)
        cy, cx = np.argwhere((rgb != 255).any(-1)).mean(0)
        px, py = project(view, (corners.min(0) + corners.max(0)) / 2, framing, size)
        assert abs(cx + 0.5 - px) <= 1.5 and abs(cy + 0.5 - py) <= 1.5, view


# -- a step: red boxes, segmentation ---------------------------------------------------------------
@pytest.fixture(scope="module")
def step(reader, renderer):
    before = [placed("3001", 71, (0, 0, 0))]  # grey 2 x 4 brick, top at y=0
    new = [placed("3003", 1, (10, -24, 0))]  # blue 2 x 2 brick on top of it, off-centre
    return before, new, render_step_full(renderer, before, new, 256)


def test_red_box_contains_the_new_part_and_is_tight(step, reader):
    _, new, res = step
    part = render.images.load_part(reader, "3003")
    corners = box_corners(np.asarray(part.bbox) + new[0].pose.t)
    seen = 0
    for k, view in enumerate(ORTHO_VIEWS):
        box = res.boxes[view][0]
        if view == "Bottom":  # hidden under the 2 x 4 brick
            assert box is None
            continue
        seen += 1
        proj = res.framing.project(view, corners, 256)
        lo, hi = proj.min(0), proj.max(0)
        x0, y0, x1, y1 = box
        assert x0 <= lo[0] and y0 <= lo[1] and x1 + 1 >= hi[0] and y1 + 1 >= hi[1], (view, box, lo, hi)
        assert lo[0] - x0 <= 4 and lo[1] - y0 <= 4 and x1 + 1 - hi[0] <= 4 and y1 + 1 - hi[1] <= 4, view
        # The box is drawn: the red pixels of the tile span exactly the box.
        tile = six_tile(res.images["after"], k, 256)
        red = (tile == np.array(compose.RED, np.uint8)).all(-1)
        ys, xs = np.nonzero(red)
        assert (xs.min(), ys.min(), xs.max(), ys.max()) == (x0, y0, x1, y1), view
        # ... and dashed: the top side has gaps.
        top = red[y0, x0 : x1 + 1]
        assert 0.3 < top.mean() < 0.9
    assert seen == 5
    before_tile = six_tile(res.images["before"], 1, 256)
    assert not (before_tile == np.array(compose.RED, np.uint8)).all(-1).any()


def test_segmentation_ids_are_in_range(step):
    before, new, res = step
    n = len(before) + len(new)
    for view, seg in res.segmentation.items():
        assert seg.dtype == np.int32 and seg.min() >= -1 and seg.max() < n, view
        assert (seg == -1).any()
    assert set(np.unique(res.segmentation["Front"])) == {-1, 0, 1}


def test_step_images_and_sizes(step):
    _, _, res = step
    strip = compose.label_strip_height(256)
    assert set(res.images) == {"before", "after", "isometric", "part_1", "axes"}
    assert res.images["before"].size == (3 * 256 + 2 * GAP, 2 * (256 + strip) + GAP)
    assert res.images["after"].size == res.images["before"].size


def test_same_framing_before_and_after(reader, renderer):
    before = [placed("3001", 71, (0, 0, 0))]
    new = [placed("3001", 4, (0, -24, 0))]
    res = render_step_full(renderer, before, new, 128, parts=False)
    assert res.framing == Framing.from_bounds(bounds_of(before + new, reader))
    # The grey brick sits at the same pixels before and after the step.
    for k, view in enumerate(ORTHO_VIEWS):
        if view == "Top":  # covered by the new brick
            continue
        b = six_tile(res.images["before"], k, 128)
        ys, xs = np.nonzero((b != 255).any(-1))
        ya, xa = np.nonzero(res.segmentation[view] == 0)
        # (the RGB silhouette also holds the outline, up to 2 px outside the faces)
        assert abs(xs.min() - xa.min()) <= 2 and abs(xs.max() - xa.max()) <= 2, view
        assert abs(ys.max() - ya.max()) <= 2, view


# -- ticks -----------------------------------------------------------------------------------------
def test_tick_labels_agree_with_the_pixel_mapping(step):
    _, _, res = step
    f, size = res.framing, 256
    img = np.asarray(res.images["axes"])
    ml, mb = _axes_margins(size)
    strip = compose.label_strip_height(size)
    tile_w, tile_h = size + ml, size + strip + mb
    for k, view in enumerate(ORTHO_VIEWS):
        ticks = f.ticks(view, size)
        assert len(ticks["h"]) >= 3 and len(ticks["v"]) >= 3
        (hi, _), (vi, _) = VIEWS[view].axes()
        r, c = divmod(k, 4)
        ox, oy = c * (tile_w + GAP), r * (tile_h + GAP)
        for value, x in ticks["h"]:
            p = np.asarray(f.center, float)
            p[hi] = value
            assert project(view, p, f, size)[0] == pytest.approx(x)
            assert value % 1 == 0 or value * 2 % 1 == 0  # round LDU values
            # A dark tick mark hangs below the render at that column.
            xi = ox + ml + min(size - 1, int(np.floor(x)))
            assert tuple(img[oy + strip + size + 2, xi]) == compose.INK, (view, value)
        for value, y in ticks["v"]:
            p = np.asarray(f.center, float)
            p[vi] = value
            assert project(view, p, f, size)[1] == pytest.approx(y)
            yi = oy + strip + min(size - 1, int(np.floor(y)))
            assert tuple(img[yi, ox + ml - 3]) == compose.INK, (view, value)
        # Values grow in the direction the view's axis points.
        (_, hs), _ = VIEWS[view].axes()
        xs = [x for _, x in ticks["h"]]
        vals = [v for v, _ in ticks["h"]]
        assert np.all(np.diff(vals) * hs * np.sign(np.diff(xs)) > 0)


# -- outlines --------------------------------------------------------------------------------------
@pytest.mark.parametrize("colour", [4, 14, 72])  # red, yellow, dark bluish grey
def test_adjacent_same_colour_bricks_are_distinguishable(reader, colour, renderer):
    size = 192
    side = [placed("3001", colour, (-40, 0, 0)), placed("3001", colour, (40, 0, 0))]  # touching at x = 0
    stack = [placed("3001", colour, (0, 0, 0)), placed("3001", colour, (0, -24, 0))]  # touching at y = 0
    for parts, axis in ((side, 0), (stack, 1)):
        f = Framing.from_bounds(bounds_of(parts, reader))
        items = [Item(render.images.load_part(reader, p.part), p.colour, p.pose) for p in parts]
        scene = renderer.scene_for([it.part for it in items], render.images.EDGE_PX * f.height / size)
        img = render_rgb(scene, items, renderer.colours, "Front", f, size).astype(float)
        lum = img @ np.array([0.299, 0.587, 0.114])
        sx, sy = project("Front", (0.0, 12.0 if axis == 0 else 0.0, -20.0), f, size)
        if axis == 0:  # vertical seam at x = 0, sampled down the face's middle rows
            rows = slice(int(sy) - 5, int(sy) + 5)
            seam_lum = lum[rows, int(sx) - 1 : int(sx) + 1].min(1).mean()
            face = lum[rows, int(sx) + 15]
        else:  # horizontal seam at y = 0
            cols = slice(int(sx) - 30, int(sx) + 30)
            seam_lum = lum[int(sy) - 1 : int(sy) + 1, cols].min(0).mean()
            face = lum[int(sy) + 12, cols]
        assert seam_lum < 0.6 * face.mean(), (axis, seam_lum, face.mean())


def test_a_scene_redraws_whatever_items_it_is_given(reader, renderer):
    """Views of one set of parts reuse its poses and colours; other items, even equal copies or a
    colour change, are drawn as given."""
    size = 128
    parts = [placed("3001", 4, (0, 0, 0)), placed("3001", 1, (0, -24, 0))]
    f = Framing.from_bounds(bounds_of(parts, reader))
    items = [Item(render.images.load_part(reader, p.part), p.colour, p.pose) for p in parts]
    scene = renderer.scene_for([it.part for it in items], render.images.EDGE_PX * f.height / size)
    colours = renderer.colours
    both = render_rgb(scene, items, colours, "Front", f, size)
    lower = render_rgb(scene, items[:1], colours, "Front", f, size)
    recoloured = render_rgb(scene, [items[0], Item(items[1].part, 14, items[1].pose)], colours, "Front", f, size)
    copies = render_rgb(scene, [Item(it.part, it.colour, it.pose) for it in items], colours, "Front", f, size)
    again = render_rgb(scene, items, colours, "Front", f, size)
    assert not np.array_equal(both, lower) and not np.array_equal(both, recoloured)
    assert np.array_equal(both, copies) and np.array_equal(both, again)
    assert np.allclose(scene.bounds(items), scene.bounds(items[:1]) + [[0, -24, 0], [0, 0, 0]])


def test_one_segmentation_table_serves_every_view_of_the_same_items(reader, renderer):
    """`Scene.segment_lut` is kept across views of one set of items: each view's segmentation
    equals the one read with a table rebuilt for that view, and other items get a new table."""
    size = 96
    parts = [placed("3001", 4, (0, 0, 0)), placed("3003", 1, (10, -24, 0)), placed("3024", 14, (-30, 8, 20))]
    f = Framing.from_bounds(bounds_of(parts, reader))
    items = [Item(render.images.load_part(reader, p.part), p.colour, p.pose) for p in parts]
    scene = renderer.scene_for([it.part for it in items], render.images.EDGE_PX * f.height / size)
    for view in ALL_VIEWS:
        kept = render_seg(scene, items, renderer.colours, view, f, size)
        scene._lut_memo = None  # rebuilt from this view's scene
        fresh = render_seg(scene, items, renderer.colours, view, f, size)
        assert np.array_equal(kept, fresh), view
        assert set(np.unique(fresh)) <= {-1, 0, 1, 2} and (fresh >= 0).any(), view
    front = render_seg(scene, items, renderer.colours, "Front", f, size)
    shuffled = render_seg(scene, items[::-1], renderer.colours, "Front", f, size)  # item indices reversed
    assert np.array_equal(np.where(front >= 0, 2 - front, -1), shuffled)


# -- catalog ---------------------------------------------------------------------------------------
def test_catalog_cells_are_where_the_grid_says(reader, renderer):
    parts = [("3001", 71)] * 3 + [("3024", 71), ("3003", 71), ("3001", 4), ("3023", 71), ("3024", 71)]
    img, cells = render_catalog(renderer, parts, tile=96)
    assert cells == [(1, 1), (1, 2), (1, 3), (1, 4), (1, 5), (1, 6), (2, 1), (2, 2)]
    strip = compose.label_strip_height(96)
    th = 96 + strip
    assert img.size == (6 * 96 + 5 * GAP, 2 * th + GAP)
    arr = np.asarray(img).astype(int)

    def tile(row, col):
        y0, x0 = (row - 1) * (th + GAP), (col - 1) * (96 + GAP)
        return arr[y0 : y0 + th, x0 : x0 + 96]

    def reddish(t):
        return ((t[..., 0] > 150) & (t[..., 1] < 60) & (t[..., 2] < 60)).sum()

    r, c = cells[5]  # the one red brick
    assert reddish(tile(r, c)) > 200
    assert all(reddish(tile(*cells[i])) == 0 for i in range(len(parts)) if i != 5)
    # Identical bricks get separate, identical tiles; a common scale makes the 1 x 1 plate smaller.
    assert np.array_equal(tile(*cells[0]), tile(*cells[1]))
    assert np.array_equal(tile(*cells[3]), tile(*cells[7]))

    def area(t):
        return (t[strip:] != 255).any(-1).sum()

    assert area(tile(*cells[3])) < 0.3 * area(tile(*cells[0]))
    with pytest.raises(ValueError):
        render_catalog(renderer, [])


# -- part and feedback renders -------------------------------------------------------------------
def test_part_render_draws_labelled_axes_from_the_origin(reader, renderer):
    img = np.asarray(render_part(renderer, "3001", 71, size=192)).astype(int)
    strip = compose.label_strip_height(192)
    body = img[strip:]
    for name in "XYZ":
        rgb = np.array(compose.AXIS_RGB[name])
        assert (np.abs(body - rgb).sum(-1) < 10).sum() > 50, name
    # Red +X points right of green +Y, which points down.
    xs = np.argwhere(np.abs(body - compose.AXIS_RGB["X"]).sum(-1) < 10)
    ys = np.argwhere(np.abs(body - compose.AXIS_RGB["Y"]).sum(-1) < 10)
    assert xs[:, 1].max() > ys[:, 1].max() + 20
    assert ys[:, 0].max() > xs[:, 0].max()


def test_feedback_draws_the_prediction_in_red(reader, renderer):
    before = [placed("3001", 1, (0, 0, 0))]
    wrong = [placed("3003", 14, (60, -24, 0), R=np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]]))]
    img = np.asarray(render_feedback(renderer, before, wrong, 128)).astype(int)
    strip = compose.label_strip_height(128)
    top = img[strip : strip + 128, 0:128]  # the Top view
    red = (top[..., 0] > 180) & (top[..., 1] < 60) & (top[..., 2] < 60)
    assert red.sum() > 100
    f = Framing.from_bounds(bounds_of(before + wrong, reader))
    cx, _ = project("Top", (60, -24, 0), f, 128)
    assert abs(np.argwhere(red)[:, 1].mean() - cx) < 4


def test_feedback_draws_the_settled_part_solid_and_the_prediction_as_an_outline(reader, renderer):
    before = [placed("3001", 1, (0, 0, 0))]
    predicted = [placed("3003", 14, (60, -60, 0))]  # in the air beside the brick
    settled = [placed("3003", 14, (60, 0, 0))]  # where it fell: on the table
    img = np.asarray(render_feedback(renderer, before, predicted, 128, settled=settled)).astype(int)
    strip = compose.label_strip_height(128)
    view = ALL_VIEWS.index("Front")
    row, col = divmod(view, 4)
    y0, x0 = row * (128 + strip + 2) + strip, col * (128 + 2)  # compose.grid's 2-pixel gaps
    front = img[y0 : y0 + 128, x0 : x0 + 128]
    red = (front[..., 0] > 180) & (front[..., 1] < 60) & (front[..., 2] < 60)  # solid red only
    f = Framing.from_bounds(bounds_of(before + predicted + settled, reader))
    _, y_settled = project("Front", (60, 0, 0), f, 128)
    _, y_predicted = project("Front", (60, -60, 0), f, 128)
    assert red.sum() > 50
    rows = np.argwhere(red)[:, 0]
    # The solid red is at the settled brick, not at the outlined prediction 60 LDU above it.
    assert abs(rows.mean() - y_settled) < abs(rows.mean() - y_predicted)


# -- determinism ------------------------------------------------------------------------------------
def _png(img) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def test_same_input_gives_identical_png_bytes(reader, renderer):
    before = [placed("3001", 4, (0, 0, 0)), placed("3001", 4, (0, 0, 40))]
    new = [placed("3039", 14, (0, -24, 10))]
    a = render_step(renderer, before, new, 128)
    with Renderer(reader) as fresh:  # freshly compiled scenes and a new GL context
        b = render_step(fresh, before, new, 128)
    assert a.keys() == b.keys()
    for k in a:
        assert _png(a[k]) == _png(b[k]), k


# -- backend errors and the command line ----------------------------------------------------------
def test_no_gl_library_names_what_to_install(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(gl_backend.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(RenderUnavailableError, match="libosmesa6"):
        gl._choose_backend()
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    with pytest.raises(RenderUnavailableError, match="apt-get install libosmesa6"):
        gl._choose_backend()
    monkeypatch.delenv("MUJOCO_GL")
    gl_backend.pin()  # no library: a command starts anyway, and the renderer says what to install
    assert "MUJOCO_GL" not in os.environ


def test_a_command_pins_the_gl_backend_so_mujoco_never_loads_glfw():
    """GLFW's import starts a Python child; a Ctrl-C during its start printed Python's fatal error."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    code = "import sys, os, mujoco; print(os.environ.get('MUJOCO_GL'), 'glfw' in sys.modules)"
    plain = subprocess.run([sys.executable, "-c", "import factory; " + code], env=env, capture_output=True, text=True)
    assert plain.stdout.split() == ["None", "True"], plain.stderr  # a user's script: untouched
    as_command = "import sys; sys.orig_argv[:] = [sys.executable, '-m', 'pipelines.synth']; "  # what -m gives
    probe = subprocess.run(  # SIGINT as a terminal gives it (a test runner's worker may ignore it: inherited)
        [sys.executable, "-c", as_command + "import factory; " + code],
        env=env, capture_output=True, text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert probe.stdout.split() == [gl_backend.choose(), "False"], probe.stderr


def _cli(*args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "pipelines.render", *map(str, args)],
        check=False, capture_output=True, text=True, cwd=ROOT, timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])), **(env or {})},
    )


def test_cli_writes_the_image_set_deterministically(tmp_path, reader):
    outs = []
    for run in ("a", "b"):
        res = _cli(TOWER, "--step", 3, "--out", tmp_path / run, "--size", 128, "--tile", 64)
        assert res.returncode == 0, res.stderr
        outs.append(tmp_path / run)
    names = sorted(p.name for p in outs[0].iterdir())
    assert names == ["after.png", "axes.png", "before.png", "catalog.png", "feedback.png", "isometric.png",
                     "part_1.png", "part_2.png", "step.json"]
    for n in names:
        assert (outs[0] / n).read_bytes() == (outs[1] / n).read_bytes(), n


@pytest.mark.parametrize(
    "args, message",
    [
        (("--step", 99), "out of range"),
        (("--step", 0, "--size", 5), "--size"),
        (("--step", 0, "--predict", "1 2 3"), "12 numbers"),
    ],
)
def test_cli_bad_input_is_one_line_and_nonzero(tmp_path, args, message):
    res = _cli(TOWER, "--out", tmp_path / "o", *args)
    assert res.returncode != 0
    assert message in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_cli_missing_model_and_bad_ldraw(tmp_path):
    res = _cli(tmp_path / "nope.ldr", "--step", 0, "--out", tmp_path / "o")
    assert res.returncode == 2 and res.stderr.startswith("error:") and len(res.stderr.strip().splitlines()) == 1
    res = _cli(TOWER, "--step", 0, "--out", tmp_path / "o", "--ldraw", tmp_path)
    assert res.returncode == 2 and "not an LDraw library" in res.stderr


def test_feedback_accepts_a_matrix_that_is_not_a_rotation(reader, renderer):
    bad = [placed("3003", 14, (0, -24, 0), R=np.array([[2.0, 0, 0], [0, 1, 0], [0, 0, -1]]))]
    img = render_feedback(renderer, [placed("3001", 1, (0, 0, 0))], bad, 64)
    assert img.size[0] == 4 * 64 + 3 * GAP


def test_feedback_draws_an_answer_of_1e308_at_its_reach(reader, renderer):
    """A model's pose answer of x = 1e308 (scored wrong and capped) made the world-feedback render
    fail (MuJoCo: "vertex coordinate 0 is not finite"); it is drawn 10,000 LDU away in its
    direction instead, and the same answer within reach is drawn where it says."""
    from factory.render.images import FEEDBACK_REACH_LDU, within_reach

    centre = np.zeros(3)
    far = within_reach(placed("3003", 14, (1e308, -1e308, 0)).pose, centre)
    assert np.allclose(far.t, FEEDBACK_REACH_LDU * np.array([1.0, -1.0, 0.0]) / np.sqrt(2))
    near = placed("3003", 14, (40, -24, 0)).pose
    assert within_reach(near, centre) is near
    img = render_feedback(renderer, [placed("3001", 1, (0, 0, 0))], [placed("3003", 14, (1e308, 0, 0))], 64)
    assert img.size[0] == 4 * 64 + 3 * GAP


@pytest.mark.skipif(
    __import__("ctypes.util").util.find_library("OSMesa") is None,
    reason="libOSMesa is not installed (apt-get install libosmesa6); EGL is the default backend",
)
def test_osmesa_fallback_renders_the_step(tmp_path):
    env = {"MUJOCO_GL": "osmesa", "PYOPENGL_PLATFORM": "osmesa"}
    res = _cli(TOWER, "--step", 3, "--out", tmp_path, "--size", 96, "--tile", 48, env=env)
    assert res.returncode == 0, res.stderr
    from PIL import Image

    after = np.asarray(Image.open(tmp_path / "after.png").convert("RGB")).astype(int)
    red = (after[..., 0] > 200) & (after[..., 1] < 60) & (after[..., 2] < 60)
    assert red.sum() > 20, "the red box around the new part is drawn"


def test_kept_glyph_masks_draw_what_pil_draws():
    """`compose.text` (glyph masks kept across calls) gives the pixels of `ImageDraw.text` for the
    labels the renders draw, at every font size they use, on a busy background, drawn twice."""
    from PIL import Image, ImageDraw

    from factory.render import compose

    rng = np.random.default_rng(0)
    labels = ["0", "-20", "140", "12.5", "X (LDU)", "-Y (LDU)", "Brick 3", "front", "Catalog", "+Z"]
    for size in (9, 10, 12, 14, 20, 28):
        base = rng.integers(0, 256, size=(60, 160, 3), dtype=np.uint8)
        for fill in (compose.INK, (220, 30, 30)):
            a, b = Image.fromarray(base), Image.fromarray(base)
            da, db = ImageDraw.Draw(a), ImageDraw.Draw(b)
            for k, s in enumerate(labels * 2):
                xy = (int(rng.integers(-5, 150)), int(rng.integers(-5, 50)))
                da.text(xy, s, fill=fill, font=compose.font(size))
                compose.text(db, xy, s, size, fill)
            assert np.array_equal(np.asarray(a), np.asarray(b)), (size, fill)


def test_a_chosen_egl_device_that_is_not_there_falls_back(monkeypatch):
    """A numbered worker whose GPU share names an EGL device that does not exist (more GPUs than EGL
    devices) renders on the default device instead of failing its shard."""
    from factory import gpus
    from factory.render import gl

    if gl.configure() != "egl":
        pytest.skip("the EGL backend is not the one in use")
    script = ("import os; from factory import gpus; gpus.count = lambda: 64; "
              "from factory.render import gl; c = gl.Context(); "
              "print(c.backend, os.environ.get('MUJOCO_EGL_DEVICE_ID'))")
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_EGL_DEVICE_ID"}
    env[gpus.SLOT_ENV] = "63"
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["egl", "None"]


def test_axes_views_made_from_the_previous_step_match_rendered_ones(reader, renderer):
    """A step's 'before' axes views come from the previous step's plain views and segmentation
    (background turned light) instead of seven renders: the same image but for antialiased
    silhouette pixels, which blend with white instead of the light grey."""
    scene_parts = [placed("3001", 15, (0, 0, 0)), placed("3003", 4, (30, -24, 10)),
                   placed("3020", 1, (0, -48, 0))]
    bounds = bounds_of(scene_parts, reader)
    kw = dict(bounds=bounds, scene_parts=scene_parts, parts=False)
    first = render_step_full(renderer, scene_parts[:1], scene_parts[1:2], 128, **kw)
    alone = render_step_full(renderer, scene_parts[:2], scene_parts[2:], 128, before_views=first.after_views, **kw)
    reused = render_step_full(renderer, scene_parts[:2], scene_parts[2:], 128, before_views=first.after_views,
                              before_isometric=first.after_isometric, before_segmentation=first.segmentation, **kw)
    a = np.asarray(alone.images["axes"]).astype(int)
    b = np.asarray(reused.images["axes"]).astype(int)
    diff = np.abs(a - b).max(-1)
    assert a.shape == b.shape and 0 < np.count_nonzero(diff) < 0.01 * diff.size and diff.max() <= 16
    # the white brick's faces stay white: only background pixels turn light
    white_a, white_b = ((x == 255).all(-1).sum() for x in (a, b))
    assert white_a > 500 and abs(int(white_a) - int(white_b)) < 0.01 * diff.size
    for name in ("before", "after", "isometric"):
        assert alone.images[name].tobytes() == reused.images[name].tobytes()


def test_part_image_is_the_same_whatever_was_rendered_before(reader):
    """Part images (`PartImages`) outlive the renderer that drew them (the dataset builder keeps them
    across its per-object renderers), so they must not depend on the scenes a renderer built
    before: the same pixels from a fresh renderer and after a step whose scene holds the part among
    others, and a kept image is what a later renderer returns."""
    with Renderer(reader) as first:
        fresh = np.asarray(render_part(first, "3039", 14, 128))
    images = PartImages()
    before = [placed("3001", 4, (0, 0, 0)), placed("3039", 14, (0, -24, 10))]
    with Renderer(reader, part_images=images) as second:
        render_step(second, before, [placed("3039", 14, (40, -24, 10))], 128)
        assert len(images) == 1
        again = np.asarray(render_part(second, "3039", 14, 128))
    assert np.array_equal(fresh, again)
    with Renderer(reader, part_images=images) as third:
        step = render_step(third, before, [placed("3039", 14, (40, -24, 10))], 128)
    assert np.array_equal(np.asarray(step["part_1"]), fresh)
    with pytest.raises(RuntimeError, match="closed"):
        render_part(third, "3039", 14, 128)


def test_a_model_past_the_scene_budget_is_refused_at_once(tmp_path, monkeypatch, capsys):
    """A 20,000-part model ran past 60 s at 2 GB in `pipelines.render`: models past
    `MAX_SCENE_PARTS` are refused up front with the file named (a scaled-down budget here), and the
    library refuses such a scene too."""
    from factory.errors import LDrawLimitError

    model = tmp_path / "grid.ldr"
    model.write_text("".join(f"1 4 {40 * i} 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n" for i in range(12)))
    from pipelines import render as render_cli

    assert render_cli.main([str(model), "--step", "0", "--out", str(tmp_path / "o1")]) == 0  # within the budget
    monkeypatch.setattr(render.scene, "MAX_SCENE_PARTS", 10)
    parts = [placed("3001", 4, (40 * i, 0, 0)) for i in range(11)]
    with Renderer(max_scene_parts=10) as small, pytest.raises(LDrawLimitError, match="at most 10 are rendered"):
        render_step(small, parts[:1], parts[1:], 64, scene_parts=parts)
    capsys.readouterr()
    assert render_cli.main([str(model), "--step", "0", "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {model}: model places 12 parts; at most 10 are rendered\n"
    assert not (tmp_path / "o2").exists()


def test_a_renderer_frees_what_it_drops_and_everything_on_exit(reader):
    """A scene dropped from a renderer's kept set frees its render contexts at once; leaving the
    `with` block frees the rest and the GL context, and the renderer refuses to render again."""
    framing = Framing.from_bounds(np.array([[-60.0] * 3, [60.0] * 3]))
    brick, plate = (render.images.load_part(reader, name) for name in ("3001", "3024"))
    with Renderer(reader, max_singles=1) as r:
        first = r.scene_for([brick], 1.0)
        render_rgb(first, [Item(brick, 4, Pose.identity())], r.colours, "Front", framing, 64)
        assert first.has_contexts()
        second = r.scene_for([plate], 1.0)  # a second one-part scene: the first is dropped
        render_rgb(second, [Item(plate, 1, Pose.identity())], r.colours, "Front", framing, 64)
        assert not first.has_contexts() and second.has_contexts()
        assert r.scene_for([plate], 1.0) is second
    assert not second.has_contexts()
    with pytest.raises(RuntimeError, match="closed"):
        r.scene_for([plate], 1.0)


def test_outline_segments_are_kept_on_disk_and_read_back_the_same(reader, tmp_path, monkeypatch):
    """`geometry.simplified_edges` keeps each part's simplified outline per tolerance in the
    cache folder: read back, it is the computed array exactly; a damaged entry is made again."""
    from factory.parts import load_part
    from factory.render import geometry

    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    edges = geometry.part_geometry(load_part(reader, "3001")).edges
    calls = []
    inner = geometry.simplify_edges
    monkeypatch.setattr(geometry, "simplify_edges", lambda s, t: calls.append(t) or inner(s, t))
    first = [geometry.simplified_edges(edges, t) for t in (0.6, 2.0)]
    assert len(calls) == 2 and len(list((tmp_path / "outlines").glob("*.npy"))) == 2
    again = [geometry.simplified_edges(edges, t) for t in (0.6, 2.0)]
    assert len(calls) == 2
    for a, b, t in zip(first, again, (0.6, 2.0)):
        assert a.dtype == b.dtype == np.float64 and np.array_equal(a, b) and np.array_equal(a, inner(edges, t))
    assert len(first[1]) < len(first[0]) < len(edges)  # a coarser tolerance keeps fewer segments
    for entry in (tmp_path / "outlines").glob("*.npy"):
        entry.write_bytes(entry.read_bytes()[:40])
    assert all(np.array_equal(a, geometry.simplified_edges(edges, t)) for a, t in zip(first, (0.6, 2.0)))
    assert len(calls) == 4
