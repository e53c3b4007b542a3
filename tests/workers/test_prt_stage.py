"""Stage prt (workers/stages/prt.py) and relighting (workers/prt_relight.py) on real bakes.

The stage is called with a hand-built StageContext on top of the real pipeline up to ``light``
(``bake_until``), so these tests do not depend on the stage being registered in proto/stages.py.
Reference results come from the light stage's own bounce loop (``light.integrate`` on the cached hits,
emission excluded, sky 0) through :func:`tests.workers.prt_reference.light_stage_reference`.
"""
from __future__ import annotations

import json
from types import SimpleNamespace
import zipfile

import numpy as np
import pytest

from proto import bundle
from proto.models import BakeConfig
from tests.conftest import shared_path
from tests.workers.gltf.builders import QUAD, QUAD_UV, Gltf, write_glb
from tests.workers.prt_reference import light_stage_reference
from tests.workers.test_probes import bake_until
from workers import prt_relight
from workers.gltf import ingest_file
from workers.kernels import prt as kprt
from workers.kernels import prt_scenario as scenario
from workers.kernels.ddgi import sample_irradiance
from workers.kernels.gather import ddgi_weights
from workers.kernels.prt_dataset import USABLE_TEST_CONFIGS
from workers.stages import prt as sprt
from workers.stages.base import StageContext

# lights in front of the open side (+z) of the procedural Cornell box, spots aimed into it: the paper's
# "lights around the asset" (PRT §4.1, Fig 7-8)
FRONT = {"types": ["point", "spot"], "box": {"min": [0.0, 0.1, 1.3], "max": [1.0, 0.9, 2.0]},
         "intensity_min": 2.0, "intensity_max": 8.0, "color_min": [0.5, 0.5, 0.5], "color_max": [1.0, 1.0, 1.0]}


def _config(**prt):
    # rescue_offset 0: the 4x4x4 grid's outer layer lies on the box's walls; rescued (the default since issue 12),
    # those probes stand next to the walls, where near-wall lights give sharp responses: the held-out relit error at
    # n = 16 reads 0.047 (12% of the rms) instead of 0.010 (6%). These tests are about the transfer's fit on a fixed
    # set of probes, so they keep DDGI-P's relocation alone (walls' probes OFF).
    return {"place": {"counts": [4, 4, 4]}, "trace": {"rays_per_probe": 64, "rescue_offset": 0.0},
            "prt": {"enabled": True, "scenario": FRONT, "lightmap": 64, **prt}}


def _ctx(tmp, scene_path, cfg):
    scene, s = bake_until(tmp, scene_path, cfg, "light")
    return StageContext(config=BakeConfig.model_validate(cfg), scene_loader=lambda: scene, inputs=s,
                        report=lambda f: None)


@pytest.fixture(scope="module")
def cornell(tmp_path_factory, scene_files):
    """The procedural Cornell box with N = 128, M = 256: its dataset and the stage output (n = 16)."""
    ctx = _ctx(tmp_path_factory.mktemp("prt"), scene_files["cornell"],
               _config(configurations=128, measurement_points=256, basis=16))
    ds = sprt.prt_dataset(ctx)
    out = sprt.prt_output(ctx, ds)
    return ctx, ds, out


@pytest.fixture(scope="module")
def heldout(cornell):
    """16 held-out configurations (another seed) with the light stage's result for each."""
    ctx, ds, _ = cornell
    sc = ctx.config.prt.scenario
    caster = ds.probes["caster"]
    lights = scenario.random_light_configurations(np.random.default_rng(2024), sc.model_dump(), 16, sc.box.min,
                                              sc.box.max, inside=caster.inside_parity,
                                              target_box=((0, 0, 0), (1, 1, 1)))
    refs = [light_stage_reference(ds, L, ctx.config.light) for L in lights]
    xs = [scenario.measurement_direct(ds.points, L, caster, ds.probes["eps"]) for L in lights]
    return lights, xs, [r[0].reshape(-1, 3) for r in refs], [r[1] for r in refs]


def _fit(ds, data, n, sec):
    """The stage's fit (workers.kernels.prt_dataset.fit_targets) of ``data`` with n slots and ``sec``'s settings."""
    return kprt.fit(ds.direct, data, n, sec.ridge, sec.gamma, sec.channels, sec.norm, sec.ridge_folds)


def _rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


