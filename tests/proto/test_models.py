"""Bake config validation, section hashing, the exported schema, and the stage plan's cache keys."""
from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from proto.export_schema import SCHEMA_PATH, schema_text
from proto.models import BakeConfig
from proto.stages import plan


def test_defaults_are_documented_and_valid():
    c = BakeConfig()
    assert c.place.counts is None and c.place.spacing is None     # the grid is chosen from the scene
    assert c.visibility.samples_per_cell is None and c.place.budget > 0
    assert c.scene.sky == (0.0, 0.0, 0.0) and c.scene.use_scene_lights
    schema = BakeConfig.model_json_schema()
    place = schema["$defs"]["PlaceSection"]["properties"]
    assert "description" in place["counts"] and "description" in place["spacing"]


def test_spacing_alone_replaces_counts():
    c = BakeConfig.model_validate({"place": {"spacing": 0.5}})
    assert c.place.counts is None and c.place.spacing == 0.5
    with pytest.raises(ValidationError, match="at most one of counts or spacing"):
        BakeConfig.model_validate({"place": {"spacing": 0.5, "counts": [2, 2, 2]}})


@pytest.mark.parametrize("data, loc", [
    ({"plac": {}}, ("plac",)),
    ({"place": {"counts": [4, 4, 0]}}, ("place", "counts", 2)),
    ({"place": {"counts": [4, 4]}}, ("place", "counts")),
    ({"place": {"spacing": -1}}, ("place", "spacing")),
    ({"place": {"box": {"min": [0, 0, 0], "max": [1, 0, 1]}}}, ("place", "box")),
    ({"scene": {"sky": [0, float("nan"), 0]}}, ("scene", "sky")),
    ({"scene": {"lights": [{"type": "point"}]}}, ("scene", "lights", 0)),
    ({"scene": {"lights": [{"type": "directional", "direction": [0, 0, 0]}]}}, ("scene", "lights", 0)),
    ({"scene": {"lights": [{"type": "spot", "position": [0, 0, 0], "direction": [0, -1, 0],
                            "inner_cone_angle": 0.8, "outer_cone_angle": 0.5}]}}, ("scene", "lights", 0)),
    ({"scene": {"lights": [{"type": "area", "position": [0, 0, 0]}]}}, ("scene", "lights", 0, "type")),
    ({"seed": -1}, ("seed",)),
])
def test_bad_values_name_their_field(data, loc):
    with pytest.raises(ValidationError) as e:
        BakeConfig.model_validate(data)
    assert tuple(e.value.errors()[0]["loc"])[:len(loc)] == loc


def test_section_hash_changes_only_with_its_section():
    a = BakeConfig()
    b = BakeConfig.model_validate({"place": {"counts": [4, 4, 4]}})
    assert a.section_hash("scene") == b.section_hash("scene")
    assert a.section_hash("place") != b.section_hash("place")


def test_plan_keys_follow_inputs():
    a, b = BakeConfig(), BakeConfig.model_validate({"place": {"counts": [4, 4, 4]}})
    pa, pb = dict((s.name, k) for s, k in plan("s1", a)), dict((s.name, k) for s, k in plan("s1", b))
    assert pa["ingest"] == pb["ingest"] and pa["place"] != pb["place"]
    pc = dict((s.name, k) for s, k in plan("s2", a))
    assert pc["ingest"] != pa["ingest"] and pc["place"] != pa["place"]  # a new scene re-runs everything
    c = BakeConfig.model_validate({"scene": {"sky": [1, 1, 1]}})
    pd = dict((s.name, k) for s, k in plan("s1", c))
    assert pd["ingest"] != pa["ingest"] and pd["place"] != pa["place"]  # downstream of a change re-runs


def test_exported_schema_is_in_sync():
    assert SCHEMA_PATH.read_text() == schema_text(), "run: python -m proto.export_schema"
    assert json.loads(schema_text())["title"] == "BakeConfig"


def test_the_readme_config_example_states_the_defaults():
    """The README's bake config (TOML) is the reference a user reads: every value it sets uncommented is the default
    (it said evaluate.spp = 128 after the default became 192), except the lights and sky it adds as an example."""
    import re
    import tomllib
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block, "README.md has no ```toml bake config"
    doc = tomllib.loads(block.group(1))
    defaults = BakeConfig().model_dump()
    examples = {("scene", "sky"), ("scene", "lights")}
    checked = 0
    for section, values in doc.items():
        if not isinstance(values, dict):
            assert defaults[section] == values, section
            continue
        for key, value in values.items():
            if (section, key) in examples:
                continue
            default = defaults[section][key]
            assert (list(default) if isinstance(default, tuple) else default) == value, f"{section}.{key}"
            checked += 1
    assert checked >= 20
