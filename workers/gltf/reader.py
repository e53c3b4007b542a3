"""Reading one upload: :func:`ingest_file` and :class:`GltfReader`, which puts the other modules together.

:func:`ingest_file` sniffs the upload (:mod:`workers.gltf.container`), extracts a zip's model
(:mod:`workers.gltf.archive`), splits a GLB and parses the JSON, then :class:`GltfReader` checks the asset,
the required extensions and every URI, plans the triangle budget from the JSON alone, reads materials and
textures (:mod:`workers.gltf.materials`), and for each primitive of the default scene its accessors
(:mod:`workers.gltf.accessors`), morph targets, skin or instances (:mod:`workers.gltf.nodes`) into world-space
triangles (:mod:`workers.gltf.primitives`), then the lights (:mod:`workers.gltf.lights`) and cameras
(:mod:`workers.gltf.cameras`). Whatever goes wrong leaves as :class:`workers.gltf.errors.IngestError`.
Consumer: :mod:`workers.jobs` (uploads), :mod:`server.cli` (``kiln bake``). Inverse: :mod:`workers.scene_glb`.
"""

from __future__ import annotations

import copy
import os
import posixpath
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from workers.gltf.accessors import Accessors
from workers.gltf.archive import ZipFiles, ZipUpload
from workers.gltf.cameras import build_cameras
from workers.gltf.container import Files, NoFiles, parse_json, read_glb, sniff, split_uri
from workers.gltf.document import Document, is_int, vec
from workers.gltf.errors import IngestError, err, invalid, plural, scrub
from workers.gltf.lights import build_lights
from workers.gltf.limits import LFS_POINTER, IngestLimits, check_extent, far_from_origin
from workers.gltf.materials import DEFAULT_MATERIAL, DEFAULT_MATERIAL_WARNING, Materials
from workers.gltf.nodes import instances, morphed, scene_nodes, skin_matrices, world_matrices
from workers.gltf.primitives import emit, planned_triangles, triangle_indices
from workers.scene import NormalizedScene

__all__ = ["ingest_file", "GltfReader"]


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
        exc.message = scrub(exc.message, where)  # the upload's own path never reaches the user
        exc.args = (f"{exc.code}: {exc.message}",)
        raise
    except MemoryError as exc:
        raise err("too_large", f"'{label}' needs more memory than this service allows") from exc
    except RecursionError as exc:
        raise err("json_too_deep", f"'{label}' is nested too deeply to read") from exc
    except Exception as exc:  # a numpy/PIL/zipfile surprise on a bad upload is still a 4xx, never a 500
        message = f"'{label}' could not be read as glTF 2.0 ({type(exc).__name__}: {exc})"
        raise invalid(scrub(message, where)) from exc


# ---------------------------------------------------------------------------------------------- entry


def _ingest(path: Path, limits: IngestLimits, label: str) -> NormalizedScene:
    try:
        st = path.stat()
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise err("unreadable_upload", f"the upload '{label}' cannot be read: {exc.strerror or exc}") from exc
    if st.st_size > limits.max_bytes:
        raise err("too_large", f"'{label}' is {st.st_size} bytes; the limit is {limits.max_bytes} bytes")
    kind = sniff(head)
    if kind == "zip":
        with tempfile.TemporaryDirectory(prefix="kiln-ingest-") as tmp:
            archive = ZipUpload(path, limits, Path(tmp), label)
            try:
                model_name = archive.model_member()
                model_path = archive.extract(model_name)
                with open(model_path, "rb") as f:
                    model_kind = sniff(f.read(4096))
                if model_kind not in ("glb", "gltf"):
                    raise err("not_gltf", f"'{model_name}' in '{label}' is neither GLB nor glTF JSON")
                files = archive.files(posixpath.dirname(model_name))
                return _load_model(model_path, model_kind, files, limits, f"{label}/{model_name}")
            finally:
                archive.close()
    if kind in ("glb", "gltf"):
        return _load_model(path, kind, NoFiles(), limits, label)
    if head.startswith(LFS_POINTER):
        raise err("not_gltf", f"'{label}' is a Git LFS pointer (a small text file), not the model: fetch the "
                               "real file (git lfs pull) and upload that")
    raise err(
        "not_gltf",
        f"'{label}' is not glTF 2.0: expected a .glb (starting with 'glTF'), a .gltf (a JSON object) "
        "or a .zip holding one",
    )


