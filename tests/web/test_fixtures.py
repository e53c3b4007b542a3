"""proto/fixtures: the parity fixtures the JS tests read (web/tests/parity.test.js) are current and decode,
in Python, to the numbers expected.json holds (STYLE.md "Cross-language parity")."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from proto.ktx2 import read_ktx2
from workers.kernels.octahedral import oct_decode, oct_encode
from workers.kernels.samplers import sh_l2_sample
from workers.kernels.sh import sh_irradiance, sh_irradiance_l1_nonlinear, sh_irradiance_l2, sh_l2_from_atlas

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "proto" / "fixtures"
GENERATOR = ROOT / "tests" / "proto" / "make_fixtures.py"


def _expected(folder: Path = FIX) -> dict:
    return json.loads((folder / "expected.json").read_text())


def _differences(new, old, path: str = "", rtol: float = 1e-9, atol: float = 1e-12) -> list[str]:
    """Where two expected.json documents differ: keys, lengths, strings, or numbers beyond ``rtol``/``atol``
    (numpy and BLAS builds change the last digits of float64 sums: 1.7906976907453245 vs ...325; what the JS
    parity tests check is 1e-6 and coarser)."""
    if isinstance(old, dict):
        if not isinstance(new, dict) or set(new) != set(old):
            return [f"{path}: keys"]
        return [d for k in old for d in _differences(new[k], old[k], f"{path}.{k}", rtol, atol)]
    if isinstance(old, list):
        if not isinstance(new, list) or len(new) != len(old):
            return [f"{path}: length"]
        return [d for i, (a, b) in enumerate(zip(new, old)) for d in _differences(a, b, f"{path}[{i}]", rtol, atol)]
    if isinstance(old, bool) or not isinstance(old, (int, float)) or not isinstance(new, (int, float)):
        return [] if new == old else [f"{path}: {new!r} != {old!r}"]
    return [] if abs(new - old) <= atol + rtol * abs(old) else [f"{path}: {new!r} != {old!r}"]


def test_fixtures_are_current(tmp_path):
    """Regenerating gives the same expected numbers (to float64 rounding) and the same decoded textures (zstd
    bytes may differ between zstd versions, so textures are compared decoded)."""
    r = subprocess.run([sys.executable, str(GENERATOR), "--out", str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    stale = _differences(_expected(tmp_path), _expected())
    assert not stale, f"proto/fixtures is stale ({stale[:5]}): run .venv/bin/python tests/proto/make_fixtures.py"
    for f in sorted(FIX.glob("*.ktx2")):
        a, ia = read_ktx2(f)
        b, ib = read_ktx2(tmp_path / f.name)
        assert ia["vk_format"] == ib["vk_format"] and a.shape == b.shape and np.array_equal(a, b), f.name


def test_fixture_differences_are_found():
    old = {"a": [1.0, 2.0, {"b": "x"}], "c": 0.0}
    assert _differences({"a": [1.0 + 1e-13, 2.0, {"b": "x"}], "c": 1e-16}, old) == []
    assert _differences({"a": [1.0001, 2.0, {"b": "x"}], "c": 0.0}, old) == [".a[0]: 1.0001 != 1.0"]
    assert _differences({"a": [1.0, 2.0, {"b": "y"}], "c": 0.0}, old) == [".a[2].b: 'y' != 'x'"]
    assert _differences({"a": [1.0, 2.0], "c": 0.0}, old) == [".a: length"]
    assert _differences({"a": [1.0, 2.0, {"b": "x"}]}, old) == [": keys"]


def test_python_decodes_fixtures_to_expected():
    e = _expected()
    for v in e["volumes"]:
        arr, info = read_ktx2(FIX / v["file"])
        assert info["format_name"] == v["format"]
        assert arr.shape == (v["depth"], v["height"], v["width"], v["components"])[0 if v["depth"] else 1:]  # 2D: no D
        assert np.array_equal(arr.astype(np.float64).ravel(), np.asarray(v["values"], np.float64))
    atlas, _ = read_ktx2(FIX / e["atlas"]["file"])
    assert np.array_equal(atlas.ravel(), np.asarray(e["atlas"]["values"], np.float32))
    sh = np.stack([read_ktx2(FIX / f)[0] for f in e["sh"]["files"]], axis=-1)  # (D, H, W, 4, 3)
    assert np.array_equal(sh.ravel(), np.asarray(e["sh"]["coeffs"], np.float32))
    irr = sh_irradiance(sh.astype(np.float64)[..., None, :, :], np.asarray(e["sh"]["normals"]))
    np.testing.assert_allclose(irr.ravel(), e["sh"]["irradiance"], rtol=1e-12)
    irr_nl = sh_irradiance_l1_nonlinear(sh.astype(np.float64)[..., None, :, :], np.asarray(e["sh"]["normals"]))
    np.testing.assert_allclose(irr_nl.ravel(), e["sh"]["irradiance_nonlinear"], rtol=1e-12)
    o = e["octahedral"]
    np.testing.assert_allclose(oct_encode(np.asarray(o["dirs"])), o["encoded"], atol=1e-12)
    np.testing.assert_allclose(oct_decode(np.asarray(o["uv"])), o["decoded"], atol=1e-12)


def test_python_decodes_the_l2_fixture_and_its_identities():
    """sh_l2.ktx2 (three.js LightProbeGrid layout) decodes to the coefficients, evaluates (L2, RH01) and samples
    (7 fetches, samplers.sh_l2_sample) to expected.json's numbers — what parity.test.js checks in JavaScript and
    tests/render/test_shading.py in GLSL — and the identities hold: constant radiance -> π·L, clamped-cosine
    lobe -> its exact irradiance (to L2's band-limit, 0.02)."""
    e = _expected()["sh_l2"]
    atlas, info = read_ktx2(FIX / e["file"])
    assert info["format_name"] == "R32G32B32A32_SFLOAT" and list(atlas.shape) == e["atlas_shape"]
    sh = sh_l2_from_atlas(atlas)
    assert np.array_equal(sh.ravel(), np.asarray(e["coeffs"], np.float32))
    irr = sh_irradiance_l2(sh.astype(np.float64)[..., None, :, :], np.asarray(e["normals"]))
    np.testing.assert_allclose(irr.ravel(), e["irradiance"], rtol=1e-12)
    for smp in e["samples"]:
        c9 = sh_l2_sample(atlas, np.asarray([smp["p"]]), e["grid"])[0]
        np.testing.assert_allclose(c9, smp["coeffs"], rtol=1e-12, atol=1e-15)
    const = e["constant"]
    np.testing.assert_allclose(sh_irradiance_l2(np.asarray(const["coeffs"]), np.asarray(e["normals"])),
                               const["irradiance"], rtol=1e-3)
    lobe = e["cosine_lobe"]
    got = sh_irradiance_l2(np.asarray(lobe["coeffs"])[:, None], np.asarray(e["normals"]))[:, 0]
    np.testing.assert_allclose(got, lobe["irradiance"], rtol=1e-12)
    np.testing.assert_allclose(got, lobe["exact"], atol=0.02)