# ------------------------------------------------------------------------------------------- stage
def test_disabled_stage_returns_nothing(tmp_path, scene_files):
    cfg = {"place": {"counts": [2, 2, 2]}, "trace": {"rays_per_probe": 16}}
    out = sprt.run_prt(_ctx(tmp_path, scene_files["cornell"], cfg))
    assert out.artifacts == [] and out.stats == {"enabled": False}


def test_a_dataset_too_large_is_refused(tmp_path, scene_files, monkeypatch):
    from workers.kernels import prt_dataset
    from workers.stages.base import StageError

    monkeypatch.setattr(prt_dataset, "DATASET_BYTES", 1000)
    ctx = _ctx(tmp_path, scene_files["cornell"], {**_config(configurations=4, measurement_points=8, lightmap=0),
                                                   "place": {"counts": [2, 2, 2]}})
    with pytest.raises(StageError) as e:
        sprt.prt_dataset(ctx)
    assert e.value.code == "prt_too_large" and "lower prt.configurations" in str(e.value)


def test_ddgi_weights_reproduce_the_sampler(cornell):
    _, ds, _ = cornell
    pr, g = ds.probes, ds.probes["grid"]
    surf = pr["surf"]
    W = ddgi_weights(surf.position, surf.normal, surf.view, g, pr["positions"], pr["states"], pr["depth"],
                          pr["n"], pr["bias"], pr["visible"])
    assert W.shape == (surf.index.size, 64 * (pr["n"] + 2) ** 2) and W.nnz <= 32 * W.shape[0]
    maps = np.random.default_rng(0).random((64, pr["n"] + 2, pr["n"] + 2, 3)).astype(np.float32)
    ref = sample_irradiance(surf.position, surf.normal, surf.view, g["counts"], g["origin"], g["spacing"],
                            pr["positions"], pr["states"], maps, pr["depth"], pr["bias"], visible=pr["visible"])
    assert np.allclose(W @ maps.reshape(-1, 3), ref, atol=1e-5)


def test_dataset_equals_the_light_stage_for_its_configurations(cornell):
    ctx, ds, _ = cornell
    for k in (0, 5, 77):
        sh, tex = light_stage_reference(ds, ds.configs[k], ctx.config.light)
        assert np.allclose(ds.sh[k], sh, rtol=1e-4, atol=1e-5 * np.abs(sh).max())
        assert np.allclose(ds.texels[k], tex, rtol=1e-4, atol=1e-5 * np.abs(tex).max())
        assert np.allclose(ds.direct[k], scenario.measurement_direct(ds.points, ds.configs[k], ds.probes["caster"],
                                                                 ds.probes["eps"]))
    assert ds.bounces.min() >= 2


def test_measurement_points_are_blue_noise_on_lit_surfaces(cornell):
    ctx, ds, _ = cornell
    p = ds.points
    assert p["position"].shape == (256, 3) and np.array_equal(p["offsets"], np.arange(257))
    assert np.all(p["albedo"].max(axis=1) > 0)
    lit = np.zeros(256, bool)
    for lights in ds.configs[:USABLE_TEST_CONFIGS]:
        lit |= ds.direct[ds.configs.index(lights)].max(axis=1) > 0
    assert lit.all()                      # every point is lit by some configuration
    tri, u, v = scenario.area_samples(ctx.scene.triangles, 256, np.random.default_rng(0))
    t = ctx.scene.triangles[tri].astype(np.float64)
    rand = (1 - u - v)[:, None] * t[:, 0] + u[:, None] * t[:, 1] + v[:, None] * t[:, 2]
    assert scenario.min_spacing(p["position"]) > 2 * scenario.min_spacing(rand)


def test_artifacts_and_section(cornell):
    ctx, ds, out = cornell
    arts = {a.name: a for a in out.artifacts}
    sec = arts["prt"].data
    assert sec["basis"] == 16 and sec["channels"] == "mono" and sec["configurations"] == 128
    assert sec["sh"]["coefficients"] == 9 and sec["sh"]["counts"] == [4, 4, 4]
    assert len(sec["sh"]["basis"]) == 9 and all(len(g) == 4 for g in sec["sh"]["basis"])
    for k, names in enumerate(sec["sh"]["basis"]):
        for g, name in enumerate(names):
            assert name == f"prt_sh_basis_c{k}_g{g}"
            assert arts[name].data.shape == (4, 4, 4, 4) and arts[name].data.dtype == np.float16  # RGBA16F
    assert arts["prt_sh_transfer"].data.shape == (3, 16, 257)
    assert arts["prt_points"].data.shape == (256, 9) and arts["prt_point_offsets"].data.shape == (257,)
    lm = sec["lightmap"]
    assert lm["resolution"] == 64 and lm["uv_source"] == "xatlas" and lm["texels"] > 500
    assert [arts[n].data.shape for n in lm["basis"]] == [(64, 64, 4)] * 4
    assert arts["prt_lm_transfer"].data.shape == (3, 16, 257)
    assert arts["prt_lm_uv"].data.shape == (ctx.scene.n_triangles, 3, 2)
    mask = arts["prt_lm_mask"].data
    assert mask.dtype == np.uint8 and int((mask == 1).sum()) == lm["texels"] and (mask == 2).any()
    assert len(arts["prt_lights"].data["configurations"]) == 128
    assert out.stats["enabled"] and out.stats["sh_energy_kept"] > 0.9
    json.dumps(out.stats)  # the stage record is JSON


