"""A zip upload: its member names checked, its sizes bounded, its members streamed out one by one on demand.

The zip holds one ``.gltf``/``.glb`` and the files it references. Member names are read as UTF-8 even without
the UTF-8 flag; absolute names and names that climb out with ``..`` are ``path_traversal``; entry count,
declared expansion and compression ratio are bounded before anything is extracted (``zip_bomb``,
:class:`workers.gltf.limits.IngestLimits`), and again while each member streams to a private temporary
directory under a name of our own (``member-00000``). :class:`ZipFiles` resolves the model's relative URIs
against its folder in the zip (Unicode normalization and, as a fallback, letter case ignored).
Consumer: :mod:`workers.gltf.reader`. Inverse: none.
"""

from __future__ import annotations

import posixpath
import re
import struct
import unicodedata
import zipfile
import zlib
from collections import Counter
from pathlib import Path

from workers.gltf.container import Files, climbs_out
from workers.gltf.errors import IngestError, err
from workers.gltf.limits import IngestLimits

__all__ = ["ZipUpload", "ZipFiles"]

_RATIO_MIN_BYTES = 8 << 20  # zip ratio checks apply from this many uncompressed bytes (smaller members
# cannot hurt; real glTF buffers full of zeros legitimately compress ~1000x)
_COPY_CHUNK = 1 << 20


class ZipUpload:
    """A zip upload: member names checked, sizes bounded, members streamed out one by one on demand."""

    def __init__(self, path: Path, limits: IngestLimits, tmp: Path, label: str):
        self.limits = limits
        self.tmp = tmp
        self.label = label
        self.extracted: dict[str, Path] = {}
        self.expanded = 0
        try:
            self.zf = zipfile.ZipFile(path)
            infos = self.zf.infolist()
        except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError, EOFError, struct.error) as exc:
            raise err("broken_zip", f"'{label}' is not a readable zip archive ({exc})") from exc
        if len(infos) > limits.max_zip_members:
            self.zf.close()
            raise err("zip_bomb", f"'{label}' holds {len(infos)} entries; the limit is {limits.max_zip_members}")
        self.members: dict[str, zipfile.ZipInfo] = {}
        total_u = total_c = 0
        try:
            for info in infos:
                name = _member_name(info)
                if name.startswith("/") or re.match(r"^[A-Za-z]:", name):
                    raise err("path_traversal", f"'{label}' has an absolute member name '{info.filename}'")
                if climbs_out(name):
                    raise err(
                        "path_traversal", f"'{label}' has a member name that climbs out with '..': '{info.filename}'"
                    )
                name = posixpath.normpath(name)  # 'textures/../a.png' is 'a.png': '..' inside the zip is fine
                if info.is_dir() or name in (".", ""):
                    continue
                if name.startswith("__MACOSX/") or posixpath.basename(name).startswith("._"):
                    continue  # macOS resource forks
                if name in self.members:
                    raise err("broken_zip", f"'{label}' holds '{name}' twice")
                total_u += info.file_size
                total_c += info.compress_size
                if total_u > limits.max_expanded_bytes:
                    raise err(
                        "zip_bomb",
                        f"'{label}' expands to more than {limits.max_expanded_bytes} bytes (the limit)",
                    )
                if info.file_size >= _RATIO_MIN_BYTES and info.file_size > limits.max_zip_ratio * max(
                    info.compress_size, 1
                ):
                    raise err(
                        "zip_bomb",
                        f"'{name}' in '{label}' expands {info.file_size / max(info.compress_size, 1):.0f}x; "
                        f"the limit is {limits.max_zip_ratio:g}x",
                    )
                self.members[name] = info
            if total_u >= _RATIO_MIN_BYTES and total_u > limits.max_zip_ratio * max(total_c, 1):
                raise err(
                    "zip_bomb",
                    f"'{label}' expands {total_u / max(total_c, 1):.0f}x in total; "
                    f"the limit is {limits.max_zip_ratio:g}x",
                )
        except IngestError:
            self.zf.close()
            raise
        # Unicode normalization: a URI written in NFC finds a member stored NFD (macOS) and vice versa
        nfc = Counter(_nfc(n) for n in self.members)
        self._by_nfc = {_nfc(n): n for n in self.members if nfc[_nfc(n)] == 1}
        self._nfc_lower = Counter(_nfc(n).lower() for n in self.members)

    def close(self) -> None:
        self.zf.close()

    def model_member(self) -> str:
        models = sorted(n for n in self.members if n.lower().endswith((".gltf", ".glb")))
        if not models:
            raise err("not_gltf", f"'{self.label}' holds no .gltf or .glb file")
        if len(models) > 1:
            shown = ", ".join(models[:5]) + (", ..." if len(models) > 5 else "")
            raise err("multiple_models", f"'{self.label}' holds {len(models)} models ({shown}); upload one per zip")
        return models[0]

    def extract(self, name: str) -> Path:
        """Stream one member to the temporary directory, enforcing its declared size and the total limit."""
        if name in self.extracted:
            return self.extracted[name]
        info = self.members[name]
        out = self.tmp / f"member-{len(self.extracted):05d}"  # never a user-chosen path
        written = 0
        try:
            with self.zf.open(info) as src, open(out, "wb") as dst:
                while True:
                    chunk = src.read(_COPY_CHUNK)
                    if not chunk:
                        break
                    written += len(chunk)
                    if written > info.file_size or self.expanded + written > self.limits.max_expanded_bytes:
                        raise err(
                            "zip_bomb", f"'{name}' in '{self.label}' expands past its declared size or the limit"
                        )
                    dst.write(chunk)
        except IngestError:
            raise
        except NotImplementedError as exc:
            raise err(
                "unsupported", f"'{name}' in '{self.label}' uses a compression method this service cannot read"
            ) from exc
        except RuntimeError as exc:  # encrypted member (its message holds a ZipInfo repr: not shown)
            raise err("unsupported", f"'{name}' in '{self.label}' is encrypted (password-protected); "
                                      "upload it unencrypted") from exc
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
            raise err("broken_zip", f"'{name}' in '{self.label}' is damaged ({exc})") from exc
        self.expanded += written
        self.extracted[name] = out
        return out

    def files(self, base: str) -> ZipFiles:
        return ZipFiles(self, base)


