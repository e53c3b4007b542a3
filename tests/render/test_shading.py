"""The deferred shading pass (workers/render/shading.py) and the GLSL of every GI mode (proto/glsl).

GLSL = Python: points (positions + normals in float textures) are shaded through each mode's GLSL into a
float target and compared with the Python reference samplers (workers/kernels/samplers.py, ddgi.py).
Tolerance: float16 precision relative to the values, 2^-10 × max |reference| (≈ one half-float ulp at
the largest value), for 99.5% of the points (leaking: all of them). Hardware LINEAR filtering computes its
weights in fixed point (8 fractional bits on llvmpipe and NVIDIA, as GL allows), so where a filtered value
jumps across one texel (a mask edge, a depth discontinuity), it may differ by up to 2^-8 of the jump: the
remaining points are held to 2^-8 × scale (mask modes) and 5% (ddgi, whose Chebyshev weight is a steep
function of the filtered depth near r ≈ μ).
"""
from __future__ import annotations

import numpy as np
import pytest

from proto.glsl_preprocess import ShaderSourceError, load_sources, preprocess
from workers.kernels import samplers as SM
from workers.kernels.ddgi import sample_irradiance
from workers.kernels.grid import unpack_atlas
from workers.kernels.shading import direct_irradiance
from workers.raycast import RayCaster
from workers.render.shading import MODES, GBufferInputs, ShadingRenderer, frame_matrix, prepare_mode, shadow_masks

from tests.render.conftest import bake_arrays, bake_grid, mask_meta
from tests.workers.test_probes import bake_until

F16 = 2.0 ** -10
TWO_ROOMS_BOX = {"min": [0.2, 0.2, 0.2], "max": [7.85, 2.8, 3.8]}
CFG = {"place": {"counts": [9, 4, 5], "box": TWO_ROOMS_BOX}, "trace": {"rays_per_probe": 128},
       "light": {"bounces": 2}, "visibility": {"samples_per_cell": 4, "slabs": 1},
       "masks": {"clusters": 4, "sweeps": 200}}


@pytest.fixture(scope="module")
def two_rooms(tmp_path_factory, scene_files):
    scene, s = bake_until(tmp_path_factory.mktemp("shade"), scene_files["two-rooms"], CFG, "compress")
    return scene, s


def _points(n, rng, box):
    lo, hi = np.array(box["min"]) - 0.4, np.array(box["max"]) + 0.4  # some outside the grid box too
    p = lo + rng.random((n, 3)) * (hi - lo)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return p, nrm


def _as_image(a, W=64):
    return np.asarray(a, np.float32).reshape(-1, W, a.shape[-1])


def _render_indirect(ctx, res, mode, p, n, eye, frame=None) -> np.ndarray:
    """(N, 3) E_indirect of ``mode`` (prepared ``res``) at the 64 × 48 G-buffer of points p, normals n (bake frame
    ``frame``, None = identity)."""
    r = ShadingRenderer(ctx, frame=frame)
    try:
        r.set_mode(res)
        r.set_gbuffer(GBufferInputs(_as_image(p), _as_image(n), np.zeros((48, 64, 3)), np.zeros((48, 64, 3)),
                                    np.ones((48, 64), bool)))
        return r.render(mode, output=1, eye=eye).reshape(-1, 3).astype(np.float64)
    finally:
        r.release()


def test_preprocessor_contract():
    src = {"a.glsl": '#include "b.glsl"\n#include "b.glsl"\nvoid main() {}\n', "b.glsl": "float x;\n",
           "c.glsl": '#include "@mode"\n', "v.glsl": "#version 330\n", "cyc.glsl": '#include "cyc2.glsl"\n',
           "cyc2.glsl": '#include "cyc.glsl"\n'}
    out = preprocess("a.glsl", src, target="desktop", defines={"MAX_LIGHTS": 8, "FLAG": True, "OFF": False})
    lines = out.code.splitlines()
    assert lines[:4] == ["#version 330", "#define KILN_DESKTOP 1", "#define MAX_LIGHTS 8", "#define FLAG"]
    assert out.code.count("float x;") == 1                          # included once
    assert out.line_map[lines.index("float x;")] == ("b.glsl", 1)
    assert out.line_map[lines.index("void main() {}")] == ("a.glsl", 3)
    es = preprocess("a.glsl", src, target="webgl2").code.splitlines()
    assert es[0] == "#version 300 es" and "precision highp sampler3D;" in es and "#define KILN_WEBGL2 1" in es
    assert "b.glsl" in preprocess("c.glsl", src, slots={"mode": "b.glsl"}).line_map[-2]
    for entry, kw in (("c.glsl", {}), ("v.glsl", {}), ("nope.glsl", {}), ("cyc.glsl", {}), ("a.glsl", {"target": "x"})):
        with pytest.raises(ShaderSourceError):
            preprocess(entry, src, **kw)


