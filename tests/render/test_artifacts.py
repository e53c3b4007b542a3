"""The artifacts users reported (issue "Artist UX" item 6), each measured numerically on the region that was wrong.

Each test renders (or samples) the mode the artifact was seen in, with the headless renderer (workers/render:
G-buffer + the proto/glsl mode, the viewer's shaders) where the artifact is a picture, and puts a number on the
wrong region. Where the cause is the method itself, or its fix lies in a stage this file's owner does not edit,
the test is marked ``xfail(strict=True)`` with plain assertions: it states the measured number, the cause and the
fix, and it fails the suite (XPASS, strict) the day the artifact goes away without the marker being removed, so the
number stays watched either way.

Measured at HEAD 6a4925b (numbers in each test's docstring; llvmpipe, this 2-core machine):

1. normalized-mask speckle at the grid edge: not reproducible (0.0008 of the edge pixels: one), guarded.
2. Cornell short-block seam (mask modes): reproduced, L2 SH ringing of the block's front probes; fixed (L2 kept
   above 0.75 of each probe's own map, workers/kernels/sh.py sh_l2_floor), tested.
3. DDGI blotches at 8³ / 256 rays: reproduced, Monte Carlo noise of the probe rays (the point light's spot on
   the panel); fixed (the spot sampled from the light, workers/kernels/light_spots.py), tested.
4. plain mask GI halo around a doorway: reproduced at coarse grids; re-measured, the ring is right and the wall
   away from the door dark (eq 3 unnormalized, where the grid straddles the wall), xfail at 11 x 6 x 7; at the
   default automatic grid 1.05 (tested): the report's case is fixed by the defaults.
5. PRT hotspot / near-black walls: reproduced, the linear transfer's generalization; improved (lights near
   surfaces in the scenario, L1 direct norm, cross-validated ridge: near-black 0.050 -> 0.007, relative RMS
   0.55 -> 0.37), still xfail on the RMS (0.3; the 16-slot basis's own projection is 0.33-0.36 there).
   Re-measured at 167a145: 0.0007 and 0.53 (projection 0.52) since the rescue relocation put the wall layers'
   probes 3 cm off the walls, next to the light; no basis size, dataset size, norm, ridge or reconstruction
   tried reaches 0.3 (table in the test). The reported symptoms are tested on their own numbers and pass
   (near-black 0.0007, brightest direction 0.59 of the reference's, 2.1% of lit directions over 2x; before the
   fixes 0.039 / 0.31 / 16.6%); the RMS stays a strict xfail.
6. found on the way: DDGI rendered 0 on grids whose atlas is wider than GL_MAX_TEXTURE_SIZE: fixed, tested.
"""
from __future__ import annotations

import numpy as np
import pytest

from workers.render.cameras import Camera, fit_clip_planes

from tests.render.conftest import bake_arrays, bake_grid, mask_meta
from tests.workers.test_probes import bake_until


def _render(ctx, scene, s, cam: Camera, modes):
    """G-buffer of ``cam`` and each mode's E_indirect (output 1) through the mode's GLSL: (gbuffer, {mode: (H, W, 3)})."""
    from workers.render.gbuffer import GBufferRenderer
    from workers.render.shading import GBufferInputs, ShadingRenderer, prepare_mode

    arrays, grid = bake_arrays(s), bake_grid(s)
    gr = GBufferRenderer(scene, ctx)
    sh = ShadingRenderer(ctx)
    try:
        gb = gr.render(fit_clip_planes(cam, bounds=np.asarray(scene.bounds)))
        for m in modes:
            kw = {"mask_meta": mask_meta(s)} if m.startswith("mask") else {}
            sh.set_mode(prepare_mode(m, arrays, grid, **kw))
        sh.set_gbuffer(GBufferInputs.from_gbuffer(gb))
        return gb, {m: sh.render(m, 1, cam.position).astype(np.float64) for m in modes}
    finally:
        sh.release()
        gr.release()


# --------------------------------------------------------------------------------------------- 1. grid-edge speckle
EDGE_CFG = {"place": {"counts": [6, 4, 6], "box": {"min": [-1.5, -0.002, -1.5], "max": [1.5, 1.5, 1.5]}},
            "trace": {"rays_per_probe": 128}, "light": {"bounces": 2},
            "visibility": {"samples_per_cell": 8, "slabs": 1}, "masks": {"sweeps": 200}}