def test_heldout_relight_close_to_projection_and_better_with_more_basis(cornell, heldout):
    """PRT Fig 14: relit RMSE near the RMSE of projecting the reference onto the basis; falls with n.

    Probe SH (the light stage's ``probe_sh``): within 1.2x of the projection at n = 16. The lightmap's
    basis projects the reference better (its irradiance is smoother), so the same regression error of the
    coefficients from 256 points weighs more there: within 2x (measured 1.45 here, 1.25 on the vinc3r
    bench)."""
    ctx, ds, _ = cornell
    _, xs, sh_true, tex_true = heldout
    N, P, K = ds.sh.shape[:3]
    sec = ctx.config.prt
    for data, truth, bound in ((ds.sh.reshape(N, P * K, 3), sh_true, 1.2), (ds.texels, tex_true, 2.0)):
        f = _fit(ds, data, 64, sec)
        relit = {n: _rmse([kprt.reconstruct(f.truncated(n), x) for x in xs], truth) for n in (4, 16, 64)}
        proj16 = _rmse([kprt.project(f.truncated(16), x, y) for x, y in zip(xs, truth)], truth)
        rms = float(np.sqrt(np.mean(np.square(truth))))
        assert relit[16] <= bound * proj16, (relit, proj16)
        assert relit[4] > relit[16] > relit[64], relit
        assert relit[16] < 0.1 * rms


def test_relight_linear_and_reproduces_the_dataset(cornell):
    ctx, ds, out = cornell
    arts = {a.name: a.data for a in out.artifacts}
    model = prt_relight.PrtModel.from_arrays(arts)
    caster = ds.probes["caster"]
    L = ds.configs[3]
    one = prt_relight.relight(model, L, caster)
    two = prt_relight.relight(model, [dict(light, intensity=2 * light["intensity"]) for light in L], caster)
    for name in ("probe_sh", "sh_l1_r", "lightmap"):
        scale = np.abs(one[name]).max()
        rgb = slice(None) if name != "lightmap" else slice(0, 3)
        assert np.allclose(two[name][..., rgb], 2 * one[name][..., rgb], atol=1e-5 * scale)
    zero = prt_relight.relight(model, [], caster)                       # no lights, no light
    assert all(not np.any(v[..., :3]) for v in zero.values())
    # the dataset's own configurations come back up to the truncation error of n = 16 slots (within 20 %: the
    # cross-validated ridge, λ >= 0.1 of the data's scale, gives up some training fit for held-out lights; 1.10 here)
    N, P, K = ds.sh.shape[:3]
    f = _fit(ds, ds.sh.reshape(N, P * K, 3), 16, ctx.config.prt)
    rel, proj, truth = [], [], []
    for k in range(0, N, 8):
        y = ds.sh[k].reshape(-1, 3)
        rel.append(prt_relight.relight(model, ds.configs[k], caster, lightmap=False)["probe_sh"].reshape(-1, 3))
        proj.append(kprt.project(f, ds.direct[k], y))
        truth.append(y)
    assert _rmse(rel, truth) <= 1.2 * _rmse(proj, truth)
    # the float32 relight path equals the kernel's reconstruction
    assert np.allclose(rel[0], kprt.reconstruct(f, ds.direct[0]), rtol=1e-3, atol=1e-4 * np.abs(truth[0]).max())
    assert one["sh_l1_g"].shape == (4, 4, 4, 4) and np.array_equal(one["sh_l1_g"], one["probe_sh"][..., :4, 1])
    # L2 bake (light.sh_order 2, the default): relight also gives the sh_l2 volume (three.js LightProbeGrid layout)
    from workers.kernels.sh import sh_l2_from_atlas

    assert one["probe_sh"].shape == (4, 4, 4, 9, 3) and one["sh_l2"].shape == (7 * (4 + 2), 4, 4, 4)
    assert np.array_equal(sh_l2_from_atlas(one["sh_l2"]), one["probe_sh"])
    assert one["lightmap"].shape == (64, 64, 4) and set(np.unique(one["lightmap"][..., 3])) == {0.0, 1.0}


