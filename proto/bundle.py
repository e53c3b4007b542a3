"""Kiln bundles: a folder (or a .zip of it) with ``manifest.json`` and one file per artifact.

Byte-level description in ``proto/bundle.md``. In short::

    <bundle>/manifest.json       the Manifest model (proto.models), UTF-8 JSON
    <bundle>/<name>.ktx2         textures / volumes (proto.ktx2 subset)
    <bundle>/<name>.npy          any other array (numpy .npy v1+, no pickles)
    <bundle>/<name>.json         a JSON object (metrics, tables)
    <bundle>/<name>.png          previews (written by the evaluate stage)
    <bundle>/<name>.glb          the baked scene as glTF 2.0 binary (written by the ingest stage)

Every write is atomic (temp file in the same folder + ``os.replace``); every read
checks each file's byte size and sha256 against the manifest.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Literal

import numpy as np

from proto.atlas import atlas_add_border
from proto.atomic import atomic_write_bytes
from proto.ktx2 import KTX2Error, decode_ktx2, encode_ktx2
from proto.models import FORMAT_VERSION, ArtifactInfo, Manifest

__all__ = [
    "BundleError",
    "MANIFEST_NAME",
    "NAME_RE",
    "artifact_file_name",
    "load_artifact",
    "open_bundle",
    "read_manifest",
    "with_artifact",
    "write_artifact",
    "write_manifest",
    "zip_bundle",
]

MANIFEST_NAME = "manifest.json"
NAME_RE = re.compile(r"[a-z0-9_.-]{1,64}")
"""Artifact names: lower-case letters, digits, ``_ . -``; 1..64 chars; not starting with a dot."""
_FILE_RE = re.compile(r"[a-z0-9_][a-z0-9_.-]{0,63}\.(ktx2|npy|json|png|glb)")
_EXTENSIONS = {"ktx2": "ktx2", "npy": "npy", "json": "json", "png": "png", "glb": "glb"}
GLB_MAGIC = b"glTF"
"""The first bytes of a glTF 2.0 binary file (its version, 2, follows as a little-endian uint32)."""
ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)
"""Timestamp of every zip entry, so that the same bundle always zips to the same bytes."""
MAX_ARTIFACT_BYTES = 1 << 32
DEFAULT_ZSTD_LEVEL = 3
"""Zstandard level of a KTX2 artifact written without ``zstd_level`` (0 writes it uncompressed): level 3 keeps
within ~15% of level 10's size at 4x its speed on this project's atlases (tests/bench/bench_formats.py)."""
TABLE_FORMATS = {"f4": "R32_SFLOAT", "f2": "R16_SFLOAT", "i4": "R32_SINT", "u4": "R32_UINT", "u2": "R16_UINT",
                 "u1": "R8_UINT"}
"""KTX2 format of a table artifact (``write_artifact(..., table=True)``) by numpy dtype (kind + bytes)."""
_CHUNK = 1 << 20


class BundleError(ValueError):
    """A bundle that is malformed, incomplete or whose files do not match the manifest."""


# --------------------------------------------------------------------------- helpers


def artifact_file_name(name: str, format: str) -> str:
    """``<name>.<ext>`` after checking ``name`` (ValueError if it is not allowed)."""
    if not isinstance(name, str) or not NAME_RE.fullmatch(name) or name.startswith("."):
        raise ValueError(f"artifact name {name!r} must match [a-z0-9_.-]{{1,64}} and not start with '.'")
    if format not in _EXTENSIONS:
        raise ValueError(f"artifact format {format!r} must be one of {sorted(_EXTENSIONS)}")
    file = f"{name}.{_EXTENSIONS[format]}"
    if file == MANIFEST_NAME:
        raise ValueError(f"artifact name {name!r} would overwrite {MANIFEST_NAME}")
    return file


def _dtype_str(dtype: np.dtype) -> str:
    """numpy's short name ('float32') where it round-trips, else the full type string."""
    try:
        if np.dtype(dtype.name) == dtype:
            return dtype.name
    except TypeError:
        pass
    return dtype.str


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _encode_json(obj: dict[str, Any]) -> bytes:
    try:
        text = json.dumps(obj, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False,
                          default=_json_default)
    except ValueError as exc:  # NaN / inf: JSON.parse in a browser would refuse them
        raise ValueError(f"JSON artifact holds a non-finite number: {exc}") from exc
    return (text + "\n").encode("utf-8")