def test_normalized_mask_no_speckle_at_the_grid_edge(ctx, tmp_path, scene_files):
    """Artifact 1: salt-and-pepper speckle of normalized mask GI where the probes end before the geometry.

    sealed-box, a 6 x 4 x 6 grid over [-1.5, 1.5]² of its 10 x 10 m floor (the floor runs 3.5 m past the grid on
    every side; the bottom layer 2 mm under the floor). Region: the shaded pixels within one cell of the grid box's
    x/z faces or outside it. Number: the fraction of them whose E differs from its 3x3 neighbourhood's median by more
    than 25% (speckle is isolated pixels; smooth gradients and edges of 3+ pixels do not count).
    Measured: 0.0008 (one pixel; leaking and ddgi flag as many on the same view), also 0.0 on two-rooms with the grid
    ending in room B; no pixel has Σ m_k w_k < 0.3: not reproducible since the own-cell mask lookup and the zero free channels (compress/masks).
    A real-but-different failure found on the way: with the bottom layer exactly on the floor (box min y = 0) the
    floor outside the box reads 0 in leaking and both mask modes (the layer's probes are OFF and the texel clamps to
    that layer; E = 0, not speckle); the automatic grid fits layers between faces, so it does not place one there.
    """
    from scipy.ndimage import median_filter

    scene, s = bake_until(tmp_path, scene_files["sealed-box"], EDGE_CFG, "compress")
    cam = Camera(position=(3.5, 3.0, 3.5), target=(0.0, 0.3, 0.0), fov_y=70, width=96, height=72)
    gb, out = _render(ctx, scene, s, cam, ["mask_normalized"])
    g = bake_grid(s)
    lo = np.asarray(g["origin"])
    hi = lo + np.asarray(g["spacing"]) * (np.asarray(g["counts"]) - 1)
    sp = np.asarray(g["spacing"])
    p = gb.position.astype(np.float64)
    inner = np.all((p[..., [0, 2]] > lo[[0, 2]] + sp[[0, 2]]) & (p[..., [0, 2]] < hi[[0, 2]] - sp[[0, 2]]), axis=-1)
    v = out["mask_normalized"].mean(-1)
    sel = gb.shaded
    # pixels whose 3x3 neighbourhood is one flat surface (no silhouette, no crease: those are edges, not speckle)
    nrm = gb.normal.astype(np.float64)
    flat = sel.copy()
    H, W = sel.shape
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sh = np.zeros_like(sel)
            sh[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)] = (
                sel[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]
                & (np.sum(nrm[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]
                          * nrm[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)], -1) > 0.99))
            flat &= sh
    flat[[0, -1], :] = flat[:, [0, -1]] = False
    med = median_filter(np.where(sel, v, 0.0), size=3, mode="nearest")
    region = flat & ~inner
    assert region.sum() > 500 and v[region].max() > 0          # the edge region is seen and lit
    scale = np.maximum(med, 0.1 * v[region].mean())           # the dark rim, where E falls to 0, counts relative to the mean
    speckle = (np.abs(v - med) > 0.25 * scale)[region].mean()
    assert speckle <= 0.003, speckle


# --------------------------------------------------------------------------------------------- Cornell bakes
@pytest.fixture(scope="module")
def cornell_default(tmp_path_factory, scene_files):
    """The default grid (automatic: 16³ at 7 cm here) and rays (256), up to the compressed masks."""
    return bake_until(tmp_path_factory.mktemp("cornell-default"), scene_files["cornell"], {}, "compress")