def test_every_mode_compiles_forward_and_deferred(ctx):
    """scene.frag.glsl (the viewer's forward shader) and deferred.frag.glsl compile with every mode, with the
    L1 and the L2 (KILN_SH_L2) SH evaluation."""
    src = load_sources()
    vert = preprocess("scene.vert.glsl", src, target="desktop").code
    for extra in ({}, {"KILN_SH_L2": 1}):
        for mode in MODES:
            for entry in ("scene.frag.glsl",):
                code = preprocess(entry, src, target="desktop", slots={"mode": f"mode_{mode}.glsl"},
                                  defines={"MAX_LIGHTS": 8, **extra}).code
                ctx.program(vertex_shader=vert, fragment_shader=code).release()
            preprocess("deferred.frag.glsl", src, target="webgl2", slots={"mode": f"mode_{mode}.glsl"},
                       defines={"MAX_LIGHTS": 8, **extra})
        r = ShadingRenderer(ctx)
        try:
            for mode in MODES:
                r.program(mode, extra)
        finally:
            r.release()


def _rectilinear(grid: dict, seed: int = 5) -> dict:
    """The grid with its layers moved by up to ±0.3 spacing each (the ends too): a rectilinear grid of the same
    counts (the bake's arrays read through it: GLSL and Python must still agree)."""
    rng = np.random.default_rng(seed)
    layers = []
    for a in range(3):
        n, o, sp = int(grid["counts"][a]), float(grid["origin"][a]), float(grid["spacing"][a])
        layers.append((o + sp * (np.arange(n) + rng.uniform(-0.3, 0.3, n))).tolist() if n > 1 else [o])
    return {"counts": grid["counts"], "origin": [L[0] for L in layers],
            "spacing": [(L[-1] - L[0]) / max(len(L) - 1, 1) for L in layers], "layers": layers}


@pytest.mark.parametrize("mode,sh_order,rect", [
    ("leaking", None, False), ("leaking", 1, False), ("ddgi", None, False), ("mask", None, False), ("mask", 1, False),
    ("mask_normalized", None, False), ("mask_normalized", 1, False),
    ("leaking", None, True), ("ddgi", None, True), ("mask_normalized", None, True), ("mask", 1, True)])
