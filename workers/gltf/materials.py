"""Materials and the textures they use: glTF's metallic-roughness model as :mod:`workers.scene` keeps it ([glTF] 3.9).

Per material: base colour factor and texture (``KHR_materials_pbrSpecularGlossiness`` diffuse when a material
has no metallic-roughness block), metallic and roughness factors and texture, emissive factor x
``KHR_materials_emissive_strength`` and emissive texture, ``doubleSided``, ``alphaMode`` and ``alphaCutoff``;
``KHR_materials_transmission`` only for a warning (the glass is baked opaque, as the Cycles Lambert reference bakes
it); ``KHR_materials_unlit`` as the flag ``unlit`` (the reader leaves such primitives out of the bake); the texture slot whose UV set (and ``KHR_texture_transform``) ``uv0`` carries. Textures are decoded once per
image to RGBA uint8, their size checked from the header first: PNG, JPEG and WebP (``EXT_texture_webp``) with PIL,
KTX2 with a Basis Universal payload (``KHR_texture_basisu``: ETC1S or UASTC, any supercompression) with Binomial's
transcoder (opengl-basisu), level 0 transcoded to RGBA8 — the bytes as stored, sRGB-encoded like a PNG's. A texture's
extension source is preferred to its ``source`` (the PNG/JPEG fallback the extensions allow), since that is what an
engine that reads the extension shows. :data:`DEFAULT_MATERIAL` is glTF's default material (3.9.6), for primitives without one.
Consumer: :mod:`workers.gltf.reader`. Inverse: :mod:`workers.scene_glb` (materials written back).

References
----------
.. [glTF] Khronos, "glTF 2.0 Specification", sections 3.8 (textures, images), 3.9 (materials).
.. [KHR_texture_transform] Khronos glTF extension: offset, rotation, scale of texture coordinates.
.. [KHR_texture_basisu] Khronos glTF extension: KTX2 images with ETC1S or UASTC payloads; 2D, top-left origin.
"""

from __future__ import annotations

import io
import math
import urllib.parse
import warnings as _pywarnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from workers.gltf.accessors import Accessors
from workers.gltf.container import Files, decode_data_uri, split_uri
from workers.gltf.document import Document, is_int, is_num, num, vec
from workers.gltf.errors import IngestError, err, invalid
from workers.gltf.limits import LFS_POINTER, IngestLimits, check_emissive

KTX2_MAGIC = b"\xabKTX 20\xbb\r\n\x1a\n"
"""The first 12 bytes of a KTX 2 file (KTX 2.0 specification, section 3.1)."""
#: Texture extensions whose ``source`` is read, in order of preference, before the texture's own ``source``.
TEXTURE_SOURCE_EXTENSIONS = ("KHR_texture_basisu", "EXT_texture_webp")

__all__ = ["Materials", "TexRef", "DEFAULT_MATERIAL", "DEFAULT_MATERIAL_WARNING", "texture_transform_matrix"]

DEFAULT_MATERIAL = {
    "name": "default",
    "base_color": [1.0, 1.0, 1.0, 1.0],
    "base_color_texture": None,
    "emissive": [0.0, 0.0, 0.0],
    "emissive_texture": None,
    "double_sided": False,
    # [glTF] 3.9.6 default material: metallic 1, roughness 1 (a rough white metal)
    "metallic": 1.0,
    "roughness": 1.0,
    "metallic_roughness_texture": None,
    "alpha_mode": "OPAQUE",
    "alpha_cutoff": 0.5,
}
"""The material of primitives without one (copy it before changing it)."""
DEFAULT_MATERIAL_WARNING = (
    "primitives without a material use glTF's default material (a rough white metal: "
    "diffuse albedo 0, its specular reflection baked as albedo 0.5)")


@dataclass
class TexRef:
    """One material texture slot: the glTF texture index, its UV set and its UV transform."""

    texture: int
    texcoord: int
    transform: np.ndarray | None  # (2, 3) or None


