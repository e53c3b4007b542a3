"""Stages anneal, masks and clusters (Mask Decomposition) on the procedural scenes, through the real pipeline
up to visibility, then the stage functions with a hand-built context."""
from __future__ import annotations

import numpy as np
import pytest

from proto.bundle import load_artifact
from proto.models import BakeConfig
from workers.kernels import samplers as SM
from workers.kernels.coloring import edge_loss
from workers.kernels.grid import OFF
from workers.kernels.mask_field import field_fractions, join_theta
from workers.kernels.sh import sh_l2_atlas
from workers.stages.anneal import run_anneal
from workers.stages.base import LazyArtifacts, StageContext, StageOutput
from workers.stages.clusters import run_clusters
from workers.stages.masks import run_masks

from tests.workers.test_probes import bake_until

TWO_ROOMS_BOX = {"min": [0.2, 0.2, 0.2], "max": [7.85, 2.8, 3.8]}
# sealed-box: the closed box is [-0.5, 0.5] x [0, 1] x [-0.5, 0.5] with 5 cm walls. Probes every 0.75 m
# in x and z and 0.55 m in y: (0, 0.1, 0) and (0, 0.65, 0) lie in the cavity, their neighbours at
# x or z = ±0.75 outside, so every cell around the cavity straddles a wall.
SEALED_BOX = {"min": [-1.5, 0.1, -1.5], "max": [1.5, 1.2, 1.5]}


def _bake(tmp_path, scene_path, cfg):
    scene, s = bake_until(tmp_path, scene_path, cfg, "visibility")
    return scene, s


def _ctx(scene, s, cfg) -> StageContext:
    return StageContext(config=BakeConfig.model_validate(cfg), scene_loader=lambda: scene, inputs=s,
                        report=lambda f: None)


def _lazy(out) -> LazyArtifacts:
    return LazyArtifacts(out.stats, {a.name: (lambda a=a: a.data) for a in out.artifacts})


def _md(scene, s, cfg, parts: bool = False):
    """Run anneal, masks and clusters on the baked inputs; returns (anneal output, the masks' and the clusters'
    outputs as one: their artifacts and stats together) — with ``parts`` also the two apart."""
    a = run_anneal(_ctx(scene, s, cfg))
    inputs = {**s, "anneal": _lazy(a)}
    light = inputs.pop("light")                 # the masks read no light (without the light-aware fit)
    m = run_masks(_ctx(scene, {**inputs, "light": light} if cfg["masks"].get("light_aware") else inputs, cfg))
    c = run_clusters(_ctx(scene, {**inputs, "light": light}, cfg))
    both = StageOutput(artifacts=m.artifacts + c.artifacts, stats={**m.stats, **c.stats})
    return (a, both, m, c) if parts else (a, both)


def _arrays(s, m) -> dict:
    arrays = {a.name: a.data for a in m.artifacts}
    for n in ("sh_l1_r", "sh_l1_g", "sh_l1_b", "sh_l2"):      # sh_l2: the references shade L2 like the masks
        arrays[n] = s["light"][n]
    for n in ("theta_0123", "theta_4567", "dont_care"):
        arrays[n] = s["visibility"][n]
    return arrays


def _two_rooms_cfg(S, **masks):
    return {"place": {"counts": [9, 4, 5], "box": TWO_ROOMS_BOX}, "trace": {"rays_per_probe": 128},
            "light": {"bounces": 2}, "visibility": {"samples_per_cell": S}, "masks": {"clusters": 4, **masks}}


@pytest.mark.parametrize("S", [4, 8])
def test_two_rooms_annealing_beats_random_and_is_seeded(tmp_path, scene_files, S):
    cfg = _two_rooms_cfg(S)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    a = run_anneal(_ctx(scene, s, cfg))
    st = a.stats
    loss = next(x.data for x in a.artifacts if x.name == "anneal_loss")
    g = next(x.data for x in a.artifacts if x.name == "clusters").reshape(-1)
    assert loss.shape == (1001,) and loss.dtype == np.float32          # a float32 KTX2 table (R32_SFLOAT)
    assert st["final_loss"] <= st["initial_loss"] == pytest.approx(loss[0], rel=1e-6)
    assert st["final_loss"] == pytest.approx(loss.min(), rel=1e-6)
    assert st["final_edge_loss"] <= 0.05 * st["random_loss"]          # eq 7: at most 5% of random
    assert st["random_loss"] > 0 and st["edges"] > 0
    # probes sharing a cell across the wall (relocated to opposite sides, away from the door) see
    # different samples: every such pair gets two colours
    states = s["trace"]["probe_states"].reshape(-1)
    pos = s["relocate"]["probe_positions_relocated"].reshape(-1, 3)
    theta = join_theta(s["visibility"]["theta_0123"], s["visibility"]["theta_4567"])
    pairs, w = edge_loss(theta, s["visibility"]["dont_care"], [9, 4, 5], S, states)
    pi, pj = pos[pairs[:, 0]], pos[pairs[:, 1]]
    across = ((pi[:, 0] < 4.0) & (pj[:, 0] > 4.05)) | ((pj[:, 0] < 4.0) & (pi[:, 0] > 4.05))
    away = (np.maximum(pi[:, 2], pj[:, 2]) < 1.5) | (np.minimum(pi[:, 2], pj[:, 2]) > 2.5)
    wall = across & away
    assert wall.sum() >= 10 and np.all(w[wall] > 1.0)
    assert np.all(g[pairs[wall, 0]] != g[pairs[wall, 1]])
    # the same seed gives the same colouring; another seed runs its own chain and still meets the bound
    again = run_anneal(_ctx(scene, s, cfg))
    assert np.array_equal(next(x.data for x in again.artifacts if x.name == "clusters").reshape(-1), g)
    other = run_anneal(_ctx(scene, s, {**cfg, "seed": 5}))
    other_loss = next(x.data for x in other.artifacts if x.name == "anneal_loss")
    assert not np.array_equal(other_loss, loss)
    assert other.stats["final_edge_loss"] <= 0.05 * other.stats["random_loss"]


@pytest.mark.parametrize("K", [3, 6])
def test_stage_outputs_layout(tmp_path, scene_files, K):
    cfg = _two_rooms_cfg(4, clusters=K, sweeps=200)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    a, m, masks, clusters = _md(scene, s, cfg, parts=True)
    arts = {x.name: x for x in a.artifacts + m.artifacts}
    assert {x.name for x in masks.artifacts} == {"masks_0123"} | ({"masks_4567"} if K > 4 else set())
    assert not {x.name for x in clusters.artifacts} & {x.name for x in masks.artifacts}
    nx, ny, nz = 9, 4, 5
    Z, Y, X = s["visibility"]["theta_0123"].shape[:3]
    assert arts["clusters"].data.shape == (nz, ny, nx, 1) and arts["clusters"].data.dtype == np.uint8
    assert arts["clusters"].data.max() < K
    assert arts["anneal_loss"].format == "ktx2" and arts["anneal_loss"].table
    assert arts["anneal_loss"].data.shape == (201,)
    want = {"masks_0123", "cluster_weights_0123"} | {f"cluster_sh_{k}_{c}" for k in range(K) for c in "rgb"}
    want |= {f"cluster_sh_l2_{k}" for k in range(K)}                 # light.sh_order 2 (the default): L2 too
    if K > 4:
        want |= {"masks_4567", "cluster_weights_4567"}
    assert {x.name for x in m.artifacts} == want
    assert arts["masks_0123"].data.shape == (Z, Y, X, 4) and arts["masks_0123"].data.dtype == np.uint8
    assert arts["masks_0123"].zstd_level == 3
    q = np.concatenate([arts[n].data for n in ("masks_0123", "masks_4567") if n in arts], axis=3)
    assert np.all(q[..., K:] == 0)                                    # unused channels 0
    w = np.concatenate([arts[n].data for n in ("cluster_weights_0123", "cluster_weights_4567") if n in arts], 3)
    on = (s["trace"]["probe_states"][..., 0] != OFF)
    assert np.array_equal(w.sum(axis=3), on.astype(np.float32)) and np.all(w[..., K:] == 0)
    g = arts["clusters"].data[..., 0]
    assert np.array_equal(np.argmax(w, axis=3)[on], g[on])
    for i, c in enumerate("rgb"):     # from the light stage's float32 L1 (the bundle's sh_l1_* are RGBA16F)
        total = sum(arts[f"cluster_sh_{k}_{c}"].data for k in range(K))
        assert total.shape == (nz, ny, nx, 4) and total.dtype == np.float16            # RGBA16F (issue 17)
        assert arts[f"cluster_sh_0_{c}"].zstd_level == 9      # workers/stages/clusters.py ZSTD_PROBES
        assert np.array_equal(total, np.where(on[..., None], s["light"]["sh_l1_full"][..., i], 0).astype(np.float16))
    # the L2 cluster volumes (sh_l2 layout) partition the probes' 9 coefficients the same way
    from workers.kernels.sh import sh_l2_atlas_depth, sh_l2_from_atlas

    l2 = [arts[f"cluster_sh_l2_{k}"].data for k in range(K)]
    assert all(v.shape == (sh_l2_atlas_depth(nz), ny, nx, 4) and v.dtype == np.float16 for v in l2)
    total2 = sum(sh_l2_from_atlas(v) for v in l2)
    assert np.array_equal(total2, np.where(on[..., None, None], s["light"]["probe_sh"], 0).astype(np.float16))
    assert m.stats["half_clamped"] == 0 and w.dtype == np.float16
    assert np.array_equal(total2[..., :4, :], np.stack([total_c for total_c in
                          (sum(arts[f"cluster_sh_{k}_{c}"].data for k in range(K)) for c in "rgb")], -1))
    # every artifact goes through the bundle format and back unchanged
    for x in a.artifacts + m.artifacts:
        info = x.write(tmp_path / "bundle", "md")
        assert np.array_equal(load_artifact(tmp_path / "bundle" / info.file, info), x.data)