def test_glsl_equals_python(ctx, two_rooms, mode, sh_order, rect):
    """sh_order None: the default, L2 (the bake is light.sh_order 2: sh_l2, cluster_sh_l2_{k}); 1: the L1 path.
    ``rect``: the same arrays read through a rectilinear grid (uGridLayers, probe_grid.glsl giGridIndex)."""
    scene, s = two_rooms
    arrays, grid = bake_arrays(s), bake_grid(s)
    if rect:
        grid = _rectilinear(grid)
    rng = np.random.default_rng(7)
    N = 64 * 48
    p, n = _points(N, rng, TWO_ROOMS_BOX)
    eye = np.array([4.0, 1.5, 2.0])
    view = (eye - p) / np.linalg.norm(eye - p, axis=1, keepdims=True)
    if mode == "leaking":
        want = np.maximum(SM.irradiance("leaking", arrays, grid, p, n, sh_order=sh_order), 0)
        if sh_order == 1:
            assert np.array_equal(want, np.maximum(SM.leaking(p, n, arrays["sh_l1_r"], arrays["sh_l1_g"],
                                                              arrays["sh_l1_b"], grid), 0))
    elif mode == "ddgi":
        counts = grid["counts"]
        irr = unpack_atlas(arrays["irradiance"], counts, arrays["irradiance"].shape[0] // counts[1])[..., :3]
        dep = unpack_atlas(arrays["depth_moments"], counts, arrays["depth_moments"].shape[0] // counts[1])
        want = sample_irradiance(p, n, view, counts, grid["origin"], grid["spacing"],
                                 arrays["probe_positions_relocated"].reshape(-1, 3),
                                 arrays["probe_states"].reshape(-1), irr, dep, 0.3,
                                 layers=grid.get("layers")).astype(np.float64)
    else:
        # the GLSL clamps SH ringing at 0; its mask lookup moves along n + v (v = giViewDir, set from uEye)
        want = np.maximum(SM.irradiance(mode, arrays, grid, p, n, views=view, sh_order=sh_order), 0)
    res = prepare_mode(mode, arrays, grid, mask_meta=mask_meta(s), sh_order=sh_order)
    if mode != "ddgi":
        assert res.info["sh_order"] == (sh_order or 2) and ("KILN_SH_L2" in res.defines) == (sh_order is None)
    assert ("uGridLayers" in res.textures) == rect and res.uniforms["uGridRectilinear"] == rect
    got = _render_indirect(ctx, res, mode, p, n, eye)
    scale = np.abs(want).max()
    assert scale > 0
    if rect:                                  # the layers matter: the uniform grid's reading is far from this one
        uni = {k: grid[k] for k in ("counts", "origin", "spacing")}
        off = _render_indirect(ctx, prepare_mode(mode, arrays, uni, mask_meta=mask_meta(s), sh_order=sh_order),
                               mode, p, n, eye)
        assert np.mean(np.abs(off - want).max(axis=1) / scale > 4 * F16) > 0.2
    err = np.abs(got - want)
    per_point = err.max(axis=1) / scale
    if mode == "leaking":
        assert per_point.max() <= F16, per_point.max()
    else:
        assert np.quantile(per_point, 0.995) <= F16, np.quantile(per_point, 0.995)
        assert per_point.max() <= (0.05 if mode == "ddgi" else 2.0 ** -8), per_point.max()


def _yaw(deg: float) -> np.ndarray:
    """R_y(θ) = [[cos θ, 0, sin θ], [0, 1, 0], [-sin θ, 0, cos θ]] (a turn about +Y)."""
    t = np.radians(deg)
    return np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])


@pytest.mark.parametrize("mode,sh_order", [("leaking", None), ("leaking", 1), ("ddgi", None), ("mask", None),
                                           ("mask_normalized", 1)])
def test_bake_frame_evaluates_the_mode_at_the_bake_frame_point(ctx, two_rooms, mode, sh_order):
    """A bake in a frame M = R_y(30°)ᵀ (grid.frame.matrix, world -> bake): its artifacts are the two-rooms bake's as
    they are (the bake frame), the world is the bake frame turned by Mᵀ. Points, normals and the eye given in world
    (p_w = Mᵀ p) with frame=M shade as the same points given in the bake frame with no frame: the pass hands the mode
    M·p, M·n and M·v (uGiFrame; the view direction matters to ddgi's bias and the mask lookup). Without the frame, or
    with Mᵀ in its place, the world points read other cells: far off."""
    scene, s = two_rooms
    arrays, grid = bake_arrays(s), bake_grid(s)
    rng = np.random.default_rng(17)
    p, n = _points(64 * 48, rng, TWO_ROOMS_BOX)
    eye = np.array([4.0, 1.5, 2.0])
    M = _yaw(30.0).T
    res = prepare_mode(mode, arrays, grid, mask_meta=mask_meta(s), sh_order=sh_order)
    want = _render_indirect(ctx, res, mode, p, n, eye)                       # bake frame = world
    pw, nw, eyew = p @ M, n @ M, M.T @ eye                                    # rows: Mᵀ · x
    got = _render_indirect(ctx, res, mode, pw, nw, eyew, frame=M)
    scale = np.abs(want).max()
    assert scale > 0
    per_point = np.abs(got - want).max(axis=1) / scale
    # the same lookups up to float32 rounding of M·(Mᵀ p): hardware filter weights (8 bits) may step at a mask edge
    assert np.quantile(per_point, 0.995) <= F16, np.quantile(per_point, 0.995)
    assert per_point.max() <= (0.05 if mode == "ddgi" else 2.0 ** -8), per_point.max()
    for wrong in (None, M.T):                                                # the test can fail
        off = np.abs(_render_indirect(ctx, res, mode, pw, nw, eyew, frame=wrong) - want).max(axis=1) / scale
        assert np.mean(off > 0.02) > 0.2, (wrong, np.mean(off > 0.02))


