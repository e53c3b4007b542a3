"""Relighting a PRT bake: new lights -> the reconstructed indirect (probe SH volume, lightmap).

Used by :mod:`workers.relight` (what ``POST /v1/bakes/{id}/relight`` runs) and by the evaluate stage. The math is :mod:`workers.kernels.prt` (PRT eq 10 + §4.2): direct vector x at the measurement
points, then per colour channel ``u_c = T_c [x_c, ‖x_c‖]`` and ``y_c = Σ_j u_cj · slot_j``.

The direct vector needs shadow rays. The choice made here: **trace them** (Embree, from the
measurement samples to each light), with a ray caster the caller builds once per scene and keeps
(:class:`workers.relight.RelightCache`; a BVH build is ~65 ms for 58k triangles, the rays themselves
~M·S·lights, a few hundred, well under a millisecond). Precomputing visibility instead is not possible for arbitrary new
lights: it would need visibility from every measurement sample to every possible light position. Without
shadows the direct vector of any light behind a wall would be wrong.

``relight`` takes the bake's PRT artifacts as a dict ``{artifact name: array or dict}`` (what
:func:`proto.bundle.open_bundle` returns, or the store's artifacts of the ``prt`` stage), or a prepared
:class:`PrtModel` (unpacking the basis textures once; do that and cache it when relighting repeatedly).

Outputs (float32, same layouts and names as the light stage's artifacts, proto/bundle.md §5.1):

- ``probe_sh`` (nz, ny, nx, K, 3): radiance SH per probe (three.js order), the probe light of the given
  lights alone (emission and sky are not part of the transfer);
- ``sh_l1_r``, ``sh_l1_g``, ``sh_l1_b`` (nz, ny, nx, 4): L0 + L1 of each channel (leaking probe GI volumes);
- ``sh_l2`` (7·(nz+2), ny, nx, 4): all 9 coefficients in the three.js LightProbeGrid layout
  (:func:`workers.kernels.sh.sh_l2_atlas`), only when the bake's SH is L2 (K = 9, ``light.sh_order`` 2, the
  default): what leaking probe GI and the prt GLSL mode shade with by default;
- ``lightmap`` (R, R, 4): indirect irradiance (lux x colour) in rgb, a = 1 on covered (and dilated)
  texels, 0 elsewhere; only when the bake has a lightmap target;
- ``prt_direct`` (M, 3): the direct vector x used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.kernels import prt as kprt
from workers.kernels.sh import sh_l2_atlas
from workers.kernels.shading import direct_irradiance

__all__ = ["PrtModel", "relight", "direct_vector"]


@dataclass
class _Target:
    slots: np.ndarray        # (L·c, n) float32: column j is slot j (c = 1 mono, 3 multi, colour fastest)
    transfer: np.ndarray     # (C, n, D + 1) float32


@dataclass
class PrtModel:
    """A bake's PRT arrays, unpacked for fast relighting."""

    section: dict
    points: dict             # position, normal, albedo (K, 3) float32; offsets (M + 1,) int32
    sh: _Target
    counts: tuple            # (nx, ny, nz)
    coefficients: int        # K, SH coefficients per probe
    lightmap: _Target | None = None
    lm_texels: np.ndarray | None = None   # (L,) flat indices of the covered + dilated texels
    lm_res: int = 0

    @property
    def channels(self) -> str:
        return self.section["channels"]

    @property
    def gamma(self) -> float | None:
        return self.section["gamma"]

    @property
    def norm(self) -> str:
        """‖x‖ of ``[x, ‖x‖]``: ``"l1"`` or ``"l2"`` (bundles before the field: l2)."""
        return self.section.get("norm", "l2")

    @classmethod
    def from_arrays(cls, arrays) -> "PrtModel":
        """Unpack the ``prt`` stage's artifacts (``{name: array or dict}``; see workers/stages/prt.py)."""
        sec = arrays["prt"]
        n = int(sec["basis"])
        mono = sec["channels"] == "mono"
        table = np.asarray(arrays[sec["points"]], np.float32)
        points = {"position": table[:, 0:3], "normal": table[:, 3:6], "albedo": table[:, 6:9],
                  "offsets": np.asarray(arrays[sec["point_offsets"]], np.int64)}
        shs = sec["sh"]
        nx, ny, nz = shs["counts"]
        K = int(shs["coefficients"])
        per_k = []
        for names in shs["basis"]:
            vols = np.stack([np.asarray(arrays[nm], np.float32) for nm in names])       # (G, nz, ny, nx, 4)
            per_k.append(kprt.unpack_rgba(vols, n) if mono else vols[..., :3])          # (n, nz, ny, nx[, 3])
        slots = np.stack(per_k, axis=4)                                                 # (n, nz, ny, nx, K[, 3])
        sh = _Target(np.ascontiguousarray(slots.reshape(n, -1).T), np.asarray(arrays[shs["transfer"]], np.float32))
        model = cls(section=sec, points=points, sh=sh, counts=(nx, ny, nz), coefficients=K)
        lm = sec.get("lightmap")
        if lm:
            res = int(lm["resolution"])
            mask = np.asarray(arrays[lm["mask"]]).reshape(res, res)
            texels = np.flatnonzero(mask.ravel() > 0)
            texs = np.stack([np.asarray(arrays[nm], np.float32) for nm in lm["basis"]])  # (G, R, R, 4)
            imgs = kprt.unpack_rgba(texs, n) if mono else texs[..., :3]                   # (n, R, R[, 3])
            flat = imgs.reshape(n, res * res, -1)[:, texels]                              # (n, L, c)
            model.lightmap = _Target(np.ascontiguousarray(flat.reshape(n, -1).T),
                                     np.asarray(arrays[lm["transfer"]], np.float32))
            model.lm_texels, model.lm_res = texels, res
        return model


