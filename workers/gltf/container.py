"""The upload's container: what kind of file it is, its GLB chunks, its JSON, and where its URIs lead.

An upload is a ``.glb`` (12-byte header, a JSON chunk, an optional BIN chunk [glTF] 4.4), a ``.gltf`` (JSON whose
buffers and images are ``data:`` URIs) or a ``.zip`` holding one of those and the files it references
(:mod:`workers.gltf.archive`); :func:`sniff` tells them apart by their first bytes. Every GLB length is checked
against the file before anything is allocated; the JSON's nesting is measured without recursion before it is
parsed. URIs are relative paths inside the upload or ``data:`` URIs: schemes, absolute and UNC paths are
refused (``external_uri``), ``..`` above the upload is ``path_traversal``. :class:`Files` is where relative
URIs resolve (:class:`NoFiles` for a loose file, :class:`workers.gltf.archive.ZipFiles` for a zip).
Consumer: :mod:`workers.gltf.reader`, :mod:`workers.gltf.accessors`, :mod:`workers.gltf.materials`.
Inverse: none (:mod:`workers.scene_glb` writes GLB).

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.3 (URIs), 4 (GLB file format specification).
"""

from __future__ import annotations

import base64
import binascii
import json
import posixpath
import re
import struct
import urllib.parse
from pathlib import Path

import numpy as np

from workers.gltf.errors import IngestError, err, invalid
from workers.gltf.limits import IngestLimits

__all__ = ["sniff", "read_glb", "json_depth", "parse_json", "split_uri", "climbs_out", "decode_data_uri", "Files",
           "NoFiles", "map_file"]

_GLB_MAGIC = b"glTF"
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")  # local file header; end of central directory (empty zip)
_UTF8_BOM = b"\xef\xbb\xbf"
_CHUNK_JSON = 0x4E4F534A  # "JSON"
_CHUNK_BIN = 0x004E4942  # "BIN\0"
_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


def sniff(head: bytes) -> str | None:
    """Upload type from the first bytes: ``"glb"``, ``"zip"``, ``"gltf"`` (JSON object) or None."""
    if head.startswith(_GLB_MAGIC):
        return "glb"
    if head[:4] in _ZIP_MAGICS:
        return "zip"
    text = head[len(_UTF8_BOM) :] if head.startswith(_UTF8_BOM) else head
    if text.lstrip(b" \t\r\n").startswith(b"{"):
        return "gltf"
    return None


# ---------------------------------------------------------------------------------------------- GLB / JSON


