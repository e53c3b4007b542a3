"""KTX 2.0 writer and reader for the uncompressed volume textures of a Kiln bundle.

The subset (see ``proto/bundle.md`` for the byte layout):

* one mip level (``levelCount`` 1), no array layers (``layerCount`` 0), one face;
  2D (``pixelDepth`` 0) or 3D textures;
* the uncompressed formats of :data:`FORMATS` only (two packed ones, ``B10G11R11_UFLOAT_PACK32`` and the
  shared-exponent ``E5B9G9R9_UFLOAT_PACK32``, read and written as float32 RGB arrays: :func:`pack_b10g11r11`,
  :func:`pack_e5b9g9r9`);
* ``supercompressionScheme`` 0 (none) or 2 (Zstandard, one frame per level);
* a Basic Data Format Descriptor as the Khronos Data Format spec (1.3/1.4) and
  libktx's ``vk2dfd`` define it for the format;
* key/value data: ``KTXwriter`` always, ``KTXwriterScParams`` with Zstandard, plus
  caller-given string pairs.

Axis order: a 3D array is ``(depth, height, width, channels)`` = ``(z, y, x, c)`` and a
2D array ``(height, width, channels)``, C order, so x varies fastest in memory exactly
as texels do in a KTX level. ``read_ktx2`` always returns the channel axis.

Everything is little-endian as KTX requires, whatever the host.
"""
from __future__ import annotations

import io
import hashlib
import math
import os
import struct
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pyzstd

from proto.atomic import atomic_write_bytes
from proto.models import FORMAT_VERSION

__all__ = [
    "FORMATS",
    "KTX2Error",
    "KTX2_IDENTIFIER",
    "VkFormatInfo",
    "decode_ktx2",
    "encode_ktx2",
    "format_for",
    "pack_b10g11r11",
    "pack_e5b9g9r9",
    "read_ktx2",
    "unpack_b10g11r11",
    "unpack_e5b9g9r9",
    "write_ktx2",
    "zstd_frame",
]

KTX2_IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"
KTX_WRITER = f"Kiln proto.ktx2 (bundle format {FORMAT_VERSION})"
"""Value written under ``KTXwriter``; fixed so that identical inputs give identical files."""

SUPERCOMPRESSION_NONE = 0
SUPERCOMPRESSION_ZSTD = 2
_SUPERCOMPRESSION_NAMES = {SUPERCOMPRESSION_NONE: "none", SUPERCOMPRESSION_ZSTD: "zstd"}

HEADER_SIZE = 80  # identifier 12 + 9 UInt32 + dfd/kvd offsets 4 UInt32 + sgd 2 UInt64
LEVEL_INDEX_ENTRY_SIZE = 24
DEFAULT_ZSTD_LEVEL = 10
MAX_LEVEL_BYTES = 1 << 32
"""Largest level (uncompressed) this reader accepts: a guard against absurd headers."""

# Khronos Data Format constants (khr_df.h).
KHR_DF_VERSIONNUMBER_1_3 = 2
KHR_DF_MODEL_RGBSDA = 1
KHR_DF_PRIMARIES_UNSPECIFIED = 0
KHR_DF_PRIMARIES_BT709 = 1
KHR_DF_TRANSFER_UNSPECIFIED = 0
KHR_DF_TRANSFER_LINEAR = 1
KHR_DF_TRANSFER_SRGB = 2
KHR_DF_FLAG_ALPHA_STRAIGHT = 0
KHR_DF_CHANNEL_RED, KHR_DF_CHANNEL_GREEN, KHR_DF_CHANNEL_BLUE, KHR_DF_CHANNEL_ALPHA = 0, 1, 2, 15
KHR_DF_SAMPLE_DATATYPE_LINEAR = 0x10
KHR_DF_SAMPLE_DATATYPE_EXPONENT = 0x20
KHR_DF_SAMPLE_DATATYPE_SIGNED = 0x40
KHR_DF_SAMPLE_DATATYPE_FLOAT = 0x80
_CHANNEL_IDS = (KHR_DF_CHANNEL_RED, KHR_DF_CHANNEL_GREEN, KHR_DF_CHANNEL_BLUE, KHR_DF_CHANNEL_ALPHA)
_F32_ONE = 0x3F800000  # 1.0f
_F32_MINUS_ONE = 0xBF800000  # -1.0f


class KTX2Error(ValueError):
    """A KTX2 file that is malformed, truncated or outside the subset this module reads."""


@dataclass(frozen=True)
class VkFormatInfo:
    """One supported ``VkFormat``: its numpy element type and channel count."""

    vk_format: int
    name: str
    dtype: np.dtype  # little-endian element type (of the packed word for a packed format)
    channels: int
    suffix: str  # UNORM, SRGB, SFLOAT, UFLOAT, UINT, SINT
    packed_bits: tuple[int, ...] = ()  # packed formats: bits per channel from bit 0 (R first)

    @property
    def type_size(self) -> int:
        """KTX ``typeSize``: bytes of one component (of the packed word for a ``_PACK32`` format)."""
        return self.dtype.itemsize

    @property
    def texel_size(self) -> int:
        """Bytes of one texel (the texel block size of an uncompressed format)."""
        return self.dtype.itemsize * (1 if self.packed_bits else self.channels)

    @property
    def array_dtype(self) -> np.dtype:
        """The numpy dtype of the decoded array: float32 for the packed float format, else ``dtype``."""
        return np.dtype("<f4") if self.packed_bits else self.dtype

    @property
    def level_alignment(self) -> int:
        """Alignment of an uncompressed level: lcm(texel block size, 4)."""
        return math.lcm(self.texel_size, 4)


