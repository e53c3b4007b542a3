"""A model on disk with the files it references, as one upload: what ``kiln bake scene.gltf`` sends.

A ``.gltf`` usually keeps its buffers and images beside it (``scene.bin``, ``textures/wall.webp``), and a ``.glb``
may reference images outside its binary chunk. The service takes one file per upload (:func:`workers.gltf.ingest_file`:
a ``.glb``, a ``.gltf`` with ``data:`` URIs, or a ``.zip`` of a model and its files), so the command line packs a
model whose buffers or images are relative files into a zip of the model and those files, at their relative paths,
and bakes (or uploads) that: the same reader, the same checks (sizes, ``..``, schemes) as any zip upload.

Only what the model references is packed, read from its JSON (``buffers[].uri``, ``images[].uri``;
percent-decoded, as the reader resolves them). A URI that is not a plain relative path (a scheme, an absolute path)
or that climbs out of the model's folder is left out: the reader then refuses it with its own code
(``external_uri``, ``path_traversal``). A referenced file that does not exist is :class:`MissingFile`.

:func:`embed_glb` makes the same files ONE GLB instead (buffers and images in its binary chunk), deterministic: for
tools that want a single file or a content digest of a model spread over several (the fidelity bench's references
and Blender, tests/data/fidelity/make_references.py).
"""
from __future__ import annotations

import json
import mimetypes
import os
import posixpath
import struct
import zipfile
from urllib.parse import unquote
from pathlib import Path

from workers.gltf.container import climbs_out, read_glb, sniff, split_uri
from workers.gltf.errors import IngestError

__all__ = ["referenced_files", "pack_model", "embed_glb", "MissingFile"]

class MissingFile(Exception):
    """A file the model references is not on disk beside it (``rel``: the decoded URI)."""

    def __init__(self, rel: str, what: str):
        super().__init__(f"{what} '{rel}' does not exist beside the model")
        self.rel, self.what = rel, what


def _json_of(path: Path) -> dict | None:
    """The glTF JSON of a ``.gltf`` or a ``.glb`` (read by the reader's own :func:`read_glb`); None when it is neither
    or cannot be read (the reader says why when the model is ingested)."""
    try:
        with open(path, "rb") as f:
            kind = sniff(f.read(4096))
        raw = read_glb(path, path.name, [])[0] if kind == "glb" else path.read_bytes() if kind == "gltf" else None
        doc = json.loads(raw) if raw is not None else None
    except (IngestError, OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    return doc if isinstance(doc, dict) else None


def referenced_files(path: str | os.PathLike) -> list[tuple[str, str]]:
    """``[(relative path, what)]`` of the files a model references (``what``: "buffer 0", "image 3"), '/'-separated
    and percent-decoded (:func:`split_uri`, as the reader resolves them), without ``data:`` URIs, schemes, absolute
    paths and paths that leave the model's folder (:func:`climbs_out`)."""
    doc = _json_of(Path(path))
    out: list[tuple[str, str]] = []
    for key, noun in (("buffers", "buffer"), ("images", "image")):
        items = doc.get(key) if doc else None
        for i, item in enumerate(items if isinstance(items, list) else []):
            uri = item.get("uri") if isinstance(item, dict) else None
            try:
                kind, rel = split_uri(uri, f"{noun} {i}")
            except IngestError:
                continue                                 # no URI, a scheme, an absolute path: the reader refuses
            norm = posixpath.normpath(rel)
            if kind == "file" and not climbs_out(norm) and (norm, f"{noun} {i}") not in out:
                out.append((norm, f"{noun} {i}"))
    return out


def pack_model(path: str | os.PathLike, out_zip: str | os.PathLike) -> bool:
    """Write ``out_zip``: the model at its file name and every file of :func:`referenced_files` at its relative path
    (stored, not deflated: images and buffers are compressed or large). Returns False (and writes nothing) when the
    model references no file. Raises :class:`MissingFile` for a referenced file that is not there."""
    path = Path(path)
    refs = referenced_files(path)
    if not refs:
        return False
    root = path.resolve().parent
    files = []
    for rel, what in refs:
        f = root / rel
        if not f.is_file():
            raise MissingFile(rel, what)
        files.append((rel, f))
    with zipfile.ZipFile(out_zip, "w", zipfile.ZIP_STORED) as z:
        z.write(path, path.name)
        for rel, f in dict(files).items():
            if rel != path.name:
                z.write(f, rel)
    return True


def embed_glb(path: str | os.PathLike) -> bytes:
    """A ``.gltf`` and the files it references as ONE self-contained GLB (glTF 2.0 spec, "GLB File Format
    Specification"): every buffer with a relative URI becomes part of the BIN chunk (buffers concatenated in order,
    each 4-byte aligned; ``bufferViews[].byteOffset`` shifted), every image with a relative URI a new bufferView of
    it (``mimeType`` from the image or its extension; the URI removed). Everything else of the JSON is kept, so
    the GLB holds the same scene. Deterministic: the same files give the same bytes (a stable content digest for
    a model spread over several files, and a single file for tools that want one). A ``.glb`` is returned as it is.

    Raises :class:`MissingFile` for a referenced file that is not there and ``ValueError`` for a buffer or image URI
    that is not a plain relative path inside the model's folder (a scheme, ``data:``, an absolute path, ``..``)."""
    path = Path(path)
    raw = path.read_bytes()
    if raw[:4] == b"glTF":
        return raw
    doc = json.loads(raw)
    root = path.resolve().parent

    def read(uri, what: str) -> bytes:
        rel = posixpath.normpath(unquote(uri)) if isinstance(uri, str) else None
        if rel is None or ":" in uri or rel.startswith("/") or climbs_out(rel):
            raise ValueError(f"{what}: {uri!r} is not a relative path inside the model's folder")
        f = root / rel
        if not f.is_file():
            raise MissingFile(rel, what)
        return f.read_bytes()

    blob = bytearray()
    starts = []
    for i, b in enumerate(doc.get("buffers", [])):
        starts.append(len(blob))
        if "uri" in b:
            data = read(b["uri"], f"buffer {i}")
            if len(data) < b["byteLength"]:
                raise ValueError(f"buffer {i} has {len(data)} bytes, byteLength says {b['byteLength']}")
            blob += data[:b["byteLength"]]
        else:
            raise ValueError(f"buffer {i} has no URI (a .gltf buffer must have one)")
        blob += b"\0" * (-len(blob) % 4)
    for v in doc.get("bufferViews", []):
        v["byteOffset"] = v.get("byteOffset", 0) + starts[v["buffer"]]
        v["buffer"] = 0
    for i, img in enumerate(doc.get("images", [])):
        if "uri" not in img:
            continue
        data = read(img["uri"], f"image {i}")
        mime = img.get("mimeType") or mimetypes.guess_type(unquote(img["uri"]))[0] or "application/octet-stream"
        doc.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob += data
        blob += b"\0" * (-len(blob) % 4)
        del img["uri"]
        img["bufferView"], img["mimeType"] = len(doc["bufferViews"]) - 1, mime
    if blob:
        doc["buffers"] = [{"byteLength": len(blob)}]
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks
