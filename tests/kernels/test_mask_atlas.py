"""Channel-block mask compression (workers/kernels/mask_atlas.py; MD §3.4.2 per mask channel): codes, atlas,
lossless round trip, the tolerance bound, the sampler against the dense lookup, K > 4, bad input."""
from __future__ import annotations

import numpy as np
import pytest

from tests.kernels.test_compress import GRID, blocky_volume, random_points
from workers.kernels import compress as C
from workers.kernels import mask_atlas as MA


def _volumes(rng, counts, S, K, **kw):
    vols = [blocky_volume(rng, counts, S, **kw) for _ in range(-(-K // 4))]
    vols[-1][..., K - 4 * (len(vols) - 1):] = 0                                # channels >= K are 0
    return vols


@pytest.mark.parametrize("K", [3, 4, 6, 8])
def test_lossless_round_trip_codes_and_sampling(K):
    rng = np.random.default_rng(K)
    counts, S = GRID["counts"], 4
    vols = _volumes(rng, counts, S, K, n_boxes=5, levels=(0, 90, 255))
    ca = MA.compress_channels(vols, counts, S, K)
    for got, want in zip(MA.decompress_channels(ca.atlas, ca.indirection, ca.meta), vols):
        np.testing.assert_array_equal(got, want)
    # codes from the definition: 0 = all 0, 1 = all 255, else a slot holding exactly the block
    cells = C.cells_of(counts)
    dense = np.concatenate(vols, axis=3)
    codes = MA.codes_of(ca.indirection, K)
    assert codes.shape == (cells[2], cells[1], cells[0], K) and np.array_equal(codes, ca.codes)
    assert ca.indirection.shape == (2 * len(vols) * cells[2], cells[1], cells[0], 4)
    bx, by = ca.meta["block_grid"][:2]
    for (k, j, i, c), code in np.ndenumerate(codes):
        blk = dense[k * S:(k + 1) * S, j * S:(j + 1) * S, i * S:(i + 1) * S, c]
        if code == MA.CODE_ZERO:
            assert blk.max() == 0
        elif code == MA.CODE_ONE:
            assert blk.min() == 255
        else:
            s = code - MA.FIRST_SLOT
            x, y, z = s % bx, (s // bx) % by, s // (bx * by)
            np.testing.assert_array_equal(ca.atlas[z * S:(z + 1) * S, y * S:(y + 1) * S, x * S:(x + 1) * S, 0], blk)
    st = ca.stats
    assert st["constant_zero"] + st["constant_one"] + (codes >= 2).sum() == st["channel_blocks"] == codes.size
    assert st["atlas_blocks"] == st["unique_blocks"] == len(np.unique(
        dense.reshape(cells[2], S, cells[1], S, cells[0], S, -1)[..., :K].transpose(0, 2, 4, 6, 1, 3, 5)
        .reshape(-1, S ** 3)[(codes >= 2).reshape(-1)], axis=0))
    assert st["max_block_error"] == 0 and st["compressed_bytes"] == ca.atlas.nbytes + ca.indirection.nbytes
    # the runtime lookup (offset along n + v and at the point, blended) equals the dense one
    pts = random_points(rng, 3000, counts, GRID["origin"], GRID["spacing"], margin=0.1)
    d = rng.normal(size=pts.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    from workers.kernels.samplers import mask_values

    want = mask_values(vols, pts, d, GRID, 1.0)[:, :K]
    got = MA.sample_channel_atlas(ca.atlas, ca.indirection, ca.meta, pts, counts, GRID["origin"], GRID["spacing"],
                                  np.float64, dirs=d, samples=1.0)
    assert np.abs(got - want).max() < 1e-9
    got32 = MA.sample_channel_atlas(ca.atlas, ca.indirection, ca.meta, pts, counts, GRID["origin"], GRID["spacing"])
    want0 = mask_values(vols, pts, d, GRID, 0.0)[:, :K]
    assert np.abs(got32 - want0).max() < 1e-4                               # float32 coordinates (GLSL highp)


def test_channel_blocks_repeat_where_cell_blocks_do_not():
    """The same wall between clusters 0 | 1 in one cell and 2 | 3 in another: one RGBA cell block each, one shared
    channel block (the per-channel layout's point)."""
    counts, S = (3, 2, 2), 4
    v = np.zeros((S, S, 2 * S, 4), np.uint8)
    ramp = np.linspace(0, 255, S).round().astype(np.uint8)[None, None, :]
    v[:, :, :S, 0], v[:, :, :S, 1] = ramp, 255 - ramp
    v[:, :, S:, 2], v[:, :, S:, 3] = ramp, 255 - ramp
    cell = C.compress_masks(v, counts, S, layout="cell")
    ch = MA.compress_channels(v, counts, S, 4)
    assert cell.stats["unique_blocks"] == 2 and ch.stats["atlas_blocks"] == 2       # ramp, 255 - ramp
    assert ch.stats["constant_zero"] == 4 and ch.stats["ratio"] > cell.stats["ratio"]


def test_tolerance_bound_and_constant_codes():
    rng = np.random.default_rng(5)
    counts, S = GRID["counts"], 4
    base = blocky_volume(rng, counts, S, n_boxes=6, levels=(0, 128, 255))
    noisy = np.clip(base.astype(int) + rng.integers(-3, 4, base.shape), 0, 255).astype(np.uint8)
    exact = MA.compress_channels(noisy, counts, S, 4)
    lossy = MA.compress_channels(noisy, counts, S, 4, tolerance=4 / 255)
    assert lossy.stats["atlas_blocks"] < exact.stats["atlas_blocks"]
    assert lossy.stats["constant_zero"] + lossy.stats["constant_one"] > exact.stats["constant_zero"] + \
        exact.stats["constant_one"]                                         # near-constant blocks take codes 0 / 1
    dec = MA.decompress_channels(lossy.atlas, lossy.indirection, lossy.meta)[0]
    err = np.abs(dec.astype(int) - noisy.astype(int)).max()
    assert 0 < err <= 4 and lossy.stats["max_block_error"] == err / 255.0
    MA.compress_channels(noisy, counts, S, 4, tolerance=0.9 / 255)          # below one step: lossless
    assert np.array_equal(MA.decompress_channels(*_parts(MA.compress_channels(noisy, counts, S, 4, 0.9 / 255)))[0],
                          noisy)


def test_tolerance_never_merges_across_zeros():
    """A hidden cluster (0) stays hidden and a seen one stays seen: blocks within the tolerance that differ in where
    they are 0 are not merged (merging them would add light through a wall)."""
    counts, S = (3, 2, 2), 4
    v = np.full((S, S, 2 * S, 4), 128, np.uint8)
    v[..., 1:] = 0
    v[0, 0, 0, 0] = 0                                      # cell 0: one sample of cluster 0 hidden
    v[0, 0, S, 0] = 2                                      # cell 1: the same sample barely seen
    ca = MA.compress_channels(v, counts, S, 4, tolerance=8 / 255)
    assert ca.stats["atlas_blocks"] == 2
    np.testing.assert_array_equal(MA.decompress_channels(*_parts(ca))[0], v)
    v[0, 0, 0, 0], v[0, 0, S, 0] = 126, 120                # no zero involved: one block
    assert MA.compress_channels(v, counts, S, 4, tolerance=8 / 255).stats["atlas_blocks"] == 1


def _parts(ca):
    return ca.atlas, ca.indirection, ca.meta


def test_all_constant_and_bad_input():
    counts, S = (3, 3, 2), 2
    v = np.zeros((S, 2 * S, 2 * S, 4), np.uint8)
    v[..., 1] = 255
    ca = MA.compress_channels(v, counts, S, 2)
    assert ca.stats["atlas_blocks"] == 0 and ca.atlas.shape == (S, S, S, 1)         # one zero slot
    assert np.array_equal(MA.decompress_channels(*_parts(ca))[0], v)
    with pytest.raises(ValueError):
        MA.compress_channels(v, counts, S, 5)                               # 5 clusters need 2 volumes
    with pytest.raises(ValueError):
        MA.compress_channels(v[:-1], counts, S, 2)
    with pytest.raises(ValueError):
        MA.compress_channels(v.astype(np.float32), counts, S, 2)
    with pytest.raises(ValueError):
        MA.compress_channels(v, counts, S, 2, tolerance=1.5)


def _greedy_reference(blocks, order, thr):
    """The module doc's greedy clustering, plainly: each block joins the first representative (in the order made)
    within thr of it everywhere and 0 exactly where it is 0, else it becomes one."""
    reps, rep_of = [], {}
    for u in order:
        for r in reps:
            d = np.abs(blocks[u].astype(int) - blocks[r].astype(int))
            if d.max() <= thr and np.array_equal(blocks[u] == 0, blocks[r] == 0):
                rep_of[u] = r
                break
        else:
            reps.append(u)
            rep_of[u] = u
    return [rep_of[u] for u in range(len(blocks))], reps


@pytest.mark.parametrize("thr", [1, 6, 40])
def test_bucketed_merge_is_the_plain_greedy(thr):
    rng = np.random.default_rng(thr)
    S = 4
    base = rng.choice([0, 60, 200, 255], (12, S ** 3)).astype(np.uint8)
    blocks = np.clip(base[rng.integers(0, 12, 300)].astype(int) + rng.integers(-thr, thr + 1, (300, S ** 3))
                     * (rng.random((300, S ** 3)) < 0.2), 0, 255).astype(np.uint8)
    order = rng.permutation(300)
    rep_of, err, reps = MA._merge(blocks, S, order, thr)
    want_of, want_reps = _greedy_reference(blocks, order, thr)
    assert list(reps) == want_reps and list(rep_of) == want_of and len(want_reps) < 300
    assert all(np.abs(blocks[u].astype(int) - blocks[r].astype(int)).max() == e for u, (r, e) in
               enumerate(zip(rep_of, err)))
