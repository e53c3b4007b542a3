"""Mask compression (MD §3.4.2): per-cell blocks with a border, merged, atlas + indirection.

Kernel tests on hand-made volumes (sparse / blocky / noisy), the ``compress`` stage through a hand-built
StageContext, and θ volumes of the procedural scenes baked through the real pipeline.
"""
from __future__ import annotations

import numpy as np
import pytest

from proto.models import BakeConfig
from workers.kernels import compress as C
from workers.stages.base import LazyArtifacts, StageContext, StageError

LAYOUTS = C.LAYOUTS


def blocky_volume(rng, counts, S, n_boxes=6, levels=(0, 255), soft=False):
    """A sparse RGBA8 refined-grid volume: zeros with a few random axis-aligned boxes of constant values
    (per channel), optionally with soft (ramped) values; box corners at arbitrary samples."""
    cells = C.cells_of(counts)
    shape = (int(cells[2]) * S, int(cells[1]) * S, int(cells[0]) * S)
    vol = np.zeros(shape + (4,), np.uint8)
    for _ in range(n_boxes):
        lo = [int(rng.integers(0, n)) for n in shape]
        hi = [int(rng.integers(a + 1, n + 1)) for a, n in zip(lo, shape)]
        val = rng.choice(levels, 4) if not soft else rng.integers(0, 256, 4)
        vol[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = val
    return vol


def random_points(rng, n, counts, origin, spacing, margin=0.0):
    counts = np.asarray(counts)
    ext = np.asarray(spacing) * np.maximum(counts - 1, 0)
    lo = np.asarray(origin) - margin * ext
    return lo + rng.random((n, 3)) * ext * (1 + 2 * margin)


BORDERS = {"bordered": (1, 1), "shared": (0, 1), "cell": (0, 0)}


def bordered_blocks_reference(vol, S, lo, hi=1):
    """Every cell's block straight from the definition: dense sample clamp(c·S − lo + a) per axis,
    0 <= a < T = S + lo + hi."""
    Z, Y, X = vol.shape[:3]
    T = S + lo + hi
    out = {}
    for k in range(Z // S):
        for j in range(Y // S):
            for i in range(X // S):
                zz = np.clip(k * S - lo + np.arange(T), 0, Z - 1)
                yy = np.clip(j * S - lo + np.arange(T), 0, Y - 1)
                xx = np.clip(i * S - lo + np.arange(T), 0, X - 1)
                out[k, j, i] = vol[np.ix_(zz, yy, xx)]
    return out


def atlas_block(atlas, indirection, meta, k, j, i):
    T = meta["block_size"]
    bx, by, bz = indirection[k, j, i, :3].astype(int)
    return atlas[bz * T:(bz + 1) * T, by * T:(by + 1) * T, bx * T:(bx + 1) * T]


GRID = dict(counts=(6, 5, 4), origin=np.array([1.0, -2.0, 0.5]), spacing=np.array([0.5, 0.7, 1.1]))


# ---------------------------------------------------------------------------- layout
def test_atlas_layout_fits_256_when_possible():
    for T in (3, 6, 9, 10, 34):
        m = 256 // T
        for n in sorted({1, 2, 7, m, m + 1, m * m, m ** 3 - 1, m ** 3}):
            bx, by, bz = C.atlas_layout(n, T)
            assert bx * by * bz >= n
            assert max(bx, by, bz) * T <= 256, (n, T, (bx, by, bz))
            if m <= 30:  # the fewest allocated blocks of any grid that fits (brute force)
                r = np.arange(1, m + 1)
                tot = r[:, None, None] * r[None, :, None] * r[None, None, :]
                assert bx * by * bz == tot[tot >= n].min()


def test_atlas_layout_exact_factorization_and_limits():
    assert np.prod(C.atlas_layout(1500, 10)) == 1500           # 25 x 20 x 3
    assert C.atlas_layout(1, 10) == (1, 1, 1)
    m = 256 // 10
    bx, by, bz = C.atlas_layout(m ** 3 + 1, 10)                 # does not fit 256: up to 2048
    assert max(bx, by, bz) * 10 > 256 and max(bx, by, bz) * 10 <= 2048 and bx * by * bz >= m ** 3 + 1
    with pytest.raises(ValueError):
        C.atlas_layout((2048 // 34) ** 3 + 1, 34)
    bx, by, bz = C.atlas_layout(300 ** 2, 3)                    # S = 1: byte block coordinates, <= 256 per axis
    assert max(bx, by, bz) <= 256 and bx * by * bz >= 300 ** 2
    with pytest.raises(ValueError):
        C.atlas_layout(256 ** 3 + 1, 3)
    with pytest.raises(ValueError):
        C.atlas_layout(0, 10)


# ---------------------------------------------------------------------------- lossless
@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("S", [1, 2, 5, 8])
def test_lossless_blocks_decompress_and_sampling(layout, S):
    rng = np.random.default_rng(S)
    counts, origin, spacing = GRID["counts"], GRID["origin"], GRID["spacing"]
    vol = blocky_volume(rng, counts, S, soft=True)
    cm = C.compress_masks(vol, counts, S, layout=layout)
    st, meta = cm.stats, cm.meta
    lo, hi = BORDERS[layout]
    T = S + lo + hi
    assert meta["block_size"] == T and meta["border_lo"] == lo and meta["border_hi"] == hi
    assert meta["layout"] == layout
    assert st["blocks"] == 5 * 4 * 3 and st["max_block_error"] == 0.0
    assert st["atlas_blocks"] == st["unique_blocks"] <= st["blocks"]
    (atlas,) = cm.atlases
    assert atlas.dtype == np.uint8 and atlas.shape == tuple(b * T for b in meta["block_grid"][::-1]) + (4,)
    assert list(atlas.shape[2::-1]) == meta["atlas_size"]
    assert cm.indirection.shape == (3, 4, 5, 4) and cm.indirection.dtype == np.uint8
    assert np.all(cm.indirection[..., 3] == 0)
    # every cell's block in the atlas is its bordered block, by definition
    for (k, j, i), ref in bordered_blocks_reference(vol, S, lo, hi).items():
        np.testing.assert_array_equal(atlas_block(atlas, cm.indirection, meta, k, j, i), ref)
    np.testing.assert_array_equal(C.decompress(atlas, cm.indirection, meta), vol)
    assert st["dense_bytes"] == vol.nbytes
    assert st["compressed_bytes"] == atlas.nbytes + cm.indirection.nbytes
    assert st["ratio"] == pytest.approx(vol.nbytes / st["compressed_bytes"])
    # 10k random points: the same trilinear samples (float64 coordinates: to rounding; float32, as GLSL:
    # the two paths round the texel coordinate differently, |Δ| ≲ 1e-5 · the step between neighbours)
    pts = random_points(rng, 10000, counts, origin, spacing)
    for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-4)):
        d = C.sample_dense(vol, pts, counts, origin, spacing, dtype=dtype)
        c = C.sample_compressed(atlas, cm.indirection, meta, pts, counts, origin, spacing, S, dtype=dtype)
        assert c.shape == (10000, 4) and c.min() >= 0.0 and c.max() <= 1.0
        assert np.abs(d - c).max() <= tol
    assert C.sample_error(vol, cm, counts, origin, spacing, S) <= 1 / 255


def test_sample_dense_hits_texel_centres_and_matches_field_convention():
    rng = np.random.default_rng(1)
    counts, origin, spacing, S = GRID["counts"], GRID["origin"], GRID["spacing"], 4
    vol = blocky_volume(rng, counts, S, soft=True)
    Z, Y, X = vol.shape[:3]
    z, y, x = np.meshgrid(np.arange(Z), np.arange(Y), np.arange(X), indexing="ij")
    idx = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    pts = origin + spacing * (idx + 0.5) / S                     # bundle.md §5: refined-grid sample positions
    got = C.sample_dense(vol, pts, counts, origin, spacing, dtype=np.float64)
    np.testing.assert_allclose(got, vol.reshape(-1, 4) / 255.0, atol=1e-12)
    cm = C.compress_masks(vol, counts, S, layout="shared")
    got = C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, pts, counts, origin, spacing, S, np.float64)
    np.testing.assert_allclose(got, vol.reshape(-1, 4) / 255.0, atol=1e-12)
    try:  # the reference samplers of the shading modes, when present: the same filter
        from workers.kernels.samplers import field_uvw, trilinear
    except ImportError:
        return
    q = random_points(rng, 2000, counts, origin, spacing, margin=0.2)
    grid = {"counts": list(counts), "origin": origin, "spacing": spacing}
    # the own-cell rule: plain trilinear inside the box of a cell's sample centres, ...
    g = (q - np.asarray(origin)) / np.asarray(spacing)
    frac = g - np.floor(g)
    inside = np.all((frac > 0.5 / S) & (frac < 1 - 0.5 / S), axis=1) & np.all((g > 0) & (g < C.cells_of(counts)), 1)
    assert inside.sum() > 100
    np.testing.assert_allclose(C.sample_dense(vol, q[inside], counts, origin, spacing, np.float64),
                               trilinear(vol, field_uvw(q[inside], grid)), atol=1e-12)
    # ... and within half a sample of a face the texel coordinate stops at the cell's own last sample
    cells = C.cells_of(counts)
    cell = np.clip(np.floor(g), 0, cells - 1)
    t = np.clip(g * S - 0.5, cell * S, cell * S + S - 1)
    dims = np.array(vol.shape[2::-1], np.float64)
    np.testing.assert_allclose(C.sample_dense(vol, q, counts, origin, spacing, np.float64),
                               trilinear(vol, (t + 0.5) / dims), atol=1e-12)
    assert not np.allclose(C.sample_dense(vol, q[~inside], counts, origin, spacing, np.float64),
                           trilinear(vol, field_uvw(q[~inside], grid)), atol=1e-6)


# ---------------------------------------------------------------------------- merging
@pytest.mark.parametrize("layout", LAYOUTS)
def test_identical_blocks_merge(layout):
    counts, S = (9, 7, 5), 4
    vol = np.zeros((4 * S, 6 * S, 8 * S, 4), np.uint8)
    cm = C.compress_masks(vol, counts, S, layout=layout)
    assert cm.stats["unique_blocks"] == 1 and cm.stats["block_grid"] == [1, 1, 1]
    assert np.all(cm.indirection == 0)
    vol[:, :, :, 2] = 255                                        # still constant
    vol[5:9, 9:14, 10:13] = (10, 20, 30, 40)                    # one small box: only nearby cells differ
    cm = C.compress_masks(vol, counts, S, layout=layout)
    touched = set()
    lo, hi = BORDERS[layout]
    for (k, j, i), ref in bordered_blocks_reference(vol, S, lo, hi).items():
        if not np.all(ref == ref[0, 0, 0]):
            touched.add((k, j, i))
    assert cm.stats["unique_blocks"] == len(touched) + 1
    assert cm.stats["ratio"] > 4
    np.testing.assert_array_equal(C.decompress(cm.atlases[0], cm.indirection, cm.meta), vol)
    # the most used block takes slot 0
    assert np.all(cm.slot_of_cell[0, 0, 0] == 0)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_two_volumes_share_one_indirection(layout):
    """K > 4: a cell's key is its blocks in both volumes; each atlas decompresses to its own volume."""
    rng = np.random.default_rng(3)
    counts, origin, spacing, S = GRID["counts"], GRID["origin"], GRID["spacing"], 4
    v0 = np.zeros((3 * S, 4 * S, 5 * S, 4), np.uint8)             # all blocks identical in volume 0
    v1 = blocky_volume(rng, counts, S, n_boxes=3)                # ... not in volume 1
    one = C.compress_masks(v0, counts, S, layout=layout)
    two = C.compress_masks([v0, v1], counts, S, layout=layout)
    alone = C.compress_masks(v1, counts, S, layout=layout)
    assert one.stats["unique_blocks"] == 1
    assert two.stats["unique_blocks"] == alone.stats["unique_blocks"] > 1
    assert len(two.atlases) == 2 and two.atlases[0].shape == two.atlases[1].shape
    assert two.stats["dense_bytes"] == v0.nbytes + v1.nbytes
    assert two.stats["compressed_bytes"] == two.atlases[0].nbytes * 2 + two.indirection.nbytes
    for v, a in zip((v0, v1), two.atlases):
        np.testing.assert_array_equal(C.decompress(a, two.indirection, two.meta), v)
    # and the other way round: the key is the pair of blocks
    assert C.compress_masks([v1, v0], counts, S, layout=layout).stats["unique_blocks"] == alone.stats["unique_blocks"]
    pts = random_points(rng, 10000, counts, origin, spacing)
    for v, a in zip((v0, v1), two.atlases):
        d = C.sample_dense(v, pts, counts, origin, spacing)
        c = C.sample_compressed(a, two.indirection, two.meta, pts, counts, origin, spacing, S)
        assert np.abs(d - c).max() <= 1e-4
    assert C.sample_error([v0, v1], two, counts, origin, spacing, S) <= 1e-4


# ---------------------------------------------------------------------------- tolerance
@pytest.mark.parametrize("layout", LAYOUTS)
def test_tolerance_merges_within_the_reported_bound(layout):
    rng = np.random.default_rng(7)
    counts, origin, spacing, S = (9, 6, 7), np.zeros(3), np.array([1.0, 0.8, 1.2]), 4
    base = blocky_volume(rng, counts, S, n_boxes=4)
    noise = rng.integers(-3, 4, base.shape) * (rng.random(base.shape[:3]) < 0.02)[..., None]
    vol = np.clip(base.astype(int) + noise, 0, 255).astype(np.uint8)   # sparse ±3 noise: blocks differ slightly
    exact = C.compress_masks(vol, counts, S, layout=layout)
    refs = bordered_blocks_reference(vol, S, *BORDERS[layout])
    prev = exact
    for tol in (1 / 255, 3 / 255, 0.05):
        cm = C.compress_masks(vol, counts, S, tol, layout=layout)
        st = cm.stats
        assert st["tolerance"] == tol and st["max_block_error"] <= tol + 1e-12
        assert st["atlas_blocks"] <= prev.stats["atlas_blocks"] and st["unique_blocks"] == exact.stats["unique_blocks"]
        # the bound is exact: the largest texel difference of any cell's block (borders included)
        worst = max(np.abs(atlas_block(cm.atlases[0], cm.indirection, cm.meta, *kji).astype(int) - ref).max()
                    for kji, ref in refs.items())
        assert worst / 255 == pytest.approx(st["max_block_error"])
        # ... and it bounds the trilinear samples anywhere (convex combinations of texels)
        pts = random_points(rng, 10000, counts, origin, spacing, margin=0.05)
        err = np.abs(C.sample_dense(vol, pts, counts, origin, spacing, np.float64)
                     - C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, pts, counts, origin, spacing,
                                           S, np.float64)).max()
        assert err <= st["max_block_error"] + 1e-12
        assert C.sample_error(vol, cm, counts, origin, spacing, S) <= st["max_block_error"] + 1e-4
        prev = cm
    assert prev.stats["atlas_blocks"] < exact.stats["unique_blocks"]
    assert prev.stats["ratio"] > exact.stats["ratio"]
    assert prev.stats["max_block_error"] > 0


def test_tolerance_zero_below_one_step_is_lossless():
    rng = np.random.default_rng(2)
    vol = blocky_volume(rng, GRID["counts"], 3, soft=True)
    a = C.compress_masks(vol, GRID["counts"], 3, 0.0)
    b = C.compress_masks(vol, GRID["counts"], 3, 0.5 / 255)    # floor(255·tol) = 0: exact merging only
    assert b.stats["atlas_blocks"] == a.stats["atlas_blocks"] and b.stats["max_block_error"] == 0.0
    with pytest.raises(ValueError):
        C.compress_masks(vol, GRID["counts"], 3, -0.1)


# ---------------------------------------------------------------------------- edges
@pytest.mark.parametrize("layout", LAYOUTS)
def test_cell_boundaries_corners_and_outside_points(layout):
    rng = np.random.default_rng(11)
    counts, origin, spacing, S = GRID["counts"], GRID["origin"], GRID["spacing"], 4
    vol = blocky_volume(rng, counts, S, soft=True, n_boxes=10)
    cm = C.compress_masks(vol, counts, S, layout=layout)
    cells = C.cells_of(counts)
    # points exactly on cell faces / edges / corners (integer grid coordinates) and on sample planes
    gi = [np.arange(c + 1, dtype=np.float64) for c in cells]
    gx, gy, gz = np.meshgrid(*gi, indexing="ij")
    on_faces = origin + spacing * np.stack([gx.ravel(), gy.ravel(), gz.ravel()], 1)
    mixed = origin + spacing * np.stack([rng.integers(0, cells[a] + 1, 3000) if a == 0 else
                                         rng.random(3000) * cells[a] for a in range(3)], 1)
    half = origin + spacing * (rng.integers(0, cells * S, (3000, 3)) + 0.5) / S          # sample centres
    edge = origin + spacing * (rng.integers(0, cells * S + 1, (3000, 3))) / S            # between samples
    far = random_points(rng, 3000, counts, origin, spacing, margin=2.0)                  # mostly outside
    ext = spacing * (np.asarray(counts) - 1)
    for pts in (on_faces, mixed, half, edge, far):
        for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-4)):
            d = C.sample_dense(vol, pts, counts, origin, spacing, dtype)
            c = C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, pts, counts, origin, spacing, S, dtype)
            assert np.abs(d - c).max() <= tol
    # outside points return what the nearest point of the grid box returns (clamp to edge)
    clamped = np.clip(far, origin, origin + ext)
    np.testing.assert_allclose(
        C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, far, counts, origin, spacing, S, np.float64),
        C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, clamped, counts, origin, spacing, S,
                            np.float64), atol=1e-12)
    # the grid-box corners are the corner samples exactly
    corners = origin + ext * np.array([[a & 1, a >> 1 & 1, a >> 2 & 1] for a in range(8)])
    want = np.array([vol[-1 if a >> 2 & 1 else 0, -1 if a >> 1 & 1 else 0, -1 if a & 1 else 0]
                     for a in range(8)]) / 255.0
    got = C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, corners, counts, origin, spacing, S, np.float64)
    np.testing.assert_allclose(got, want, atol=1e-12)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("counts,spacing", [((2, 2, 2), (1.0, 2.0, 0.5)),      # a single cell
                                            ((2, 5, 3), (0.7, 0.4, 1.0)),      # one cell along x
                                            ((4, 1, 3), (0.5, 0.0, 0.5)),      # one-probe y axis (spacing 0)
                                            ((1, 1, 2), (0.0, 0.0, 1.0))])
