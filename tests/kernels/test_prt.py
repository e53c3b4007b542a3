"""PRT kernels (workers/kernels/prt.py): the fit (PRT eq 7-10, 14), supersample means, packing."""
from __future__ import annotations

import math

import numpy as np
import pytest

from workers.kernels import prt as k


def test_group_mean():
    v = np.arange(12, dtype=float).reshape(6, 2)
    out = k.group_mean(v, np.array([0, 1, 4, 6]))
    assert np.allclose(out, [[0, 1], [4, 5], [9, 10]])


# ------------------------------------------------------------------------------------------ fit
def _linear_dataset(N=60, M=24, L=150, seed=0):
    """Exactly linear transport per channel (different per channel, as albedo makes it)."""
    rng = np.random.default_rng(seed)
    A = rng.random((3, L, M))
    x = rng.random((N, M, 3)) * rng.uniform(0.1, 10, (N, 1, 1))    # intensities over two decades
    y = np.einsum("clm,nmc->nlc", A, x)
    return x, y, A


@pytest.mark.parametrize("norm", ["l2", "l1"])
@pytest.mark.parametrize("ridge", [0.0, 1e-8])
def test_mono_fit_reproduces_linear_transport_with_enough_basis(ridge, norm):
    x, y, A = _linear_dataset()
    f = k.fit(x, y, 80, ridge=ridge, norm=norm)   # one basis for 3 channels: the data spans 3·24 (+ mean) dimensions
    assert f.slots.shape == (80, 150) and f.transfer.shape == (3, 80, 25)
    assert np.allclose(f.transfer[:, 0], np.r_[np.zeros(24), 1.0])   # u_0 = ‖x‖
    rng = np.random.default_rng(9)
    for _ in range(3):                        # held-out direct vectors
        xn = rng.random((24, 3)) * 5
        yn = np.einsum("clm,mc->lc", A, xn)
        assert np.allclose(k.reconstruct(f, xn), yn, rtol=1e-4, atol=1e-4 * np.abs(yn).max())
    r = 72 if norm == "l2" else 69            # l1: x/‖x‖₁ lies on the plane Σ = 1, centred rank 23 per channel
    U = f.slots[1:1 + r].astype(np.float64)
    assert np.allclose(U @ U.T, np.eye(r), atol=1e-5)    # orthonormal basis vectors


def test_multi_channel_fit_and_projection():
    x, y, A = _linear_dataset(N=90, M=8, L=40)
    f = k.fit(x, y, 30, ridge=0.0, channels="multi")   # interleaved rgb: rank 3·8 = 24
    assert f.slots.shape == (30, 40, 3) and f.transfer.shape == (1, 30, 25)
    for i in range(3):
        assert np.allclose(k.reconstruct(f, x[i]), y[i], rtol=1e-4, atol=1e-5 * np.abs(y[i]).max())
        assert np.allclose(k.project(f, x[i], y[i]), y[i], atol=1e-5 * np.abs(y[i]).max())


def test_truncation_is_nested_and_projection_bounds_reconstruction():
    x, y, _ = _linear_dataset()
    f = k.fit(x, y, 16, ridge=1e-3)
    g = k.fit(x, y, 8, ridge=1e-3)
    assert np.allclose(f.truncated(8).slots, g.slots, atol=1e-6)
    assert np.allclose(f.truncated(8).transfer, g.transfer, atol=1e-4 * np.abs(g.transfer).max())
    errs = [np.sqrt(np.mean((k.project(f.truncated(n), x[0], y[0]) - y[0]) ** 2)) for n in (2, 4, 8, 16)]
    assert errs == sorted(errs, reverse=True)


@pytest.mark.parametrize("norm", ["l2", "l1"])
@pytest.mark.parametrize("gamma", [None, 2.2])
@pytest.mark.parametrize("channels", ["mono", "multi"])
def test_relighting_is_homogeneous(gamma, channels, norm):
    x, y, _ = _linear_dataset()
    f = k.fit(x, y, 8, ridge=1e-3, gamma=gamma, channels=channels, norm=norm)
    xn = np.random.default_rng(4).random((24, 3))
    assert np.allclose(k.reconstruct(f, 2 * xn), 2 * k.reconstruct(f, xn), rtol=1e-9, atol=1e-12)
    assert np.allclose(k.reconstruct(f, np.zeros((24, 3))), 0)