@pytest.mark.parametrize("prt", [{"channels": "multi"}, {"gamma": 2.2}, {"supersampling": 4},
                                 {"ridge": 0.0, "lightmap": 0}])
def test_variants_round_trip_through_the_bundle_format(tmp_path, scene_files, prt):
    ctx = _ctx(tmp_path, scene_files["cornell"], _config(configurations=24, measurement_points=32, basis=6, **prt))
    ds = sprt.prt_dataset(ctx)
    out = sprt.prt_output(ctx, ds)
    arts = {a.name: a.data for a in out.artifacts}
    infos = [a.write(tmp_path / "b", "prt") for a in out.artifacts]
    loaded = {i.name: bundle.load_artifact(tmp_path / "b" / i.file, i) for i in infos}
    from workers.raycast import RayCaster

    caster = RayCaster(ctx.scene.triangles)
    L = arts["prt_lights"]["configurations"][1]
    a, b = prt_relight.relight(arts, L, caster), prt_relight.relight(loaded, L, caster)
    assert a.keys() == b.keys() and ("lightmap" in a) == (prt.get("lightmap", 64) > 0)
    for name in a:
        assert np.array_equal(a[name], b[name])
    # the unpacked textures give the kernel's reconstruction (float32 vs float64)
    sec = ctx.config.prt
    N, P, K = ds.sh.shape[:3]
    f = _fit(ds, ds.sh.reshape(N, P * K, 3), 6, sec)
    want = kprt.reconstruct(f, scenario.measurement_direct(ds.points, L, caster, ds.probes["eps"]))
    assert np.allclose(a["probe_sh"].reshape(-1, 3), want, rtol=1e-3, atol=1e-4 * np.abs(want).max())
    if ds.texels is not None:
        g = _fit(ds, ds.texels, 6, sec)
        want = kprt.reconstruct(g, scenario.measurement_direct(ds.points, L, caster, ds.probes["eps"]))
        got = a["lightmap"].reshape(-1, 4)[ds.lightmap["covered"].ravel(), :3]
        assert np.allclose(got, want, rtol=1e-3, atol=1e-4 * np.abs(want).max())
    if prt.get("supersampling"):
        off = arts["prt_point_offsets"]
        assert arts["prt_points"].shape == (32 * 4, 9) and off[-1] == 128 and np.all(np.diff(off) >= 1)
    if prt.get("channels") == "multi":
        assert arts["prt_sh_transfer"].shape == (1, 6, 3 * 32 + 1) and len(arts["prt"]["sh"]["basis"][0]) == 6
    assert np.all(np.isfinite(a["probe_sh"]))


# ------------------------------------------------------------------------------ TEXCOORD_1 lightmaps
def test_ingest_keeps_texcoord1_of_the_meshes_that_have_it(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh(QUAD[:3], TEXCOORD_1=QUAD_UV[:3] * 0.5))
    g.node(mesh=g.mesh(QUAD[:3] + 1))
    g.node(mesh=g.mesh(QUAD[:3] + 2, TEXCOORD_1=QUAD_UV[:3] * 0.25))
    s = ingest_file(write_glb(tmp_path / "a.glb", g))
    assert s.uv1 is None and "TEXCOORD_1 dropped: not every primitive has it" in s.warnings
    uv, chart = s.texcoord1()
    assert chart.tolist() == [0, -1, 2]
    np.testing.assert_allclose(uv[0], QUAD_UV[:3] * 0.5)
    np.testing.assert_allclose(uv[2], QUAD_UV[:3] * 0.25)
    assert np.all(uv[1] == 0)
    back = type(s).from_bytes(s.to_bytes())
    assert np.array_equal(back.uv1_chart, s.uv1_chart) and np.array_equal(back.uv1_partial, s.uv1_partial)


