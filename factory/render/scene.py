"""A visual MuJoCo scene: slots of part meshes whose poses, colours and visibility change per render.

A `Scene` is compiled once for a multiset of parts (one body per slot; one visual mesh per distinct
part and colour group, shared by every slot of that part; one edge mesh per distinct part). Every
geom is visual only (`contype=0 conaffinity=0`). Poses (`body_pos`, `body_quat`), colours
(`geom_rgba`) and visibility (`geom_group`: 0 shown, 3 hidden) are model fields written at render
time, so one compiled model and one pair of GL contexts serve every step of an assembly, the
feedback render (the same part at a predicted pose, in red) and the "current assembly" renders.

Scenes are built and kept by a `factory.render.renderer.Renderer` (`Renderer.scene_for`), whose GL
context their render contexts live in.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from factory.ldraw import ColourTable, Reader
from factory.ldraw.colours import EDGE, MAIN
from factory.parts import Part
from factory.pose import LDU_M, Pose, points_to_mujoco
from factory.render import gl
from factory.render.geometry import outline_mesh, part_geometry

SHOWN, HIDDEN = 0, 3
"""Geom groups: the render option shows group 0 only."""

BACKGROUND = (255, 255, 255)
RGB_SAMPLES = int(os.environ.get("BRICK_RENDER_SAMPLES", "4"))
"""Multisamples of the RGB renders (`BRICK_RENDER_SAMPLES`; 0 is faster on llvmpipe, with jagged edges)."""
Rgba = tuple[float, float, float, float]


@dataclass(frozen=True)
class Item:
    """One part to show: the part, its colour (an LDraw code or an explicit RGBA) and its pose."""

    part: Part
    colour: int | Rgba
    pose: Pose
    edge_rgba: Rgba | None = None
    """Outline colour; default: `outline_rgba` of the colour (near black on all but dark faces)."""


def colour_table(reader: Reader) -> ColourTable:
    """The library's LDConfig colours (codes it lacks render neutral grey); a `Renderer` keeps its
    reader's table as `Renderer.colours`."""
    return reader.colours


def luminance(rgb) -> float:
    return float(0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2])


DARK_EDGE = (0.05, 0.05, 0.05, 1.0)
LIGHT_EDGE = (0.6, 0.6, 0.6, 1.0)


def outline_rgba(rgba, ldconfig_edge=None) -> Rgba:
    """The outline colour for a face colour: near black, except on dark faces.

    LDConfig's edge colours are mostly #333333, which on red or blue faces barely differs in
    brightness; outlines must separate adjacent same-colour bricks, so faces of luminance 0.2 or
    more get near-black outlines, darker faces LDConfig's edge colour if it is clearly lighter
    (black's is grey), else light grey.
    """
    lum = luminance(rgba)
    if lum >= 0.2:
        return DARK_EDGE
    if ldconfig_edge is not None and luminance(ldconfig_edge) >= lum + 0.25:
        return tuple(ldconfig_edge[:3]) + (1.0,)  # type: ignore[return-value]
    return LIGHT_EDGE


def _rgba_of(colours: ColourTable, colour: int | Rgba) -> tuple[Rgba, Rgba]:
    if isinstance(colour, (tuple, list, np.ndarray)):
        rgba = tuple(float(c) for c in colour)
        rgba = (*rgba[:3], rgba[3] if len(rgba) > 3 else 1.0)
        return rgba, outline_rgba(rgba)  # type: ignore[return-value]
    c = colours.get(int(colour))
    return tuple(c.rgba), outline_rgba(c.rgba, c.edge)  # type: ignore[return-value]


def quantize_radius(r: float) -> float:
    """Edge radii snap to powers of 2 ** (1/4), so nearby framings share a compiled scene."""
    return float(2 ** (round(4 * math.log2(max(r, 1e-3))) / 4))