def _sha256_file(path: Path) -> tuple[str, int]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


# --------------------------------------------------------------------------- writing


def write_artifact(bundle_dir: str | os.PathLike[str], name: str, array: np.ndarray | dict[str, Any],
                   stage: str, *, format: Literal["ktx2", "npy", "json", "png", "glb"] = "ktx2",
                   vk_format: int | str | None = None, zstd_level: int | None = None,
                   description: str = "", meta: dict[str, Any] | None = None,
                   volume: bool | None = None, table: bool = False) -> ArtifactInfo:
    """Write one artifact file into ``bundle_dir`` (created if missing); return its manifest entry.

    * ``ktx2``: ``array`` is ``(H, W[, C])`` or ``(D, H, W, C)`` (``volume=True`` makes a
      3-axis array a one-channel ``(D, H, W)`` volume); ``vk_format`` as in
      :func:`proto.ktx2.write_ktx2`; ``zstd_level`` None is :data:`DEFAULT_ZSTD_LEVEL`, 0 no
      supercompression. The format details go to ``meta["ktx2"]``.
      ``table=True``: any array of shape ``(n0, n1, ...)`` as a one-channel 2D texture of
      height n0 and width n1·n2·… (1 for a 1-D array) in the format :data:`TABLE_FORMATS`
      gives its dtype (``meta["ktx2"]["table"] = true``; proto/bundle.md 3); it loads back
      in its own shape.
    * ``npy``: any non-object array, saved with ``allow_pickle=False``.
    * ``json``: ``array`` is a dict (numpy scalars/arrays are converted; NaN refused).
    * ``png`` / ``glb``: ``array`` is the encoded file's bytes (PNG signature / GLB header checked).

    ``shape``/``dtype`` describe the array :func:`load_artifact` gives back (``[]`` and
    ``"dict"`` for JSON). ``sha256`` and ``bytes`` are computed from the written file.
    """
    file = artifact_file_name(name, format)
    meta = dict(meta or {})
    if format == "ktx2":
        arr = np.asarray(array)
        level = DEFAULT_ZSTD_LEVEL if zstd_level is None else (zstd_level or None)
        texture = arr
        if table:
            key = f"{arr.dtype.kind}{arr.dtype.itemsize}"
            if key not in TABLE_FORMATS or arr.ndim == 0 or arr.size == 0:
                raise ValueError(f"table artifact {name!r}: dtype {arr.dtype} shape {arr.shape} has no table format; "
                                 f"convert to one of {sorted(TABLE_FORMATS)}")
            vk_format = vk_format or TABLE_FORMATS[key]
            texture = arr.reshape(arr.shape[0], -1 if arr.ndim > 1 else 1, 1)
        data = encode_ktx2(texture, vk_format, level, volume=False if table else volume)
        _, info = decode_ktx2(data)  # cheap for our sizes; proves the file reads back
        shape, dtype = list(arr.shape), info["dtype"]
        dims = [info["pixel_width"], info["pixel_height"], info["pixel_depth"]]
        meta.setdefault("ktx2", {
            "vk_format": info["vk_format"],
            "format": info["format_name"],
            "supercompression": info["supercompression_name"],
            "pixel_size": info["pixel_size"],
            "size": dims,  # width, height, depth (0 for 2D)
            **({"table": True} if table else {}),
        })
    elif format == "npy":
        if vk_format is not None or zstd_level is not None or table:
            raise ValueError("vk_format/zstd_level/table apply to ktx2 artifacts only")
        arr = np.asarray(array)
        if arr.dtype.hasobject:
            raise ValueError(f"npy artifact {name!r}: object arrays cannot be saved without pickles")
        buf = io.BytesIO()
        np.save(buf, arr, allow_pickle=False)
        data = buf.getvalue()
        shape, dtype = list(arr.shape), _dtype_str(arr.dtype)
    elif format == "json":
        if not isinstance(array, dict):
            raise ValueError(f"json artifact {name!r} must be a dict, got {type(array).__name__}")
        data = _encode_json(array)
        shape, dtype = [], "dict"
    elif format == "png":  # an encoded image (previews); loads back as its bytes
        data = bytes(array)
        if not data.startswith(b"\x89PNG\r\n\x1a\n"):
            raise ValueError(f"png artifact {name!r} must be PNG-encoded bytes")
        shape, dtype = [len(data)], "uint8"
    elif format == "glb":  # glTF 2.0 binary (the baked scene); loads back as its bytes
        data = bytes(array)
        if len(data) < 12 or not data.startswith(GLB_MAGIC) or int.from_bytes(data[4:8], "little") != 2 \
                or int.from_bytes(data[8:12], "little") != len(data):
            raise ValueError(f"glb artifact {name!r} must be glTF 2.0 binary bytes (header glTF, version 2, length)")
        shape, dtype = [len(data)], "uint8"
    else:  # pragma: no cover - artifact_file_name checked the format
        raise ValueError(format)

    bundle = Path(bundle_dir)
    bundle.mkdir(parents=True, exist_ok=True)
    path = bundle / file
    atomic_write_bytes(path, data)
    sha, size = _sha256_file(path)
    return ArtifactInfo(name=name, file=file, format=format, shape=shape, dtype=dtype, bytes=size,
                        sha256=sha, stage=stage, description=description, meta=meta)


