"""Relighting a stored PRT bake: what ``POST /v1/bakes/{id}/relight`` (server/api/routes/relight.py) runs.

:func:`write_relit_bundle` loads the bake's ``prt`` artifacts from the store, traces the shadow rays of the
direct vector against the bake's scene (Embree, :func:`workers.raycast.caster_for_scene`), reconstructs the
indirect of the given lights (:func:`workers.prt_relight.relight`, PRT eq 10 + §4.2) and writes it as a bundle
folder (proto/bundle.md): one stage, ``relight``, and these artifacts, the light stage's names and layouts
(proto/bundle.md §5.1) so that a viewer swaps them in for the baked ones (a *table*: a one-channel R32_SFLOAT
KTX2 2D texture of the array's rows, proto/bundle.md §3; KTX2 files Zstandard-supercompressed):

================ ================================== =====================================================
``probe_sh``     table (nz, ny, nx, K, 3) float32    radiance SH per probe (three.js order, K = 9 or 4)
``sh_l1_r/g/b``  ktx2 (nz, ny, nx, 4) RGBA16F        L0 + L1 of one colour channel per probe (as the light
                                                     stage: :func:`workers.kernels.precision.half`)
``lightmap``     ktx2 (R, R, 4) RGBA32F              indirect irradiance rgb, a = 1 on covered texels
                                                     (only when the bake has a lightmap and it is asked for)
``prt_direct``   table (M, 3) float32                the direct vector at the measurement points
``relight``      json                                the request's lights and timings (seconds)
================ ================================== =====================================================

Caching is the caller's: a :class:`RelightCache` (the API keeps one per app, ``server.api.deps.relight_cache``)
keeps unpacked PRT models and ray casters between calls, so that a repeated relight costs well under a
millisecond of math plus the encoding; with ``cache=None`` every call loads and builds afresh. This module keeps
no state of its own, and imports the numeric modules only when it relights (the API imports it at start).
"""
from __future__ import annotations

import hashlib
import json
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Callable

from proto import bundle
from proto.models import ArtifactInfo, Manifest, SceneSummary, StageInfo
from proto.stages import KILN_VERSION

__all__ = ["RelightCache", "bake_grid", "load_prt_model", "write_relit_bundle"]

MODEL_CACHE_SIZE = 8
"""Unpacked PRT models a :class:`RelightCache` keeps (a few MB each for a 16x32x16 grid)."""
CASTER_CACHE_SIZE = 4
"""Scenes whose ray caster (Embree BVH, ~65 ms to build for 58k triangles) a :class:`RelightCache` keeps."""


class RelightCache:
    """Two small LRUs, owned by whoever relights repeatedly: unpacked PRT models by the sha256 of their
    artifacts, ray casters by scene id. Thread-safe (the API relights from its thread pool); a value is built
    outside the lock, so two threads missing at once build it twice, harmlessly."""

    def __init__(self, models: int = MODEL_CACHE_SIZE, casters: int = CASTER_CACHE_SIZE):
        self._size = {"model": models, "caster": casters}
        self._lru: dict[str, OrderedDict] = {"model": OrderedDict(), "caster": OrderedDict()}
        self._lock = threading.Lock()

    def get(self, kind: str, key: str, make: Callable[[], object]):
        """The cached ``kind`` (``"model"`` or ``"caster"``) under ``key``, made by ``make()`` on a miss."""
        lru = self._lru[kind]
        with self._lock:
            if key in lru:
                lru.move_to_end(key)
                return lru[key]
        value = make()
        with self._lock:
            lru[key] = value
            lru.move_to_end(key)
            while len(lru) > self._size[kind]:
                lru.popitem(last=False)
            return lru[key]

    def __len__(self) -> int:
        with self._lock:
            return sum(len(lru) for lru in self._lru.values())


def load_prt_model(store, infos: dict[str, dict]):
    """The bake's :class:`workers.prt_relight.PrtModel` from its ``prt`` artifacts in ``store``.

    ``infos``: the bake's artifacts by name (``ArtifactInfo`` dicts); the ``prt`` section names the others
    (points, offsets, SH transfer and basis volumes, the lightmap's transfer, mask and basis textures).
    """
    from workers.prt_relight import PrtModel

    def load(name: str):
        return bundle.load_artifact(store.blob_path(infos[name]["sha256"]), ArtifactInfo(**infos[name]))

    section = load("prt")
    names = {section["points"], section["point_offsets"], section["sh"]["transfer"],
             *(n for group in section["sh"]["basis"] for n in group)}
    if section.get("lightmap"):
        lm = section["lightmap"]
        names |= {lm["transfer"], lm["mask"], *lm["basis"]}
    return PrtModel.from_arrays({"prt": section, **{n: load(n) for n in names}})


def _model_key(infos: dict[str, dict]) -> str:
    """The cache key of a bake's PRT model: sha256 of its ``prt*`` artifacts' sha256s, sorted."""
    return hashlib.sha256("".join(sorted(i["sha256"] for n, i in infos.items() if n.startswith("prt"))).encode()
                          ).hexdigest()


