"""Directional accuracy of the runtime SH evaluation on an open lit floor (issue 12 item 3; docs/architecture.md
"Runtime SH evaluation"): the measurement that chose L2 as the default.

Two floors, baked through the real pipeline with an explicit grid, the 6 axis normals compared per probe:

1. **Closed form**: a 200 m floor (albedo 0.5) under a uniform sky L_s and a sun. A point above it sees sky above
   and a floor of constant radiance L_f = ρ/π (π L_s + E_sun cos θ) below, so E(up) = π L_s, E(down) = π L_f,
   E(side) = π (L_s + L_f)/2 — linear in n, so L1 linear and L2 are exact up to Monte Carlo noise; the non-linear L1
   (Hazel 2017) bends it (the sides low, up and down high).
2. **Cycles**: the procedural sealed-box scene's open floor (sun + lamp, sky 0) against the Blender Cycles references
   of ``tests/data/fidelity`` (64 bounces, 8192 spp; skipped where they are absent): the stored probe SH at the
   probe positions (region ``probes``) and the runtime modes at free-space points (region ``open``).

Directions whose reference is below 10% of the point's largest are held in absolute terms (the up-facing light of
a dark sky, ~0.3% of the down-facing), the others relative (the issue's target: ±10%).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.gltf_build import GltfBuilder, quad
from tests.workers.test_probes import bake_until
from workers.kernels import samplers as SM
from workers.kernels.sh import sh_irradiance, sh_irradiance_l1_nonlinear, sh_irradiance_l2

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
FIDELITY = Path(__file__).resolve().parents[1] / "data" / "fidelity"


def _evaluations(sh) -> dict[str, np.ndarray]:
    """(P, 9, 3) probe SH -> {name: (P, 6, 3)} at the 6 axis normals."""
    sh = np.asarray(sh, np.float64)[:, None]
    return {"L2": sh_irradiance_l2(sh, AXES[None]), "L1 linear": sh_irradiance(sh[..., :4, :], AXES[None]),
            "L1 non-linear": sh_irradiance_l1_nonlinear(sh[..., :4, :], AXES[None])}


def _floor_glb(path: Path, width: float = 200.0) -> Path:
    b = GltfBuilder()
    mat = b.material(pbrMetallicRoughness={"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0,
                                           "roughnessFactor": 1.0})
    pos, nrm, _, idx = quad([-width / 2, 0, -width / 2], [width, 0, 0], [0, 0, width], [0, 1, 0])
    b.mesh(pos, idx, normals=nrm, material=mat)
    path.write_bytes(b.glb())
    return path


def test_open_floor_closed_form(tmp_path):
    Ls, E_sun = 0.2, 3.0
    sun = np.array([-0.4, -1.0, -0.3])
    sun /= np.linalg.norm(sun)
    cfg = {"place": {"counts": [2, 2, 2], "box": {"min": [-1, 0.5, -1], "max": [1, 1.5, 1]}},
           "scene": {"sky": [Ls] * 3,
                     "lights": [{"type": "directional", "direction": sun.tolist(), "intensity": E_sun}]},
           "trace": {"rays_per_probe": 1024}}
    _, s = bake_until(tmp_path, _floor_glb(tmp_path / "floor.glb"), cfg, "light")
    Lf = 0.5 / math.pi * (math.pi * Ls + E_sun * -sun[1])
    exact = math.pi * np.array([(Ls + Lf) / 2] * 2 + [Ls, Lf] + [(Ls + Lf) / 2] * 2)
    ev = _evaluations(np.asarray(s["light"]["probe_sh"]).reshape(-1, 9, 3))
    ratio = {k: v[..., 1] / exact for k, v in ev.items()}                    # (P, 6), green channel
    for k, r in ratio.items():
        print(f"{k:14s} E / exact per axis (+x -x +y -y +z -z):", np.round(r.mean(axis=0), 3))
    # each probe its own rotation of the 1024 rays (trace.ray_rotations): per probe within 2%, the mean within 1%
    for k in ("L2", "L1 linear"):
        assert np.abs(ratio[k] - 1).max() < 0.02 and np.abs(ratio[k].mean(axis=0) - 1).max() < 0.01
    nl = ratio["L1 non-linear"].mean(axis=0)
    assert nl[2] > 1.1 and nl[[0, 1, 4, 5]].max() < 0.97                   # up high, the sides low
    # the runtime path (sh_l2 volume, 7 trilinear fetches) between the probes: the same
    grid = {k: s["place"].stats[k] for k in ("counts", "origin", "spacing")}
    p = np.repeat([[0.3, 1.1, -0.2]], 6, axis=0)
    e = SM.irradiance("leaking", {"sh_l2": s["light"]["sh_l2"]}, grid, p, AXES)[:, 1]
    assert np.abs(e / exact - 1).max() < 0.015


def _cycles():
    pts, ref = FIDELITY / "sealed-box.points.json", FIDELITY / "sealed-box.lambert.cycles.json"
    if not (pts.exists() and ref.exists()):
        pytest.skip("no Cycles references in tests/data/fidelity (tests/data/fidelity/make_references.py)")
    return json.loads(pts.read_text()), json.loads(ref.read_text())


def _errors(e, ref):
    """Per point and axis: relative error where the reference is >= 10% of the point's largest, else NaN; and the
    absolute error over the point's largest (all axes)."""
    big = ref >= 0.1 * ref.max(axis=1, keepdims=True)
    rel = np.where(big, e / np.where(big, ref, 1.0) - 1.0, np.nan)
    return rel, np.abs(e - ref) / ref.max(axis=1, keepdims=True)


