"""Bake presets (proto/presets.json): one file for the web form and ``kiln bake --preset``. Every preset is a
partial config the schema and the models accept; medium is the defaults; the estimates order preview < medium <
production and production fits the server's default budget; the CLI applies a preset under ``--config``."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from proto import cost
from proto.models import BakeConfig
from server.cli import load_presets
from tests.server.test_cli import kiln

ROOT = Path(__file__).resolve().parents[2]
PRESETS = json.loads((ROOT / "proto" / "presets.json").read_text())["presets"]
TWO_ROOMS = {"triangles": 352, "bounds": [[-0.05, -0.05, -0.05], [8.1, 3.05, 4.05]]}   # the procedural two-rooms


def test_the_presets_file():
    assert [p["id"] for p in PRESETS] == ["preview", "medium", "production"]
    assert list(load_presets()) == ["preview", "medium", "production"]   # what the CLI reads: the same file
    for p in PRESETS:
        assert set(p) == {"id", "label", "description", "config"} and p["label"] and p["description"]
        assert "scene" not in p["config"] and "seed" not in p["config"], "a preset leaves the scene's lighting alone"


@pytest.mark.parametrize("preset", PRESETS, ids=lambda p: p["id"])
def test_every_preset_validates_against_the_schema(preset):
    jsonschema_rs = pytest.importorskip("jsonschema_rs")
    schema = json.loads((ROOT / "proto" / "schema" / "bake-config.schema.json").read_text())
    validator = jsonschema_rs.validator_for(schema)
    errors = [e.message for e in validator.iter_errors(preset["config"])]
    assert not errors, errors
    BakeConfig.model_validate(preset["config"])   # and the models (strict: unknown fields refused)


def test_the_schema_validator_refuses_a_bad_preset():
    """The check above can fail: a typo and an out-of-range value are caught."""
    jsonschema_rs = pytest.importorskip("jsonschema_rs")
    schema = json.loads((ROOT / "proto" / "schema" / "bake-config.schema.json").read_text())
    validator = jsonschema_rs.validator_for(schema)
    assert not validator.is_valid({"place": {"budjet": 2000}})
    assert not validator.is_valid({"trace": {"rays_per_probe": 8}})


def test_medium_is_the_defaults_and_the_estimates_are_ordered():
    by_id = {p["id"]: BakeConfig.model_validate(p["config"]) for p in PRESETS}
    assert by_id["medium"] == BakeConfig()
    est = {k: cost.estimate(TWO_ROOMS, c) for k, c in by_id.items()}
    assert est["preview"].probes < est["medium"].probes < est["production"].probes
    for key in ("seconds", "peak_memory_bytes", "artifact_bytes"):
        assert getattr(est["preview"], key) < getattr(est["medium"], key) < getattr(est["production"], key), key
    assert est["preview"].seconds < 30, "preview is meant to take seconds"
    assert by_id["production"].trace.rays_per_probe > by_id["medium"].trace.rays_per_probe
    assert not by_id["preview"].evaluate.enabled and by_id["production"].evaluate.enabled
    # production is not refused by a server with the default limits (KILN_MAX_BAKE_*)
    from server.api.routes.bakes import budget_of
    from server.config import Settings

    assert cost.over_budget(est["production"], budget_of(Settings())) == []


def test_cli_bake_with_a_preset_and_a_config_on_top(tmp_path, scene_files):
    cfg = tmp_path / "bake.toml"
    cfg.write_text("[trace]\nrays_per_probe = 32\n[masks]\nclusters = 2\n")
    r = kiln("bake", scene_files["two-rooms"], "--preset", "preview", "--config", cfg, "--out", tmp_path / "out",
             "--json", "--quiet", "--cache", tmp_path / "cache", timeout=300)
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout)
    c = m["config"]
    assert c["trace"]["rays_per_probe"] == 32                  # --config wins
    assert c["trace"]["relocate_iterations"] == 2              # the preset's, in the same table
    assert c["masks"]["clusters"] == 2 and c["masks"]["sweeps"] == 200
    assert c["place"]["budget"] == 2000 and c["visibility"]["samples_per_cell"] == 4
    assert c["evaluate"]["enabled"] is False
    nx, ny, nz = m["grid"]["counts"]
    assert nx * ny * nz <= 2000 and m["grid"]["auto"]["budget"] == 2000
    ev = next(s for s in m["stages"] if s["name"] == "evaluate")
    assert not (ev.get("stats") or {}).get("metrics"), "preview does not evaluate"
    # the same preset without --config: its own ray count
    r = kiln("bake", scene_files["two-rooms"], "--preset", "preview", "--out", tmp_path / "out2", "--json", "--quiet",
             "--cache", tmp_path / "cache", timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["config"]["trace"]["rays_per_probe"] == 64


def test_cli_unknown_preset_is_a_usage_error(tmp_path, scene_files):
    r = kiln("bake", scene_files["two-rooms"], "--preset", "ultra", "--out", tmp_path / "out")
    assert r.returncode == 2 and "ultra" in r.stderr and "preview" in r.stderr
    assert not (tmp_path / "out").exists()
