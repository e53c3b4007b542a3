"""A finished bake's bundle folder, written from the store (``kiln bake`` and ``GET /v1/bakes/{id}/bundle``).

Apart from :mod:`persist.store` so that the store imports the standard library only (a worker's forked
work-horse and a spawned writer start without numpy and pydantic).
"""
from __future__ import annotations

import os
from pathlib import Path

from persist.store import Store
from proto import bundle
from proto.atomic import atomic_write_bytes
from proto.models import Manifest

__all__ = ["export_bundle", "bake_artifacts"]


def export_bundle(store: Store, manifest: Manifest, out_dir: str | os.PathLike) -> Path:
    """Write a bundle folder (proto/bundle.md): ``manifest.json`` plus one file per artifact, read from
    ``store`` by sha256, each written atomically. Returns the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for a in manifest.artifacts:
        data = store.read_bytes(a.sha256)
        atomic_write_bytes(out / a.file, data)
    bundle.write_manifest(out, manifest)
    return out


def bake_artifacts(store: Store, bake: dict) -> list[dict]:
    """The artifacts of a catalog bake so far (``ArtifactInfo`` dicts): its manifest's once it succeeded, else
    those of its finished stages, read from their stored records."""
    if bake.get("manifest"):
        return bake["manifest"]["artifacts"]
    out = []
    for s in bake["stages"]:
        if s["status"] == "succeeded":
            rec = store.get_stage(s["cache_key"])
            if rec:
                out += rec["artifacts"]
    return out