def _fmt(vk: int, name: str, dtype: str, channels: int, suffix: str) -> VkFormatInfo:
    return VkFormatInfo(vk, name, np.dtype(dtype), channels, suffix)


FORMATS: dict[int, VkFormatInfo] = {
    f.vk_format: f
    for f in (
        _fmt(9, "R8_UNORM", "u1", 1, "UNORM"),
        _fmt(13, "R8_UINT", "u1", 1, "UINT"),
        _fmt(16, "R8G8_UNORM", "u1", 2, "UNORM"),
        _fmt(37, "R8G8B8A8_UNORM", "u1", 4, "UNORM"),
        _fmt(43, "R8G8B8A8_SRGB", "u1", 4, "SRGB"),
        _fmt(74, "R16_UINT", "<u2", 1, "UINT"),
        _fmt(76, "R16_SFLOAT", "<f2", 1, "SFLOAT"),
        _fmt(83, "R16G16_SFLOAT", "<f2", 2, "SFLOAT"),
        _fmt(97, "R16G16B16A16_SFLOAT", "<f2", 4, "SFLOAT"),
        _fmt(98, "R32_UINT", "<u4", 1, "UINT"),
        _fmt(99, "R32_SINT", "<i4", 1, "SINT"),
        _fmt(100, "R32_SFLOAT", "<f4", 1, "SFLOAT"),
        _fmt(103, "R32G32_SFLOAT", "<f4", 2, "SFLOAT"),
        _fmt(106, "R32G32B32_SFLOAT", "<f4", 3, "SFLOAT"),
        _fmt(109, "R32G32B32A32_SFLOAT", "<f4", 4, "SFLOAT"),
        VkFormatInfo(122, "B10G11R11_UFLOAT_PACK32", np.dtype("<u4"), 3, "UFLOAT", (11, 11, 10)),
        # shared exponent: 9-bit mantissas R, G, B from bit 0, the 5-bit exponent in bits 27-31
        VkFormatInfo(123, "E5B9G9R9_UFLOAT_PACK32", np.dtype("<u4"), 3, "UFLOAT", (9, 9, 9, 5)),
    )
}
"""Supported formats by VkFormat number."""

_BY_NAME = {f.name: f for f in FORMATS.values()}

# Format chosen when ``vk_format`` is None, by (dtype kind+size, channels). uint8 maps
# to UNORM (the texture reading of bytes), not UINT.
_INFER: dict[tuple[str, int], int] = {
    ("u1", 1): 9, ("u1", 2): 16, ("u1", 4): 37,
    ("f2", 1): 76, ("f2", 2): 83, ("f2", 4): 97,
    ("f4", 1): 100, ("f4", 2): 103, ("f4", 3): 106, ("f4", 4): 109,
    ("u4", 1): 98, ("i4", 1): 99, ("u2", 1): 74,
}


def format_for(dtype: np.dtype | str | type, channels: int) -> VkFormatInfo:
    """The format ``write_ktx2`` picks for an array of ``dtype`` with ``channels`` channels."""
    dt = np.dtype(dtype)
    key = (f"{dt.kind}{dt.itemsize}", channels)
    vk = _INFER.get(key)
    if vk is None:
        options = ", ".join(f"{k[0]}x{k[1]}" for k in _INFER)
        raise ValueError(
            f"no KTX2 format for dtype {dt} with {channels} channel(s); supported (dtype x channels): {options}"
            + (" (pad RGB uint8 to RGBA)" if key == ("u1", 3) else "")
        )
    return FORMATS[vk]


def _lookup(vk_format: int | str) -> VkFormatInfo:
    if isinstance(vk_format, str):
        name = vk_format.upper().removeprefix("VK_FORMAT_")
        if name in _BY_NAME:
            return _BY_NAME[name]
    elif vk_format in FORMATS:
        return FORMATS[vk_format]
    raise ValueError(f"unsupported vk_format {vk_format!r}; supported: "
                     + ", ".join(f"{f.vk_format} {f.name}" for f in FORMATS.values()))


# --------------------------------------------------------------------------- packed floats

UFLOAT11_MAX = 65024.0
"""Largest finite value of the 11- and 10-bit unsigned floats (B10G11R11_UFLOAT_PACK32): (2 - 2^-6) · 2^15."""


