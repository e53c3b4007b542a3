"""workers/relight.py: relighting a stored PRT bake into a bundle folder (what POST /v1/bakes/{id}/relight runs),
and the caller-owned RelightCache. The route through a real service: tests/server/test_relight.py."""
from __future__ import annotations

import numpy as np
import pytest

from persist.store import Store
from proto import bundle
from proto.models import ArtifactInfo, BakeConfig
from workers import pipeline, prt_relight
from workers.gltf import ingest_file
from workers.kernels.precision import half
from workers.raycast import caster_for_scene
from workers.relight import RelightCache, bake_grid, load_prt_model, write_relit_bundle

CONFIG = {"place": {"counts": [3, 3, 3]}, "trace": {"rays_per_probe": 32},
          "prt": {"enabled": True, "configurations": 16, "measurement_points": 32, "basis": 6, "lightmap": 32,
                  "scenario": {"types": ["point", "spot"], "box": {"min": [0.0, 0.1, 1.3], "max": [1.0, 0.9, 2.0]}}}}
LIGHTS = [{"type": "point", "position": [0.5, 0.5, 1.6], "intensity": 5.0, "color": [1.0, 0.8, 0.6]}]
RELIT = {"probe_sh", "sh_l1_r", "sh_l1_g", "sh_l1_b", "lightmap", "prt_direct", "relight"}


@pytest.fixture(scope="module")
def prt_bake(tmp_path_factory, scene_files):
    """A store holding the Cornell box's scene and the stages up to prt; the catalog-like bake and its infos."""
    store = Store(tmp_path_factory.mktemp("relight") / "store")
    scene = ingest_file(scene_files["cornell"])
    sid = store.put_bytes(scene.to_bytes())
    cfg = BakeConfig.model_validate(CONFIG)
    recs = {n: pipeline.execute_stage(store, sid, cfg, n)[0] for n in ("ingest", "place", "relocate", "trace",
                                                                        "light", "prt")}
    infos = {a["name"]: a for rec in recs.values() for a in rec["artifacts"]}
    bake = {"id": "b1", "scene_id": sid, "config": cfg.model_dump(mode="json"), "manifest": None,
            "stages": [{"name": n, "stats": rec["stats"]} for n, rec in recs.items()]}
    scene_summary = {"triangles": len(scene.triangles), "bounds": [[0, 0, 0], [1, 1, 1]], "lights": 0,
                     "materials": 1, "warnings": []}
    return store, scene, bake, scene_summary, infos


def test_relit_bundle_is_relight_of_the_stored_model(prt_bake, tmp_path):
    store, scene, bake, summary, infos = prt_bake
    m = write_relit_bundle(store, bake, summary, infos, LIGHTS, tmp_path / "relit")
    manifest, arrays = bundle.open_bundle(tmp_path / "relit")          # every file's size and sha256 checked
    assert manifest == m and {a.name for a in m.artifacts} == RELIT
    assert m.bake_id == "b1" and m.grid == bake_grid(bake) and m.grid["counts"] == [3, 3, 3]
    assert [s.name for s in m.stages] == ["relight"] and m.stages[0].stats["lights"] == 1
    prt = {n: bundle.load_artifact(store.blob_path(i["sha256"]), ArtifactInfo(**i)) for n, i in infos.items()
           if n.startswith("prt")}
    want = prt_relight.relight(prt, LIGHTS, caster_for_scene(scene))
    for name in RELIT - {"relight"}:      # sh_l1_* as the light stage stores them: RGBA16F (precision.half)
        np.testing.assert_array_equal(arrays[name], half(want[name])[0] if name.startswith("sh_l1") else want[name])
    assert all(a.format in ("ktx2", "json") for a in m.artifacts)        # no .npy: readable without numpy
    assert arrays["relight"]["lights"] == LIGHTS
    m2 = write_relit_bundle(store, bake, summary, infos, LIGHTS, tmp_path / "no-lm", lightmap=False)
    assert {a.name for a in m2.artifacts} == RELIT - {"lightmap"}


