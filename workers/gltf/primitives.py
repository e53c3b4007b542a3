"""Mesh primitives: their triangles from indices and modes, and their corners written out in world space.

:func:`planned_triangles` bounds a primitive's triangle count from accessor counts alone (the triangle limit is
checked before any geometry is read); :func:`triangle_indices` turns TRIANGLES, TRIANGLE_STRIP and
TRIANGLE_FAN into (T, 3) corner indices ([glTF] 3.7.2.1; points and lines are counted and dropped);
:func:`emit` transforms one primitive's corners to world space, per instance or per skinned vertex, keeps
counter-clockwise front faces under mirroring transforms, normalizes normals (face normals where a vertex
normal is zero or NaN) and writes triangles, normals, UVs, colours and material indices into the output
arrays, in blocks that bound the float64 temporaries. Consumer: :mod:`workers.gltf.reader`. Inverse: none.

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", section 3.7.2.1 (primitive modes, topology).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from workers.gltf.accessors import Accessors
from workers.gltf.document import Document, is_int
from workers.gltf.errors import err, invalid
from workers.gltf.limits import BLOCK, check_world_positions
from workers.gltf.nodes import cofactor, normalize_rows

__all__ = ["MODE_NAMES", "planned_triangles", "triangle_indices", "emit"]

MODE_NAMES = {0: "point", 1: "line", 2: "line-loop", 3: "line-strip", 4: "triangles", 5: "strip", 6: "fan"}
"""glTF primitive mode -> the word its warnings use."""


def planned_triangles(doc: Document, prim: dict, what: str) -> int:
    """Upper bound on a primitive's triangle count from accessor counts only (no data read)."""
    attrs = prim.get("attributes")
    if not isinstance(attrs, dict) or "POSITION" not in attrs:
        return 0
    mode = prim.get("mode", 4)
    src = prim["indices"] if "indices" in prim else attrs["POSITION"]
    n = doc.item("accessors", src, what).get("count")
    if not is_int(n) or n < 0:
        raise invalid(f"{what}: accessor count must be a non-negative integer")
    if mode == 4:
        return n // 3
    if mode in (5, 6):
        return max(n - 2, 0)
    return 0


def triangle_indices(acc: Accessors, prim: dict, n_vertices: int, what: str, counts: Counter) -> np.ndarray | None:
    """(T, 3) int64 corner indices (TRIANGLES / strip / fan), None for points and lines."""
    mode = prim.get("mode", 4)
    if not is_int(mode) or mode not in MODE_NAMES:
        raise invalid(f"{what} has unknown mode {mode!r}")
    if "indices" in prim:
        idx = acc.indices(prim["indices"], n_vertices, what)
    else:
        idx = np.arange(n_vertices, dtype=np.int64)
    if mode < 4:
        counts[f"{MODE_NAMES[mode]} primitive(s) ignored"] += 1
        return None
    n = idx.size
    if mode == 4:
        if n % 3:
            counts[
                "TRIANGLES primitive(s) whose index count is not a multiple of 3 (extra indices ignored)"
            ] += 1
        return idx[: n - n % 3].reshape(-1, 3)
    if n < 3:
        return np.zeros((0, 3), np.int64)
    i = np.arange(n - 2)
    if mode == 5:  # [glTF] 3.7.2.1: p_i = {v_i, v_{i+(1+i%2)}, v_{i+(2-i%2)}}
        odd = i % 2
        return np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)
    return np.stack([idx[i + 1], idx[i + 2], np.full(n - 2, idx[0])], axis=1)  # fan: {v_{i+1}, v_{i+2}, v_0}