@pytest.mark.parametrize("scene_name", ["two-rooms", "sealed-box"])
def test_parity_masks_reproduce_visibility_weighting(tmp_path, scene_files, scene_name):
    """MD §3.2: K = 8, parity colouring (eq 4), masks from θ (no filter, no light-aware fit): R̂ = 0, the
    stored mask bytes are the θ bytes, and mask GI equals visibility-weighted GI at every care sample."""
    masks = {"clusters": 8, "coloring": "parity", "sigma": 0.0, "light_aware": False}
    if scene_name == "two-rooms":
        cfg = _two_rooms_cfg(4, **masks)
    else:
        cfg = {"place": {"counts": [5, 3, 5], "box": SEALED_BOX}, "trace": {"rays_per_probe": 128},
               "light": {"bounces": 1}, "visibility": {"samples_per_cell": 8}, "masks": masks}
    scene, s = _bake(tmp_path, scene_files[scene_name], cfg)
    a, m = _md(scene, s, cfg)
    assert a.stats["coloring"] == "parity" and a.stats["sweeps"] == 0
    assert m.stats["residual_eq5"] == 0.0 and m.stats["residual_stored"] == 0.0    # eq 5, exactly
    arrays = _arrays(s, m)
    grid = s["place"].stats
    counts = np.asarray(grid["counts"])
    S = cfg["visibility"]["samples_per_cell"]
    dc = arrays["dont_care"][..., 0].astype(bool)
    if scene_name == "sealed-box":
        assert dc.any()                                                   # the walls hold samples
    # bytes: channel k of a sample in a cell whose base corner has parity b is θ of corner k ^ b
    theta = join_theta(arrays["theta_0123"], arrays["theta_4567"])
    q = np.concatenate([arrays["masks_0123"], arrays["masks_4567"]], axis=3)
    cx, cy, cz, *_ = field_fractions(counts, S)
    b = (cx[None, None, :] & 1) | ((cy[None, :, None] & 1) << 1) | ((cz[:, None, None] & 1) << 2)
    for k in range(8):
        th = np.take_along_axis(theta, (k ^ b)[..., None], axis=3)[..., 0]
        assert np.array_equal(q[..., k][~dc], th[~dc])
    # samplers at every care sample (texel centres: trilinear returns the texel, so no 1/255 rounding
    # enters: both read the same bytes; the rest is float64 summation order)
    z, y, x = np.nonzero(~dc)
    pts = np.asarray(grid["origin"]) + np.asarray(grid["spacing"]) * (np.stack([x, y, z], 1) + 0.5) / S
    rng = np.random.default_rng(0)
    n = rng.normal(size=pts.shape)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # (masks read at the point itself: the runtime's normal offset moves the lookup off the sample)
    # (and with the linear L1 SH evaluation: the non-linear one is not additive; visibility_weighted is L1)
    # (the cluster volumes hold, as half floats (RGBA16F), the float32 SH the masks stage read: eq 2 of the same
    # half-rounded SH; OFF probes have θ = 0)
    arrays = {**dict(arrays), **{f"sh_l1_{c}": s["light"]["sh_l1_full"][..., i].astype(np.float16)
                                 for i, c in enumerate("rgb")},
              "sh_l2": sh_l2_atlas(np.asarray(s["light"]["probe_sh"], np.float32)).astype(np.float16)}
    ref = SM.irradiance("visibility_weighted", arrays, grid, pts, n, linear=True, sh_order=1)
    got = SM.irradiance("mask_normalized", arrays, grid, pts, n, mask_offset_samples=0, linear=True, sh_order=1)
    assert np.abs(ref).max() > 0.01
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-12)
    ref_un = SM.visibility_weighted(pts, n, arrays["sh_l1_r"], arrays["sh_l1_g"], arrays["sh_l1_b"],
                                    arrays["theta_0123"], arrays["theta_4567"], grid, normalize=False, linear=True)
    assert np.allclose(SM.irradiance("mask", arrays, grid, pts, n, mask_offset_samples=0, linear=True, sh_order=1),
                       ref_un, rtol=1e-9, atol=1e-12)
    # and with L2 (the default; linear, so additive): cluster_sh_l2 against the probes' sh_l2
    ref2 = SM.irradiance("visibility_weighted", arrays, grid, pts, n, sh_order=2)
    got2 = SM.irradiance("mask_normalized", arrays, grid, pts, n, mask_offset_samples=0)
    assert np.allclose(got2, ref2, rtol=1e-6, atol=1e-9 * np.abs(ref2).max())