def test_cornell_short_block_no_black_seam_in_mask_modes(ctx, cornell_default):
    """Artifact 2: a black seam along the top of the short block's front face (z = 0.92, facing the open side)
    in mask and mask_normalized.

    Region: the face, x in [0.66, 0.90]; the band y in [0.255, 0.285] (the seam) against the face below it,
    y in [0.06, 0.22]. Number: mean(band) / mean(below). Path-traced reference (4096 spp): the face reads
    0.015-0.019 everywhere (ratio ≈ 1). Measured: mask 0.18, mask_normalized 0.17 (band 0.004-0.007, i.e. black;
    below 0.02-0.04); at 320 x 240 leaking reads 0.70, ddgi 1.1.
    Cause (numbers at the cage probes): the front probes 3.5 cm in front of the face see the bright box behind them
    and the black open side ahead: E(+z) from their octahedral irradiance (the Monte Carlo integral) 0.027-0.043,
    from their L2 SH -0.010..+0.018 (ringing, 1% of the probe's 2.5 facing -z), clamped to 0. The mask modes keep
    only these probes there (the probes above the block's top are rightly masked: the block hides them), leaking
    averages in the bright ones above. Not the masks, not the lookup: the Python samplers give the same numbers.
    Tried before (lead): the heat-kernel window or a relative least-squares fit of the 9 coefficients to the probe's
    octahedral map, chosen per probe where its L2 irradiance falls below half the map: the seam 0.18 -> 0.35
    (windows) / 0.70 (fit), but the fit moved the open lit floor's side axes 15-20% off Cycles (test_sh_directional,
    limit 10%); with a softer relative weight the floor held (8.5%) and the seam only reached 0.26.
    L1 (sh_order = 1) has no seam but reads the face 3-6x too bright.
    Fix (light stage v4, workers/kernels/sh.py sh_l2_floor): the smallest change of each probe's 9 coefficients (in
    the irradiance norm) that keeps its L2 irradiance at least 0.75 of its own octahedral map at every texel
    direction (a quadratic programme per probe and channel; inactive, so no change, wherever L2 does not ring): the
    one-sided probes are lifted where they ring and barely move elsewhere, the open floor holds
    (test_sh_directional). After: mask 0.73 (band 0.012, below 0.017: the path-traced 0.015-0.019), mask_normalized
    0.71. (With light v3's spot sampling alone the seam read 0.03: the spot's light reaches these probes from
    behind only, deepening the ring.)
    """
    scene, s = cornell_default
    cam = Camera(position=(0.45, 0.55, 1.6), target=(0.78, 0.18, 0.78), fov_y=35, width=160, height=120)
    gb, out = _render(ctx, scene, s, cam, ["mask", "mask_normalized"])
    p, n = gb.position.astype(np.float64), gb.normal
    face = gb.shaded & (n[..., 2] > 0.99) & (np.abs(p[..., 2] - 0.92) < 2e-3) & (p[..., 0] > 0.66) & (p[..., 0] < 0.90)
    band = face & (p[..., 1] > 0.255) & (p[..., 1] < 0.285)
    below = face & (p[..., 1] > 0.06) & (p[..., 1] < 0.22)
    assert band.sum() > 20 and below.sum() > 100
    ratios = {m: float(out[m].mean(-1)[band].mean() / out[m].mean(-1)[below].mean()) for m in out}
    assert min(ratios.values()) >= 0.5, ratios


def _blotch(p, v) -> float:
    """RMS of v about its least-squares cubic in (x, y), relative to its mean: a smooth gradient gives ~0."""
    x, y = p[:, 0], p[:, 1]
    X = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y, x ** 3, y ** 3, x * x * y, x * y * y], 1)
    c, *_ = np.linalg.lstsq(X, v, rcond=None)
    return float(np.sqrt(np.mean((v - X @ c) ** 2)) / v.mean())


def test_ddgi_no_blotches_at_8_cubed_probes(ctx, tmp_path, scene_files):
    """Artifact 3: DDGI blotches at 8³ probes / 256 rays (Cornell).

    Region: the back wall (z = 0.02) above the boxes, x in [0.4, 0.9], y in [0.65, 0.95]. Number: the blotch
    measure (RMS about a cubic fit / mean). Before: ddgi 0.117 at 256 rays (leaking 0.129, mask_normalized
    0.121: every mode, so the probes' values, not the DDGI weights). Cause: the scene's 1 cd point light sits 1 cm
    under the emitter panel (workers/procedural.py), so it lights a spot of ~2 cm on the panel's underside to
    E ≈ 1 / 0.01² = 10⁴ lux, reflected radiance ≈ 2,300 — 230x the panel's own emission — over ~10⁻³ sr from a
    probe, which its 256 rays (0.05 sr each) hit or miss by chance, independently of its neighbours. Without the
    point light the same grid and rays give 0.034. More rays from the probes do not cure it: uniform extra rays
    for the noisy probes (4x / 8x their rays for the fixed term) gave 0.03-0.06 / 0.11 over seeds 0-3, 2,048 rays
    0.096 — a 10⁻³ sr spot is hit 0-3 times either way.
    Fix (workers/kernels/light_spots.py, light stage v3): the spot is sampled from the light's side — each point
    light's direct irradiance above 32x its median at the probe-ray hits is left out of the rays and carried by
    virtual point lights made from photons (instant radiosity), each tested against every probe with a shadow
    ray; unbiased up to the photons' merging (tests/kernels/test_light_spots.py: 2% of the path integral).
    After: 0.020 (seed 0; 0.020 at seed 3, where the rays alone gave 0.167).
    """
    cfg = {"place": {"counts": [8, 8, 8]}, "visibility": {"slabs": 1}}
    scene, s = bake_until(tmp_path, scene_files["cornell"], cfg, "light")
    cam = Camera(position=(0.5, 0.5, 1.8), target=(0.5, 0.5, 0.0), fov_y=30, width=128, height=96)
    gb, out = _render(ctx, scene, s, cam, ["ddgi"])
    p, n = gb.position.astype(np.float64), gb.normal
    wall = (gb.shaded & (n[..., 2] > 0.99) & (np.abs(p[..., 2] - 0.02) < 2e-3) & (p[..., 0] > 0.4) & (p[..., 0] < 0.9)
            & (p[..., 1] > 0.65) & (p[..., 1] < 0.95))
    assert wall.sum() > 500
    b = _blotch(p[wall], out["ddgi"].mean(-1)[wall])
    assert b <= 0.07, b