def test_bake_frame_identity_by_default_and_direct_light_stays_world(ctx, two_rooms):
    """No frame = the identity (GLSL ES has no uniform initializers: an unset mat3 would be 0): frame=None and
    frame=I render the same bits, and both equal the Python sampler at the world points. E_direct ignores the
    frame: the lights, the G-buffer and the eye are world."""
    scene, s = two_rooms
    arrays, grid = bake_arrays(s), bake_grid(s)
    lights = s["ingest"]["lights"]["lights"]
    rng = np.random.default_rng(19)
    p, n = _points(64 * 48, rng, TWO_ROOMS_BOX)
    eye = np.array([4.0, 1.5, 2.0])
    res = prepare_mode("leaking", arrays, grid)
    plain = _render_indirect(ctx, res, "leaking", p, n, eye)
    assert np.array_equal(plain, _render_indirect(ctx, res, "leaking", p, n, eye, frame=np.eye(3)))
    assert np.array_equal(plain, _render_indirect(ctx, res, "leaking", p, n, eye, frame={"counts": grid["counts"]}))
    want = np.maximum(SM.irradiance("leaking", arrays, grid, p, n), 0)
    assert np.abs(plain - want).max() <= F16 * np.abs(want).max()
    direct = {}
    for key, frame in (("none", None), ("yaw", {"frame": {"yaw_deg": 30.0, "matrix": _yaw(30.0).T.tolist()}})):
        r = ShadingRenderer(ctx, lights, frame=frame)
        try:
            r.set_mode(res)
            r.set_gbuffer(GBufferInputs(_as_image(p), _as_image(n), np.zeros((48, 64, 3)), np.zeros((48, 64, 3)),
                                        np.ones((48, 64), bool)))
            direct[key] = r.render("leaking", output=2, eye=eye)
            if key == "yaw":   # set_frame(None) goes back to the identity
                r.set_frame(None)
                assert np.array_equal(r.render("leaking", output=1, eye=eye).reshape(-1, 3), plain)
        finally:
            r.release()
    assert np.abs(direct["none"]).max() > 0 and np.array_equal(direct["none"], direct["yaw"])


def test_frame_matrix_forms_and_errors():
    """frame_matrix: None, a grid without frame -> I; grid.frame's matrix as given (row-major world -> bake);
    anything but a rotation is refused."""
    M = _yaw(-12.5).T
    assert np.array_equal(frame_matrix(None), np.eye(3))
    assert np.array_equal(frame_matrix({"counts": [2, 2, 2], "origin": [0, 0, 0]}), np.eye(3))
    for form in (M, M.tolist(), {"yaw_deg": -12.5, "matrix": M.tolist()}, {"frame": {"matrix": M.tolist()}}):
        assert np.array_equal(frame_matrix(form), M)
    for bad in (2 * np.eye(3), np.diag([1.0, 1.0, -1.0]), np.eye(2), np.full((3, 3), np.nan)):
        with pytest.raises(ValueError):
            frame_matrix(bad)