def _six_normals(n):
    return np.repeat(np.concatenate([np.eye(3), -np.eye(3)]), -(-n // 6), axis=0)[:n]


def test_sealed_box_mask_gi_does_not_leak(tmp_path, scene_files):
    # light.bounces = 1: the cavity probes are then exactly dark. (With more bounces the light stage's
    # DDGI-weighted indirect at the cavity's inner walls picks up the lit probes outside, 5 cm away
    # through the wall, and the cavity probes themselves are lit; that is the light stage's leak.)
    cfg = {"place": {"counts": [5, 3, 5], "box": SEALED_BOX}, "trace": {"rays_per_probe": 128},
           "light": {"bounces": 1}, "visibility": {"samples_per_cell": 8}, "masks": {"clusters": 4}}
    scene, s = _bake(tmp_path, scene_files["sealed-box"], cfg)
    a, m = _md(scene, s, cfg)
    g = a.artifacts[0].data.reshape(5, 3, 5)                           # (nz, ny, nx)
    cavity = {int(g[2, 0, 2]), int(g[2, 1, 2])}                          # the two probes in the cavity
    around = {int(g[k, j, i]) for k in (1, 2, 3) for j in (0, 1, 2) for i in (1, 2, 3)
              if not (i == 2 and k == 2 and j < 2)}                      # every probe sharing a cell with them
    assert len(cavity) == 1 and not cavity & around                      # the annealing isolates the cavity
    arrays = _arrays(s, m)
    grid = s["place"].stats
    rng = np.random.default_rng(1)
    # at least one refined-grid sample (9.4 cm) away from the 5 cm walls' inner faces
    inside = rng.uniform([-0.35, 0.15, -0.35], [0.35, 0.85, 0.35], (3000, 3))
    out = rng.uniform([-1.5, 0.1, -1.5], [1.5, 1.2, 1.5], (6000, 3))
    out = out[np.any(np.abs(out - [0, 0.5, 0]) > 0.65, axis=1)][:3000]
    e = {}
    for mode in SM.MODES:
        e[mode] = (SM.irradiance(mode, arrays, grid, inside, _six_normals(len(inside))).mean(),
                   SM.irradiance(mode, arrays, grid, out, _six_normals(len(out))).mean())
    e_out = e["visibility_weighted"][1]
    assert e_out > 0.1
    assert e["leaking"][0] > 0.2 * e["leaking"][1]                      # trilinear leaks the outside in
    for mode in ("mask", "mask_normalized", "visibility_weighted"):
        assert e[mode][0] <= 0.01 * e[mode][1], (mode, e[mode])         # ≤ 1% of outside
    assert e["mask_normalized"][1] == pytest.approx(e_out, rel=0.02)    # outside: the same light


def _near_wall_points(n, seed=0):
    """Room B within 0.8 m of the shared wall (x = 4.05), away from the door (z in [1.55, 2.45])."""
    rng = np.random.default_rng(seed)
    return rng.uniform([4.1, 0.3, 0.3], [4.8, 2.7, 1.2], (n, 3))


def test_two_rooms_wall_mask_gi_matches_visibility_weighting(tmp_path, scene_files):
    cfg = _two_rooms_cfg(8)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    _, m = _md(scene, s, cfg)
    arrays = _arrays(s, m)
    grid = s["place"].stats
    pts = _near_wall_points(3000)
    n = _six_normals(len(pts))
    ref = SM.irradiance("visibility_weighted", arrays, grid, pts, n)
    # free-space points with normals along ± each axis (not surfaces): masks read at the point; the
    # runtime's normal offset is for surface points (next test)
    err = {mode: np.abs(SM.irradiance(mode, arrays, grid, pts, n, mask_offset_samples=0) - ref).mean()
           for mode in SM.MODES}
    scale = ref.mean()
    assert scale > 0.1
    assert err["leaking"] > 1.0 * scale                      # room A's light through the wall
    assert err["mask_normalized"] < 0.02 * scale
    assert err["mask"] < 0.8 * scale                         # eq 3 is darker (MD Fig 4), but no leak
    assert SM.irradiance("mask", arrays, grid, pts, n).mean() <= 1.02 * scale


def test_two_rooms_mask_gi_on_the_thin_wall_surface_does_not_leak(tmp_path, scene_files):
    """Surface points on both faces of the 5 cm shared wall (x = 4.0 in lit room A, x = 4.05 in room B),
    normals into their room. Refined samples inside the wall are don't-care (every channel 1), so masks
    read *at* the surface weight the far room's clusters by about ½; the runtime reads them one refined
    sample along the normal, clamped to the point's cell (samplers module doc)."""
    cfg = _two_rooms_cfg(8)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    _, m = _md(scene, s, cfg)
    arrays = _arrays(s, m)
    grid = s["place"].stats
    rng = np.random.default_rng(0)
    for face, sign in ((4.05, 1.0), (4.0, -1.0)):
        N = 2000
        p = np.stack([np.full(N, face + 1e-4 * sign), rng.uniform(0.3, 2.7, N), rng.uniform(0.3, 1.3, N)], 1)
        n = np.tile([sign, 0.0, 0.0], (N, 1))
        ref = SM.irradiance("visibility_weighted", arrays, grid, p + 0.01 * n, n)     # 1 cm in front
        leak = SM.irradiance("leaking", arrays, grid, p, n).mean()
        off = np.abs(SM.irradiance("mask_normalized", arrays, grid, p, n) - ref).mean()
        if sign > 0:                                  # room B: dark but for the light through the door
            assert ref.mean() < 0.1 * leak
            assert off < 0.01 * leak, (off, leak)
        else:                                         # room A: lit
            assert off < 0.01 * ref.mean(), (off, ref.mean())
        assert SM.irradiance("mask", arrays, grid, p, n).mean() <= 1.02 * ref.mean() + 1e-3
    # a vertical line on room B's face across the cell face y = 1.067: a cluster free in the cell below must not
    # bleed into the cell above, where it is present but masked out (with free values 255: a bright line)
    y = np.linspace(0.6, 1.6, 201)
    p = np.stack([np.full_like(y, 4.0501), y, np.full_like(y, 0.8)], 1)
    n = np.tile([1.0, 0.0, 0.0], (len(y), 1))
    e = SM.irradiance("mask_normalized", arrays, grid, p, n)[:, 0]
    ref = SM.irradiance("visibility_weighted", arrays, grid, p + 0.01 * n, n)[:, 0]
    assert np.abs(e - ref).max() < 0.1 * leak, (np.abs(e - ref).max(), leak)


def test_mask_lookup_offsets_within_the_own_cell():
    from workers.kernels.compress import mask_lookup_texel

    grid = {"counts": [3, 3, 1], "origin": [0.0, 0.0, 0.0], "spacing": [1.0, 0.5, 0.0]}
    S = 4
    p = np.array([[0.2, 0.2, 0.0], [0.95, 0.1, 0.0], [1.0, 0.5, 0.0], [0.5, 0.6, 7.0]])
    d = np.array([[1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 1.0]])
    args = (grid["counts"], grid["origin"], grid["spacing"], S)
    t0, cell = mask_lookup_texel(p, *args, dtype=np.float64)
    # own cells (z: the one-probe axis, its middle); texel coordinate g·S − 0.5 clamped to [c·S, c·S + 3]
    assert np.array_equal(cell, [[0, 0, 0], [0, 0, 0], [1, 1, 0], [0, 1, 0]])
    # the second point (3.3) stops at its cell's last sample, the third (on the faces, cell (1, 1)) at its first
    assert np.allclose(t0, [[0.3, 1.1, 1.5], [3.0, 0.3, 1.5], [4.0, 4.0, 1.5], [1.5, 4.3, 1.5]])
    t, cell2 = mask_lookup_texel(p, *args, d, 1.0, dtype=np.float64)
    assert np.array_equal(cell2, cell)                  # the cell is the point's, not the lookup point's
    # one sample per unit of d on each live axis, whatever the spacing (x 0.25 m, y 0.125 m); z is not live;
    # the third point's lookup moves into cell 0 and is clamped back to cell 1's first sample
    assert np.allclose(t, [[1.3, 1.1, 1.5], [3.0, 0.3, 1.5], [4.0, 4.0, 1.5], [1.5, 5.3, 1.5]])


def test_two_rooms_mask_gi_at_a_corner_reads_the_camera_side(tmp_path, scene_files):
    """The former default grid, 8x8x8 over the bounds (probes on the outer walls, 1.16 m apart in x; S = 4): a point on room B's side wall
    (z = 0) next to the shared wall (x = 4.05) has the shared wall and room A's samples inside its footprint
    along x, which its normal (+z) does not move away from; the view term of the lookup (a camera in room
    B) does, and the corner reads as the wall further along."""
    cfg = {"place": {"counts": [8, 8, 8]}, "visibility": {"samples_per_cell": 4}, "masks": {"clusters": 4}}
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    _, m = _md(scene, s, cfg)
    arrays = _arrays(s, m)
    grid = s["place"].stats
    x = np.array([4.0505, 4.06, 4.08, 4.1, 4.12])
    p = np.stack([x, np.full_like(x, 1.5), np.full_like(x, 1e-4)], 1)
    far = np.array([[4.4, 1.5, 1e-4]])
    n = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    eye = np.array([7.8, 1.5, 3.8])                                         # room B's far corner
    view = lambda q: (eye - q) / np.linalg.norm(eye - q, axis=1, keepdims=True)  # noqa: E731
    e = SM.irradiance("mask_normalized", arrays, grid, p, n, views=view(p))[:, 0]
    e_far = SM.irradiance("mask_normalized", arrays, grid, far, n[:1], views=view(far))[0, 0]
    e_normal_only = SM.irradiance("mask_normalized", arrays, grid, p, n)[:, 0]
    assert e_far > 0
    np.testing.assert_allclose(e, e_far, rtol=0.05)
    assert e_normal_only[0] > 2 * e_far                                      # the corner line without v


def test_free_mask_channels_are_zero(tmp_path, scene_files):
    """A cluster with no (non-OFF) probe among a cell's corners has mask 0 at every sample of that cell, so
    the shader's m_k > 0 test alone picks the clusters to sample (MD §1; mask_fit.canonicalize)."""
    cfg = _two_rooms_cfg(4)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    a, m = _md(scene, s, cfg)
    arrays = _arrays(s, m)
    nx, ny, nz = 9, 4, 5
    S, K = 4, 4
    g = next(x.data for x in a.artifacts if x.name == "clusters").reshape(nz, ny, nx)
    on = np.asarray(s["trace"]["probe_states"]).reshape(nz, ny, nx) != OFF
    q = arrays["masks_0123"]
    free_cells = 0
    for k in range(nz - 1):
        for j in range(ny - 1):
            for i in range(nx - 1):
                corner = (slice(k, k + 2), slice(j, j + 2), slice(i, i + 2))
                present = set(g[corner][on[corner]].tolist())
                block = q[k * S:(k + 1) * S, j * S:(j + 1) * S, i * S:(i + 1) * S]
                for c in range(K):
                    if c not in present:
                        free_cells += 1
                        assert np.all(block[..., c] == 0), (k, j, i, c)
    assert free_cells > 0


def test_light_aware_fit_brings_mask_gi_closer(tmp_path, scene_files):
    cfg = _two_rooms_cfg(8)
    scene, s = _bake(tmp_path, scene_files["two-rooms"], cfg)
    a = run_anneal(_ctx(scene, s, cfg))
    inputs = {**s, "anneal": _lazy(a)}
    clusters = run_clusters(_ctx(scene, inputs, cfg)).artifacts               # the probes' side: the same for both
    plain = run_masks(_ctx(scene, {k: v for k, v in inputs.items() if k != "light"}, cfg))
    fitted = run_masks(_ctx(scene, inputs, _two_rooms_cfg(8, light_aware=True)))
    plain = StageOutput(artifacts=plain.artifacts + clusters, stats=plain.stats)
    fitted = StageOutput(artifacts=fitted.artifacts + clusters, stats=fitted.stats)
    la = fitted.stats["light_aware"]
    assert plain.stats["light_aware"] is None
    assert la["loss_after"] < 0.5 * la["loss_before"]
    grid = s["place"].stats
    pts = _near_wall_points(3000, seed=1)
    n = _six_normals(len(pts))
    ref = SM.irradiance("visibility_weighted", _arrays(s, plain), grid, pts, n)
    e_plain = np.abs(SM.irradiance("mask", _arrays(s, plain), grid, pts, n) - ref).mean()
    e_fit = np.abs(SM.irradiance("mask", _arrays(s, fitted), grid, pts, n) - ref).mean()
    assert e_fit < 0.7 * e_plain                              # eq 9 targets eq 3 (unnormalized)