def test_vinc3r_lightmap_uses_texcoord1_charts_and_xatlas(tmp_path):
    pytest.importorskip("xatlas", reason="xatlas generates UVs for the meshes without TEXCOORD_1")
    folder = shared_path("scenes", "cornell-box-vinc3r")
    gltf = folder / "cornellBox-2.80-Eevee-gltf.gltf"
    doc = json.loads(gltf.read_text())
    zpath = tmp_path / "cornell.zip"
    with zipfile.ZipFile(zpath, "w") as z:
        z.write(gltf, gltf.name)
        for key in ("buffers", "images"):
            for obj in doc.get(key, []):
                if (folder / obj.get("uri", "")).is_file():
                    z.write(folder / obj["uri"], obj["uri"])
    cfg = {"place": {"counts": [4, 4, 4]}, "trace": {"rays_per_probe": 64},
           "prt": {"enabled": True, "configurations": 16, "measurement_points": 64, "basis": 8, "lightmap": 128,
                   "scenario": {"types": ["point"], "box": {"min": [-1.5, 0.5, 2.5], "max": [1.5, 2.5, 4.0]}}}}
    ctx = _ctx(tmp_path / "bake", zpath, cfg)
    uv, chart = ctx.scene.texcoord1()
    assert set(np.unique(chart)) >= {-1, 0, 1, 3}          # bloc, suzanne, the box; the lamp and logos lack it
    ds = sprt.prt_dataset(ctx)
    lm = ds.lightmap
    assert lm["source"] == "texcoord1+xatlas"
    tri_map = lm["tri"]
    covered_tris = np.unique(tri_map[tri_map >= 0])
    # every chart lands in the map, in its own region: texels of different charts never share a footprint box
    charts_in = set(chart[covered_tris].tolist())
    assert {0, 1, 3} <= charts_in and -1 in charts_in
    atlas = lm["uv"]
    boxes = {}
    for c in (0, 1, 3):
        pts = atlas[chart == c].reshape(-1, 2)
        boxes[c] = (pts.min(axis=0), pts.max(axis=0))
    for a in boxes:
        for b in boxes:
            if a < b:
                (a0, a1), (b0, b1) = boxes[a], boxes[b]
                assert np.any(a1 <= b0) or np.any(b1 <= a0), (a, b)
    sh, tex = light_stage_reference(ds, ds.configs[0], ctx.config.light)
    assert np.allclose(ds.texels[0], tex, rtol=1e-4, atol=1e-5 * np.abs(tex).max())
    assert np.abs(tex).max() > 0


def test_the_dataset_shades_hits_as_the_light_stage(tmp_path, scene_files):
    """What PRT is fit to is the light stage's own result: for a directional light alone (no emission, sky 0, no hot
    spot), the dataset's computation (light_stage_reference: the dataset's bent normals, horizon factor and near-field
    occlusion) reproduces the light stage's stored probe SH. Without the near-field term it does not (light stage 8
    occludes the hits near edges)."""
    from workers.kernels.grid import OFF
    from workers.scene import NormalizedScene

    cfg = _config(configurations=8, measurement_points=32, basis=4)
    # no L2 deringing: the stored SH is the projection itself; no adaptive rays: the dataset has the trace's rays only
    cfg["light"] = {"sh_order": 1, "extra_rays": 0}
    cfg["scene"] = {"use_scene_lights": False, "sky": [0, 0, 0],
                    "lights": [{"type": "directional", "direction": [0.3, -0.6, -1.0], "intensity": 4.0}]}
    ctx = _ctx(tmp_path, scene_files["sealed-box"], cfg)       # a box on a ground slab: concave edges, no emission
    scene: NormalizedScene = ctx.scene
    assert scene.emissive_materials() == 0
    ds = sprt.prt_dataset(ctx)
    assert ds.probes["near"] is not None and ds.probes["near"].index.size > 0
    lights = ctx.inputs["ingest"]["lights"]["lights"]
    want = np.asarray(ctx.inputs["light"]["probe_sh"], np.float64).reshape(-1, 4, 3)
    live = ctx.inputs["trace"]["probe_states"].reshape(-1) != OFF
    got = light_stage_reference(ds, lights, ctx.config.light, lightmap=False)[0].reshape(-1, 4, 3)
    scale = np.abs(want[live]).max()
    assert scale > 0
    tol = 2e-3 * scale                                                            # half floats stored
    np.testing.assert_allclose(got[live], want[live], atol=tol)
    without = dict(ds.probes, near=None)
    far = light_stage_reference(SimpleNamespace(probes=without, lightmap=None), lights, ctx.config.light,
                                lightmap=False)[0].reshape(-1, 4, 3)
    err_with = np.abs(got[live] - want[live]).max()
    err_without = np.abs(far[live] - want[live]).max()
    print(f"dataset vs light stage: {err_with:.2e} with the near-field term, {err_without:.2e} without (tol {tol:.2e})")
    assert err_without > 4 * err_with
