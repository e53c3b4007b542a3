"""``POST /v1/bakes/{id}/relight`` through a real service (embedded Redis, RQ workers, the app).

Until the ``prt`` stage is registered in proto/stages.py the workers do not run it: the test then runs
the stage in this process on the service's store (as the pipeline would) and adds its artifacts to the
bake's manifest. Once registered, the bake carries them already and that step is skipped.
"""
from __future__ import annotations

import base64
import io
import json
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from proto import bundle
from proto.ktx2 import decode_ktx2
from proto.models import ArtifactInfo, BakeConfig, LightConfig
from proto.stages import plan
from workers import pipeline, prt_relight
from workers.raycast import RayCaster
from workers.scene import NormalizedScene
from workers.stages.base import StageContext

KEYS = "teama:key-aaaaaaaa,teamb:key-bbbbbbbb"
A = {"Authorization": "Bearer key-aaaaaaaa"}
B = {"Authorization": "Bearer key-bbbbbbbb"}
PRT = {"enabled": True, "configurations": 16, "measurement_points": 32, "basis": 8, "lightmap": 32,
       "scenario": {"types": ["point", "spot"], "box": {"min": [0.0, 0.1, 1.3], "max": [1.0, 0.9, 2.0]}}}
CONFIG = {"place": {"counts": [3, 3, 3]}, "trace": {"rays_per_probe": 32},
          "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 10}, "prt": PRT,
          "evaluate": {"enabled": False}}   # relighting reads the prt stage's artifacts, not the evaluation
LIGHTS = [{"type": "point", "position": [0.5, 0.5, 1.6], "intensity": 5.0, "color": [1.0, 0.8, 0.6]},
          {"type": "spot", "position": [0.2, 0.7, 1.5], "direction": [0.3, -0.4, -1.0], "intensity": 3.0}]


def _ensure_prt(app, bake: dict) -> None:
    """Run the prt stage in this process and add its artifacts to the bake, unless the workers did."""
    store, catalog = app.state.store, app.state.catalog
    if any(a["name"] == "prt" for a in bake["manifest"]["artifacts"]):
        return
    cfg = BakeConfig.model_validate(bake["config"])
    keys = {st.name: key for st, key in plan(bake["scene_id"], cfg)}
    inputs = {n: pipeline._lazy(store, store.get_stage(keys[n])) for n in ("ingest", "place", "relocate", "trace",
                                                                            "light")}
    from workers.stages.prt import run_prt

    scene = NormalizedScene.from_bytes(store.read_bytes(bake["scene_id"]))
    out = run_prt(StageContext(cfg, lambda: scene, inputs, lambda f: None))
    infos = []
    with tempfile.TemporaryDirectory(dir=store.root / "tmp") as tmp:
        for art in out.artifacts:
            info = art.write(tmp, "prt")
            store.put_file(Path(tmp) / info.file, move=True)
            infos.append(info.model_dump())
    manifest = dict(bake["manifest"], artifacts=bake["manifest"]["artifacts"] + infos)
    assert catalog.set_bake_status(bake["id"], "succeeded", only_from=("succeeded",), manifest=manifest)


def _expected(app, bake_id: str, lights: list[dict]) -> dict:
    """relight() in this process on the bake's stored artifacts."""
    store, catalog = app.state.store, app.state.catalog
    bake = catalog.get_bake(bake_id)
    arrays = {a["name"]: bundle.load_artifact(store.blob_path(a["sha256"]), ArtifactInfo(**a))
              for a in bake["manifest"]["artifacts"] if a["name"].startswith("prt")}
    scene = NormalizedScene.from_bytes(store.read_bytes(bake["scene_id"]))
    return prt_relight.relight(arrays, [LightConfig(**light).model_dump(mode="json") for light in lights],
                               RayCaster(scene.triangles))


