"""Accessors and buffer views: the glTF's binary data as numpy arrays ([glTF] 3.6).

:class:`Accessors` reads buffers (the GLB BIN chunk or an extracted file memory-mapped, a ``data:`` URI
decoded), slices buffer views with their ranges checked, and gives each accessor as a ``(count, n)`` array:
interleaved (``byteStride``) views, accessors without a buffer view (zeros), ``sparse`` substitution, and
float conversion of normalized integers (``KHR_mesh_quantization``: ``c / max``, signed clamped at -1).
Compressed data enters the same path through small hooks: a meshopt bufferView's decoded bytes replace the
view's contents, a Draco primitive's decoded faces and attributes become its accessors' values
(:mod:`workers.gltf.compression`), the decoded bytes charged to ``IngestLimits.max_decoded_bytes``. Every
result is cached per index and read-only. Consumer: the other modules of :mod:`workers.gltf`. Inverse: none.

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.6 (accessors, sparse accessors, normalized integers).
.. [KHR_mesh_quantization], [KHR_draco_mesh_compression], [EXT_meshopt_compression] Khronos glTF extensions.
"""

from __future__ import annotations

import numpy as np

from workers.gltf import compression as gc
from workers.gltf.container import Files, decode_data_uri, map_file, split_uri
from workers.gltf.document import Document, is_int, lookup
from workers.gltf.errors import err, invalid
from workers.gltf.limits import IngestLimits, check_binary

__all__ = ["Accessors", "COMPONENT_DTYPES", "TYPE_SIZES", "INDEX_COMPONENTS"]

COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
"""glTF componentType -> little-endian numpy dtype."""
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
"""glTF accessor type -> components per element."""
INDEX_COMPONENTS = (5121, 5123, 5125)
"""componentTypes allowed for indices: unsigned byte, short, int."""


