"""The parsed glTF JSON: checked access to its arrays and objects, its number fields, its version and extensions.

:class:`Document` wraps the parsed JSON (:func:`workers.gltf.container.parse_json`): ``array`` and ``item``
turn a wrong type or an index out of range into ``invalid_gltf`` naming the place; :func:`vec` and :func:`num`
read number fields (``non_finite`` for NaN or infinity). :meth:`Document.check_asset` and
:meth:`Document.check_extensions` refuse what this reader cannot honour ([glTF] 3.2 asset,
3.12 extensions). Consumer: the other modules of :mod:`workers.gltf`. Inverse: none.
"""

from __future__ import annotations

import math
import re

from workers.gltf.errors import err, invalid

__all__ = ["Document", "HONOURED_EXTENSIONS", "EXPLAINED_EXTENSIONS", "lookup", "is_int", "is_num", "vec", "num"]

#: Extensions we read (or that need nothing from us): allowed in ``extensionsRequired``.
HONOURED_EXTENSIONS = frozenset(
    {
        "KHR_lights_punctual",
        "KHR_materials_emissive_strength",
        "KHR_texture_transform",
        "KHR_mesh_quantization",
        "EXT_texture_webp",
        "KHR_texture_basisu",  # KTX2 images transcoded with opengl-basisu (workers.gltf.materials)
        "EXT_mesh_gpu_instancing",
        "KHR_materials_pbrSpecularGlossiness",
        "KHR_draco_mesh_compression",  # decoded with DracoPy (workers.gltf.compression)
        "EXT_meshopt_compression",  # decoded with meshoptimizer (workers.gltf.compression)
        "KHR_meshopt_compression",
        "KHR_materials_unlit",  # its primitives left out of the bake, as Blender's importer does (workers.gltf.reader)
    }
)
#: Extensions read only to say what the bake does with them: their own warning (:mod:`workers.gltf.materials`)
#: instead of a place in "extensions ignored"; still refused when required.
EXPLAINED_EXTENSIONS = frozenset({"KHR_materials_transmission", "KHR_materials_volume"})


def lookup(table: dict, key):
    """``table.get(key)`` for any JSON value (lists and objects are unhashable: None)."""
    return table.get(key) if isinstance(key, (int, str)) and not isinstance(key, bool) else None


def is_int(v) -> bool:
    """A JSON integer (``True`` is not one)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_num(v) -> bool:
    """A JSON number (``True`` is not one)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def vec(v, n: int, default, what: str) -> list[float]:
    """A list of ``n`` finite numbers (or ``default`` when absent) as Python floats."""
    if v is None:
        if default is None:
            raise invalid(f"{what} must be {n} numbers")
        return [float(x) for x in default]
    if not isinstance(v, list) or len(v) != n or not all(is_num(x) for x in v):
        raise invalid(f"{what} must be {n} numbers")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        raise err("non_finite", f"{what} holds NaN or infinity")
    return out


def num(v, default, what: str) -> float:
    """A finite number (or ``default`` when absent) as a Python float."""
    if v is None:
        return float(default)
    if not is_num(v):
        raise invalid(f"{what} must be a number")
    x = float(v)
    if not math.isfinite(x):
        raise err("non_finite", f"{what} is NaN or infinite")
    return x


class Document:
    """Checked access to a parsed glTF document ``g`` (a dict with an ``asset`` object)."""

    def __init__(self, gltf: dict):
        self.g = gltf

    def array(self, key: str, owner: dict | None = None) -> list:
        """``owner[key]`` (the document's when ``owner`` is None), ``[]`` when absent; an array or invalid."""
        v = (self.g if owner is None else owner).get(key, [])
        if not isinstance(v, list):
            raise invalid(f"'{key}' must be an array")
        return v

    def item(self, key: str, idx, what: str) -> dict:
        """The object ``g[key][idx]``, referred to by ``what``; invalid when missing or not an object."""
        lst = self.array(key)
        if not is_int(idx):
            raise invalid(f"{what} refers to {key} index {idx!r}, which is not an integer")
        if not 0 <= idx < len(lst):
            raise invalid(f"{what} refers to {key}[{idx}], but the file has {len(lst)} {key}")
        item = lst[idx]
        if not isinstance(item, dict):
            raise invalid(f"{key}[{idx}] is not an object")
        return item

    @staticmethod
    def exts(obj: dict) -> dict:
        """An object's ``extensions`` (``{}`` when absent or not an object)."""
        e = obj.get("extensions", {})
        return e if isinstance(e, dict) else {}

    def check_asset(self) -> None:
        """glTF 2.x only, and no ``minVersion`` past 2.0 (``unsupported``)."""
        asset = self.g["asset"]
        version = asset.get("version")
        m = re.fullmatch(r"(\d+)\.(\d+)", version) if isinstance(version, str) else None
        if m is None:
            raise invalid(f"asset.version {version!r} is not 'major.minor'")
        if int(m.group(1)) != 2:
            raise err("unsupported", f"this is glTF {version}; only glTF 2.x is supported")
        min_version = asset.get("minVersion")
        if min_version is not None:
            mm = re.fullmatch(r"(\d+)\.(\d+)", min_version) if isinstance(min_version, str) else None
            if mm is None:
                raise invalid(f"asset.minVersion {min_version!r} is not 'major.minor'")
            if (int(mm.group(1)), int(mm.group(2))) > (2, 0):
                raise err(
                    "unsupported",
                    f"the file requires glTF {min_version} (asset.minVersion); this service reads glTF 2.0",
                )

    def check_extensions(self, warnings: list[str]) -> None:
        """Refuse ``extensionsRequired`` outside :data:`HONOURED_EXTENSIONS` (``unsupported_extension``); name
        the ignored ``extensionsUsed`` in ``warnings``."""
        required = self.array("extensionsRequired")
        used = self.array("extensionsUsed")
        for name in required:
            if not isinstance(name, str):
                raise invalid("extensionsRequired must hold strings")
            if name not in HONOURED_EXTENSIONS:
                raise err("unsupported_extension", f"required extension {name} is not supported by this service")
        ignored = sorted({u for u in used if isinstance(u, str) and u not in HONOURED_EXTENSIONS
                          and u not in EXPLAINED_EXTENSIONS})
        if ignored:
            warnings.append("extensions ignored: " + ", ".join(ignored))