def read_glb(path: Path, label: str, warnings: list[str]) -> tuple[bytes, tuple[Path, int, int] | None]:
    """Split a GLB into its JSON bytes and the (path, offset, length) of its BIN chunk.

    Every length is checked against the file size before anything is allocated.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(12)
        if len(header) < 12:
            raise err("truncated_glb", f"'{label}' ends inside the 12-byte GLB header")
        _, version, length = struct.unpack("<4sII", header)
        if version != 2:
            raise err("unsupported", f"'{label}' is GLB version {version}; only glTF 2.0 (GLB version 2) is supported")
        if length > size:
            raise err("truncated_glb", f"'{label}' GLB header says {length} bytes but the file has {size}")
        if length < 20:
            raise err("truncated_glb", f"'{label}' GLB header length {length} leaves no room for a JSON chunk")
        json_bytes = None
        bin_chunk = None
        pos = 12
        n_chunk = 0
        while pos + 8 <= length:
            f.seek(pos)
            chunk_len, chunk_type = struct.unpack("<II", f.read(8))
            if pos + 8 + chunk_len > length:
                raise err(
                    "truncated_glb",
                    f"'{label}' GLB chunk {n_chunk} claims {chunk_len} bytes at offset {pos + 8}, past the "
                    f"end of the file ({length} bytes)",
                )
            if n_chunk == 0:
                if chunk_type != _CHUNK_JSON:
                    raise invalid(f"'{label}' GLB first chunk is not JSON (type 0x{chunk_type:08x})")
                json_bytes = f.read(chunk_len)
            elif chunk_type == _CHUNK_BIN and bin_chunk is None:
                bin_chunk = (path, pos + 8, chunk_len)
            pos += 8 + chunk_len
            n_chunk += 1
        if json_bytes is None:
            raise err("truncated_glb", f"'{label}' GLB has no JSON chunk")
        if length < size:
            warnings.append(f"{size - length} bytes after the end of the GLB ignored")
    return json_bytes, bin_chunk


def json_depth(data: bytes) -> int:
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
    raise err("broken_json", f"the JSON contains {name}, which JSON does not allow")


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


def parse_json(data: bytes, limits: IngestLimits, label: str) -> dict:
    """Parse glTF JSON bytes (UTF-8, optional BOM) after a non-recursive depth check."""
    if data.startswith(_UTF8_BOM):
        data = data[len(_UTF8_BOM) :]
    depth = json_depth(data)
    if depth > limits.max_json_depth:
        raise err("json_too_deep", f"'{label}' JSON nests {depth} levels deep; the limit is {limits.max_json_depth}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise err("broken_json", f"'{label}' JSON is not valid UTF-8 (byte {exc.start})") from exc
    try:
        doc = json.loads(text, parse_constant=_reject_constant, parse_float=_parse_float)
    except json.JSONDecodeError as exc:
        raise err(
            "broken_json", f"'{label}' JSON is broken at line {exc.lineno} column {exc.colno}: {exc.msg}"
        ) from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        raise err("not_gltf", f"'{label}' is JSON but not glTF: it has no \"asset\" object")
    return doc


# ---------------------------------------------------------------------------------------------- URIs


def split_uri(uri, what: str) -> tuple[str, str]:
    """Classify a glTF URI: ``("data", uri)`` or ``("file", relative path, percent-decoded, '/'-separated)``.

    Raises ``external_uri`` for schemes (http:, file:, C:), absolute paths and UNC paths, checked on the raw
    and the percent-decoded URI. ``..`` segments are kept: where the URI lands is the resolver's to judge
    (:class:`ZipFiles`: anywhere inside the zip is fine, ``path_traversal`` above its root; a loose file
    has nothing beside it).
    """
    if not isinstance(uri, str) or not uri:
        raise invalid(f"{what} has a URI that is not a non-empty string")
    if uri[:5].lower() == "data:":
        return "data", uri
    decoded = urllib.parse.unquote(uri)
    for candidate in (uri, decoded):
        if _URI_SCHEME.match(candidate) or candidate.startswith(("/", "\\")):
            raise err(
                "external_uri",
                f"{what} points outside the upload ('{uri}'): only relative paths inside the upload "
                "and data: URIs are allowed",
            )
    if "\x00" in decoded:
        raise invalid(f"{what} URI contains a NUL byte")
    return "file", decoded.replace("\\", "/")


def climbs_out(rel: str) -> bool:
    """Whether a '/'-separated relative path leaves its root (``../a``, ``a/../../b``); ``a/../b`` does not."""
    target = posixpath.normpath(rel)
    return target == ".." or target.startswith("../")


def decode_data_uri(uri: str, what: str) -> bytes:
    header, sep, payload = uri.partition(",")
    if not sep:
        raise invalid(f"{what} has a data: URI without a ',' before its payload")
    if header.lower().endswith(";base64"):
        try:
            return base64.b64decode(payload, validate=False)
        except (binascii.Error, ValueError) as exc:
            raise invalid(f"{what} data: URI is not valid base64 ({exc})") from exc
    return urllib.parse.unquote_to_bytes(payload)


class Files:
    """Where relative URIs resolve. ``locate`` checks existence; ``path`` gives a readable file."""

    def locate(self, rel: str, what: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def path(self, rel: str, what: str) -> Path:  # pragma: no cover - interface
        raise NotImplementedError


class NoFiles(Files):
    """A loose .glb/.gltf: nothing beside it was uploaded."""

    def _missing(self, rel: str, what: str) -> IngestError:
        return err(
            "missing_resource",
            f"{what} '{rel}' is not in the upload: a lone .gltf/.glb must embed its buffers and images "
            "(data: URIs or the GLB binary chunk); upload a .zip holding the model and its files instead",
        )

    def locate(self, rel: str, what: str) -> None:
        if climbs_out(rel):
            raise err("path_traversal", f"{what} URI '{rel}' climbs out of the upload with '..'")
        raise self._missing(rel, what)

    def path(self, rel: str, what: str) -> Path:
        self.locate(rel, what)  # always raises
        raise self._missing(rel, what)


def map_file(path: Path, offset: int, length: int | None) -> np.ndarray:
    """Read-only uint8 memory map of ``length`` bytes of a file from ``offset`` (to the end if None)."""
    size = path.stat().st_size
    if length is None:
        length = size - offset
    if length <= 0:
        return np.zeros(0, np.uint8)
    return np.memmap(path, dtype=np.uint8, mode="r", offset=offset, shape=(length,))