def bake_grid(bake: dict) -> dict:
    """The probe grid (``counts``, ``origin``, ``spacing``) of a catalog bake: its manifest's, or while it runs the
    ``place`` stage's stats; ``{}`` before place has finished."""
    if bake.get("manifest"):
        return bake["manifest"].get("grid", {})
    for s in bake["stages"]:
        if s["name"] == "place" and s.get("stats"):
            return {k: s["stats"][k] for k in ("counts", "origin", "spacing", "layers", "frame") if k in s["stats"]}
    return {}


def write_relit_bundle(store, bake: dict, scene: dict, infos: dict[str, dict], lights: list[dict],
                       folder: str | Path, *, lightmap: bool = True, cache: RelightCache | None = None
                       ) -> Manifest:
    """Relight ``bake`` for ``lights`` and write the result into the bundle folder ``folder``; returns its manifest.

    Parameters
    ----------
    store : persist.store.Store
        Where the bake's artifacts and its normalized scene (a blob named by the scene id) are.
    bake : dict
        The catalog's bake (``id``, ``scene_id``, ``config``, ``stages``, ``manifest``).
    scene : dict
        The catalog's scene summary (``triangles``, ``bounds``, ``lights``, ``materials``, ``warnings``; missing
        keys count as empty), for the manifest.
    infos : dict
        The bake's artifacts by name; must hold ``prt`` (the caller answers 409 otherwise).
    lights : list of dict
        ``LightConfig.model_dump(mode="json")`` each: KHR_lights_punctual units, world space, metres.
    lightmap : bool
        Also reconstruct the lightmap, when the bake has one.
    cache : RelightCache or None
        Keeps the unpacked model and the scene's ray caster between calls.
    """
    import numpy as np

    from workers.kernels.precision import half
    from workers.prt_relight import relight
    from workers.raycast import caster_for_scene
    from workers.scene import NormalizedScene

    from workers.kernels.frame import frame_of, rotate_lights, rotate_scene

    M = frame_of(bake_grid(bake))       # the bake frame (proto/bundle.md 5): the PRT points and basis live in it

    def make_caster():
        return caster_for_scene(rotate_scene(NormalizedScene.from_bytes(store.read_bytes(scene_id)), M))

    scene_id = bake["scene_id"]
    t0 = time.perf_counter()
    if cache is None:
        model, caster = load_prt_model(store, infos), make_caster()
    else:
        model = cache.get("model", _model_key(infos), lambda: load_prt_model(store, infos))
        caster = cache.get("caster", scene_id if M is None else f"{scene_id}:{bake_grid(bake)['frame']['yaw_deg']}",
                           make_caster)
    t1 = time.perf_counter()
    out = relight(model, rotate_lights(lights, M), caster, lightmap=lightmap)
    t2 = time.perf_counter()

    summary = SceneSummary(id=scene_id, triangles=scene.get("triangles", 0), bounds=scene.get("bounds", []),
                           lights=scene.get("lights", 0), materials=scene.get("materials", 0),
                           warnings=scene.get("warnings", []))
    info = {"bake_id": bake["id"], "lights": lights, "load_seconds": t1 - t0, "relight_seconds": t2 - t1,
            "direct_norm": [float(v) for v in (out["prt_direct"] ** 2).sum(axis=0) ** 0.5],
            "note": "indirect light of these lights only (no emission, scene lights or sky)"}
    folder = Path(folder)
    arts = [bundle.write_artifact(folder, "probe_sh", np.asarray(out["probe_sh"], np.float32), "relight",
                                  table=True, description="relit radiance SH per probe (three.js order), linear RGB")]
    for c in "rgb":
        data, vk, meta = half(out[f"sh_l1_{c}"])
        arts.append(bundle.write_artifact(folder, f"sh_l1_{c}", data, "relight", vk_format=vk, meta=meta,
                                          description=f"relit L0 + L1 radiance SH of the {c} channel per probe"))
    if "lightmap" in out:
        arts.append(bundle.write_artifact(folder, "lightmap", out["lightmap"], "relight",
                                          description="relit indirect irradiance, a = 1 on covered texels",
                                          meta={"uv": "prt_lm_uv"}))
    arts.append(bundle.write_artifact(folder, "prt_direct", np.asarray(out["prt_direct"], np.float32), "relight",
                                      table=True,
                                      description="direct vector at the measurement points"))
    arts.append(bundle.write_artifact(folder, "relight", info, "relight", format="json",
                                      description="the request's lights and timings"))
    key = hashlib.sha256(json.dumps(lights, sort_keys=True).encode()).hexdigest()
    manifest = Manifest(kiln_version=KILN_VERSION, bake_id=bake["id"], scene=summary,
                        config=bake.get("config") or {}, grid=bake_grid(bake),
                        stages=[StageInfo(name="relight", seconds=t2 - t1, cache_key=key,
                                          stats={"lights": len(lights), "direct_norm": info["direct_norm"]})],
                        artifacts=arts)
    bundle.write_manifest(folder, manifest)
    return manifest
