"""Ingest: an uploaded glTF 2.0 file -> :class:`workers.scene.NormalizedScene` (DESIGN "Bake stages / 0. ingest").

Accepts ``.glb``, ``.gltf`` with every buffer and image embedded as a ``data:`` URI, or a ``.zip`` holding
one ``.gltf``/``.glb`` and the files it references. The type is sniffed from the magic bytes; the file
name is only used in messages.

Everything the bake needs is read straight from the glTF JSON and its accessors with numpy (not through
trimesh: trimesh merges primitives and loses the glTF material/texture indices, ignores skins, drops
TRIANGLE_FAN primitives, does not percent-decode URIs, loads Draco meshes as zeros without DracoPy, and
allocates whatever a GLB chunk header claims). What is read:

- meshes of the default scene, node transforms applied (TRS or matrix, ``EXT_mesh_gpu_instancing``,
  skins at their static pose, morph targets at their default weights), primitive modes TRIANGLES,
  TRIANGLE_STRIP and TRIANGLE_FAN (points and lines are dropped with a warning), sparse and
  quantized/normalized accessors (``KHR_mesh_quantization``), interleaved buffer views;
- compressed geometry, decoded by :mod:`workers.gltf_compression` into the same accessor path:
  ``KHR_draco_mesh_compression`` primitives (DracoPy; preferred over an uncompressed fallback) and
  ``EXT_meshopt_compression`` / ``KHR_meshopt_compression`` buffer views (meshoptimizer; fallback
  buffers without data are never read), the decoded bytes counted against
  ``IngestLimits.max_decoded_bytes`` and the triangle limit;
- materials: base colour factor and texture (``KHR_materials_pbrSpecularGlossiness`` diffuse when a
  material has no metallic-roughness block), emissive factor x ``KHR_materials_emissive_strength`` and
  emissive texture, ``doubleSided``; ``KHR_texture_transform`` is applied to the UVs;
- textures used by materials, decoded with PIL to RGBA uint8 (PNG, JPEG, WebP via ``EXT_texture_webp``);
- ``KHR_lights_punctual`` lights placed by their nodes' world transforms.

Every bad input raises :class:`IngestError` with a machine-readable ``code``, a sentence and a 4xx
``status``; no other exception type leaves :func:`ingest_file`.

Frames and units: glTF's (+Y up, right-handed, metres, counter-clockwise front faces); see
:mod:`workers.scene` for the output arrays. Consumer: ``workers/stages`` (every bake stage) and the
upload route. Inverse: none.

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.5 (nodes), 3.6 (accessors), 3.7.2 (meshes,
   primitive modes), 3.7.3 (skins), 3.9 (materials).
.. [KHR_lights_punctual] Khronos glTF extension: point, spot and directional lights.
.. [KHR_texture_transform] Khronos glTF extension: offset, rotation, scale of texture coordinates.
.. [KHR_draco_mesh_compression], [EXT_meshopt_compression] Khronos glTF extensions; see
   :mod:`workers.gltf_compression`.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import os
import posixpath
import re
import struct
import tempfile
import unicodedata
import urllib.parse
import warnings as _pywarnings
import zipfile
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from workers import gltf_compression as _gc
from workers.gltf_cameras import build_cameras
from workers.scene import NormalizedScene

__all__ = ["IngestError", "IngestLimits", "ingest_file"]


# ---------------------------------------------------------------------------------------------- errors


class IngestError(Exception):
    """A bad upload: a machine-readable ``code``, a human ``message`` and the HTTP ``status``.

    Parameters
    ----------
    code : str
        Stable identifier, e.g. ``"truncated_glb"``, ``"missing_resource"`` (see :data:`ERROR_CODES`).
    message : str
        One sentence saying what is wrong and, where it helps, what to do.
    status : int
        HTTP status for the upload route: 413 for size limits, 415 for files that are not glTF,
        422 for everything else.
    """

    def __init__(self, code: str, message: str, status: int = 422):
        message = _scrub(message)
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.status = status


_OBJECT_REPR = re.compile(r"<[^<>]*? at 0x[0-9a-fA-F]+>")
_TEMP_MEMBER = re.compile(r"""(?:[A-Za-z]:)?[^\s'"<>]*kiln-ingest-[^\s'"<>/\\]+[/\\]member-\d+""")


def _scrub(message: str, paths: tuple[str, ...] = ()) -> str:
    """A message without temporary paths or object addresses (they say nothing to the user, and leak the
    server's layout): ``<_io.BytesIO object at 0x7f...>`` -> ``the data``, a path under the temp directory
    (where zip members are extracted, where the API stages uploads) -> ``a file in the upload``."""
    message = _OBJECT_REPR.sub("the data", message)
    message = _TEMP_MEMBER.sub("a file in the upload", message)
    for p in sorted({p for p in paths if p and p != os.sep}, key=len, reverse=True):
        message = message.replace(p, "the upload")
    for root in {tempfile.gettempdir(), os.path.realpath(tempfile.gettempdir())}:
        if root and root != os.sep and root in message:
            message = re.sub(re.escape(root) + r"""[^\s'"<>]*""", "a file in the upload", message)
    return message


#: Every code :func:`ingest_file` raises, with its HTTP status.
ERROR_CODES: dict[str, int] = {
    "not_gltf": 415,  # unknown magic, or JSON that is not an object with "asset"
    "truncated_glb": 422,  # GLB header/chunk lengths larger than the file
    "broken_json": 422,  # JSON syntax error, bad UTF-8, NaN/Infinity literals
    "json_too_deep": 422,  # nesting deeper than IngestLimits.max_json_depth
    "broken_zip": 422,  # unreadable archive, CRC error, duplicate member names
    "multiple_models": 422,  # a zip with more than one .gltf/.glb
    "external_uri": 422,  # http:, file:, UNC, absolute paths
    "path_traversal": 422,  # ".." in a URI or zip member name, absolute zip member names
    "missing_resource": 422,  # a referenced buffer or image is not in the upload
    "invalid_gltf": 422,  # structural errors: bad indices, ranges, accessor types
    "invalid_image": 422,  # an image PIL cannot decode, or not PNG/JPEG/WebP
    "non_finite": 422,  # NaN/inf positions or UVs after transforms
    "absurd_magnitude": 422,  # |world position| > MAX_COORD, emissive x strength > MAX_EMISSIVE, light intensity
    # > MAX_LIGHT_INTENSITY or colour > MAX_LIGHT_COLOR (a scale of 1e20, an emissive of 1e60: garbage, not a scene)
    "negative_emissive": 422,  # an emissiveFactor component or emissiveStrength below 0 (negative light)
    "negative_light": 422,  # a KHR_lights_punctual light with a negative colour component or intensity
    "zero_extent": 422,  # every triangle in one point (the bounds' diagonal below MIN_EXTENT)
    "degenerate_triangles": 422,  # every triangle has zero area (all on lines or points)
    "text_buffer": 422,  # a buffer holding text, not binary numbers (a Git LFS pointer committed in its place)
    "no_triangles": 422,  # nothing to bake
    "unsupported": 422,  # a feature refused with a reason (glTF 1.0, minVersion 2.1, encrypted zip)
    "unsupported_extension": 422,  # extensionsRequired we cannot honour
    "too_large": 413,  # upload larger than IngestLimits.max_bytes
    "too_many_triangles": 413,
    "zip_bomb": 413,
    "decoded_too_large": 413,  # Draco/meshopt data decoding to more than IngestLimits.max_decoded_bytes
    "image_too_large": 413,
    "unreadable_upload": 500,  # the upload path itself cannot be read (a server fault, not bad input)
}


def _err(code: str, message: str) -> IngestError:
    return IngestError(code, message, ERROR_CODES[code])


def _invalid(message: str) -> IngestError:
    return _err("invalid_gltf", message)


# ---------------------------------------------------------------------------------------------- limits


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


# ---------------------------------------------------------------------------------------------- constants

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
_LFS_POINTER = b"version https://git-lfs"
_TEXT_BYTES = bytes(range(0x20, 0x7F)) + b"\t\n\r"
_TEXT_MIN_BYTES = 64  # shorter buffers are not judged (a few random floats can be printable bytes)

_GLB_MAGIC = b"glTF"
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # local file header; end of central directory (empty zip)
_UTF8_BOM = b"\xef\xbb\xbf"
_CHUNK_JSON = 0x4E4F534A  # "JSON"
_CHUNK_BIN = 0x004E4942  # "BIN\0"
_RATIO_MIN_BYTES = 8 << 20  # zip ratio checks apply from this many uncompressed bytes (smaller members
# cannot hurt; real glTF buffers full of zeros legitimately compress ~1000x)
_COPY_CHUNK = 1 << 20

_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_INDEX_COMPONENTS = (5121, 5123, 5125)

_MODE_NAMES = {0: "point", 1: "line", 2: "line-loop", 3: "line-strip", 4: "triangles", 5: "strip", 6: "fan"}

#: Extensions we read (or that need nothing from us): allowed in ``extensionsRequired``.
HONOURED_EXTENSIONS = frozenset(
    {
        "KHR_lights_punctual",
        "KHR_materials_emissive_strength",
        "KHR_texture_transform",
        "KHR_mesh_quantization",
        "EXT_texture_webp",
        "EXT_mesh_gpu_instancing",
        "KHR_materials_pbrSpecularGlossiness",
        "KHR_draco_mesh_compression",  # decoded with DracoPy (workers.gltf_compression)
        "EXT_meshopt_compression",  # decoded with meshoptimizer (workers.gltf_compression)
        "KHR_meshopt_compression",
    }
)
#: Extensions refused by name when required, with the reason given to the user.
_REFUSED_EXTENSIONS = {
    "KHR_texture_basisu": "KTX2/Basis Universal textures cannot be decoded here; re-export with PNG, "
    "JPEG or WebP textures",
}

_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


# ---------------------------------------------------------------------------------------------- public API


def ingest_file(
    path: str | os.PathLike, limits: IngestLimits | None = None, filename: str | None = None
) -> NormalizedScene:
    """Read an uploaded glTF 2.0 file into a normalized, world-space scene.

    Parameters
    ----------
    path : str or os.PathLike
        The upload on disk: a ``.glb``, a ``.gltf`` whose buffers and images are ``data:`` URIs, or a
        ``.zip`` holding one ``.gltf``/``.glb`` and its files. The type comes from the magic bytes.
    limits : IngestLimits, optional
        Size, triangle, zip and image bounds; defaults to ``IngestLimits()``.
    filename : str, optional
        The name the user uploaded it as; used in messages only.

    Returns
    -------
    NormalizedScene
        ``triangles`` (T, 3, 3) float32 world-space metres, ``normals`` (T, 3, 3) float32 unit,
        ``uv0`` (T, 3, 2) float32, ``uv1`` (T, 3, 2) float32 or None, ``material`` (T,) int32,
        materials, lights, RGBA uint8 textures and warnings (things dropped or approximated).

    Raises
    ------
    IngestError
        For every bad input (see :data:`ERROR_CODES`); never any other exception type.

    Notes
    -----
    Zip members are streamed to a private temporary directory (removed before returning) with their
    sizes checked while copying; nothing is written anywhere else. GLB binary chunks and extracted
    buffers are memory-mapped, not read whole.
    """
    limits = limits if limits is not None else IngestLimits()
    label = filename or os.path.basename(os.fspath(path))
    where = (os.path.abspath(path), os.path.dirname(os.path.abspath(path)))  # scrubbed from messages
    try:
        with np.errstate(all="ignore"):  # NaN/inf are checked explicitly where they matter
            return _ingest(Path(path), limits, label)
    except IngestError as exc:
        exc.message = _scrub(exc.message, where)  # the upload's own path never reaches the user
        exc.args = (f"{exc.code}: {exc.message}",)
        raise
    except MemoryError as exc:
        raise _err("too_large", f"'{label}' needs more memory than this service allows") from exc
    except RecursionError as exc:
        raise _err("json_too_deep", f"'{label}' is nested too deeply to read") from exc
    except Exception as exc:  # a numpy/PIL/zipfile surprise on a bad upload is still a 4xx, never a 500
        message = f"'{label}' could not be read as glTF 2.0 ({type(exc).__name__}: {exc})"
        raise _invalid(_scrub(message, where)) from exc