def texture_transform_matrix(ext: dict, what: str) -> np.ndarray:
    """KHR_texture_transform as a (2, 3) affine map on [u, v, 1]: translation * rotation * scale.

    Rotation follows the glTF sample viewer and three.js: ``u' = cos r * u + sin r * v``,
    ``v' = -sin r * u + cos r * v`` (counter-clockwise in UV space, whose v axis points down the image).
    """
    off = vec(ext.get("offset"), 2, [0.0, 0.0], f"{what} KHR_texture_transform offset")
    rot = num(ext.get("rotation"), 0.0, f"{what} KHR_texture_transform rotation")
    scale = vec(ext.get("scale"), 2, [1.0, 1.0], f"{what} KHR_texture_transform scale")
    c, s = math.cos(rot), math.sin(rot)
    r = np.array([[c, s], [-s, c]])
    m = np.zeros((2, 3))
    m[:, :2] = r @ np.diag(scale)
    m[:, 2] = off
    return m


def same_transform(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Whether two texture slots map UVs alike: both without a transform, or with equal (2, 3) matrices."""
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


def is_lfs(src: io.BytesIO | Path) -> bool:
    """Whether an image source starts like a Git LFS pointer file."""
    try:
        if isinstance(src, Path):
            with open(src, "rb") as f:
                return f.read(len(LFS_POINTER)) == LFS_POINTER
        return src.getvalue()[: len(LFS_POINTER)] == LFS_POINTER
    except OSError:
        return False


class Materials:
    """Reads the document's materials and decodes the images they use.

    Parameters
    ----------
    doc, acc, files, limits
        The document, its accessors (images in buffer views), where relative URIs resolve, the image limits.
    counts : Counter
        Things dropped, summarized as warnings by the reader.
    warnings : list of str
        Where approximations are reported.
    """

    def __init__(self, doc: Document, acc: Accessors, files: Files, limits: IngestLimits, counts: Counter,
                 warnings: list[str]):
        self.doc = doc
        self.acc = acc
        self.files = files
        self.limits = limits
        self.counts = counts
        self.warnings = warnings
        self._image_pixels = 0  # decoded image pixels so far (IngestLimits.max_total_image_pixels)

    # ------------------------------------------------------------------ images
    def _image_source(self, img_idx: int) -> io.BytesIO | Path:
        img = self.doc.item("images", img_idx, "a texture")
        if "uri" in img:
            kind, rel = split_uri(img["uri"], f"image {img_idx}")
            if kind == "data":
                return io.BytesIO(decode_data_uri(rel, f"image {img_idx}"))
            return self.files.path(rel, f"image {img_idx}")
        if "bufferView" in img:
            raw, _ = self.acc.view_bytes(img["bufferView"], f"images[{img_idx}]")
            return io.BytesIO(raw.tobytes())
        raise invalid(f"images[{img_idx}] has neither a uri nor a bufferView")

    def _check_size(self, name: str, w: int, h: int) -> None:
        """Refuse an image over the limits (``image_too_large``) from its header, before it is decoded."""
        if w * h > self.limits.max_image_pixels:
            raise err(
                "image_too_large",
                f"{name} is {w}x{h} pixels; the limit is {self.limits.max_image_pixels} pixels",
            )
        cap = self.limits.max_total_image_pixels
        if cap is not None and self._image_pixels + w * h > cap:
            raise err(
                "image_too_large",
                f"the images decode to more than {cap} pixels in all ({name} is {w}x{h}); "
                "use smaller textures",
            )
        self._image_pixels += w * h

    def _load_ktx2(self, data: bytes, name: str) -> np.ndarray:
        """A KTX2 image with a Basis Universal payload ([KHR_texture_basisu]) -> (H, W, 4) uint8 RGBA of level 0.

        The transcoder writes the stored values (sRGB-encoded for colour, as a PNG's); glTF's KTX2 images have
        their origin top-left like PNGs, so rows are kept as they are. Cube maps, arrays, video and HDR codecs
        are not glTF textures: ``invalid_image``.
        """
        import opengl_basisu

        try:
            tex = opengl_basisu.open(data)
        except opengl_basisu.BasisuError as exc:  # UnsupportedError too: vkFormat without a Basis payload
            raise err("invalid_image", f"{name} is a KTX2 file that cannot be read as Basis Universal ({exc})") from exc
        if tex.faces != 1 or tex.is_array or tex.is_video:
            raise err("invalid_image", f"{name} is a KTX2 cube map, array or video; a glTF texture is one 2D image")
        if tex.codec.is_hdr:
            raise err("invalid_image", f"{name} is a high dynamic range KTX2 ({tex.codec.name}); "
                      "KHR_texture_basisu textures are ETC1S or UASTC LDR")
        self._check_size(name, tex.width, tex.height)
        try:
            rgba = tex.transcode(opengl_basisu.Target.RGBA8, 0).data
        except opengl_basisu.BasisuError as exc:
            raise err("invalid_image", f"{name}: the KTX2 image could not be transcoded ({exc})") from exc
        return np.ascontiguousarray(rgba.reshape(tex.height, tex.width, 4), dtype=np.uint8)

    def load_image(self, img_idx: int) -> np.ndarray:
        """Decode one image to (H, W, 4) uint8 RGBA, checking its header dimensions first."""
        src = self._image_source(img_idx)
        name = f"image {img_idx}"
        img = self.doc.g["images"][img_idx]
        if isinstance(img.get("uri"), str) and not img["uri"].startswith("data:"):
            name += f" '{urllib.parse.unquote(img['uri'])}'"
        data = src.read_bytes() if isinstance(src, Path) else src.getvalue()
        if data[: len(KTX2_MAGIC)] == KTX2_MAGIC:
            return self._load_ktx2(data, name)
        try:
            with _pywarnings.catch_warnings():
                _pywarnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with Image.open(io.BytesIO(data), formats=["PNG", "JPEG", "WEBP"]) as im:
                    w, h = im.size
                    self._check_size(name, w, h)
                    im.seek(0)
                    im.load()
                    if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                        a = np.asarray(im).astype(np.float64)
                        scale = 255.0 / 65535.0
                        im = Image.fromarray(np.clip(np.rint(a * scale), 0, 255).astype(np.uint8), "L")
                    elif im.mode == "F":
                        a = np.asarray(im)
                        im = Image.fromarray(np.clip(np.rint(np.nan_to_num(a) * 255.0), 0, 255).astype(np.uint8), "L")
                    rgba = np.array(im.convert("RGBA"), dtype=np.uint8)
        except IngestError:
            raise
        except Image.DecompressionBombError as exc:
            raise err("image_too_large", f"{name} is too large to decode ({exc})") from exc
        except Image.UnidentifiedImageError as exc:  # its message names the file object or temp path: not shown
            lfs = " (it is a Git LFS pointer: fetch the real file with git lfs pull)" if is_lfs(src) else ""
            raise err("invalid_image", f"{name} is not a PNG, JPEG, WebP or KTX2 image{lfs}") from exc
        except Exception as exc:  # truncated data, unsupported modes
            raise err(
                "invalid_image", f"{name} is not a readable PNG, JPEG or WebP image ({type(exc).__name__}: {exc})"
            ) from exc
        if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.size == 0:
            raise err("invalid_image", f"{name} decoded to an empty image")
        return rgba

    # ------------------------------------------------------------------ materials
    def texref(self, info, what: str) -> TexRef | None:
        if info is None:
            return None
        if not isinstance(info, dict):
            raise invalid(f"{what} must be a textureInfo object")
        tex_idx = info.get("index")
        self.doc.item("textures", tex_idx, what)
        texcoord = info.get("texCoord", 0)
        if not is_int(texcoord) or texcoord < 0:
            raise invalid(f"{what}.texCoord must be a non-negative integer")
        transform = None
        tt = self.doc.exts(info).get("KHR_texture_transform")
        if isinstance(tt, dict):
            transform = texture_transform_matrix(tt, what)
            tc = tt.get("texCoord")
            if tc is not None:
                if not is_int(tc) or tc < 0:
                    raise invalid(f"{what} KHR_texture_transform texCoord must be a non-negative integer")
                texcoord = tc
        return TexRef(tex_idx, texcoord, transform)

    def _texture_image(self, tex_idx: int) -> int | None:
        """glTF texture -> image index (:data:`TEXTURE_SOURCE_EXTENSIONS` preferred), None when none."""
        tex = self.doc.item("textures", tex_idx, "a material")
        ext = self.doc.exts(tex)
        for key in TEXTURE_SOURCE_EXTENSIONS:
            e = ext.get(key)
            if isinstance(e, dict) and "source" in e:
                self.doc.item("images", e["source"], f"textures[{tex_idx}].{key}")
                return e["source"]
        src = tex.get("source")
        if src is None:
            self.counts["texture(s) without a PNG/JPEG/WebP/KTX2 source ignored"] += 1
            return None
        self.doc.item("images", src, f"textures[{tex_idx}]")
        return src

    def build(self) -> tuple[list[dict], list[np.ndarray], list[TexRef | None]]:
        """Materials in glTF order, the decoded textures they use, and each material's UV source.

        Returns
        -------
        materials : list of dict
            See :mod:`workers.scene`; texture indices point into ``textures``.
        textures : list of (H, W, 4) uint8
            Images used by base colour or emissive slots, in first-use order, each decoded once.
        uv_refs : list of TexRef or None
            Per material: the texture slot whose UV set (and transform) ``uv0`` carries.
        """
        materials: list[dict] = []
        textures: list[np.ndarray] = []
        image_slot: dict[int, int] = {}
        uv_refs: list[TexRef | None] = []
        alpha_modes: Counter = Counter()
        transmissive: list[str] = []

        def tex_index(ref: TexRef | None) -> int | None:
            if ref is None:
                return None
            img = self._texture_image(ref.texture)
            if img is None:
                return None
            if img not in image_slot:
                image_slot[img] = len(textures)
                textures.append(self.load_image(img))
            return image_slot[img]

        for i, m in enumerate(self.doc.array("materials")):
            what = f"materials[{i}]"
            if not isinstance(m, dict):
                raise invalid(f"{what} is not an object")
            ext = self.doc.exts(m)
            pbr = m.get("pbrMetallicRoughness")
            sg = ext.get("KHR_materials_pbrSpecularGlossiness")
            mr_ref = None
            if pbr is None and isinstance(sg, dict):
                # specular-glossiness: the diffuse colour is the diffuse albedo (no metallic term)
                base = vec(sg.get("diffuseFactor"), 4, [1, 1, 1, 1], f"{what} diffuseFactor")
                base_ref = self.texref(sg.get("diffuseTexture"), f"{what}.diffuseTexture")
                metallic, roughness = 0.0, 1.0 - num(sg.get("glossinessFactor"), 1.0, f"{what} glossinessFactor")
            else:
                # [glTF] 3.9.2: a material without pbrMetallicRoughness has metallic 1 and roughness 1 too
                pbr = pbr if isinstance(pbr, dict) else {}
                base = vec(pbr.get("baseColorFactor"), 4, [1, 1, 1, 1], f"{what} baseColorFactor")
                base_ref = self.texref(pbr.get("baseColorTexture"), f"{what}.baseColorTexture")
                metallic = num(pbr.get("metallicFactor"), 1.0, f"{what} metallicFactor")
                roughness = num(pbr.get("roughnessFactor"), 1.0, f"{what} roughnessFactor")
                mr_ref = self.texref(pbr.get("metallicRoughnessTexture"), f"{what}.metallicRoughnessTexture")
            if not (0.0 <= metallic <= 1.0 and 0.0 <= roughness <= 1.0):
                self.warnings.append(f"{what}: metallicFactor/roughnessFactor outside [0, 1] clamped")
                metallic, roughness = min(max(metallic, 0.0), 1.0), min(max(roughness, 0.0), 1.0)
            emissive = vec(m.get("emissiveFactor"), 3, [0, 0, 0], f"{what} emissiveFactor")
            strength_ext = ext.get("KHR_materials_emissive_strength")
            strength = num(
                strength_ext.get("emissiveStrength") if isinstance(strength_ext, dict) else None,
                1.0,
                f"{what} emissiveStrength",
            )
            check_emissive(emissive, strength, what)
            emissive_ref = self.texref(m.get("emissiveTexture"), f"{what}.emissiveTexture")
            double_sided = m.get("doubleSided", False)
            if not isinstance(double_sided, bool):
                raise invalid(f"{what}.doubleSided must be true or false")
            alpha = m.get("alphaMode", "OPAQUE")
            if alpha not in ("OPAQUE", "MASK", "BLEND"):
                raise invalid(f"{what}.alphaMode must be OPAQUE, MASK or BLEND, not {alpha!r}")
            cutoff = num(m.get("alphaCutoff"), 0.5, f"{what} alphaCutoff")
            if cutoff < 0:
                raise invalid(f"{what}.alphaCutoff must not be negative")
            if alpha == "BLEND":
                alpha_modes[alpha] += 1
            unlit = isinstance(ext.get("KHR_materials_unlit"), dict)
            tr = ext.get("KHR_materials_transmission")
            if isinstance(tr, dict) and is_num(tr.get("transmissionFactor")) and tr["transmissionFactor"] > 0:
                name = m.get("name")
                transmissive.append(name if isinstance(name, str) else f"material_{i}")
            uv_ref = base_ref or emissive_ref or mr_ref
            for other, slot in ((emissive_ref, "emissive"), (mr_ref, "metallic-roughness")):
                if (other is not None and uv_ref is not None and other is not uv_ref
                        and (other.texcoord != uv_ref.texcoord or not same_transform(other.transform, uv_ref.transform))):
                    self.warnings.append(f"{what}: {slot} texture sampled with the base colour texture's UVs")
            name = m.get("name")
            materials.append(
                {
                    "name": name if isinstance(name, str) else f"material_{i}",
                    "base_color": base,
                    "base_color_texture": tex_index(base_ref),
                    "emissive": [e * strength for e in emissive],
                    "emissive_texture": tex_index(emissive_ref),
                    "double_sided": double_sided,
                    "metallic": metallic,
                    "roughness": roughness,
                    "metallic_roughness_texture": tex_index(mr_ref),
                    "alpha_mode": alpha,
                    "alpha_cutoff": cutoff,
                    **({"unlit": True} if unlit else {}),
                }
            )
            uv_refs.append(uv_ref)
        for mode, n in sorted(alpha_modes.items()):
            self.warnings.append(
                f"alphaMode BLEND on {n} material{'s' * (n != 1)} baked as a cutout at alpha 0.5 "
                "(probe rays see a blended surface where its alpha is at least 0.5, and through it elsewhere)")
        if transmissive:
            n = len(transmissive)
            shown = ", ".join(repr(t) for t in transmissive[:3]) + (f" and {n - 3} more" if n > 3 else "")
            self.warnings.append(
                f"KHR_materials_transmission on {n} material{'s' * (n != 1)} ({shown}) baked as opaque diffuse "
                "surfaces (a diffuse-only probe bake, as the Cycles Lambert reference): no light passes through "
                "them, so a room lit only through glass reads dark; to let light through, remove the glass or give "
                "it alphaMode MASK with an alpha below alphaCutoff")
        return materials, textures, uv_refs
