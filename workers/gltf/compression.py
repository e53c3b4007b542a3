"""Decoders for glTF 2.0 geometry compression: ``KHR_draco_mesh_compression`` and
``EXT_meshopt_compression`` / ``KHR_meshopt_compression`` (numpy in, numpy out).

:mod:`workers.gltf.accessors` calls these from small hooks: a Draco primitive's decoded attributes and faces
become the values of the accessors the primitive names [KHR_draco_mesh_compression]; a meshopt
bufferView's decoded bytes replace the view's data [EXT_meshopt_compression]. Everything after that
(accessor normalization, ``KHR_mesh_quantization``, node transforms, skins, morph targets, texture
transforms) is the reader's ordinary path, unchanged.

The decoding itself is done by DracoPy (Google's Draco decoder) and ``meshopt`` (meshoptimizer's
decoders); this module validates the extension JSON, runs the decoder, checks what comes back and turns
every failure into :class:`CompressionError` (the reader reports it as ``invalid_gltf``).

References
----------
.. [KHR_draco_mesh_compression] Khronos glTF extension, "KHR_draco_mesh_compression" (Draco bitstream
   2.2): the primitive's extension names a ``bufferView`` and maps attribute semantics to Draco
   attribute unique ids; the primitive's accessors keep count/componentType/type/normalized and ignore
   their ``bufferView``/``byteOffset``; ``mode`` is TRIANGLES or TRIANGLE_STRIP.
.. [EXT_meshopt_compression] Khronos glTF extension, "EXT_meshopt_compression" (and its successor
   "KHR_meshopt_compression", which adds the COLOR filter and vertex codec version 1): on a bufferView,
   ``{buffer, byteOffset, byteLength, byteStride, count, mode, filter}``; mode ATTRIBUTES, TRIANGLES or
   INDICES; filter NONE, OCTAHEDRAL, QUATERNION, EXPONENTIAL (KHR: also COLOR); the decoded
   ``count * byteStride`` bytes are the view's contents; the view's own ``buffer`` may be a fallback
   placeholder without data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "CompressionError",
    "DracoGeometry",
    "MeshoptView",
    "decode_draco",
    "draco_attribute_as",
    "meshopt_view",
    "decode_meshopt",
    "MESHOPT_EXTENSIONS",
]

#: bufferView / buffer extensions that carry meshopt-compressed data, in the order they are looked for.
MESHOPT_EXTENSIONS = ("KHR_meshopt_compression", "EXT_meshopt_compression")

_MESHOPT_MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
_MESHOPT_FILTERS = {
    "EXT_meshopt_compression": ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL"),
    "KHR_meshopt_compression": ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR"),
}
_DRACO_COLOR = 2  # draco::GeometryAttribute::COLOR (DracoPy.AttributeType.COLOR)


class CompressionError(ValueError):
    """Compressed data or its extension JSON is invalid; ``str(err)`` is one sentence for the user."""


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


# ---------------------------------------------------------------------------------------------- Draco


@dataclass
class DracoGeometry:
    """One decoded Draco mesh.

    Attributes
    ----------
    faces : np.ndarray
        (F, 3) uint32 point indices, counter-clockwise as encoded. Draco may reorder points and faces
        and drops degenerate faces, so F can be smaller than the encoder's input.
    n_points : int
        N, the number of decoded points (every attribute has N rows).
    attributes : dict[int, np.ndarray]
        Draco attribute unique id -> (N, k) values in the attribute's decoded type; quantized
        attributes (positions, normals, texture coordinates) come back dequantized as float32.
    kinds : dict[int, int]
        Draco attribute unique id -> ``draco::GeometryAttribute::Type`` (0 position, 1 normal,
        2 color, 3 texcoord, 4 generic).
    """

    faces: np.ndarray
    n_points: int
    attributes: dict[int, np.ndarray]
    kinds: dict[int, int]

    @property
    def nbytes(self) -> int:
        """Bytes held by the decoded arrays."""
        return int(self.faces.nbytes + sum(a.nbytes for a in self.attributes.values()))


def decode_draco(data: bytes | np.ndarray) -> DracoGeometry:
    """Decode a Draco mesh bitstream [KHR_draco_mesh_compression].

    Parameters
    ----------
    data : bytes or np.ndarray
        The compressed bytes ((L,) uint8 when an array): the contents of the extension's bufferView.

    Returns
    -------
    DracoGeometry
        Faces (F, 3) uint32, and (N, k) arrays by attribute unique id.

    Raises
    ------
    CompressionError
        The bytes are not a Draco mesh (corrupt, truncated, a point cloud), or the decoded faces index
        points that do not exist.
    """
    import DracoPy

    raw = data.tobytes() if isinstance(data, np.ndarray) else bytes(data)
    try:
        mesh = DracoPy.decode(raw)
    except MemoryError:
        raise
    except Exception as exc:  # DracoPy.FileTypeException and friends
        raise CompressionError(f"the Draco data cannot be decoded ({type(exc).__name__}: {exc})") from exc
    faces = getattr(mesh, "faces", None)
    if not isinstance(mesh, DracoPy.DracoMesh) or faces is None:
        raise CompressionError("the Draco data is a point cloud, not a triangle mesh")
    faces = np.asarray(faces)
    if faces.size == 0:
        faces = faces.reshape(0, 3)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.dtype.kind not in "ui":
        raise CompressionError(f"the Draco data decodes to faces of shape {faces.shape}, not (F, 3) integers")
    attributes: dict[int, np.ndarray] = {}
    kinds: dict[int, int] = {}
    n_points = None
    for att in mesh.attributes:
        uid = att.get("unique_id")
        values = np.asarray(att.get("data"))
        if values.ndim == 1:
            values = values.reshape(-1, 1)
        if values.ndim != 2:
            raise CompressionError(f"Draco attribute {uid} decodes to shape {values.shape}")
        if n_points is None:
            n_points = values.shape[0]
        elif values.shape[0] != n_points:
            raise CompressionError(
                f"Draco attribute {uid} has {values.shape[0]} values, not one per point ({n_points})"
            )
        attributes[int(uid)] = values
        kinds[int(uid)] = int(att.get("attribute_type", -1))
    if n_points is None:
        n_points = int(np.asarray(mesh.points).reshape(-1, 3).shape[0])
    if faces.size and (int(faces.max()) >= n_points or int(faces.min()) < 0):
        raise CompressionError(f"the Draco faces index point {int(faces.max())} of {n_points}")
    return DracoGeometry(faces.astype(np.uint32, copy=False), int(n_points), attributes, kinds)


def draco_attribute_as(
    values: np.ndarray, dtype: np.dtype, ncomp: int, normalized: bool, kind: int = -1
) -> np.ndarray:
    """Decoded Draco values in the layout of the accessor that refers to them.

    Parameters
    ----------
    values : np.ndarray
        (N, k) decoded attribute values (:attr:`DracoGeometry.attributes`).
    dtype : np.dtype
        The accessor's component type (native byte order is returned).
    ncomp : int
        The accessor type's component count; must equal k.
    normalized : bool
        The accessor's ``normalized`` flag: float values are stored as ``round(v * max)`` of an integer
        ``dtype`` (the inverse of glTF's normalization), which the reader then undoes.
    kind : int
        Draco attribute type; integer COLOR values read into a float accessor are normalized by their
        type's maximum (Draco stores colours normalized).

    Returns
    -------
    np.ndarray
        (N, ncomp) read-only array of ``dtype``.

    Raises
    ------
    CompressionError
        Component count mismatch, or integer values the accessor's type cannot hold.
    """
    values = np.asarray(values)
    if values.ndim == 1:
        values = values.reshape(-1, 1)
    if values.shape[1] != ncomp:
        raise CompressionError(f"the Draco attribute has {values.shape[1]} components, the accessor {ncomp}")
    dtype = np.dtype(dtype).newbyteorder("=")
    if values.dtype == dtype:
        out = values.copy()
    elif dtype.kind == "f":
        out = values.astype(dtype)
        if values.dtype.kind in "ui" and kind == _DRACO_COLOR:
            out /= dtype.type(np.iinfo(values.dtype).max)
    else:
        info = np.iinfo(dtype)
        if values.dtype.kind == "f":
            if not np.isfinite(values).all():
                raise CompressionError("the Draco attribute holds NaN or infinite values for an integer accessor")
            scaled = values.astype(np.float64) * (info.max if normalized else 1.0)
            v = np.rint(scaled)
        else:
            v = values.astype(np.int64)
        if v.size and (v.min() < info.min or v.max() > info.max):
            raise CompressionError(f"the Draco attribute's values do not fit the accessor's {dtype.name} components")
        out = v.astype(dtype)
    out.setflags(write=False)
    return out


# ---------------------------------------------------------------------------------------------- meshopt


@dataclass(frozen=True)
class MeshoptView:
    """A validated meshopt bufferView extension [EXT_meshopt_compression].

    Attributes
    ----------
    buffer, byte_offset, byte_length : int
        Where the compressed bytes are.
    stride, count : int
        The decoded layout: ``count`` elements of ``stride`` bytes.
    mode : str
        ``"ATTRIBUTES"``, ``"TRIANGLES"`` or ``"INDICES"``.
    filter : str
        ``"NONE"``, ``"OCTAHEDRAL"``, ``"QUATERNION"``, ``"EXPONENTIAL"`` or (KHR only) ``"COLOR"``.
    """

    buffer: int
    byte_offset: int
    byte_length: int
    stride: int
    count: int
    mode: str
    filter: str

    @property
    def decoded_bytes(self) -> int:
        """``count * stride``: the size of the decoded view."""
        return self.count * self.stride


def meshopt_view(name: str, ext, view: dict) -> MeshoptView:
    """Validate a bufferView's meshopt extension object against the rules of its spec.

    Parameters
    ----------
    name : str
        ``"EXT_meshopt_compression"`` or ``"KHR_meshopt_compression"``.
    ext : object
        The extension JSON (expected: a dict).
    view : dict
        The parent bufferView (its ``byteStride``, when present, must equal the extension's).

    Returns
    -------
    MeshoptView

    Raises
    ------
    CompressionError
        A missing or out-of-range property, or a mode/filter/stride combination the spec forbids.
    """
    if not isinstance(ext, dict):
        raise CompressionError(f"{name} must be an object")

    def integer(key: str, default=None, minimum: int = 0) -> int:
        v = ext.get(key, default)
        if not _is_int(v) or v < minimum:
            raise CompressionError(f"{name}.{key} must be an integer >= {minimum}")
        return v

    buffer = integer("buffer")
    byte_offset = integer("byteOffset", 0)
    byte_length = integer("byteLength", minimum=1)
    stride = integer("byteStride", minimum=1)
    count = integer("count", minimum=1)
    mode = ext.get("mode")
    if mode not in _MESHOPT_MODES:
        raise CompressionError(f"{name}.mode {mode!r} is not one of {', '.join(_MESHOPT_MODES)}")
    filt = ext.get("filter", "NONE")
    filters = _MESHOPT_FILTERS.get(name, _MESHOPT_FILTERS["KHR_meshopt_compression"])
    if filt not in filters:
        raise CompressionError(f"{name}.filter {filt!r} is not one of {', '.join(filters)}")
    if mode == "ATTRIBUTES":
        if stride % 4 or stride > 256:
            raise CompressionError(f"{name}: ATTRIBUTES byteStride {stride} must be a multiple of 4 up to 256")
    else:
        if stride not in (2, 4):
            raise CompressionError(f"{name}: {mode} byteStride must be 2 or 4, not {stride}")
        if filt != "NONE":
            raise CompressionError(f"{name}: {mode} data cannot use the {filt} filter")
        if mode == "TRIANGLES" and count % 3:
            raise CompressionError(f"{name}: TRIANGLES count {count} is not a multiple of 3")
    if filt in ("OCTAHEDRAL", "COLOR") and stride not in (4, 8):
        raise CompressionError(f"{name}: the {filt} filter needs byteStride 4 or 8, not {stride}")
    if filt == "QUATERNION" and stride != 8:
        raise CompressionError(f"{name}: the QUATERNION filter needs byteStride 8, not {stride}")
    view_stride = view.get("byteStride")
    if view_stride is not None and view_stride != stride:
        raise CompressionError(f"{name}.byteStride {stride} differs from the bufferView's byteStride {view_stride}")
    return MeshoptView(buffer, byte_offset, byte_length, stride, count, mode, filt)


def decode_meshopt(data: bytes | np.ndarray, spec: MeshoptView) -> np.ndarray:
    """Decode one meshopt-compressed bufferView [EXT_meshopt_compression] Appendix A/B.

    Parameters
    ----------
    data : bytes or np.ndarray
        The compressed bytes ((byteLength,) uint8 when an array).
    spec : MeshoptView
        Mode, filter and the decoded layout.

    Returns
    -------
    np.ndarray
        (count * stride,) uint8, read-only: the view's decoded contents, filter applied. TRIANGLES data
        keeps every triangle and its winding (the codec may rotate a triangle's corners).

    Raises
    ------
    CompressionError
        Malformed or truncated data.
    """
    import meshopt

    src = np.ascontiguousarray(np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data, np.uint8)
    try:
        out = meshopt.decode_gltf_buffer(src, spec.count, spec.stride, spec.mode, spec.filter)
    except MemoryError:
        raise
    except Exception as exc:  # ValueError("Malformed buffer data: -2") and friends
        raise CompressionError(f"the meshopt {spec.mode} data cannot be decoded ({exc})") from exc
    out = np.ascontiguousarray(out).view(np.uint8).reshape(-1)
    if out.size != spec.decoded_bytes:
        raise CompressionError(f"the meshopt data decoded to {out.size} bytes, expected {spec.decoded_bytes}")
    out.setflags(write=False)
    return out