# ---------------------------------------------------------------------------------------------- entry


def _ingest(path: Path, limits: IngestLimits, label: str) -> NormalizedScene:
    try:
        st = path.stat()
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise _err("unreadable_upload", f"the upload '{label}' cannot be read: {exc.strerror or exc}") from exc
    if st.st_size > limits.max_bytes:
        raise _err("too_large", f"'{label}' is {st.st_size} bytes; the limit is {limits.max_bytes} bytes")
    kind = _sniff(head)
    if kind == "zip":
        with tempfile.TemporaryDirectory(prefix="kiln-ingest-") as tmp:
            archive = _ZipUpload(path, limits, Path(tmp), label)
            try:
                model_name = archive.model_member()
                model_path = archive.extract(model_name)
                with open(model_path, "rb") as f:
                    model_kind = _sniff(f.read(4096))
                if model_kind not in ("glb", "gltf"):
                    raise _err("not_gltf", f"'{model_name}' in '{label}' is neither GLB nor glTF JSON")
                files = archive.files(posixpath.dirname(model_name))
                return _load_model(model_path, model_kind, files, limits, f"{label}/{model_name}")
            finally:
                archive.close()
    if kind in ("glb", "gltf"):
        return _load_model(path, kind, _NoFiles(), limits, label)
    if head.startswith(_LFS_POINTER):
        raise _err("not_gltf", f"'{label}' is a Git LFS pointer (a small text file), not the model: fetch the "
                               "real file (git lfs pull) and upload that")
    raise _err(
        "not_gltf",
        f"'{label}' is not glTF 2.0: expected a .glb (starting with 'glTF'), a .gltf (a JSON object) "
        "or a .zip holding one",
    )


def _sniff(head: bytes) -> str | None:
    """Upload type from the first bytes: ``"glb"``, ``"zip"``, ``"gltf"`` (JSON object) or None."""
    if head.startswith(_GLB_MAGIC):
        return "glb"
    if head[:4] in _ZIP_MAGICS:
        return "zip"
    text = head[len(_UTF8_BOM) :] if head.startswith(_UTF8_BOM) else head
    if text.lstrip(b" \t\r\n").startswith(b"{"):
        return "gltf"
    return None


def _load_model(path: Path, kind: str, files: _Files, limits: IngestLimits, label: str) -> NormalizedScene:
    warnings: list[str] = []
    bin_chunk = None
    if kind == "glb":
        json_bytes, bin_chunk = _read_glb(path, label, warnings)
    else:
        json_bytes = path.read_bytes()
    gltf = _parse_json(json_bytes, limits, label)
    del json_bytes
    reader = _GltfReader(gltf, path, bin_chunk, files, limits, label, warnings)
    return reader.build()


# ---------------------------------------------------------------------------------------------- GLB / JSON


def _read_glb(path: Path, label: str, warnings: list[str]) -> tuple[bytes, tuple[Path, int, int] | None]:
    """Split a GLB into its JSON bytes and the (path, offset, length) of its BIN chunk.

    Every length is checked against the file size before anything is allocated.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(12)
        if len(header) < 12:
            raise _err("truncated_glb", f"'{label}' ends inside the 12-byte GLB header")
        _, version, length = struct.unpack("<4sII", header)
        if version != 2:
            raise _err("unsupported", f"'{label}' is GLB version {version}; only glTF 2.0 (GLB version 2) is supported")
        if length > size:
            raise _err("truncated_glb", f"'{label}' GLB header says {length} bytes but the file has {size}")
        if length < 20:
            raise _err("truncated_glb", f"'{label}' GLB header length {length} leaves no room for a JSON chunk")
        json_bytes = None
        bin_chunk = None
        pos = 12
        n_chunk = 0
        while pos + 8 <= length:
            f.seek(pos)
            chunk_len, chunk_type = struct.unpack("<II", f.read(8))
            if pos + 8 + chunk_len > length:
                raise _err(
                    "truncated_glb",
                    f"'{label}' GLB chunk {n_chunk} claims {chunk_len} bytes at offset {pos + 8}, past the "
                    f"end of the file ({length} bytes)",
                )
            if n_chunk == 0:
                if chunk_type != _CHUNK_JSON:
                    raise _invalid(f"'{label}' GLB first chunk is not JSON (type 0x{chunk_type:08x})")
                json_bytes = f.read(chunk_len)
            elif chunk_type == _CHUNK_BIN and bin_chunk is None:
                bin_chunk = (path, pos + 8, chunk_len)
            pos += 8 + chunk_len
            n_chunk += 1
        if json_bytes is None:
            raise _err("truncated_glb", f"'{label}' GLB has no JSON chunk")
        if length < size:
            warnings.append(f"{size - length} bytes after the end of the GLB ignored")
    return json_bytes, bin_chunk


def _json_depth(data: bytes) -> int:
    """Deepest object/array nesting in JSON text, counted without recursion.

    String literals are blanked first, so brackets inside strings do not count.
    """
    stripped = _JSON_STRING.sub(b'""', data)
    a = np.frombuffer(stripped, np.uint8)
    if a.size == 0:
        return 0
    delta = ((a == ord("{")) | (a == ord("["))).astype(np.int32)
    delta -= ((a == ord("}")) | (a == ord("]"))).astype(np.int32)
    return int(np.cumsum(delta).max(initial=0))


def _reject_constant(name: str):
    raise _err("broken_json", f"the JSON contains {name}, which JSON does not allow")


def _parse_float(text: str) -> float | int:
    """A JSON number with a fraction or exponent; an integral one (``3.0``, ``1e2``) is read as an int.

    glTF's schema types indices, counts and offsets as JSON Schema ``integer``, which "matches any number
    with a zero fractional part" (JSON Schema 2020-12, 6.1.1: ``1.0`` is an integer), so ``"count": 3.0`` is
    valid glTF. Every float the reader uses goes through ``float()``, so nothing else changes.
    """
    x = float(text)
    if x.is_integer() and abs(x) < 2.0**53:
        return int(x)
    return x


def _parse_json(data: bytes, limits: IngestLimits, label: str) -> dict:
    """Parse glTF JSON bytes (UTF-8, optional BOM) after a non-recursive depth check."""
    if data.startswith(_UTF8_BOM):
        data = data[len(_UTF8_BOM) :]
    depth = _json_depth(data)
    if depth > limits.max_json_depth:
        raise _err("json_too_deep", f"'{label}' JSON nests {depth} levels deep; the limit is {limits.max_json_depth}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _err("broken_json", f"'{label}' JSON is not valid UTF-8 (byte {exc.start})") from exc
    try:
        doc = json.loads(text, parse_constant=_reject_constant, parse_float=_parse_float)
    except json.JSONDecodeError as exc:
        raise _err(
            "broken_json", f"'{label}' JSON is broken at line {exc.lineno} column {exc.colno}: {exc.msg}"
        ) from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        raise _err("not_gltf", f"'{label}' is JSON but not glTF: it has no \"asset\" object")
    return doc


# ---------------------------------------------------------------------------------------------- URIs


def _split_uri(uri, what: str) -> tuple[str, str]:
    """Classify a glTF URI: ``("data", uri)`` or ``("file", relative path, percent-decoded, '/'-separated)``.

    Raises ``external_uri`` for schemes (http:, file:, C:), absolute paths and UNC paths, checked on the raw
    and the percent-decoded URI. ``..`` segments are kept: where the URI lands is the resolver's to judge
    (:class:`_ZipFiles`: anywhere inside the zip is fine, ``path_traversal`` above its root; a loose file
    has nothing beside it).
    """
    if not isinstance(uri, str) or not uri:
        raise _invalid(f"{what} has a URI that is not a non-empty string")
    if uri[:5].lower() == "data:":
        return "data", uri
    decoded = urllib.parse.unquote(uri)
    for candidate in (uri, decoded):
        if _URI_SCHEME.match(candidate) or candidate.startswith(("/", "\\")):
            raise _err(
                "external_uri",
                f"{what} points outside the upload ('{uri}'): only relative paths inside the upload "
                "and data: URIs are allowed",
            )
    if "\x00" in decoded:
        raise _invalid(f"{what} URI contains a NUL byte")
    return "file", decoded.replace("\\", "/")


def _climbs_out(rel: str) -> bool:
    """Whether a '/'-separated relative path leaves its root (``../a``, ``a/../../b``); ``a/../b`` does not."""
    target = posixpath.normpath(rel)
    return target == ".." or target.startswith("../")


def _decode_data_uri(uri: str, what: str) -> bytes:
    header, sep, payload = uri.partition(",")
    if not sep:
        raise _invalid(f"{what} has a data: URI without a ',' before its payload")
    if header.lower().endswith(";base64"):
        try:
            return base64.b64decode(payload, validate=False)
        except (binascii.Error, ValueError) as exc:
            raise _invalid(f"{what} data: URI is not valid base64 ({exc})") from exc
    return urllib.parse.unquote_to_bytes(payload)


class _Files:
    """Where relative URIs resolve. ``locate`` checks existence; ``path`` gives a readable file."""

    def locate(self, rel: str, what: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def path(self, rel: str, what: str) -> Path:  # pragma: no cover - interface
        raise NotImplementedError


class _NoFiles(_Files):
    """A loose .glb/.gltf: nothing beside it was uploaded."""

    def _missing(self, rel: str, what: str) -> IngestError:
        return _err(
            "missing_resource",
            f"{what} '{rel}' is not in the upload: a lone .gltf/.glb must embed its buffers and images "
            "(data: URIs or the GLB binary chunk); upload a .zip holding the model and its files instead",
        )

    def locate(self, rel: str, what: str) -> None:
        if _climbs_out(rel):
            raise _err("path_traversal", f"{what} URI '{rel}' climbs out of the upload with '..'")
        raise self._missing(rel, what)

    def path(self, rel: str, what: str) -> Path:
        self.locate(rel, what)  # always raises
        raise self._missing(rel, what)


# ---------------------------------------------------------------------------------------------- zip


class _ZipUpload:
    """A zip upload: member names checked, sizes bounded, members streamed out one by one on demand."""

    def __init__(self, path: Path, limits: IngestLimits, tmp: Path, label: str):
        self.limits = limits
        self.tmp = tmp
        self.label = label
        self.extracted: dict[str, Path] = {}
        self.expanded = 0
        try:
            self.zf = zipfile.ZipFile(path)
            infos = self.zf.infolist()
        except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError, EOFError, struct.error) as exc:
            raise _err("broken_zip", f"'{label}' is not a readable zip archive ({exc})") from exc
        if len(infos) > limits.max_zip_members:
            self.zf.close()
            raise _err("zip_bomb", f"'{label}' holds {len(infos)} entries; the limit is {limits.max_zip_members}")
        self.members: dict[str, zipfile.ZipInfo] = {}
        total_u = total_c = 0
        try:
            for info in infos:
                name = _member_name(info)
                if name.startswith("/") or re.match(r"^[A-Za-z]:", name):
                    raise _err("path_traversal", f"'{label}' has an absolute member name '{info.filename}'")
                if _climbs_out(name):
                    raise _err(
                        "path_traversal", f"'{label}' has a member name that climbs out with '..': '{info.filename}'"
                    )
                name = posixpath.normpath(name)  # 'textures/../a.png' is 'a.png': '..' inside the zip is fine
                if info.is_dir() or name in (".", ""):
                    continue
                if name.startswith("__MACOSX/") or posixpath.basename(name).startswith("._"):
                    continue  # macOS resource forks
                if name in self.members:
                    raise _err("broken_zip", f"'{label}' holds '{name}' twice")
                total_u += info.file_size
                total_c += info.compress_size
                if total_u > limits.max_expanded_bytes:
                    raise _err(
                        "zip_bomb",
                        f"'{label}' expands to more than {limits.max_expanded_bytes} bytes (the limit)",
                    )
                if info.file_size >= _RATIO_MIN_BYTES and info.file_size > limits.max_zip_ratio * max(
                    info.compress_size, 1
                ):
                    raise _err(
                        "zip_bomb",
                        f"'{name}' in '{label}' expands {info.file_size / max(info.compress_size, 1):.0f}x; "
                        f"the limit is {limits.max_zip_ratio:g}x",
                    )
                self.members[name] = info
            if total_u >= _RATIO_MIN_BYTES and total_u > limits.max_zip_ratio * max(total_c, 1):
                raise _err(
                    "zip_bomb",
                    f"'{label}' expands {total_u / max(total_c, 1):.0f}x in total; "
                    f"the limit is {limits.max_zip_ratio:g}x",
                )
        except IngestError:
            self.zf.close()
            raise
        # Unicode normalization: a URI written in NFC finds a member stored NFD (macOS) and vice versa
        nfc = Counter(_nfc(n) for n in self.members)
        self._by_nfc = {_nfc(n): n for n in self.members if nfc[_nfc(n)] == 1}
        self._nfc_lower = Counter(_nfc(n).lower() for n in self.members)

    def close(self) -> None:
        self.zf.close()

    def model_member(self) -> str:
        models = sorted(n for n in self.members if n.lower().endswith((".gltf", ".glb")))
        if not models:
            raise _err("not_gltf", f"'{self.label}' holds no .gltf or .glb file")
        if len(models) > 1:
            shown = ", ".join(models[:5]) + (", ..." if len(models) > 5 else "")
            raise _err("multiple_models", f"'{self.label}' holds {len(models)} models ({shown}); upload one per zip")
        return models[0]

    def extract(self, name: str) -> Path:
        """Stream one member to the temporary directory, enforcing its declared size and the total limit."""
        if name in self.extracted:
            return self.extracted[name]
        info = self.members[name]
        out = self.tmp / f"member-{len(self.extracted):05d}"  # never a user-chosen path
        written = 0
        try:
            with self.zf.open(info) as src, open(out, "wb") as dst:
                while True:
                    chunk = src.read(_COPY_CHUNK)
                    if not chunk:
                        break
                    written += len(chunk)
                    if written > info.file_size or self.expanded + written > self.limits.max_expanded_bytes:
                        raise _err(
                            "zip_bomb", f"'{name}' in '{self.label}' expands past its declared size or the limit"
                        )
                    dst.write(chunk)
        except IngestError:
            raise
        except NotImplementedError as exc:
            raise _err(
                "unsupported", f"'{name}' in '{self.label}' uses a compression method this service cannot read"
            ) from exc
        except RuntimeError as exc:  # encrypted member (its message holds a ZipInfo repr: not shown)
            raise _err("unsupported", f"'{name}' in '{self.label}' is encrypted (password-protected); "
                                      "upload it unencrypted") from exc
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
            raise _err("broken_zip", f"'{name}' in '{self.label}' is damaged ({exc})") from exc
        self.expanded += written
        self.extracted[name] = out
        return out

    def files(self, base: str) -> _ZipFiles:
        return _ZipFiles(self, base)


def _nfc(name: str) -> str:
    return unicodedata.normalize("NFC", name)


def _member_name(info: zipfile.ZipInfo) -> str:
    """A zip member's name, '/'-separated; UTF-8 even when the archiver did not set the UTF-8 flag.

    Without flag bit 11 the zip format says cp437 (zipfile decodes so), but most archivers write UTF-8
    regardless: such a name that is valid UTF-8 is read as UTF-8.
    """
    name = info.filename
    if not info.flag_bits & 0x800 and not name.isascii():
        try:
            name = name.encode("cp437").decode("utf-8")
        except (UnicodeEncodeError, UnicodeDecodeError):
            pass
    return name.replace("\\", "/")


class _ZipFiles(_Files):
    """Relative URIs resolved against the model's folder inside the zip (case-insensitive as a fallback)."""

    def __init__(self, archive: _ZipUpload, base: str):
        self.archive = archive
        self.base = base
        self.case_fixed: list[str] = []

    def _member(self, rel: str, what: str) -> str:
        target = posixpath.normpath(posixpath.join(self.base, rel)) if self.base else posixpath.normpath(rel)
        if target == ".." or target.startswith("../"):
            raise _err("path_traversal", f"{what} '{rel}' climbs out of the upload")
        if target in self.archive.members:
            return target
        if _nfc(target) in self.archive._by_nfc:  # the same name in another Unicode normalization form
            return self.archive._by_nfc[_nfc(target)]
        lower = _nfc(target).lower()
        if self.archive._nfc_lower.get(lower) == 1:
            for name in self.archive.members:
                if _nfc(name).lower() == lower:
                    self.case_fixed.append(f"{rel} -> {name}")
                    return name
        raise _err("missing_resource", f"{what} '{rel}' is not in the zip '{self.archive.label}'")

    def locate(self, rel: str, what: str) -> None:
        self._member(rel, what)

    def path(self, rel: str, what: str) -> Path:
        return self.archive.extract(self._member(rel, what))