def _nfc(name: str) -> str:
    return unicodedata.normalize("NFC", name)


def _member_name(info: zipfile.ZipInfo) -> str:
    """A zip member's name, '/'-separated; UTF-8 even when the archiver did not set the UTF-8 flag.

    Without flag bit 11 the zip format says cp437 (zipfile decodes so), but most archivers write UTF-8
    regardless: such a name that is valid UTF-8 is read as UTF-8.
    """
    name = info.filename
    if not info.flag_bits & 0x800 and not name.isascii():
        try:
            name = name.encode("cp437").decode("utf-8")
        except (UnicodeEncodeError, UnicodeDecodeError):
            pass
    return name.replace("\\", "/")


class ZipFiles(Files):
    """Relative URIs resolved against the model's folder inside the zip (case-insensitive as a fallback)."""

    def __init__(self, archive: ZipUpload, base: str):
        self.archive = archive
        self.base = base
        self.case_fixed: list[str] = []

    def _member(self, rel: str, what: str) -> str:
        target = posixpath.normpath(posixpath.join(self.base, rel)) if self.base else posixpath.normpath(rel)
        if target == ".." or target.startswith("../"):
            raise err("path_traversal", f"{what} '{rel}' climbs out of the upload")
        if target in self.archive.members:
            return target
        if _nfc(target) in self.archive._by_nfc:  # the same name in another Unicode normalization form
            return self.archive._by_nfc[_nfc(target)]
        lower = _nfc(target).lower()
        if self.archive._nfc_lower.get(lower) == 1:
            for name in self.archive.members:
                if _nfc(name).lower() == lower:
                    self.case_fixed.append(f"{rel} -> {name}")
                    return name
        raise err("missing_resource", f"{what} '{rel}' is not in the zip '{self.archive.label}'")

    def locate(self, rel: str, what: str) -> None:
        self._member(rel, what)

    def path(self, rel: str, what: str) -> Path:
        return self.archive.extract(self._member(rel, what))
