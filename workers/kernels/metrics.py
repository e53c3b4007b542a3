"""Image metrics of the evaluate stage: tone map, RMSE (MD §4.2), FLIP, leak score, heatmaps, previews.

All functions take numpy arrays and return arrays, numbers or PNG bytes (no files).

Tone map (one, fixed, for every image of a comparison)
-----------------------------------------------------
:func:`tonemap` maps linear radiance ``L`` (H, W, 3) to display-referred sRGB in [0, 1]:

1. exposure: ``x = k · L`` with ``k`` from the *reference* image only (:func:`exposure_for`):
   ``k = 0.18 / median(Y)`` over its covered pixels, Y the Rec. 709 luminance — the photographic
   key 0.18 (Reinhard et al. 2002) on the median rather than the log-average, which large black
   regions (shadowed rooms, back faces) or a bright emitter in view would drag;
2. curve: the ACES filmic fit of Narkowicz (2015), per channel,
   ``f(x) = clamp(x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), 0, 1)``;
3. encoding: the sRGB OETF (IEC 61966-2-1).

Every mode of one camera uses the reference's ``k``, so images differ only where radiance does.

RMSE (MD §4.2)
--------------
MD measures the error of the *final shading result* (the rendered image) against the ground truth
with colour values "in normalized (0 to 1) range": per pixel
``E(x) = sqrt(1/3 Σ_{n∈RGB} (C_n(x) − C'_n(x))²)`` (:func:`pixel_error`, the heatmap of MD Fig 3,
bottom row, range 0 … 1) and over the image ``E_RMSE = sqrt(1/s Σ_i E(i)²)`` (:func:`rmse`), s the
number of pixels. We apply both to the tone-mapped LDR colours (the images a user sees), over the
covered pixels when a mask is given. :func:`relative_rmse` is our addition for linear quantities
(irradiance): ``sqrt(mean |T − R|²) / mean |R|``.

FLIP
----
:func:`flip_mean`: NVIDIA FLIP (``flip-evaluator``, LDR mode, 67 pixels per degree) on the two
tone-mapped sRGB images — the perceptual error DDGI-I §4.1 reports. The inputs are validated here
first (flip-evaluator exits the process on bad arguments). The mean is over the mask when given.

Leak score
----------
:func:`leak_score`: light that reaches places where the reference says almost none arrives.
With R(x), T(x) the luminance of the reference's and the test's *indirect irradiance* at the covered
pixels P, the dark set is ``D = {x ∈ P : R(x) ≤ τ · mean_P R}`` (τ = 0.05 by default) and

    leak = mean_{x ∈ D} |T(x) − R(x)| / mean_P R

(0 when D is empty). So 0.1 means: in the dark places, the test adds on average 10% of the scene's
mean indirect light. Within D, ``|T − R|`` differs from the excess ``max(0, T − R)`` by at most
τ · mean R. The reference scores 0 against itself.

Colour maps: :func:`heatmap` uses a jet-style ramp (0 blue → cyan → green → yellow → 1 red, MD Fig 3
bottom row); FLIP error maps come back magma-coloured from flip-evaluator (DDGI-I Figs 5, 7, 8).

Consumers: the evaluate stage, tests. Inverse: none.
"""
from __future__ import annotations

import io
import math

import numpy as np

__all__ = ["luminance", "exposure_for", "tonemap", "srgb_encode", "pixel_error", "rmse", "relative_rmse",
           "flip_mean", "flip_magma", "leak_score", "heatmap", "to_uint8", "png_bytes", "contact_sheet", "REC709"]

REC709 = np.array([0.2126, 0.7152, 0.0722])
LEAK_TAU = 0.05
FLIP_PPD = 67.0


# ------------------------------------------------------------------------------------ tone map
def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of linear RGB (..., 3) -> (...)."""
    return np.asarray(rgb, np.float64) @ REC709


def _mask_or_all(shape, mask):
    if mask is None:
        return np.ones(shape, bool)
    m = np.asarray(mask, bool)
    if m.shape != shape:
        raise ValueError(f"mask shape {m.shape} does not match the image {shape}")
    return m


def exposure_for(reference, mask=None, key: float = 0.18) -> float:
    """Exposure k with ``k · median luminance = key`` over the reference's covered pixels; the mean
    stands in when the median is 0, and k = 1 for a black image."""
    ref = _image(reference, "reference")
    m = _mask_or_all(ref.shape[:2], mask)
    y = luminance(ref)[m]
    y = np.maximum(y[np.isfinite(y)], 0.0)
    if y.size == 0 or not np.any(y > 0):
        return 1.0
    mid = float(np.median(y))
    return float(key / (mid if mid > 0 else float(y.mean())))


def srgb_encode(c) -> np.ndarray:
    """sRGB OETF: linear [0, 1] -> encoded [0, 1] (float64)."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def tonemap(radiance, exposure: float) -> np.ndarray:
    """Linear radiance (H, W, 3) -> display sRGB in [0, 1], float32 (see the module doc)."""
    x = np.maximum(np.asarray(radiance, np.float64), 0.0) * float(exposure)
    x = np.nan_to_num(x, nan=0.0, posinf=1e30)
    y = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    return srgb_encode(y).astype(np.float32)