def _to_ufloat(x: np.ndarray, mantissa: int) -> np.ndarray:
    """float32 -> unsigned small float bits (5-bit exponent, bias 15, ``mantissa`` bits), round to nearest even.

    Negative values and NaN become 0, values above the largest finite one that largest value (no infinities
    are written). As the GL/Vulkan conversion rules for these formats (Vulkan spec "Unsigned 11-Bit/10-Bit
    Floating-Point Numbers").
    """
    x = np.nan_to_num(np.asarray(x, np.float32), nan=0.0, posinf=UFLOAT11_MAX, neginf=0.0)
    largest = np.float32((2.0 - 2.0 ** -mantissa) * 2.0 ** 15)
    x = np.clip(x, 0.0, largest).astype(np.float32)
    shift = 23 - mantissa
    bits = x.view(np.uint32).astype(np.int64)
    # normal range: rebias the exponent (127 -> 15) and round the mantissa, carries run into the exponent
    v = bits - ((127 - 15) << 23)
    normal = (v + ((1 << (shift - 1)) - 1) + ((v >> shift) & 1)) >> shift
    # below the smallest normal 2^-14: multiples of 2^(-14 - mantissa), np.rint rounds half to even
    sub = np.rint(x.astype(np.float64) * 2.0 ** (14 + mantissa)).astype(np.int64)
    return np.where(x < np.float32(2.0 ** -14), sub, normal).astype(np.uint32)


def _from_ufloat(bits: np.ndarray, mantissa: int) -> np.ndarray:
    """Unsigned small float bits -> float32 (exponent 31: inf / NaN)."""
    bits = bits.astype(np.int64)
    e, m = bits >> mantissa, bits & ((1 << mantissa) - 1)
    val = np.where(e == 0, m * 2.0 ** (-14 - mantissa),
                   (1.0 + m / float(1 << mantissa)) * np.exp2(e.astype(np.float64) - 15.0))
    val = np.where(e == 31, np.where(m == 0, np.inf, np.nan), val)
    return val.astype(np.float32)


