"""workers/kernels/precision.py: the storage formats of the float artifacts and when they fall back to float32."""
from __future__ import annotations

import numpy as np
import pytest

from proto.ktx2 import decode_ktx2, encode_ktx2
from workers.kernels.precision import HALF_MAX, SMALLEST_SCALE, half, relative_rmse, rgb9e5, rgb_ufloat


def _atlas(rng, scale=100.0, shape=(20, 30, 4)):
    a = (rng.uniform(0.0, 1.0, shape) * scale).astype(np.float32)
    a[..., 3] = 1.0
    return a


def test_irradiance_packs_to_11_11_10_floats_and_reads_back_what_it_reports():
    a = _atlas(np.random.default_rng(1))
    data, vk, meta = rgb_ufloat(a)
    assert vk == "B10G11R11_UFLOAT_PACK32" and data.shape == a.shape[:-1] + (3,) and data.dtype == np.float32
    back, info = decode_ktx2(encode_ktx2(data, vk, 3))          # the stored values are exactly representable
    assert info["pixel_size"] == 4 and np.array_equal(back, data)
    err = relative_rmse(data, a[..., :3])
    assert meta["precision"] == {"format": vk, "relative_rmse": err}
    assert 1e-3 < err < 1e-2                                      # 6- and 5-bit mantissas: well under 1%
    assert np.all(np.abs(data - a[..., :3]) <= a[..., :3] * 2.0 ** -6 + 1e-30)   # round to nearest: ≤ half a step
    again = rgb_ufloat(a.copy())
    assert np.array_equal(again[0], data) and again[2] == meta   # deterministic


@pytest.mark.parametrize("pack, name", [(rgb_ufloat, "B10G11R11_UFLOAT_PACK32"), (rgb9e5, "E5B9G9R9_UFLOAT_PACK32")],
                         ids=["11-11-10", "rgb9e5"])
@pytest.mark.parametrize("change, want, why", [
    (lambda a: a.__setitem__((0, 0, 0), -0.5), "R16G16B16A16_SFLOAT", "negative"),
    (lambda a: a.__setitem__((0, 0, 1), 65450.0), "R16G16B16A16_SFLOAT", "> 65"),     # > 65024 resp. > 65408
    (lambda a: a.__setitem__((0, 0, 2), 70000.0), "R32G32B32A32_SFLOAT", "> 65504"),
    (lambda a: a.__setitem__((0, 0, 0), np.nan), "R32G32B32A32_SFLOAT", "non-finite"),
], ids=["negative", "over-packed-max", "over-half-max", "nan"])
def test_irradiance_falls_back_to_rgba16f_then_rgba32f(pack, name, change, want, why):
    a = _atlas(np.random.default_rng(2))
    change(a)
    data, vk, meta = pack(a)
    assert vk == want and data.shape == a.shape
    assert why in meta["precision"]["fallback_from"] + meta["precision"].get("fallback", "")
    assert meta["precision"]["fallback_from"].startswith(name)
    if vk == "R16G16B16A16_SFLOAT":
        assert data.dtype == np.float16 and np.all(data[..., 3] == 1)
    else:
        assert data.dtype == np.float32 and np.array_equal(data, a, equal_nan=True)   # float32: unchanged


def test_rgb_input_gets_alpha_when_it_falls_back():
    a = _atlas(np.random.default_rng(3))[..., :3].copy()
    a[0, 0, 0] = -1.0
    data, vk, _ = rgb_ufloat(a)
    assert vk == "R16G16B16A16_SFLOAT" and data.shape == a.shape[:-1] + (4,) and np.all(data[..., 3] == 1)


@pytest.mark.parametrize("shape, vk", [((6, 7, 2), "R16G16_SFLOAT"), ((3, 4, 5, 4), "R16G16B16A16_SFLOAT"),
                                       ((6, 7), "R16_SFLOAT")], ids=["rg-atlas", "rgba-volume", "one-channel"])
def test_half_where_it_holds_the_data(shape, vk):
    a = np.random.default_rng(4).normal(0.0, 50.0, shape).astype(np.float32)
    data, got, meta = half(a)
    assert got == vk and data.dtype == np.float16 and data.shape == a.shape
    assert np.array_equal(data, a.astype(np.float16))               # numpy's round to nearest even
    assert 0 < meta["precision"]["relative_rmse"] < 2.0 ** -11
    assert "fallback" not in meta["precision"]


@pytest.mark.parametrize("top, why", [(HALF_MAX * 1.01, "> 65504"), (SMALLEST_SCALE / 2, "<")],
                         ids=["overflow", "too-small"])
def test_half_keeps_float32_when_half_would_not_hold_it(top, why):
    a = np.random.default_rng(5).uniform(0.0, 1.0, (5, 5, 2)).astype(np.float32)
    a[0, 0, 0] = top
    a *= np.float32(top / a.max())
    data, vk, meta = half(a)
    assert vk == "R32G32_SFLOAT" and data.dtype == np.float32 and np.array_equal(data, a)
    assert why in meta["precision"]["fallback"] and meta["precision"]["relative_rmse"] == 0.0


def test_zeros_stay_half_with_zero_error():
    data, vk, meta = half(np.zeros((2, 3, 4, 4), np.float32))
    assert vk == "R16G16B16A16_SFLOAT" and meta["precision"]["relative_rmse"] == 0.0 and not data.any()


def test_irradiance_packs_to_rgb9e5_within_its_bound_and_reads_back_what_it_reports():
    """The light stage's irradiance format: 4 bytes a texel, each texel's largest channel within 2^-9 of itself,
    a grey value within 0.2% (R11G11B10F: up to 0.89%), the smaller channels within half the shared step."""
    a = _atlas(np.random.default_rng(4))
    a[:5, :, :3] = a[:5, :, :1]                                   # grey rows: the flat-light case
    data, vk, meta = rgb9e5(a)
    assert vk == "E5B9G9R9_UFLOAT_PACK32" and data.shape == a.shape[:-1] + (3,) and data.dtype == np.float32
    back, info = decode_ktx2(encode_ktx2(data, vk, 3))
    assert info["pixel_size"] == 4 and np.array_equal(back, data)
    rgb = a[..., :3].astype(np.float64)
    top = rgb.max(axis=-1)
    err = np.abs(data - rgb)
    assert np.all(err.max(axis=-1) <= top * 2.0 ** -9)
    grey = np.sqrt((((data[:5] - rgb[:5]) / rgb[:5]) ** 2).mean(axis=-1))
    assert grey.max() <= 2.0 ** -9 and grey.max() > 0
    rel = relative_rmse(data, a[..., :3])
    assert meta["precision"] == {"format": vk, "relative_rmse": rel} and 1e-4 < rel < 2e-3
    again = rgb9e5(a.copy())
    assert np.array_equal(again[0], data) and again[2] == meta
