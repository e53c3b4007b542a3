"""The reference stage: cached per scene and lighting, the same cameras and points for every probe config.

Small on purpose: two-rooms with tiny probe grids, a few hundred surface points at a few paths each, no previews
(test_evaluate covers them).
"""
from __future__ import annotations

import numpy as np

from proto.models import BakeConfig
from proto.stages import STAGE_BY_NAME, plan
from persist.store import Store
from workers import pipeline
from workers.gltf import ingest_file

EV = {"enabled": True, "cameras": 2, "surface_points": 96, "spp": 4, "previews": 0,
      "points": {"points": [[2.0, 1.2, 2.0], [6.0, 1.2, 2.0]], "regions": {"room-a": [0], "room-b": [1]}}}
SMALL = {"trace": {"rays_per_probe": 32, "relocate_iterations": 1}, "light": {"bounces": 1},
         "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"clusters": 2, "sweeps": 20},
         "evaluate": EV}


def _config(counts, **extra) -> BakeConfig:
    return BakeConfig.model_validate({**SMALL, "place": {"counts": counts}, **extra})


def test_reference_key_ignores_the_probe_config():
    st = STAGE_BY_NAME["reference"]
    assert st.inputs == ("ingest",) and not any(s.split(".")[0] in ("place", "trace", "light") for s in st.sections)
    keys = lambda c: {s.name: k for s, k in plan("scene", c)}  # noqa: E731
    a = keys(_config([3, 2, 2]))
    b = keys(_config([4, 3, 3], light={"bounces": 3}, masks={"clusters": 4}, trace={"rays_per_probe": 64}))
    assert a["reference"] == b["reference"] and a["evaluate"] != b["evaluate"]
    c = keys(BakeConfig.model_validate({**SMALL, "place": {"counts": [3, 2, 2]},
                                        "evaluate": {**EV, "repeats": 2, "flip": False}}))
    assert c["reference"] == a["reference"]                      # preview timing settings: not the reference's
    d = keys(BakeConfig.model_validate({**SMALL, "place": {"counts": [3, 2, 2]}, "evaluate": {**EV, "spp": 8}}))
    e = keys(_config([3, 2, 2], scene={"sky": [0.1, 0.1, 0.1]}))
    assert d["reference"] != a["reference"] and e["reference"] != a["reference"]   # settings and lighting: it is


def test_second_bake_reuses_the_reference_same_cameras_points_and_direct_metrics(tmp_path, scene_files):
    store = Store(tmp_path / "store")
    scene = ingest_file(scene_files["two-rooms"])
    m1 = pipeline.bake_local(store, scene, _config([3, 2, 2]))
    m2 = pipeline.bake_local(store, scene, _config([4, 2, 3]))
    s1 = {s.name: s for s in m1.stages}
    s2 = {s.name: s for s in m2.stages}
    assert not s1["reference"].cached and s2["reference"].cached          # the record says so
    assert s1["reference"].cache_key == s2["reference"].cache_key
    assert not s2["evaluate"].cached and not s2["place"].cached
    assert m1.grid["counts"] != m2.grid["counts"]
    e1, e2 = s1["evaluate"].stats, s2["evaluate"].stats
    cams = e1["cameras"]
    assert len(cams) == 2 and cams == e2["cameras"]                        # identical poses, recorded
    assert {"position", "target", "fov"} <= set(cams[0]) and e1["camera_source"] == "auto"
    assert e1["points"] == e2["points"] > 0 and e1["check_points"] == 2
    # the same points: the direct mode (no probes) scores identically
    d1 = {k: v for k, v in e1["metrics"].items() if k.startswith("direct.")}
    d2 = {k: v for k, v in e2["metrics"].items() if k.startswith("direct.")}
    assert d1 and d1 == d2
    m = e1["metrics"]
    for mode in e1["modes"]:
        for k in ("rmse", "leak", "indirect_relative_rmse", "mean_ratio"):
            assert f"{mode}.{k}" in m and m[f"{mode}.{k}_stderr"] >= 0, (mode, k)
        assert f"{mode}.region.room-a.mean_ratio" in m
    assert m["reference.mean_indirect"] > 0
    # the reference's own record: its points and cameras, no probe stage read
    rec = store.get_stage(s1["reference"].cache_key)
    assert rec["stats"]["surface_points"] == e1["points"] and rec["stats"]["cameras"] == cams
    assert all(a["meta"].get("internal") for a in rec["artifacts"])
    names = {a.name for a in m1.artifacts}
    assert {"check_points", "eval_metrics", "eval_cameras"} <= names and not any(n.startswith("reference_") for n in names)