# ------------------------------------------------------------------------------------ errors
def _image(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} must be an (H, W, 3) image, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got {a.dtype}")
    return a.astype(np.float64, copy=False)


def _pair(test, reference):
    t = _image(test, "test")
    r = _image(reference, "reference")
    if t.shape != r.shape:
        raise ValueError(f"test {t.shape} and reference {r.shape} differ in shape")
    return t, r


def pixel_error(test, reference) -> np.ndarray:
    """MD §4.2 per-pixel error ``E(x) = sqrt(mean_RGB (C − C')²)``, (H, W) float64."""
    t, r = _pair(test, reference)
    return np.sqrt(np.mean((t - r) ** 2, axis=-1))


def rmse(test, reference, mask=None) -> float:
    """MD §4.2 ``E_RMSE = sqrt(mean_i E(i)²)`` over the (masked) pixels of two LDR colour images in [0, 1]."""
    e = pixel_error(test, reference)
    m = _mask_or_all(e.shape, mask)
    if not m.any():
        return 0.0
    return float(np.sqrt(np.mean(e[m] ** 2)))


def relative_rmse(test, reference, mask=None) -> float:
    """Linear-quantity RMSE relative to the reference's mean magnitude: ``sqrt(mean |T−R|²) / mean |R|``
    (RGB vectors, over the masked pixels); 0 for identical inputs, inf when R is all zero and T is not."""
    t, r = _pair(test, reference)
    m = _mask_or_all(t.shape[:2], mask)
    if not m.any():
        return 0.0
    num = math.sqrt(float(np.mean(np.sum((t[m] - r[m]) ** 2, axis=-1))))
    den = float(np.mean(np.linalg.norm(r[m], axis=-1)))
    if den == 0:
        return 0.0 if num == 0 else math.inf
    return num / den


def flip_mean(test_ldr, reference_ldr, mask=None, ppd: float = FLIP_PPD, return_map: bool = False):
    """Mean FLIP error of two LDR sRGB images in [0, 1] (H, W, 3); with ``return_map`` also the (H, W)
    error map. Validates inputs first (shape, finite, range, size), since flip-evaluator calls sys.exit."""
    t, r = _pair(test_ldr, reference_ldr)
    for name, a in (("test", t), ("reference", r)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"flip_mean: the {name} image has NaN or inf")
        if a.min() < 0.0 or a.max() > 1.0:
            raise ValueError(f"flip_mean: the {name} image must be LDR in [0, 1] (tone map it first), "
                             f"got [{a.min()}, {a.max()}]")
    if not (math.isfinite(ppd) and ppd > 0):
        raise ValueError(f"flip_mean: ppd must be positive, got {ppd}")
    m = _mask_or_all(t.shape[:2], mask)
    import flip_evaluator

    err, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(r, np.float32), np.ascontiguousarray(t, np.float32),
                                           "LDR", inputsRGB=True, applyMagma=False, computeMeanError=True,
                                           parameters={"ppd": float(ppd)})
    emap = np.asarray(err, np.float64).reshape(t.shape[:2])
    value = float(emap[m].mean()) if mask is not None else float(mean)
    if not m.any():
        value = 0.0
    return (value, emap) if return_map else value


def flip_magma(error_map) -> np.ndarray:
    """(H, W) FLIP errors in [0, 1] -> (H, W, 3) uint8 with the magma colour map (flip-evaluator's)."""
    e = np.clip(np.asarray(error_map, np.float64), 0, 1)
    if e.ndim != 2:
        raise ValueError(f"flip_magma: error map must be (H, W), got {e.shape}")
    return to_uint8(_ramp(e, _MAGMA))


def leak_score(test_indirect, reference_indirect, mask=None, tau: float = LEAK_TAU) -> dict:
    """Leak score of a test's indirect irradiance against the reference's (see the module doc).

    Returns ``{"leak", "dark_fraction", "dark_pixels", "tau", "mean_reference"}``.
    """
    t, r = _pair(test_indirect, reference_indirect)
    if not (tau >= 0 and math.isfinite(tau)):
        raise ValueError(f"leak_score: tau must be finite and >= 0, got {tau}")
    m = _mask_or_all(t.shape[:2], mask)
    yt, yr = luminance(t)[m], luminance(r)[m]
    mean_r = float(yr.mean()) if yr.size else 0.0
    if yr.size == 0 or mean_r <= 0:
        return {"leak": 0.0, "dark_fraction": 0.0, "dark_pixels": 0, "tau": tau, "mean_reference": mean_r}
    dark = yr <= tau * mean_r
    leak = float(np.abs(yt[dark] - yr[dark]).mean() / mean_r) if dark.any() else 0.0
    return {"leak": leak, "dark_fraction": float(dark.mean()), "dark_pixels": int(dark.sum()), "tau": tau,
            "mean_reference": mean_r}


