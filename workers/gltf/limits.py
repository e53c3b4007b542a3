"""What one upload may cost, and the checks that refuse hostile or meaningless magnitudes.

:class:`IngestLimits` bounds sizes (bytes, triangles, zip expansion, image pixels, decoded geometry, JSON depth);
the constants and ``check_*`` functions here refuse values that are numbers but not a scene: non-finite or
absurdly far world positions, emitters and lights past any physical brightness, a scene with zero extent or
only zero-area triangles, and buffers that hold text rather than binary numbers (a Git LFS pointer committed
in the model's place). Each raises :class:`workers.gltf.errors.IngestError` with the code named in its doc.
Consumer: the other modules of :mod:`workers.gltf`. Inverse: none.
"""

from __future__ import annotations

import math
import urllib.parse
from dataclasses import dataclass

import numpy as np

from workers.gltf.errors import err, plural

__all__ = ["IngestLimits", "MAX_COORD", "MAX_EMISSIVE", "MAX_LIGHT_INTENSITY", "MAX_LIGHT_COLOR", "MIN_EXTENT",
           "DEGENERATE_SINE", "LFS_POINTER", "BLOCK", "check_binary", "check_world_positions", "check_emissive",
           "check_light_values", "check_light_place", "check_extent"]


@dataclass
class IngestLimits:
    """Upper bounds on what one upload may cost.

    Attributes
    ----------
    max_bytes : int
        Upload size in bytes (code ``too_large``, 413).
    max_triangles : int
        Triangles after instancing, counted from the JSON before any geometry is read
        (``too_many_triangles``, 413).
    max_expanded_bytes : int
        Zip: sum of the declared uncompressed member sizes, also enforced while extracting
        (``zip_bomb``, 413).
    max_zip_ratio : float
        Zip: uncompressed/compressed size, per member and in total, checked for members (or totals)
        of at least 8 MiB (``zip_bomb``).
    max_zip_members : int
        Zip: number of entries (``zip_bomb``).
    max_image_pixels : int
        Width x height of one image, read from its header before decoding (``image_too_large``, 413).
    max_json_depth : int
        Nesting of JSON objects/arrays (``json_too_deep``).
    max_decoded_bytes : int or None
        Draco and meshopt data: bytes after decoding, summed over the file (``decoded_too_large``, 413);
        None means 16 x ``max_bytes``.
    max_total_image_pixels : int or None
        Width x height summed over every image the scene keeps, from their headers before each is decoded
        (``image_too_large``, 413): four 8192² PNGs in a 350 KB file decode to 1 GB. None: no total limit.
    """

    max_bytes: int = 512 * 2**20
    max_triangles: int = 5_000_000
    max_expanded_bytes: int = 1 * 2**30
    max_zip_ratio: float = 200.0
    max_zip_members: int = 10_000
    max_image_pixels: int = 64 * 2**20
    max_json_depth: int = 64
    max_decoded_bytes: int | None = None
    max_total_image_pixels: int | None = None


MAX_COORD = 1e7
"""Largest world-space coordinate, metres (10,000 km), after node transforms: beyond it a scene is garbage (a
scale of 1e20, text read as floats ~1e31), and float32 cannot place probes in it (``absurd_magnitude``)."""
MAX_EMISSIVE = 1e6
"""Largest emissive factor x KHR_materials_emissive_strength (``absurd_magnitude``)."""
MAX_LIGHT_INTENSITY = 1e12
"""Largest KHR_lights_punctual intensity, candela or lux (the sun is ~1e5 lux) (``absurd_magnitude``)."""
MAX_LIGHT_COLOR = 1e6
"""Largest KHR_lights_punctual colour component (``absurd_magnitude``)."""
MIN_EXTENT = 1e-6
"""Smallest diagonal of the scene's bounds, metres (``zero_extent``)."""
DEGENERATE_SINE = 1e-6
"""A triangle is degenerate when twice its area is below this times its longest edge squared (``|e1 x e2| <
1e-6 * l_max^2``: an angle under ~1e-6 rad, float32 rounding of collinear corners included)."""
LFS_POINTER = b"version https://git-lfs"
"""How a Git LFS pointer file starts (a small text file committed in place of the model or a buffer)."""
BLOCK = 1 << 19
"""Corners per processing block: bounds the float64 temporaries (~40 MB each)."""
_TEXT_BYTES = bytes(range(0x20, 0x7F)) + b"\t\n\r"
_TEXT_MIN_BYTES = 64  # shorter buffers are not judged (a few random floats can be printable bytes)