def test_points_and_cameras_are_deterministic(scene_files):
    from workers.kernels.surface_points import area_points, camera_points
    from workers.raycast import caster_for_scene
    from workers.render.cameras import auto_cameras

    scene = ingest_file(scene_files["two-rooms"])
    caster = caster_for_scene(scene)
    a, b = area_points(scene, 64, seed=3, caster=caster), area_points(scene, 64, seed=3, caster=caster)
    assert len(a["position"]) == 64 and np.array_equal(a["position"], b["position"])
    assert np.allclose(np.linalg.norm(a["normal"], axis=1), 1, atol=1e-5)
    cams = auto_cameras(caster, scene.bounds, 2)
    c = camera_points(scene, cams, 50, seed=0, caster=caster)
    assert 0 < len(c["position"]) <= 50
    # normals face the camera that sees the point
    to_cam = np.asarray([cams[i].position for i in c["camera"]]) - c["position"]
    assert (np.einsum("ij,ij->i", c["normal"], to_cam) > 0).mean() > 0.95


def test_camera_points_fill_their_share_when_sky_fills_the_image(tmp_path):
    """A 10 m floor seen from above at a slant: most pixels are sky. The first pixel grid (1.5x the share) found 421
    of 2,048 points on such a scene (few_surface_points); denser grids fill the share, spread over what is seen."""
    from tests.gltf_build import GltfBuilder, quad
    from workers.kernels.surface_points import camera_points
    from workers.raycast import caster_for_scene
    from workers.render.cameras import Camera

    b = GltfBuilder()
    m = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0.0})
    p, n, uv, ix = quad([-5, 0, 5], [10, 0, 0], [0, 0, -10], [0, 1, 0])
    b.mesh(p, ix, normals=n, material=m)
    (tmp_path / "floor.glb").write_bytes(b.glb())
    scene = ingest_file(tmp_path / "floor.glb")
    caster = caster_for_scene(scene)
    cam = Camera(position=(0.0, 1.6, 9.0), target=(0.0, 1.2, 0.0), width=160, height=120)   # the horizon mid-image
    c = camera_points(scene, [cam], 400, seed=0, caster=caster)
    assert len(c["position"]) == 400
    assert np.allclose(c["position"][:, 1], 0.0, atol=1e-5)
    assert np.ptp(c["position"][:, 0]) > 5.0                                   # spread over the floor it sees
    d = camera_points(scene, [cam], 400, seed=0, caster=caster)
    assert np.array_equal(c["position"], d["position"])                        # deterministic


def test_reference_reports_progress_per_batch_of_points(scene_files):
    from workers.stages.base import LazyArtifacts, StageContext
    from workers.stages.reference import BATCH_POINTS, run_reference

    scene = ingest_file(scene_files["two-rooms"])
    lights = {"lights": [dict(l) for l in scene.lights], "sky": [0.0, 0.0, 0.0]}
    config = BakeConfig.model_validate({"evaluate": {**EV, "surface_points": 3 * BATCH_POINTS, "spp": 1,
                                                     "points": None}})
    seen = []
    out = run_reference(StageContext(config=config, scene_loader=lambda: scene, report=seen.append,
                                     inputs={"ingest": LazyArtifacts({}, {"lights": lambda: lights})}))
    assert out.stats["surface_points"] == 3 * BATCH_POINTS and out.stats["trace"]["batches"] == 3
    assert seen == sorted(seen) and seen[-1] == 1.0
    assert len([f for f in seen if 0.05 < f < 1.0]) >= 2          # between the batches, not only start and end


def test_check_points_get_their_own_low_noise_path_count(scene_files):
    """evaluate.check_spp (default max(spp, 8192)): the few check points a level designer reads get low-noise
    values, whatever the surface points' spp; the standard error shrinks as 1/sqrt(paths)."""
    from proto.models import CHECK_SPP_DEFAULT
    from workers.stages.base import LazyArtifacts, StageContext
    from workers.stages.reference import run_reference

    scene = ingest_file(scene_files["two-rooms"])
    lights = {"lights": [dict(l) for l in scene.lights], "sky": [0.0, 0.0, 0.0]}
    pts = {"points": [[2.0, 1.2, 2.0]], "normals": [[0.0, 1.0, 0.0]]}

    def run(**ev):
        config = BakeConfig.model_validate({"evaluate": {**EV, "surface_points": 8, "cameras": 0, "points": pts,
                                                         **ev}})
        assert config.evaluate.effective_check_spp() == ev.get("check_spp", CHECK_SPP_DEFAULT)
        out = run_reference(StageContext(config=config, scene_loader=lambda: scene, report=lambda f: None,
                                         inputs={"ingest": LazyArtifacts({}, {"lights": lambda: lights})}))
        doc = next(a.data for a in out.artifacts if a.name == "reference_check_points")
        return out.stats, float(np.mean(doc["reference_indirect"])), float(np.mean(doc["reference_stderr"]))

    s_hi, e_hi, err_hi = run()
    s_lo, e_lo, err_lo = run(check_spp=128)
    assert s_hi["check_spp"] == CHECK_SPP_DEFAULT and s_lo["check_spp"] == 128 and s_hi["spp"] == EV["spp"]
    assert e_hi > 0 and err_hi / e_hi < 0.02                       # a low-noise value in the lit room
    assert 4.0 < err_lo / err_hi < 12.0                             # sqrt(8192 / 128) = 8
    assert abs(e_lo - e_hi) < 5 * err_lo