def direct_vector(model: PrtModel, lights: list[dict], caster) -> np.ndarray:
    """x (M, 3) float64: ``albedo/π · E_direct`` at the measurement samples, averaged per point (PRT §4.3, §5.1)."""
    p = model.points
    if not lights:
        return np.zeros((p["offsets"].size - 1, 3))
    e = direct_irradiance(p["position"], p["normal"], lights, caster, float(model.section["shadow_eps"]))
    return kprt.group_mean(p["albedo"].astype(np.float64) / math.pi * e, p["offsets"])


def _apply(model: PrtModel, target: _Target, x: np.ndarray) -> np.ndarray:
    """(L, 3) float32 reconstruction of one target from the direct vector x (M, 3)."""
    xg = kprt.gamma_encode(x, model.gamma)
    T = target.transfer
    if model.channels == "mono":
        xa = np.concatenate([xg, kprt.direct_norm(xg, 0, model.norm)[None]], axis=0).astype(np.float32)  # [x_c, ‖x_c‖]
        u = np.einsum("cnm,mc->nc", T, xa)                        # (n, 3): one transfer per channel
        y = target.slots @ u                                      # (L, 3)
    else:
        flat = xg.reshape(-1)
        u = T[0] @ np.append(flat, kprt.direct_norm(flat, None, model.norm)).astype(np.float32)
        y = (target.slots @ u).reshape(-1, 3)
    return kprt.gamma_decode(y, model.gamma).astype(np.float32, copy=False)


def relight(prt_arrays, lights: list[dict], caster=None, *, lightmap: bool = True) -> dict[str, np.ndarray]:
    """The reconstructed indirect for new lights (see the module doc for the outputs).

    Parameters
    ----------
    prt_arrays : dict or PrtModel
        The ``prt`` stage's artifacts by name, or a model from :meth:`PrtModel.from_arrays`.
    lights : list of dict
        Lights in the scene format (``proto.models.LightConfig.model_dump()`` works): type, position,
        direction, color, intensity, range, cone angles. An empty list gives zeros.
    caster : workers.raycast.RayCaster
        For the shadow rays of the direct vector (:class:`workers.relight.RelightCache` keeps one per scene). Required
        unless ``lights`` is empty.
    lightmap : bool
        Also reconstruct the lightmap (when the bake has one).
    """
    model = prt_arrays if isinstance(prt_arrays, PrtModel) else PrtModel.from_arrays(prt_arrays)
    if lights and caster is None:
        raise ValueError("relight: a ray caster is needed for the shadow rays of the direct vector "
                         "(workers.raycast.caster_for_scene(scene))")
    x = direct_vector(model, list(lights), caster)
    nx, ny, nz = model.counts
    K = model.coefficients
    sh = _apply(model, model.sh, x).reshape(nz, ny, nx, K, 3)
    out = {"probe_sh": sh, "prt_direct": x.astype(np.float32)}
    for i, c in enumerate("rgb"):
        out[f"sh_l1_{c}"] = np.ascontiguousarray(sh[..., :4, i])
    if K == 9:
        out["sh_l2"] = sh_l2_atlas(sh)
    if lightmap and model.lightmap is not None:
        res = model.lm_res
        img = np.zeros((res * res, 4), np.float32)
        img[model.lm_texels, :3] = _apply(model, model.lightmap, x)
        img[model.lm_texels, 3] = 1.0
        out["lightmap"] = img.reshape(res, res, 4)
    return out