def _load_model(path: Path, kind: str, files: Files, limits: IngestLimits, label: str) -> NormalizedScene:
    warnings: list[str] = []
    bin_chunk = None
    if kind == "glb":
        json_bytes, bin_chunk = read_glb(path, label, warnings)
    else:
        json_bytes = path.read_bytes()
    gltf = parse_json(json_bytes, limits, label)
    del json_bytes
    reader = GltfReader(gltf, path, bin_chunk, files, limits, label, warnings)
    return reader.build()


class GltfReader:
    """Reads one parsed glTF document into a :class:`NormalizedScene`.

    Parameters
    ----------
    gltf : dict
        The parsed JSON.
    path : Path
        The .gltf/.glb on disk (GLB BIN chunk lives in it).
    bin_chunk : (Path, int, int) or None
        GLB binary chunk: file, byte offset, byte length.
    files : Files
        Resolves relative URIs (nothing for loose uploads; zip members otherwise).
    """

    def __init__(
        self, gltf: dict, path: Path, bin_chunk, files: Files, limits: IngestLimits, label: str, warnings: list[str]
    ):
        self.doc = Document(gltf)
        self.path = path
        self.files = files
        self.limits = limits
        self.label = label
        self.warnings = warnings
        self.acc = Accessors(self.doc, bin_chunk, files, limits, label)
        self._counts: Counter = Counter()  # things dropped, summarized as warnings at the end

    def _check_uris(self) -> None:
        """Every buffer and image URI: no escapes, and present in the upload (used or not)."""
        for key, noun in (("buffers", "buffer"), ("images", "image")):
            for i, obj in enumerate(self.doc.array(key)):
                if not isinstance(obj, dict):
                    raise invalid(f"{key}[{i}] is not an object")
                if "uri" in obj:
                    kind, rel = split_uri(obj["uri"], f"{noun} {i}")
                    if kind == "file" and not (key == "buffers" and self.acc.meshopt_fallback(obj)):
                        self.files.locate(rel, f"{noun} {i}")  # meshopt fallbacks are never read

    def build(self) -> NormalizedScene:
        """The whole document as a :class:`NormalizedScene` (see :func:`ingest_file`)."""
        self.doc.check_asset()
        self.doc.check_extensions(self.warnings)
        self._check_uris()
        world = world_matrices(self.doc)
        order = scene_nodes(self.doc)
        nodes = self.doc.array("nodes")
        meshes = self.doc.array("meshes")

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
            mesh = self.doc.item("meshes", node["mesh"], f"nodes[{ni}]")
            k = 1
            inst = self.doc.exts(node).get("EXT_mesh_gpu_instancing")
            if isinstance(inst, dict) and isinstance(inst.get("attributes"), dict) and inst["attributes"]:
                first = next(iter(inst["attributes"].values()))
                k = self.doc.item("accessors", first, f"nodes[{ni}] EXT_mesh_gpu_instancing").get("count", 0)
                if not is_int(k) or k < 0:
                    raise invalid(f"nodes[{ni}] EXT_mesh_gpu_instancing count must be an integer")
            prims = self.doc.array("primitives", mesh)
            if not prims:
                raise invalid(f"meshes[{node['mesh']}] has no primitives")
            for pi, prim in enumerate(prims):
                what = f"meshes[{node['mesh']}].primitives[{pi}]"
                if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                    raise invalid(f"{what} needs an 'attributes' object")
                # Draco primitives are planned from their indices accessor's declared count; the
                # decoded faces are checked against it (Accessors.draco_primitive)
                n = planned_triangles(self.doc, prim, what) * k
                planned += n
                if n and "TEXCOORD_1" not in prim["attributes"]:
                    all_uv1 = False
                if n and "TEXCOORD_1" in prim["attributes"]:
                    any_uv1 = True
                if n and "COLOR_0" in prim["attributes"]:
                    any_color = True
                draws.append((ni, node["mesh"], pi, prim))
        if planned > self.limits.max_triangles:
            raise err(
                "too_many_triangles", f"the scene has {planned} triangles; the limit is {self.limits.max_triangles}"
            )

        materials, textures, uv_refs = Materials(self.doc, self.acc, self.files, self.limits, self._counts,
                                                 self.warnings).build()
        default_material: int | None = None
        # KHR_materials_unlit: drawn without lighting (sky domes, backgrounds, baked-lighting meshes). Blender's
        # importer makes them an emission seen by camera rays only, transparent to every other ray, so the Cycles
        # oracle's light passes through them; the bake leaves them out, unless nothing else is left to bake
        unlit = {i for i, m in enumerate(materials) if m.get("unlit")}
        skip_unlit = bool(unlit) and any(not (is_int(p.get("material")) and p["material"] in unlit)
                                         for _, _, _, p in draws)     # (a malformed index is refused below)
        unlit_skipped: Counter = Counter()

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
            prim = self.acc.draco_primitive(prim, what)  # KHR_draco_mesh_compression -> its accessors
            pos = self.acc.accessor_float(attrs["POSITION"], f"{what} POSITION", (3,))
            n_vertices = pos.shape[0]
            tri = triangle_indices(self.acc, prim, n_vertices, what, self._counts)
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
                self.doc.item("materials", prim["material"], what)
                mat = prim["material"]
                uv_ref = uv_refs[mat]
            else:
                if default_material is None:
                    default_material = len(materials)
                    materials.append(copy.deepcopy(DEFAULT_MATERIAL))
                    self.warnings.append(DEFAULT_MATERIAL_WARNING)
                mat = default_material
                uv_ref = None
            if mat in unlit and skip_unlit:
                unlit_skipped[materials[mat]["name"]] += 1
                continue
            uv_set = uv_ref.texcoord if uv_ref is not None else 0
            color = None
            if "COLOR_0" in attrs:
                # [glTF] 3.7.2.1: COLOR_0 (VEC3/VEC4 float, normalized ubyte/ushort) multiplies the base colour
                color = self.acc.accessor_float(attrs["COLOR_0"], f"{what} COLOR_0", (3, 4))
                if color.shape[0] != n_vertices:
                    raise invalid(f"{what} COLOR_0 has {color.shape[0]} elements, POSITION {n_vertices}")
                color = color if sel is None else color[sel]
                if color.shape[1] == 3:
                    color = np.concatenate([color, np.ones((color.shape[0], 1), np.float32)], axis=1)
                if not np.isfinite(color).all():
                    raise err("non_finite", f"{what} has NaN or infinite COLOR_0 values")
                if (color < 0).any():
                    raise invalid(f"{what} COLOR_0 has negative values")

            # morph targets at default weights ([glTF] 3.7.2.2), then skin or node transforms
            n_targets = len(self.doc.array("targets", prim))
            weights: list[float] = []
            if n_targets:
                w = node.get("weights", mesh.get("weights"))
                weights = vec(w, n_targets, [0.0] * n_targets, f"{what} morph weights")
            pos64 = morphed(self.doc, self.acc, prim, pos, "POSITION", weights, n_vertices, sel, what).astype(np.float64)
            nrm = None
            if "NORMAL" in attrs:
                nrm = self.acc.vertex_attr(attrs["NORMAL"], n_vertices, sel, 3, f"{what} NORMAL")
                nrm = morphed(self.doc, self.acc, prim, nrm, "NORMAL", weights, n_vertices, sel, what).astype(np.float64)

            uv = None
            uv_key = f"TEXCOORD_{uv_set}"
            if uv_key in attrs:
                uv = self.acc.vertex_attr(attrs[uv_key], n_vertices, sel, 2, f"{what} {uv_key}")
                uv = morphed(self.doc, self.acc, prim, uv, uv_key, weights, n_vertices, sel, what)
                if uv_ref is not None and uv_ref.transform is not None:  # [KHR_texture_transform]
                    uv = uv.astype(np.float64) @ uv_ref.transform[:, :2].T + uv_ref.transform[:, 2]
            elif uv_ref is not None:
                self._counts[f"primitive(s) lacking the {uv_key} their material's texture needs (UVs set to 0)"] += 1
            if uv_set != 0:
                self._counts[f"primitive(s) whose uv0 holds {uv_key} (the UV set their material's textures use)"] += 1
            uv1 = None
            if uv1_out is not None and "TEXCOORD_1" in attrs:
                uv1 = self.acc.vertex_attr(attrs["TEXCOORD_1"], n_vertices, sel, 2, f"{what} TEXCOORD_1")

            skin_m = skin_matrices(self.doc, self.acc, node, ni, prim, world, n_vertices, sel, what)
            mats = instances(self.doc, self.acc, node, ni, world[ni]) if skin_m is None else None
            out = (tri_out, nrm_out, uv0_out, uv1_out, mat_out, color_out)
            start = cursor
            cursor = emit(out, cursor, pos64, nrm, skin_m, mats, tri, uv, uv1, mat, f"{what} (node {ni})",
                          self._counts, color=color)
            if uv1 is not None:
                chart_out[start:cursor] = ni

        if cursor == 0:
            dropped = {k: n for k, n in self._counts.items() if k.endswith("primitive(s) ignored")}
            if dropped:
                shown = ", ".join(f"{n} {k.split()[0]}" for k, n in dropped.items())
                raise err(
                    "unsupported",
                    f"'{self.label}' holds only point and line primitives ({shown}); " "a bake needs triangles",
                )
            why = "; ".join(plural(n, k) for k, n in self._counts.items())
            raise err(
                "no_triangles", f"'{self.label}' has no triangles in its scene to bake" + (f" ({why})" if why else "")
            )
        if unlit_skipped:
            n = sum(unlit_skipped.values())
            names = ", ".join(repr(k) for k in list(unlit_skipped)[:3]) + (" ..." if len(unlit_skipped) > 3 else "")
            self.warnings.append(
                f"{n} primitive{'s' * (n != 1)} with unlit materials (KHR_materials_unlit: {names}) left out of the "
                "bake: drawn without lighting, they neither block nor reflect light (as Blender's importer makes "
                "them); a sky dome's light comes from the bake config's scene.sky")
        elif unlit:
            self.warnings.append(
                "every primitive is unlit (KHR_materials_unlit): baked as diffuse surfaces of their base colour (a "
                "scanned or baked-lighting model), where an engine and Blender's importer let light through them")
        far = far_from_origin(*check_extent(tri_out[:cursor], self.label))
        if far:
            self.warnings.append(far)
        if any_uv1 and not all_uv1:
            # ``uv1`` stays None (it promises every triangle); the coordinates live on in uv1_partial
            self.warnings.append("TEXCOORD_1 dropped: not every primitive has it")

        lights = build_lights(self.doc, order, world)
        cameras = build_cameras(self.doc.g, order, world)   # the glTF's own cameras (workers.gltf.cameras)
        if self.doc.array("animations"):
            n = len(self.doc.array("animations"))
            self.warnings.append(f"{n} animation{'s' * (n != 1)} ignored (static pose baked)")
        if isinstance(self.files, ZipFiles) and self.files.case_fixed:
            self.warnings.append("URIs matched zip members by case only: " + ", ".join(self.files.case_fixed))
        for what, n in self._counts.items():
            self.warnings.append(plural(n, what))

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
