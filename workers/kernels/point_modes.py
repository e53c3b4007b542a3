"""Each runtime GI mode's indirect irradiance at arbitrary points, on the CPU (the evaluate stage's metrics).

The Python twins of the GLSL modes (``proto/glsl``), fed from the bake's artifacts by name, so the metrics need
no OpenGL and are computed at the reference's points (:mod:`workers.stages.reference`):

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

__all__ = ["mode_irradiance", "MaskArrays"]


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
                and f"mask_atlas_{k[-4:]}" in self._arrays and "mask_indirection" in self._arrays:
            from workers.kernels.compress import decompress

            v = decompress(np.asarray(self._arrays[f"mask_atlas_{k[-4:]}"]),
                           np.asarray(self._arrays["mask_indirection"]), self._meta)
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
                                float(self_shadow_bias))
    elif mode == "prt":
        from workers.prt_relight import PrtModel, relight

        model = prt_model if prt_model is not None else PrtModel.from_arrays(arrays)
        relit = relight(model, list(lights), caster, lightmap=False)
        out = SM.irradiance("leaking", relit, grid, pts, nrm)
    else:
        raise ValueError(f"unknown mode {mode!r}")
    out = np.asarray(out, np.float64)
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