@pytest.mark.parametrize("sh_order", [None, 1])
def test_mask_glsl_equals_python_with_two_code_groups(ctx, tmp_path, scene_files, sh_order):
    """K = 6: the indirection holds two groups of codes (channels 0-3, 4-7; 4 texelFetch) and the shader's second
    half (KILN_MASK_CLUSTERS 6); GLSL = the Python samplers on the masks the atlas stands for."""
    cfg = {**CFG, "masks": {"clusters": 6, "sweeps": 100}}
    scene, s = bake_until(tmp_path, scene_files["two-rooms"], cfg, "compress")
    arrays, grid = bake_arrays(s), bake_grid(s)
    assert s["compress"]["mask_indirection"].shape[0] == 4 * (grid["counts"][2] - 1)
    from workers.kernels.mask_atlas import FIRST_SLOT, codes_of

    codes = codes_of(s["compress"]["mask_indirection"], 6)
    assert (codes[..., 4:] >= FIRST_SLOT).any() and (codes[..., 4:] > 0).mean() > 0.1   # the second group is used
    rng = np.random.default_rng(11)
    p, n = _points(64 * 48, rng, TWO_ROOMS_BOX)
    eye = np.array([4.0, 1.5, 2.0])
    view = (eye - p) / np.linalg.norm(eye - p, axis=1, keepdims=True)
    for mode in ("mask", "mask_normalized"):
        want = np.maximum(SM.irradiance(mode, arrays, grid, p, n, views=view, sh_order=sh_order), 0)
        res = prepare_mode(mode, arrays, grid, mask_meta=mask_meta(s), sh_order=sh_order)
        assert res.info["clusters"] == 6 and res.defines["KILN_MASK_CLUSTERS"] == 6
        got = _render_indirect(ctx, res, mode, p, n, eye)
        per_point = np.abs(got - want).max(axis=1) / np.abs(want).max()
        assert np.quantile(per_point, 0.995) <= F16 and per_point.max() <= 2.0 ** -8, (mode, per_point.max())


def test_leaking_l2_glsl_equals_the_shared_fixture(ctx):
    """Python = GLSL = JavaScript on proto/fixtures: mode_leaking.glsl with KILN_SH_L2 (7 hardware-trilinear fetches
    of sh_l2.ktx2 through giPaddedStackedUVW, shIrradianceL2Packed) gives expected.json's L2 irradiance at the
    fixture's points (written by Python, checked in JS by web/tests/parity.test.js), at the probes too."""
    import json

    from proto.ktx2 import read_ktx2
    from tests.web.test_fixtures import FIX

    e = json.loads((FIX / "expected.json").read_text())["sh_l2"]
    atlas, _ = read_ktx2(FIX / e["file"])
    grid = e["grid"]
    normals = np.asarray(e["normals"])
    nx, ny, nz = grid["counts"]
    probes = [np.asarray(grid["origin"]) + np.asarray(grid["spacing"]) * (i, j, k)
              for k in range(nz) for j in range(ny) for i in range(nx)]
    pts = np.array([smp["p"] for smp in e["samples"]] + probes)
    p = np.repeat(pts, len(normals), axis=0)
    n = np.tile(normals, (len(pts), 1))
    want_samples = np.array([smp["irradiance"][str(i)] for smp in e["samples"] for i in range(len(normals))])
    want_probes = np.asarray(e["irradiance"]).reshape(-1, 3)                  # (D, H, W, N, 3) flattened
    want = np.maximum(np.concatenate([want_samples, want_probes]), 0)
    res = prepare_mode("leaking", {"sh_l2": atlas}, grid)
    assert res.defines == {"KILN_SH_L2": 1} and set(res.textures) == {"uShL2"}
    W = len(normals)
    r = ShadingRenderer(ctx)
    try:
        r.set_mode(res)
        H = len(p) // W
        r.set_gbuffer(GBufferInputs(_as_image(p, W), _as_image(n, W), np.zeros((H, W, 3)), np.zeros((H, W, 3)),
                                    np.ones((H, W), bool)))
        got = r.render("leaking", output=1).reshape(-1, 3).astype(np.float64)
    finally:
        r.release()
    scale = np.abs(want).max()
    # the probes' own values are exact up to float32; between probes hardware filtering weights (8 bits) enter
    np.testing.assert_allclose(got[len(want_samples):], want[len(want_samples):], rtol=1e-5, atol=1e-5 * scale)
    assert np.abs(got - want).max() <= 2.0 ** -8 * scale


