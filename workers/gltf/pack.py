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
import zipfile
from pathlib import Path

from workers.gltf.container import climbs_out, read_glb, sniff, split_uri
from workers.gltf.errors import IngestError

__all__ = ["referenced_files", "pack_model", "MissingFile"]

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
