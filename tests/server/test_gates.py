"""``kiln bake --fail-on`` / ``--junit`` (server/gates.py): the grammar, and the CLI's exit code 7 with a failing
JUnit test case. The bake is tiny (explicit small probe grid, a few paths per point, no previews)."""
from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET

import pytest

from server.gates import GateError, check, junit_xml, parse_gate
from tests.server.test_cli import kiln

CONFIG = """
[place]
counts = [3, 2, 2]
[trace]
rays_per_probe = 32
relocate_iterations = 1
[light]
bounces = 1
[visibility]
samples_per_cell = 2
slabs = 1
[masks]
clusters = 2
sweeps = 10
[evaluate]
enabled = true
surface_points = 64
spp = 4
previews = 0
modes = ["direct", "leaking", "mask_normalized"]
[evaluate.points]
points = [[2.0, 1.2, 2.0], [6.0, 1.2, 2.0]]
normals = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
"""


def test_gate_grammar():
    g = parse_gate(" mask_normalized.leak>=5e-2 ")
    assert (g.metric, g.op, g.value) == ("mask_normalized.leak", ">=", 0.05)
    for bad in ("leak", "a.b > x", "a.b => 1", "a b > 1", "> 1", "a.b > 1 2", ""):
        with pytest.raises(GateError):
            parse_gate(bad)
    m = {"mask.leak": 0.1, "leaking.leak": 0.3, "mask.rmse": 0.02}
    gates = [parse_gate("mask.leak > 0.05"), parse_gate("*.leak > 0.2"), parse_gate("mask.rmse < 0.01"),
             parse_gate("ddgi.leak > 1")]
    failed = check(gates, m)
    assert [g.text for g in failed] == ["mask.leak > 0.05", "*.leak > 0.2", "ddgi.leak > 1"]
    assert gates[1].failing == {"leaking.leak": 0.3} and gates[1].matched == {"leaking.leak": 0.3, "mask.leak": 0.1}
    assert "no metric" in gates[3].describe()
    manifest = {"stages": [{"name": "evaluate", "seconds": 1.0, "stats": {"modes": ["mask", "leaking"], "metrics": m}}],
                "artifacts": []}
    root = ET.fromstring(junit_xml(gates, manifest, m))
    suites = {s.get("name"): s for s in root.iter("testsuite")}
    assert suites["kiln.gates"].get("tests") == "4" and suites["kiln.gates"].get("failures") == "3"
    cases = {c.get("name"): c for c in suites["kiln.modes"].iter("testcase")}
    assert set(cases) == {"mask", "leaking"}
    assert cases["mask"].find("failure") is not None and cases["leaking"].find("failure") is not None


def test_cli_fail_on_exit_7_and_junit(tmp_path, scene_files):
    cfg = tmp_path / "bake.toml"
    cfg.write_text(CONFIG)
    junit = tmp_path / "report.xml"
    cache = tmp_path / "cache"
    r = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out", "--cache", cache,
             "--quiet", "--fail-on", "leaking.leak > -1", "--fail-on", "direct.rmse < 0", "--junit", junit,
             timeout=600)
    assert r.returncode == 7, r.stderr
    assert "gate FAILED: leaking.leak > -1" in r.stderr and "gate passed: direct.rmse < 0" in r.stderr
    root = ET.parse(junit).getroot()
    gates = {c.get("name"): c for c in root.find("testsuite[@name='kiln.gates']").iter("testcase")}
    assert gates["leaking.leak > -1"].find("failure") is not None and gates["direct.rmse < 0"].find("failure") is None
    modes = {c.get("name"): c for c in root.find("testsuite[@name='kiln.modes']").iter("testcase")}
    assert set(modes) == {"direct", "leaking", "mask_normalized"} and modes["leaking"].find("failure") is not None
    assert "leaking.rmse = " in modes["leaking"].find("system-out").text
    # the bundle is written, with the check points (one given normal per point)
    cp = json.loads((tmp_path / "out" / "check_points.json").read_text())
    assert len(cp["points"]) == 2 and len(cp["reference_indirect"][0]) == 1 and set(cp["modes"]) >= {"leaking"}
    assert cp["normals"][1] == [[1.0, 0.0, 0.0]]

    # passing gates: exit 0 (every stage from the cache); a gate naming no metric fails; a bad one is a usage error
    r = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out2", "--cache", cache,
             "--quiet", "--fail-on", "mask_normalized.rmse > 10", "--junit", junit)
    assert r.returncode == 0, r.stderr
    assert ET.parse(junit).getroot().get("failures") == "0"
    r = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out3", "--cache", cache,
             "--quiet", "--fail-on", "prt.leak > 0")
    assert r.returncode == 7 and "no metric 'prt.leak'" in r.stderr
    r = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out4", "--cache", cache,
             "--fail-on", "leak is bad")
    assert r.returncode == 2 and "cannot read the gate" in r.stderr and not (tmp_path / "out4").exists()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))


def test_gates_show_the_reference_noise():
    """A value is shown with its standard error, and a verdict within 2 standard errors of the threshold says the
    reference's noise could change it; ``*.rmse*`` does not gate the standard errors themselves."""
    m = {"ddgi.rmse": 0.0025, "ddgi.rmse_stderr": 0.001, "leaking.rmse": 0.1, "leaking.rmse_stderr": 0.0003}
    near, far, pattern = parse_gate("ddgi.rmse > 0.002"), parse_gate("leaking.rmse > 0.05"), parse_gate("*.rmse* > 1")
    assert [g.text for g in check([near, far, pattern], m)] == ["ddgi.rmse > 0.002", "leaking.rmse > 0.05"]
    assert near.uncertain == ["ddgi.rmse"] and "ddgi.rmse = 0.0025 ± 0.001" in near.describe()
    assert "noise could change this verdict" in near.describe()
    assert far.uncertain == [] and "± 0.0003" in far.describe() and "noise" not in far.describe()
    assert sorted(pattern.matched) == ["ddgi.rmse", "leaking.rmse"]
    root = ET.fromstring(junit_xml([near], {"stages": [], "artifacts": []}, m))
    assert "ddgi.rmse = 0.0025 ± 0.001" in root.find(".//testcase/system-out").text
