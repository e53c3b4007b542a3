"""The storage precision of the bundle's float artifacts (issue 17, item 1; RTXGI's choices as the reference).

Each function takes an artifact's float32 data and returns ``(data, vk_format, meta)``: the data as the writer
takes it (:func:`proto.bundle.write_artifact`), the KTX2 format and what it cost, for the artifact's ``meta``:
``{"precision": {"format", "relative_rmse", "fallback"?}}`` where ``relative_rmse`` = ‖q − a‖₂ / ‖a‖₂ over the
values stored (0 for an all-zero array) and ``fallback`` says why a narrower format was not used.

=========================== =================================== ===========================================
function                    formats, first that fits            fits when
=========================== =================================== ===========================================
:func:`rgb9e5`              E5B9G9R9_UFLOAT_PACK32 (4 B/texel), every value is finite, ≥ 0 and ≤ 65408
                            else :func:`half` of RGBA           (the shared exponent's range)
:func:`rgb_ufloat`          B10G11R11_UFLOAT_PACK32 (4 B/texel), every value is finite, ≥ 0 and ≤ 65024
                            else :func:`half` of RGBA           (the 11/10-bit floats' range)
:func:`half`                R16…_SFLOAT (2 B per component),    every |value| ≤ 65504 (half's largest)
                            else R32…_SFLOAT
=========================== =================================== ===========================================

Both also fall back (to float32) when the largest magnitude is below :data:`SMALLEST_SCALE`, where half's
subnormal spacing would be a visible part of the signal. Rounding is to nearest even (numpy's ``astype(float16)``,
:func:`proto.ktx2.pack_b10g11r11`), so the same input always gives the same bytes. What each format adds to the GI
error of the runtime modes is measured by ``tests/bench/bench_formats.py``. The stages use :func:`half` (depth moments,
SH volumes, the PRT basis) and :func:`rgb9e5` (the irradiance atlas, issue 17: 4 bytes a texel instead of 8; 9
significant bits for the largest channel, so a grey value is off by at most 2^-9 ≈ 0.2%); :func:`rgb_ufloat` is
measured but not used: on a flatly lit region its rounding does not average out, and a grey value's error reaches
0.89% (over 0.5% for 38% of values).
"""
from __future__ import annotations

import numpy as np

from proto.ktx2 import RGB9E5_MAX, UFLOAT11_MAX, pack_b10g11r11, pack_e5b9g9r9, unpack_b10g11r11, unpack_e5b9g9r9

__all__ = ["HALF_MAX", "SMALLEST_SCALE", "half", "rgb9e5", "rgb_ufloat", "relative_rmse"]

HALF_MAX = 65504.0
"""Largest finite IEEE half."""
SMALLEST_SCALE = 2.0 ** -10
"""Below this largest magnitude (about 1e-3, in the artifact's unit) the float32 format is kept: half's subnormal
spacing, 2^-24 (2^-20 for the 11-bit floats), would then exceed 0.1% of the largest value."""

_HALF_FORMATS = {1: "R16_SFLOAT", 2: "R16G16_SFLOAT", 4: "R16G16B16A16_SFLOAT"}
_FLOAT_FORMATS = {1: "R32_SFLOAT", 2: "R32G32_SFLOAT", 3: "R32G32B32_SFLOAT", 4: "R32G32B32A32_SFLOAT"}


def relative_rmse(quantized: np.ndarray, exact: np.ndarray) -> float:
    """‖q − a‖₂ / ‖a‖₂ (float64 sums; 0 when ``exact`` is all 0)."""
    a = np.asarray(exact, np.float64)
    q = np.asarray(quantized, np.float64)
    norm = float(np.sqrt((a * a).sum()))
    return float(np.sqrt(((q - a) ** 2).sum())) / norm if norm > 0 else 0.0


def _scale_fallback(a: np.ndarray, limit: float) -> str | None:
    if not np.isfinite(a).all():
        return "non-finite values"
    top = float(np.abs(a).max(initial=0.0))
    if top > limit:
        return f"largest |value| {top:.6g} > {limit:.6g}"
    if 0.0 < top < SMALLEST_SCALE:
        return f"largest |value| {top:.3g} < {SMALLEST_SCALE:.3g}"
    return None


def _float32(a: np.ndarray, why: str) -> tuple[np.ndarray, str, dict]:
    c = a.shape[-1] if a.ndim >= 3 else 1
    return a, _FLOAT_FORMATS[c], {"precision": {"format": _FLOAT_FORMATS[c], "relative_rmse": 0.0, "fallback": why}}


def half(a: np.ndarray) -> tuple[np.ndarray, str, dict]:
    """(…, C) float32 (C = 1, 2 or 4; a 2-axis array is one channel) as half floats where they hold it, else float32.

    Returns ``(data, vk_format, meta)`` (module doc); ``data`` is float16 or the float32 input.
    """
    a = np.ascontiguousarray(a, np.float32)
    c = a.shape[-1] if a.ndim >= 3 else 1
    why = _scale_fallback(a, HALF_MAX)
    if why is not None or c not in _HALF_FORMATS:
        return _float32(a, why or f"{c} channels: no half format")
    q = a.astype(np.float16)
    return q, _HALF_FORMATS[c], {"precision": {"format": _HALF_FORMATS[c], "relative_rmse": relative_rmse(q, a)}}


def _packed_rgb(rgba: np.ndarray, name: str, limit: float, pack, unpack) -> tuple[np.ndarray, str, dict]:
    a = np.ascontiguousarray(rgba, np.float32)
    rgb = a[..., :3]
    why = _scale_fallback(rgb, limit)
    if why is None and float(rgb.min(initial=0.0)) < 0.0:
        why = f"negative values (smallest {float(rgb.min()):.6g})"
    if why is None:
        q = unpack(pack(rgb))
        return q, name, {"precision": {"format": name, "relative_rmse": relative_rmse(q, rgb)}}
    if a.shape[-1] == 3:
        a = np.concatenate([a, np.ones(a.shape[:-1] + (1,), np.float32)], axis=-1)
    data, vk, meta = half(a)
    meta["precision"]["fallback_from"] = f"{name}: {why}"
    return data, vk, meta


def rgb9e5(rgba: np.ndarray) -> tuple[np.ndarray, str, dict]:
    """(…, 3 or 4) float32 RGB(A) irradiance as E5B9G9R9_UFLOAT_PACK32 (shared exponent; alpha dropped: a reader
    sees a = 1) where it holds it, else :func:`half` of RGBA (alpha 1 where the input has none).

    Returns ``(data, vk_format, meta)``; ``data`` is the float32 RGB the packed format stores exactly (what a reader
    decodes, :func:`proto.ktx2.unpack_e5b9g9r9`) or the :func:`half` result.
    """
    return _packed_rgb(rgba, "E5B9G9R9_UFLOAT_PACK32", RGB9E5_MAX, pack_e5b9g9r9, unpack_e5b9g9r9)


def rgb_ufloat(rgba: np.ndarray) -> tuple[np.ndarray, str, dict]:
    """(…, 3 or 4) float32 RGB(A) irradiance as B10G11R11_UFLOAT_PACK32 (alpha dropped: it reads as 1) where the
    packed floats hold it, else :func:`half` of RGBA (alpha 1 where the input has none).

    Returns ``(data, vk_format, meta)``; ``data`` is the float32 RGB the packed format stores exactly (what a
    reader decodes) or the :func:`half` result.
    """
    return _packed_rgb(rgba, "B10G11R11_UFLOAT_PACK32", UFLOAT11_MAX, pack_b10g11r11, unpack_b10g11r11)
