"""Each runtime GI mode's indirect irradiance at arbitrary points, on the CPU (the evaluate stage's metrics).

The Python twins of the GLSL modes (``proto/glsl``), fed from the bake's artifacts by name, so the metrics need
no OpenGL and are computed at the reference's points (:mod:`workers.stages.reference`); also which modes a bake
has (:func:`available_modes`) and each mode's GI texture fetches per pixel (:func:`gi_fetches`):

=================== ===========================================================================================
``direct``          0 (no indirect light)
``leaking``         :func:`workers.kernels.samplers.irradiance` (L2 ``sh_l2`` when the bake has it, else L1)
``ddgi``            :func:`workers.kernels.ddgi.sample_irradiance` on the light stage's octahedral irradiance,
                    the trace stage's depth moments and the relocated probes, self-shadow bias of the config
``mask``,           :func:`workers.kernels.samplers.irradiance` with the masks the runtime reads: the compressed
``mask_normalized`` mask atlas decompressed (:func:`workers.kernels.compress.decompress`; equal to the dense
                    masks at ``compress_tolerance = 0``), the lookup offset along n + v of the runtime default;
                    L1 where the L2 cluster stack would not fit one 3D texture (as the shading pass falls back)
``prt``             the PRT reconstruction for the bake's own lights (:func:`workers.prt_relight.relight`), read
                    like ``leaking`` from the relit SH volumes
=================== ===========================================================================================

Results are clamped at 0 (the GLSL clamps). ``views``: unit directions from the points toward the viewer (the
camera for camera points; the normal for points without a viewer).
"""
from __future__ import annotations

import numpy as np

from proto.gi_modes import SELF_SHADOW_BIAS
from workers.kernels import samplers as SM
from workers.kernels.ddgi import cage_probes
from workers.kernels.grid import OFF

__all__ = ["mode_irradiance", "MaskArrays", "available_modes", "gi_fetches"]


class MaskArrays(dict):
    """A mapping of a bake's arrays with ``masks_0123`` / ``masks_4567`` replaced by the decompressed atlas (what
    the runtime samples); built lazily from ``arrays`` and the compress stage's meta."""

    def __init__(self, arrays, mask_meta: dict | None):
        super().__init__()
        self._arrays, self._meta = arrays, mask_meta

    def __contains__(self, k) -> bool:
        return k in self._arrays

    def __getitem__(self, k):
        if dict.__contains__(self, k):
            return dict.__getitem__(self, k)
        if k in ("masks_0123", "masks_4567") and self._meta is not None \
                and "mask_atlas" in self._arrays and "mask_indirection" in self._arrays:
            from proto.gi_modes import cluster_count
            from workers.kernels.mask_atlas import decompress_channels

            meta = {**self._meta, "clusters": self._meta.get("clusters") or cluster_count(self._arrays)}
            vols = decompress_channels(np.asarray(self._arrays["mask_atlas"]),
                                       np.asarray(self._arrays["mask_indirection"]), meta)
            if k == "masks_4567" and len(vols) < 2:
                raise KeyError(k)
            v = vols[0] if k == "masks_0123" else vols[1]
        else:
            v = self._arrays[k]
        dict.__setitem__(self, k, v)
        return v


def _mask_sh_order(arrays, grid) -> int | None:
    from proto.gi_modes import MAX_3D_TEXTURE_DEPTH, cluster_count
    from workers.kernels.sh import sh_l2_atlas_depth

    K = cluster_count(arrays)
    nz = int(grid["counts"][2])
    if SM.has_l2("mask", arrays) and sh_l2_atlas_depth(nz, K) > MAX_3D_TEXTURE_DEPTH:
        return 1
    return None


