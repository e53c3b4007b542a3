"""The normalized scene: what every bake stage reads instead of glTF.

Produced by :func:`workers.ingest.ingest_file` (glTF 2.0 -> normalized scene).
All geometry is flattened to world space (node transforms applied), float32, metres,
glTF's frame (+Y up, right-handed). Triangles keep the glTF winding (counter-clockwise
front faces).

Arrays (T = triangle count):

- ``triangles`` : (T, 3, 3) float32, world-space vertex positions.
- ``normals``   : (T, 3, 3) float32, unit world-space vertex normals (geometric if the mesh has none).
- ``uv0``       : (T, 3, 2) float32, the UV set the material's base-colour (else emissive) texture
  samples, KHR_texture_transform applied (TEXCOORD_0 unless the material says otherwise; zeros where absent).
- ``uv1``       : (T, 3, 2) float32 or None, TEXCOORD_1 where every mesh has it.
- ``material``  : (T,) int32, index into ``materials``.
- ``textures``  : list of (H, W, 4) uint8 RGBA images (sRGB-encoded as stored in the file).

Materials and lights are plain dicts (JSON-able):

- material: ``{"name", "base_color": [r,g,b,a] linear, "base_color_texture": int|None,
  "emissive": [r,g,b] linear (factor x strength), "emissive_texture": int|None, "double_sided": bool}``
- light: ``{"type": "point"|"spot"|"directional", "color": [r,g,b], "intensity": float,
  "range": float|None, "position": [x,y,z]|None, "direction": [x,y,z]|None (unit, the direction
  light travels), "inner_cone_angle", "outer_cone_angle", "name"}``

The scene id is the sha256 of :meth:`NormalizedScene.to_bytes` output, so the same geometry
and materials uploaded as .glb, .gltf or .zip get the same id.
"""
from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field

import numpy as np


@dataclass
class NormalizedScene:
    triangles: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray
    material: np.ndarray
    materials: list[dict]
    lights: list[dict] = field(default_factory=list)
    textures: list[np.ndarray] = field(default_factory=list)
    uv1: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)

    # ------------------------------------------------------------------ properties
    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: min and max corner, world space, metres."""
        v = self.triangles.reshape(-1, 3)
        return np.stack([v.min(axis=0), v.max(axis=0)]).astype(np.float64)

    def summary(self, scene_id: str) -> dict:
        return {
            "id": scene_id,
            "triangles": self.n_triangles,
            "bounds": self.bounds.round(6).tolist(),
            "lights": len(self.lights),
            "materials": len(self.materials),
            "warnings": list(self.warnings),
        }

    # ------------------------------------------------------------------ (de)serialization
    def to_bytes(self) -> bytes:
        """Canonical, deterministic serialization (an uncompressed .npz)."""
        arrays = {
            "triangles": np.ascontiguousarray(self.triangles, np.float32),
            "normals": np.ascontiguousarray(self.normals, np.float32),
            "uv0": np.ascontiguousarray(self.uv0, np.float32),
            "material": np.ascontiguousarray(self.material, np.int32),
        }
        if self.uv1 is not None:
            arrays["uv1"] = np.ascontiguousarray(self.uv1, np.float32)
        for i, t in enumerate(self.textures):
            arrays[f"texture_{i:04d}"] = np.ascontiguousarray(t, np.uint8)
        meta = {"materials": self.materials, "lights": self.lights, "warnings": self.warnings,
                "n_textures": len(self.textures)}
        arrays["meta"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)
        buf = io.BytesIO()
        # np.savez writes zip entries with a fixed timestamp, so the bytes are reproducible.
        np.savez(buf, **arrays)
        return buf.getvalue()

    def scene_id(self) -> str:
        return hashlib.sha256(self.to_bytes()).hexdigest()

    @classmethod
    def from_bytes(cls, data: bytes) -> "NormalizedScene":
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            return cls(
                triangles=z["triangles"],
                normals=z["normals"],
                uv0=z["uv0"],
                material=z["material"],
                materials=meta["materials"],
                lights=meta["lights"],
                textures=[z[f"texture_{i:04d}"] for i in range(meta["n_textures"])],
                uv1=z["uv1"] if "uv1" in z.files else None,
                warnings=meta.get("warnings", []),
            )
