"""Data-driven precomputed radiance transfer: the math of the ``prt`` stage and of relighting (PRT §3-5).

Everything here is numpy/scipy, no I/O. :mod:`workers.kernels.prt_dataset` builds a dataset of N random
lighting configurations (:func:`workers.kernels.prt_scenario.random_light_configurations`): for each, the
*direct* illumination at M measurement points (blue noise on the surfaces,
:func:`workers.kernels.prt_scenario.measurement_points`) and the *indirect* illumination at a target (probe SH
coefficients, lightmap texels, :mod:`workers.kernels.lightmap`). From that dataset :func:`fit` extracts

- a basis (PRT §3.2 eq 7-8, §4.2): the mean of the normalized indirect vectors plus the first n - 1
  left singular vectors of the mean-subtracted ones, found from the N x N Gram matrix (Turk & Pentland,
  as PRT §4.2 does);
- a transfer matrix per colour channel (PRT eq 14, ridge regression; eq 13's pseudo-inverse for λ = 0;
  λ given, or chosen by cross-validation over the configurations, :func:`ridge_cv`) mapping a direct vector
  to the basis coefficients.

Conventions
-----------
- A direct vector x is the *outgoing radiance* of the measurement points, ``albedo/π · E_direct``
  (linear RGB; the "fake G-buffer" deferred shading of PRT §4.3), averaged over each point's
  supersamples (§5.1). Shape (M, 3).
- A target vector y has shape (L, 3): L scalar slots per colour channel (L = probes x SH coefficients,
  or covered lightmap texels).
- **Slots**: ``slots[0]`` is the mean μ, ``slots[1:]`` the basis vectors U (orthonormal); "n basis"
  counts the mean, as PRT §4.2 does ("16 basis elements = the mean and 15 basis elements").
  mono (§5.2, default): slots (n, L), one basis shared by the three colour channels, one transfer per
  channel; multi: slots (n, L, 3), colour interleaved in the vectors, one transfer for all.
- **Normalization** (§4.2): each training pair is divided by the direct vector's norm and the mean
  is scaled back by ‖x‖ at runtime. The transfer therefore acts on the direct vector *augmented with
  its norm*, ``x⁺ = [x, ‖x‖]``: ``u = T x⁺``, ``y ≈ Σ_j u_j · slot_j``. Row 0 of T is ``[0, …, 0, 1]``
  (u_0 = ‖x‖, the mean's coefficient, as in PRT); rows j >= 1 are the ridge regression of eq 14 fitted
  *with an intercept* (centred data), the intercept landing in the ‖x‖ column. The paper's plain eq 14
  has no intercept, but its coefficients ``C = Uᵀ(y/‖x‖ - μ)`` are affine, not linear, in x/‖x‖
  (the constant -Uᵀμ), so without it even exactly linear data is not reproduced. This stays
  homogeneous: doubling the lights doubles y.
  **Which norm** (``norm``; PRT §4.2 says only "the norm of the direct vector"): ``"l2"``, or ``"l1"``
  (Σ_m |x_m|: with blue-noise points, proportional to the power the surfaces reflect, which is what the
  indirect light scales with). A light close to a surface concentrates x on a few points: its L2 norm
  grows against its L1 norm (‖x‖₂/‖x‖₁ 0.26 for a point 8 cm above the Cornell floor, 0.16 for the median
  random light), so under L2 the mean's coefficient u_0 = ‖x‖ overshoots and the basis coefficients must
  cancel it, which they do poorly (overshoot + negative SH: the hotspot and black walls of
  tests/render/test_artifacts.py). The stage's default is l1 (``prt.norm``).
- **Gamma** (§5.3): with γ set, x and y are mapped by ``g(v) = sign(v)·|v|^(1/γ)`` before everything
  (signed, because SH coefficients and basis vectors can be negative) and the result by ``g⁻¹``.

References
----------
.. [PRT] L. Belcour, T. Deliot, W. Barbier, C. Soler, "A Data-Driven Paradigm for Precomputed Radiance
   Transfer", SIGGRAPH 2022 (``../shared/papers/data-driven-prt.txt``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "group_mean", "gamma_encode", "gamma_decode", "PrtFit", "direct_norm", "fit", "reconstruct", "project", "fit_stats",
    "pack_rgba", "unpack_rgba", "sh_volumes", "lm_textures",
]

OUTLIER_RATIO = 10.0
"""A training column whose normalized indirect ‖y‖/‖x‖ exceeds this many times the median is left out
of the fit: its light is almost unseen by the measurement points (PRT §7, "sparse illumination
measurement"), and one such column can own the mean and the first basis vector."""


# ------------------------------------------------------------------------------------- supersamples
def group_mean(values, offsets) -> np.ndarray:
    """Mean of consecutive row groups: rows ``offsets[g]:offsets[g+1]`` of ``values`` (K, ...) -> (G, ...).

    The §5.1 downscaling of supersampled direct illumination (every group non-empty)."""
    v = np.asarray(values)
    off = np.asarray(offsets, np.int64)
    sums = np.add.reduceat(v, off[:-1], axis=0)
    cnt = np.diff(off).reshape((-1,) + (1,) * (v.ndim - 1))
    return sums / cnt


# --------------------------------------------------------------------------------------------- gamma
def gamma_encode(v, gamma: float | None) -> np.ndarray:
    """``sign(v)·|v|^(1/γ)`` (PRT §5.3, signed); identity when gamma is None."""
    v = np.asarray(v)
    if gamma is None:
        return v
    return np.sign(v) * np.abs(v) ** (1.0 / gamma)


def gamma_decode(v, gamma: float | None) -> np.ndarray:
    """Inverse of :func:`gamma_encode`: ``sign(v)·|v|^γ``."""
    v = np.asarray(v)
    if gamma is None:
        return v
    return np.sign(v) * np.abs(v) ** gamma


# --------------------------------------------------------------------------------------- basis + fit
@dataclass
class PrtFit:
    """A fitted transfer (see the module doc).

    slots : (n, L) mono or (n, L, 3) multi, float32 — slot 0 the mean, then orthonormal basis vectors.
    transfer : (3, n, M + 1) mono (one per colour channel) or (1, n, 3M + 1) multi, float32, acting on
        ``[x, ‖x‖]``; row 0 is ``[0, …, 0, 1]``. Multi-channel direct vectors are interleaved
        ``[x0r, x0g, x0b, x1r, ...]``.
    singular : (r,) float64 — all singular values of the mean-subtracted normalized dataset.
    gamma, channels : as fitted. columns : training columns used (zero direct norms and outliers, see
    :data:`OUTLIER_RATIO`, are dropped); dropped : outlier columns left out. norm : "l2" or "l1" (the ‖x‖).
    ridges : the λ of eq 14 used per transfer (colour channel), chosen or given.
    """

    slots: np.ndarray
    transfer: np.ndarray
    singular: np.ndarray
    gamma: float | None
    channels: str
    columns: int
    dropped: int = 0
    norm: str = "l2"
    ridges: tuple = ()

    @property
    def n(self) -> int:
        return int(self.slots.shape[0])

    def truncated(self, n: int) -> "PrtFit":
        """The same fit with only the first n slots (SVD truncation and ridge rows are nested)."""
        return PrtFit(self.slots[:n], self.transfer[:, :n], self.singular, self.gamma, self.channels, self.columns,
                      self.dropped, self.norm, self.ridges)


def _columns(direct, target, gamma, channels):
    """Training columns: (d (K, Mdim), y (K, Ldim), channel (K,)) in gamma space, unnormalized."""
    D = gamma_encode(np.asarray(direct, np.float64), gamma)   # (N, M, 3)
    Y = gamma_encode(np.asarray(target, np.float64), gamma)   # (N, L, 3)
    N = D.shape[0]
    if channels == "mono":  # PRT §5.2: colour channels as separate vectors
        d = D.transpose(2, 0, 1).reshape(3 * N, -1)
        y = Y.transpose(2, 0, 1).reshape(3 * N, -1)
        ch = np.repeat(np.arange(3), N)
    else:
        d = D.reshape(N, -1)
        y = Y.reshape(N, -1)
        ch = np.zeros(N, np.int64)
    return d, y, ch


RIDGE_GRID = (0.1, 0.3, 1.0)
"""Candidate λ of the cross-validated ridge (:func:`ridge_cv`), relative to the centred direct vectors' mean
squared norm. From 0.1, not 0: cross-validation scores the squared error, not the ringing that eq 14's ridge is
there to remove (PRT §4.3 "Deringing"); with 0.01 and below allowed, the Cornell test light 8 cm above the floor
(tests/render/test_artifacts.py) came back 2.4 % near-black instead of 0.7 %."""


def ridge_cv(C, Dt, groups, folds: int, grid=RIDGE_GRID) -> float:
    """λ of eq 14 chosen by ``folds``-fold cross-validation over the lighting configurations.

    C : (r, K) basis coefficients, Dt : (K, Mdim) normalized direct vectors (as :func:`_ridge_solve`), groups :
    (K,) configuration of each column (a configuration's columns share a fold). Each λ = g·Σs²/K of ``grid``
    (s the singular values of the centred Dt: the scale of the data, so the same grid serves ``norm`` l1 and l2)
    is scored by the squared error of the held-out coefficients predicted from the other folds (folds: a fixed
    permutation of the configurations); returns the absolute λ of the smallest total error (the grid's middle
    one when there are fewer configurations than folds)
    (PRT §4.3 leaves λ "a small scalar": too small and the transfer does not generalize to lights unlike the
    dataset's, too large and it loses what it could)."""
    scale = float(np.sum((Dt - Dt.mean(axis=0)) ** 2)) / max(Dt.shape[0], 1)
    lam = np.asarray(grid, np.float64) * scale
    ids = np.unique(groups)
    if folds < 2 or ids.size < folds or scale <= 0:
        return float(lam[len(lam) // 2])
    fold_of = np.random.default_rng(0).permutation(ids.size) % folds
    fold = fold_of[np.searchsorted(ids, groups)]
    err = np.zeros(lam.size)
    for f in range(folds):
        tr, te = fold != f, fold == f
        dm, cm = Dt[tr].mean(axis=0), C[:, tr].mean(axis=1)
        Q, s, Pt = np.linalg.svd(Dt[tr] - dm, full_matrices=False)
        W = (C[:, tr] - cm[:, None]) @ Q                                # (r, k)
        Z = (Dt[te] - dm) @ Pt.T                                         # (t, k)
        cut = max(Dt.shape) * np.finfo(np.float64).eps * (s[0] if s.size else 0.0)
        for i, l in enumerate(lam):
            g = s / (s * s + l) if l > 0 else np.where(s > cut, 1.0 / np.where(s > cut, s, 1.0), 0.0)
            pred = (W * g) @ Z.T + cm[:, None]                           # (r, t)
            err[i] += float(np.sum((pred - C[:, te]) ** 2))
    return float(lam[int(np.argmin(err))])


def _ridge_solve(C, Dt, ridge: float):
    """``[M, b]`` with ``C ≈ M Dtᵀ + b 1ᵀ``: PRT eq 14 on centred data plus an intercept.

    C : (r, K) coefficients, Dt : (K, Mdim) normalized direct vectors as rows. With the centred
    D = (Dt - mean)ᵀ = P S Qᵀ (SVD), ``M = C_c (DᵀD + λI)⁻¹ Dᵀ = C_c Q diag(s / (s² + λ)) Pᵀ`` (eq 14;
    the pseudo-inverse of eq 13 when λ = 0, singular values below max(K, Mdim)·ε·s_max dropped) and
    ``b = mean(C) - M·mean(Dt)``. Returns (r, Mdim + 1).
    """
    dm = Dt.mean(axis=0)
    cm = C.mean(axis=1)
    Q, s, Pt = np.linalg.svd(Dt - dm, full_matrices=False)   # Dt - dm = Q S Pᵀ
    if ridge > 0:
        f = s / (s * s + ridge)
    else:
        cut = max(Dt.shape) * np.finfo(np.float64).eps * (s[0] if s.size else 0.0)
        f = np.where(s > cut, 1.0 / np.where(s > cut, s, 1.0), 0.0)
    M = ((C - cm[:, None]) @ Q) * f @ Pt                      # eq 14
    return np.concatenate([M, (cm - M @ dm)[:, None]], axis=1)


def direct_norm(v, axis=None, norm: str = "l2") -> np.ndarray:
    """The norm ‖x‖ of direct vectors along ``axis``: ``"l2"`` (Euclidean) or ``"l1"`` (sum of |x|)."""
    v = np.asarray(v)
    if norm == "l1":
        return np.abs(v).sum(axis=axis)
    if norm == "l2":
        return np.linalg.norm(v, axis=axis)
    raise ValueError(f"direct_norm: norm must be 'l1' or 'l2', got {norm!r}")


def fit(direct, target, n: int, ridge: float = 1e-3, gamma: float | None = None, channels: str = "mono",
        norm: str = "l2", ridge_folds: int = 0) -> PrtFit:
    """Basis and transfer from a dataset (PRT §4.2, eq 7-10 and 14).

    Parameters
    ----------
    direct : (N, M, 3) float — direct vectors x_k (outgoing radiance at the measurement points).
    target : (N, L, 3) float — indirect vectors y_k (any linear quantity per slot and channel).
    n : int >= 1 — slots kept, the mean included (so n - 1 singular vectors; fewer when the data has
        fewer non-zero singular values, the remaining slots then being zero).
    ridge : λ of eq 14, relative to unit-norm direct vectors (0: pseudo-inverse, eq 13).
    gamma : exponent of §5.3, or None for linear space.
    channels : "mono" (§5.2: shared basis, one transfer per channel) or "multi".
    norm : ‖x‖ of the normalization and of ``[x, ‖x‖]``, :func:`direct_norm` ("l2" or "l1"; module doc).
    ridge_folds : >= 2: λ chosen per colour channel by that many-fold cross-validation over the configurations
        (:func:`ridge_cv`; ``ridge`` is then unused), recorded in ``PrtFit.ridges``; 0: ``ridge``.
    """
    if channels not in ("mono", "multi"):
        raise ValueError(f"fit: channels must be 'mono' or 'multi', got {channels!r}")
    direct = np.asarray(direct)
    target = np.asarray(target)
    if direct.ndim != 3 or target.ndim != 3 or direct.shape[2] != 3 or target.shape[2] != 3 \
            or direct.shape[0] != target.shape[0]:
        raise ValueError(f"fit: direct (N, M, 3) and target (N, L, 3) expected, got {direct.shape}, {target.shape}")
    if n < 1:
        raise ValueError("fit: n must be >= 1")
    d, y, ch = _columns(direct, target, gamma, channels)
    cfg = np.arange(d.shape[0]) % np.asarray(direct).shape[0]          # the configuration of each column
    nrm_kind = norm
    norm = direct_norm(d, 1, nrm_kind)
    keep = norm > 1e-12 * max(float(norm.max(initial=0.0)), 1e-300)
    d, y, ch, norm, cfg = d[keep], y[keep], ch[keep], norm[keep], cfg[keep]
    L = y.shape[1]
    n_ch = 3 if channels == "mono" else 1
    mdim = d.shape[1]
    slots = np.zeros((n, L), np.float64)
    transfer = np.zeros((n_ch, n, mdim + 1), np.float64)
    transfer[:, 0, mdim] = 1.0                               # u_0 = ‖x‖: the mean's coefficient (§4.2)
    if d.shape[0] == 0:
        return PrtFit(_shape_slots(slots, channels), transfer.astype(np.float32), np.zeros(0), gamma, channels, 0,
                      norm=nrm_kind)
    dn = d / norm[:, None]                                   # PRT §4.2: normalize by the direct norm
    yn = y / norm[:, None]
    ratio = np.linalg.norm(yn, axis=1)
    sane = ratio <= OUTLIER_RATIO * np.median(ratio)
    dropped = int((~sane).sum())
    d, dn, yn, ch, cfg = d[sane], dn[sane], yn[sane], ch[sane], cfg[sane]
    mean = yn.mean(axis=0)                                   # PRT §4.2: mean-subtracted
    Z = yn - mean
    # SVD of Zᵀ (L x K) through the K x K Gram matrix (Turk & Pentland 1991; PRT §4.2)
    G = np.zeros((Z.shape[0], Z.shape[0]))
    for a in range(0, L, 8192):
        blk = Z[:, a:a + 8192]
        G += blk @ blk.T
    ev, V = np.linalg.eigh(G)
    ev, V = ev[::-1], V[:, ::-1]
    sing = np.sqrt(np.clip(ev, 0.0, None))
    tol = max(G.shape) * np.finfo(np.float64).eps * (sing[0] ** 2 if sing.size else 0.0)
    r = int(min(n - 1, np.count_nonzero(ev > max(tol, 0.0))))
    slots[0] = mean
    ridges = []
    if r:
        U = (Z.T @ V[:, :r]) / sing[:r]                      # eq 7: Zᵀ = U Σ Vᵀ
        U /= np.linalg.norm(U, axis=0)                      # re-orthonormalize against Gram round-off
        flip = np.sign(U[np.abs(U).argmax(axis=0), np.arange(r)])
        U *= np.where(flip == 0, 1.0, flip)                  # deterministic signs
        slots[1:1 + r] = U.T
        C = U.T @ Z.T                                        # eq 8: coefficients C_n (r x K)
        for c in range(n_ch):
            sel = ch == c
            if sel.any():
                lam = ridge_cv(C[:, sel], dn[sel], cfg[sel], ridge_folds) if ridge_folds >= 2 else ridge
                ridges.append(lam)
                transfer[c, 1:1 + r] = _ridge_solve(C[:, sel], dn[sel], lam)     # eq 14 per channel (§5.2)
    return PrtFit(_shape_slots(slots, channels), transfer.astype(np.float32), sing, gamma, channels,
                  int(d.shape[0]), dropped, nrm_kind, tuple(ridges))


def _shape_slots(slots, channels):
    s = slots.astype(np.float32)
    return s if channels == "mono" else s.reshape(s.shape[0], -1, 3)


def _coefficients(fitted: PrtFit, x):
    """(n, C) coefficients and the gamma-space direct of (M, 3) x; C = 3 (mono) or 1 (multi)."""
    xg = gamma_encode(np.asarray(x, np.float64), fitted.gamma)
    T = fitted.transfer.astype(np.float64)
    if fitted.channels == "mono":
        xa = np.concatenate([xg, direct_norm(xg, 0, fitted.norm)[None]], axis=0)   # [x_c, ‖x_c‖]
        return np.einsum("cnm,mc->nc", T, xa)                # u_c = T_c x⁺_c (eq 10, one per channel)
    flat = xg.reshape(-1)
    return (T[0] @ np.append(flat, direct_norm(flat, None, fitted.norm)))[:, None]


def reconstruct(fitted: PrtFit, x) -> np.ndarray:
    """y ≈ g⁻¹(‖x‖·μ + U·M x) for a direct vector x (M, 3): (L, 3) float64 (PRT eq 10 + §4.2, §5.3)."""
    u = _coefficients(fitted, x)
    S = fitted.slots.astype(np.float64)
    if fitted.channels == "mono":
        y = S.T @ u                                          # (L, n) @ (n, 3)
    else:
        y = np.einsum("nlc,n->lc", S, u[:, 0])
    return gamma_decode(y, fitted.gamma)


def project(fitted: PrtFit, x, y) -> np.ndarray:
    """The best the basis can do for a known result: ``‖x‖·μ + U·Uᵀ(y/‖x‖ - μ)``·‖x‖ in gamma space.

    The mean keeps its coefficient ‖x‖ and the rest of y is projected orthogonally onto the basis
    vectors (the "projecting the reference in the basis" curve of PRT Fig 14). x (M, 3), y (L, 3).
    """
    xg = gamma_encode(np.asarray(x, np.float64), fitted.gamma)
    yg = gamma_encode(np.asarray(y, np.float64), fitted.gamma)
    S = fitted.slots.astype(np.float64)
    if fitted.channels == "mono":
        nx = direct_norm(xg, 0, fitted.norm)                 # (3,)
        mu, U = S[0], S[1:]
        res = yg - nx * mu[:, None]
        out = nx * mu[:, None] + U.T @ (U @ res)
    else:
        nx = direct_norm(xg, None, fitted.norm)
        mu, U = S[0].reshape(-1), S[1:].reshape(S.shape[0] - 1, -1)
        res = yg.reshape(-1) - nx * mu
        out = (nx * mu + U.T @ (U @ res)).reshape(yg.shape)
    return gamma_decode(out, fitted.gamma)


# ------------------------------------------------------------------------------------------- packing
def pack_rgba(slots) -> np.ndarray:
    """(n, ...) mono slots -> (ceil(n/4), ..., 4) float32: four basis slots per RGBA texel (PRT §5.2)."""
    s = np.asarray(slots, np.float32)
    g = -(-s.shape[0] // 4)
    pad = np.zeros((4 * g,) + s.shape[1:], np.float32)
    pad[:s.shape[0]] = s
    return np.ascontiguousarray(np.moveaxis(pad.reshape((g, 4) + s.shape[1:]), 1, -1))


def unpack_rgba(groups, n: int) -> np.ndarray:
    """Inverse of :func:`pack_rgba`: (G, ..., 4) -> (n, ...)."""
    a = np.asarray(groups)
    s = np.moveaxis(a, -1, 1)
    return np.ascontiguousarray(s.reshape((-1,) + a.shape[1:-1])[:n])


def sh_volumes(slots: np.ndarray, channels: str, counts, K: int):
    """Probe basis volumes: ``[[(name, (nz, ny, nx, 4) float32) per slot group] per SH coefficient]``.

    mono: slots (n, P·K) -> volume ``prt_sh_basis_c{k}_g{g}`` holds SH coefficient k of slots 4g..4g+3
    in RGBA (slot 0 = the mean; PRT §5.2 packing). multi: slots (n, P·K, 3) -> one volume per slot g
    with its RGB in rgb and a = 0."""
    nx, ny, nz = counts
    n = slots.shape[0]
    out = []
    if channels == "mono":
        vol = slots.reshape(n, nz, ny, nx, K)
        for k in range(K):
            out.append([(f"prt_sh_basis_c{k}_g{g}", grp) for g, grp in enumerate(pack_rgba(vol[..., k]))])
    else:
        vol = slots.reshape(n, nz, ny, nx, K, 3)
        pad = np.zeros((nz, ny, nx, 1), np.float32)
        for k in range(K):
            out.append([(f"prt_sh_basis_c{k}_g{j}", np.concatenate([vol[j, ..., k, :], pad], axis=-1))
                        for j in range(n)])
    return out


def lm_textures(images: np.ndarray, channels: str):
    """Lightmap basis textures ``[(name, (H, W, 4) float32)]``: mono images (n, H, W) four slots per
    texture (``prt_lm_basis_g{g}``: slots 4g..4g+3); multi images (n, H, W, 3) one slot per texture."""
    if channels == "mono":
        return [(f"prt_lm_basis_g{g}", grp) for g, grp in enumerate(pack_rgba(images))]
    pad = np.zeros(images.shape[1:3] + (1,), np.float32)
    return [(f"prt_lm_basis_g{j}", np.concatenate([images[j], pad], axis=-1)) for j in range(images.shape[0])]


def fit_stats(fitted: PrtFit, direct, target) -> dict:
    """How well a fit explains its own dataset: ``columns``, ``outliers_dropped``, ``energy_kept`` (Σ of the kept
    n − 1 squared singular values over all of them, PRT §4.2), the first 64 ``singular_values``, ``train_rmse``
    (of :func:`reconstruct` against ``target``) and ``train_rms`` (of ``target``). direct (N, M, 3), target (N, L, 3).
    """
    s2 = fitted.singular ** 2
    kept = min(fitted.n - 1, s2.size)
    y = np.asarray(target, np.float64)
    err = np.stack([reconstruct(fitted, direct[k]) - y[k] for k in range(y.shape[0])])
    rms = float(np.sqrt(np.mean(y ** 2)))
    energy = float(s2[:kept].sum() / s2.sum()) if s2.sum() > 0 else 1.0
    return {"columns": fitted.columns, "outliers_dropped": fitted.dropped, "energy_kept": energy,
            "ridge_used": [float(v) for v in fitted.ridges],
            "singular_values": fitted.singular[:min(64, fitted.singular.size)].tolist(),
            "train_rmse": float(np.sqrt(np.mean(err ** 2))), "train_rms": rms}