# --------------------------------------------------------------------------------------------- 4. doorway halo
HALO_CFG = {"place": {"budget": 500}, "trace": {"rays_per_probe": 128}, "visibility": {"slabs": 1}}


def test_plain_mask_no_halo_around_the_doorway(tmp_path, scene_files):
    """Artifact 4: plain mask GI brighter in a ring around the door on room B's face of the shared wall (two-rooms).

    The automatic grid (place.budget 500: 11 x 6 x 7, 0.81 m; the wall between two layers). Points on the wall
    (x = 4.05, normal +x, viewed from (7.5, 1.4, 2.0)): the ring within 0.2 m of the door frame and the wall 0.4-1.0 m
    from it. Number: (mode / path-traced reference in the ring) / (the same away from it); 1 = no halo.
    Measured: mask 1.63 (256 spp reference; 1.65 at 1024 spp), mask_normalized 1.33; at the default budget (28 x 12 x 15, 0.31 m) mask
    1.08; with a probe layer inside the wall (counts 9 x 4 x 5) mask 2.95: the automatic grid's wall-fitted layers
    took most of it away. What is left: the masks are read one refined sample in front of the surface along n + v
    (samplers.mask_values), and there, next to the jamb, the samples see room A's probes through the door (the
    surface itself does not: the door is in its plane), so room A's clusters get weight on room B's wall; the plain
    mode also darkens the wall away from the door (eq 3 unnormalized, 0.63 of the reference; MD Fig 4), which makes
    the ring stand out. Without the view term: 1.46; smaller offsets leak through the 5 cm wall everywhere (0.5
    sample: 1.49x the reference away from the door). A fix needs the masks to answer for the surface, not a point in
    front of it: e.g. θ of the refined samples on a wall taken from the surface side (the visibility stage), or
    the lookup offset limited to the distance to the nearest don't-care sample.
    Re-measured after the lookup's both-sides blend (HEAD 51cd8b5; light stage v4): 1.63 still, and split into its
    two factors (mode / reference): mask ring 1.04, away 0.64 — the ring is right, the wall away from the door is
    dark. The grid's layers straddle the wall (x = 3.61 in room A, 4.42 in room B): a point on the wall's room-B face
    has trilinear weight 0.54 on room B's probes and 0.46 on room A's, which its masks rightly remove, and eq 3
    does not renormalize (MD Fig 4's darkening); next to the door the offset read sees room A's clusters through
    it and gets their weight back. The halo is eq 3's missing normalization, which is the plain mode's definition:
    mask_normalized is its fix (ring 1.64, away 1.24 there: 1.32). Offsets 0 / 0.5 / 2 samples: 0.80 (but 2.7x the
    reference away: the read inside the wall sees both rooms) / 1.45 / 2.07.
    Since the automatic grid turns rectilinear where the budget binds (workers/kernels/autogrid.py step 4b: a layer
    0.2 x the fill spacing in front of both faces of the thin wall: 10 x 4 x 5 probes, 1.02 m apart, layers at
    x = 3.80 and 4.25, so the wall's cell is 0.46 m wide and a point on room B's face weighs room A's probes less):
    1.249 (was 1.63). Held to 1.35: the ring stays a little bright (eq 3 unnormalized), no longer the 1.6 it was.
    """
    halo = _doorway_halo(tmp_path, scene_files, HALO_CFG)
    assert halo <= 1.35, halo


def test_plain_mask_no_halo_around_the_doorway_at_the_default_grid(tmp_path, scene_files):
    """Artifact 4 as it was reported: the default config. The report was made on the old fixed 8x8x8 grid; the
    automatic grid (issue 12; two-rooms: 28 x 12 x 15, 0.31 m, layers fitted to the walls) is what a user gets now,
    and there the ring/away ratio of the test above is 1.05 (measured at HEAD ed748e1): fixed by the defaults. The coarse grid above stays
    xfail (the method's own limit, eq 3 unnormalized)."""
    halo = _doorway_halo(tmp_path, scene_files, {"visibility": {"slabs": 1}})
    assert halo <= 1.25, halo


