"""proto/stages.py: ``manifest_metrics`` and ``finalize_bake`` compute what finishing a bake records, and write
nothing (their callers, ``workers.jobs.finish_bake`` and ``POST /v1/bakes``, write the catalog)."""
from __future__ import annotations

import math

import pytest

from proto.models import BakeConfig, Manifest
from proto.stages import Finalized, finalize_bake, manifest_metrics, plan
from tests.proto.test_warnings import SCENE_ID, SUMMARY, records_with

ART = {"name": "probe_sh", "file": "probe_sh.npy", "format": "npy", "sha256": "cd" * 32, "bytes": 1234,
       "shape": [2, 2, 2, 9, 3], "dtype": "float32", "stage": "light"}
INTERNAL = dict(ART, name="hits", file="hits.npy", bytes=99, stage="trace", meta={"internal": True})


def _bake(config: BakeConfig) -> dict:
    stages = [{"name": st.name, "cached": st.name == "ingest"} for st, _ in plan(SCENE_ID, config)]
    return {"id": "b1", "team": None, "scene_id": SCENE_ID, "config": config.model_dump(mode="json"),
            "stages": stages}


def test_manifest_metrics_flattens_seconds_bytes_and_finite_evaluate_metrics():
    config = BakeConfig()
    stats = {"evaluate": {"metrics": {"ddgi.rmse": 0.25, "ddgi.flip": float("nan"), "ddgi.psnr": 31}}}
    fin = finalize_bake(_bake(config), SUMMARY, records_with(config, stats, seconds=0.5,
                                                             artifacts_by_stage={"light": [ART], "trace": [INTERNAL]}))
    m = fin.metrics
    assert m == manifest_metrics(Manifest.model_validate(fin.manifest))
    assert {k for k in m if k.startswith("stage_seconds.")} == {f"stage_seconds.{st.name}" for st, _ in
                                                                 plan(SCENE_ID, config)}
    assert all(m[f"stage_seconds.{st.name}"] == 0.5 for st, _ in plan(SCENE_ID, config))
    assert m["artifact_bytes"] == 1234                         # internal artifacts are not in the bundle
    assert m["ddgi.rmse"] == 0.25 and m["ddgi.psnr"] == 31 and "ddgi.flip" not in m   # NaN dropped
    assert all(not (isinstance(v, float) and math.isnan(v)) for v in m.values())


def test_finalize_bake_returns_the_manifest_and_writes_nothing():
    config = BakeConfig()
    records = records_with(config, {"ingest": {"warnings": [{"code": "unlit_scene", "message": "dark"}]}})
    before = {k: dict(v) for k, v in records.items()}
    bake = _bake(config)
    fin = finalize_bake(bake, dict(SUMMARY, created=1.0, filename="a.glb"), records)
    assert isinstance(fin, Finalized)
    assert records == before                                   # nothing written
    assert fin.manifest["bake_id"] == "b1" and fin.manifest["scene"]["id"] == SCENE_ID
    assert [s["name"] for s in fin.manifest["stages"]] == [st.name for st, _ in plan(SCENE_ID, config)]
    assert [s["cached"] for s in fin.manifest["stages"]] == [s["cached"] for s in bake["stages"]]
    assert fin.manifest["grid"] == {"counts": [2, 2, 2], "origin": [0, 0, 0], "spacing": [1, 1, 1]}
    assert [w["code"] for w in fin.manifest["warnings"]] == ["scene", "unlit_scene"]


def test_finalize_bake_refuses_a_missing_scene_or_stage():
    config = BakeConfig()
    with pytest.raises(RuntimeError, match="not in the catalog"):
        finalize_bake(_bake(config), None, records_with(config, {}))
    records = records_with(config, {})
    records.pop(plan(SCENE_ID, config)[-1][1])
    with pytest.raises(RuntimeError, match="not in the store"):
        finalize_bake(_bake(config), SUMMARY, records)