def check_binary(data: np.ndarray, length: int, idx: int, buffer: dict) -> None:
    """Refuse ``buffers[idx]`` (``buffer``, its JSON; ``data``, its bytes) when its first 4 KiB are all printable
    text, or it starts like a Git LFS pointer (``text_buffer``): text read as floats is ~1e31 garbage."""
    head = bytes(data[: min(4096, length)])
    if (len(head) >= _TEXT_MIN_BYTES or head.startswith(LFS_POINTER)) and not head.translate(None, _TEXT_BYTES):
        uri = buffer.get("uri")
        name = f" ('{urllib.parse.unquote(uri)}')" if "uri" in buffer and not uri.startswith("data:") else ""
        why = (" It is a Git LFS pointer: fetch the real file (git lfs pull) and upload that."
               if head.startswith(LFS_POINTER) else "")
        raise err("text_buffer", f"buffers[{idx}]{name} holds text, not binary vertex data.{why}")


def check_world_positions(p: np.ndarray, p32: np.ndarray, what: str) -> None:
    """World-space corners ``p`` (float64) and ``p32`` (the same as float32, where overflow became inf):
    ``non_finite`` when any is NaN or infinite, ``absurd_magnitude`` past :data:`MAX_COORD` metres."""
    if not np.isfinite(p32).all():
        raise err("non_finite", f"{what} has NaN or infinite world-space positions")
    reach = float(np.abs(p).max(initial=0.0))
    if reach > MAX_COORD:
        raise err("absurd_magnitude", f"{what} has world-space positions {reach:.3g} m from the "
                  f"origin; the limit is {MAX_COORD:g} m (check its node transforms' scale and its "
                  "POSITION data)")


def check_emissive(emissive: list[float], strength: float, what: str) -> None:
    """A material's emissiveFactor (3 floats) and emissiveStrength: ``negative_emissive`` below 0,
    ``absurd_magnitude`` when their product passes :data:`MAX_EMISSIVE`."""
    if strength < 0 or min(emissive) < 0:
        raise err("negative_emissive", f"{what} has a negative emissive "
                  f"{'strength' if strength < 0 else 'factor'}: emitted light cannot be negative")
    if max(emissive) * strength > MAX_EMISSIVE:
        raise err("absurd_magnitude", f"{what} emits {max(emissive) * strength:.3g} (emissiveFactor x "
                  f"emissiveStrength); the limit is {MAX_EMISSIVE:g}")


def check_light_values(intensity: float, color: list[float], what: str) -> None:
    """A KHR_lights_punctual light's intensity and colour: ``negative_light`` below 0, ``absurd_magnitude``
    past :data:`MAX_LIGHT_INTENSITY` / :data:`MAX_LIGHT_COLOR`."""
    if intensity < 0 or min(color) < 0:
        raise err("negative_light", f"{what} has a negative {'intensity' if intensity < 0 else 'color'}: "
                                    "emitted light cannot be negative")
    if intensity > MAX_LIGHT_INTENSITY or max(color) > MAX_LIGHT_COLOR:
        raise err("absurd_magnitude", f"{what} has intensity {intensity:.3g} and color up to "
                  f"{max(color):.3g}; the limits are {MAX_LIGHT_INTENSITY:g} and {MAX_LIGHT_COLOR:g}")


def check_light_place(position: list[float] | None, direction: list[float] | None, ni: int, li: int) -> None:
    """Light ``li`` placed by ``nodes[ni]``: ``non_finite`` position or direction, ``absurd_magnitude`` position
    past :data:`MAX_COORD` metres."""
    if (position is not None and not all(map(math.isfinite, position))) or (
        direction is not None and not all(map(math.isfinite, direction))
    ):
        raise err("non_finite", f"nodes[{ni}] puts light {li} at a NaN or infinite place")
    if position is not None and max(map(abs, position)) > MAX_COORD:
        raise err("absurd_magnitude", f"nodes[{ni}] puts light {li} {max(map(abs, position)):.3g} m from "
                  f"the origin; the limit is {MAX_COORD:g} m")