def _doorway_halo(tmp_path, scene_files, cfg) -> float:
    """(plain mask GI / path-traced reference in the 0.2 m ring around room B's door frame) / (the same 0.4-1.0 m
    from it), on the wall x = 4.05 viewed from (7.5, 1.4, 2.0); 1 = no halo."""
    from workers.kernels import samplers as SM
    from workers.kernels.pathtrace import indirect_irradiance

    scene, s = bake_until(tmp_path, scene_files["two-rooms"], cfg, "compress")
    arrays, grid = bake_arrays(s), bake_grid(s)
    rng = np.random.default_rng(0)
    zz, yy = rng.uniform(0.8, 3.2, 1200), rng.uniform(0.05, 2.9, 1200)
    keep = ~((zz > 1.55) & (zz < 2.45) & (yy < 2.0))
    zz, yy = zz[keep], yy[keep]
    dist = np.where(yy < 2.0, np.minimum(np.abs(zz - 1.55), np.abs(zz - 2.45)),
                    np.hypot(np.maximum(np.maximum(1.55 - zz, zz - 2.45), 0.0), yy - 2.0))
    ring, away = dist < 0.2, (dist > 0.4) & (dist < 1.0)
    sel = ring | away
    p = np.stack([np.full(sel.sum(), 4.05), yy[sel], zz[sel]], -1)
    ring, away = ring[sel], away[sel]
    n = np.tile([1.0, 0.0, 0.0], (len(p), 1))
    ref = indirect_irradiance(scene, p, n, s["ingest"]["lights"]["lights"], spp=256, bounces=16).irradiance.mean(1)
    eye = np.array([7.5, 1.4, 2.0])
    view = (eye - p) / np.linalg.norm(eye - p, axis=1, keepdims=True)
    e = np.maximum(SM.irradiance("mask", arrays, grid, p, n, views=view), 0).mean(1)
    return float((e[ring].mean() / ref[ring].mean()) / (e[away].mean() / ref[away].mean()))


# --------------------------------------------------------------------------------------------- 5. PRT hotspot
PRT_CFG = {"place": {"counts": [8, 8, 8]}, "trace": {"rays_per_probe": 128}, "visibility": {"slabs": 1},
           "prt": {"enabled": True, "lightmap": 0, "configurations": 64}}


@pytest.fixture(scope="module")
def prt_near_light(tmp_path_factory, scene_files) -> dict:
    """:func:`_prt_near_light` of PRT_CFG, baked once for the two tests below."""
    return _prt_near_light(tmp_path_factory.mktemp("prt"), scene_files, PRT_CFG)


def test_prt_indirect_no_hotspot_or_black_walls(prt_near_light):
    """Artifact 5 as reported: a saturated hotspot and near-black walls in PRT's indirect-only view (Cornell, a point
    light 8 cm above the floor; the setting and the metrics of :func:`_prt_near_light`, whose docstring below has the
    history). Numbers at the probes over the 6 axis normals, PRT against the light stage's own bounce loop for that
    light: near-black (the share of lit directions PRT gives < 0.1 of) ≤ 0.01; hotspot: PRT's brightest direction
    over the reference's brightest ≤ 1.25, and the share of lit directions PRT reads more than 2x ≤ 0.05.
    Before the fixes (uniform scenario lights, L2 norm, λ = 1e-3; ``prt.scenario.near_surface`` 0, ``prt.norm``
    "l2", ``prt.ridge_folds`` 0, ``prt.ridge`` 1e-3, on this HEAD's bake, d86ebe2): near-black 0.039, peak 0.31,
    over 2x 0.166 — fails on near-black and on the many directions read 2x and more (the speckled overshoot; the
    brightest direction itself is under-read). Shipped: 0.0007, 0.59, 0.021. What stays wrong is the size of the
    local response next to the light, not a hotspot: the relative RMS (0.61 before, 0.53 shipped;
    :func:`test_prt_indirect_relative_rms_near_a_light`, xfail)."""
    m = prt_near_light
    assert m["black"] <= 0.01 and m["peak"] <= 1.25 and m["over2"] <= 0.05, m


@pytest.mark.xfail(strict=True, reason="relative RMS 0.53 > 0.3: the 16-slot basis's own projection is 0.52 "
                                       "since the rescue relocation (docstring)")
def test_prt_indirect_relative_rms_near_a_light(prt_near_light):
    """PRT's relative RMS error at the probes for a light 8 cm above the floor (≤ 0.3 asked): 0.53. See
    :func:`_prt_near_light`."""
    m = prt_near_light
    assert m["rms"] <= 0.3, m


