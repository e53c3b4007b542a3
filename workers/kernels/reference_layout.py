"""The layout of the reference stage's tables, shared by its writer (stage ``reference``) and its reader
(stage ``evaluate``): one source for both (numpy only).

- ``reference_points`` (N, 27) float32: column groups :data:`POINT_COLUMNS`, 3 columns each — world-space
  position (metres), shading normal, geometric normal, view (unit, towards the camera), albedo, emission,
  then the reference's direct and indirect irradiance and the indirect's standard error (linear RGB).
- ``reference_<cam>_gbuffer`` (H, W, 16) float32: channel groups :data:`GBUFFER_CHANNELS`, 3 channels each,
  ``shaded`` 1 (1.0 where the pixel reflects light, :attr:`workers.render.gbuffer.GBuffer.shaded`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["POINT_COLUMNS", "GBUFFER_CHANNELS", "point_column", "point_table", "point_columns", "pack_gbuffer",
           "unpack_gbuffer"]

POINT_COLUMNS = ("position", "normal", "geo_normal", "view", "albedo", "emission", "e_direct", "e_indirect",
                 "stderr")
"""Column groups (3 each) of the ``reference_points`` table."""
GBUFFER_CHANNELS = ("position", "normal", "geo_normal", "albedo", "emission", "shaded")
"""Channel groups of ``reference_<cam>_gbuffer`` (3 each, ``shaded`` 1)."""


def point_column(table: np.ndarray, name: str) -> np.ndarray:
    """Column group ``name`` of a ``reference_points`` table: (N, 3) float64."""
    i = POINT_COLUMNS.index(name)
    return np.asarray(table, np.float64)[:, 3 * i:3 * i + 3]


def point_columns(table: np.ndarray) -> dict[str, np.ndarray]:
    """Every column group of a ``reference_points`` table: ``{name: (N, 3) float64}``."""
    table = np.asarray(table, np.float64)
    return {k: point_column(table, k) for k in POINT_COLUMNS}


def point_table(surface: dict, e_direct, e_indirect, stderr) -> np.ndarray:
    """The (N, 27) float32 ``reference_points`` table of surface points ``surface`` (the first six column groups,
    (N, 3) each, as :mod:`workers.kernels.surface_points` returns them) and their reference values (N, 3)."""
    if not len(surface["position"]):
        return np.zeros((0, 3 * len(POINT_COLUMNS)), np.float32)
    cols = [surface[k] for k in POINT_COLUMNS[:6]] + [e_direct, e_indirect, stderr]
    return np.concatenate(cols, axis=1).astype(np.float32)


def pack_gbuffer(gb) -> np.ndarray:
    """(H, W, 16) float32 of a :class:`workers.render.gbuffer.GBuffer` (channels :data:`GBUFFER_CHANNELS`)."""
    return np.concatenate([gb.position, gb.normal, gb.geo_normal, gb.albedo, gb.emission,
                           gb.shaded[..., None].astype(np.float32)], axis=-1).astype(np.float32)


def unpack_gbuffer(packed: np.ndarray) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_gbuffer`: ``{channel: (H, W, 3) float32}``, ``shaded`` (H, W) bool."""
    out, c = {}, 0
    for k in GBUFFER_CHANNELS:
        w = 1 if k == "shaded" else 3
        out[k] = np.ascontiguousarray(packed[..., c:c + w]) if w == 3 else packed[..., c] > 0.5
        c += w
    return out