# ------------------------------------------------------------------------------------ images
# jet-style ramp: 0 dark blue, blue, cyan, yellow, red, 1 dark red
_JET = np.array([[0.000, 0.0, 0.0, 0.5], [0.125, 0.0, 0.0, 1.0], [0.375, 0.0, 1.0, 1.0], [0.625, 1.0, 1.0, 0.0],
                 [0.875, 1.0, 0.0, 0.0], [1.000, 0.5, 0.0, 0.0]])
# magma (matplotlib) at 9 stops
_MAGMA = np.array([[0.000, 0.001, 0.000, 0.014], [0.125, 0.113, 0.065, 0.277], [0.250, 0.316, 0.072, 0.485],
                   [0.375, 0.512, 0.128, 0.504], [0.500, 0.716, 0.215, 0.475], [0.625, 0.904, 0.310, 0.388],
                   [0.750, 0.990, 0.503, 0.383], [0.875, 0.996, 0.738, 0.525], [1.000, 0.987, 0.991, 0.750]])


def _ramp(v: np.ndarray, stops: np.ndarray) -> np.ndarray:
    v = np.clip(v, 0.0, 1.0)
    return np.stack([np.interp(v, stops[:, 0], stops[:, c]) for c in (1, 2, 3)], axis=-1)


def heatmap(error, vmax: float = 1.0, mask=None) -> np.ndarray:
    """(H, W) errors -> (H, W, 3) uint8, ``error / vmax`` through the jet-style ramp (MD Fig 3 bottom row:
    0 … 1); pixels outside ``mask`` are black."""
    e = np.asarray(error, np.float64)
    if e.ndim != 2:
        raise ValueError(f"heatmap: error must be (H, W), got {e.shape}")
    if not (vmax > 0 and math.isfinite(vmax)):
        raise ValueError(f"heatmap: vmax must be positive, got {vmax}")
    rgb = _ramp(np.nan_to_num(e / vmax), _JET)
    if mask is not None:
        rgb[~_mask_or_all(e.shape, mask)] = 0.0
    return to_uint8(rgb)


def to_uint8(img) -> np.ndarray:
    """[0, 1] float (or uint8) image -> uint8, rounded; (H, W) or (H, W, C)."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    return np.round(np.clip(np.nan_to_num(a.astype(np.float64)), 0.0, 1.0) * 255.0).astype(np.uint8)


def png_bytes(img, compress_level: int = 1) -> bytes:
    """PNG file bytes of an (H, W), (H, W, 3) or (H, W, 4) image in [0, 1] float or uint8 (row 0 = top).
    ``compress_level`` (zlib, 0-9): 1 by default, 3-4x faster than PIL's 6 for previews a few % larger."""
    from PIL import Image

    a = to_uint8(img)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (1, 3, 4)):
        raise ValueError(f"png_bytes: unsupported image shape {a.shape}")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(a)).save(buf, format="PNG", optimize=False, compress_level=int(compress_level))
    return buf.getvalue()


def contact_sheet(tiles, columns: int | None = None, pad: int = 4, label_height: int = 14,
                  background=(24, 24, 24)) -> np.ndarray:
    """Tiles side by side with a label above each: ``tiles`` = [(label, image), ...] (images as in
    :func:`png_bytes`, any sizes). Returns an (H, W, 3) uint8 image."""
    from PIL import Image, ImageDraw

    tiles = list(tiles)
    if not tiles:
        raise ValueError("contact_sheet: no tiles")
    imgs = []
    for label, im in tiles:
        a = to_uint8(im)
        if a.ndim == 2:
            a = np.repeat(a[:, :, None], 3, axis=2)
        if a.ndim != 3 or a.shape[2] not in (3, 4):
            raise ValueError(f"contact_sheet: tile {label!r} has unsupported shape {a.shape}")
        imgs.append((str(label), a[:, :, :3]))
    n = len(imgs)
    cols = int(columns) if columns else min(n, 4)
    rows = -(-n // cols)
    cw = max(a.shape[1] for _, a in imgs)
    ch = max(a.shape[0] for _, a in imgs) + label_height
    sheet = Image.new("RGB", (cols * cw + (cols + 1) * pad, rows * ch + (rows + 1) * pad), tuple(background))
    draw = ImageDraw.Draw(sheet)
    for k, (label, a) in enumerate(imgs):
        r, c = divmod(k, cols)
        x = pad + c * (cw + pad)
        y = pad + r * (ch + pad)
        draw.text((x + 2, y + 1), label, fill=(230, 230, 230))
        sheet.paste(Image.fromarray(np.ascontiguousarray(a)), (x, y + label_height))
    return np.asarray(sheet)
