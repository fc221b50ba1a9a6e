"""Renders for vision-language models: six orthographic views, isometric, part, catalog, feedback.

Every render takes a `Renderer` (a context manager owning the GL context, the compiled scenes and
the image caches): `with Renderer(reader) as r: render_step(r, before, new)`.

Importing this package chooses the headless OpenGL backend (`factory.render.gl`) before MuJoCo's GL
modules load. See docs/concepts/renders.md.
"""

from factory.render import gl as _gl

_gl.configure()  # before anything imports mujoco's GL modules

from factory.render.cameras import (
    ALL_VIEWS,
    ISOMETRIC,
    ORTHO_VIEWS,
    VIEWS,
    Framing,
    View,
    project,
)
from factory.render.gl import RenderUnavailableError
from factory.render.images import (
    StepRender,
    bounds_of,
    framing_for,
    render_axes,
    render_catalog,
    render_feedback,
    render_part,
    render_step,
    render_step_full,
    render_views,
    six_view_composite,
)
from factory.render.renderer import PartImages, Renderer

__all__ = [
    "ALL_VIEWS",
    "ISOMETRIC",
    "ORTHO_VIEWS",
    "VIEWS",
    "Framing",
    "PartImages",
    "RenderUnavailableError",
    "Renderer",
    "StepRender",
    "View",
    "bounds_of",
    "framing_for",
    "project",
    "render_axes",
    "render_catalog",
    "render_feedback",
    "render_part",
    "render_step",
    "render_step_full",
    "render_views",
    "six_view_composite",
]
