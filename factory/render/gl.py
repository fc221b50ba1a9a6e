"""Headless OpenGL for MuJoCo's renderer: pick a backend; a `Context` that frees what lives in it.

The backend is `factory.gl_backend.choose()`'s (MUJOCO_GL, else EGL, else OSMesa). `configure()`
sets `MUJOCO_GL` and `PYOPENGL_PLATFORM` so that a later `import mujoco` picks the same backend; it
runs when `factory.render` is imported.

EGL on this project's CPU machine works with the stock environment (`MUJOCO_GL=egl`); the `EGLError`
seen in quick tries comes from MuJoCo's `Renderer.__del__` at interpreter exit, after `eglTerminate`.
Here every context is freed explicitly by an exit hook registered after the EGL display exists, so it
runs before MuJoCo's own `eglTerminate` hook.
"""

from __future__ import annotations

import atexit
import os
import sys
import weakref

from factory import gl_backend, gpus

_INSTALL_HINT = gl_backend.INSTALL_HINT
RenderUnavailableError = gl_backend.RenderUnavailableError
_choose_backend = gl_backend.choose


BACKEND: str | None = None


def configure() -> str:
    """Choose the backend and export it to the environment (before mujoco's GL modules load)."""
    global BACKEND
    if BACKEND is None:
        BACKEND = _choose_backend()
        if "mujoco" not in sys.modules:
            os.environ["MUJOCO_GL"] = BACKEND
        platform = os.environ.get("PYOPENGL_PLATFORM")
        if platform and platform.lower() != BACKEND and "OpenGL" not in sys.modules:
            raise RenderUnavailableError(
                f"PYOPENGL_PLATFORM={platform} conflicts with the {BACKEND} backend; unset it or set it to {BACKEND}"
            )
        if not platform and "OpenGL" not in sys.modules:
            os.environ["PYOPENGL_PLATFORM"] = BACKEND
    return BACKEND


class Context:
    """A GL context, made current, with the MuJoCo render contexts living in it (a
    `factory.render.renderer.Renderer` owns one; a process may hold several)."""

    def __init__(self):
        backend = configure()
        chosen = gpus.choose_egl_device() if backend == "egl" else None  # this worker's share of the GPUs
        try:
            if backend == "egl":
                from mujoco.egl import GLContext  # lazy: the chosen backend's only (it loads libEGL)
            else:
                from mujoco.osmesa import GLContext  # lazy: the chosen backend's only (it loads libOSMesa)
            try:
                self._gl = GLContext(64, 64)
            except Exception:
                if chosen is None:
                    raise
                # EGL lists fewer devices than the driver has GPUs: the default device, not a failed build
                del os.environ["MUJOCO_EGL_DEVICE_ID"]
                self._gl = GLContext(64, 64)
            self._gl.make_current()
        except Exception as exc:
            raise RenderUnavailableError(
                f"cannot start a headless OpenGL context with {backend} ({type(exc).__name__}: {exc}); {_INSTALL_HINT}"
            ) from exc
        self.backend = backend
        self._owners: weakref.WeakSet = weakref.WeakSet()
        # Registered after the backend's own hooks (EGL registers eglTerminate on first use), so it
        # runs before them: free everything while the display is still alive.
        atexit.register(self._close_at_exit)

    @property
    def alive(self) -> bool:
        return self._gl is not None

    def make_current(self) -> None:
        self._gl.make_current()

    def adopt(self, owner) -> None:
        """Track an object with a `free()` method that holds GL resources (freed before the context)."""
        self._owners.add(owner)

    def _close_at_exit(self) -> None:
        """`close` as the process ends: a render cut short (Ctrl-C in the middle of a GL call) can
        leave the context unable to be made current, and the process frees it anyway, so a
        failure here is not printed (it was a traceback after the interrupted build's one line)."""
        try:
            self.close()
        except Exception:  # noqa: BLE001 - the process is ending; the driver frees what is left
            self._gl = None

    def close(self) -> None:
        """Free the adopted owners, then the context (idempotent)."""
        if self._gl is None:
            return
        atexit.unregister(self._close_at_exit)
        try:
            self._gl.make_current()
            for owner in list(self._owners):
                owner.free()
        finally:
            self._gl.free()
            self._gl = None
