"""Reference samplers of the shading modes (workers/kernels/samplers.py) on synthetic volumes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels import mask_fit as M
from workers.kernels import samplers as SM
from workers.kernels.coloring import parity_coloring
from workers.kernels.sh import SH_C0, sh_irradiance, sh_irradiance_l1_nonlinear


def _grid(counts=(4, 3, 5), origin=(-1.0, 0.5, 2.0), spacing=(0.5, 0.75, 0.4)):
    counts = np.asarray(counts)
    spacing = np.where(counts > 1, spacing, 0.0)
    return SM.Grid(counts, origin, spacing)


def _normals(n, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _points(grid, n, seed=0, margin=0.0):
    rng = np.random.default_rng(seed)
    lo = grid.origin - margin
    hi = grid.origin + grid.spacing * (grid.counts - 1) + margin
    return rng.uniform(lo, hi, (n, 3))


def test_trilinear_centres_linear_and_clamped():
    vol = np.arange(4, dtype=np.float64).reshape(1, 1, 4)          # one row along x: 0 1 2 3
    u = np.array([0.125, 0.375, 0.5, 0.875, 0.0, 1.0, -3.0, 7.0])  # centres, midpoint, edges, far outside
    uvw = np.stack([u, np.full_like(u, 0.5), np.full_like(u, 0.5)], 1)
    assert np.allclose(SM.trilinear(vol, uvw)[:, 0], [0, 1, 1.5, 3, 0, 3, 0, 3])
    # uint8 is UNORM
    assert SM.trilinear(np.full((2, 2, 2, 1), 51, np.uint8), uvw[:1])[0, 0] == pytest.approx(0.2)
    # 3D: trilinear reproduces an affine function inside the centre box
    z, y, x = np.meshgrid(np.arange(3), np.arange(4), np.arange(5), indexing="ij")
    vol3 = (2 * x - y + 0.5 * z + 1.0)[..., None]
    t = np.random.default_rng(0).uniform([0, 0, 0], [4, 3, 2], (100, 3))   # texel space (x, y, z)
    uvw3 = (t + 0.5) / np.array([5, 4, 3])
    assert np.allclose(SM.trilinear(vol3, uvw3)[:, 0], 2 * t[:, 0] - t[:, 1] + 0.5 * t[:, 2] + 1.0)


def _const_sh(grid, rgb_l0, l1=(0.0, 0.0, 0.0)):
    """(nz, ny, nx, 4) per channel: constant L0 per channel, the same L1 (y, z, x) for all."""
    shape = (int(grid.counts[2]), int(grid.counts[1]), int(grid.counts[0]), 4)
    out = []
    for c in rgb_l0:
        v = np.zeros(shape, np.float32)
        v[..., 0] = c
        v[..., 1:] = l1
        out.append(v)
    return out


def test_leaking_constant_volume_is_the_constant_irradiance():
    g = _grid()
    sh = _const_sh(g, [0.3, 1.0, 2.5], l1=(0.1, -0.2, 0.05))
    pts = _points(g, 200, margin=1.0)                          # inside and outside the grid box
    n = _normals(200)
    e = SM.leaking(pts, n, *sh, g, linear=True)
    coeffs = np.stack([s[0, 0, 0] for s in sh], -1)              # (4, 3)
    assert np.allclose(e, sh_irradiance(coeffs, n), rtol=1e-6)
    # the default evaluation is the non-linear L1 reconstruction of the same coefficients
    assert np.allclose(SM.leaking(pts, n, *sh, g), sh_irradiance_l1_nonlinear(coeffs, n), rtol=1e-6)
    # L0 only: E = π·c0·L0 for every normal, in both evaluations
    for linear in (True, False):
        e0 = SM.leaking(pts, n, *_const_sh(g, [1.0, 2.0, 3.0]), g, linear=linear)
        assert np.allclose(e0, math.pi * SH_C0 * np.array([1.0, 2.0, 3.0]), rtol=1e-6)


def test_leaking_interpolates_probes_trilinearly():
    g = _grid()
    rng = np.random.default_rng(3)
    sh = [rng.random((5, 3, 4, 4)).astype(np.float32) for _ in range(3)]
    # probe positions themselves return the probe, midpoints the mean of the two
    p = np.array([[1, 2, 3], [0, 0, 0], [3, 2, 4]])
    pts = g.origin + p * g.spacing
    n = np.tile([0.0, 1.0, 0.0], (3, 1))
    e = SM.leaking(pts, n, *sh, g, linear=True)
    for r, (i, j, k) in enumerate(p):
        P = np.stack([s[k, j, i] for s in sh], -1)
        assert np.allclose(e[r], sh_irradiance(P, n[r]), rtol=1e-6)
    mid = g.origin + np.array([[1.5, 2, 3]]) * g.spacing
    P = 0.5 * (np.stack([s[3, 2, 1] for s in sh], -1) + np.stack([s[3, 2, 2] for s in sh], -1))
    assert np.allclose(SM.leaking(mid, n[:1], *sh, g, linear=True)[0], sh_irradiance(P, n[0]), rtol=1e-6)
    # non-linear: the coefficients are interpolated, then evaluated
    assert np.allclose(SM.leaking(mid, n[:1], *sh, g)[0], sh_irradiance_l1_nonlinear(P, n[0]), rtol=1e-6)


def test_one_probe_axes():
    g = _grid(counts=(3, 1, 1), origin=(0.0, 1.0, 2.0), spacing=(1.0, 0.0, 0.0))
    assert np.array_equal(g.spacing, [1.0, 0.0, 0.0])
    sh = [np.arange(3, dtype=np.float32).reshape(1, 1, 3, 1) * np.array([1, 0, 0, 0], np.float32)] * 3
    pts = np.array([[0.5, -4.0, 9.0], [1.75, 1.0, 2.0], [5.0, 7.0, -1.0]])   # y, z anywhere
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    e = SM.leaking(pts, n, *sh, g)
    assert np.allclose(e[:, 0], math.pi * SH_C0 * np.array([0.5, 1.75, 2.0]))
    uvw = SM.field_uvw(pts, g)
    assert np.allclose(uvw[:, 1:], 0.5) and np.allclose(uvw[:, 0], [0.25, 0.875, 2.5])
    assert np.allclose(SM.probe_uvw(pts, g)[:, 1:], 0.5)
    # visibility-weighted with everything visible = leaking; masks with one cluster = leaking
    S = 2
    theta = np.full((S, S, 2 * S, 4), 255, np.uint8)
    vw = SM.visibility_weighted(pts, n, *sh, theta, theta, g)
    assert np.allclose(vw, e)


@pytest.mark.parametrize("counts", [(4, 3, 5), (3, 1, 4)])
def test_visibility_weighted_all_visible_is_leaking(counts):
    g = _grid(counts)
    rng = np.random.default_rng(1)
    nz, ny, nx = int(g.counts[2]), int(g.counts[1]), int(g.counts[0])
    sh = [rng.normal(size=(nz, ny, nx, 4)).astype(np.float32) for _ in range(3)]
    S = 3
    cells = np.maximum(g.counts - 1, 1)
    theta = np.full((cells[2] * S, cells[1] * S, cells[0] * S, 4), 255, np.uint8)
    pts = _points(g, 300, seed=2)
    n = _normals(300, 1)
    assert np.allclose(SM.visibility_weighted(pts, n, *sh, theta, theta, g), SM.leaking(pts, n, *sh, g),
                       rtol=1e-9, atol=1e-12)
    # one cluster, mask 1 everywhere: eq 3 = eq 1, and normalized too (w = Σ φ = 1)
    m = [np.full(theta.shape, 255, np.uint8)]
    w = [np.ones((nz, ny, nx, 4), np.float32)]
    e = SM.mask(pts, n, m, [tuple(sh)], g)
    assert np.allclose(e, SM.leaking(pts, n, *sh, g), rtol=1e-9, atol=1e-12)
    assert np.allclose(SM.mask_normalized(pts, n, m, [tuple(sh)], w, g), e, rtol=1e-9, atol=1e-12)


def test_visibility_weighted_reads_theta_inside_the_cell():
    # two cells along x; θ of corner 1 (probe 1 seen from cell 0) is 0, everything else 1.
    g = _grid(counts=(3, 2, 2), origin=(0, 0, 0), spacing=(1, 1, 1))
    S = 4
    th = np.full((S, S, 2 * S, 8), 255, np.uint8)
    th[:, :, :S, 1] = 0                  # cell 0 does not see its corner 1 (= probe x = 1)
    t0123, t4567 = np.ascontiguousarray(th[..., :4]), np.ascontiguousarray(th[..., 4:])
    sh = [np.zeros((2, 2, 3, 4), np.float32) for _ in range(3)]
    sh[0][:, :, 1, 0] = 1.0              # only the probes at x = 1 are bright (red, L0)
    n = np.array([[0.0, 1.0, 0.0]])
    # just left of the cell face x = 1: only corner 1 (y = z = 0 row) is hidden; θ must not bleed
    # from cell 1's texels (where channel 1 means probe x = 2)
    p = np.array([[0.99, 0.0, 0.0]])
    e = SM.visibility_weighted(p, n, *sh, t0123, t4567, g)
    assert e[0, 0] == pytest.approx(0.0, abs=1e-12)
    q = np.array([[1.01, 0.0, 0.0]])     # cell 1: probe x = 1 is its corner 0, visible
    e1 = SM.visibility_weighted(q, n, *sh, t0123, t4567, g)
    assert e1[0, 0] == pytest.approx(0.99 * math.pi * SH_C0, rel=1e-9)
    # unnormalized: Σ θ φ P
    e2 = SM.visibility_weighted(q, n, *sh, t0123, t4567, g, normalize=False)
    assert e2[0, 0] == pytest.approx(0.99 * math.pi * SH_C0, rel=1e-9)


def test_mask_normalized_zero_where_no_weight():
    g = _grid(counts=(2, 2, 2), origin=(0, 0, 0), spacing=(1, 1, 1))
    sh = tuple(np.ones((2, 2, 2, 4), np.float32) for _ in range(3))
    m = [np.zeros((2, 2, 2, 4), np.uint8)]
    w = [np.ones((2, 2, 2, 4), np.float32)]
    p = np.array([[0.3, 0.4, 0.5]])
    n = np.array([[1.0, 0.0, 0.0]])
    assert np.all(SM.mask_normalized(p, n, m, [sh], w, g) == 0)
    assert np.all(SM.mask(p, n, m, [sh], g) == 0)


def test_parity_masks_reproduce_visibility_weighting_at_samples():
    """MD §3.2 on a synthetic field: K = 8, parity colouring, masks from θ, at every care sample."""
    g = _grid(counts=(4, 3, 3), origin=(0.0, 0.0, 0.0), spacing=(0.5, 0.6, 0.7))
    S = 3
    cells = np.maximum(g.counts - 1, 1)
    shape = (cells[2] * S, cells[1] * S, cells[0] * S)
    rng = np.random.default_rng(0)
    theta = rng.integers(0, 256, shape + (8,)).astype(np.uint8)
    theta[rng.random(shape + (8,)) < 0.4] = 0
    dc = rng.random(shape) < 0.1
    gcol = parity_coloring(g.counts)
    m = M.fit_masks(theta, dc, g.counts, S, gcol, 8)
    m, _ = M.fill_dont_care(m, dc)
    q = M.quantize(m)
    P = int(np.prod(g.counts))
    sh = rng.normal(size=(P, 4, 3)).astype(np.float32)
    vols, w = M.cluster_volumes(sh.reshape(3, 3, 4, 4, 3), gcol, 8)
    z, y, x = np.nonzero(~dc)
    pts = g.origin + g.spacing * (np.stack([x, y, z], 1) + 0.5) / S
    n = _normals(len(pts))
    shv = [np.ascontiguousarray(sh.reshape(3, 3, 4, 4, 3)[..., c]) for c in range(3)]
    masks = [q[..., :4], q[..., 4:]]
    cl = [tuple(np.ascontiguousarray(v[..., c]) for c in range(3)) for v in vols]
    wts = [w[..., :4], w[..., 4:]]
    # (MD §3.2 is an identity of the linear SH evaluation: the non-linear one is not additive)
    ref = SM.visibility_weighted(pts, n, *shv, theta[..., :4], theta[..., 4:], g, linear=True)
    ref_un = SM.visibility_weighted(pts, n, *shv, theta[..., :4], theta[..., 4:], g, normalize=False, linear=True)
    assert np.allclose(SM.mask_normalized(pts, n, masks, cl, wts, g, linear=True), ref, rtol=1e-9, atol=1e-12)
    assert np.allclose(SM.mask(pts, n, masks, cl, g, linear=True), ref_un, rtol=1e-9, atol=1e-12)
    # with no don't-care samples it also holds between the samples, anywhere in a cell, faces included
    # (masks and θ are both read from the point's own cell's samples)
    q0 = M.quantize(M.fit_masks(theta, np.zeros_like(dc), g.counts, S, gcol, 8))
    cell = rng.integers(0, cells, (500, 3))
    inner = g.origin + g.spacing * (cell + rng.uniform(0.0, 1.0, (500, 3)))
    n2 = _normals(500, 3)
    assert np.allclose(SM.mask_normalized(inner, n2, [q0[..., :4], q0[..., 4:]], cl, wts, g, linear=True),
                       SM.visibility_weighted(inner, n2, *shv, theta[..., :4], theta[..., 4:], g, linear=True),
                       rtol=1e-9, atol=1e-12)


def test_irradiance_dispatch_and_errors():
    g = _grid(counts=(2, 2, 2), origin=(0, 0, 0), spacing=(1, 1, 1))
    sh = _const_sh(g, [1.0, 1.0, 1.0])
    arrays = {"sh_l1_r": sh[0], "sh_l1_g": sh[1], "sh_l1_b": sh[2]}
    p, n = np.array([[0.5, 0.5, 0.5]]), np.array([[0.0, 1.0, 0.0]])
    assert SM.irradiance("leaking", arrays, {"counts": [2, 2, 2], "origin": [0, 0, 0], "spacing": [1, 1, 1]},
                         p, n)[0, 0] == pytest.approx(math.pi * SH_C0)
    with pytest.raises(ValueError, match="unknown mode"):
        SM.irradiance("nope", arrays, g, p, n)
    with pytest.raises(ValueError, match="probe volume"):
        SM.leaking(p, n, sh[0][:1], sh[1], sh[2], g)


# ------------------------------------------------------------------------------------------------ L2
def _random_l2(g, seed=0):
    rng = np.random.default_rng(seed)
    sh = rng.normal(0.0, 0.3, size=(int(g.counts[2]), int(g.counts[1]), int(g.counts[0]), 9, 3))
    sh[..., 0, :] += 1.0
    return sh.astype(np.float32)


def _trilinear_coeffs(sh, g, p):
    """Reference: the 9 x 3 coefficients trilinearly interpolated between the 8 cage probes (clamped)."""
    t = np.clip(np.where(g.live, (p - g.origin) / np.where(g.live, g.spacing, 1.0), 0.0), 0, g.counts - 1)
    i0 = np.minimum(np.floor(t).astype(int), np.maximum(g.counts - 2, 0))
    f = t - i0
    out = np.zeros((9, 3))
    for c in range(8):
        off = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
        idx = np.minimum(i0 + off, g.counts - 1)
        out += np.prod(np.where(off, f, 1 - f)) * sh[idx[2], idx[1], idx[0]]
    return out


@pytest.mark.parametrize("counts", [(4, 3, 5), (3, 1, 4), (1, 1, 1)])
def test_leaking_l2_interpolates_the_nine_coefficients(counts):
    """sh_l2_sample of the sh_l2 atlas = trilinear interpolation of the probes' 9 x 3 coefficients (clamped at the
    border, constant along one-probe axes), and leaking_l2 = their linear L2 evaluation."""
    from workers.kernels.sh import sh_irradiance_l2, sh_l2_atlas

    g = _grid(counts=counts)
    sh = _random_l2(g, 1)
    atlas = sh_l2_atlas(sh)
    pts = _points(g, 60, seed=2, margin=0.6)
    n = _normals(60, 3)
    got = SM.sh_l2_sample(atlas, pts, g)
    want = np.stack([_trilinear_coeffs(sh.astype(np.float64), g, p) for p in pts])
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(SM.leaking_l2(pts, n, atlas, g), sh_irradiance_l2(want, n), rtol=1e-5, atol=1e-6)
    # probe positions return the probe itself
    k, j, i = (np.asarray(sh.shape[:3]) - 1) // 2
    np.testing.assert_allclose(SM.sh_l2_sample(atlas, (g.origin + np.array([i, j, k]) * g.spacing)[None], g)[0],
                               sh[k, j, i], rtol=1e-6)


def test_leaking_l2_constant_radiance_and_dispatch():
    """Constant radiance L (L0 = L / Y00 only): π·L for every normal; irradiance() picks L2 where the bake has sh_l2
    (sh_order None, the runtime default), L1 when asked, and refuses L2 without the volume."""
    from workers.kernels.sh import sh_l2_atlas

    g = _grid(counts=(2, 2, 2), origin=(0, 0, 0), spacing=(1, 1, 1))
    L = np.array([0.5, 1.0, 2.0])
    sh = np.zeros((2, 2, 2, 9, 3), np.float32)
    sh[..., 0, :] = L / SH_C0
    arrays = {f"sh_l1_{c}": np.ascontiguousarray(sh[..., :4, i]) for i, c in enumerate("rgb")}
    pts, n = _points(g, 50, margin=0.5), _normals(50)
    e1 = SM.irradiance("leaking", arrays, g, pts, n)
    np.testing.assert_allclose(e1, np.tile(math.pi * L, (50, 1)), rtol=1e-6)
    with pytest.raises(ValueError, match="no L2"):
        SM.irradiance("leaking", arrays, g, pts, n, sh_order=2)
    sh[..., 4:, :] = [0.3, -0.1, 0.2]                                     # band 2 only changes the L2 evaluation
    arrays["sh_l2"] = sh_l2_atlas(sh)
    e2 = SM.irradiance("leaking", arrays, g, pts, n)
    np.testing.assert_allclose(e2, SM.leaking_l2(pts, n, arrays["sh_l2"], g))
    assert not np.allclose(e2, e1)
    np.testing.assert_allclose(SM.irradiance("leaking", arrays, g, pts, n, sh_order=1), e1)
    assert SM.has_l2("leaking", arrays) and not SM.has_l2("mask", arrays)


def test_mask_l2_sums_the_cluster_l2_volumes():
    """Mask GI with cluster_sh_l2: Σ_k m_k E_L2(SH_k); with every mask 1 and the clusters partitioning the probes
    (linear L2, additive), it is leaking_l2 of the whole grid."""
    from workers.kernels.sh import sh_l2_atlas

    g = _grid(counts=(3, 3, 3), origin=(0, 0, 0), spacing=(1, 1, 1))
    sh = _random_l2(g, 4)
    K = 2
    labels = (np.arange(27) % K).reshape(3, 3, 3)
    vols = [sh_l2_atlas(np.where((labels == k)[..., None, None], sh, 0)) for k in range(K)]
    S = 2
    masks = [np.full((2 * S, 2 * S, 2 * S, 4), 255, np.uint8)]
    arrays = {"masks_0123": masks[0], **{f"cluster_sh_{k}_{c}": np.zeros((3, 3, 3, 4), np.float32)
                                         for k in range(K) for c in "rgb"},
              **{f"cluster_sh_l2_{k}": vols[k] for k in range(K)}}
    pts, n = _points(g, 40, seed=5), _normals(40, 6)
    got = SM.irradiance("mask", arrays, g, pts, n, mask_offset_samples=0.0)
    np.testing.assert_allclose(got, SM.leaking_l2(pts, n, sh_l2_atlas(sh), g), rtol=1e-5, atol=1e-6)
    assert SM.has_l2("mask", arrays)
    # the L1 path reads the (here zero) L1 cluster volumes
    assert np.all(SM.irradiance("mask", arrays, g, pts, n, mask_offset_samples=0.0, sh_order=1) == 0)


def _wall_masks(in_wall):
    """One cell [0, 1]³ (counts 2³, spacing 1), S = 8 samples per axis (12.5 cm): cluster 0 in front of the plane
    x = 0.5, cluster 1 behind it; the samples of x in (0.5, 0.625) hold ``in_wall`` (clusters 0, 1) (e.g. a wall's
    don't-care samples, filled from both sides)."""
    S = 8
    x = (np.arange(S) + 0.5) / S
    vol = np.zeros((S, S, S, 4), np.float64)
    vol[:, :, x < 0.5, 0] = 1.0
    vol[:, :, x > 0.5, 1] = 1.0
    vol[:, :, (x > 0.5) & (x < 0.625), :2] = in_wall
    return [np.rint(vol * 255).astype(np.uint8)], SM.Grid((2, 2, 2), (0, 0, 0), (1, 1, 1))


def test_mask_lookup_offset_does_not_step_through_a_wall_the_receiver_faces():
    """A receiver one sample (12.5 cm) in front of a surface, facing it, with the runtime offset (1 sample along
    n + v = 2 samples, 25 cm): the offset read lands behind the surface, on clusters the receiver does not see, so
    the lookup keeps the read at the point (godot-living-room 5 cm = 1 sample from its walls: normalized mask GI
    0.84 -> 1.00 of Cycles, tests/bench/bench_fidelity.py)."""
    masks, g = _wall_masks((0.0, 1.0))
    p, n = np.array([[0.375, 0.5, 0.5]]), np.array([[1.0, 0.0, 0.0]])
    at_point = SM.mask_values(masks, p, n, g, 0.0)[0, :2]
    offset_only = SM.mask_values(masks, p + 0.25 * n, n, g, 0.0)[0, :2]
    np.testing.assert_allclose(at_point, [1.0, 0.0], atol=2e-3)
    np.testing.assert_allclose(offset_only, [0.0, 1.0], atol=2e-3)          # what the offset alone read
    np.testing.assert_allclose(SM.mask_values(masks, p, n, g, 1.0, views=n)[0, :2], at_point, atol=1e-9)


def test_mask_lookup_offset_still_lifts_a_surface_off_its_wall():
    """A receiver on a wall's surface (x = 0.5, facing -x): half its footprint lies in the wall, whose samples hold
    both sides' clusters; the offset read (25 cm in front) holds only its own side's, which the point holds too
    (overlap 0.75 >= 0.5), so the offset read wins and the far side gets no weight."""
    masks, g = _wall_masks((0.5, 0.5))
    p, n = np.array([[0.5, 0.5, 0.5]]), np.array([[-1.0, 0.0, 0.0]])
    np.testing.assert_allclose(SM.mask_values(masks, p, n, g, 0.0)[0, :2], [0.75, 0.25], atol=3e-3)
    np.testing.assert_allclose(SM.mask_values(masks, p, n, g, 1.0, views=n)[0, :2], [1.0, 0.0], atol=1e-9)


def test_mask_lookup_offset_ending_inside_a_thin_wall_takes_nothing_from_its_far_side():
    """A receiver facing a wall thinner than two samples, one and a half samples in front of it: the offset
    (2 samples along n + v) ends in the wall's don't-care samples, filled half and half from both sides. The point
    sees part of that read (its own cluster) but not the far side's cluster, which the lookup no longer takes in
    (it took 0.5 x the offset read's far half before: tests/data/fidelity rooms-unequal, 5 cm from a 2 cm wall,
    normalized mask GI 1.6 of Cycles; now 1.06)."""
    masks, g = _wall_masks((0.5, 0.5))
    p, n = np.array([[0.3125, 0.5, 0.5]]), np.array([[1.0, 0.0, 0.0]])   # 1.5 samples in front of x = 0.5
    at_point = SM.mask_values(masks, p, n, g, 0.0)[0, :2]
    offset_only = SM.mask_values(masks, p + 0.25 * n, n, g, 0.0)[0, :2]
    np.testing.assert_allclose(at_point, [1.0, 0.0], atol=2e-3)
    np.testing.assert_allclose(offset_only, [0.5, 0.5], atol=3e-3)         # inside the wall: both sides
    got = SM.mask_values(masks, p, n, g, 1.0, views=n)[0, :2]
    assert got[1] == 0.0 and got[0] > 0.4                                   # no far side; own cluster kept


def test_lookup_blend_is_linear_between_the_overlap_bounds():
    from workers.kernels.compress import MASK_OVERLAP, MASK_PRESENT, lookup_blend

    lo, hi = MASK_OVERLAP
    a = np.array([[0.5, 0.5, 0.0]] * 3)
    seen = np.array([lo, (lo + hi) / 2, hi])              # share of a's clusters the point sees
    b = np.stack([np.full(3, 1.0), 2 * seen - 1, np.zeros(3)], axis=1)
    b[:, 1] = (2 * seen - 1) * MASK_PRESENT                # cluster 1 seen at that fraction of MASK_PRESENT
    a_seen = a * np.minimum(b / MASK_PRESENT, 1.0)         # only the clusters the point sees come from a
    got = lookup_blend([a, b])
    np.testing.assert_allclose(got[0], b[0])
    np.testing.assert_allclose(got[1], (a_seen[1] + b[1]) / 2)
    np.testing.assert_allclose(got[2], a_seen[2])
    assert got[2, 1] == 0.0                                # cluster 1, not seen at the point, is not taken from a
    np.testing.assert_array_equal(lookup_blend([b]), b)
    # a cluster seen at MASK_PRESENT or more counts fully: a thin-walled room's corner keeps the offset read
    far = np.array([[0.0, 1.0]])
    np.testing.assert_allclose(lookup_blend([np.array([[1.0, 0.0]]), np.array([[MASK_PRESENT, 1 - MASK_PRESENT]])]),
                               [[1.0, 0.0]])
    np.testing.assert_allclose(lookup_blend([far, np.array([[0.99, 0.01]])]), [[0.99, 0.01]])
