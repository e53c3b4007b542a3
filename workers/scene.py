"""The normalized scene: what every bake stage reads instead of glTF.

Produced by :func:`workers.gltf.ingest_file` (glTF 2.0 -> normalized scene).
All geometry is flattened to world space (node transforms applied), float32, metres,
glTF's frame (+Y up, right-handed). Triangles keep the glTF winding (counter-clockwise
front faces).

Arrays (T = triangle count):

- ``triangles`` : (T, 3, 3) float32, world-space vertex positions.
- ``normals``   : (T, 3, 3) float32, unit world-space vertex normals (geometric if the mesh has none).
- ``uv0``       : (T, 3, 2) float32, the UV set the material's base-colour (else emissive) texture
  samples, KHR_texture_transform applied (TEXCOORD_0 unless the material says otherwise; zeros where absent).
- ``uv1``       : (T, 3, 2) float32 or None, TEXCOORD_1 where every mesh has it.
- ``uv1_partial``: (T, 3, 2) float32 or None, TEXCOORD_1 per triangle when only *some* meshes have it
  (zeros on the triangles without it; ``uv1`` is None then). None when ``uv1`` is set or no mesh has it.
- ``uv1_chart`` : (T,) int32 or None, set whenever some mesh has TEXCOORD_1: the glTF node index whose
  mesh gave the triangle its TEXCOORD_1 (triangles with the same chart share one UV1 space, i.e. one
  lightmap; different nodes' UV1 spaces may overlap), -1 for triangles without TEXCOORD_1. Instances of
  one node (EXT_mesh_gpu_instancing) share its chart. Use :meth:`NormalizedScene.texcoord1`.
- ``colors``    : (T, 3, 4) float32 or None, COLOR_0 per triangle corner as linear RGBA (it multiplies
  the base colour, [glTF] 3.7.2.1); ones on triangles whose primitive has none; None when no mesh has it.
- ``material``  : (T,) int32, index into ``materials``.
- ``textures``  : list of (H, W, 4) uint8 RGBA images (sRGB-encoded as stored in the file).

Materials and lights are plain dicts (JSON-able):

- material: ``{"name", "base_color": [r,g,b,a] linear, "base_color_texture": int|None,
  "emissive": [r,g,b] linear (factor x strength), "emissive_texture": int|None, "double_sided": bool,
  "metallic": float, "roughness": float (perceptual, glTF's), "metallic_roughness_texture": int|None
  (linear; B = metallic, G = roughness), "alpha_mode": "OPAQUE"|"MASK"|"BLEND", "alpha_cutoff": float}``.
  Scenes stored before these keys existed read as metallic 0, opaque (see :mod:`workers.kernels.materials`).
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
    uv1_partial: np.ndarray | None = None
    uv1_chart: np.ndarray | None = None
    colors: np.ndarray | None = None
    #: The glTF's own cameras (perspective, world space): ``[{"name", "position", "target", "fov_y"}]`` (fov in
    #: degrees; target one metre along the camera's -Z). The evaluate stage's review cameras when present.
    cameras: list[dict] = field(default_factory=list)
    #: Upper bound on the diffuse GI albedo at every hit (``scene.max_albedo`` of the bake config); not part
    #: of the scene's bytes or id: the bake sets it on its loaded copy.
    max_albedo: float | None = field(default=None, compare=False)
    #: How much of the specular reflection the GI albedo carries (``scene.specular_gi``,
    #: :mod:`workers.kernels.materials`); like ``max_albedo``, set by the bake, not stored.
    specular_gi: str = field(default="metals", compare=False)

    # ------------------------------------------------------------------ properties
    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: min and max corner, world space, metres."""
        v = self.triangles.reshape(-1, 3)
        return np.stack([v.min(axis=0), v.max(axis=0)]).astype(np.float64)

    def texcoord1(self) -> tuple[np.ndarray, np.ndarray] | None:
        """TEXCOORD_1 per triangle and its chart: ``(uv (T, 3, 2) float32, chart (T,) int32)``, chart -1
        where a triangle has none; None when no mesh has TEXCOORD_1. Scenes stored before charts existed
        (``uv1`` without ``uv1_chart``) get chart 0 everywhere."""
        uv = self.uv1 if self.uv1 is not None else self.uv1_partial
        if uv is None:
            return None
        chart = self.uv1_chart if self.uv1_chart is not None else np.zeros(self.n_triangles, np.int32)
        return uv, chart

    def emissive_materials(self) -> int:
        """How many materials that some triangle uses emit light (an emissive factor above 0 or a texture)."""
        used = set(np.unique(self.material).tolist()) if self.n_triangles else set()
        return sum(1 for i, m in enumerate(self.materials) if i in used
                   and (max(m.get("emissive", [0, 0, 0]) or [0]) > 0 or m.get("emissive_texture") is not None))

    def summary(self, scene_id: str) -> dict:
        """What the catalog and the API show of a scene; ``emissive_materials`` lets the web app warn about an
        unlit scene before a bake starts."""
        return {
            "id": scene_id,
            "triangles": self.n_triangles,
            "bounds": self.bounds.round(6).tolist(),
            "lights": len(self.lights),
            "materials": len(self.materials),
            "emissive_materials": self.emissive_materials(),
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
        if self.uv1_partial is not None:
            arrays["uv1_partial"] = np.ascontiguousarray(self.uv1_partial, np.float32)
        if self.uv1_chart is not None:
            arrays["uv1_chart"] = np.ascontiguousarray(self.uv1_chart, np.int32)
        if self.colors is not None:
            arrays["colors"] = np.ascontiguousarray(self.colors, np.float32)
        for i, t in enumerate(self.textures):
            arrays[f"texture_{i:04d}"] = np.ascontiguousarray(t, np.uint8)
        meta = {"materials": self.materials, "lights": self.lights, "warnings": self.warnings,
                "n_textures": len(self.textures)}
        if self.cameras:  # only then: the bytes (and ids) of scenes without cameras stay as they were
            meta["cameras"] = self.cameras
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
                uv1_partial=z["uv1_partial"] if "uv1_partial" in z.files else None,
                uv1_chart=z["uv1_chart"] if "uv1_chart" in z.files else None,
                colors=z["colors"] if "colors" in z.files else None,
                cameras=list(meta.get("cameras") or []),
            )
