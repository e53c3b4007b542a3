"""KTX 2.0 writer/reader (proto/ktx2.py): round trips, exact byte layout, validation."""
from __future__ import annotations

import io
import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from proto.ktx2 import (
    FORMATS,
    KTX2_IDENTIFIER,
    KTX_WRITER,
    KTX2Error,
    build_dfd,
    decode_ktx2,
    encode_ktx2,
    format_for,
    RGB9E5_MAX,
    pack_b10g11r11,
    pack_e5b9g9r9,
    read_ktx2,
    unpack_b10g11r11,
    unpack_e5b9g9r9,
    write_ktx2,
)

RNG_SEED = 1234


def _random(fmt, shape, rng):
    """Random data covering the format's bit patterns (finite floats only; the packed format's representable)."""
    if fmt.name == "E5B9G9R9_UFLOAT_PACK32":                          # every word is a finite value
        return unpack_e5b9g9r9(rng.integers(0, 1 << 32, size=shape[:-1], dtype=np.uint32))
    if fmt.packed_bits:
        words = rng.integers(0, 1 << 32, size=shape[:-1], dtype=np.uint32)
        ok = ((words & 0x7C0) != 0x7C0) & ((words & 0x3E0000) != 0x3E0000) & ((words >> 27) != 31)  # exponent 31
        return unpack_b10g11r11(np.where(ok, words, 0).astype(np.uint32))
    if fmt.dtype.kind == "f":
        a = (rng.standard_normal(shape) * 100).astype(fmt.dtype)
        assert np.isfinite(a).all()
        return a
    info = np.iinfo(fmt.dtype)
    return rng.integers(info.min, info.max, size=shape, endpoint=True, dtype=fmt.dtype)


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-identical comparison (also for floats)."""
    if a.shape != b.shape or a.dtype.newbyteorder("=") != b.dtype.newbyteorder("="):
        return False
    return a.astype(a.dtype.newbyteorder("<")).tobytes() == b.astype(b.dtype.newbyteorder("<")).tobytes()


def _header(buf: bytes) -> dict:
    f = struct.unpack_from("<9I4I2Q3Q", buf, 12)
    keys = ("vkFormat typeSize pixelWidth pixelHeight pixelDepth layerCount faceCount levelCount "
            "supercompressionScheme dfdByteOffset dfdByteLength kvdByteOffset kvdByteLength "
            "sgdByteOffset sgdByteLength byteOffset byteLength uncompressedByteLength").split()
    return dict(zip(keys, f))


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("zstd", [None, 5], ids=["raw", "zstd"])
@pytest.mark.parametrize("dims", [(5, 7), (3, 5, 7)], ids=["2d", "3d"])
@pytest.mark.parametrize("vk", sorted(FORMATS), ids=[FORMATS[v].name for v in sorted(FORMATS)])
def test_round_trip_every_format(vk, dims, zstd):
    fmt = FORMATS[vk]
    rng = np.random.default_rng([RNG_SEED, vk, len(dims)])
    a = _random(fmt, dims + (fmt.channels,), rng)
    data = encode_ktx2(a, vk, zstd_level=zstd)
    b, info = decode_ktx2(data)
    assert _same_bits(a, b)
    assert b.flags.writeable and b.dtype.byteorder in ("=", "|")
    h = _header(data)
    assert h["vkFormat"] == vk and info["vk_format"] == vk and info["format_name"] == fmt.name
    assert h["typeSize"] == fmt.dtype.itemsize == info["type_size"]   # 4 for the packed format's word
    assert (h["pixelWidth"], h["pixelHeight"], h["pixelDepth"]) == (7, 5, 3 if len(dims) == 3 else 0)
    assert (h["layerCount"], h["faceCount"], h["levelCount"]) == (0, 1, 1)
    assert h["supercompressionScheme"] == (2 if zstd else 0) == info["supercompression"]
    assert info["supercompression_name"] == ("zstd" if zstd else "none")
    n = a.size // fmt.channels * fmt.texel_size
    assert h["uncompressedByteLength"] == n == info["uncompressed_byte_length"]
    assert info["pixel_size"] == fmt.texel_size == (4 if fmt.packed_bits else fmt.channels * fmt.dtype.itemsize)
    assert h["byteOffset"] + h["byteLength"] == len(data)
    if zstd:
        assert info["kv"]["KTXwriterScParams"] == "--zstd 5"
    else:
        assert h["byteLength"] == n
        # uncompressed levels start on lcm(texel size, 4)
        assert h["byteOffset"] % np.lcm(info["pixel_size"], 4) == 0
        pack = pack_e5b9g9r9 if fmt.name == "E5B9G9R9_UFLOAT_PACK32" else pack_b10g11r11
        stored = pack(a) if fmt.packed_bits else a.astype(fmt.dtype)
        assert data[h["byteOffset"]:] == stored.astype(fmt.dtype).tobytes()


def test_float16_and_uint8_exact_values():
    rng = np.random.default_rng(RNG_SEED)
    h = rng.uniform(-65504, 65504, size=(4, 6, 9, 4)).astype(np.float16)
    assert not np.isnan(h).any()
    for z in (None, 19):
        back, info = decode_ktx2(encode_ktx2(h, zstd_level=z))
        assert info["vk_format"] == 97
        assert np.array_equal(back.view(np.uint16), h.view(np.uint16))
    u = rng.integers(0, 256, size=(3, 5, 7, 4), dtype=np.uint8)
    back, info = decode_ktx2(encode_ktx2(u))
    assert info["vk_format"] == 37 and np.array_equal(back, u)


@pytest.mark.parametrize("channel, mantissa", [(0, 6), (1, 6), (2, 5)], ids=["r11", "g11", "b10"])
def test_b10g11r11_rounds_to_nearest_even_and_clamps(channel, mantissa):
    """Every float goes to the nearest of the 11/10-bit values (ties to the even code), as a brute-force search
    over all finite codes finds; negatives and NaN give 0, values past the largest the largest."""
    shift = (0, 11, 22)[channel]
    codes = np.arange(31 << mantissa, dtype=np.uint32)                   # every finite code, increasing
    values = unpack_b10g11r11(codes << np.uint32(shift))[:, channel].astype(np.float64)
    assert np.all(np.diff(values) > 0) and values[-1] == (2 - 2.0 ** -mantissa) * 2 ** 15
    rng = np.random.default_rng(RNG_SEED)
    x = np.concatenate([np.exp(rng.uniform(np.log(1e-9), np.log(7e4), 50000)), values,
                        (values[:-1] + values[1:]) / 2, [0.0, -1.0, np.nan, 1e9]]).astype(np.float32)
    rgb = np.zeros((len(x), 3), np.float32)
    rgb[:, channel] = x
    got = (pack_b10g11r11(rgb) >> np.uint32(shift)) & np.uint32((1 << (mantissa + 5)) - 1)
    v = np.clip(np.nan_to_num(x.astype(np.float64), nan=0.0), 0.0, values[-1])
    i = np.clip(np.searchsorted(values, v), 1, len(values) - 1)
    below, above = v - values[i - 1], values[i] - v
    want = np.where(below < above, i - 1, np.where(below > above, i, np.where((i - 1) % 2 == 0, i - 1, i)))
    assert np.array_equal(got, want)
    assert np.all((pack_b10g11r11(rgb) & ~np.uint32(((1 << (mantissa + 5)) - 1) << shift)) == 0)  # others 0


def test_b10g11r11_dfd_as_libktx():
    """createDFDPacked(0, 3, {11, 11, 10}, {R, G, B}, s_UFLOAT): one 4-byte plane, samples R at bit 0, G at 11,
    B at 22, FLOAT qualifier without SIGNED, lower 0.0f, upper 1.0f."""
    w = _dfd_words(122)
    assert w[:7] == (4 + 24 + 48, 0, 2 | (72 << 16), 1 | (1 << 8) | (1 << 16), 0, 4, 0)
    assert [w[7 + 4 * s] for s in range(3)] == [0 | (10 << 16) | (0x80 << 24), 11 | (10 << 16) | (0x81 << 24),
                                                22 | (9 << 16) | (0x82 << 24)]
    assert all(w[8 + 4 * s] == 0 and w[9 + 4 * s] == 0 and w[10 + 4 * s] == 0x3F800000 for s in range(3))


def test_e5b9g9r9_rounds_to_nearest_on_the_shared_exponent():
    """The Vulkan/GL shared-exponent conversion: the exponent from the largest channel, every channel the nearest
    multiple of that exponent's step (ties up, floor(x + 0.5)); the largest channel keeps 9 significant bits, so
    it is off by at most half a step, 2^-10 of 2^e, i.e. ≤ 2^-9 of itself; negatives and NaN give 0, values past
    65408 clamp to it."""
    rng = np.random.default_rng(RNG_SEED)
    rgb = np.exp(rng.uniform(np.log(1e-8), np.log(7e4), (50000, 3))).astype(np.float32)
    rgb[:100] = rgb[:100, :1]                                           # greys
    words = pack_e5b9g9r9(rgb)
    back = unpack_e5b9g9r9(words).astype(np.float64)
    x = np.minimum(rgb.astype(np.float64), RGB9E5_MAX)
    top = x.max(axis=1)
    e = (words >> np.uint32(27)).astype(np.int64)
    step = np.exp2(e - 24.0)
    assert np.all(np.abs(back - x) <= step[:, None] / 2 * (1 + 1e-12))  # nearest multiple of the shared step
    big = top >= 2.0 ** -15                                             # normal range: 9 significant bits
    assert np.all(np.abs(back - x).max(axis=1)[big] <= top[big] * 2.0 ** -9)
    assert np.all(((words & 0x1FF) | ((words >> np.uint32(9)) & 0x1FF) | ((words >> np.uint32(18)) & 0x1FF))
                  [top >= 2.0 ** -24] > 0)                              # nothing from the smallest step up reads 0
    assert np.all(np.maximum.reduce([words & 0x1FF, (words >> np.uint32(9)) & 0x1FF, (words >> np.uint32(18)) & 0x1FF])
                  [big] >= 256)                                         # the largest mantissa is normalized
    edge = unpack_e5b9g9r9(pack_e5b9g9r9(np.array([[-1.0, np.nan, 1e9], [RGB9E5_MAX, 0, 0], [0.99999, 0.5, 0],
                                                   [2.0 ** -24, 0, 0]], np.float32)))
    assert edge.tolist() == [[0.0, 0.0, RGB9E5_MAX], [RGB9E5_MAX, 0.0, 0.0], [1.0, 0.5, 0.0], [2.0 ** -24, 0.0, 0.0]]


def test_e5b9g9r9_dfd_as_libktx():
    """createDFDPacked(0, 6, ...)'s E5B9G9R9 case: one 4-byte plane, per channel its 9-bit mantissa (bit 9·c, no
    qualifier, lower 0, upper 8448) then the shared exponent (bit 27, 5 bits, EXPONENT qualifier, lower 15, upper
    31)."""
    w = _dfd_words(123)
    assert w[:7] == (4 + 24 + 96, 0, 2 | (120 << 16), 1 | (1 << 8) | (1 << 16), 0, 4, 0)
    samples = [w[7 + 4 * s:11 + 4 * s] for s in range(6)]
    for c in range(3):
        assert samples[2 * c] == (9 * c | (8 << 16) | (c << 24), 0, 0, 8448)
        assert samples[2 * c + 1] == (27 | (4 << 16) | ((0x20 | c) << 24), 0, 15, 31)


def test_axis_order_x_fastest():
    d, h, w = 3, 5, 7
    k, j, i = np.meshgrid(np.arange(d), np.arange(h), np.arange(w), indexing="ij")
    a = (i + 10 * j + 100 * k).astype(np.float32)[..., None]  # texel (i, j, k) = i + 10 j + 100 k
    data = encode_ktx2(a)
    off = _header(data)["byteOffset"]
    level = np.frombuffer(data[off:], dtype="<f4")
    for (ii, jj, kk) in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (6, 4, 2), (3, 2, 1)]:
        assert level[(kk * h + jj) * w + ii] == ii + 10 * jj + 100 * kk


def test_exact_bytes_rgba8_2d():
    a = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)  # H=2, W=3
    data = encode_ktx2(a)
    assert data[:12] == KTX2_IDENTIFIER == b"\xabKTX 20\xbb\r\n\x1a\n"
    h = _header(data)
    dfd_len = 4 + 24 + 4 * 16
    kvd = b"KTXwriter\0" + KTX_WRITER.encode() + b"\0"
    kvd_len = 4 + len(kvd) + (-len(kvd) % 4)
    assert h == {
        "vkFormat": 37, "typeSize": 1, "pixelWidth": 3, "pixelHeight": 2, "pixelDepth": 0,
        "layerCount": 0, "faceCount": 1, "levelCount": 1, "supercompressionScheme": 0,
        "dfdByteOffset": 104, "dfdByteLength": dfd_len,
        "kvdByteOffset": 104 + dfd_len, "kvdByteLength": kvd_len,
        "sgdByteOffset": 0, "sgdByteLength": 0,
        "byteOffset": 104 + dfd_len + kvd_len, "byteLength": 24, "uncompressedByteLength": 24,
    }
    words = struct.unpack_from("<23I", data, 104)
    assert words == (
        92, 0, 2 | (88 << 16), 1 | (1 << 8) | (1 << 16), 0, 4, 0,
        0x07_0000 | (0 << 24), 0, 0, 255,
        8 | 0x07_0000 | (1 << 24), 0, 0, 255,
        16 | 0x07_0000 | (2 << 24), 0, 0, 255,
        24 | 0x07_0000 | (15 << 24), 0, 0, 255,
    )
    kv_off = h["kvdByteOffset"]
    assert struct.unpack_from("<I", data, kv_off)[0] == len(kvd)
    assert data[kv_off + 4:kv_off + 4 + len(kvd)] == kvd
    assert data[h["byteOffset"]:] == a.tobytes()
    assert len(data) == h["byteOffset"] + 24


def _dfd_words(vk):
    b = build_dfd(FORMATS[vk])
    return struct.unpack(f"<{len(b) // 4}I", b)


def test_dfd_per_format_exact():
    # RGBA16F: float+signed qualifiers (0xC0), 16-bit samples, lower -1.0f, upper 1.0f
    w = _dfd_words(97)
    assert w[:7] == (92, 0, 2 | (88 << 16), 1 | (1 << 8) | (1 << 16), 0, 8, 0)
    assert [w[7 + 4 * s] for s in range(4)] == [
        (16 * s) | (15 << 16) | ((0xC0 | ch) << 24) for s, ch in enumerate((0, 1, 2, 15))]
    assert all(w[9 + 4 * s] == 0xBF800000 and w[10 + 4 * s] == 0x3F800000 for s in range(4))
    # RGBA8 sRGB: transfer SRGB (2), alpha sample flagged LINEAR (0x10)
    w = _dfd_words(43)
    assert (w[3] >> 16) & 0xFF == 2
    assert [w[7 + 4 * s] >> 24 for s in range(4)] == [0, 1, 2, 15 | 0x10]
    # RGB32F: 3 samples, 12-byte texels
    w = _dfd_words(106)
    assert w[0] == 4 + 24 + 48 and w[5] == 12
    assert [w[7 + 4 * s] & 0xFFFF for s in range(3)] == [0, 32, 64]
    # R32_SINT: signed qualifier, lower -1 (0xFFFFFFFF), upper 1; no colour primaries
    w = _dfd_words(99)
    assert w == (44, 0, 2 | (40 << 16), 1 | (0 << 8) | (1 << 16), 0, 4, 0, (31 << 16) | (0x40 << 24), 0,
                 0xFFFFFFFF, 1)
    # R8_UINT / R16_UINT / R32_UINT: lower 0, upper 1
    assert _dfd_words(13)[7:] == (7 << 16, 0, 0, 1)
    assert _dfd_words(74)[7:] == (15 << 16, 0, 0, 1)
    assert _dfd_words(98)[7:] == (31 << 16, 0, 0, 1)
    # R8_UNORM: upper 255; R8G8_UNORM: 2 samples at 0 and 8
    assert _dfd_words(9)[7:] == (7 << 16, 0, 0, 255)
    assert [_dfd_words(16)[7 + 4 * s] for s in range(2)] == [7 << 16, 8 | (7 << 16) | (1 << 24)]


@pytest.mark.parametrize("vk", [9, 13, 16, 74, 76, 83, 106], ids=lambda v: FORMATS[v].name)
def test_odd_sizes_are_tightly_packed_and_level_aligned(vk):
    fmt = FORMATS[vk]
    rng = np.random.default_rng(vk)
    a = _random(fmt, (3, 5, 7, fmt.channels), rng)  # rows of 7 texels: no row padding in KTX2
    data = encode_ktx2(a, vk)
    h = _header(data)
    assert h["byteLength"] == 3 * 5 * 7 * fmt.texel_size
    assert h["byteOffset"] % fmt.level_alignment == 0
    assert fmt.level_alignment == {1: 4, 2: 4, 4: 4, 12: 12}[fmt.texel_size]
    assert h["byteOffset"] - (h["kvdByteOffset"] + h["kvdByteLength"]) < fmt.level_alignment
    assert _same_bits(decode_ktx2(data)[0], a)


def test_rgb32f_level_offset_multiple_of_12():
    a = np.zeros((2, 2, 3), np.float32)
    data = encode_ktx2(a)
    h = _header(data)
    end = h["kvdByteOffset"] + h["kvdByteLength"]
    assert h["byteOffset"] == end + (-end % 12) and h["byteOffset"] % 12 == 0
    assert data[end:h["byteOffset"]] == b"\0" * (h["byteOffset"] - end)
    # zstd levels are not padded (required alignment 1)
    hz = _header(encode_ktx2(a, zstd_level=3))
    assert hz["byteOffset"] == hz["kvdByteOffset"] + hz["kvdByteLength"]


def test_channel_axis_optional_and_volume_flag():
    img = np.arange(35, dtype=np.float32).reshape(5, 7)
    b, info = decode_ktx2(encode_ktx2(img))
    assert b.shape == (5, 7, 1) and info["dimensions"] == 2 and np.array_equal(b[..., 0], img)
    vol = np.arange(105, dtype=np.uint16).reshape(3, 5, 7)
    b, info = decode_ktx2(encode_ktx2(vol, volume=True))
    assert b.shape == (3, 5, 7, 1) and info["pixel_depth"] == 3 and info["vk_format"] == 74
    assert np.array_equal(b[..., 0], vol)
    # without volume=True a 3-axis array is (H, W, C)
    b, info = decode_ktx2(encode_ktx2(np.zeros((5, 7, 2), np.float16)))
    assert b.shape == (5, 7, 2) and info["pixel_depth"] == 0 and info["vk_format"] == 83


def test_non_native_and_non_contiguous_input():
    a = np.arange(60, dtype=np.float32).reshape(3, 5, 4)
    big = a.astype(">f4")
    assert encode_ktx2(big) == encode_ktx2(a)
    t = np.ascontiguousarray(a.transpose(1, 0, 2)).transpose(1, 0, 2)  # a Fortran-ish view
    assert not t.flags.c_contiguous and encode_ktx2(t) == encode_ktx2(a)


def test_format_inference_and_errors():
    assert format_for(np.uint8, 1).name == "R8_UNORM"
    assert format_for(np.uint8, 4).name == "R8G8B8A8_UNORM"
    assert format_for(np.float16, 4).vk_format == 97
    assert format_for(np.float32, 3).vk_format == 106
    assert format_for(np.int32, 1).name == "R32_SINT"
    with pytest.raises(ValueError, match="pad RGB uint8 to RGBA"):
        encode_ktx2(np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(ValueError, match="float64"):
        encode_ktx2(np.zeros((2, 2), np.float64))
    with pytest.raises(ValueError, match="needs float16"):
        encode_ktx2(np.zeros((2, 2, 4), np.float32), vk_format=97)
    with pytest.raises(ValueError, match="3 channel.*format has 4"):
        encode_ktx2(np.zeros((2, 2, 3), np.float32), vk_format=109)
    with pytest.raises(ValueError, match="unsupported vk_format"):
        encode_ktx2(np.zeros((2, 2), np.float32), vk_format=101)
    with pytest.raises(ValueError, match="volume=True"):
        encode_ktx2(np.zeros((2, 2, 2, 1), np.float32), volume=False)
    with pytest.raises(ValueError, match="empty"):
        encode_ktx2(np.zeros((0, 2, 1), np.float32))
    with pytest.raises(ValueError, match="zstd_level"):
        encode_ktx2(np.zeros((2, 2), np.float32), zstd_level=0)
    # explicit formats by number or name
    assert _header(encode_ktx2(np.zeros((2, 2), np.uint8), vk_format=13))["vkFormat"] == 13
    assert _header(encode_ktx2(np.zeros((2, 2, 4), np.uint8), vk_format="VK_FORMAT_R8G8B8A8_SRGB"))["vkFormat"] == 43


def test_key_values():
    a = np.zeros((2, 2), np.float32)
    data = encode_ktx2(a, kv={"kiln.name": "sh_l1", "a": "é ü", "KTXorientation": "rd"})
    _, info = decode_ktx2(data)
    assert info["kv"] == {"KTXwriter": KTX_WRITER, "kiln.name": "sh_l1", "a": "é ü", "KTXorientation": "rd"}
    assert list(info["kv"]) == sorted(info["kv"])  # stored sorted by code point
    with pytest.raises(ValueError, match="reserved"):
        encode_ktx2(a, kv={"KTXfoo": "x"})
    with pytest.raises(ValueError, match="NUL"):
        encode_ktx2(a, kv={"k": "a\0b"})
    with pytest.raises(ValueError, match="non-empty"):
        encode_ktx2(a, kv={"": "x"})


def test_deterministic_and_file_io(tmp_path):
    a = np.random.default_rng(0).standard_normal((3, 4, 5, 2)).astype(np.float16)
    assert encode_ktx2(a, zstd_level=7) == encode_ktx2(a, zstd_level=7)
    p = tmp_path / "v.ktx2"
    n = write_ktx2(p, a, zstd_level=7)
    assert n == p.stat().st_size and p.read_bytes() == encode_ktx2(a, zstd_level=7)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["v.ktx2"]  # no temp file left
    n2 = write_ktx2(p, a)  # overwrite atomically
    assert n2 == p.stat().st_size
    buf = io.BytesIO()
    assert write_ktx2(buf, a) == len(buf.getvalue()) == n2
    for src in (p, str(p), p.read_bytes(), bytearray(p.read_bytes()), io.BytesIO(p.read_bytes())):
        b, _ = read_ktx2(src)
        assert _same_bits(a, b)


def test_failed_write_leaves_no_temp_file(tmp_path):
    with pytest.raises(ValueError):
        write_ktx2(tmp_path / "x.ktx2", np.zeros((2, 2, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad files


def _patch(data: bytes, offset: int, fmt: str, *values) -> bytes:
    b = bytearray(data)
    struct.pack_into(fmt, b, offset, *values)
    return bytes(b)


@pytest.fixture(scope="module")
def good():
    a = np.arange(3 * 5 * 7 * 3, dtype=np.float32).reshape(3, 5, 7, 3)
    return encode_ktx2(a), encode_ktx2(a, zstd_level=3)


def test_corrupt_files_raise(good):
    raw, z = good
    h = _header(raw)
    dfd, kvd, lvl = h["dfdByteOffset"], h["kvdByteOffset"], h["byteOffset"]
    cases = {
        "identifier": (b"\xabKTX 11\xbb\r\n\x1a\n" + raw[12:], "identifier"),
        "empty": (b"", "identifier"),
        "header only": (raw[:60], "shorter"),
        "vkformat": (_patch(raw, 12, "<I", 101), "unsupported vkFormat 101"),
        "typesize": (_patch(raw, 16, "<I", 2), "typeSize"),
        "width0": (_patch(raw, 20, "<I", 0), "size"),
        "layers": (_patch(raw, 32, "<I", 2), "array"),
        "faces": (_patch(raw, 36, "<I", 6), "cubemap"),
        "levels": (_patch(raw, 40, "<I", 2), "levelCount"),
        "scheme": (_patch(raw, 44, "<I", 1), "supercompressionScheme"),
        "sgd": (_patch(raw, 64, "<Q", 8), "global data"),
        "dfd offset": (_patch(raw, 48, "<I", 108), "DFD"),
        "dfd total": (_patch(raw, dfd, "<I", 60), "dfdTotalSize"),
        "dfd version": (_patch(raw, dfd + 8, "<H", 1), "versionNumber"),
        "dfd model": (_patch(raw, dfd + 12, "<B", 2), "colorModel"),
        "dfd bytesplane": (_patch(raw, dfd + 20, "<B", 4), "bytesPlane"),
        "dfd sample": (_patch(raw, dfd + 28 + 16 + 3, "<B", 0x40), "sample 1"),
        "kvd offset": (_patch(raw, 56, "<I", kvd + 4), "key/value"),
        "kvd entry": (_patch(raw, kvd, "<I", 1000), "keyAndValueByteLength"),
        "level offset": (_patch(raw, 80, "<Q", lvl + 4), "byteOffset"),
        "level length": (_patch(raw, 88, "<Q", h["byteLength"] - 4), "byteLength"),
        "level ulength": (_patch(raw, 96, "<Q", h["byteLength"] + 12), "uncompressedByteLength"),
        "truncated": (raw[:-1], "truncated"),
        "trailing": (raw + b"\0", "trailing"),
    }
    for name, (data, msg) in cases.items():
        with pytest.raises(KTX2Error, match=msg):
            decode_ktx2(data)
    assert issubclass(KTX2Error, ValueError)
    # sRGB transfer on a UNORM format with an sRGB variant is refused ...
    u8 = encode_ktx2(np.zeros((2, 2, 4), np.uint8))
    with pytest.raises(KTX2Error, match="SRGB"):
        decode_ktx2(_patch(u8, dfd + 14, "<B", 2))
    # ... and an sRGB format must say SRGB
    srgb = encode_ktx2(np.zeros((2, 2, 4), np.uint8), vk_format=43)
    with pytest.raises(KTX2Error, match="sRGB format"):
        decode_ktx2(_patch(srgb, dfd + 14, "<B", 1))


def test_nonzero_mip_padding_raises():
    # 12-byte texels: the level is aligned to 12, so padding follows the key/value data
    data = encode_ktx2(np.zeros((2, 2, 3), np.float32), kv={"k": "v"})
    h = _header(data)
    end = h["kvdByteOffset"] + h["kvdByteLength"]
    assert h["byteOffset"] > end
    with pytest.raises(KTX2Error, match="mipPadding"):
        decode_ktx2(_patch(data, end, "<B", 1))


def test_corrupt_zstd_raises(good):
    _, z = good
    h = _header(z)
    end = h["byteOffset"] + h["byteLength"]
    flipped = bytearray(z)
    flipped[end - 3] ^= 0xFF  # inside the checksum / last block
    with pytest.raises(KTX2Error, match="Zstandard"):
        decode_ktx2(bytes(flipped))
    with pytest.raises(KTX2Error, match="truncated"):
        decode_ktx2(z[:-2])
    # a frame that inflates to fewer bytes than the header promises
    import pyzstd

    short = pyzstd.compress(b"\0" * 16)
    bad = z[:h["byteOffset"]] + short
    bad = _patch(bad, 88, "<Q", len(short))
    with pytest.raises(KTX2Error, match="inflate"):
        decode_ktx2(bad)


def test_truncation_at_every_length_raises(good):
    raw, z = good
    for data in (raw, z):
        for cut in range(0, len(data), 7):
            with pytest.raises(KTX2Error):
                decode_ktx2(data[:cut])


def test_byte_flips_never_crash(good):
    """Flipping any byte of the metadata gives a KTX2Error or a readable file, nothing else."""
    raw, z = good
    for data in (raw, z):
        meta_end = _header(data)["byteOffset"]
        for pos in range(meta_end):
            b = bytearray(data)
            b[pos] ^= 0x5A
            try:
                decode_ktx2(bytes(b))
            except KTX2Error:
                pass


def test_legacy_unsized_bytesplane_accepted_for_zstd(good):
    raw, z = good
    dfd = _header(z)["dfdByteOffset"]
    legacy = _patch(z, dfd + 20, "<B", 0)  # bytesPlane0 = 0, as KTX 2.0 rev < 4 wanted
    a, info = decode_ktx2(legacy)
    assert info["dfd"]["bytes_plane0"] == 0 and a.shape == (3, 5, 7, 3)
    with pytest.raises(KTX2Error, match="bytesPlane"):
        decode_ktx2(_patch(raw, dfd + 20, "<B", 0))  # not allowed without supercompression


# --------------------------------------------------------------------------- external validators


def _sample_files(folder: Path) -> list[Path]:
    rng = np.random.default_rng(RNG_SEED)
    out = []
    for vk, fmt in FORMATS.items():
        for dims in ((5, 7), (3, 5, 7)):
            for z in (None, 3):
                p = folder / f"{fmt.name}_{len(dims)}d_{'z' if z else 'n'}.ktx2"
                write_ktx2(p, _random(fmt, dims + (fmt.channels,), rng), vk, zstd_level=z, kv={"kiln.t": "1"})
                out.append(p)
    return out


def test_ktx_cli_validate(tmp_path):
    """`ktx validate` (KTX-Software) when installed; Debian and PyPI do not ship it."""
    ktx = shutil.which("ktx")
    if ktx is None:
        pytest.skip("KTX-Software `ktx` tool not installed")
    probe = subprocess.run([ktx, "validate", "--help"], capture_output=True, text=True)
    if probe.returncode != 0 or "validate" not in (probe.stdout + probe.stderr):
        pytest.skip("`ktx` on PATH is not KTX-Software's tool")
    for p in _sample_files(tmp_path):
        r = subprocess.run([ktx, "validate", "--format", "json", str(p)], capture_output=True, text=True)
        report = json.loads(r.stdout or "{}")
        errors = [m for m in report.get("messages", []) if m.get("type") == "error"]
        assert r.returncode == 0 and not errors, (p.name, r.stdout, r.stderr)


_KTX_PARSE_CHECK = r"""
import { readFileSync } from 'node:fs';
import { pathToFileURL } from 'node:url';
const { read, write } = await import(pathToFileURL(process.argv[2]).href);
let bad = 0;
for (const p of process.argv.slice(3)) {
  const buf = new Uint8Array(readFileSync(p));
  const out = write(read(buf), { keepWriter: true });
  if (out.length !== buf.length || out.some((v, i) => v !== buf[i])) { bad++; console.log('MISMATCH ' + p); }
}
console.log(bad ? 'FAIL' : 'OK');
"""


WEB = Path(__file__).resolve().parents[2] / "web"
"""The web app: its dev dependencies (``npm ci`` in scripts/setup.sh) hold the independent KTX2 readers below."""


def test_ktx_parse_rewrites_identically(tmp_path):
    """ktx-parse (glTF-Transform's and three.js' KTX2 parser; a dev dependency of web/) reads our files and
    re-serializes them byte for byte. ``KILN_KTX_PARSE_DIR`` (a folder with ``node_modules/ktx-parse``) overrides."""
    env = os.environ.get("KILN_KTX_PARSE_DIR")
    mods = Path(env) / "node_modules" if env else WEB / "node_modules"
    entry = mods / "ktx-parse" / "dist" / "index.mjs"
    if not shutil.which("node") or not entry.is_file():
        pytest.skip(f"no ktx-parse in {mods} (scripts/setup.sh installs web/'s dev dependencies)")
    script = tmp_path / "check.mjs"
    script.write_text(_KTX_PARSE_CHECK)
    files = _sample_files(tmp_path)
    r = subprocess.run(["node", str(script), str(entry), *map(str, files)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip().endswith("OK"), r.stdout + r.stderr


_LIBKTX_CHECK = r"""
const dir = process.argv[2];
const LIBKTX = require(dir + '/libktx.js');
const fs = require('fs');
LIBKTX({ locateFile: (p) => dir + '/' + p }).then((ktx) => {
  let bad = 0;
  for (const p of process.argv.slice(3)) {
    const t = new ktx.ktxTexture(new Uint8Array(fs.readFileSync(p)));
    if (!t.vkFormat || !t.baseWidth) { bad++; console.log('REJECTED ' + p); }
    t.delete();
  }
  console.log(bad ? 'FAIL' : 'OK');
});
"""


def test_libktx_loads_files(tmp_path):
    """libktx, Khronos' KTX-Software library (its Emscripten build as @khronosgroup/gltf-viewer ships it in
    dist/libs; a dev dependency of web/), loads every file, inflating Zstandard levels and checking their checksums.
    ``KILN_LIBKTX_DIR`` (a folder holding libktx.js and libktx.wasm) overrides."""
    root = os.environ.get("KILN_LIBKTX_DIR") or WEB / "node_modules" / "@khronosgroup" / "gltf-viewer" / "dist" / "libs"
    if not shutil.which("node") or not (Path(root) / "libktx.js").is_file():
        pytest.skip(f"no libktx.js in {root} (scripts/setup.sh installs web/'s dev dependencies)")
    # a copy outside its package: gltf-viewer's package.json says "type": "module", and Node 20 then loads this
    # CommonJS file as an ES module (LIBKTX is not exported)
    lib = tmp_path / "libktx"
    lib.mkdir()
    for name in ("libktx.js", "libktx.wasm"):
        shutil.copyfile(Path(root) / name, lib / name)
    script = tmp_path / "check.cjs"
    script.write_text(_LIBKTX_CHECK)
    files = _sample_files(tmp_path)
    r = subprocess.run(["node", str(script), str(lib), *map(str, files)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip().endswith("OK"), r.stdout + r.stderr


def test_zstd_frame_is_kept_and_identical_to_a_fresh_compression():
    """proto.ktx2.zstd_frame keeps recent frames (a stage reports stored sizes, then writes the same array): the
    kept frame is byte-identical to compressing anew, decodes to the input, and differs per level."""
    import pyzstd

    from proto import ktx2

    raw = np.random.default_rng(3).integers(0, 4, 200_000, dtype=np.uint8).tobytes()
    fresh = pyzstd.compress(raw, {pyzstd.CParameter.compressionLevel: 19, pyzstd.CParameter.checksumFlag: 1})
    first = ktx2.zstd_frame(raw, 19)
    assert first == fresh and pyzstd.decompress(first) == raw
    assert ktx2.zstd_frame(bytes(raw), 19) is first                         # an equal input: the kept frame
    assert ktx2.zstd_frame(raw, 3) != first and pyzstd.decompress(ktx2.zstd_frame(raw, 3)) == raw
    for i in range(ktx2._ZSTD_MEMO_ENTRIES + 1):                            # bounded: the oldest frames go
        ktx2.zstd_frame(raw + bytes([i]), 1)
    assert len(ktx2._ZSTD_MEMO) == ktx2._ZSTD_MEMO_ENTRIES


def test_zstd_frames_kept_are_bounded_in_bytes(monkeypatch):
    from proto import ktx2

    monkeypatch.setattr(ktx2, "_ZSTD_MEMO_BYTES", 1000)
    rng = np.random.default_rng(4)
    for _ in range(3):
        ktx2.zstd_frame(rng.integers(0, 256, 800, dtype=np.uint8).tobytes(), 1)   # ~800 B frames, incompressible
    assert len(ktx2._ZSTD_MEMO) == 1 and sum(map(len, ktx2._ZSTD_MEMO.values())) <= 1000


def test_zstd_frame_is_safe_from_many_threads(monkeypatch):
    """workers.pipeline writes a stage's artifacts from a thread pool: concurrent calls neither raise (the kept
    frames were once trimmed while another thread added one: "OrderedDict mutated during iteration", in CI) nor
    return a wrong frame, and the bounds still hold. The kept frames' iteration yields the GIL between items here,
    so the interleaving CI hit once in a while happens on every run."""
    import time
    from collections import OrderedDict
    from concurrent.futures import ThreadPoolExecutor

    import pyzstd

    from proto import ktx2

    class Yielding(OrderedDict):
        def values(self):
            for v in super().values():
                time.sleep(0)                                               # another thread runs here
                yield v

    monkeypatch.setattr(ktx2, "_ZSTD_MEMO", Yielding())
    monkeypatch.setattr(ktx2, "_ZSTD_MEMO_ENTRIES", 4)
    inputs = [bytes([i % 7]) * (200 + 37 * i) for i in range(64)]

    def work(i):
        for j in range(20):
            raw = inputs[(i * 13 + j) % len(inputs)]
            assert pyzstd.decompress(ktx2.zstd_frame(raw, 1)) == raw
        return True

    with ThreadPoolExecutor(8) as pool:
        assert all(pool.map(work, range(32)))
    assert len(ktx2._ZSTD_MEMO) <= 4