# ---------------------------------------------------------------------------------------------- small checks


def _lookup(table: dict, key):
    """``table.get(key)`` for any JSON value (lists and objects are unhashable: None)."""
    return table.get(key) if isinstance(key, (int, str)) and not isinstance(key, bool) else None


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _vec(v, n: int, default, what: str) -> list[float]:
    """A list of ``n`` finite numbers (or ``default`` when absent) as Python floats."""
    if v is None:
        if default is None:
            raise _invalid(f"{what} must be {n} numbers")
        return [float(x) for x in default]
    if not isinstance(v, list) or len(v) != n or not all(_is_num(x) for x in v):
        raise _invalid(f"{what} must be {n} numbers")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        raise _err("non_finite", f"{what} holds NaN or infinity")
    return out


def _num(v, default, what: str) -> float:
    if v is None:
        return float(default)
    if not _is_num(v):
        raise _invalid(f"{what} must be a number")
    x = float(v)
    if not math.isfinite(x):
        raise _err("non_finite", f"{what} is NaN or infinite")
    return x


def _quat_to_matrix(q: list[float]) -> np.ndarray:
    """Unit quaternion [x, y, z, w] (glTF order) -> (3, 3) rotation matrix."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _cofactor(m: np.ndarray) -> np.ndarray:
    """Cofactor matrices of (..., 3, 3) matrices: ``det(M) * inv(M).T``, defined for singular M too.

    With columns a, b, c of M the cofactor matrix has columns b x c, c x a, a x b. Normals transform
    by ``sign(det) * cofactor`` (proportional to the inverse transpose).
    """
    a, b, c = m[..., :, 0], m[..., :, 1], m[..., :, 2]
    return np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=-1)


def _normalize_rows(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along the last axis and a mask of rows that had a usable (finite, non-zero) length."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = np.isfinite(n[..., 0]) & (n[..., 0] > 1e-30)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(ok[..., None], v / np.where(ok[..., None], n, 1.0), 0.0)
    return out, ok


def _texture_transform_matrix(ext: dict, what: str) -> np.ndarray:
    """KHR_texture_transform as a (2, 3) affine map on [u, v, 1]: translation * rotation * scale.

    Rotation follows the glTF sample viewer and three.js: ``u' = cos r * u + sin r * v``,
    ``v' = -sin r * u + cos r * v`` (counter-clockwise in UV space, whose v axis points down the image).
    """
    off = _vec(ext.get("offset"), 2, [0.0, 0.0], f"{what} KHR_texture_transform offset")
    rot = _num(ext.get("rotation"), 0.0, f"{what} KHR_texture_transform rotation")
    scale = _vec(ext.get("scale"), 2, [1.0, 1.0], f"{what} KHR_texture_transform scale")
    c, s = math.cos(rot), math.sin(rot)
    r = np.array([[c, s], [-s, c]])
    m = np.zeros((2, 3))
    m[:, :2] = r @ np.diag(scale)
    m[:, 2] = off
    return m


# ---------------------------------------------------------------------------------------------- reader


@dataclass
class _TexRef:
    """One material texture slot: the glTF texture index, its UV set and its UV transform."""

    texture: int
    texcoord: int
    transform: np.ndarray | None  # (2, 3) or None


class _GltfReader:
    """Reads one parsed glTF document into a :class:`NormalizedScene`.

    Parameters
    ----------
    gltf : dict
        The parsed JSON.
    path : Path
        The .gltf/.glb on disk (GLB BIN chunk lives in it).
    bin_chunk : (Path, int, int) or None
        GLB binary chunk: file, byte offset, byte length.
    files : _Files
        Resolves relative URIs (nothing for loose uploads; zip members otherwise).
    """

    def __init__(
        self, gltf: dict, path: Path, bin_chunk, files: _Files, limits: IngestLimits, label: str, warnings: list[str]
    ):
        self.g = gltf
        self.path = path
        self.bin_chunk = bin_chunk
        self.files = files
        self.limits = limits
        self.label = label
        self.warnings = warnings
        self._buffers: dict[int, np.ndarray] = {}
        self._accessors: dict[int, np.ndarray] = {}
        self._counts: Counter = Counter()  # things dropped, summarized as warnings at the end
        self._meshopt_views: dict[int, np.ndarray] = {}  # bufferView -> decoded bytes
        self._draco: dict[int, _gc.DracoGeometry] = {}  # Draco bufferView -> decoded mesh
        self._decoded_bytes = 0  # Draco + meshopt output so far (IngestLimits.max_decoded_bytes)
        self._image_pixels = 0  # decoded image pixels so far (IngestLimits.max_total_image_pixels)

    # ------------------------------------------------------------------ JSON access
    def _list(self, key: str, owner: dict | None = None) -> list:
        v = (self.g if owner is None else owner).get(key, [])
        if not isinstance(v, list):
            raise _invalid(f"'{key}' must be an array")
        return v

    def _item(self, key: str, idx, what: str) -> dict:
        lst = self._list(key)
        if not _is_int(idx):
            raise _invalid(f"{what} refers to {key} index {idx!r}, which is not an integer")
        if not 0 <= idx < len(lst):
            raise _invalid(f"{what} refers to {key}[{idx}], but the file has {len(lst)} {key}")
        item = lst[idx]
        if not isinstance(item, dict):
            raise _invalid(f"{key}[{idx}] is not an object")
        return item

    def _exts(self, obj: dict) -> dict:
        e = obj.get("extensions", {})
        return e if isinstance(e, dict) else {}

    # ------------------------------------------------------------------ top-level checks
    def _check_asset(self) -> None:
        asset = self.g["asset"]
        version = asset.get("version")
        m = re.fullmatch(r"(\d+)\.(\d+)", version) if isinstance(version, str) else None
        if m is None:
            raise _invalid(f"asset.version {version!r} is not 'major.minor'")
        if int(m.group(1)) != 2:
            raise _err("unsupported", f"this is glTF {version}; only glTF 2.x is supported")
        min_version = asset.get("minVersion")
        if min_version is not None:
            mm = re.fullmatch(r"(\d+)\.(\d+)", min_version) if isinstance(min_version, str) else None
            if mm is None:
                raise _invalid(f"asset.minVersion {min_version!r} is not 'major.minor'")
            if (int(mm.group(1)), int(mm.group(2))) > (2, 0):
                raise _err(
                    "unsupported",
                    f"the file requires glTF {min_version} (asset.minVersion); this service reads glTF 2.0",
                )

    def _check_extensions(self) -> None:
        required = self._list("extensionsRequired")
        used = self._list("extensionsUsed")
        for name in required:
            if not isinstance(name, str):
                raise _invalid("extensionsRequired must hold strings")
            if name in _REFUSED_EXTENSIONS:
                raise _err(
                    "unsupported_extension", f"required extension {name} is not supported: {_REFUSED_EXTENSIONS[name]}"
                )
            if name not in HONOURED_EXTENSIONS:
                raise _err("unsupported_extension", f"required extension {name} is not supported by this service")
        ignored = sorted({u for u in used if isinstance(u, str) and u not in HONOURED_EXTENSIONS})
        if ignored:
            self.warnings.append("extensions ignored: " + ", ".join(ignored))

    def _check_uris(self) -> None:
        """Every buffer and image URI: no escapes, and present in the upload (used or not)."""
        for key, noun in (("buffers", "buffer"), ("images", "image")):
            for i, obj in enumerate(self._list(key)):
                if not isinstance(obj, dict):
                    raise _invalid(f"{key}[{i}] is not an object")
                if "uri" in obj:
                    kind, rel = _split_uri(obj["uri"], f"{noun} {i}")
                    if kind == "file" and not (key == "buffers" and self._meshopt_fallback(obj)):
                        self.files.locate(rel, f"{noun} {i}")  # meshopt fallbacks are never read

    # ------------------------------------------------------------------ buffers and accessors
    def _buffer(self, idx, what: str) -> np.ndarray:
        """Buffer bytes as a read-only (byteLength,) uint8 array (memory-mapped where it is a file)."""
        if _is_int(idx) and idx in self._buffers:
            return self._buffers[idx]
        b = self._item("buffers", idx, what)
        length = b.get("byteLength")
        if not _is_int(length) or length < 1:
            raise _invalid(f"buffers[{idx}].byteLength must be a positive integer")
        if "uri" in b:
            kind, rel = _split_uri(b["uri"], f"buffer {idx}")
            if kind == "data":
                data = np.frombuffer(_decode_data_uri(rel, f"buffer {idx}"), np.uint8)
            else:
                data = _map_file(self.files.path(rel, f"buffer {idx}"), 0, None)
        elif idx == 0 and self.bin_chunk is not None:
            data = _map_file(*self.bin_chunk)
        else:
            if self._meshopt_fallback(b):
                raise _invalid(
                    f"{what} reads buffers[{idx}], a meshopt fallback buffer without data (only "
                    "meshopt-compressed bufferViews may refer to it)"
                )
            raise _invalid(f"buffers[{idx}] has no uri and is not the GLB binary chunk")
        head = bytes(data[: min(4096, length)])  # text read as floats is ~1e31 garbage: refuse it by name
        if (len(head) >= _TEXT_MIN_BYTES or head.startswith(_LFS_POINTER)) and not head.translate(None, _TEXT_BYTES):
            name = f" ('{urllib.parse.unquote(b['uri'])}')" if "uri" in b and not b["uri"].startswith("data:") else ""
            why = (" It is a Git LFS pointer: fetch the real file (git lfs pull) and upload that."
                   if head.startswith(_LFS_POINTER) else "")
            raise _err("text_buffer", f"buffers[{idx}]{name} holds text, not binary vertex data.{why}")
        if data.size < length:
            raise _invalid(f"buffers[{idx}] declares {length} bytes but holds {data.size}")
        data = data[:length]
        self._buffers[idx] = data
        return data

    def _view_bytes(self, view_idx, what: str) -> tuple[np.ndarray, dict]:
        """(byteLength,) uint8 slice of a buffer view, range-checked, and the view object."""
        view = self._item("bufferViews", view_idx, what)
        what_v = f"bufferViews[{view_idx}]"
        ext = self._exts(view)
        if any(name in ext for name in _gc.MESHOPT_EXTENSIONS):
            return self._meshopt_view(view_idx, view, ext), view  # the view's own buffer is a fallback
        buf = self._buffer(view.get("buffer"), what_v)
        off = view.get("byteOffset", 0)
        length = view.get("byteLength")
        if not _is_int(off) or off < 0 or not _is_int(length) or length < 1:
            raise _invalid(f"{what_v} needs a non-negative byteOffset and a positive byteLength")
        if off + length > buf.size:
            raise _invalid(
                f"{what_v} (bytes {off}..{off + length}) runs past the end of buffer {view.get('buffer')} "
                f"({buf.size} bytes)"
            )
        return buf[off : off + length], view

    # ------------------------------------------------------------------ compressed geometry
    def _meshopt_fallback(self, buffer: dict) -> bool:
        """Whether a buffer is marked ``{"fallback": true}`` by a meshopt extension [EXT_meshopt_compression]."""
        exts = self._exts(buffer)
        return any(isinstance(exts.get(n), dict) and exts[n].get("fallback") is True for n in _gc.MESHOPT_EXTENSIONS)

    def _count_decoded(self, nbytes: int, what: str) -> None:
        """Charge ``nbytes`` of decoded Draco/meshopt data to ``IngestLimits.max_decoded_bytes``."""
        cap = self.limits.max_decoded_bytes
        cap = 16 * self.limits.max_bytes if cap is None else cap
        self._decoded_bytes += int(nbytes)
        if self._decoded_bytes > cap:
            raise _err(
                "decoded_too_large",
                f"'{self.label}': {what} brings its decompressed geometry to {self._decoded_bytes} bytes; "
                f"the limit is {cap} bytes",
            )

    def _meshopt_view(self, view_idx: int, view: dict, ext: dict) -> np.ndarray:
        """(count * byteStride,) uint8 decoded contents of a meshopt-compressed bufferView (cached)."""
        if view_idx in self._meshopt_views:
            return self._meshopt_views[view_idx]
        name = next(n for n in _gc.MESHOPT_EXTENSIONS if n in ext)
        what_v = f"bufferViews[{view_idx}] {name}"
        try:
            spec = _gc.meshopt_view(name, ext[name], view)
        except _gc.CompressionError as exc:
            raise _invalid(f"bufferViews[{view_idx}]: {exc}") from exc
        self._count_decoded(spec.decoded_bytes, what_v)  # before decoding: count * byteStride is known
        buf = self._buffer(spec.buffer, what_v)
        end = spec.byte_offset + spec.byte_length
        if end > buf.size:
            raise _invalid(
                f"{what_v} (bytes {spec.byte_offset}..{end}) runs past the end of buffer {spec.buffer} "
                f"({buf.size} bytes)"
            )
        try:
            data = _gc.decode_meshopt(buf[spec.byte_offset : end], spec)
        except _gc.CompressionError as exc:
            raise _invalid(f"{what_v}: {exc}") from exc
        self._meshopt_views[view_idx] = data
        return data

    def _draco_primitive(self, prim: dict, what: str) -> dict:
        """Decode a ``KHR_draco_mesh_compression`` primitive into the accessors it names.

        The decoded faces and attributes become the cached values of the primitive's ``indices`` and
        attribute accessors (their own ``bufferView``/``sparse`` ignored, as the extension requires:
        Draco wins over an uncompressed fallback), so every later step reads them like any accessor.
        Returns the primitive to read: itself, or a copy with ``mode`` 4 for a TRIANGLE_STRIP (Draco
        decodes triangle lists). Primitives without the extension are returned unchanged.
        """
        ext = self._exts(prim).get("KHR_draco_mesh_compression")
        if ext is None:
            return prim
        what_d = f"{what} KHR_draco_mesh_compression"
        if not isinstance(ext, dict) or not isinstance(ext.get("attributes"), dict):
            raise _invalid(f"{what_d} needs a 'bufferView' and an 'attributes' object")
        mode = prim.get("mode", 4)
        if mode not in (4, 5):
            raise _invalid(f"{what_d}: mode must be TRIANGLES or TRIANGLE_STRIP, not {mode!r}")
        if "indices" not in prim:
            raise _invalid(f"{what_d}: the primitive needs an 'indices' accessor for the decoded faces")
        view_idx = ext.get("bufferView")
        geom = self._draco.get(view_idx) if _is_int(view_idx) else None
        if geom is None:
            raw, _ = self._view_bytes(view_idx, what_d)
            try:
                geom = _gc.decode_draco(raw)
            except _gc.CompressionError as exc:
                raise _invalid(f"{what_d}: {exc}") from exc
            self._count_decoded(geom.nbytes, what_d)
            self._draco[view_idx] = geom
        attrs = prim["attributes"]
        targets: dict[int, np.ndarray] = {}
        try:
            for sem, uid in ext["attributes"].items():
                if sem not in attrs:
                    raise _gc.CompressionError(f"attribute {sem} is not one of the primitive's attributes")
                if not _is_int(uid) or uid not in geom.attributes:
                    raise _gc.CompressionError(f"attribute {sem}: the Draco data has no attribute with id {uid!r}")
                acc = self._item("accessors", attrs[sem], what_d)
                dtype = _lookup(_COMPONENT_DTYPES, acc.get("componentType"))
                ncomp = _lookup(_TYPE_SIZES, acc.get("type"))
                if dtype is None or ncomp is None:
                    raise _gc.CompressionError(f"attribute {sem}: accessors[{attrs[sem]}] has a bad type")
                targets[attrs[sem]] = _gc.draco_attribute_as(
                    geom.attributes[uid], dtype, ncomp, bool(acc.get("normalized")), geom.kinds.get(uid, -1)
                )
        except _gc.CompressionError as exc:
            raise _invalid(f"{what_d}: {exc}") from exc
        idx_acc = self._item("accessors", prim["indices"], what_d)
        declared = idx_acc.get("count")
        if idx_acc.get("componentType") not in _INDEX_COMPONENTS or not _is_int(declared):
            raise _invalid(f"{what_d}: index accessors[{prim['indices']}] must be SCALAR unsigned integers")
        if geom.faces.size > declared:  # the triangle budget was planned from the declared count
            raise _invalid(
                f"{what_d} decodes to {geom.faces.shape[0]} triangles, more than its indices accessor "
                f"declares ({declared} indices)"
            )
        idt = _COMPONENT_DTYPES[idx_acc["componentType"]].newbyteorder("=")
        if geom.faces.size and int(geom.faces.max()) > np.iinfo(idt).max:
            raise _invalid(f"{what_d}: the decoded indices do not fit the indices accessor's {idt.name}")
        faces = geom.faces.reshape(-1, 1).astype(idt)
        faces.setflags(write=False)
        targets[prim["indices"]] = faces
        self._accessors.update(targets)  # refilled before every read: accessors may be shared
        return prim if mode == 4 else {**prim, "mode": 4}

    def _strided(
        self, raw: np.ndarray, offset, count: int, dtype: np.dtype, ncomp: int, stride: int | None, what: str
    ) -> np.ndarray:
        """(count, ncomp) copy of elements laid out in ``raw`` from ``offset`` every ``stride`` bytes."""
        if not _is_int(offset) or offset < 0:
            raise _invalid(f"{what} byteOffset must be a non-negative integer")
        elem = dtype.itemsize * ncomp
        stride = stride or elem
        if stride < elem:
            raise _invalid(f"{what} byteStride {stride} is smaller than its element ({elem} bytes)")
        need = offset + stride * (count - 1) + elem
        if need > raw.size:
            raise _invalid(f"{what} needs {need} bytes but its buffer view has {raw.size}")
        window = np.ascontiguousarray(raw[offset : offset + need])
        arr = np.ndarray((count, ncomp), dtype=dtype, buffer=window, offset=0, strides=(stride, dtype.itemsize))
        return np.array(arr, dtype=dtype.newbyteorder("="), copy=True)

    def accessor(self, idx, what: str) -> np.ndarray:
        """Raw accessor values, (count, n) in the accessor's component dtype (sparse applied).

        ``n`` is 1/2/3/4 for SCALAR/VEC2/VEC3/VEC4 and 4/9/16 for float MAT2/3/4 (column-major).
        """
        if _is_int(idx) and idx in self._accessors:
            return self._accessors[idx]
        acc = self._item("accessors", idx, what)
        what_a = f"accessors[{idx}]"
        dtype = _lookup(_COMPONENT_DTYPES, acc.get("componentType"))
        if dtype is None:
            raise _invalid(f"{what_a} has unknown componentType {acc.get('componentType')!r}")
        ncomp = _lookup(_TYPE_SIZES, acc.get("type"))
        if ncomp is None:
            raise _invalid(f"{what_a} has unknown type {acc.get('type')!r}")
        if acc["type"].startswith("MAT") and dtype.kind != "f":
            raise _err("unsupported", f"{what_a}: integer matrices (with column padding) are not supported")
        count = acc.get("count")
        if not _is_int(count) or count < 1:
            raise _invalid(f"{what_a} count must be a positive integer")
        view_idx = acc.get("bufferView")
        if view_idx is None:
            nbytes = count * ncomp * dtype.itemsize
            if nbytes > self.limits.max_bytes:  # no more than an upload could hold
                raise _err(
                    "too_large", f"{what_a} declares {nbytes} bytes of zeros; the limit is {self.limits.max_bytes}"
                )
            out = np.zeros((count, ncomp), dtype.newbyteorder("="))
        else:
            raw, view = self._view_bytes(view_idx, what_a)
            stride = view.get("byteStride")
            if stride is not None and (not _is_int(stride) or stride < 1):
                raise _invalid(f"bufferViews[{view_idx}].byteStride must be a positive integer")
            out = self._strided(raw, acc.get("byteOffset", 0), count, dtype, ncomp, stride, what_a)
        sparse = acc.get("sparse")
        if sparse is not None:
            out = self._apply_sparse(out, sparse, dtype, ncomp, what_a)
        out.setflags(write=False)
        self._accessors[idx] = out
        return out

    def _apply_sparse(self, out: np.ndarray, sparse, dtype, ncomp: int, what: str) -> np.ndarray:
        if (
            not isinstance(sparse, dict)
            or not isinstance(sparse.get("indices"), dict)
            or not isinstance(sparse.get("values"), dict)
        ):
            raise _invalid(f"{what}.sparse needs 'count', 'indices' and 'values'")
        n = sparse.get("count")
        if not _is_int(n) or not 1 <= n <= out.shape[0]:
            raise _invalid(f"{what}.sparse.count must be between 1 and the accessor count")
        ind, val = sparse["indices"], sparse["values"]
        idt = _lookup(_COMPONENT_DTYPES, ind.get("componentType"))
        if ind.get("componentType") not in _INDEX_COMPONENTS:
            raise _invalid(f"{what}.sparse.indices componentType must be an unsigned integer type")
        raw_i, _ = self._view_bytes(ind.get("bufferView"), f"{what}.sparse.indices")
        indices = self._strided(raw_i, ind.get("byteOffset", 0), n, idt, 1, None, f"{what}.sparse.indices")[:, 0]
        raw_v, _ = self._view_bytes(val.get("bufferView"), f"{what}.sparse.values")
        values = self._strided(raw_v, val.get("byteOffset", 0), n, dtype, ncomp, None, f"{what}.sparse.values")
        if indices.size and int(indices.max()) >= out.shape[0]:
            raise _invalid(f"{what}.sparse.indices reach {int(indices.max())}, past the accessor count {out.shape[0]}")
        out = out.copy()
        out[indices.astype(np.int64)] = values
        return out

    def accessor_float(self, idx, what: str, ncomp: tuple[int, ...] | None = None) -> np.ndarray:
        """Accessor as float32 (count, n), integer components normalized per the spec when ``normalized``."""
        acc = self._item("accessors", idx, what)
        arr = self.accessor(idx, what)
        if ncomp is not None and arr.shape[1] not in ncomp:
            raise _invalid(
                f"{what} uses accessors[{idx}] of type {acc.get('type')}, "
                f"expected {'/'.join(map(str, ncomp))} components"
            )
        if arr.dtype.kind == "f":
            return arr.astype(np.float32, copy=False)
        if acc.get("normalized"):
            info = np.iinfo(arr.dtype)
            f = arr.astype(np.float32) / np.float32(info.max)
            return np.maximum(f, -1.0) if info.min < 0 else f  # signed: max(c / max, -1)
        return arr.astype(np.float32)

    def indices(self, idx, n_vertices: int, what: str) -> np.ndarray:
        """Index accessor as (n,) int64, range-checked; primitive restart values are invalid glTF."""
        acc = self._item("accessors", idx, what)
        if acc.get("componentType") not in _INDEX_COMPONENTS or acc.get("type") != "SCALAR":
            raise _invalid(f"{what}: index accessors[{idx}] must be SCALAR unsigned byte/short/int")
        raw = self.accessor(idx, what)[:, 0]
        if raw.size and np.any(raw == np.iinfo(raw.dtype).max):
            raise _invalid(
                f"{what}: index accessors[{idx}] holds the primitive restart value {np.iinfo(raw.dtype).max}, "
                "which glTF forbids"
            )
        out = raw.astype(np.int64)
        if out.size and int(out.max()) >= n_vertices:
            raise _invalid(f"{what}: index {int(out.max())} is out of range for {n_vertices} vertices")
        return out

    # ------------------------------------------------------------------ images
    def _image_source(self, img_idx: int) -> io.BytesIO | Path:
        img = self._item("images", img_idx, "a texture")
        if "uri" in img:
            kind, rel = _split_uri(img["uri"], f"image {img_idx}")
            if kind == "data":
                return io.BytesIO(_decode_data_uri(rel, f"image {img_idx}"))
            return self.files.path(rel, f"image {img_idx}")
        if "bufferView" in img:
            raw, _ = self._view_bytes(img["bufferView"], f"images[{img_idx}]")
            return io.BytesIO(raw.tobytes())
        raise _invalid(f"images[{img_idx}] has neither a uri nor a bufferView")

    def load_image(self, img_idx: int) -> np.ndarray:
        """Decode one image to (H, W, 4) uint8 RGBA, checking its header dimensions first."""
        src = self._image_source(img_idx)
        name = f"image {img_idx}"
        img = self.g["images"][img_idx]
        if isinstance(img.get("uri"), str) and not img["uri"].startswith("data:"):
            name += f" '{urllib.parse.unquote(img['uri'])}'"
        try:
            with _pywarnings.catch_warnings():
                _pywarnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with Image.open(src, formats=["PNG", "JPEG", "WEBP"]) as im:
                    w, h = im.size
                    if w * h > self.limits.max_image_pixels:
                        raise _err(
                            "image_too_large",
                            f"{name} is {w}x{h} pixels; the limit is {self.limits.max_image_pixels} pixels",
                        )
                    cap = self.limits.max_total_image_pixels
                    if cap is not None and self._image_pixels + w * h > cap:
                        raise _err(
                            "image_too_large",
                            f"the images decode to more than {cap} pixels in all ({name} is {w}x{h}); "
                            "use smaller textures",
                        )
                    self._image_pixels += w * h
                    im.seek(0)
                    im.load()
                    if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                        a = np.asarray(im).astype(np.float64)
                        scale = 255.0 / 65535.0
                        im = Image.fromarray(np.clip(np.rint(a * scale), 0, 255).astype(np.uint8), "L")
                    elif im.mode == "F":
                        a = np.asarray(im)
                        im = Image.fromarray(np.clip(np.rint(np.nan_to_num(a) * 255.0), 0, 255).astype(np.uint8), "L")
                    rgba = np.array(im.convert("RGBA"), dtype=np.uint8)
        except IngestError:
            raise
        except Image.DecompressionBombError as exc:
            raise _err("image_too_large", f"{name} is too large to decode ({exc})") from exc
        except Image.UnidentifiedImageError as exc:  # its message names the file object or temp path: not shown
            lfs = " (it is a Git LFS pointer: fetch the real file with git lfs pull)" if _is_lfs(src) else ""
            raise _err("invalid_image", f"{name} is not a PNG, JPEG or WebP image{lfs}") from exc
        except Exception as exc:  # truncated data, unsupported modes
            raise _err(
                "invalid_image", f"{name} is not a readable PNG, JPEG or WebP image ({type(exc).__name__}: {exc})"
            ) from exc
        if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.size == 0:
            raise _err("invalid_image", f"{name} decoded to an empty image")
        return rgba

    # ------------------------------------------------------------------ materials
    def _texref(self, info, what: str) -> _TexRef | None:
        if info is None:
            return None
        if not isinstance(info, dict):
            raise _invalid(f"{what} must be a textureInfo object")
        tex_idx = info.get("index")
        self._item("textures", tex_idx, what)
        texcoord = info.get("texCoord", 0)
        if not _is_int(texcoord) or texcoord < 0:
            raise _invalid(f"{what}.texCoord must be a non-negative integer")
        transform = None
        tt = self._exts(info).get("KHR_texture_transform")
        if isinstance(tt, dict):
            transform = _texture_transform_matrix(tt, what)
            tc = tt.get("texCoord")
            if tc is not None:
                if not _is_int(tc) or tc < 0:
                    raise _invalid(f"{what} KHR_texture_transform texCoord must be a non-negative integer")
                texcoord = tc
        return _TexRef(tex_idx, texcoord, transform)

    def _texture_image(self, tex_idx: int) -> int | None:
        """glTF texture -> image index (EXT_texture_webp preferred), None when no decodable source."""
        tex = self._item("textures", tex_idx, "a material")
        ext = self._exts(tex)
        for key in ("EXT_texture_webp",):
            e = ext.get(key)
            if isinstance(e, dict) and "source" in e:
                self._item("images", e["source"], f"textures[{tex_idx}].{key}")
                return e["source"]
        src = tex.get("source")
        if src is None:
            self._counts["texture(s) without a PNG/JPEG/WebP source ignored"] += 1
            return None
        self._item("images", src, f"textures[{tex_idx}]")
        return src

    def build_materials(self) -> tuple[list[dict], list[np.ndarray], list[_TexRef | None]]:
        """Materials in glTF order, the decoded textures they use, and each material's UV source.

        Returns
        -------
        materials : list of dict
            See :mod:`workers.scene`; texture indices point into ``textures``.
        textures : list of (H, W, 4) uint8
            Images used by base colour or emissive slots, in first-use order, each decoded once.
        uv_refs : list of _TexRef or None
            Per material: the texture slot whose UV set (and transform) ``uv0`` carries.
        """
        materials: list[dict] = []
        textures: list[np.ndarray] = []
        image_slot: dict[int, int] = {}
        uv_refs: list[_TexRef | None] = []
        alpha_modes: Counter = Counter()

        def tex_index(ref: _TexRef | None) -> int | None:
            if ref is None:
                return None
            img = self._texture_image(ref.texture)
            if img is None:
                return None
            if img not in image_slot:
                image_slot[img] = len(textures)
                textures.append(self.load_image(img))
            return image_slot[img]

        for i, m in enumerate(self._list("materials")):
            what = f"materials[{i}]"
            if not isinstance(m, dict):
                raise _invalid(f"{what} is not an object")
            ext = self._exts(m)
            pbr = m.get("pbrMetallicRoughness")
            sg = ext.get("KHR_materials_pbrSpecularGlossiness")
            mr_ref = None
            if pbr is None and isinstance(sg, dict):
                # specular-glossiness: the diffuse colour is the diffuse albedo (no metallic term)
                base = _vec(sg.get("diffuseFactor"), 4, [1, 1, 1, 1], f"{what} diffuseFactor")
                base_ref = self._texref(sg.get("diffuseTexture"), f"{what}.diffuseTexture")
                metallic, roughness = 0.0, 1.0 - _num(sg.get("glossinessFactor"), 1.0, f"{what} glossinessFactor")
            else:
                # [glTF] 3.9.2: a material without pbrMetallicRoughness has metallic 1 and roughness 1 too
                pbr = pbr if isinstance(pbr, dict) else {}
                base = _vec(pbr.get("baseColorFactor"), 4, [1, 1, 1, 1], f"{what} baseColorFactor")
                base_ref = self._texref(pbr.get("baseColorTexture"), f"{what}.baseColorTexture")
                metallic = _num(pbr.get("metallicFactor"), 1.0, f"{what} metallicFactor")
                roughness = _num(pbr.get("roughnessFactor"), 1.0, f"{what} roughnessFactor")
                mr_ref = self._texref(pbr.get("metallicRoughnessTexture"), f"{what}.metallicRoughnessTexture")
            if not (0.0 <= metallic <= 1.0 and 0.0 <= roughness <= 1.0):
                self.warnings.append(f"{what}: metallicFactor/roughnessFactor outside [0, 1] clamped")
                metallic, roughness = min(max(metallic, 0.0), 1.0), min(max(roughness, 0.0), 1.0)
            emissive = _vec(m.get("emissiveFactor"), 3, [0, 0, 0], f"{what} emissiveFactor")
            strength_ext = ext.get("KHR_materials_emissive_strength")
            strength = _num(
                strength_ext.get("emissiveStrength") if isinstance(strength_ext, dict) else None,
                1.0,
                f"{what} emissiveStrength",
            )
            if strength < 0 or min(emissive) < 0:
                raise _err("negative_emissive", f"{what} has a negative emissive "
                           f"{'strength' if strength < 0 else 'factor'}: emitted light cannot be negative")
            if max(emissive) * strength > MAX_EMISSIVE:
                raise _err("absurd_magnitude", f"{what} emits {max(emissive) * strength:.3g} (emissiveFactor x "
                           f"emissiveStrength); the limit is {MAX_EMISSIVE:g}")
            emissive_ref = self._texref(m.get("emissiveTexture"), f"{what}.emissiveTexture")
            double_sided = m.get("doubleSided", False)
            if not isinstance(double_sided, bool):
                raise _invalid(f"{what}.doubleSided must be true or false")
            alpha = m.get("alphaMode", "OPAQUE")
            if alpha not in ("OPAQUE", "MASK", "BLEND"):
                raise _invalid(f"{what}.alphaMode must be OPAQUE, MASK or BLEND, not {alpha!r}")
            cutoff = _num(m.get("alphaCutoff"), 0.5, f"{what} alphaCutoff")
            if cutoff < 0:
                raise _invalid(f"{what}.alphaCutoff must not be negative")
            if alpha == "BLEND":
                alpha_modes[alpha] += 1
            uv_ref = base_ref or emissive_ref or mr_ref
            for other, slot in ((emissive_ref, "emissive"), (mr_ref, "metallic-roughness")):
                if (other is not None and uv_ref is not None and other is not uv_ref
                        and (other.texcoord != uv_ref.texcoord or not _same_transform(other.transform, uv_ref.transform))):
                    self.warnings.append(f"{what}: {slot} texture sampled with the base colour texture's UVs")
            name = m.get("name")
            materials.append(
                {
                    "name": name if isinstance(name, str) else f"material_{i}",
                    "base_color": base,
                    "base_color_texture": tex_index(base_ref),
                    "emissive": [e * strength for e in emissive],
                    "emissive_texture": tex_index(emissive_ref),
                    "double_sided": double_sided,
                    "metallic": metallic,
                    "roughness": roughness,
                    "metallic_roughness_texture": tex_index(mr_ref),
                    "alpha_mode": alpha,
                    "alpha_cutoff": cutoff,
                }
            )
            uv_refs.append(uv_ref)
        for mode, n in sorted(alpha_modes.items()):
            self.warnings.append(
                f"alphaMode BLEND on {n} material{'s' * (n != 1)} baked as a cutout at alpha 0.5 "
                "(probe rays see a blended surface where its alpha is at least 0.5, and through it elsewhere)")
        return materials, textures, uv_refs

    # ------------------------------------------------------------------ nodes
    def _local_matrix(self, node: dict, i: int) -> np.ndarray:
        what = f"nodes[{i}]"
        if "matrix" in node:
            m = np.array(_vec(node["matrix"], 16, None, f"{what}.matrix")).reshape(4, 4).T  # column-major
            return m
        t = _vec(node.get("translation"), 3, [0, 0, 0], f"{what}.translation")
        q = _vec(node.get("rotation"), 4, [0, 0, 0, 1], f"{what}.rotation")
        s = _vec(node.get("scale"), 3, [1, 1, 1], f"{what}.scale")
        norm = math.sqrt(sum(x * x for x in q))
        if norm < 1e-12:
            raise _invalid(f"{what}.rotation is a zero quaternion")
        m = np.eye(4)
        m[:3, :3] = _quat_to_matrix([x / norm for x in q]) * np.array(s)[None, :]
        m[:3, 3] = t
        return m

    def world_matrices(self) -> list[np.ndarray]:
        """(4, 4) float64 world matrix of every node; rejects cycles and nodes with two parents."""
        nodes = self._list("nodes")
        parent = [-1] * len(nodes)
        for i, node in enumerate(nodes):
            if not isinstance(node, dict):
                raise _invalid(f"nodes[{i}] is not an object")
            for c in self._list("children", node):
                self._item("nodes", c, f"nodes[{i}].children")
                if parent[c] != -1 or c == i:
                    raise _invalid(f"nodes[{c}] has more than one parent or is its own child")
                parent[c] = i
        world: list[np.ndarray | None] = [None] * len(nodes)
        for root in (i for i in range(len(nodes)) if parent[i] == -1):
            stack = [(root, np.eye(4))]
            while stack:
                i, pm = stack.pop()
                world[i] = pm @ self._local_matrix(nodes[i], i)
                stack.extend((c, world[i]) for c in nodes[i].get("children", []))
        if any(w is None for w in world):
            raise _invalid("the node hierarchy has a cycle")
        return world  # type: ignore[return-value]

    def scene_nodes(self) -> list[int]:
        """Nodes of the default scene (``scene``, else scene 0, else every root), depth-first pre-order."""
        nodes = self._list("nodes")
        scenes = self._list("scenes")
        if scenes:
            s_idx = self.g.get("scene", 0)
            scene = self._item("scenes", s_idx, "'scene'")
            roots = self._list("nodes", scene)
            for r in roots:
                self._item("nodes", r, f"scenes[{s_idx}].nodes")
        else:
            has_parent = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])}
            roots = [i for i in range(len(nodes)) if i not in has_parent]
        order: list[int] = []
        seen: set[int] = set()
        stack = list(reversed(roots))
        while stack:
            i = stack.pop()
            if i in seen:
                raise _invalid(f"nodes[{i}] appears twice in the scene")
            seen.add(i)
            order.append(i)
            stack.extend(reversed(nodes[i].get("children", [])))
        return order

    def _instances(self, node: dict, i: int, world: np.ndarray) -> np.ndarray:
        """(K, 4, 4) world matrices of a node: its own, or one per EXT_mesh_gpu_instancing instance."""
        inst = self._exts(node).get("EXT_mesh_gpu_instancing")
        if not isinstance(inst, dict):
            return world[None]
        attrs = inst.get("attributes")
        if not isinstance(attrs, dict) or not attrs:
            raise _invalid(f"nodes[{i}] EXT_mesh_gpu_instancing needs attributes")
        what = f"nodes[{i}] EXT_mesh_gpu_instancing"
        arrays = {}
        for key, n in (("TRANSLATION", (3,)), ("ROTATION", (4,)), ("SCALE", (3,))):
            if key in attrs:
                arrays[key] = self.accessor_float(attrs[key], what, n).astype(np.float64)
        counts = {a.shape[0] for a in arrays.values()}
        if len(counts) != 1:
            raise _invalid(f"{what} attributes have different counts")
        k = counts.pop()
        t = arrays.get("TRANSLATION", np.zeros((k, 3)))
        q = arrays.get("ROTATION", np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)))
        s = arrays.get("SCALE", np.ones((k, 3)))
        qn = np.linalg.norm(q, axis=1, keepdims=True)
        if np.any(qn < 1e-12):
            raise _invalid(f"{what} has a zero rotation quaternion")
        x, y, z, w = (q / qn).T
        r = np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
            ],
            axis=1,
        )
        m = np.tile(np.eye(4), (k, 1, 1))
        m[:, :3, :3] = r * s[:, None, :]
        m[:, :3, 3] = t
        return world[None] @ m

    # ------------------------------------------------------------------ primitives
    def _triangle_indices(self, prim: dict, n_vertices: int, what: str) -> np.ndarray | None:
        """(T, 3) int64 corner indices (TRIANGLES / strip / fan), None for points and lines."""
        mode = prim.get("mode", 4)
        if not _is_int(mode) or mode not in _MODE_NAMES:
            raise _invalid(f"{what} has unknown mode {mode!r}")
        if "indices" in prim:
            idx = self.indices(prim["indices"], n_vertices, what)
        else:
            idx = np.arange(n_vertices, dtype=np.int64)
        if mode < 4:
            self._counts[f"{_MODE_NAMES[mode]} primitive(s) ignored"] += 1
            return None
        n = idx.size
        if mode == 4:
            if n % 3:
                self._counts[
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

    def _planned_triangles(self, prim: dict, what: str) -> int:
        """Upper bound on a primitive's triangle count from accessor counts only (no data read)."""
        attrs = prim.get("attributes")
        if not isinstance(attrs, dict) or "POSITION" not in attrs:
            return 0
        mode = prim.get("mode", 4)
        src = prim["indices"] if "indices" in prim else attrs["POSITION"]
        n = self._item("accessors", src, what).get("count")
        if not _is_int(n) or n < 0:
            raise _invalid(f"{what}: accessor count must be a non-negative integer")
        if mode == 4:
            return n // 3
        if mode in (5, 6):
            return max(n - 2, 0)
        return 0

    def _vertex_attr(self, acc_idx, n_vertices: int, sel: np.ndarray | None, ncomp: int, what: str) -> np.ndarray:
        """A per-vertex float attribute, length-checked against POSITION, restricted to vertices ``sel``."""
        arr = self.accessor_float(acc_idx, what, (ncomp,))
        if arr.shape[0] != n_vertices:
            raise _invalid(f"{what} has {arr.shape[0]} elements, POSITION {n_vertices}")
        return arr if sel is None else arr[sel]

    def _morphed(
        self, prim: dict, base: np.ndarray, key: str, weights: list[float], n_vertices: int, sel, what: str
    ) -> np.ndarray:
        """Attribute ``key`` (already restricted to ``sel``) plus morph deltas at ``weights`` ([glTF] 3.7.2.2)."""
        targets = self._list("targets", prim)
        if not targets or not any(weights):
            return base
        out = base.astype(np.float64)
        for t, w in zip(targets, weights, strict=True):
            if w and isinstance(t, dict) and key in t:
                out += w * self._vertex_attr(t[key], n_vertices, sel, out.shape[1], f"{what} morph target {key}")
        return out

    def _skin_matrices(
        self, node: dict, node_idx: int, prim: dict, world: list[np.ndarray], n_vertices: int, sel, what: str
    ) -> np.ndarray | None:
        """(V, 4, 4) per-vertex skinning matrices at the static pose, or None when not skinned.

        ``sum_k w_k * world(joint_k) @ inverseBind_k`` ([glTF] 3.7.3); the mesh node's own transform
        is ignored, as the spec requires.
        """
        if "skin" not in node:
            return None
        attrs = prim["attributes"]
        if "JOINTS_0" not in attrs or "WEIGHTS_0" not in attrs:
            return None
        skin = self._item("skins", node["skin"], f"nodes[{node_idx}].skin")
        joints = self._list("joints", skin)
        if not joints:
            raise _invalid(f"skins[{node['skin']}] has no joints")
        for j in joints:
            self._item("nodes", j, f"skins[{node['skin']}].joints")
        if "inverseBindMatrices" in skin:
            ibm = self.accessor_float(skin["inverseBindMatrices"], "inverseBindMatrices", (16,)).astype(np.float64)
            if ibm.shape[0] < len(joints):
                raise _invalid(f"skins[{node['skin']}] has fewer inverseBindMatrices than joints")
            ibm = ibm[: len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        else:
            ibm = np.tile(np.eye(4), (len(joints), 1, 1))
        joint_m = np.stack([world[j] for j in joints]) @ ibm
        n_used = n_vertices if sel is None else sel.size
        skin_m = np.zeros((n_used, 4, 4))
        total_w = np.zeros(n_used)
        set_i = 0
        while f"JOINTS_{set_i}" in attrs and f"WEIGHTS_{set_i}" in attrs:
            jacc = self.accessor(attrs[f"JOINTS_{set_i}"], what)
            if jacc.dtype.kind not in "ui" or jacc.shape != (n_vertices, 4):
                raise _invalid(f"{what}: JOINTS_{set_i} must be VEC4 unsigned integers, one per vertex")
            wts = self._vertex_attr(attrs[f"WEIGHTS_{set_i}"], n_vertices, sel, 4, f"{what} WEIGHTS_{set_i}")
            wts = wts.astype(np.float64)
            jidx = (jacc if sel is None else jacc[sel]).astype(np.int64)
            if int(jidx.max()) >= len(joints) or int(jidx.min()) < 0:
                raise _invalid(f"{what}: JOINTS_{set_i} refers to a joint the skin does not have")
            for k in range(4):
                skin_m += wts[:, k, None, None] * joint_m[jidx[:, k]]
            total_w += wts.sum(axis=1)
            set_i += 1
        ok = total_w > 1e-12
        skin_m[ok] /= total_w[ok, None, None]
        skin_m[~ok] = world[node_idx]  # unweighted vertices keep the node transform
        return skin_m

    # ------------------------------------------------------------------ build
    def build(self) -> NormalizedScene:
        self._check_asset()
        self._check_extensions()
        self._check_uris()
        world = self.world_matrices()
        order = self.scene_nodes()
        nodes = self._list("nodes")
        meshes = self._list("meshes")

        # Plan: triangle budget and TEXCOORD_1 coverage from the JSON alone, before reading geometry.
        planned = 0
        all_uv1 = True
        any_uv1 = False
        any_color = False
        draws: list[tuple[int, int, int, dict]] = []  # (node, mesh, primitive index, primitive)
        for ni in order:
            node = nodes[ni]
            if "mesh" not in node:
                continue
            mesh = self._item("meshes", node["mesh"], f"nodes[{ni}]")
            k = 1
            inst = self._exts(node).get("EXT_mesh_gpu_instancing")
            if isinstance(inst, dict) and isinstance(inst.get("attributes"), dict) and inst["attributes"]:
                first = next(iter(inst["attributes"].values()))
                k = self._item("accessors", first, f"nodes[{ni}] EXT_mesh_gpu_instancing").get("count", 0)
                if not _is_int(k) or k < 0:
                    raise _invalid(f"nodes[{ni}] EXT_mesh_gpu_instancing count must be an integer")
            prims = self._list("primitives", mesh)
            if not prims:
                raise _invalid(f"meshes[{node['mesh']}] has no primitives")
            for pi, prim in enumerate(prims):
                what = f"meshes[{node['mesh']}].primitives[{pi}]"
                if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                    raise _invalid(f"{what} needs an 'attributes' object")
                # Draco primitives are planned from their indices accessor's declared count; the
                # decoded faces are checked against it (_draco_primitive)
                n = self._planned_triangles(prim, what) * k
                planned += n
                if n and "TEXCOORD_1" not in prim["attributes"]:
                    all_uv1 = False
                if n and "TEXCOORD_1" in prim["attributes"]:
                    any_uv1 = True
                if n and "COLOR_0" in prim["attributes"]:
                    any_color = True
                draws.append((ni, node["mesh"], pi, prim))
        if planned > self.limits.max_triangles:
            raise _err(
                "too_many_triangles", f"the scene has {planned} triangles; the limit is {self.limits.max_triangles}"
            )

        materials, textures, uv_refs = self.build_materials()
        default_material: int | None = None

        tri_out = np.empty((planned, 3, 3), np.float32)
        nrm_out = np.empty((planned, 3, 3), np.float32)
        uv0_out = np.zeros((planned, 3, 2), np.float32)
        # TEXCOORD_1 is kept per triangle even when only some primitives have it (zeros elsewhere): it
        # lands in ``uv1`` when every primitive has it, else in ``uv1_partial``; ``uv1_chart`` says which
        # node's UV1 space (lightmap) each triangle lives in, -1 for triangles without TEXCOORD_1.
        uv1_out = np.zeros((planned, 3, 2), np.float32) if any_uv1 and planned else None
        chart_out = np.full((planned,), -1, np.int32) if uv1_out is not None else None
        mat_out = np.empty((planned,), np.int32)
        # COLOR_0 per triangle corner (RGBA, linear), ones on primitives without it; None when none has it
        color_out = np.ones((planned, 3, 4), np.float32) if any_color and planned else None
        cursor = 0

        for ni, mi, pi, prim in draws:
            node = nodes[ni]
            mesh = meshes[mi]
            what = f"meshes[{mi}].primitives[{pi}]"
            attrs = prim["attributes"]
            if "POSITION" not in attrs:
                self._counts["primitive(s) without POSITION skipped"] += 1
                continue
            prim = self._draco_primitive(prim, what)  # KHR_draco_mesh_compression -> its accessors
            pos = self.accessor_float(attrs["POSITION"], f"{what} POSITION", (3,))
            n_vertices = pos.shape[0]
            tri = self._triangle_indices(prim, n_vertices, what)
            if tri is None:
                continue
            keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
            if not keep.all():
                self._counts["degenerate triangle(s) (repeated vertex index) dropped"] += int((~keep).sum())
                tri = tri[keep]
            if tri.shape[0] == 0:
                continue
            sel = None
            if n_vertices > 3 * tri.shape[0]:  # mostly unreferenced vertices: work on the used ones only
                sel, inverse = np.unique(tri, return_inverse=True)
                tri = inverse.reshape(tri.shape)
                pos = pos[sel]

            # material and the UV set its textures sample
            if "material" in prim:
                self._item("materials", prim["material"], what)
                mat = prim["material"]
                uv_ref = uv_refs[mat]
            else:
                if default_material is None:
                    default_material = len(materials)
                    materials.append(
                        {
                            "name": "default",
                            "base_color": [1.0, 1.0, 1.0, 1.0],
                            "base_color_texture": None,
                            "emissive": [0.0, 0.0, 0.0],
                            "emissive_texture": None,
                            "double_sided": False,
                            # [glTF] 3.9.6 default material: metallic 1, roughness 1 (a rough white metal)
                            "metallic": 1.0,
                            "roughness": 1.0,
                            "metallic_roughness_texture": None,
                            "alpha_mode": "OPAQUE",
                            "alpha_cutoff": 0.5,
                        }
                    )
                    self.warnings.append(
                        "primitives without a material use glTF's default material (a rough white metal: "
                        "diffuse albedo 0, its specular reflection baked as albedo 0.5)")
                mat = default_material
                uv_ref = None
            uv_set = uv_ref.texcoord if uv_ref is not None else 0
            color = None
            if "COLOR_0" in attrs:
                # [glTF] 3.7.2.1: COLOR_0 (VEC3/VEC4 float, normalized ubyte/ushort) multiplies the base colour
                color = self.accessor_float(attrs["COLOR_0"], f"{what} COLOR_0", (3, 4))
                if color.shape[0] != n_vertices:
                    raise _invalid(f"{what} COLOR_0 has {color.shape[0]} elements, POSITION {n_vertices}")
                color = color if sel is None else color[sel]
                if color.shape[1] == 3:
                    color = np.concatenate([color, np.ones((color.shape[0], 1), np.float32)], axis=1)
                if not np.isfinite(color).all():
                    raise _err("non_finite", f"{what} has NaN or infinite COLOR_0 values")
                if (color < 0).any():
                    raise _invalid(f"{what} COLOR_0 has negative values")

            # morph targets at default weights ([glTF] 3.7.2.2), then skin or node transforms
            n_targets = len(self._list("targets", prim))
            weights: list[float] = []
            if n_targets:
                w = node.get("weights", mesh.get("weights"))
                weights = _vec(w, n_targets, [0.0] * n_targets, f"{what} morph weights")
            pos64 = self._morphed(prim, pos, "POSITION", weights, n_vertices, sel, what).astype(np.float64)
            nrm = None
            if "NORMAL" in attrs:
                nrm = self._vertex_attr(attrs["NORMAL"], n_vertices, sel, 3, f"{what} NORMAL")
                nrm = self._morphed(prim, nrm, "NORMAL", weights, n_vertices, sel, what).astype(np.float64)

            uv = None
            uv_key = f"TEXCOORD_{uv_set}"
            if uv_key in attrs:
                uv = self._vertex_attr(attrs[uv_key], n_vertices, sel, 2, f"{what} {uv_key}")
                uv = self._morphed(prim, uv, uv_key, weights, n_vertices, sel, what)
                if uv_ref is not None and uv_ref.transform is not None:  # [KHR_texture_transform]
                    uv = uv.astype(np.float64) @ uv_ref.transform[:, :2].T + uv_ref.transform[:, 2]
            elif uv_ref is not None:
                self._counts[f"primitive(s) lacking the {uv_key} their material's texture needs (UVs set to 0)"] += 1
            if uv_set != 0:
                self._counts[f"primitive(s) whose uv0 holds {uv_key} (the UV set their material's textures use)"] += 1
            uv1 = None
            if uv1_out is not None and "TEXCOORD_1" in attrs:
                uv1 = self._vertex_attr(attrs["TEXCOORD_1"], n_vertices, sel, 2, f"{what} TEXCOORD_1")

            skin_m = self._skin_matrices(node, ni, prim, world, n_vertices, sel, what)
            mats = self._instances(node, ni, world[ni]) if skin_m is None else None
            out = (tri_out, nrm_out, uv0_out, uv1_out, mat_out, color_out)
            start = cursor
            cursor = self._emit(out, cursor, pos64, nrm, skin_m, mats, tri, uv, uv1, mat, f"{what} (node {ni})",
                                color=color)
            if uv1 is not None:
                chart_out[start:cursor] = ni

        if cursor == 0:
            dropped = {k: n for k, n in self._counts.items() if k.endswith("primitive(s) ignored")}
            if dropped:
                shown = ", ".join(f"{n} {k.split()[0]}" for k, n in dropped.items())
                raise _err(
                    "unsupported",
                    f"'{self.label}' holds only point and line primitives ({shown}); " "a bake needs triangles",
                )
            why = "; ".join(_plural(n, k) for k, n in self._counts.items())
            raise _err(
                "no_triangles", f"'{self.label}' has no triangles in its scene to bake" + (f" ({why})" if why else "")
            )
        self._check_extent(tri_out[:cursor])
        if any_uv1 and not all_uv1:
            # ``uv1`` stays None (it promises every triangle); the coordinates live on in uv1_partial
            self.warnings.append("TEXCOORD_1 dropped: not every primitive has it")

        lights = self.build_lights(order, world)
        cameras = build_cameras(self.g, order, world)   # the glTF's own cameras (workers.gltf_cameras)
        if self._list("animations"):
            n = len(self._list("animations"))
            self.warnings.append(f"{n} animation{'s' * (n != 1)} ignored (static pose baked)")
        if isinstance(self.files, _ZipFiles) and self.files.case_fixed:
            self.warnings.append("URIs matched zip members by case only: " + ", ".join(self.files.case_fixed))
        for what, n in self._counts.items():
            self.warnings.append(_plural(n, what))

        def trim(a):
            return a if a is None or cursor == planned else a[:cursor].copy()

        return NormalizedScene(
            triangles=trim(tri_out),
            normals=trim(nrm_out),
            uv0=trim(uv0_out),
            material=trim(mat_out),
            materials=materials,
            lights=lights,
            textures=textures,
            uv1=trim(uv1_out) if all_uv1 else None,
            warnings=list(self.warnings),
            uv1_partial=None if all_uv1 else trim(uv1_out),
            uv1_chart=trim(chart_out),
            colors=trim(color_out),
            cameras=cameras,
        )

    _BLOCK = 1 << 19  # corners per processing block: bounds the float64 temporaries (~40 MB each)

    def _check_extent(self, tris: np.ndarray) -> None:
        """Refuse a scene with nothing to bake in it: all triangles in one point (``zero_extent``), or every
        triangle of zero area, on lines or points (``degenerate_triangles``). Probe spacing follows the extent,
        so such a scene bakes garbage (spacing 0) rather than failing."""
        pts = tris.reshape(-1, 3)
        lo, hi = pts.min(axis=0).astype(np.float64), pts.max(axis=0).astype(np.float64)
        diag = float(np.linalg.norm(hi - lo))
        if diag < MIN_EXTENT:
            raise _err("zero_extent", f"'{self.label}': all {_plural(tris.shape[0], 'triangle(s)')} lie in one "
                       f"point (the bounds' diagonal is {diag:.3g} m; at least {MIN_EXTENT:g} m is needed)")
        for t0 in range(0, tris.shape[0], self._BLOCK // 3):
            t = tris[t0 : t0 + self._BLOCK // 3].astype(np.float64)
            e1, e2, e3 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], t[:, 2] - t[:, 1]
            twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
            longest2 = np.maximum(np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1)), (e3 * e3).sum(1))
            if np.any(twice_area > DEGENERATE_SINE * longest2):
                return
        raise _err("degenerate_triangles", f"'{self.label}': every one of its "
                   f"{_plural(tris.shape[0], 'triangle(s)')} has zero area (its corners lie on a line or in a point)")

    def _emit(
        self,
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
                wn_all = np.einsum("vij,vj->vi", _cofactor(m3) * np.sign(det_v)[:, None, None], nrm)
            groups = [(wp_all[None], None if wn_all is None else wn_all[None], det_v[None])]
        else:
            k_block = max(1, self._BLOCK // max(pos.shape[0], n_tri * 3, 1))
            groups = (
                self._instance_group(mats[k0 : k0 + k_block], pos, nrm) for k0 in range(0, mats.shape[0], k_block)
            )
        t_block = max(1, self._BLOCK // 3)
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
                if not np.isfinite(p32).all():
                    raise _err("non_finite", f"{what} has NaN or infinite world-space positions")
                reach = float(np.abs(p).max(initial=0.0))
                if reach > MAX_COORD:
                    raise _err("absurd_magnitude", f"{what} has world-space positions {reach:.3g} m from the "
                               f"origin; the limit is {MAX_COORD:g} m (check its node transforms' scale and its "
                               "POSITION data)")
                geo, geo_ok = _normalize_rows(np.cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]))
                geo[~geo_ok] = (0.0, 1.0, 0.0)  # zero-area triangle: any unit normal will do
                normals = np.broadcast_to(geo[..., None, :], p.shape)
                if wn is not None:
                    vn, vn_ok = _normalize_rows(wn[kk, corners])
                    if not vn_ok.all():
                        self._counts["vertex normal(s) that were zero or NaN replaced by face normals"] += int(
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
                        raise _err("non_finite", f"{what} has NaN or infinite {name} coordinates")
                    dst[cursor:stop] = c.reshape(-1, 3, c.shape[-1])
                cursor = stop
        return cursor

    @staticmethod
    def _instance_group(mats: np.ndarray, pos: np.ndarray, nrm: np.ndarray | None):
        """World positions (k, V, 3), normals (k, V, 3) or None and determinants (k, 1) for k instances."""
        m3 = mats[:, :3, :3]
        det = np.linalg.det(m3)
        wp = np.einsum("kij,vj->kvi", m3, pos) + mats[:, None, :3, 3]
        wn = None
        if nrm is not None:
            wn = np.einsum("kij,vj->kvi", _cofactor(m3) * np.sign(det)[:, None, None], nrm)
        return wp, wn, det[:, None]

    # ------------------------------------------------------------------ lights
    def build_lights(self, order: list[int], world: list[np.ndarray]) -> list[dict]:
        """KHR_lights_punctual lights of the scene's nodes, world space ([KHR_lights_punctual]).

        ``position`` is the node's world translation (None for directional lights); ``direction`` is
        the world transform applied to the local -Z axis, normalized (None for point lights).
        """
        ext = self._exts(self.g).get("KHR_lights_punctual")
        defs = ext.get("lights", []) if isinstance(ext, dict) else []
        if not isinstance(defs, list):
            raise _invalid("KHR_lights_punctual.lights must be an array")
        nodes = self._list("nodes")
        lights = []
        for ni in order:
            ref = self._exts(nodes[ni]).get("KHR_lights_punctual")
            if not isinstance(ref, dict):
                continue
            li = ref.get("light")
            if not _is_int(li) or not 0 <= li < len(defs) or not isinstance(defs[li], dict):
                raise _invalid(f"nodes[{ni}] refers to KHR_lights_punctual light {li!r}, which does not exist")
            d = defs[li]
            what = f"KHR_lights_punctual.lights[{li}]"
            kind = d.get("type")
            if kind not in ("point", "spot", "directional"):
                raise _invalid(f"{what} has unknown type {kind!r}")
            color = _vec(d.get("color"), 3, [1, 1, 1], f"{what}.color")
            intensity = _num(d.get("intensity"), 1.0, f"{what}.intensity")
            rng = d.get("range")
            rng = None if rng is None else _num(rng, None, f"{what}.range")
            if intensity < 0 or min(color) < 0:
                raise _err("negative_light", f"{what} has a negative {'intensity' if intensity < 0 else 'color'}: "
                                             "emitted light cannot be negative")
            if intensity > MAX_LIGHT_INTENSITY or max(color) > MAX_LIGHT_COLOR:
                raise _err("absurd_magnitude", f"{what} has intensity {intensity:.3g} and color up to "
                           f"{max(color):.3g}; the limits are {MAX_LIGHT_INTENSITY:g} and {MAX_LIGHT_COLOR:g}")
            if rng is not None and rng <= 0:
                raise _invalid(f"{what} needs range > 0")
            inner = outer = None
            if kind == "spot":
                spot = d.get("spot", {})
                if not isinstance(spot, dict):
                    raise _invalid(f"{what}.spot must be an object")
                inner = _num(spot.get("innerConeAngle"), 0.0, f"{what}.spot.innerConeAngle")
                outer = _num(spot.get("outerConeAngle"), math.pi / 4, f"{what}.spot.outerConeAngle")
                if not 0 <= inner <= outer <= math.pi / 2 + 1e-6:
                    raise _invalid(f"{what} needs 0 <= innerConeAngle <= outerConeAngle <= pi/2")
            m = world[ni]
            position = None if kind == "directional" else [float(x) for x in m[:3, 3]]
            direction = None
            if kind != "point":
                dv, ok = _normalize_rows(m[:3, :3] @ np.array([0.0, 0.0, -1.0]))
                if not ok:
                    raise _invalid(f"nodes[{ni}] scales its {kind} light's direction to zero")
                direction = [float(x) for x in dv]
            if (position is not None and not all(map(math.isfinite, position))) or (
                direction is not None and not all(map(math.isfinite, direction))
            ):
                raise _err("non_finite", f"nodes[{ni}] puts light {li} at a NaN or infinite place")
            if position is not None and max(map(abs, position)) > MAX_COORD:
                raise _err("absurd_magnitude", f"nodes[{ni}] puts light {li} {max(map(abs, position)):.3g} m from "
                           f"the origin; the limit is {MAX_COORD:g} m")
            name = d.get("name") if isinstance(d.get("name"), str) else nodes[ni].get("name")
            lights.append(
                {
                    "name": name if isinstance(name, str) else f"light_{li}",
                    "type": kind,
                    "color": color,
                    "intensity": intensity,
                    "range": rng,
                    "position": position,
                    "direction": direction,
                    "inner_cone_angle": inner,
                    "outer_cone_angle": outer,
                }
            )
        return lights


def _is_lfs(src: io.BytesIO | Path) -> bool:
    """Whether an image source starts like a Git LFS pointer file."""
    try:
        if isinstance(src, Path):
            with open(src, "rb") as f:
                return f.read(len(_LFS_POINTER)) == _LFS_POINTER
        return src.getvalue()[: len(_LFS_POINTER)] == _LFS_POINTER
    except OSError:
        return False


def _plural(n: int, text: str) -> str:
    """``"3 point primitive(s) ignored"`` -> ``"3 point primitives ignored"`` (singular for 1)."""
    return f"{n} " + text.replace("(s)", "" if n == 1 else "s")


def _same_transform(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


def _map_file(path: Path, offset: int, length: int | None) -> np.ndarray:
    """Read-only uint8 memory map of ``length`` bytes of a file from ``offset`` (to the end if None)."""
    size = path.stat().st_size
    if length is None:
        length = size - offset
    if length <= 0:
        return np.zeros(0, np.uint8)
    return np.memmap(path, dtype=np.uint8, mode="r", offset=offset, shape=(length,))
