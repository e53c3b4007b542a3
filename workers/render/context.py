"""Headless OpenGL contexts for the evaluate stage (moderngl on EGL; DESIGN stage 7).

:func:`create_context` returns a standalone ``moderngl.Context`` (OpenGL 3.3 core or newer) that
needs no display: EGL with any driver — on a machine without a GPU that is Mesa's llvmpipe
(software rasterizer), on a GPU machine the vendor's EGL. Failures become a
:class:`RenderUnavailable` that names what is missing (the Python package, the EGL library, a
driver), so a stage can refuse with a clear reason instead of a stack trace from glcontext.

GPU timer queries are unreliable on llvmpipe (they report near-zero or wall-unrelated values):
time passes with a wall clock around ``render(); ctx.finish()`` (:func:`timed`).

Consumers: workers/render/gbuffer.py, the evaluate stage (mode shaders).
"""
from __future__ import annotations

import ctypes.util
import time

__all__ = ["RenderUnavailable", "create_context", "renderer_info", "timed"]

MIN_GL_VERSION = 330  # GLSL 3.30 core: what the G-buffer shaders need


class RenderUnavailable(RuntimeError):
    """No headless OpenGL context can be made here; the message says what to install."""


def _egl_hint() -> str:
    if ctypes.util.find_library("EGL") is None:
        return ("libEGL is not installed (Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri "
                "for Mesa's software rasterizer llvmpipe)")
    return ("libEGL is present but no EGL driver gave a context (Debian/Ubuntu: apt-get install libegl-mesa0 "
            "libgl1-mesa-dri; in containers check that /usr/share/glvnd/egl_vendor.d lists a vendor)")


def create_context(backend: str = "egl", require: int = MIN_GL_VERSION):
    """A standalone (headless) moderngl context.

    Parameters
    ----------
    backend : str
        glcontext backend; ``"egl"`` (default, headless) — ``None`` lets moderngl pick the platform
        default (X11/GLX on Linux, which needs a display).
    require : int
        Minimum OpenGL version as moderngl's ``version_code`` (330 = 3.3 core).

    Returns
    -------
    moderngl.Context
        Release it with ``ctx.release()`` when done (contexts hold driver threads).

    Raises
    ------
    RenderUnavailable
        moderngl is not installed, EGL is missing or gives no context, or the context is too old.
    """
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise RenderUnavailable("the evaluate stage needs the 'moderngl' package: pip install moderngl") from exc
    kwargs = {"require": int(require)}
    if backend is not None:
        kwargs["backend"] = backend
    try:
        ctx = moderngl.create_standalone_context(**kwargs)
    except Exception as exc:  # glcontext raises plain Exceptions with terse messages
        hint = _egl_hint() if backend == "egl" else "no display or OpenGL driver"
        raise RenderUnavailable(f"cannot create a headless OpenGL {require // 100}.{require % 100 // 10} context "
                                f"(backend {backend!r}): {exc}; {hint}") from exc
    if ctx.version_code < require:  # pragma: no cover - drivers honour `require`
        found = ctx.version_code
        ctx.release()
        raise RenderUnavailable(f"OpenGL {found} is older than the required {require}")
    return ctx


def renderer_info(ctx) -> dict:
    """Vendor, renderer and version strings of a context (for metrics.json / bench reports)."""
    info = ctx.info
    return {"vendor": info.get("GL_VENDOR"), "renderer": info.get("GL_RENDERER"),
            "version": info.get("GL_VERSION"), "version_code": ctx.version_code}


def timed(ctx, fn, repeats: int = 1) -> tuple[object, float]:
    """Run ``fn()`` ``repeats`` times, each followed by ``ctx.finish()``; return (last result, mean seconds).

    Wall-clock timing: GPU timer queries are wrong on llvmpipe.
    """
    if repeats < 1:
        raise ValueError(f"timed: repeats must be >= 1, got {repeats}")
    ctx.finish()
    out = None
    t0 = time.perf_counter()
    for _ in range(repeats):
        out = fn()
        ctx.finish()
    return out, (time.perf_counter() - t0) / repeats
