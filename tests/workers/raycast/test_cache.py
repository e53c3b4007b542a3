"""One ray caster per scene and process (workers/raycast/cache.py): shared by stages, keyed by content, bounded."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from proto.models import BakeConfig
from proto.stages import plan
from persist.store import Store
from tests.kernels.test_pathtrace import closed_box
from tests.workers.test_materials import _screen_scene
from workers import pipeline
from workers.gltf import ingest_file
from workers.procedural import BAKE_BOXES
from workers.raycast import CutoutRayCaster, EmbreeRayCaster, cache, caster_for_scene


@pytest.fixture(autouse=True)
def _empty_cache():
    cache.clear()
    yield
    cache.clear()


def test_same_content_shares_one_caster():
    a, b = closed_box(0.5, 0.0), closed_box(0.5, 0.0)          # two objects, same triangles
    ca = caster_for_scene(a)
    assert isinstance(ca, EmbreeRayCaster)
    assert caster_for_scene(b) is ca and len(cache.cached_keys()) == 1
    assert caster_for_scene(a, threads=1) is not ca                 # caster options are part of the key
    assert cache.scene_key(a) == cache.scene_key(b) != cache.scene_key(closed_box(0.5, 0.0, size=2.0))


def test_materials_matter_only_through_cutouts(tmp_path):
    """Without cutouts the BVH reads triangles only (double-sided or albedo changes share it); with cutouts the
    alpha test's inputs are in the key."""
    a, b = closed_box(0.5, 0.0), closed_box(0.9, 1.0)
    b.materials[0]["double_sided"] = True
    assert caster_for_scene(b) is caster_for_scene(a)
    s = _screen_scene(tmp_path / "s")
    t = copy.deepcopy(s)
    c = caster_for_scene(s)
    assert isinstance(c, CutoutRayCaster) and caster_for_scene(t) is c
    t.materials[0]["alpha_cutoff"] = 0.9
    assert cache.scene_key(t) != cache.scene_key(s) and caster_for_scene(t) is not c


def test_bounded_and_evicted_casters_still_work():
    scenes = [closed_box(0.5, 0.0, size=1.0 + i) for i in range(cache.MAX_SCENES + 1)]
    casters = [caster_for_scene(s) for s in scenes]
    assert len(cache.cached_keys()) == cache.MAX_SCENES
    assert cache.scene_key(scenes[0]) not in cache.cached_keys()    # least recently used goes first
    h = casters[0].intersect(np.array([[0.5, 0.5, 0.5]], np.float32), np.array([[0, 1, 0]], np.float32))
    assert h.t[0] == pytest.approx(0.5)                             # the holder's caster is alive
    assert caster_for_scene(scenes[0]) is not casters[0]            # rebuilt once evicted


def test_a_forked_child_starts_empty():
    c = caster_for_scene(closed_box(0.5, 0.0))
    cache._forget_after_fork()
    assert cache.cached_keys() == [] and cache._inherited[-1] is c  # kept alive, never released by the child
    cache._inherited.clear()


def test_stages_of_a_bake_build_the_bvh_once_with_identical_results(tmp_path, scene_files, monkeypatch):
    """relocate, trace, light and the visibility slabs load their own copies of the scene; they get one caster,
    and the artifacts equal those of a run that rebuilds it for every stage."""
    builds = []
    real = cache.build_caster
    monkeypatch.setattr(cache, "build_caster", lambda scene, **k: builds.append(1) or real(scene, **k))
    lo, hi = BAKE_BOXES["two-rooms"]
    cfg = BakeConfig.model_validate({"place": {"counts": [5, 3, 3], "box": {"min": lo, "max": hi}},
                                     "trace": {"rays_per_probe": 32},
                                     "visibility": {"samples_per_cell": 2, "slabs": 2}})
    scene = ingest_file(scene_files["two-rooms"])
    runs = []
    for rebuild in (False, True):
        store = Store(tmp_path / f"store{rebuild}")
        sid = store.put_bytes(scene.to_bytes())
        cache.clear()
        builds.clear()
        out = {}
        for st, _ in plan(sid, cfg):
            if rebuild:
                cache.clear()
            rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
            out[st.name] = {a["name"]: a["sha256"] for a in rec["artifacts"]}
            if st.name == "visibility":
                break
        runs.append((len(builds), out))
    (once, shared), (every, rebuilt) = runs
    assert once == 1 and every == 5                                 # relocate, trace, light, 2 slabs
    assert shared == rebuilt