def test_direct_matches_python_and_shadow_rays(ctx, two_rooms):
    """The pass's E_direct (lights.glsl × Embree shadow mask) equals shading.direct_irradiance."""
    scene, s = two_rooms
    lights = s["ingest"]["lights"]["lights"]
    assert lights
    rng = np.random.default_rng(3)
    p, n = _points(64 * 32, rng, TWO_ROOMS_BOX)
    caster = RayCaster(scene.triangles)
    want = direct_irradiance(p, n, lights, caster, 1e-3)
    sm = shadow_masks(p, n, lights, caster, 1e-3)
    r = ShadingRenderer(ctx, lights)
    try:
        r.set_mode(prepare_mode("direct", {}, bake_grid(s)))
        r.set_gbuffer(GBufferInputs(_as_image(p), _as_image(n), np.zeros((32, 64, 3)), np.zeros((32, 64, 3)),
                                    np.ones((32, 64), bool), sm.reshape(32, 64, -1)))
        got = r.render("direct", output=2).reshape(-1, 3)
        rad = r.render("direct", output=0).reshape(-1, 3)
    finally:
        r.release()
    assert (sm == 0).any() and (sm == 1).any()
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()
    assert np.abs(rad).max() == 0  # albedo 0, no emission


def test_more_lights_than_a_pass_takes_are_drawn_in_groups(ctx, two_rooms):
    """A scene with 13 lights (MAX_LIGHTS = 8 a pass): E_direct is every light's (= shading.direct_irradiance with
    the shadow rays), the radiance adds albedo/π of all of them to the GI of one pass, and E_indirect is the mode's
    alone — where a single pass of the first 8 lights raised ValueError and failed the evaluate stage."""
    from workers.render.shading import MAX_LIGHTS

    scene, s = two_rooms
    rng = np.random.default_rng(11)
    lights = [{"type": "point", "position": (rng.random(3) * [7.4, 2.4, 3.4] + 0.3).tolist(), "intensity": 2.0 + i,
               "color": [1.0, 0.5 + 0.04 * i, 0.3]} for i in range(12)]
    lights.append({"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 1.5})
    assert len(lights) > MAX_LIGHTS
    p, n = _points(64 * 32, rng, TWO_ROOMS_BOX)
    caster = RayCaster(scene.triangles)
    want = direct_irradiance(p, n, lights, caster, 1e-3)
    sm = shadow_masks(p, n, lights, caster, 1e-3)
    albedo = rng.random((32, 64, 3)).astype(np.float32)
    emission = np.zeros((32, 64, 3), np.float32)
    emission[:4] = 0.25
    gb = GBufferInputs(_as_image(p), _as_image(n), albedo, emission, np.ones((32, 64), bool), sm.reshape(32, 64, -1))
    r = ShadingRenderer(ctx, lights)
    try:
        assert len(r.light_groups) == 2
        r.set_mode(prepare_mode("leaking", bake_arrays(s), bake_grid(s)))
        r.set_gbuffer(gb)
        e_dir = r.render("leaking", output=2).reshape(-1, 3)
        e_ind = r.render("leaking", output=1).reshape(-1, 3)
        rad = r.render("leaking", output=0).reshape(-1, 3)
    finally:
        r.release()
    r1 = ShadingRenderer(ctx, lights[:MAX_LIGHTS])            # the first group alone: the GI is the same
    try:
        r1.set_mode(prepare_mode("leaking", bake_arrays(s), bake_grid(s)))
        r1.set_gbuffer(GBufferInputs(gb.position, gb.normal, albedo, emission, gb.shaded, sm[:, :MAX_LIGHTS].reshape(32, 64, -1)))
        e_ind1 = r1.render("leaking", output=1).reshape(-1, 3)
    finally:
        r1.release()
    scale = np.abs(want).max()
    assert (sm[:, MAX_LIGHTS:] == 0).any() and (want > 0).any()
    assert np.abs(e_dir - want).max() <= 1e-4 * scale
    np.testing.assert_array_equal(e_ind, e_ind1)
    expect = emission.reshape(-1, 3) + albedo.reshape(-1, 3) / np.pi * (want + e_ind)
    assert np.abs(rad - expect).max() <= 1e-4 * np.abs(expect).max()


PRT_CFG = {"place": {"counts": [3, 3, 3]}, "trace": {"rays_per_probe": 32}, "light": {"bounces": 2},
           "prt": {"enabled": True, "configurations": 16, "measurement_points": 32, "basis": 8, "lightmap": 0,
                   "scenario": {"types": ["point"], "box": {"min": [0.2, 0.2, 0.2], "max": [0.8, 0.8, 0.8]}}}}


@pytest.mark.parametrize("sh_order", [None, 1])
def test_prt_glsl_equals_relight(ctx, tmp_path, scene_files, sh_order):
    """mode_prt.glsl's basis sum = prt_relight.relight's SH volumes sampled trilinearly: sh_l2 with all 9 basis
    coefficients (the default: the bake is light.sh_order 2), sh_l1_* with the 4 of L1."""
    from proto.models import BakeConfig
    from workers.prt_relight import PrtModel, relight
    from workers.stages.base import StageContext
    from workers.render.previews import prt_resources as _prt_resources

    prt_stage = pytest.importorskip("workers.stages.prt")
    scene, s = bake_until(tmp_path, scene_files["cornell"], PRT_CFG, "light")
    out = prt_stage.run_prt(StageContext(BakeConfig.model_validate(PRT_CFG), lambda: scene, s, lambda f: None))
    arrays = {a.name: a.data for a in out.artifacts}
    if PrtModel.from_arrays(arrays).gamma is not None:  # pragma: no cover - default config is linear
        pytest.skip("gamma-space PRT has no GLSL basis sum")
    grid = bake_grid(s)
    lights = [{"type": "point", "position": [0.5, 0.6, 0.5], "intensity": 2.0, "color": [1.0, 0.8, 0.6]}]
    caster = RayCaster(scene.triangles)
    want_vol = relight(arrays, lights, caster, lightmap=False)
    rng = np.random.default_rng(5)
    p, n = _points(64 * 16, rng, {"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]})
    if sh_order is None:
        want = np.maximum(SM.leaking_l2(p, n, want_vol["sh_l2"], grid), 0)
    else:
        want = SM.leaking(p, n, want_vol["sh_l1_r"], want_vol["sh_l1_g"], want_vol["sh_l1_b"], grid)
    res = _prt_resources(arrays, grid, lights, caster, sh_order=sh_order)
    assert res.info["coefficients"] == (9 if sh_order is None else 4)
    r = ShadingRenderer(ctx)
    try:
        r.set_mode(res)
        r.set_gbuffer(GBufferInputs(_as_image(p), _as_image(n), np.zeros((16, 64, 3)), np.zeros((16, 64, 3)),
                                    np.ones((16, 64), bool)))
        got = r.render("prt", output=1).reshape(-1, 3)
    finally:
        r.release()
    scale = np.abs(want).max()
    assert scale > 0 and np.abs(got - want).max() <= F16 * scale, np.abs(got - want).max() / scale


def test_time_passes_interleaves_modes(ctx, two_rooms):
    """time_passes times every mode the same number of rounds (side by side) and leaves the output alone."""
    scene, s = two_rooms
    arrays, grid = bake_arrays(s), bake_grid(s)
    rng = np.random.default_rng(11)
    p, n = _points(32 * 16, rng, TWO_ROOMS_BOX)
    r = ShadingRenderer(ctx)
    try:
        for m in ("direct", "leaking"):
            r.set_mode(prepare_mode(m, arrays, grid))
        r.set_gbuffer(GBufferInputs(_as_image(p, 32), _as_image(n, 32), np.zeros((16, 32, 3)),
                                    np.zeros((16, 32, 3)), np.ones((16, 32), bool)))
        before = r.render("leaking", output=1)
        t = r.time_passes(["direct", "leaking"], repeats=3)
        assert set(t) == {"direct", "leaking"}
        for v in t.values():
            assert v["repeats"] == 3 and 0 < v["min_s"] <= v["median_s"]
        assert np.array_equal(r.render("leaking", output=1), before)
    finally:
        r.release()


def _synthetic_bake(K=5, l2=True, counts=(3, 2, 2)):
    """Artifacts of every mode by name, random but of the stored shapes and dtypes (no bake needed)."""
    nx, ny, nz = counts
    P = nx * ny * nz
    rng = np.random.default_rng(0)
    vol = lambda d=4: rng.random((nz, ny, nx, d)).astype(np.float32)  # noqa: E731
    a = {f"sh_l1_{c}": vol() for c in "rgb"}
    a.update({"probe_positions_relocated": rng.random((P, 3)).astype(np.float32),
              "probe_states": np.array([0] + [1] * (P - 1), np.uint8),
              "irradiance": rng.random((ny * 8, nz * nx * 8, 4)).astype(np.float32),
              "depth_moments": rng.random((ny * 16, nz * nx * 16, 2)).astype(np.float32),
              "mask_indirection": rng.integers(0, 255, (4, 1, 2, 4)).astype(np.uint8),
              "mask_atlas": rng.integers(0, 255, (4, 4, 8, 1)).astype(np.uint8),
              "cluster_weights_0123": vol(), "cluster_weights_4567": vol()})
    for k in range(K):
        a.update({f"cluster_sh_{k}_{c}": vol() for c in "rgb"})
        if l2:
            a[f"cluster_sh_l2_{k}"] = rng.random((7 * (nz + 2), ny, nx, 4)).astype(np.float32)
    if l2:
        a["sh_l2"] = rng.random((7 * (nz + 2), ny, nx, 4)).astype(np.float32)
    basis = [[f"prt_sh_basis_c{k}_g0"] for k in range(9 if l2 else 4)]
    a.update({n: vol() for row in basis for n in row})
    return a, basis


@pytest.mark.parametrize("l2", [True, False])
@pytest.mark.parametrize("K", [2, 5])
def test_prepare_mode_binds_what_the_mode_table_says(l2, K):
    """proto/gi_modes.json is the contract: prepare_mode binds exactly its textures (with its filters), sets exactly
    its uniforms and defines (web/tests/parity.test.js checks the viewer's side against the same file)."""
    from types import SimpleNamespace

    from proto import gi_modes

    arrays, basis = _synthetic_bake(K, l2)
    grid = {"counts": [3, 2, 2], "origin": [0.0, 0.0, 0.0], "spacing": [0.5, 0.25, 1.0]}
    meta = {"samples_per_cell": 2, "block_size": 2, "border_lo": 0}
    model = SimpleNamespace(channels="mono", gamma=None, section={"sh": {"basis": basis}})
    for mode in gi_modes.MODE_IDS:
        spec = gi_modes.MODES[mode]
        res = prepare_mode(mode, arrays, grid, mask_meta=meta, prt_model=model,
                           prt_coefficients=np.ones((4, 3), np.float32))
        order = res.info.get("sh_order", 1)
        want = gi_modes.texture_bindings(mode, arrays, order, basis)
        assert list(res.textures) == list(want), mode
        for u, (_, kind) in want.items():
            assert res.textures[u][1] == (gi_modes.KINDS[kind]["filter"] == "linear"), (mode, u)
            assert res.textures[u][0].ndim == 1 + gi_modes.KINDS[kind]["dims"], (mode, u)
        assert set(res.uniforms) == set(gi_modes.GRID_UNIFORMS) | set(spec["uniforms"]), mode
        assert res.defines == gi_modes.mode_defines(mode, order, K), mode
        if mode in ("leaking", "mask", "mask_normalized", "prt"):
            assert order == (2 if l2 else 1), mode


def test_ddgi_bias_is_the_bakes_b():
    """uDdgiBias = 0.75 · D · B of DDGI-P eq 2 with B the bake's light.self_shadow_bias (the viewer's uniform for the
    same bake: tests/web/test_viewer.py test_viewer_ddgi_bias_is_the_bakes)."""
    arrays, _ = _synthetic_bake()
    grid = {"counts": [3, 2, 2], "origin": [0.0, 0.0, 0.0], "spacing": [0.5, 0.25, 1.0]}
    for B in (0.3, 0.8, 0.0):
        assert prepare_mode("ddgi", arrays, grid, self_shadow_bias=B).uniforms["uDdgiBias"] == pytest.approx(
            0.75 * 0.25 * B)
    assert prepare_mode("ddgi", arrays, grid).uniforms["uDdgiBias"] == pytest.approx(0.75 * 0.25 * 0.3)