class Accessors:
    """Buffers, buffer views and accessors of one document, decoded on first use and cached.

    Parameters
    ----------
    doc : Document
        The parsed glTF.
    bin_chunk : (Path, int, int) or None
        GLB binary chunk: file, byte offset, byte length.
    files : Files
        Resolves relative URIs (nothing for loose uploads; zip members otherwise).
    limits : IngestLimits
        ``max_bytes`` bounds accessors without a buffer view; ``max_decoded_bytes`` compressed data.
    label : str
        The upload's name, for messages.
    """

    def __init__(self, doc: Document, bin_chunk, files: Files, limits: IngestLimits, label: str):
        self.doc = doc
        self.bin_chunk = bin_chunk
        self.files = files
        self.limits = limits
        self.label = label
        self._buffers: dict[int, np.ndarray] = {}
        self._accessors: dict[int, np.ndarray] = {}
        self._meshopt_views: dict[int, np.ndarray] = {}  # bufferView -> decoded bytes
        self._draco: dict[int, gc.DracoGeometry] = {}  # Draco bufferView -> decoded mesh
        self._decoded_bytes = 0  # Draco + meshopt output so far (IngestLimits.max_decoded_bytes)

    # ------------------------------------------------------------------ buffers and views
    def buffer(self, idx, what: str) -> np.ndarray:
        """Buffer bytes as a read-only (byteLength,) uint8 array (memory-mapped where it is a file)."""
        if is_int(idx) and idx in self._buffers:
            return self._buffers[idx]
        b = self.doc.item("buffers", idx, what)
        length = b.get("byteLength")
        if not is_int(length) or length < 1:
            raise invalid(f"buffers[{idx}].byteLength must be a positive integer")
        if "uri" in b:
            kind, rel = split_uri(b["uri"], f"buffer {idx}")
            if kind == "data":
                data = np.frombuffer(decode_data_uri(rel, f"buffer {idx}"), np.uint8)
            else:
                data = map_file(self.files.path(rel, f"buffer {idx}"), 0, None)
        elif idx == 0 and self.bin_chunk is not None:
            data = map_file(*self.bin_chunk)
        else:
            if self.meshopt_fallback(b):
                raise invalid(
                    f"{what} reads buffers[{idx}], a meshopt fallback buffer without data (only "
                    "meshopt-compressed bufferViews may refer to it)"
                )
            raise invalid(f"buffers[{idx}] has no uri and is not the GLB binary chunk")
        check_binary(data, length, idx, b)  # text read as floats is ~1e31 garbage: refuse it by name
        if data.size < length:
            raise invalid(f"buffers[{idx}] declares {length} bytes but holds {data.size}")
        data = data[:length]
        self._buffers[idx] = data
        return data

    def view_bytes(self, view_idx, what: str) -> tuple[np.ndarray, dict]:
        """(byteLength,) uint8 slice of a buffer view, range-checked, and the view object."""
        view = self.doc.item("bufferViews", view_idx, what)
        what_v = f"bufferViews[{view_idx}]"
        ext = self.doc.exts(view)
        if any(name in ext for name in gc.MESHOPT_EXTENSIONS):
            return self._meshopt_view(view_idx, view, ext), view  # the view's own buffer is a fallback
        buf = self.buffer(view.get("buffer"), what_v)
        off = view.get("byteOffset", 0)
        length = view.get("byteLength")
        if not is_int(off) or off < 0 or not is_int(length) or length < 1:
            raise invalid(f"{what_v} needs a non-negative byteOffset and a positive byteLength")
        if off + length > buf.size:
            raise invalid(
                f"{what_v} (bytes {off}..{off + length}) runs past the end of buffer {view.get('buffer')} "
                f"({buf.size} bytes)"
            )
        return buf[off : off + length], view

    # ------------------------------------------------------------------ compressed geometry
    def meshopt_fallback(self, buffer: dict) -> bool:
        """Whether a buffer is marked ``{"fallback": true}`` by a meshopt extension [EXT_meshopt_compression]."""
        exts = self.doc.exts(buffer)
        return any(isinstance(exts.get(n), dict) and exts[n].get("fallback") is True for n in gc.MESHOPT_EXTENSIONS)

    def count_decoded(self, nbytes: int, what: str) -> None:
        """Charge ``nbytes`` of decoded Draco/meshopt data to ``IngestLimits.max_decoded_bytes``."""
        cap = self.limits.max_decoded_bytes
        cap = 16 * self.limits.max_bytes if cap is None else cap
        self._decoded_bytes += int(nbytes)
        if self._decoded_bytes > cap:
            raise err(
                "decoded_too_large",
                f"'{self.label}': {what} brings its decompressed geometry to {self._decoded_bytes} bytes; "
                f"the limit is {cap} bytes",
            )

    def _meshopt_view(self, view_idx: int, view: dict, ext: dict) -> np.ndarray:
        """(count * byteStride,) uint8 decoded contents of a meshopt-compressed bufferView (cached)."""
        if view_idx in self._meshopt_views:
            return self._meshopt_views[view_idx]
        name = next(n for n in gc.MESHOPT_EXTENSIONS if n in ext)
        what_v = f"bufferViews[{view_idx}] {name}"
        try:
            spec = gc.meshopt_view(name, ext[name], view)
        except gc.CompressionError as exc:
            raise invalid(f"bufferViews[{view_idx}]: {exc}") from exc
        self.count_decoded(spec.decoded_bytes, what_v)  # before decoding: count * byteStride is known
        buf = self.buffer(spec.buffer, what_v)
        end = spec.byte_offset + spec.byte_length
        if end > buf.size:
            raise invalid(
                f"{what_v} (bytes {spec.byte_offset}..{end}) runs past the end of buffer {spec.buffer} "
                f"({buf.size} bytes)"
            )
        try:
            data = gc.decode_meshopt(buf[spec.byte_offset : end], spec)
        except gc.CompressionError as exc:
            raise invalid(f"{what_v}: {exc}") from exc
        self._meshopt_views[view_idx] = data
        return data

    def draco_primitive(self, prim: dict, what: str) -> dict:
        """Decode a ``KHR_draco_mesh_compression`` primitive into the accessors it names.

        The decoded faces and attributes become the cached values of the primitive's ``indices`` and
        attribute accessors (their own ``bufferView``/``sparse`` ignored, as the extension requires:
        Draco wins over an uncompressed fallback), so every later step reads them like any accessor.
        Returns the primitive to read: itself, or a copy with ``mode`` 4 for a TRIANGLE_STRIP (Draco
        decodes triangle lists). Primitives without the extension are returned unchanged.
        """
        ext = self.doc.exts(prim).get("KHR_draco_mesh_compression")
        if ext is None:
            return prim
        what_d = f"{what} KHR_draco_mesh_compression"
        if not isinstance(ext, dict) or not isinstance(ext.get("attributes"), dict):
            raise invalid(f"{what_d} needs a 'bufferView' and an 'attributes' object")
        mode = prim.get("mode", 4)
        if mode not in (4, 5):
            raise invalid(f"{what_d}: mode must be TRIANGLES or TRIANGLE_STRIP, not {mode!r}")
        if "indices" not in prim:
            raise invalid(f"{what_d}: the primitive needs an 'indices' accessor for the decoded faces")
        view_idx = ext.get("bufferView")
        geom = self._draco.get(view_idx) if is_int(view_idx) else None
        if geom is None:
            raw, _ = self.view_bytes(view_idx, what_d)
            try:
                geom = gc.decode_draco(raw)
            except gc.CompressionError as exc:
                raise invalid(f"{what_d}: {exc}") from exc
            self.count_decoded(geom.nbytes, what_d)
            self._draco[view_idx] = geom
        attrs = prim["attributes"]
        targets: dict[int, np.ndarray] = {}
        try:
            for sem, uid in ext["attributes"].items():
                if sem not in attrs:
                    raise gc.CompressionError(f"attribute {sem} is not one of the primitive's attributes")
                if not is_int(uid) or uid not in geom.attributes:
                    raise gc.CompressionError(f"attribute {sem}: the Draco data has no attribute with id {uid!r}")
                acc = self.doc.item("accessors", attrs[sem], what_d)
                dtype = lookup(COMPONENT_DTYPES, acc.get("componentType"))
                ncomp = lookup(TYPE_SIZES, acc.get("type"))
                if dtype is None or ncomp is None:
                    raise gc.CompressionError(f"attribute {sem}: accessors[{attrs[sem]}] has a bad type")
                targets[attrs[sem]] = gc.draco_attribute_as(
                    geom.attributes[uid], dtype, ncomp, bool(acc.get("normalized")), geom.kinds.get(uid, -1)
                )
        except gc.CompressionError as exc:
            raise invalid(f"{what_d}: {exc}") from exc
        idx_acc = self.doc.item("accessors", prim["indices"], what_d)
        declared = idx_acc.get("count")
        if idx_acc.get("componentType") not in INDEX_COMPONENTS or not is_int(declared):
            raise invalid(f"{what_d}: index accessors[{prim['indices']}] must be SCALAR unsigned integers")
        if geom.faces.size > declared:  # the triangle budget was planned from the declared count
            raise invalid(
                f"{what_d} decodes to {geom.faces.shape[0]} triangles, more than its indices accessor "
                f"declares ({declared} indices)"
            )
        idt = COMPONENT_DTYPES[idx_acc["componentType"]].newbyteorder("=")
        if geom.faces.size and int(geom.faces.max()) > np.iinfo(idt).max:
            raise invalid(f"{what_d}: the decoded indices do not fit the indices accessor's {idt.name}")
        faces = geom.faces.reshape(-1, 1).astype(idt)
        faces.setflags(write=False)
        targets[prim["indices"]] = faces
        self._accessors.update(targets)  # refilled before every read: accessors may be shared
        return prim if mode == 4 else {**prim, "mode": 4}

    # ------------------------------------------------------------------ accessors
    def _strided(
        self, raw: np.ndarray, offset, count: int, dtype: np.dtype, ncomp: int, stride: int | None, what: str
    ) -> np.ndarray:
        """(count, ncomp) copy of elements laid out in ``raw`` from ``offset`` every ``stride`` bytes."""
        if not is_int(offset) or offset < 0:
            raise invalid(f"{what} byteOffset must be a non-negative integer")
        elem = dtype.itemsize * ncomp
        stride = stride or elem
        if stride < elem:
            raise invalid(f"{what} byteStride {stride} is smaller than its element ({elem} bytes)")
        need = offset + stride * (count - 1) + elem
        if need > raw.size:
            raise invalid(f"{what} needs {need} bytes but its buffer view has {raw.size}")
        window = np.ascontiguousarray(raw[offset : offset + need])
        arr = np.ndarray((count, ncomp), dtype=dtype, buffer=window, offset=0, strides=(stride, dtype.itemsize))
        return np.array(arr, dtype=dtype.newbyteorder("="), copy=True)

    def accessor(self, idx, what: str) -> np.ndarray:
        """Raw accessor values, (count, n) in the accessor's component dtype (sparse applied).

        ``n`` is 1/2/3/4 for SCALAR/VEC2/VEC3/VEC4 and 4/9/16 for float MAT2/3/4 (column-major).
        """
        if is_int(idx) and idx in self._accessors:
            return self._accessors[idx]
        acc = self.doc.item("accessors", idx, what)
        what_a = f"accessors[{idx}]"
        dtype = lookup(COMPONENT_DTYPES, acc.get("componentType"))
        if dtype is None:
            raise invalid(f"{what_a} has unknown componentType {acc.get('componentType')!r}")
        ncomp = lookup(TYPE_SIZES, acc.get("type"))
        if ncomp is None:
            raise invalid(f"{what_a} has unknown type {acc.get('type')!r}")
        if acc["type"].startswith("MAT") and dtype.kind != "f":
            raise err("unsupported", f"{what_a}: integer matrices (with column padding) are not supported")
        count = acc.get("count")
        if not is_int(count) or count < 1:
            raise invalid(f"{what_a} count must be a positive integer")
        view_idx = acc.get("bufferView")
        if view_idx is None:
            nbytes = count * ncomp * dtype.itemsize
            if nbytes > self.limits.max_bytes:  # no more than an upload could hold
                raise err(
                    "too_large", f"{what_a} declares {nbytes} bytes of zeros; the limit is {self.limits.max_bytes}"
                )
            out = np.zeros((count, ncomp), dtype.newbyteorder("="))
        else:
            raw, view = self.view_bytes(view_idx, what_a)
            stride = view.get("byteStride")
            if stride is not None and (not is_int(stride) or stride < 1):
                raise invalid(f"bufferViews[{view_idx}].byteStride must be a positive integer")
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
            raise invalid(f"{what}.sparse needs 'count', 'indices' and 'values'")
        n = sparse.get("count")
        if not is_int(n) or not 1 <= n <= out.shape[0]:
            raise invalid(f"{what}.sparse.count must be between 1 and the accessor count")
        ind, val = sparse["indices"], sparse["values"]
        idt = lookup(COMPONENT_DTYPES, ind.get("componentType"))
        if ind.get("componentType") not in INDEX_COMPONENTS:
            raise invalid(f"{what}.sparse.indices componentType must be an unsigned integer type")
        raw_i, _ = self.view_bytes(ind.get("bufferView"), f"{what}.sparse.indices")
        indices = self._strided(raw_i, ind.get("byteOffset", 0), n, idt, 1, None, f"{what}.sparse.indices")[:, 0]
        raw_v, _ = self.view_bytes(val.get("bufferView"), f"{what}.sparse.values")
        values = self._strided(raw_v, val.get("byteOffset", 0), n, dtype, ncomp, None, f"{what}.sparse.values")
        if indices.size and int(indices.max()) >= out.shape[0]:
            raise invalid(f"{what}.sparse.indices reach {int(indices.max())}, past the accessor count {out.shape[0]}")
        out = out.copy()
        out[indices.astype(np.int64)] = values
        return out

    def accessor_float(self, idx, what: str, ncomp: tuple[int, ...] | None = None) -> np.ndarray:
        """Accessor as float32 (count, n), integer components normalized per the spec when ``normalized``."""
        acc = self.doc.item("accessors", idx, what)
        arr = self.accessor(idx, what)
        if ncomp is not None and arr.shape[1] not in ncomp:
            raise invalid(
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
        acc = self.doc.item("accessors", idx, what)
        if acc.get("componentType") not in INDEX_COMPONENTS or acc.get("type") != "SCALAR":
            raise invalid(f"{what}: index accessors[{idx}] must be SCALAR unsigned byte/short/int")
        raw = self.accessor(idx, what)[:, 0]
        if raw.size and np.any(raw == np.iinfo(raw.dtype).max):
            raise invalid(
                f"{what}: index accessors[{idx}] holds the primitive restart value {np.iinfo(raw.dtype).max}, "
                "which glTF forbids"
            )
        out = raw.astype(np.int64)
        if out.size and int(out.max()) >= n_vertices:
            raise invalid(f"{what}: index {int(out.max())} is out of range for {n_vertices} vertices")
        return out

    def vertex_attr(self, acc_idx, n_vertices: int, sel: np.ndarray | None, ncomp: int, what: str) -> np.ndarray:
        """A per-vertex float attribute, length-checked against POSITION, restricted to vertices ``sel``."""
        arr = self.accessor_float(acc_idx, what, (ncomp,))
        if arr.shape[0] != n_vertices:
            raise invalid(f"{what} has {arr.shape[0]} elements, POSITION {n_vertices}")
        return arr if sel is None else arr[sel]
