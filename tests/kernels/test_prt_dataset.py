"""PRT's dataset solver and fit (workers/kernels/prt_dataset.py) on closed forms and synthetic linear data."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from workers.kernels import prt as kprt
from workers.kernels.grid import ACTIVE, OFF
from workers.kernels.probe_hits import HitSurfaces
from workers.kernels.prt_dataset import PrtDataset, fit_targets, solve_batch
from workers.kernels.sampling import fibonacci_sphere
from workers.kernels.sh import sh_project

N_TEX = 4
T = N_TEX + 2


def _closed_box(a, P=3, R=64):
    """Every probe ray hits a front face of albedo a; every hit (and texel) reads probe 0's texel (1, 1)."""
    H = P * R
    zeros = np.zeros((H, 3), np.float32)
    surf = HitSurfaces(index=np.arange(H), position=zeros, normal=zeros, view=zeros,
                       albedo=np.full((H, 3), a, np.float32), emission=zeros, miss=np.zeros((P, R), bool), P=P, R=R)

    def reads_probe0(rows):
        return sp.csr_matrix((np.ones(rows, np.float32), (np.arange(rows), np.full(rows, T + 1))),
                             shape=(rows, P * T * T))

    return surf, reads_probe0(H), reads_probe0(5), fibonacci_sphere(R).astype(np.float32)


def test_solve_batch_sums_each_configurations_geometric_series():
    a = 0.5
    surf, W, W_tex, dirs = _closed_box(a)
    e0 = np.array([[1.0, 2.0, 3.0], [0.5, 0.0, 4.0]], np.float32)
    e = np.broadcast_to(e0[:, None, :], (2, surf.index.size, 3)).copy()
    states = np.array([ACTIVE, ACTIVE, OFF])
    sh, tex, bounces, maps = solve_batch(surf, W, e, dirs, states, N_TEX, bounces=3, max_bounces=64, tolerance=0,
                                         sh_order=2, W_texels=W_tex)
    want = e0 * (a + a ** 2 + a ** 3)                                   # E_b = a·(E0 + E_{b−1})
    assert list(bounces) == [3, 3] and sh.shape == (2, 3, 9, 3) and tex.shape == (2, 5, 3)
    assert np.allclose(maps[:, :2], want[:, None, None, None], rtol=1e-5) and not maps[:, 2].any()
    assert np.allclose(tex, want[:, None], rtol=1e-5)
    for c in range(2):                                                  # constant radiance E_b/π on every ray
        rad = np.broadcast_to(want[c] / np.pi, (3, 64, 3)).astype(np.float32)
        assert np.allclose(sh[c, :2], sh_project(dirs, rad, order=2)[:2], rtol=1e-4, atol=1e-6)
    assert not sh[:, 2].any()                                           # OFF probe
    conv = solve_batch(surf, W, e, dirs, states, N_TEX, bounces=None, max_bounces=200, tolerance=1e-4, sh_order=1)
    assert conv[1] is None and conv[0].shape == (2, 3, 4, 3)
    assert np.allclose(conv[3][:, :2, 1, 1], e0[:, None] * a / (1 - a), rtol=1e-3)   # E0·a/(1 − a)


def _linear_dataset(N=40, M=12, P=8, K=4, L=30, res=8, seed=0):
    rng = np.random.default_rng(seed)
    direct = rng.random((N, M, 3)) * rng.uniform(0.5, 5, (N, 1, 1))
    A, B = rng.random((3, P * K, M)), rng.random((3, L, M))
    sh = np.einsum("clm,nmc->nlc", A, direct).reshape(N, P, K, 3).astype(np.float32)
    covered = np.zeros((res, res), bool)
    covered.reshape(-1)[rng.choice(res * res, L, replace=False)] = True
    texels = np.einsum("clm,nmc->nlc", B, direct).astype(np.float32)
    lm = {"covered": covered, "uv": np.zeros((2, 3, 2), np.float32), "source": "texcoord1", "texels_per_metre": 4.0,
          "warnings": []}
    return PrtDataset(configs=[[]] * N, points={}, direct=direct, sh=sh, texels=texels, lightmap=lm,
                      probes={"grid": {"counts": [2, 2, 2]}}, bounces=np.full(N, 3), timings={})


@pytest.mark.parametrize("channels", ["mono", "multi"])
def test_fit_targets_packs_both_targets(channels):
    ds = _linear_dataset()
    out = fit_targets(ds, basis=37, ridge=0.0, gamma=None, channels=channels, lightmap=8)
    assert len(out.sh_volumes) == 4                                     # one list per SH coefficient
    assert out.sh_stats["train_rmse"] < 1e-3 * out.sh_stats["train_rms"]
    x = ds.direct[3]
    assert np.allclose(kprt.reconstruct(out.sh, x), ds.sh[3].reshape(-1, 3), rtol=1e-3, atol=1e-4)
    lm = out.lm
    assert np.array_equal(lm.mask == 1, ds.lightmap["covered"]) and set(np.unique(lm.mask)) <= {0, 1, 2}
    assert all(tex.shape == (8, 8, 4) for _, tex in lm.textures)
    assert len(lm.textures) == (-(-37 // 4) if channels == "mono" else 37)
    assert np.allclose(kprt.reconstruct(lm.fit, x), ds.texels[3], rtol=1e-3, atol=1e-4)


def test_fit_targets_without_a_lightmap():
    ds = _linear_dataset()
    ds.lightmap, ds.texels = None, None
    assert fit_targets(ds, basis=8, ridge=1e-3, gamma=None, channels="mono", lightmap=0).lm is None