RAY_OFFSET = 1e-4
"""The bake's ray offset off a surface, x the bounds' diagonal (``workers.kernels.pathtrace.scene_eps``, the light
stage's ``eps``); restated here because ingest does not import the kernels."""
FAR_QUANTUM = 0.5
"""``far_from_origin`` when float32 positions at the scene's farthest coordinate are spaced more than this fraction
of the ray offset apart (a hit point then rounds by about as much as the offset meant to lift it off its surface).
Measured on two-rooms (9.6 m across, ray offset 0.96 mm) moved along x and z: every metric as at the origin up to
3 km; 6 km (warned: 0.49 mm spacing) the direct preview's rmse +1%; 10 km +29% and the GI modes 1.02-1.03 of
their origin values; 20 km DDGI 3.3x its reference."""


def far_from_origin(lo: np.ndarray, hi: np.ndarray) -> str | None:
    """A warning (or None) for a scene so far from the glTF origin, for its size, that float32 world positions
    cannot resolve the bake's ray offsets: every bake stage and the reference then see shadow acne and light
    through walls (two-rooms moved 20 km: DDGI 3.3x its reference, normalized mask GI 3.3x, with acne in the
    direct light; docs/architecture.md "Far from the origin").

    ``lo``, ``hi`` : (3,) the scene's bounds (world space, metres; :func:`check_extent` returns them). The float32
    spacing at the largest coordinate (``np.spacing``) against :data:`RAY_OFFSET` x the bounds' diagonal, scaled
    by :data:`FAR_QUANTUM`.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    diag = max(float(np.linalg.norm(hi - lo)), 1e-3)
    reach = float(max(np.abs(lo).max(), np.abs(hi).max()))
    quantum = float(np.spacing(np.float32(reach)))
    offset = RAY_OFFSET * diag
    if quantum <= FAR_QUANTUM * offset:
        return None
    centre = (lo + hi) / 2
    return (f"the scene lies {reach:,.0f} m from the glTF origin and spans {diag:,.3g} m: float32 positions there "
            f"are {quantum * 1000:.2g} mm apart, too coarse for the bake's {offset * 1000:.2g} mm ray offsets (expect "
            "shadow acne and light through walls in the bake and its reference). Move the scene near the origin "
            f"before exporting (its centre is at [{centre[0]:,.0f}, {centre[1]:,.0f}, {centre[2]:,.0f}] m; e.g. drop "
            "the site or survey offset)")


def check_extent(tris: np.ndarray, label: str) -> tuple[np.ndarray, np.ndarray]:
    """Refuse a scene with nothing to bake in it: all triangles in one point (``zero_extent``), or every
    triangle of zero area, on lines or points (``degenerate_triangles``). Probe spacing follows the extent,
    so such a scene bakes garbage (spacing 0) rather than failing.

    ``tris`` : (T, 3, 3) float32, world space, metres; ``label`` names the upload in messages. Returns the bounds
    ``(lo, hi)``, (3,) float64 each.
    """
    pts = tris.reshape(-1, 3)
    lo, hi = pts.min(axis=0).astype(np.float64), pts.max(axis=0).astype(np.float64)
    diag = float(np.linalg.norm(hi - lo))
    if diag < MIN_EXTENT:
        raise err("zero_extent", f"'{label}': all {plural(tris.shape[0], 'triangle(s)')} lie in one "
                  f"point (the bounds' diagonal is {diag:.3g} m; at least {MIN_EXTENT:g} m is needed)")
    for t0 in range(0, tris.shape[0], BLOCK // 3):
        t = tris[t0 : t0 + BLOCK // 3].astype(np.float64)
        e1, e2, e3 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], t[:, 2] - t[:, 1]
        twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
        longest2 = np.maximum(np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1)), (e3 * e3).sum(1))
        if np.any(twice_area > DEGENERATE_SINE * longest2):
            return lo, hi
    raise err("degenerate_triangles", f"'{label}': every one of its "
              f"{plural(tris.shape[0], 'triangle(s)')} has zero area (its corners lie on a line or in a point)")