def mode_irradiance(mode: str, arrays, grid, points, normals, views, *, self_shadow_bias: float = SELF_SHADOW_BIAS,
                    lights=(), caster=None, prt_model=None) -> np.ndarray:
    """(N, 3) float64 indirect irradiance of ``mode`` at ``points`` with unit ``normals`` (see the module doc).

    ``arrays``: the bake's artifacts by name (wrap in :class:`MaskArrays` for the mask modes to read the
    compressed masks); ``lights`` and ``caster`` (and optionally a prepared ``prt_model``) for ``prt``.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    vws = np.asarray(views, np.float64).reshape(-1, 3)
    if len(pts) == 0 or mode == "direct":
        return np.zeros((len(pts), 3))
    if mode == "leaking":
        out = SM.irradiance("leaking", arrays, grid, pts, nrm)
    elif mode in ("mask", "mask_normalized"):
        out = SM.irradiance(mode, arrays, grid, pts, nrm, views=vws, sh_order=_mask_sh_order(arrays, grid))
    elif mode == "ddgi":
        from workers.kernels.ddgi import sample_irradiance
        from workers.kernels.grid import unpack_atlas

        counts = [int(c) for c in grid["counts"]]
        ny = counts[1]
        irr_atlas = np.asarray(arrays["irradiance"], np.float32)
        dep_atlas = np.asarray(arrays["depth_moments"], np.float32)
        irr = unpack_atlas(irr_atlas, counts, irr_atlas.shape[0] // ny)[..., :3]
        dep = unpack_atlas(dep_atlas, counts, dep_atlas.shape[0] // ny)
        pos = np.asarray(arrays["probe_positions_relocated"], np.float64).reshape(-1, 3)
        states = np.asarray(arrays["probe_states"]).reshape(-1)
        out = sample_irradiance(pts, nrm, vws, counts, grid["origin"], grid["spacing"], pos, states, irr, dep,
                                float(self_shadow_bias), layers=grid.get("layers"))
    elif mode == "prt":
        from workers.prt_relight import PrtModel, relight

        model = prt_model if prt_model is not None else PrtModel.from_arrays(arrays)
        relit = relight(model, list(lights), caster, lightmap=False)
        out = SM.irradiance("leaking", relit, grid, pts, nrm)
    else:
        raise ValueError(f"unknown mode {mode!r}")
    out = np.asarray(out, np.float64)
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0), 0.0)


def available_modes(arrays) -> list[str]:
    """The GI modes a bake has the artifacts for (``arrays``: artifact names, a mapping or a set), in the
    evaluate stage's order: direct, leaking, ddgi, mask, mask_normalized, prt."""
    modes = ["direct"]
    if all(f"sh_l1_{c}" in arrays for c in "rgb"):
        modes.append("leaking")
    if all(n in arrays for n in ("irradiance", "depth_moments", "probe_positions_relocated", "probe_states")):
        modes.append("ddgi")
    if "mask_indirection" in arrays and "mask_atlas" in arrays and "cluster_sh_0_r" in arrays:
        modes.append("mask")
        if "cluster_weights_0123" in arrays:
            modes.append("mask_normalized")
    if "prt" in arrays:
        modes.append("prt")
    return modes


def gi_fetches(mode: str, res, arrays, grid, points, normals, views) -> np.ndarray:
    """(N,) GI texture fetches per pixel of ``mode`` at the points: the formulas of the mode GLSL headers.

    ``res``: the mode's :class:`workers.render.shading.ModeResources` (``info``: ``sh_order``, ``clusters``,
    ``coefficients``, ``groups``; ``uniforms``: ``uMaskOffset``); ``arrays``: the bake's artifacts by name;
    ``grid``: counts, origin, spacing; points (N, 3) world space, metres; normals, views (N, 3) unit.
    """
    N = points.shape[0]
    if mode == "direct" or N == 0:
        return np.zeros(N)
    if mode == "leaking":
        return np.full(N, 7.0 if res.info.get("sh_order") == 2 else 3.0)     # sh_l2 sub-volumes, or sh_l1_{r,g,b}
    if mode == "ddgi":
        _, cage = cage_probes(points, normals, views, grid["counts"], grid["origin"], grid["spacing"], 0.3,
                              layers=grid.get("layers"))
        live = (np.asarray(arrays["probe_states"]).reshape(-1)[cage] != OFF).sum(axis=1)
        return 8.0 + 2.0 * live                                              # 8 state/position + 2 per live corner
    if mode in ("mask", "mask_normalized"):
        from workers.kernels.compress import mask_lookups
        from workers.kernels.mask_atlas import FIRST_SLOT, codes_of

        K = res.info["clusters"]
        A = 1 + (K > 4)
        vols = [arrays["masks_0123"]] + ([arrays["masks_4567"]] if K > 4 else [])
        m = SM.mask_values(vols, points, normals, grid, float(res.uniforms.get("uMaskOffset", 0.0)), views)[:, :K]
        z = (m > 0).sum(axis=1)                                              # MD §1: clusters with m_k > 0
        S = int(res.uniforms["uMaskS"])
        _, cell = mask_lookups(points, grid["counts"], grid["origin"], grid["spacing"], S, layers=grid.get("layers"))
        ci = cell.astype(np.int64)
        codes = codes_of(arrays["mask_indirection"], K)[ci[:, 2], ci[:, 1], ci[:, 0]]
        y = (codes >= FIRST_SLOT).sum(axis=1)                                # channels stored in the atlas
        per = 7.0 if res.info.get("sh_order") == 2 else 3.0                   # L2: 7 sub-volumes per cluster
        return 2.0 * A + 2.0 * y + per * z + (A if mode == "mask_normalized" else 0)
    if mode == "prt":
        return np.full(N, float(res.info.get("coefficients", 4)) * res.info["groups"])
    raise ValueError(mode)
