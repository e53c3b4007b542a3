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
from workers.kernels.sh import sh_irradiance, sh_irradiance_l1_nonlinear

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "proto" / "fixtures"


def _expected(folder: Path = FIX) -> dict:
    return json.loads((folder / "expected.json").read_text())


def test_fixtures_are_current(tmp_path):
    """Regenerating gives the same expected numbers and the same decoded textures (zstd bytes may differ
    between zstd versions, so textures are compared decoded)."""
    r = subprocess.run([sys.executable, str(FIX / "make_fixtures.py"), "--out", str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert _expected(tmp_path) == _expected(), "proto/fixtures is stale: run .venv/bin/python proto/fixtures/make_fixtures.py"
    for f in sorted(FIX.glob("*.ktx2")):
        a, ia = read_ktx2(f)
        b, ib = read_ktx2(tmp_path / f.name)
        assert ia["vk_format"] == ib["vk_format"] and a.shape == b.shape and np.array_equal(a, b), f.name


def test_python_decodes_fixtures_to_expected():
    e = _expected()
    for v in e["volumes"]:
        arr, info = read_ktx2(FIX / v["file"])
        assert info["format_name"] == v["format"]
        assert arr.shape == (v["depth"], v["height"], v["width"], v["components"])
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
