"""Bake warnings ("no silent failures"): build_manifest collects every stage's ``stats["warnings"]`` and the
scene's ingest warnings into the manifest's top-level ``warnings``; the API's view of them for running bakes
and for manifests stored before warnings existed."""
from __future__ import annotations

import json

from proto.bundle import read_manifest, write_manifest
from proto.models import BakeConfig, BakeWarning, Manifest
from proto.stages import build_manifest, collect_warnings, plan

SCENE_ID = "ab" * 32
SUMMARY = {"id": SCENE_ID, "triangles": 12, "bounds": [[0, 0, 0], [1, 1, 1]], "lights": 0, "materials": 1,
           "warnings": ["mesh 'floor' has no normals: flat normals were computed"]}
UNLIT = {"code": "unlit_scene", "message": "nothing lights the scene"}
SLAB = {"code": "not_converged", "message": "slab warning"}


class Records(dict):
    """Stage records by cache key in memory (a ``proto.stages.StageRecords``, as ``persist.store.Store`` is)."""

    def get_stage(self, cache_key: str) -> dict | None:
        return self.get(cache_key)


def records_with(config: BakeConfig, stats_by_stage: dict[str, dict], seconds: float = 0.1,
                 artifacts_by_stage: dict[str, list] | None = None) -> Records:
    """A record for every planned stage of ``config`` (scene ``SCENE_ID``, no namespace), with the given stats."""
    records = Records()
    for st, key in plan(SCENE_ID, config):
        stats = dict(stats_by_stage.get(st.name, {}))
        if st.name == "place":
            stats.update(counts=[2, 2, 2], origin=[0, 0, 0], spacing=[1, 1, 1])
        records[key] = {"stage": st.name, "cache_key": key, "seconds": seconds, "stats": stats,
                        "artifacts": (artifacts_by_stage or {}).get(st.name, [])}
    return records


def test_build_manifest_collects_stage_and_scene_warnings(tmp_path):
    config = BakeConfig.model_validate({"visibility": {"slabs": 2}})
    stats = {
        "ingest": {"warnings": [UNLIT]},
        "light": {"warnings": [{"code": "not_converged", "message": "64 bounces, still changing 2%"}]},
        # the same warning from both shards and from the join: kept once, tagged with the stage's name
        "visibility.0": {"warnings": [SLAB]},
        "visibility.1": {"warnings": [SLAB]},
        "visibility": {"warnings": [SLAB]},
        # malformed entries still surface (never crash the bake, never vanish)
        "masks": {"warnings": ["a plain string"]},
        "anneal": {"warnings": []},
    }
    m = build_manifest(records_with(config, stats), SUMMARY, config, bake_id="b1")
    got = [(w.code, w.message, w.stage) for w in m.warnings]
    assert got == [
        ("scene", SUMMARY["warnings"][0], None),            # the scene's ingest warnings first
        ("unlit_scene", "nothing lights the scene", "ingest"),  # then stage order
        ("not_converged", "64 bounces, still changing 2%", "light"),
        ("not_converged", "slab warning", "visibility"),
        ("warning", "a plain string", "masks"),
    ]
    # the stage stats keep their own copy too
    assert next(s for s in m.stages if s.name == "ingest").stats["warnings"] == [UNLIT]

    # the manifest (and so the bundle) carries them at the top level and reads them back
    data = m.model_dump(mode="json")
    assert data["warnings"][1] == {"code": "unlit_scene", "message": "nothing lights the scene", "stage": "ingest"}
    write_manifest(tmp_path / "bundle", m)
    assert read_manifest(tmp_path / "bundle").warnings == m.warnings


def test_no_warnings_is_an_empty_list_and_old_manifests_read():
    config = BakeConfig()
    m = build_manifest(records_with(config, {}), {**SUMMARY, "warnings": []}, config)
    assert m.warnings == [] and m.model_dump(mode="json")["warnings"] == []
    old = m.model_dump(mode="json")
    del old["warnings"]  # a bundle written before warnings existed
    assert Manifest.model_validate(old).warnings == []


def test_collect_warnings_dedupes_per_stage_only():
    same = {"code": "albedo_high", "message": "material 'white' has albedo 0.98"}
    ws = collect_warnings([("ingest", {"warnings": [same, same]}), ("light", {"warnings": [same]}),
                           ("place", None), ("trace", {"warnings": {"code": "x", "message": "one dict"}})],
                          ["dup", "dup"])
    assert ws == [BakeWarning(code="scene", message="dup", stage=None),
                  BakeWarning(code="albedo_high", message=same["message"], stage="ingest"),
                  BakeWarning(code="albedo_high", message=same["message"], stage="light"),
                  BakeWarning(code="x", message="one dict", stage="trace")]


def test_api_warnings_of_running_and_old_bakes():
    from server.api.routes.bakes import bake_warnings, public

    stages = [{"name": "ingest", "status": "succeeded", "stats": {"warnings": [UNLIT]}},
              {"name": "place", "status": "running", "stats": {"warnings": [{"code": "later", "message": "?"}]}}]
    running = {"id": "b", "scene_id": SCENE_ID, "status": "running", "config": {}, "created": 1.0, "started": 1.0,
               "finished": None, "error": None, "manifest": None,
               "stages": [dict(s, progress=1.0, seconds=0.1, cached=False) for s in stages]}
    # while running: the scene's warnings and those of the stages done so far
    out = public(running, scene_warnings=["w"])
    assert out["warnings"] == [{"code": "scene", "message": "w", "stage": None},
                               {"code": "unlit_scene", "message": UNLIT["message"], "stage": "ingest"}]
    assert out["warning_count"] == 2
    json.dumps(out, allow_nan=False)
    # a manifest stored before manifests had warnings: recomputed from its stages and scene
    old = dict(running, status="succeeded", manifest={"scene": {"warnings": []},
                                                      "stages": [{"name": "ingest", "stats": {"warnings": [UNLIT]}}]})
    assert [w["code"] for w in bake_warnings(old)] == ["unlit_scene"]
    new = dict(old, manifest={"warnings": [{"code": "c", "message": "m", "stage": "light"}]})
    assert bake_warnings(new) == [{"code": "c", "message": "m", "stage": "light"}]