def test_a_cache_keeps_the_model_and_the_caster_and_gives_the_same_bundle(prt_bake, tmp_path):
    store, _, bake, summary, infos = prt_bake
    cache = RelightCache()
    one = write_relit_bundle(store, bake, summary, infos, LIGHTS, tmp_path / "a", cache=cache)
    assert len(cache) == 2                                             # one model, one caster
    built = []
    model = cache.get("model", next(iter(cache._lru["model"])), lambda: built.append("model"))
    caster = cache.get("caster", bake["scene_id"], lambda: built.append("caster"))
    assert built == [] and isinstance(model, prt_relight.PrtModel) and caster is not None
    two = write_relit_bundle(store, bake, summary, infos, LIGHTS, tmp_path / "b", cache=cache)
    assert len(cache) == 2
    for a, b in zip(one.artifacts, two.artifacts):
        if a.name != "relight":                                        # its timings differ
            assert (a.name, a.sha256) == (b.name, b.sha256)
    fresh = load_prt_model(store, infos)
    np.testing.assert_array_equal(fresh.sh.transfer, model.sh.transfer)


def test_relight_cache_is_a_bounded_lru_per_kind():
    cache = RelightCache(models=2, casters=1)
    made = []

    def make(v):
        return lambda: made.append(v) or v
    assert [cache.get("model", k, make(k)) for k in ("a", "b", "a", "c")] == ["a", "b", "a", "c"]
    assert made == ["a", "b", "c"]                                     # "a" came from the cache
    assert cache.get("model", "a", make("a2")) == "a"                  # "b" was the least recent: evicted
    assert cache.get("model", "b", make("b2")) == "b2"
    assert cache.get("caster", "s1", make("x")) == "x" and cache.get("caster", "s2", make("y")) == "y"
    assert cache.get("caster", "s1", make("x2")) == "x2" and len(cache) == 3


def test_bake_grid_from_the_manifest_or_the_place_stage():
    grid = {"counts": [2, 2, 2], "origin": [0, 0, 0], "spacing": [1, 1, 1]}
    assert bake_grid({"manifest": {"grid": grid}, "stages": []}) == grid
    assert bake_grid({"manifest": None, "stages": [{"name": "place", "stats": dict(grid, auto=None)}]}) == grid
    assert bake_grid({"manifest": None, "stages": [{"name": "place", "stats": {}}]}) == {}


def test_a_turned_bake_relights_world_lights_as_the_unturned_bake(tmp_path):
    """The Cornell box turned 30 deg in its file bakes in the frame of its walls (grid.frame): relighting it with
    world lights (the relight route's input) gives the unturned bake's relit probes for the unturned lights."""
    from tests.bench.bench_fidelity import rotated_glb, rotation_y
    from workers.procedural import make_scene

    R = rotation_y(30.0)
    out = {}
    for name, data, lights in (
            ("flat", make_scene("cornell"), LIGHTS),
            ("turned", rotated_glb(make_scene("cornell"), 30.0),
             [{**LIGHTS[0], "position": (R @ np.asarray(LIGHTS[0]["position"])).tolist()}])):
        p = tmp_path / f"{name}.glb"
        p.write_bytes(data)
        scene = ingest_file(p)
        store = Store(tmp_path / f"store-{name}")
        sid = store.put_bytes(scene.to_bytes())
        prt = {**CONFIG["prt"], "scenario": {"types": ["point", "spot"]}}        # the scene bounds: either frame
        # spacing 0.3 (probes 0.1 m outside the walls, then moved in): CONFIG's counts put probes exactly on the
        # walls, where the float rounding of the turned vertices decides their side
        cfg = BakeConfig.model_validate({**CONFIG, "place": {"spacing": 0.3}, "prt": prt})
        recs = {n: pipeline.execute_stage(store, sid, cfg, n)[0]
                for n in ("ingest", "place", "relocate", "trace", "light", "prt")}
        infos = {a["name"]: a for rec in recs.values() for a in rec["artifacts"]}
        bake = {"id": name, "scene_id": sid, "config": cfg.model_dump(mode="json"), "manifest": None,
                "stages": [{"name": n, "stats": rec["stats"]} for n, rec in recs.items()]}
        summary = {"triangles": len(scene.triangles), "bounds": [[0, 0, 0], [1, 1, 1]], "lights": 0, "materials": 1,
                   "warnings": []}
        write_relit_bundle(store, bake, summary, infos, lights, tmp_path / f"relit-{name}")
        out[name] = (bake_grid(bake), bundle.open_bundle(tmp_path / f"relit-{name}")[1])
    (g0, a0), (g30, a30) = out["flat"], out["turned"]
    assert g0["frame"]["yaw_deg"] == 0.0 and abs(g30["frame"]["yaw_deg"] - 30.0) < 1e-3
    sh0, sh30 = np.asarray(a0["probe_sh"]), np.asarray(a30["probe_sh"])
    assert np.abs(sh0).max() > 0
    np.testing.assert_allclose(sh30, sh0, atol=0.01 * np.abs(sh0).max())