def _worst(rel):
    """Per axis max |rel| over the points where it is defined (NaN where none is: the dark up-facing axis)."""
    return np.array([np.abs(c[~np.isnan(c)]).max() if (~np.isnan(c)).any() else np.nan for c in rel.T])


def test_open_lit_floor_against_cycles(tmp_path, scene_files):
    """The sealed-box scene's open floor (10 x 10 m, sun + lamp, sky 0) against Cycles: L2 within ±10% on every
    lit axis (measured: within 8%), the non-linear L1 up to 33% off; the dark up-facing axis within 6% of the point's
    largest in absolute terms."""
    points, ref = _cycles()
    E = np.asarray(ref["E_probe_rgb"]).mean(axis=-1)                          # (points, 6) RGB mean
    assert np.allclose(ref["dirs"], AXES)
    g = points["probe_grid"]
    lo = np.asarray(g["origin"])
    cfg = {"place": {"counts": g["counts"], "box": {"min": lo.tolist(),
                                                     "max": (lo + np.asarray(g["spacing"]) * 7).tolist()}}}
    _, s = bake_until(tmp_path, scene_files["sealed-box"], cfg, "clusters")
    grid = {k: s["place"].stats[k] for k in ("counts", "origin", "spacing")}
    P = np.asarray(points["points"])
    # 1. the stored probe SH at the probe positions (they are grid positions; relocation moved none here)
    probes = points["regions"]["probes"]
    ijk = np.round((P[probes] - np.asarray(grid["origin"])) / np.asarray(grid["spacing"])).astype(int)
    nx, ny, _ = grid["counts"]
    flat = (ijk[:, 2] * ny + ijk[:, 1]) * nx + ijk[:, 0]
    reloc = np.asarray(s["relocate"]["probe_positions_relocated"]).reshape(-1, 3)[flat]
    assert np.abs(reloc - P[probes]).max() < 1e-3
    ev = _evaluations(np.asarray(s["light"]["probe_sh"]).reshape(-1, 9, 3)[flat])
    worst = {}
    for k, v in ev.items():
        rel, ab = _errors(np.maximum(v.mean(axis=-1), 0), E[probes])
        worst[k] = (_worst(rel), ab.max(axis=0))
        print(f"probes {k:14s} worst |E/Cycles - 1| per axis:", np.round(worst[k][0], 3),
              " worst |E - Cycles| / max:", np.round(worst[k][1], 3))
    assert np.nanmax(worst["L2"][0]) < 0.10 and worst["L2"][1].max() < 0.06
    assert np.nanmax(worst["L1 non-linear"][0]) > 0.2                        # what L2 replaced
    # 2. the runtime modes at free-space points (their default is L2: the bake has the L2 volumes)
    arrays = {}
    for st in ("light", "masks", "clusters", "visibility"):
        for n in s[st].names():
            arrays[n] = s[st][n]
    opened = points["regions"]["open"]
    p = np.repeat(P[opened], 6, axis=0)
    n = np.tile(AXES, (len(opened), 1))
    for mode in ("leaking", "mask", "mask_normalized"):
        for order in (2, 1):
            e = np.maximum(SM.irradiance(mode, arrays, grid, p, n, views=n, sh_order=order), 0)
            rel, ab = _errors(e.mean(axis=-1).reshape(len(opened), 6), E[opened])
            print(f"open {mode:16s} L{order} worst |E/Cycles - 1| per axis:", np.round(_worst(rel), 3),
                  " worst |E - Cycles| / max:", np.round(ab.max(0), 3))
            if order == 2:
                assert np.nanmax(np.abs(rel)) < 0.10 and ab.max() < 0.06, mode
            else:
                assert np.nanmax(np.abs(rel)) > 0.15, mode