def test_one_cell_axes(layout, counts, spacing):
    rng = np.random.default_rng(5)
    origin, spacing, S = np.array([0.3, -1.0, 2.0]), np.array(spacing), 4
    vol = blocky_volume(rng, counts, S, soft=True, n_boxes=5)
    cm = C.compress_masks(vol, counts, S, layout=layout)
    cells = C.cells_of(counts)
    assert cm.indirection.shape == (cells[2], cells[1], cells[0], 4)
    np.testing.assert_array_equal(C.decompress(cm.atlases[0], cm.indirection, cm.meta), vol)
    pts = random_points(rng, 5000, counts, origin, spacing, margin=0.3)
    pts[:, spacing == 0] += rng.normal(size=(5000, int((spacing == 0).sum())))   # off the probe plane
    for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-4)):
        d = C.sample_dense(vol, pts, counts, origin, spacing, dtype)
        c = C.sample_compressed(cm.atlases[0], cm.indirection, cm.meta, pts, counts, origin, spacing, S, dtype)
        assert np.all(np.isfinite(c)) and np.abs(d - c).max() <= tol


def test_bad_volumes_are_refused():
    counts, S = (3, 3, 3), 2
    good = np.zeros((4, 4, 4, 4), np.uint8)
    C.compress_masks(good, counts, S)
    for bad in (np.zeros((4, 4, 5, 4), np.uint8), np.zeros((4, 4, 4, 3), np.uint8), np.zeros((4, 4, 4, 4), np.float32)):
        with pytest.raises(ValueError):
            C.compress_masks(bad, counts, S)
    with pytest.raises(ValueError):
        C.compress_masks([good, np.zeros((4, 4, 4, 3), np.uint8)], counts, S)
    with pytest.raises(ValueError):
        C.compress_masks(good, counts, S, layout="tiled")