def _prt_near_light(tmp_path, scene_files, cfg) -> dict:
    """Artifact 5: PRT's indirect-only view shows a saturated hotspot and near-black walls (Cornell).

    A point light 8 cm above the floor, (0.5, 0.1, 0.3), 1 cd, relit through the baked transfer
    (prt_relight.relight) against the light stage's own bounce loop for that light on the same probe rays
    (prt_reference.light_stage_reference: what the transfer is fit to). Numbers at the probes, over the 6 axis normals
    (L2): the fraction of probe directions that the reference lights (> 0.2 x median) but PRT gives < 0.1 of it
    (near-black), and PRT's relative RMS error. Measured before the fix below (64 configurations, basis 16):
    near-black 0.050, relative RMS 0.55; at 128 configurations 0.16 and 1.4 (0.27-0.56 for lights 10-15 cm from
    a wall, 0.11 in the middle of the box). More basis vectors do not help (16 -> 128: 1.99 -> 1.98 at 128
    configurations): the error is the transfer's (eq 14's ridge regression from the 256 measurement points'
    direct light), which generalizes poorly to a light close to a surface — a sharp,
    local response outside what a linear map fit to N random configurations spans — and the reconstruction then
    rings: an overshoot at the light and negative (clamped: black) SH elsewhere. Even on its training
    configurations the relative error is 0.12-0.7. Behaviour of data-driven PRT at this N and M (PRT §4); fixes
    lie in the prt stage (more configurations near surfaces in the scenario, a non-negative reconstruction), not
    in the runtime shaders, which reproduce relight() exactly (test_shading.test_prt_glsl_equals_relight).
    For the scene's own light (1 cd, 1 cm under the emitter panel) part of the hotspot is real: the reference's
    brightest probe direction is 87x the median (the panel's underside lit to ~10⁴ lux, see artifact 3); PRT reads
    31x there, with relative RMS 0.84.

    Fixed in the prt stage (PRT §4.1-4.3), defaults: (1) the scenario places half of its point/spot lights 2-25 cm
    off a surface (``prt.scenario.near_surface`` 0.5, ``near_distance``; PRT §4.1 lets the scenario define the
    distribution); (2) the dataset is normalized by the L1 norm of x (``prt.norm`` "l1"; §4.2 says only "the norm":
    the L2 norm of a concentrated direct field, 0.26 of its L1 norm here against 0.16 for the median random light,
    overshoots the mean's coefficient); (3) λ of eq 14 by 4-fold cross-validation over the configurations
    (``prt.ridge_folds``, relative grid 0.1-1, kernels/prt.py RIDGE_GRID). Numbers (near-black, relative RMS):

    ====================================================== ============ =============
    before (uniform lights, L2 norm, λ = 1e-3)              0.050        0.55
    + lights near surfaces                                  0.009        0.41
    + L1 norm, λ = 0.01 fixed                               0.006        0.37
    + L1 norm, cross-validated λ (grid from 0)              0.024        0.41
    + L1 norm, cross-validated λ (grid from 0.1): shipped   0.007        0.37
    L2 norm, cross-validated λ, lights near surfaces        0.000        0.39
    ====================================================== ============ =============

    The near-black fraction passes; the RMS does not, and cannot at this N and n: projecting the reference itself
    onto the fitted 16-slot basis (kprt.project, the best any transfer can do) leaves 0.33 (L2) / 0.36 (L1); all
    64 configurations as basis 0.24. A second seed (bake seed 2) scatters a lot at N = 64 (before: 0.175 and 1.28;
    shipped: 0.003 and 0.41). Ordinary lights are not worse: 12 held-out uniform lights in this box, mean relative
    RMS (same metric) 0.66 -> 0.485 (seed 2: 0.60 -> 0.47); tests/bench/bench_prt.py on cornell-box-vinc3r
    (64 configurations, 6³ probes, 128 rays, lightmap 64², 8 held-out, SH / lightmap RMSE at n = 16): room
    0.147 / 0.167 -> 0.138 / 0.170, front 0.017 / 0.017 -> 0.019 / 0.027 (front: the old fit, L2 and λ = 1e-3, on
    the redrawn dataset gives 0.018 / 0.024: most of that is the dataset's random draw, not the fit).

    Re-measured at 167a145 (the test's config; kprt.fit + reconstruct on one saved dataset per N and M, which
    match relight() to the digits shown): 0.0007 and 0.53. The cause is upstream: the trace stage's rescue
    (``trace.rescue_offset`` 0.95, commits 3293b20 / a0346e7) now moves the 264 probes of the wall layers, which
    sat in the walls (OFF), to 3 cm off them; with ``trace.rescue_offset`` 0 the same bake gives 0.007 and 0.37
    again. The 5 bottom-layer probes 9-15 cm from the light (3 cm above the floor) carry 72 % of the squared
    error: the light stage reads 35-50 lux there (the floor's lit spot fills their lower hemisphere), PRT 7-17 —
    no longer a hotspot but an underestimate of a local response. The interior 6³ probes alone: 0.42 (0.37 without
    rescue). Variants (relit: near-black / relative RMS, near-black ≤ 0.01 unless given; proj: the reference
    projected on the same basis, the best any transfer can do; held: mean relative RMS of 12 held-out uniform
    lights drawn as bench_prt draws them, rng [seed, 0xBEEF], the scenario without its near share):

    ====================================================== ============= ===== =====
    variant (N configurations, M points, n basis slots)     relit         proj  held
    ====================================================== ============= ===== =====
    shipped: N = 64, M = 256, n = 16, l1, cross-validated λ 0.0007 / 0.53 0.52  0.91
    n = 24                                                  0.51          0.49  0.93
    n = 32                                                  0.49          0.47  0.92
    n = 64                                                  0.46          0.34  0.93
    n = all 185 columns                                     0.46          0.30  0.93
    N = 96, n = 16                                          0.55          0.53  0.90
    N = 96, n = 32                                          0.54          0.51  0.88
    N = 96, n = all 280 columns                             0.47          0.27  0.90
    N = 128, n = 16                                         0.53          0.50  0.87
    N = 128, n = 32                                         0.50          0.46  0.84
    N = 128, n = 64                                         0.41          0.28  0.82
    M = 1024, n = 16                                        0.55          0.54  0.71
    M = 1024, n = 32                                        0.50          0.46  0.67
    M = 1024, N = 128, n = 16                               0.53          0.52  0.77
    M = 1024, N = 128, n = 64                               0.40          0.27  0.70
    N = 128, n = 16, λ = 0 (eq 13)                          0.14 / 1.36   0.50  1.53
    N = 128, n = 16, λ = 1e-3 fixed                         0.08 / 0.91   0.50  1.03
    N = 128, n = 16, λ = 0.1 fixed                          0.53          0.50  0.86
    N = 128, n = 16, l2 norm, cross-validated λ             0.61          -     1.14
    gamma 2 (§5.3), n = 16                                  0.51          -     0.83
    gamma 2, n = 64                                         0.013 / 0.48  -     0.82
    gamma 2, N = 128, n = 16                                0.015 / 0.46  -     0.71
    gamma 2, N = 128, n = 64                                0.31          -     0.65
    scenario near_surface 0.9 (0.5 shipped)                0.58          0.50  0.84
    basis from unit-norm columns (weighted PCA), n = 16     0.014 / 0.49  0.49  0.94
    coefficients u clamped to their training range         0.53          0.52  0.91
    bake seed 2 (and its own held-out draw)                 0.0 / 0.50    0.46  0.56
    ``trace.rescue_offset`` 0                               0.007 / 0.37  0.36  0.90
    ====================================================== ============= ===== =====

    At n = 16 the basis's own projection is 0.46-0.54 in every row, so no transfer on it reaches 0.3; only
    n ≥ 64 with N ≥ 128 brings the projection under 0.3, and the transfer then still reads 0.40 (gamma 2, which
    mode_prt.glsl cannot sum: it interpolates a linear basis, 0.31). More measurement points help the held-out
    lights (0.91 -> 0.71), not this one. The held column does not reproduce the 0.485 above (another draw or
    metric; one of these 12 lights stands 3 cm off the back wall and reads 2.8; median 0.75). Cost (N = 64): the
    prt stage's dataset 9.4 s and fit 0.1 s at any n; prt_* artifacts 231 / 330 / 429 KB at
    n = 16 / 24 / 32 (basis volumes 151 / 226 / 301 KB, transfer 44 / 68 / 91 KB); relight() 0.24-0.31 ms;
    mode_prt.glsl 9·⌈n/4⌉ texture fetches per pixel (36 / 54 / 72) and 3·⌈n/4⌉ vec4 uniforms (at most 64 slots,
    KILN_PRT_MAX_GROUPS 16).
    """
    from proto.models import BakeConfig
    from tests.workers.prt_reference import light_stage_reference
    from workers.kernels.sh import sh_irradiance_l2
    from workers.prt_relight import relight
    from workers.raycast import RayCaster
    from workers.stages import prt as P
    from workers.stages.base import StageContext

    scene, s = bake_until(tmp_path, scene_files["cornell"], cfg, "light")
    bc = BakeConfig.model_validate(cfg)
    ctx = StageContext(bc, lambda: scene, s, lambda f: None)
    ds = P.prt_dataset(ctx)
    arrays = {a.name: a.data for a in P.prt_output(ctx, ds).artifacts}
    lights = [{"type": "point", "position": [0.5, 0.1, 0.3], "intensity": 1.0, "color": [1.0, 1.0, 1.0]}]
    ref, _ = light_stage_reference(ds, lights, bc.light, lightmap=False)
    got = relight(arrays, lights, RayCaster(scene.triangles), lightmap=False)["probe_sh"]
    on = s["trace"]["probe_states"].reshape(-1) != 0
    axes = np.vstack([np.eye(3), -np.eye(3)])

    def e6(sh):
        sh = np.asarray(sh, np.float64).reshape(-1, 9, 3)[on]
        return np.stack([sh_irradiance_l2(sh, np.tile(a, (len(sh), 1))).mean(1) for a in axes], 1)

    er, eg = e6(ref), e6(got)
    med = np.median(er)
    black = float(((eg < 0.1 * er) & (er > 0.2 * med)).mean())
    rms = float(np.sqrt(np.mean((eg - er) ** 2) / np.mean(er ** 2)))
    lit = er > 0.2 * med
    return {"black": black, "rms": rms, "peak": float(eg.max() / er.max()), "over2": float((lit & (eg > 2 * er)).mean())}