def emit(
    out,
    cursor: int,
    pos: np.ndarray,
    nrm: np.ndarray | None,
    skin_m: np.ndarray | None,
    mats: np.ndarray | None,
    tri: np.ndarray,
    uv: np.ndarray | None,
    uv1: np.ndarray | None,
    mat: int,
    what: str,
    counts: Counter,
    color: np.ndarray | None = None,
) -> int:
    """Write one primitive's world-space triangles into the output arrays from row ``cursor``.

    Parameters
    ----------
    out : tuple of arrays
        ``(triangles (N, 3, 3), normals (N, 3, 3), uv0 (N, 3, 2), uv1 (N, 3, 2) or None, material (N,),
        colors (N, 3, 4) or None)``.
    pos, nrm : (V, 3) float64
        Object-space positions and normals (``nrm`` None: flat geometric normals are used).
    skin_m : (V, 4, 4) float64 or None
        Per-vertex skinning matrices (object -> world); else ``mats``.
    mats : (K, 4, 4) float64 or None
        Object -> world matrices, one per instance.
    tri : (T, 3) int64
        Corner indices into the vertices.
    uv, uv1 : (V, 2) or None
        The texture UV set for ``uv0`` (transform applied) and TEXCOORD_1.
    color : (V, 4) float32 or None
        COLOR_0 as linear RGBA (ones where the primitive has none).
    mat : int
        Material index for every triangle.

    Returns
    -------
    int
        The next free output row.
    """
    tri_out, nrm_out, uv0_out, uv1_out, mat_out, color_out = out
    n_tri = tri.shape[0]
    if skin_m is not None:
        m3 = skin_m[:, :3, :3]
        det_v = np.linalg.det(m3)
        wp_all = np.einsum("vij,vj->vi", m3, pos) + skin_m[:, :3, 3]
        wn_all = None
        if nrm is not None:
            wn_all = np.einsum("vij,vj->vi", cofactor(m3) * np.sign(det_v)[:, None, None], nrm)
        groups = [(wp_all[None], None if wn_all is None else wn_all[None], det_v[None])]
    else:
        k_block = max(1, BLOCK // max(pos.shape[0], n_tri * 3, 1))
        groups = (
            _instance_group(mats[k0 : k0 + k_block], pos, nrm) for k0 in range(0, mats.shape[0], k_block)
        )
    t_block = max(1, BLOCK // 3)
    for wp, wn, det in groups:  # wp, wn: (k, V, 3); det: (k, V) or (k, 1)
        k = wp.shape[0]
        kk = np.arange(k)[:, None, None]
        for t0 in range(0, n_tri, t_block):
            sub = tri[t0 : t0 + t_block]
            t = sub.shape[0]
            # A negative determinant mirrors the triangle: swap two corners to keep CCW front faces.
            flip = (det[:, sub[:, 0]] if det.shape[1] > 1 else np.broadcast_to(det, (k, t))) < 0
            corners = np.broadcast_to(sub, (k, t, 3)).copy()
            corners[flip] = corners[flip][:, [0, 2, 1]]
            p = wp[kk, corners]  # (k, t, 3, 3)
            p32 = p.astype(np.float32)  # overflow -> inf, reported just below
            check_world_positions(p, p32, what)
            geo, geo_ok = normalize_rows(np.cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]))
            geo[~geo_ok] = (0.0, 1.0, 0.0)  # zero-area triangle: any unit normal will do
            normals = np.broadcast_to(geo[..., None, :], p.shape)
            if wn is not None:
                vn, vn_ok = normalize_rows(wn[kk, corners])
                if not vn_ok.all():
                    counts["vertex normal(s) that were zero or NaN replaced by face normals"] += int(
                        (~vn_ok).sum()
                    )
                normals = np.where(vn_ok[..., None], vn, normals)
            stop = cursor + k * t
            tri_out[cursor:stop] = p32.reshape(-1, 3, 3)
            nrm_out[cursor:stop] = normals.reshape(-1, 3, 3)
            mat_out[cursor:stop] = mat
            for src, dst, name in ((uv, uv0_out, "uv0"), (uv1, uv1_out, "TEXCOORD_1"), (color, color_out, "COLOR_0")):
                if src is None or dst is None:
                    continue
                c = src[corners].astype(np.float32)  # (k, t, 3, 2|4)
                if not np.isfinite(c).all():
                    raise err("non_finite", f"{what} has NaN or infinite {name} coordinates")
                dst[cursor:stop] = c.reshape(-1, 3, c.shape[-1])
            cursor = stop
    return cursor


def _instance_group(mats: np.ndarray, pos: np.ndarray, nrm: np.ndarray | None):
    """World positions (k, V, 3), normals (k, V, 3) or None and determinants (k, 1) for k instances."""
    m3 = mats[:, :3, :3]
    det = np.linalg.det(m3)
    wp = np.einsum("kij,vj->kvi", m3, pos) + mats[:, None, :3, 3]
    wn = None
    if nrm is not None:
        wn = np.einsum("kij,vj->kvi", cofactor(m3) * np.sign(det)[:, None, None], nrm)
    return wp, wn, det[:, None]