# ---------------------------------------------------------------------------- stage
def _ctx(volumes: dict, counts, origin, spacing, S, tol=0.0, K=None):
    cfg = BakeConfig.model_validate({"place": {"counts": list(counts)}, "visibility": {"samples_per_cell": S},
                                     "masks": {"compress_tolerance": tol}})
    place = {"counts": list(counts), "origin": list(map(float, origin)), "spacing": list(map(float, spacing))}
    K = K or 4 * len(volumes)
    return StageContext(config=cfg, scene_loader=lambda: None,
                        inputs={"masks": LazyArtifacts({"clusters": K}, {k: (lambda v=v: v) for k, v in volumes.items()}),
                                "place": LazyArtifacts(place, {})},
                        report=lambda f: None)


@pytest.mark.parametrize("two", [False, True])
def test_stage_run_compress(two):
    from proto.ktx2 import decode_ktx2, encode_ktx2
    from workers.kernels.mask_atlas import decompress_channels
    from workers.stages.compress import ZSTD_LEVEL, run_compress

    rng = np.random.default_rng(13)
    counts, origin, spacing, S = (7, 4, 5), np.array([0.0, 1.0, -1.0]), np.array([0.5, 0.5, 0.6]), 8
    vols = {"masks_0123": blocky_volume(rng, counts, S, n_boxes=3)}
    if two:
        vols["masks_4567"] = blocky_volume(rng, counts, S, n_boxes=3)
    out = run_compress(_ctx(vols, counts, origin, spacing, S))
    names = [a.name for a in out.artifacts]
    assert names == ["mask_atlas", "mask_indirection"]
    st = out.stats
    for key in ("channel_blocks", "constant_zero", "constant_one", "unique_blocks", "atlas_blocks", "dense_bytes",
                "atlas_bytes", "indirection_bytes", "compressed_bytes", "ratio", "compressed_zstd_bytes",
                "ratio_stored", "max_block_error", "max_sample_error", "tolerance", "layout", "block_grid", "fits_256"):
        assert key in st
    K = 8 if two else 4
    assert st["channel_blocks"] == 6 * 3 * 4 * K and st["tolerance"] == 0.0 and st["fits_256"]
    assert st["max_sample_error"] <= 1e-9 and st["ratio"] > 1 and st["compressed_bytes"] < st["dense_bytes"]
    assert st["ratio_stored"] == st["dense_bytes"] / st["compressed_zstd_bytes"]
    arts = {a.name: a for a in out.artifacts}
    meta = arts["mask_indirection"].meta
    assert meta["samples_per_cell"] == S and meta["block_size"] == S and meta["border_lo"] == 0
    assert meta["layout"] == "channel" and meta["clusters"] == K and meta["groups"] == K // 4
    ind, atlas = arts["mask_indirection"].data, arts["mask_atlas"].data
    assert ind.shape == (2 * (K // 4) * 4, 3, 6, 4) and ind.dtype == np.uint8
    assert atlas.dtype == np.uint8 and atlas.ndim == 4 and atlas.shape[3] == 1 and arts["mask_atlas"].meta == meta
    stored = 0
    for x in (atlas, ind):
        back, info = decode_ktx2(encode_ktx2(x, zstd_level=ZSTD_LEVEL))    # R8 / RGBA8 3D KTX2, as stored
        np.testing.assert_array_equal(back.reshape(x.shape), x)
        stored += info["byte_length"]
    assert st["compressed_zstd_bytes"] == stored      # the stats' sizes are the frames the artifacts store
    for got, want in zip(decompress_channels(atlas, ind, meta), vols.values()):
        np.testing.assert_array_equal(got, want)
    import json
    json.dumps(st), json.dumps(meta)                                        # JSON-able


def test_stage_tolerance_and_bad_input():
    from workers.stages.compress import run_compress

    rng = np.random.default_rng(17)
    counts, origin, spacing, S = (7, 4, 5), np.zeros(3), np.ones(3), 4
    v = blocky_volume(rng, counts, S, n_boxes=3, levels=(0, 120, 255))
    v = np.clip(v.astype(int) + rng.integers(-2, 3, v.shape) * (rng.random(v.shape) < 0.01), 0, 255).astype(np.uint8)
    exact = run_compress(_ctx({"masks_0123": v}, counts, origin, spacing, S)).stats
    lossy = run_compress(_ctx({"masks_0123": v}, counts, origin, spacing, S, tol=0.01)).stats
    assert lossy["atlas_blocks"] < exact["atlas_blocks"] and lossy["ratio"] > exact["ratio"]
    assert exact["max_block_error"] == 0 and exact["max_sample_error"] <= 1e-9 and exact["max_read_error"] <= 1e-9
    assert 0 < lossy["max_block_error"] <= 0.01 and lossy["max_read_error"] <= lossy["max_block_error"] + 1e-9
    with pytest.raises(StageError):
        run_compress(_ctx({"masks_0123": v[:-1]}, counts, origin, spacing, S))
    with pytest.raises(StageError):
        run_compress(_ctx({}, counts, origin, spacing, S))


# ---------------------------------------------------------------------------- procedural scenes
SCENE_GRIDS = {"cornell": [10, 10, 10], "two-rooms": [16, 6, 8], "sealed-box": [8, 8, 8]}


@pytest.mark.parametrize("scene", sorted(SCENE_GRIDS))
def test_theta_volumes_of_procedural_scenes_compress(tmp_path, scene_files, scene):
    """θ (the visibility stage's RGBA8 volumes, the masks' format) of each procedural scene: lossless,
    smaller than dense with either layout, K ≤ 4 (θ_0123) and K > 4 (θ_0123 + θ_4567)."""
    from tests.workers.test_probes import bake_until

    cfg = {"place": {"counts": SCENE_GRIDS[scene]}, "trace": {"rays_per_probe": 64}, "visibility": {"slabs": 1}}
    _, s = bake_until(tmp_path, scene_files[scene], cfg, "visibility")
    place = s["place"].stats
    counts, origin, spacing = place["counts"], place["origin"], place["spacing"]
    S = 8
    t0123, t4567 = s["visibility"]["theta_0123"], s["visibility"]["theta_4567"]
    for vols in ([t0123], [t0123, t4567]):
        ratios = {}
        for layout in LAYOUTS:
            cm = C.compress_masks(vols, counts, S, layout=layout)
            st = cm.stats
            assert st["compressed_bytes"] < st["dense_bytes"], (scene, layout, st)
            assert st["fits_256"]
            for v, a in zip(vols, cm.atlases):
                np.testing.assert_array_equal(C.decompress(a, cm.indirection, cm.meta), v)
            assert C.sample_error(vols, cm, counts, origin, spacing, S) <= 1e-4
            ratios[layout] = st["ratio"]
        assert ratios["shared"] > ratios["bordered"]
