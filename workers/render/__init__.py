"""Rasterization for the evaluate stage (DESIGN stage 7): headless moderngl contexts (EGL),
cameras (given or auto-placed) and the G-buffer the GI modes and the path-traced reference shade.

- :mod:`.context` — :func:`create_context` (EGL, clear :class:`RenderUnavailable` errors), :func:`timed`.
- :mod:`.cameras` — :class:`Camera` (view/projection matrices, pixel rays), :func:`auto_cameras`.
- :mod:`.gbuffer` — :class:`GBufferRenderer`, :class:`GBuffer`, :func:`render_gbuffer`.

Importing this package does not import moderngl; creating a context does.
"""
from .cameras import Camera, auto_cameras, default_camera, fit_clip_planes
from .context import RenderUnavailable, create_context, timed

__all__ = ["Camera", "auto_cameras", "default_camera", "fit_clip_planes", "RenderUnavailable", "create_context",
           "timed", "GBuffer", "GBufferRenderer", "render_gbuffer"]


def __getattr__(name):  # lazy: the G-buffer module only when asked for
    if name in ("GBuffer", "GBufferRenderer", "render_gbuffer"):
        from . import gbuffer
        return getattr(gbuffer, name)
    raise AttributeError(name)
