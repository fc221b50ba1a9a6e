"""Render one view of a scene: RGB (multisampled) or segmentation (item index per pixel)."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from factory.ldraw import ColourTable
from factory.pose import LDU_M
from factory.render.cameras import Framing, View, _as_view
from factory.render.scene import BACKGROUND, Item, Scene


def _setup(scene: Scene, items: Sequence[Item], colours: ColourTable, view: View, framing: Framing,
           edges: bool = True) -> None:
    m, d = scene.model, scene.data
    scene.show(items, colours, edges=edges)
    b = scene.bounds(items) if items else np.zeros((2, 3))
    c = np.asarray(framing.center)
    reach = float(np.linalg.norm(b - c, axis=1).max()) + framing.height_of(view)
    dist = reach + 10.0
    pos, rot, fovy = framing.camera(view, dist)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    m.cam_pos[0] = pos
    m.cam_quat[0] = quat
    m.cam_fovy[0] = fovy
    # Clip planes bracket everything shown (orthographic depth is linear, so range costs little).
    m.stat.extent = 1.0
    m.vis.map.znear = max(1.0, dist - reach - 5.0) * LDU_M
    m.vis.map.zfar = (dist + reach + 5.0) * LDU_M
    mujoco.mj_kinematics(m, d)
    mujoco.mj_camlight(m, d)
    mujoco.mjv_updateScene(m, d, scene.option, None, scene.camera, mujoco.mjtCatBit.mjCAT_ALL, scene.mjv_scene)
    f = scene.mjv_scene.flags
    f[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
    f[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    f[mujoco.mjtRndFlag.mjRND_FOG] = 0
    f[mujoco.mjtRndFlag.mjRND_HAZE] = 0
    f[mujoco.mjtRndFlag.mjRND_SKYBOX] = 1


def render_rgb(
    scene: Scene, items: Sequence[Item], colours: ColourTable, view: str | View, framing: Framing, size: int,
    background: tuple[int, int, int] = BACKGROUND,
) -> np.ndarray:
    """(size, size, 3) uint8 image of `items` seen from `view`, on a flat `background` colour."""
    v = _as_view(view)
    con = scene.context("rgb", size)
    scene.set_background(background, con)
    _setup(scene, items, colours, v, framing)
    rect = mujoco.MjrRect(0, 0, size, size)
    mujoco.mjr_render(rect, scene.mjv_scene, con)
    out = np.empty((size, size, 3), np.uint8)
    mujoco.mjr_readPixels(out, None, rect, con)
    return np.ascontiguousarray(out[::-1])


def render_seg(
    scene: Scene, items: Sequence[Item], colours: ColourTable, view: str | View, framing: Framing, size: int
) -> np.ndarray:
    """(size, size) int32: the index into `items` of the part seen at each pixel, -1 for background."""
    v = _as_view(view)
    con = scene.context("seg", size)
    _setup(scene, items, colours, v, framing, edges=False)
    scn = scene.mjv_scene
    scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
    scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
    rect = mujoco.MjrRect(0, 0, size, size)
    try:
        mujoco.mjr_render(rect, scn, con)
    finally:
        scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
        scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
    raw = np.empty((size, size, 3), np.uint8)
    mujoco.mjr_readPixels(raw, None, rect, con)
    # Id colour: segid + 1 in the low 24 bits (red lowest), 0 on the background. Widened to 32 bits
    # through a zeroed fourth byte: half the time of or-ing three widened channels.
    rgba = np.zeros((size, size, 4), np.uint8)
    rgba[..., :3] = raw[::-1]
    lut = scene.segment_lut()
    return lut[np.minimum(rgba.view("<u4")[..., 0], len(lut) - 1)]