def test_relight_api(service, scene_files, tmp_path):
    from server.api.routes import relight as relight_routes

    service.start_workers()
    client = service.start_app(api_keys=KEYS)
    if not any(getattr(r, "path", "") == "/v1/bakes/{bake_id}/relight" for r in client.app.routes):
        client.app.include_router(relight_routes.router)
    r = service.upload(scene_files["cornell"], headers=A)
    assert r.status_code in (200, 201), r.text
    scene_id = r.json()["id"]
    r = client.post("/v1/bakes", json={"scene_id": scene_id, "config": CONFIG}, headers=A)
    assert r.status_code == 202, r.text
    bake_id = r.json()["id"]
    assert service.wait_bake(bake_id, timeout=240, headers=A)["status"] == "succeeded"
    app = client.app
    _ensure_prt(app, app.state.catalog.get_bake(bake_id))

    # zip: a bundle with the light stage's artifact names, equal to relight() in process
    r = client.post(f"/v1/bakes/{bake_id}/relight", json={"lights": LIGHTS}, headers=A)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip"
    (tmp_path / "relit.zip").write_bytes(r.content)
    manifest, arrays = bundle.open_bundle(tmp_path / "relit.zip")
    assert {a.name for a in manifest.artifacts} == {"probe_sh", "sh_l1_r", "sh_l1_g", "sh_l1_b", "lightmap",
                                                     "prt_direct", "relight"}
    assert manifest.bake_id == bake_id and manifest.grid["counts"] == [3, 3, 3]
    assert manifest.stages[0].name == "relight" and manifest.stages[0].stats["lights"] == 2
    assert manifest.artifact("sh_l1_r").format == "ktx2" and manifest.artifact("lightmap").shape == [32, 32, 4]
    want = _expected(app, bake_id, LIGHTS)
    for name in ("probe_sh", "sh_l1_r", "sh_l1_g", "sh_l1_b", "lightmap", "prt_direct"):
        assert arrays[name].shape == want[name].shape
        half = name.startswith("sh_l1")          # RGBA16F, as the light stage's (workers.kernels.precision.half)
        assert arrays[name].dtype == (np.float16 if half else np.float32), name
        assert np.allclose(arrays[name], want[name], rtol=1e-3 if half else 1e-5,
                           atol=1e-6 * max(np.abs(want[name]).max(), 1e-30))
    assert all(a.format in ("ktx2", "json") for a in manifest.artifacts)    # no .npy: readable without numpy
    assert np.abs(arrays["probe_sh"]).max() > 0
    assert arrays["relight"]["lights"][1]["type"] == "spot"

    # json: the same manifest and files, base64
    r = client.post(f"/v1/bakes/{bake_id}/relight?format=json", json={"lights": LIGHTS}, headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/json")
    body = r.json()
    assert body["format"] == "kiln-relight/1"
    with zipfile.ZipFile(io.BytesIO((tmp_path / "relit.zip").read_bytes())) as z:
        for a in manifest.artifacts:
            if a.name != "relight":          # its timings differ between the two calls
                assert base64.b64decode(body["files"][a.file]) == z.read(a.file)
    assert body["manifest"]["bake_id"] == bake_id

    # linearity through the API; no lightmap when not asked for
    double = [dict(light, intensity=2 * light["intensity"]) for light in LIGHTS[:1]]
    r1 = client.post(f"/v1/bakes/{bake_id}/relight?format=json", json={"lights": LIGHTS[:1], "lightmap": False},
                     headers=A).json()
    r2 = client.post(f"/v1/bakes/{bake_id}/relight?format=json", json={"lights": double, "lightmap": False},
                     headers=A).json()
    assert "lightmap.ktx2" not in r1["files"]
    sh1 = decode_ktx2(base64.b64decode(r1["files"]["probe_sh.ktx2"]))[0]     # a float32 table (rows of probes)
    sh2 = decode_ktx2(base64.b64decode(r2["files"]["probe_sh.ktx2"]))[0]
    assert np.allclose(sh2, 2 * sh1, rtol=1e-5, atol=1e-6 * np.abs(sh1).max())

    # errors: another team's bake and unknown bakes are 404; bad lights are 422 naming the field
    r = client.post(f"/v1/bakes/{bake_id}/relight", json={"lights": LIGHTS}, headers=B)
    assert r.status_code == 404 and r.json()["error"]["code"] == "bake_not_found"
    r = client.post("/v1/bakes/nope/relight", json={"lights": LIGHTS}, headers=A)
    assert r.status_code == 404
    for bad, field in (([{"type": "point"}], "lights.0"),
                       ([LIGHTS[0], {"type": "point", "position": [0, 0, 0], "intensity": -1}], "lights.1.intensity"),
                       ([{"type": "spot", "position": [0, 0, 0], "direction": [0, 0, 1], "colour": [1, 1, 1]}],
                        "lights.0.colour"),
                       ([{"type": "area", "position": [0, 0, 0]}], "lights.0.type")):
        r = client.post(f"/v1/bakes/{bake_id}/relight", json={"lights": bad}, headers=A)
        assert r.status_code == 422, r.text
        assert field in r.json()["error"]["message"], r.json()
    r = client.post(f"/v1/bakes/{bake_id}/relight", json={}, headers=A)
    assert r.status_code == 422 and "lights" in r.json()["error"]["message"]

    # a bake without PRT: 409
    cfg = json.loads(json.dumps(CONFIG))
    cfg["prt"] = {"enabled": False}
    r = client.post("/v1/bakes", json={"scene_id": scene_id, "config": cfg}, headers=A)
    plain = r.json()["id"]
    assert service.wait_bake(plain, timeout=240, headers=A)["status"] == "succeeded"
    r = client.post(f"/v1/bakes/{plain}/relight", json={"lights": LIGHTS}, headers=A)
    assert r.status_code == 409 and r.json()["error"]["code"] == "no_prt"
    assert "prt.enabled = false" in r.json()["error"]["message"]
