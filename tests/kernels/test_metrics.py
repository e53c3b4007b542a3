"""Image metrics of the evaluate stage (workers/kernels/metrics.py)."""
from __future__ import annotations

import io
import math

import numpy as np
import pytest

from workers.kernels import metrics as M


def _img(seed=0, h=48, w=64, scale=1.0):
    rng = np.random.default_rng(seed)
    return (rng.random((h, w, 3)) * scale).astype(np.float32)


def test_rmse_md_4_2():
    a = _img(1)
    assert M.rmse(a, a) == 0.0
    assert np.all(M.pixel_error(a, a) == 0)
    b = a.copy()
    b[..., 0] += 0.3                        # one channel off by 0.3 everywhere: E(x) = sqrt(0.09/3)
    np.testing.assert_allclose(M.pixel_error(b, a), math.sqrt(0.09 / 3), rtol=1e-6)
    np.testing.assert_allclose(M.rmse(b, a), math.sqrt(0.03), rtol=1e-6)
    mask = np.zeros(a.shape[:2], bool)
    mask[:10] = True
    c = a.copy()
    c[~mask] = 1 - c[~mask]                  # errors outside the mask do not count
    assert M.rmse(c, a, mask) == 0.0
    assert M.rmse(c, a) > 0
    assert M.relative_rmse(a, a) == 0.0 and M.relative_rmse(2 * a, a) > 0.5
    with pytest.raises(ValueError):
        M.rmse(a, a[:, :10])
    with pytest.raises(ValueError):
        M.rmse(a[..., :2], a[..., :2])


def test_tonemap_fixed_and_bounded():
    hdr = _img(2, scale=50.0)
    k = M.exposure_for(hdr)
    ldr = M.tonemap(hdr, k)
    assert ldr.dtype == np.float32 and ldr.min() >= 0 and ldr.max() <= 1
    assert M.tonemap(np.zeros((2, 2, 3)), k).max() == 0
    # monotone per channel, and one exposure for all images of a comparison
    x = np.linspace(0, 10, 100)[None, :, None].repeat(3, axis=2)
    y = M.tonemap(x, 1.0)[0, :, 0]
    assert np.all(np.diff(y) >= 0) and y[-1] > 0.99
    # the median luminance maps to key 0.18 before the curve, whatever the extremes
    flat = np.full((5, 5, 3), 7.0)
    assert abs(M.exposure_for(flat) * 7.0 - 0.18) < 1e-12
    flat[0, :3] = 1e6
    flat[1, :3] = 0.0
    assert abs(M.exposure_for(flat) * 7.0 - 0.18) < 1e-12
    assert M.exposure_for(np.zeros((3, 3, 3))) == 1.0


def test_flip():
    a = M.tonemap(_img(3, scale=2.0), 1.0)
    assert M.flip_mean(a, a) == 0.0
    black = np.zeros((64, 64, 3), np.float32)
    white = np.ones((64, 64, 3), np.float32)
    assert M.flip_mean(black, white) > 0.5
    v, emap = M.flip_mean(black, white, return_map=True)
    assert emap.shape == (64, 64) and 0 <= emap.min() and emap.max() <= 1
    mask = np.zeros((64, 64), bool)
    mask[:8, :8] = True
    assert M.flip_mean(black, white, mask) > 0.5
    b = a.copy()
    b[10:20, 10:20] = 1 - b[10:20, 10:20]
    assert 0 < M.flip_mean(b, a) < M.flip_mean(black, white)
    # invalid inputs raise ValueError here instead of reaching flip-evaluator (which exits the process)
    for bad in (np.full((8, 8, 3), 2.0, np.float32), np.full((8, 8, 3), np.nan, np.float32)):
        with pytest.raises(ValueError):
            M.flip_mean(bad, np.zeros((8, 8, 3), np.float32))
    with pytest.raises(ValueError):
        M.flip_mean(np.zeros((8, 8, 3)), np.zeros((8, 9, 3)))
    with pytest.raises(ValueError):
        M.flip_mean(np.zeros((8, 8)), np.zeros((8, 8)))
    with pytest.raises(ValueError):
        M.flip_mean(a, a, ppd=0)


def test_leak_score():
    ref = np.ones((20, 20, 3), np.float32)
    ref[:, :5] = 0.0                     # a dark quarter: mean luminance 0.75
    assert M.leak_score(ref, ref)["leak"] == 0.0
    test = ref.copy()
    test[:, :5] = 0.3                    # light leaks into the dark part
    s = M.leak_score(test, ref)
    assert s["dark_pixels"] == 100 and abs(s["dark_fraction"] - 0.25) < 1e-9
    np.testing.assert_allclose(s["leak"], 0.3 / 0.75, rtol=1e-6)
    # errors in lit places do not count
    lit_err = ref.copy()
    lit_err[:, 5:] *= 1.5
    assert M.leak_score(lit_err, ref)["leak"] == 0.0
    # no reference light at all: 0 by definition
    assert M.leak_score(ref, np.zeros_like(ref))["leak"] == 0.0
    mask = np.zeros((20, 20), bool)
    mask[:, 3:] = True
    assert M.leak_score(test, ref, mask)["dark_pixels"] == 40


def test_images_png_heatmap_contact_sheet():
    from PIL import Image

    err = np.linspace(0, 1, 64 * 8).reshape(8, 64)
    hm = M.heatmap(err)
    assert hm.shape == (8, 64, 3) and hm.dtype == np.uint8
    assert hm[0, 0, 2] > 100 and hm[0, 0, 0] == 0          # 0: blue
    assert hm[-1, -1, 0] > 100 and hm[-1, -1, 2] == 0      # 1: red
    mask = np.ones(err.shape, bool)
    mask[0] = False
    assert np.all(M.heatmap(err, mask=mask)[0] == 0)
    png = M.png_bytes(hm)
    back = np.asarray(Image.open(io.BytesIO(png)))
    assert np.array_equal(back, hm)
    sheet = M.contact_sheet([("a", hm), ("b", np.zeros((20, 30, 3))), ("c", err)], columns=2)
    assert sheet.dtype == np.uint8 and sheet.ndim == 3 and sheet.shape[1] >= 2 * 64
    assert M.flip_magma(err).shape == (8, 64, 3)
    with pytest.raises(ValueError):
        M.contact_sheet([])