class Scene:
    """A compiled visual model with one slot per part of `parts` (see the module doc)."""

    def __init__(self, parts: Sequence[Part], edge_radius: float, gl_context: Callable[[], gl.Context]):
        """`gl_context`: returns the GL context the render contexts live in, made current (the
        owning renderer's `Renderer.gl_context`)."""
        self.parts = list(parts)
        self._gl_context = gl_context
        self._glc: gl.Context | None = None
        self.edge_radius = edge_radius
        spec = mujoco.MjSpec()
        spec.modelname = "brick_factory_render"
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.visual.global_.offwidth = 512
        spec.visual.global_.offheight = 512
        spec.visual.quality.offsamples = RGB_SAMPLES
        # No shadows are drawn (lights cast none), so skip the 4096² shadow map each render
        # context would allocate (84 MB).
        spec.visual.quality.shadowsize = 0
        spec.visual.headlight.ambient = [0.42, 0.42, 0.42]
        spec.visual.headlight.diffuse = [0.42, 0.42, 0.42]
        spec.visual.headlight.specular = [0.0, 0.0, 0.0]
        spec.add_texture(
            name="background",
            type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
            builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,
            rgb1=[c / 255 for c in BACKGROUND],
            rgb2=[c / 255 for c in BACKGROUND],
            width=8,
            height=8,
        )
        # A key light from above, front and left (LDraw direction of travel), fixed in the world.
        key = points_to_mujoco(np.array([0.45, 1.0, 0.7])) / LDU_M
        spec.worldbody.add_light(
            type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
            dir=(key / np.linalg.norm(key)).tolist(),
            pos=[0, 0, 1],
            diffuse=[0.28, 0.28, 0.28],
            specular=[0, 0, 0],
            ambient=[0, 0, 0],
            castshadow=False,
        )
        spec.worldbody.add_camera(name="view", proj=mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC, fovy=0.1)

        meshes: dict[int, tuple[list[tuple[str, int]], str | None]] = {}
        for part in self.parts:
            if id(part) in meshes:
                continue
            geo = part_geometry(part)
            names = []
            for gi, (code, tris) in enumerate(geo.groups):
                name = f"m{len(meshes)}_{gi}"
                self._add_mesh(spec, name, tris)
                names.append((name, code))
            edge_name = None
            edge_tris = outline_mesh(part, edge_radius)
            if len(edge_tris):
                edge_name = f"m{len(meshes)}_edges"
                self._add_mesh(spec, edge_name, edge_tris)
            meshes[id(part)] = (names, edge_name)

        geom_names: list[tuple[int, str, int | None]] = []  # (slot, geom name, colour code / None=edge)
        for slot, part in enumerate(self.parts):
            body = spec.worldbody.add_body(name=f"slot{slot}")
            names, edge_name = meshes[id(part)]
            for gi, (mesh, code) in enumerate(names):
                gname = f"s{slot}_g{gi}"
                body.add_geom(
                    name=gname, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh,
                    contype=0, conaffinity=0, group=HIDDEN, mass=0,
                )
                geom_names.append((slot, gname, code))
            if edge_name:
                gname = f"s{slot}_e"
                body.add_geom(
                    name=gname, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=edge_name,
                    contype=0, conaffinity=0, group=HIDDEN, mass=0,
                )
                geom_names.append((slot, gname, None))
        self.model = spec.compile()
        m = self.model
        self.data = mujoco.MjData(m)
        self.body_of_slot = np.array(
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"slot{s}") for s in range(len(self.parts))], int
        )
        self.geom_slot = np.full(m.ngeom, -1, int)
        self.slot_geoms: list[list[tuple[int, int | None]]] = [[] for _ in self.parts]
        for slot, gname, code in geom_names:
            gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, gname)
            self.geom_slot[gid] = slot
            self.slot_geoms[slot].append((gid, code))
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:] = 0
        self.option.geomgroup[SHOWN] = 1
        self.mjv_scene = mujoco.MjvScene(m, maxgeom=m.ngeom + 64)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.camera.fixedcamid = 0
        self._contexts: dict[str, mujoco.MjrContext] = {}
        self._background: dict[int, tuple[int, int, int]] = {}
        self._buffer = 512
        self.shown: list[int] = []
        self._show_key: tuple | None = None
        self._edge_geoms = np.zeros(0, np.int64)
        self._edges_on = True
        self._bounds_memo: tuple | None = None
        self._lut_memo: tuple | None = None
        self._vertices = {id(p): part_geometry(p).vertices for p in self.parts}

    @staticmethod
    def _add_mesh(spec: mujoco.MjSpec, name: str, tris: np.ndarray) -> None:
        if len(tris) == 1:  # MuJoCo wants 4 vertices or more: show the lone triangle from both sides
            tris = np.concatenate([tris, tris[:, ::-1]])
        mesh = spec.add_mesh(name=name)
        mesh.uservert = points_to_mujoco(tris.reshape(-1, 3)).astype(np.float32).ravel()
        mesh.userface = np.arange(len(tris) * 3, dtype=np.int32)
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL

    # -- slots -------------------------------------------------------------------------------
    def counts(self) -> Counter:
        return Counter(id(p) for p in self.parts)

    def show(self, items: Sequence[Item], colours: ColourTable, edges: bool = True) -> list[int]:
        """Show exactly `items` (in slots holding their parts); returns the slot of each item.

        `edges=False` leaves the outline prisms hidden (segmentation needs faces only).
        """
        # The views of one image set show the same items: on a GPU, rewriting 60 parts' poses and
        # colours per view cost more than drawing it. Items are frozen; `_shown_items` holds them,
        # so their ids cannot be reused while the key is kept.
        # The outlines are switched on their own: RGB and segmentation renders of one view
        # alternate, and with `edges` in the key every view rewrote every pose and colour twice.
        key = (tuple(map(id, items)), id(colours))
        if key == self._show_key:
            if edges != self._edges_on:
                self.model.geom_group[self._edge_geoms] = SHOWN if edges else HIDDEN
                self._edges_on = edges
            return self.shown
        free: dict[int, list[int]] = {}
        for slot, part in enumerate(self.parts):
            free.setdefault(id(part), []).append(slot)
        slots = []
        for it in items:
            pool = free.get(id(it.part))
            if not pool:
                raise ValueError(f"scene has no free slot for {it.part.name}")
            slots.append(pool.pop(0))
        m = self.model
        m.geom_group[:] = HIDDEN
        edge_geoms = []
        for it, slot in zip(items, slots):
            body = self.body_of_slot[slot]
            pos, quat = it.pose.to_mujoco_quat()
            m.body_pos[body] = pos
            m.body_quat[body] = quat
            rgba, edge = _rgba_of(colours, it.colour)
            if it.edge_rgba is not None:
                edge = tuple(it.edge_rgba)
            for gid, code in self.slot_geoms[slot]:
                if code is None or code == EDGE:
                    m.geom_rgba[gid] = edge
                elif code == MAIN:
                    m.geom_rgba[gid] = rgba
                else:
                    m.geom_rgba[gid] = colours.get(code).rgba
                if code is None:
                    edge_geoms.append(gid)
                if edges or code is not None:
                    m.geom_group[gid] = SHOWN
        self._edge_geoms = np.array(edge_geoms, np.int64)
        self._edges_on = edges
        self.shown = slots
        self._shown_items = list(items)
        self._show_key = key
        return slots

    def bounds(self, items: Sequence[Item]) -> np.ndarray:
        """Exact axis-aligned bounds (LDU) of placed items, from their mesh vertices."""
        key = tuple(map(id, items))
        if self._bounds_memo is not None and self._bounds_memo[0] == key:
            return self._bounds_memo[2].copy()
        pts = [it.pose.apply(self._vertices[id(it.part)]) for it in items if len(self._vertices[id(it.part)])]
        if not pts:
            return np.zeros((2, 3))
        allp = np.concatenate(pts)
        out = np.stack([allp.min(0), allp.max(0)])
        self._bounds_memo = (key, list(items), out)
        return out.copy()

    def segment_lut(self) -> np.ndarray:
        """Item index (int32) by id colour of a segmentation render of the scene last built by
        `mjv_updateScene`: entry k is for segid k - 1 (entry 0, the background, and anything not an
        item's face: -1); the last entry stands for every colour past the others (-1 too).
        Segids follow the order in which visible geoms enter the scene, which only the shown items
        and outlines decide (not the camera), so one table serves every view of an image set
        (reading it geom by geom took 0.30 ms a render for an 80-part scene, development machine)."""
        scn = self.mjv_scene
        key = (self._show_key, self._edges_on, scn.ngeom)
        if self._lut_memo is not None and self._lut_memo[0] == key:
            return self._lut_memo[1]
        slot_to_item = np.full(len(self.parts), -1, np.int32)
        slot_to_item[np.asarray(self.shown, int)] = np.arange(len(self.shown))
        lut = np.full(scn.ngeom + 3, -1, np.int32)
        geom = mujoco.mjtObj.mjOBJ_GEOM
        for i in range(scn.ngeom):
            g = scn.geoms[i]
            if g.segid >= 0 and g.objtype == geom and 0 <= g.objid < len(self.geom_slot):
                slot = self.geom_slot[g.objid]
                if slot >= 0:
                    lut[g.segid + 1] = slot_to_item[slot]
        self._lut_memo = (key, lut)
        return lut

    # -- GL ----------------------------------------------------------------------------------
    def context(self, kind: str, size: int) -> mujoco.MjrContext:
        """The MuJoCo render context: 'rgb' (4x multisampling) or 'seg' (no multisampling)."""
        glc = self._glc = self._gl_context()
        if size > self._buffer:
            self.free()
            self._buffer = 1 << (int(size) - 1).bit_length()
        con = self._contexts.get(kind)
        if con is None:
            m = self.model
            m.vis.global_.offwidth = self._buffer
            m.vis.global_.offheight = self._buffer
            # Multisampling blends segmentation id colours into ids that do not exist.
            m.vis.quality.offsamples = RGB_SAMPLES if kind == "rgb" else 0
            con = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
            m.vis.quality.offsamples = RGB_SAMPLES
            self._contexts[kind] = con
            glc.adopt(self)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, con)
        return con

    def set_background(self, rgb: tuple[int, int, int], con: mujoco.MjrContext) -> None:
        """Recolour the flat background (a skybox texture, so it renders as exactly `rgb`)."""
        rgb = tuple(int(c) for c in rgb)
        if self._background.get(id(con)) == rgb:
            return
        m = self.model
        n, a = int(m.tex_nchannel[0]), int(m.tex_adr[0])
        k = int(m.tex_width[0] * m.tex_height[0])
        m.tex_data[a : a + k * n] = np.tile(np.array(rgb[:n], np.uint8), k)
        mujoco.mjr_uploadTexture(m, con, 0)
        self._background[id(con)] = rgb

    def has_contexts(self) -> bool:
        return bool(self._contexts)

    def free(self) -> None:
        """Free the render contexts (the GL context they live in must be current)."""
        self._background.clear()
        for con in self._contexts.values():
            con.free()
        self._contexts.clear()

    def __del__(self):
        try:
            if self._contexts and self._glc is not None and self._glc.alive:
                self._glc.make_current()
                self.free()
        except Exception:  # noqa: BLE001, S110 - never raise from a destructor
            pass


MAX_SCENE_PARTS = 10_000
"""Parts one render scene holds (one body per part, with outlines). Measured here (2 shared
cores, EGL on the CPU, 2x4 bricks, `pipelines.render --step 0`): 2,000 parts 3.8 s and 0.5 GB,
6,000 parts 8.7 s and 0.8 GB; 20,000 ran past 60 s at 2 GB. 10,000 holds the largest sets people
build (a few thousand to about 7,500 pieces) and renders in well under a minute."""