# --------------------------------------------------------------------------------------------- found on the way
def test_ddgi_renders_grids_wider_than_the_texture_limit(ctx):
    """Found reproducing artifact 3: DDGI rendered black (every pixel exactly 0) on large grids. The irradiance atlas
    is nz·nx tiles wide (proto/bundle.md 5.1): sealed-box's default automatic grid, 53 x 8 x 53, makes it 28,090
    texels, over GL_MAX_TEXTURE_SIZE (16,384 on llvmpipe, the usual GPU and WebGL2 limit), so the texture did not
    upload and every fetch read 0. The pass now binds such an atlas re-packed (shading.wrap_atlas, tile columns
    wrapped into row blocks; mode_ddgi.glsl reads it through octahedral.glsl octAtlasUVWrapped).
    Number: GLSL vs the Python DDGI sampler (ddgi.sample_irradiance) on a synthetic 45 x 2 x 40 grid (18,000 texels
    wide; every probe a constant colour, no occlusion), max |error| / max |reference|.
    Before: 1.0 (GLSL 0 everywhere). After: ≤ 2^-8 (fixed-point filter weights, as test_shading).
    The web viewer binds the atlas as stored (uIrradianceColumns / uDepthColumns unset = 0): it needs the same
    re-pack (web/src/state/modes.js) to show such bakes.
    """
    from workers.kernels.ddgi import sample_irradiance
    from workers.kernels.grid import ACTIVE, base_positions, pack_atlas
    from workers.render.shading import MAX_TEXTURE_SIZE, GBufferInputs, ShadingRenderer, prepare_mode, wrap_atlas

    counts, origin, spacing = [45, 2, 40], np.zeros(3), np.array([0.5, 1.0, 0.5])
    nx, ny, nz = counts
    P = nx * ny * nz
    rng = np.random.default_rng(3)
    colour = rng.uniform(0.1, 1.0, (P, 3))
    irr = np.broadcast_to(colour[:, None, None, :], (P, 10, 10, 3)).astype(np.float32)
    dep = np.broadcast_to(np.array([100.0, 1e4], np.float32), (P, 18, 18, 2)).copy()
    pos = base_positions(counts, origin, spacing).astype(np.float32)
    states = np.full(P, ACTIVE, np.uint8)
    rgba = np.concatenate([irr, np.ones(irr.shape[:-1] + (1,), np.float32)], -1)
    arrays = {"irradiance": pack_atlas(rgba, counts), "depth_moments": pack_atlas(dep, counts),
              "probe_positions_relocated": pos, "probe_states": states}
    assert arrays["irradiance"].shape[1] > MAX_TEXTURE_SIZE
    wrapped, cols = wrap_atlas(arrays["irradiance"], counts)
    assert wrapped.shape[1] <= MAX_TEXTURE_SIZE and cols == MAX_TEXTURE_SIZE // 10
    c = 1234                                               # tile c = k·nx + i, probe (i, j = 1, k)
    np.testing.assert_array_equal(wrapped[(c // cols * ny + 1) * 10:(c // cols * ny + 2) * 10, c % cols * 10:(c % cols + 1) * 10],
                                  arrays["irradiance"][10:20, c * 10:(c + 1) * 10])
    W, H = 64, 16
    hi = origin + spacing * (np.array(counts) - 1)
    p = origin + rng.random((W * H, 3)) * (hi - origin)
    n = rng.normal(size=(W * H, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    eye = np.array([11.0, 3.0, 10.0])
    view = (eye - p) / np.linalg.norm(eye - p, axis=1, keepdims=True)
    want = sample_irradiance(p, n, view, counts, origin, spacing, pos, states, irr, dep, 0.3)
    grid = {"counts": counts, "origin": origin.tolist(), "spacing": spacing.tolist()}
    r = ShadingRenderer(ctx)
    try:
        r.set_mode(prepare_mode("ddgi", arrays, grid))
        r.set_gbuffer(GBufferInputs(p.reshape(H, W, 3).astype(np.float32), n.reshape(H, W, 3).astype(np.float32),
                                    np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.ones((H, W), bool)))
        got = r.render("ddgi", output=1, eye=eye).reshape(-1, 3).astype(np.float64)
    finally:
        r.release()
    err = np.abs(got - want).max() / np.abs(want).max()
    assert err <= 2.0 ** -8, err
