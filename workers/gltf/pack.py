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
"""
from __future__ import annotations

import json
import os
import posixpath
import struct
import urllib.parse
import zipfile
from pathlib import Path

__all__ = ["referenced_files", "pack_model", "MissingFile"]

_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A


class MissingFile(Exception):
    """A file the model references is not on disk beside it (``rel``: the decoded URI)."""

    def __init__(self, rel: str, what: str):
        super().__init__(f"{what} '{rel}' does not exist beside the model")
        self.rel, self.what = rel, what


def _json_of(path: Path) -> dict | None:
    """The glTF JSON of a ``.gltf`` or a ``.glb`` (its first chunk); None when it is neither (the reader says why)."""
    try:
        with open(path, "rb") as f:
            head = f.read(20)
            if head[:4] == _GLB_MAGIC:
                if len(head) < 20:
                    return None
                length, kind = struct.unpack_from("<II", head, 12)
                if kind != _JSON_CHUNK or length > os.path.getsize(path):
                    return None
                raw = f.read(length)
            else:
                raw = head + f.read()
        doc = json.loads(raw)
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    return doc if isinstance(doc, dict) else None


def referenced_files(path: str | os.PathLike) -> list[tuple[str, str]]:
    """``[(relative path, what)]`` of the files a model references (``what``: "buffer 0", "image 3"), '/'-separated
    and percent-decoded, without ``data:`` URIs, schemes, absolute paths and paths that leave the model's folder."""
    doc = _json_of(Path(path))
    out: list[tuple[str, str]] = []
    if doc is None:
        return out
    for key, noun in (("buffers", "buffer"), ("images", "image")):
        items = doc.get(key)
        for i, item in enumerate(items if isinstance(items, list) else []):
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or not uri or uri[:5].lower() == "data:":
                continue
            rel = urllib.parse.unquote(uri).replace("\\", "/")
            if ":" in rel.split("/")[0] or rel.startswith("/") or "\x00" in rel:
                continue                                         # a scheme or an absolute path: the reader refuses
            norm = posixpath.normpath(rel)
            if norm == ".." or norm.startswith("../"):
                continue                                         # climbs out: the reader says path_traversal
            if (norm, f"{noun} {i}") not in out:
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