def test_gamma_round_trip_signed():
    v = np.array([-4.0, -0.25, 0.0, 0.5, 9.0])
    assert np.allclose(k.gamma_decode(k.gamma_encode(v, 2.2), 2.2), v)
    assert np.allclose(k.gamma_encode(v, 2.0), [-2, -0.5, 0, math.sqrt(0.5), 3])
    assert k.gamma_encode(v, None) is not None and np.array_equal(k.gamma_encode(v, None), v)


def test_outlier_columns_are_left_out():
    x, y, _ = _linear_dataset(N=40)
    x2, y2 = x.copy(), y.copy()
    x2[0] *= 1e-4   # a configuration the measurement points barely see: y/‖x‖ explodes
    f = k.fit(x2, y2, 8)
    assert f.dropped >= 1 and f.columns == 3 * 40 - f.dropped
    clean = k.fit(x[1:], y[1:], 8)
    assert np.allclose(np.abs(f.slots[0]), np.abs(clean.slots[0]), rtol=0.2)


def test_zero_direct_columns_are_ignored():
    x, y, _ = _linear_dataset(N=20)
    x[:, :, 2] = 0
    y[:, :, 2] = 0    # a blue-free scenario
    f = k.fit(x, y, 6)
    assert f.columns == 40
    assert np.allclose(k.reconstruct(f, x[0])[:, 2], 0)


# ---------------------------------------------------------------------------------------- packing
@pytest.mark.parametrize("n", [1, 4, 6, 16])
def test_pack_unpack_rgba(n):
    s = np.random.default_rng(n).random((n, 3, 5, 7)).astype(np.float32)
    p = k.pack_rgba(s)
    assert p.shape == (-(-n // 4), 3, 5, 7, 4)
    assert np.array_equal(p[0, ..., 0], s[0])
    if n > 1:
        assert np.array_equal(p[0, ..., 1], s[1])
    assert np.array_equal(k.unpack_rgba(p, n), s)


def test_sh_volumes_pack_four_slots_per_texel_mono_and_one_per_volume_multi():
    counts, K, n = (3, 2, 4), 9, 6
    P = 3 * 2 * 4
    mono = np.random.default_rng(0).random((n, P * K)).astype(np.float32)
    vols = k.sh_volumes(mono, "mono", counts, K)
    assert len(vols) == K and all(len(g) == 2 for g in vols)               # ceil(6 / 4) slot groups
    name, vol = vols[4][1]
    assert name == "prt_sh_basis_c4_g1" and vol.shape == (4, 2, 3, 4)      # (nz, ny, nx, 4)
    want = mono.reshape(n, 4, 2, 3, K)[4:, ..., 4]                         # slots 4, 5 of coefficient 4
    assert np.array_equal(vol[..., 0], want[0]) and np.array_equal(vol[..., 1], want[1]) and not vol[..., 2:].any()
    multi = np.random.default_rng(1).random((n, P * K, 3)).astype(np.float32)
    vm = k.sh_volumes(multi, "multi", counts, K)
    assert len(vm[0]) == n and vm[2][5][0] == "prt_sh_basis_c2_g5"
    assert np.array_equal(vm[2][5][1][..., :3], multi.reshape(n, 4, 2, 3, K, 3)[5, ..., 2, :])
    assert not vm[2][5][1][..., 3].any()


def test_lm_textures_names_and_channels():
    imgs = np.random.default_rng(2).random((5, 8, 8)).astype(np.float32)
    mono = k.lm_textures(imgs, "mono")
    assert [name for name, _ in mono] == ["prt_lm_basis_g0", "prt_lm_basis_g1"]
    assert np.array_equal(mono[1][1][..., 0], imgs[4]) and mono[1][1].shape == (8, 8, 4)
    rgb = np.random.default_rng(3).random((2, 8, 8, 3)).astype(np.float32)
    multi = k.lm_textures(rgb, "multi")
    assert len(multi) == 2 and np.array_equal(multi[1][1][..., :3], rgb[1]) and not multi[1][1][..., 3].any()


def test_fit_stats_of_an_exact_fit():
    x, y, _ = _linear_dataset()
    f = k.fit(x, y, 80, ridge=0.0)            # enough basis: the data spans 3·24 (+ mean) dimensions
    st = k.fit_stats(f, x, y)
    assert st["columns"] == f.columns > 0 and st["outliers_dropped"] == 0
    assert st["train_rmse"] < 1e-4 * st["train_rms"] and st["energy_kept"] == pytest.approx(1.0)
    assert st["train_rms"] == pytest.approx(float(np.sqrt(np.mean(y ** 2))))
    short = k.fit_stats(f.truncated(8), x, y)   # fewer slots: less energy, larger error
    assert short["energy_kept"] < st["energy_kept"] and short["train_rmse"] > 100 * st["train_rmse"]
    assert st["singular_values"] == f.singular[:min(64, f.singular.size)].tolist()


def test_direct_norm_l1_and_l2():
    x = np.array([[3.0, -1.0], [4.0, 2.0]])
    assert np.allclose(k.direct_norm(x, 0, "l2"), [5.0, math.sqrt(5.0)])
    assert np.allclose(k.direct_norm(x, 0, "l1"), [7.0, 3.0])
    assert k.direct_norm(x, None, "l1") == pytest.approx(10.0)
    with pytest.raises(ValueError):
        k.direct_norm(x, 0, "max")
    f = k.fit(*_linear_dataset()[:2], 4, norm="l1")
    assert f.norm == "l1" and f.truncated(2).norm == "l1"


def test_cross_validated_ridge_follows_the_noise():
    """ridge_cv: exactly linear data (60 configurations, 24 points: the transfer is determined) gets the smallest λ
    of the grid (with a grid from 0: λ = 0, and the data reproduced); the same data with noise on the indirect gets
    a larger λ, which predicts held-out lights better than a tiny one."""
    x, y, A = _linear_dataset()
    exact = k.fit(x, y, 80, ridge_folds=4)
    scale = [float(np.sum((d - d.mean(0)) ** 2)) / len(d) for d in
             (x[..., c] / np.linalg.norm(x[..., c], axis=1, keepdims=True) for c in range(3))]
    assert len(exact.ridges) == 3 and np.allclose(exact.ridges, k.RIDGE_GRID[0] * np.array(scale))
    xn = np.random.default_rng(9).random((24, 3)) * 5
    yn = np.einsum("clm,mc->lc", A, xn)
    d = x[..., 0] / np.linalg.norm(x[..., 0], axis=1, keepdims=True)
    f0 = k.fit(x, y, 80, ridge=0.0)
    C = f0.slots[1:].astype(np.float64) @ (y[..., 0] / np.linalg.norm(x[..., 0], axis=1, keepdims=True)
                                            - f0.slots[0]).T
    assert k.ridge_cv(C, d, np.arange(60), 4, grid=(0.0, 1e-4, 1e-2, 1.0)) == 0.0
    assert np.allclose(k.reconstruct(f0, xn), yn, rtol=1e-3, atol=1e-3 * np.abs(yn).max())
    rng = np.random.default_rng(1)
    x2, y2, _ = _linear_dataset(N=30)
    noisy = y2 + rng.normal(size=y2.shape) * 0.3 * np.abs(y2).mean()
    cv = k.fit(x2, noisy, 16, ridge_folds=5)
    tiny = k.fit(x2, noisy, 16, ridge=1e-8)
    assert min(cv.ridges) > max(exact.ridges)
    held = [rng.random((24, 3)) * 5 for _ in range(8)]
    def err(f):
        return np.mean([np.mean((k.reconstruct(f, h) - np.einsum("clm,mc->lc", A, h)) ** 2) for h in held])
    assert err(cv) < err(tiny)
