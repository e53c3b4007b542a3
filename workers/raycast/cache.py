"""One ray caster (one BVH) per scene per process, reused by every stage that casts rays.

:func:`caster_for_scene` is what stages call. It keys each caster by :func:`scene_key` — a sha256 of what
the caster reads from the scene (the triangles; with alpha cutouts also the materials, per-triangle
material indices, ``uv0``, COLOR_0 and textures that the alpha test reads) plus the caster's own options —
and keeps the last :data:`MAX_SCENES` of them. So the place, relocate, trace, visibility, light, PRT,
reference and evaluate stages of one bake, run in one process, build the scene's BVH once; two scene
objects with the same content (each stage loads its own copy) share it, and a changed triangle or cutout
gets a new one. Results are identical: a caster's answers depend only on the rays and that content.

Release: an evicted caster is only dropped from the cache; the stages still holding it keep it alive and
Python frees its Embree scene when the last one lets go. A forked child (an RQ work-horse) starts with an
empty cache and never releases what its parent built (:func:`_forget_after_fork`): Embree objects made
before a fork are not touched after it.

Lifetime under ``kiln worker``: RQ forks one work-horse per job and each stage is one job, so there the
cache lives for one stage; the saving is within a job and in single-process bakes (``bake_local``, the
CLI, the tests).
"""
from __future__ import annotations

import hashlib
import json
import os
import threading
from collections import OrderedDict

import numpy as np

from .cutout import build_caster

__all__ = ["MAX_SCENES", "caster_for_scene", "scene_key", "cached_keys", "clear"]

MAX_SCENES = 2
"""Casters (scenes × options) kept per process: a bake's scene, plus one (e.g. a relight) beside it."""

_lock = threading.Lock()
_casters: OrderedDict[tuple, object] = OrderedDict()
_inherited: list = []          # casters built by a parent process before fork: kept, never released here


def _update(h, a) -> None:
    a = np.ascontiguousarray(a)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a.reshape(-1)).cast("B"))


def scene_key(scene, **kwargs) -> tuple:
    """The cache key of ``scene``'s caster: (sha256 hex of its ray-relevant content, sorted options).

    Content: ``triangles`` (T, 3, 3) float32; when any triangle's material is a cutout (alphaMode MASK or
    BLEND, :func:`workers.kernels.materials.cutout_materials`) also ``material``, the materials (JSON),
    ``uv0``, ``colors`` and the textures, which :func:`workers.kernels.materials.opaque_at_hits` reads.
    ``kwargs`` are the caster options (``threads``, ``chunk_size``, ``robust``).
    """
    from workers.kernels.materials import cutout_materials

    h = hashlib.sha256()
    _update(h, np.asarray(scene.triangles, np.float32))
    mat = np.asarray(scene.material)
    cut = cutout_materials(scene)
    if cut.any() and mat.size and cut[mat].any():
        h.update(b"cutout")
        _update(h, mat)
        h.update(json.dumps(scene.materials, sort_keys=True, default=str).encode())
        _update(h, np.asarray(scene.uv0, np.float32))
        if getattr(scene, "colors", None) is not None:
            _update(h, np.asarray(scene.colors))
        for tex in scene.textures:
            _update(h, np.asarray(tex))
    return h.hexdigest(), tuple(sorted(kwargs.items()))


def caster_for_scene(scene, **kwargs):
    """The ray caster of a :class:`workers.scene.NormalizedScene` (:func:`workers.raycast.cutout.build_caster`:
    a plain :class:`EmbreeRayCaster` without cutouts, else a :class:`CutoutRayCaster`), built once per
    :func:`scene_key` and process (module doc). ``kwargs`` go to the caster (and into the key)."""
    key = scene_key(scene, **kwargs)
    with _lock:
        caster = _casters.get(key)
        if caster is not None:
            _casters.move_to_end(key)
            return caster
    caster = build_caster(scene, **kwargs)         # outside the lock: a long build blocks no other scene
    with _lock:
        caster = _casters.setdefault(key, caster)  # a racing build of the same key: the first one wins
        _casters.move_to_end(key)
        while len(_casters) > MAX_SCENES:
            _casters.popitem(last=False)           # dropped, not destroyed: holders keep it alive
    return caster


def cached_keys() -> list[tuple]:
    """The keys of the cached casters, least recently used first (for tests and diagnostics)."""
    with _lock:
        return list(_casters)


def clear() -> None:
    """Drop every cached caster (holders keep theirs)."""
    with _lock:
        _casters.clear()


def _forget_after_fork() -> None:
    global _lock
    _lock = threading.Lock()
    _inherited.extend(_casters.values())
    _casters.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)
