"""glTF ingest: an uploaded glTF 2.0 file -> :class:`workers.scene.NormalizedScene` (DESIGN "Bake stages / 0. ingest").

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
- compressed geometry, decoded by :mod:`workers.gltf.compression` into the same accessor path:
  ``KHR_draco_mesh_compression`` primitives (DracoPy; preferred over an uncompressed fallback) and
  ``EXT_meshopt_compression`` / ``KHR_meshopt_compression`` buffer views (meshoptimizer; fallback
  buffers without data are never read), the decoded bytes counted against
  ``IngestLimits.max_decoded_bytes`` and the triangle limit;
- materials: base colour factor and texture (``KHR_materials_pbrSpecularGlossiness`` diffuse when a
  material has no metallic-roughness block), emissive factor x ``KHR_materials_emissive_strength`` and
  emissive texture, ``doubleSided``; ``KHR_texture_transform`` is applied to the UVs;
- textures used by materials, decoded with PIL to RGBA uint8 (PNG, JPEG, WebP via ``EXT_texture_webp``);
- ``KHR_lights_punctual`` lights placed by their nodes' world transforms; perspective cameras.

Every bad input raises :class:`IngestError` with a machine-readable ``code``, a sentence and a 4xx
``status``; no other exception type leaves :func:`ingest_file`.

Modules: :mod:`~workers.gltf.reader` (:func:`ingest_file`, the orchestration), :mod:`~workers.gltf.container`
(sniffing, GLB chunks, JSON, URIs and ``data:`` URIs), :mod:`~workers.gltf.archive` (zip uploads),
:mod:`~workers.gltf.document` (checked JSON access, version, extensions), :mod:`~workers.gltf.accessors`
(buffers, views, accessors), :mod:`~workers.gltf.compression` (Draco, meshopt), :mod:`~workers.gltf.materials`
(materials, textures), :mod:`~workers.gltf.nodes` (transforms, instancing, skins, morph targets),
:mod:`~workers.gltf.primitives` (triangles in world space), :mod:`~workers.gltf.lights`,
:mod:`~workers.gltf.cameras`, :mod:`~workers.gltf.limits` (size limits, hostile magnitudes),
:mod:`~workers.gltf.errors` (:class:`IngestError`, :data:`ERROR_CODES`).

Frames and units: glTF's (+Y up, right-handed, metres, counter-clockwise front faces); see
:mod:`workers.scene` for the output arrays. Consumer: ``workers/stages`` (every bake stage) and the
upload route. Inverse: :mod:`workers.scene_glb`.

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.5 (nodes), 3.6 (accessors), 3.7.2 (meshes,
   primitive modes), 3.7.3 (skins), 3.9 (materials).
.. [KHR_lights_punctual] Khronos glTF extension: point, spot and directional lights.
.. [KHR_texture_transform] Khronos glTF extension: offset, rotation, scale of texture coordinates.
.. [KHR_draco_mesh_compression], [EXT_meshopt_compression] Khronos glTF extensions; see
   :mod:`workers.gltf.compression`.
"""

from workers.gltf.errors import ERROR_CODES, IngestError
from workers.gltf.limits import MAX_COORD, IngestLimits
from workers.gltf.reader import ingest_file

__all__ = ["ingest_file", "IngestError", "IngestLimits", "ERROR_CODES", "MAX_COORD"]