def pack_b10g11r11(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float RGB -> (...) uint32 B10G11R11_UFLOAT_PACK32 words (R bits 0-10, G 11-21, B 22-31)."""
    rgb = np.asarray(rgb)
    return (_to_ufloat(rgb[..., 0], 6) | (_to_ufloat(rgb[..., 1], 6) << np.uint32(11))
            | (_to_ufloat(rgb[..., 2], 5) << np.uint32(22))).astype(np.uint32)


RGB9E5_MAX = 511.0 / 512.0 * 2.0 ** 16
"""Largest value of E5B9G9R9_UFLOAT_PACK32: (2^9 − 1)/2^9 · 2^(31 − 15) = 65408."""


def pack_e5b9g9r9(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float RGB -> (...) uint32 E5B9G9R9_UFLOAT_PACK32 words (R bits 0-8, G 9-17, B 18-26, the shared
    exponent 27-31; value = mantissa · 2^(e − 15 − 9)).

    The conversion of the Vulkan spec ("Shared Exponent" in "Fixed-Point Data Conversions"; OpenGL's
    EXT_texture_shared_exponent): each channel clamped to [0, 65408] (NaN to 0), the exponent from the largest
    channel (at least −16), mantissas rounded to nearest with ``floor(x + 0.5)``, the exponent raised by one where
    the largest mantissa rounds up to 512. The largest channel keeps 9 significant bits (relative error ≤ 2^-9 ≈
    0.2%); smaller channels share its step.
    """
    # float32 throughout: the scales are powers of 2 and the mantissas below 2^10, so every step is exact
    c = np.nan_to_num(np.asarray(rgb, np.float32), nan=0.0, posinf=RGB9E5_MAX, neginf=0.0)
    c = np.clip(c, np.float32(0.0), np.float32(RGB9E5_MAX))
    top = c.max(axis=-1)
    _, e2 = np.frexp(top)                               # top = f · 2^e2, f in [0.5, 1): floor(log2(top)) = e2 − 1
    e = np.where(top > 0, np.maximum(e2 - 1, -16), -16) + 16        # biased exponent, floor(log2 max) + 1 + 15
    scale = np.ldexp(np.float32(1.0), (24 - e).astype(np.int32))    # 1 / 2^(e − 15 − 9)
    bump = np.floor(top * scale + np.float32(0.5)) >= 512           # the largest mantissa rounds up to 2^9
    e = np.where(bump, e + 1, e)
    scale = np.where(bump, scale * np.float32(0.5), scale)
    m = np.floor(c * scale[..., None] + np.float32(0.5)).astype(np.uint32)
    return (m[..., 0] | (m[..., 1] << np.uint32(9)) | (m[..., 2] << np.uint32(18))
            | (e.astype(np.uint32) << np.uint32(27))).astype(np.uint32)


def unpack_e5b9g9r9(words: np.ndarray) -> np.ndarray:
    """(...) uint32 E5B9G9R9_UFLOAT_PACK32 words -> (..., 3) float32 RGB (exact: 9 bits times a power of 2)."""
    w = np.asarray(words, np.uint32)
    scale = np.ldexp(np.float32(1.0), (w >> np.uint32(27)).astype(np.int32) - 24)   # exact in float32
    out = np.empty(w.shape + (3,), np.float32)
    for i in range(3):
        out[..., i] = ((w >> np.uint32(9 * i)) & np.uint32(0x1FF)).astype(np.float32) * scale
    return out


def _pack(fmt: VkFormatInfo, rgb: np.ndarray) -> np.ndarray:
    return pack_e5b9g9r9(rgb) if fmt.vk_format == 123 else pack_b10g11r11(rgb)


def _unpack(fmt: VkFormatInfo, words: np.ndarray) -> np.ndarray:
    return unpack_e5b9g9r9(words) if fmt.vk_format == 123 else unpack_b10g11r11(words)


def unpack_b10g11r11(words: np.ndarray) -> np.ndarray:
    """(...) uint32 B10G11R11_UFLOAT_PACK32 words -> (..., 3) float32 RGB."""
    w = np.asarray(words, np.uint32)
    return np.stack([_from_ufloat(w & 0x7FF, 6), _from_ufloat((w >> 11) & 0x7FF, 6),
                     _from_ufloat(w >> 22, 5)], axis=-1)


# --------------------------------------------------------------------------- DFD


def _expected_samples(fmt: VkFormatInfo) -> list[tuple[int, int, int, int, int]]:
    """(bitOffset, bitLength-1, channelType|qualifiers, sampleLower, sampleUpper) per sample.

    As libktx's ``createDFDUnpacked`` (little-endian, one sample per channel).
    """
    if fmt.vk_format == 123:  # libktx createDFDPacked's E5B9G9R9 case: per channel its mantissa, then the exponent
        out = []
        for i in range(3):
            out.append((9 * i, 8, _CHANNEL_IDS[i], 0, 8448))
            out.append((27, 4, _CHANNEL_IDS[i] | KHR_DF_SAMPLE_DATATYPE_EXPONENT, 15, 31))
        return out
    if fmt.packed_bits:  # createDFDPacked, little-endian: one sample per channel from bit 0
        out, offset = [], 0
        for i, bits in enumerate(fmt.packed_bits):
            out.append((offset, bits - 1, _CHANNEL_IDS[i] | KHR_DF_SAMPLE_DATATYPE_FLOAT, 0, _F32_ONE))
            offset += bits
        return out
    bits = fmt.type_size * 8
    out = []
    for i in range(fmt.channels):
        ch = _CHANNEL_IDS[i]  # R, G, B, A in component order
        if fmt.suffix in ("UNORM", "SRGB"):
            lower, upper = 0, (1 << bits) - 1
            if fmt.suffix == "SRGB" and ch == KHR_DF_CHANNEL_ALPHA:
                ch |= KHR_DF_SAMPLE_DATATYPE_LINEAR  # alpha is stored linear in sRGB formats
        elif fmt.suffix == "UINT":
            lower, upper = 0, 1
        elif fmt.suffix == "SINT":
            ch |= KHR_DF_SAMPLE_DATATYPE_SIGNED
            lower, upper = 0xFFFFFFFF, 1  # -1 as a 32-bit two's complement word
        elif fmt.suffix == "SFLOAT":
            ch |= KHR_DF_SAMPLE_DATATYPE_FLOAT | KHR_DF_SAMPLE_DATATYPE_SIGNED
            lower, upper = _F32_MINUS_ONE, _F32_ONE
        else:  # pragma: no cover - FORMATS holds only the suffixes above
            raise AssertionError(fmt.suffix)
        out.append((bits * i, bits - 1, ch, lower, upper))
    return out


def _color_info(fmt: VkFormatInfo) -> tuple[int, int]:
    """(colorPrimaries, transferFunction) written for ``fmt``.

    Colour formats get BT.709 primaries with the sRGB or linear transfer function, as
    libktx writes them. For *_UINT/*_SINT, KTX 2.0 revision 4 asks for UNSPECIFIED
    primaries and transfer; libktx (as built in @khronosgroup/gltf-viewer 1.1.0) refuses
    to load a file whose transfer is UNSPECIFIED ("File data is inconsistent with KTX
    spec"), so integer formats get
    UNSPECIFIED primaries and the LINEAR transfer, which every loader accepts.
    """
    if fmt.suffix in ("UINT", "SINT"):
        return KHR_DF_PRIMARIES_UNSPECIFIED, KHR_DF_TRANSFER_LINEAR
    transfer = KHR_DF_TRANSFER_SRGB if fmt.suffix == "SRGB" else KHR_DF_TRANSFER_LINEAR
    return KHR_DF_PRIMARIES_BT709, transfer


def build_dfd(fmt: VkFormatInfo) -> bytes:
    """The DFD (``dfdTotalSize`` + one Basic descriptor block) for ``fmt``.

    ``bytesPlane0`` is the texel size also for supercompressed files (KTX 2.0.4 wants the
    pre-deflation value kept; earlier revisions used 0, which the reader accepts).
    """
    samples = _expected_samples(fmt)
    block_size = 24 + 16 * len(samples)
    primaries, transfer = _color_info(fmt)
    words = [
        block_size + 4,  # dfdTotalSize
        0,  # vendorId (17 bits) = KHRONOS 0, descriptorType (15 bits) = BASICFORMAT 0
        KHR_DF_VERSIONNUMBER_1_3 | (block_size << 16),
        KHR_DF_MODEL_RGBSDA | (primaries << 8) | (transfer << 16) | (KHR_DF_FLAG_ALPHA_STRAIGHT << 24),
        0,  # texelBlockDimension0..3 = 0 (1x1x1x1)
        fmt.texel_size,  # bytesPlane0 = texel size, bytesPlane1..3 = 0
        0,  # bytesPlane4..7 = 0
    ]
    for bit_offset, bit_length, channel_type, lower, upper in samples:
        words += [bit_offset | (bit_length << 16) | (channel_type << 24), 0, lower, upper]
    return struct.pack(f"<{len(words)}I", *words)


def _parse_dfd(buf: bytes, fmt: VkFormatInfo, supercompression: int) -> dict[str, Any]:
    """Check the DFD against ``fmt`` (layout fields strictly, colour fields leniently)."""
    if len(buf) < 28 or len(buf) % 4:
        raise KTX2Error(f"DFD of {len(buf)} bytes is too short or not a multiple of 4")
    total, w0, w1, w2, w3, w4, w5 = struct.unpack_from("<7I", buf, 0)
    if total != len(buf):
        raise KTX2Error(f"dfdTotalSize {total} != dfdByteLength {len(buf)}")
    vendor, dtype_ = w0 & 0x1FFFF, w0 >> 17
    version, block_size = w1 & 0xFFFF, w1 >> 16
    if vendor != 0 or dtype_ != 0:
        raise KTX2Error(f"first DFD block is not a Khronos basic block (vendor {vendor}, type {dtype_})")
    if block_size < 24 or (block_size - 24) % 16 or block_size > total - 4:
        raise KTX2Error(f"basic DFD block size {block_size} is invalid (DFD holds {total - 4} bytes)")
    if version != KHR_DF_VERSIONNUMBER_1_3:
        raise KTX2Error(f"basic DFD versionNumber {version}, expected {KHR_DF_VERSIONNUMBER_1_3}")
    model, primaries, transfer, flags = w2 & 0xFF, (w2 >> 8) & 0xFF, (w2 >> 16) & 0xFF, w2 >> 24
    if model != KHR_DF_MODEL_RGBSDA:
        raise KTX2Error(f"DFD colorModel {model}, expected RGBSDA (1) for {fmt.name}")
    if w3 != 0:
        raise KTX2Error(f"DFD texelBlockDimension {w3:#x}, expected 1x1x1x1 for {fmt.name}")
    bytes_plane0 = w4 & 0xFF
    legacy_unsized = supercompression != SUPERCOMPRESSION_NONE and bytes_plane0 == 0
    if (w4 >> 8) or w5 or (bytes_plane0 != fmt.texel_size and not legacy_unsized):
        raise KTX2Error(f"DFD bytesPlane0..7 = {w4:#010x} {w5:#010x}, expected {fmt.texel_size} for {fmt.name}")
    if fmt.suffix == "SRGB" and transfer != KHR_DF_TRANSFER_SRGB:
        raise KTX2Error(f"DFD transferFunction {transfer} for sRGB format {fmt.name}, expected SRGB (2)")
    if fmt.suffix == "UNORM" and transfer == KHR_DF_TRANSFER_SRGB:
        raise KTX2Error(f"DFD transferFunction is SRGB for non-sRGB format {fmt.name}")
    n = (block_size - 24) // 16
    expected = _expected_samples(fmt)
    if n != len(expected):
        raise KTX2Error(f"DFD has {n} samples, {fmt.name} needs {len(expected)}")
    samples = []
    for i, (e_off, e_len, e_type, _lo, _hi) in enumerate(expected):
        s0, pos, lower, upper = struct.unpack_from("<4I", buf, 28 + 16 * i)
        off, length, ctype = s0 & 0xFFFF, (s0 >> 16) & 0xFF, s0 >> 24
        if (off, length, ctype, pos) != (e_off, e_len, e_type, 0):
            raise KTX2Error(
                f"DFD sample {i} (bitOffset {off}, bitLength {length + 1}, channelType {ctype:#04x}, "
                f"position {pos:#x}) does not match {fmt.name} (expected {e_off}, {e_len + 1}, {e_type:#04x}, 0)"
            )
        samples.append({"bit_offset": off, "bit_length": length + 1, "channel_id": ctype & 0x0F,
                        "qualifiers": ctype & 0xF0, "lower": lower, "upper": upper})
    return {"color_model": model, "color_primaries": primaries, "transfer_function": transfer,
            "flags": flags, "bytes_plane0": bytes_plane0, "samples": samples}


# --------------------------------------------------------------------------- key/value data


def _check_kv(kv: dict[str, str] | None) -> dict[str, str]:
    out: dict[str, str] = {"KTXwriter": KTX_WRITER}
    for key, value in (kv or {}).items():
        if not isinstance(key, str) or not key or "\0" in key:
            raise ValueError(f"KTX2 key {key!r} must be a non-empty string without NUL")
        if not isinstance(value, str) or "\0" in value:
            raise ValueError(f"KTX2 value for {key!r} must be a string without NUL")
        if key.lower().startswith("ktx") and key not in ("KTXwriter", "KTXorientation", "KTXswizzle"):
            raise ValueError(f"KTX2 key {key!r}: keys starting with KTX/ktx are reserved by the spec")
        if len(key.encode()) + len(value.encode()) + 2 > 1 << 16:
            raise ValueError(f"KTX2 key/value {key!r} is too long")
        out[key] = value
    return out


def _encode_kvd(kv: dict[str, str]) -> bytes:
    parts = []
    for key in sorted(kv):  # sorted by Unicode code point, as the spec asks
        entry = key.encode("utf-8") + b"\0" + kv[key].encode("utf-8") + b"\0"
        parts.append(struct.pack("<I", len(entry)) + entry + b"\0" * (-len(entry) % 4))
    return b"".join(parts)


def _parse_kvd(buf: bytes) -> dict[str, str | bytes]:
    kv: dict[str, str | bytes] = {}
    pos = 0
    while pos < len(buf):
        if len(buf) - pos < 6:
            raise KTX2Error(f"key/value data: {len(buf) - pos} stray bytes at the end")
        (length,) = struct.unpack_from("<I", buf, pos)
        start, end = pos + 4, pos + 4 + length
        if length < 2 or end > len(buf):
            raise KTX2Error(f"key/value entry at +{pos} has bad keyAndValueByteLength {length}")
        entry = buf[start:end]
        nul = entry.find(b"\0")
        if nul <= 0:
            raise KTX2Error(f"key/value entry at +{pos} has an empty or unterminated key")
        try:
            key = entry[:nul].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise KTX2Error(f"key/value entry at +{pos}: key is not UTF-8") from exc
        if key in kv:
            raise KTX2Error(f"duplicate key {key!r} in key/value data")
        raw = entry[nul + 1:]
        try:
            kv[key] = raw[:-1].decode("utf-8") if raw.endswith(b"\0") else raw.decode("utf-8")
        except UnicodeDecodeError:
            kv[key] = bytes(raw)  # binary value: returned as is
        pos = end + (-length % 4)
        if pos > len(buf) or any(buf[end:pos]):
            raise KTX2Error(f"key/value entry {key!r}: bad valuePadding")
    return kv


# --------------------------------------------------------------------------- encode / decode


def _image_shape(array: np.ndarray, fmt_channels: int | None, volume: bool | None) -> tuple[int, int, int, int]:
    """(depth or 0, height, width, channels) of ``array`` under the axis convention."""
    nd = array.ndim
    if volume is None:
        volume = nd == 4
    if volume:
        if nd == 3:
            d, h, w = array.shape
            c = 1
        elif nd == 4:
            d, h, w, c = array.shape
        else:
            raise ValueError(f"a 3D texture needs a (D, H, W[, C]) array, got shape {array.shape}")
    else:
        if nd == 2:
            (h, w), c = array.shape, 1
        elif nd == 3:
            h, w, c = array.shape
        else:
            raise ValueError(f"a 2D texture needs an (H, W[, C]) array, got shape {array.shape}"
                             + ("; pass volume=True for (D, H, W, C)" if nd == 4 else ""))
        d = 0
    if min(array.shape) == 0:
        raise ValueError(f"empty array (shape {array.shape})")
    if max(w, h, d) > 0xFFFFFFFF:
        raise ValueError(f"array of shape {array.shape} too large for KTX2")
    if fmt_channels is not None and c != fmt_channels:
        raise ValueError(f"array has {c} channel(s) but the format has {fmt_channels}")
    return d, h, w, c


_ZSTD_MEMO: "OrderedDict[tuple[bytes, int], bytes]" = OrderedDict()
_ZSTD_MEMO_ENTRIES = 8
_ZSTD_MEMO_BYTES = 16 << 20   # and at most this many frame bytes: a long-lived worker holds little
_ZSTD_MEMO_LOCK = threading.Lock()   # artifacts are written from a thread pool (workers.pipeline.execute_stage)


def zstd_frame(raw: bytes, level: int) -> bytes:
    """The Zstandard frame KTX2 supercompression stores for ``raw`` (level ``level``, content checksum on).

    Deterministic, so the last :data:`_ZSTD_MEMO_ENTRIES` frames (at most :data:`_ZSTD_MEMO_BYTES` in all) are kept by the BLAKE2b digest of their input and
    level: a stage that reports its stored sizes (``workers.stages.compress``: the mask atlas at level 19, about
    5 CPU seconds on zdm2) and then writes the same array pays for the compression once."""
    key = (hashlib.blake2b(raw, digest_size=20).digest(), int(level))
    with _ZSTD_MEMO_LOCK:
        hit = _ZSTD_MEMO.get(key)
        if hit is not None:
            _ZSTD_MEMO.move_to_end(key)
            return hit
    # compressed outside the lock: pyzstd releases the GIL, so threads writing different artifacts overlap
    frame = pyzstd.compress(raw, {pyzstd.CParameter.compressionLevel: int(level), pyzstd.CParameter.checksumFlag: 1})
    with _ZSTD_MEMO_LOCK:
        _ZSTD_MEMO[key] = frame
        while len(_ZSTD_MEMO) > _ZSTD_MEMO_ENTRIES or sum(map(len, _ZSTD_MEMO.values())) > _ZSTD_MEMO_BYTES:
            _ZSTD_MEMO.popitem(last=False)
    return frame


def encode_ktx2(array: np.ndarray, vk_format: int | str | None = None, zstd_level: int | None = None,
                kv: dict[str, str] | None = None, *, volume: bool | None = None) -> bytes:
    """The bytes of a KTX2 file holding ``array`` (see :func:`write_ktx2`)."""
    array = np.asarray(array)
    if vk_format is None:
        d, h, w, c = _image_shape(array, None, volume)
        fmt = format_for(array.dtype, c)
    else:
        fmt = _lookup(vk_format)
        want = fmt.array_dtype
        if array.dtype.kind != want.kind or array.dtype.itemsize != want.itemsize:
            raise ValueError(f"{fmt.name} needs {want.name} data, got {array.dtype}; convert it first")
        d, h, w, c = _image_shape(array, fmt.channels, volume)
    if zstd_level is not None and not (1 <= zstd_level <= 22):
        raise ValueError(f"zstd_level must be in 1..22, got {zstd_level}")
    entries = _check_kv(kv)
    if zstd_level is not None:
        entries.setdefault("KTXwriterScParams", f"--zstd {zstd_level}")

    if fmt.packed_bits:
        raw = np.ascontiguousarray(_pack(fmt, array.reshape(-1, 3)), dtype=fmt.dtype).tobytes()
    else:
        raw = np.ascontiguousarray(array, dtype=fmt.dtype).tobytes()
    if zstd_level is None:
        scheme, level_data = SUPERCOMPRESSION_NONE, raw
    else:
        scheme = SUPERCOMPRESSION_ZSTD
        level_data = zstd_frame(raw, zstd_level)

    dfd = build_dfd(fmt)
    kvd = _encode_kvd(entries)
    dfd_offset = HEADER_SIZE + LEVEL_INDEX_ENTRY_SIZE
    kvd_offset = dfd_offset + len(dfd)  # dfd is a multiple of 4 long: kvd is 4-aligned
    end = kvd_offset + len(kvd)
    alignment = fmt.level_alignment if scheme == SUPERCOMPRESSION_NONE else 1
    level_offset = end + (-end % alignment)

    header = struct.pack(
        "<12s9I4I2Q", KTX2_IDENTIFIER,
        fmt.vk_format, fmt.type_size, w, h, d,
        0,  # layerCount: not an array
        1,  # faceCount
        1,  # levelCount
        scheme,
        dfd_offset, len(dfd), kvd_offset if kvd else 0, len(kvd),
        0, 0,  # no supercompression global data
    )
    level_index = struct.pack("<3Q", level_offset, len(level_data), len(raw))
    return b"".join((header, level_index, dfd, kvd, b"\0" * (level_offset - end), level_data))


def decode_ktx2(data: bytes | bytearray | memoryview) -> tuple[np.ndarray, dict[str, Any]]:
    """Parse and validate KTX2 bytes; return ``(array, info)`` (see :func:`read_ktx2`)."""
    buf = bytes(data)
    n = len(buf)
    if n < 12 or buf[:12] != KTX2_IDENTIFIER:
        raise KTX2Error("not a KTX 2.0 file (bad identifier)")
    if n < HEADER_SIZE + LEVEL_INDEX_ENTRY_SIZE:
        raise KTX2Error(f"file of {n} bytes is shorter than a KTX2 header and level index")
    (_, vk, type_size, w, h, d, layers, faces, levels, scheme,
     dfd_off, dfd_len, kvd_off, kvd_len, sgd_off, sgd_len) = struct.unpack_from("<12s9I4I2Q", buf, 0)

    fmt = FORMATS.get(vk)
    if fmt is None:
        raise KTX2Error(f"unsupported vkFormat {vk} (supported: {sorted(FORMATS)})")
    if type_size != fmt.type_size:
        raise KTX2Error(f"typeSize {type_size} != {fmt.type_size} for {fmt.name}")
    if w == 0 or h == 0:
        raise KTX2Error(f"unsupported texture size {w}x{h}x{d} (1D textures are not read)")
    if layers != 0 or faces != 1:
        raise KTX2Error(f"array or cubemap textures are not supported (layerCount {layers}, faceCount {faces})")
    if levels not in (0, 1):
        raise KTX2Error(f"only single-level files are supported (levelCount {levels})")
    if scheme not in _SUPERCOMPRESSION_NAMES:
        raise KTX2Error(f"unsupported supercompressionScheme {scheme}")
    if sgd_off != 0 or sgd_len != 0:
        raise KTX2Error(f"unexpected supercompression global data (offset {sgd_off}, length {sgd_len})")

    dfd_expected = HEADER_SIZE + LEVEL_INDEX_ENTRY_SIZE
    if dfd_off != dfd_expected or dfd_len < 28 or dfd_off + dfd_len > n:
        raise KTX2Error(f"bad DFD index (offset {dfd_off}, length {dfd_len}, file {n} bytes)")
    dfd_info = _parse_dfd(buf[dfd_off:dfd_off + dfd_len], fmt, scheme)
    meta_end = dfd_off + dfd_len
    if kvd_len:
        if kvd_off != meta_end or kvd_off + kvd_len > n:
            raise KTX2Error(f"bad key/value index (offset {kvd_off}, length {kvd_len}, expected offset {meta_end})")
        kv = _parse_kvd(buf[kvd_off:kvd_off + kvd_len])
        meta_end = kvd_off + kvd_len
    elif kvd_off != 0:
        raise KTX2Error(f"kvdByteOffset {kvd_off} with kvdByteLength 0")
    else:
        kv = {}

    level_off, level_len, level_ulen = struct.unpack_from("<3Q", buf, HEADER_SIZE)
    expected_len = w * h * max(d, 1) * fmt.texel_size
    if expected_len > MAX_LEVEL_BYTES:
        raise KTX2Error(f"level of {expected_len} bytes exceeds the {MAX_LEVEL_BYTES}-byte limit")
    alignment = fmt.level_alignment if scheme == SUPERCOMPRESSION_NONE else 1
    first = meta_end + (-meta_end % alignment)
    if level_off != first:
        raise KTX2Error(f"level byteOffset {level_off}, expected {first} (alignment {alignment})")
    if level_ulen != expected_len:
        raise KTX2Error(f"level uncompressedByteLength {level_ulen} != {expected_len} for "
                        f"{w}x{h}x{max(d, 1)} {fmt.name}")
    if scheme == SUPERCOMPRESSION_NONE and level_len != level_ulen:
        raise KTX2Error(f"level byteLength {level_len} != uncompressedByteLength {level_ulen}")
    if level_off + level_len != n:
        what = "truncated" if level_off + level_len > n else "has trailing bytes"
        raise KTX2Error(f"file {what}: level ends at byte {level_off + level_len}, file is {n} bytes")
    if any(buf[meta_end:level_off]):
        raise KTX2Error("non-zero mipPadding before the level data")

    payload = buf[level_off:level_off + level_len]
    if scheme == SUPERCOMPRESSION_ZSTD:
        dec = pyzstd.ZstdDecompressor()
        try:
            raw = dec.decompress(payload, max_length=expected_len)
        except pyzstd.ZstdError as exc:
            raise KTX2Error(f"corrupt Zstandard level data: {exc}") from exc
        if len(raw) != expected_len or not dec.eof or dec.unused_data:
            raise KTX2Error(f"Zstandard level data does not inflate to exactly {expected_len} bytes")
    else:
        raw = payload

    shape = (d, h, w, fmt.channels) if d else (h, w, fmt.channels)
    if fmt.packed_bits:
        array = _unpack(fmt, np.frombuffer(raw, dtype=fmt.dtype)).reshape(shape)
    else:
        array = np.frombuffer(raw, dtype=fmt.dtype).reshape(shape).astype(fmt.dtype.newbyteorder("="))
    info = {
        "vk_format": vk,
        "format_name": fmt.name,
        "dtype": array.dtype.name,
        "channels": fmt.channels,
        "type_size": type_size,
        "pixel_size": fmt.texel_size,
        "pixel_width": w,
        "pixel_height": h,
        "pixel_depth": d,
        "dimensions": 3 if d else 2,
        "supercompression": scheme,
        "supercompression_name": _SUPERCOMPRESSION_NAMES[scheme],
        "byte_length": level_len,
        "uncompressed_byte_length": level_ulen,
        "file_bytes": n,
        "dfd": dfd_info,
        "kv": kv,
    }
    return array, info


# --------------------------------------------------------------------------- files


def write_ktx2(path_or_fileobj: str | os.PathLike[str] | BinaryIO, array: np.ndarray,
               vk_format: int | str | None = None, zstd_level: int | None = None,
               kv: dict[str, str] | None = None, *, volume: bool | None = None) -> int:
    """Write ``array`` as a single-level KTX2 texture; return the bytes written.

    ``array`` is ``(H, W[, C])`` for a 2D texture or ``(D, H, W, C)`` for a 3D one (x
    fastest). A 3-axis array is read as ``(H, W, C)`` unless ``volume=True``, which makes
    it a one-channel ``(D, H, W)`` volume. ``vk_format`` (number, or name such as
    ``"R16G16B16A16_SFLOAT"``) defaults to the format matching the dtype and channel
    count (uint8 -> UNORM); the array's dtype must match the format's. ``zstd_level``
    (1..22) turns on Zstandard supercompression. ``kv`` adds string key/value pairs.
    A path is written atomically.
    """
    data = encode_ktx2(array, vk_format, zstd_level, kv, volume=volume)
    if isinstance(path_or_fileobj, (str, os.PathLike)):
        return atomic_write_bytes(path_or_fileobj, data)
    path_or_fileobj.write(data)
    return len(data)


def read_ktx2(path_or_bytes: str | os.PathLike[str] | bytes | bytearray | memoryview | BinaryIO
              ) -> tuple[np.ndarray, dict[str, Any]]:
    """Read a KTX2 file of the supported subset; return ``(array, info)``.

    ``array`` is ``(D, H, W, C)`` for 3D textures and ``(H, W, C)`` for 2D (channel axis
    always present), native byte order, writable. ``info`` holds ``vk_format``,
    ``format_name``, ``pixel_size`` (bytes per texel), ``pixel_width/height/depth``,
    ``supercompression`` (0 or 2) and its name, level byte lengths, the parsed ``dfd``
    and ``kv`` (str values; bytes where a value is not UTF-8). Raises :class:`KTX2Error`
    on anything malformed.
    """
    if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
        data = bytes(path_or_bytes)
    elif isinstance(path_or_bytes, (str, os.PathLike)):
        data = Path(path_or_bytes).read_bytes()
    elif isinstance(path_or_bytes, io.IOBase) or hasattr(path_or_bytes, "read"):
        data = path_or_bytes.read()
    else:
        raise TypeError(f"read_ktx2 takes a path, bytes or a binary file, not {type(path_or_bytes).__name__}")
    return decode_ktx2(data)