def with_artifact(manifest: Manifest, info: ArtifactInfo) -> Manifest:
    """A copy of ``manifest`` with ``info`` added, or replacing the entry of the same name."""
    others = [a for a in manifest.artifacts if a.name != info.name]
    if len(others) == len(manifest.artifacts):
        return manifest.model_copy(update={"artifacts": [*others, info]})
    return manifest.model_copy(update={"artifacts": [info if a.name == info.name else a
                                                     for a in manifest.artifacts]})


def _check_manifest(manifest: Manifest) -> None:
    names, files = set(), set()
    for a in manifest.artifacts:
        if a.name in names:
            raise BundleError(f"manifest lists artifact {a.name!r} twice")
        if a.file in files:
            raise BundleError(f"manifest lists file {a.file!r} twice")
        if not _FILE_RE.fullmatch(a.file) or a.file == MANIFEST_NAME:
            raise BundleError(f"artifact {a.name!r}: bad file name {a.file!r}")
        if not a.file.endswith("." + _EXTENSIONS[a.format]):
            raise BundleError(f"artifact {a.name!r}: file {a.file!r} does not match format {a.format!r}")
        if not re.fullmatch(r"[0-9a-f]{64}", a.sha256) or a.bytes < 0:
            raise BundleError(f"artifact {a.name!r}: bad sha256 or byte size")
        names.add(a.name)
        files.add(a.file)


def write_manifest(bundle_dir: str | os.PathLike[str], manifest: Manifest) -> Path:
    """Write ``manifest.json`` atomically (2-space indented JSON, trailing newline)."""
    _check_manifest(manifest)  # BundleError (a ValueError) on duplicate or unsafe entries
    bundle = Path(bundle_dir)
    bundle.mkdir(parents=True, exist_ok=True)
    path = bundle / MANIFEST_NAME
    atomic_write_bytes(path, (manifest.model_dump_json(indent=2) + "\n").encode("utf-8"))
    return path


# --------------------------------------------------------------------------- reading


def _parse_manifest(data: bytes) -> Manifest:
    try:
        raw = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise BundleError(f"{MANIFEST_NAME} is not valid JSON: {exc}") from exc
    version = raw.get("format_version") if isinstance(raw, dict) else None
    if isinstance(version, int) and version > FORMAT_VERSION:
        raise BundleError(f"bundle format_version {version} is newer than this reader ({FORMAT_VERSION})")
    try:
        manifest = Manifest.model_validate(raw)
    except ValueError as exc:  # pydantic.ValidationError is a ValueError
        raise BundleError(f"{MANIFEST_NAME} does not match the Manifest schema: {exc}") from exc
    _check_manifest(manifest)
    return manifest


