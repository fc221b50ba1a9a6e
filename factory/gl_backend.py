"""Which headless OpenGL library MuJoCo renders with: the choice only (stdlib), so that a command can
make it before anything imports MuJoCo.

Order: `MUJOCO_GL` if it names `egl` or `osmesa` (the user's choice, no fallback); else EGL when
`libEGL` is installed (Mesa llvmpipe on a CPU machine, the NVIDIA driver on a GPU); else OSMesa when
`libOSMesa` is installed. `factory.render.gl` starts contexts with it.

Why a command pins it early (`pin`): with `MUJOCO_GL` unset, `import mujoco` loads GLFW, whose import
starts a Python child process to probe GLFW's version; a Ctrl-C while that child starts makes it print
Python's fatal start-up error under the command's one line. With `MUJOCO_GL` set to the backend the
renderer would pick anyway, MuJoCo never loads GLFW.
"""

from __future__ import annotations

import ctypes.util
import os

INSTALL_HINT = (
    "install Mesa's EGL (Debian/Ubuntu: apt-get install libegl1 libgl1-mesa-dri) for MUJOCO_GL=egl, "
    "or OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=osmesa"
)


class RenderUnavailableError(RuntimeError):
    """No headless OpenGL backend could be started; the message says what to install."""


def choose() -> str:
    """'egl' or 'osmesa', or RenderUnavailableError saying what to install."""
    env = os.environ.get("MUJOCO_GL", "").strip().lower()
    if env == "osmesa" and not ctypes.util.find_library("OSMesa"):
        raise RenderUnavailableError(
            "MUJOCO_GL=osmesa but libOSMesa is not installed (apt-get install libosmesa6); or unset MUJOCO_GL to use EGL"
        )
    if env == "egl" and not ctypes.util.find_library("EGL"):
        raise RenderUnavailableError(f"MUJOCO_GL=egl but libEGL is not installed; {INSTALL_HINT}")
    if env in ("egl", "osmesa"):
        return env
    if ctypes.util.find_library("EGL"):
        return "egl"
    if ctypes.util.find_library("OSMesa"):
        return "osmesa"
    raise RenderUnavailableError(f"no headless OpenGL library found (neither libEGL nor libOSMesa); {INSTALL_HINT}")


def pin() -> None:
    """Export the chosen backend as `MUJOCO_GL` when the user left it unset (a command calls this
    before importing MuJoCo). Without a GL library nothing is set: the renderer says what to
    install when it is first needed, and a command that never renders does not care."""
    if os.environ.get("MUJOCO_GL", "").strip():
        return
    try:
        os.environ["MUJOCO_GL"] = choose()
    except RenderUnavailableError:
        pass