def read_manifest(path: str | os.PathLike[str]) -> Manifest:
    """The manifest of a bundle folder or .zip, validated (no artifact is read)."""
    with _BundleReader(Path(path)) as reader:
        return reader.manifest


def load_artifact(path_or_bytes: str | os.PathLike[str] | bytes | bytearray | memoryview,
                  info: ArtifactInfo, *, verify: bool = True) -> np.ndarray | dict[str, Any]:
    """Decode one artifact file; with ``verify`` its size and sha256 must match ``info``.

    KTX2 arrays come back in ``info.shape`` (e.g. without the channel axis when written
    that way, or a table's own shape: any shape with the texture's number of values, read in
    level order), except an octahedral atlas stored without its tile borders (``meta.stored_border`` 0,
    ``meta.texels`` n): it comes back with them, (rows·(n+2), cols·(n+2), C) (:func:`proto.atlas.atlas_add_border`);
    PNG previews and GLB scenes come back as their encoded bytes (1-D uint8).
    """
    if isinstance(path_or_bytes, (str, os.PathLike)):
        data = Path(path_or_bytes).read_bytes()
    else:
        data = bytes(path_or_bytes)
    where = f"artifact {info.name!r} ({info.file})"
    if verify:
        if len(data) != info.bytes:
            raise BundleError(f"{where}: {len(data)} bytes, manifest says {info.bytes}")
        sha = hashlib.sha256(data).hexdigest()
        if sha != info.sha256:
            raise BundleError(f"{where}: sha256 {sha} does not match the manifest's {info.sha256}")
    if info.format == "ktx2":
        try:
            arr, _ = decode_ktx2(data)
        except KTX2Error as exc:
            raise BundleError(f"{where}: {exc}") from exc
        want = tuple(info.shape)
        table = bool((info.meta.get("ktx2") or {}).get("table"))
        if want != arr.shape and not (arr.shape[-1] == 1 and want == arr.shape[:-1]) \
                and not (table and int(np.prod(want, dtype=np.int64)) == arr.size):
            raise BundleError(f"{where}: texture of shape {arr.shape} does not fit manifest shape {info.shape}")
        arr = _check_dtype(arr.reshape(info.shape), info, where)
        if info.meta.get("stored_border") == 0:      # a DDGI atlas stored without its tile borders (bundle.md 5.1)
            arr = atlas_add_border(arr, int(info.meta["texels"]))
        return arr
    if info.format == "npy":
        try:
            arr = np.load(io.BytesIO(data), allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise BundleError(f"{where}: not a readable .npy file: {exc}") from exc
        if list(arr.shape) != list(info.shape):
            raise BundleError(f"{where}: shape {list(arr.shape)} != manifest shape {info.shape}")
        return _check_dtype(arr, info, where)
    if info.format == "json":
        try:
            obj = json.loads(data.decode("utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise BundleError(f"{where}: not valid UTF-8 JSON: {exc}") from exc
        if not isinstance(obj, dict):
            raise BundleError(f"{where}: holds a {type(obj).__name__}, not a JSON object")
        return obj
    if info.format == "png":
        if not data.startswith(b"\x89PNG\r\n\x1a\n"):
            raise BundleError(f"{where}: not a PNG file")
        return np.frombuffer(data, dtype=np.uint8).copy()
    if info.format == "glb":
        if not data.startswith(GLB_MAGIC):
            raise BundleError(f"{where}: not a glTF binary (GLB) file")
        return np.frombuffer(data, dtype=np.uint8).copy()
    raise BundleError(f"{where}: unknown format {info.format!r}")  # pragma: no cover


def _check_dtype(arr: np.ndarray, info: ArtifactInfo, where: str) -> np.ndarray:
    try:
        want = np.dtype(info.dtype)
    except TypeError as exc:
        raise BundleError(f"{where}: manifest dtype {info.dtype!r} is not a numpy dtype") from exc
    if arr.dtype != want and arr.dtype.newbyteorder("=") != want.newbyteorder("="):
        raise BundleError(f"{where}: dtype {arr.dtype} != manifest dtype {info.dtype}")
    return arr


class _BundleReader:
    """Reads member files from a bundle folder or a .zip (root or one top-level folder)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.zip: zipfile.ZipFile | None = None
        self.prefix = ""
        if path.is_dir():
            if not (path / MANIFEST_NAME).is_file():
                raise BundleError(f"{path}: no {MANIFEST_NAME}")
        elif path.is_file():
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as exc:
                raise BundleError(f"{path}: not a bundle folder or zip: {exc}") from exc
            names = set(self.zip.namelist())
            if MANIFEST_NAME not in names:
                tops = [n[: -len(MANIFEST_NAME)] for n in names
                        if n.endswith("/" + MANIFEST_NAME) and n.count("/") == 1]
                if len(tops) != 1:
                    self.zip.close()
                    raise BundleError(f"{path}: no {MANIFEST_NAME} at the zip root or in one top folder")
                self.prefix = tops[0]
        else:
            raise BundleError(f"{path}: no such bundle")
        try:
            self.manifest = _parse_manifest(self.read(MANIFEST_NAME, 1 << 26))
        except BaseException:
            self.close()
            raise

    def read(self, file: str, expected: int) -> bytes:
        """Bytes of member ``file``; refuses to read far more than ``expected`` bytes."""
        limit = min(max(expected, 0), MAX_ARTIFACT_BYTES) + 1
        if self.zip is None:
            p = self.path / file
            if not p.is_file():
                raise BundleError(f"{self.path}: missing file {file}")
            with open(p, "rb") as f:
                return f.read(limit)
        try:
            zinfo = self.zip.getinfo(self.prefix + file)
        except KeyError as exc:
            raise BundleError(f"{self.path}: missing file {file}") from exc
        try:
            with self.zip.open(zinfo) as f:
                return f.read(limit)
        except (zipfile.BadZipFile, OSError, EOFError) as exc:  # bad CRC, truncated member
            raise BundleError(f"{self.path}: cannot read {file}: {exc}") from exc

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()

    def __enter__(self) -> "_BundleReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_bundle(path: str | os.PathLike[str]) -> tuple[Manifest, dict[str, np.ndarray | dict[str, Any]]]:
    """Load a bundle folder or .zip: its manifest and every artifact, by name.

    Each file's size and sha256 are checked against the manifest; anything missing,
    altered or malformed raises :class:`BundleError`.
    """
    with _BundleReader(Path(path)) as reader:
        artifacts = {a.name: load_artifact(reader.read(a.file, a.bytes), a) for a in reader.manifest.artifacts}
        return reader.manifest, artifacts


# --------------------------------------------------------------------------- zip


def zip_bundle(bundle_dir: str | os.PathLike[str], out_path: str | os.PathLike[str]) -> Path:
    """Zip a bundle folder deterministically; return ``out_path``.

    Holds ``manifest.json`` and the files the manifest lists (nothing else), at the zip
    root, in sorted order, each dated 1980-01-01 with mode 0644; PNGs are stored,
    everything else deflated (level 6). Each file is checked against the manifest first.
    The zip is written atomically.
    """
    bundle = Path(bundle_dir)
    if not bundle.is_dir():
        raise BundleError(f"{bundle}: zip_bundle takes a bundle folder")
    with _BundleReader(bundle) as reader:
        members = {MANIFEST_NAME: reader.read(MANIFEST_NAME, 1 << 26)}
        for a in reader.manifest.artifacts:
            data = reader.read(a.file, a.bytes)
            if len(data) != a.bytes or hashlib.sha256(data).hexdigest() != a.sha256:
                raise BundleError(f"{bundle}: {a.file} does not match its manifest entry")
            members[a.file] = data

    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            with zipfile.ZipFile(f, "w") as zf:
                for name in sorted(members):
                    zi = zipfile.ZipInfo(name, date_time=ZIP_DATE_TIME)
                    zi.create_system = 3  # unix, so external_attr holds the mode
                    zi.external_attr = (0o100644 & 0xFFFF) << 16
                    if name.endswith(".png"):
                        zi.compress_type = zipfile.ZIP_STORED
                    else:
                        zi.compress_type = zipfile.ZIP_DEFLATED
                    zf.writestr(zi, members[name], compresslevel=6 if zi.compress_type else None)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return out
