"""The one exception type of glTF ingest, its codes, and how its messages are made safe to show.

Every bad input raises :class:`IngestError` with a machine-readable ``code`` (:data:`ERROR_CODES`), a sentence
and a 4xx ``status``; :func:`workers.gltf.reader.ingest_file` lets no other exception type out. Messages are
scrubbed of temporary paths and object addresses (:func:`scrub`). Consumer: every module of
:mod:`workers.gltf`, the upload route and the CLI. Inverse: none.
"""

from __future__ import annotations

import os
import re
import tempfile

__all__ = ["IngestError", "ERROR_CODES", "err", "invalid", "scrub", "plural"]


class IngestError(Exception):
    """A bad upload: a machine-readable ``code``, a human ``message`` and the HTTP ``status``.

    Parameters
    ----------
    code : str
        Stable identifier, e.g. ``"truncated_glb"``, ``"missing_resource"`` (see :data:`ERROR_CODES`).
    message : str
        One sentence saying what is wrong and, where it helps, what to do.
    status : int
        HTTP status for the upload route: 413 for size limits, 415 for files that are not glTF,
        422 for everything else.
    """

    def __init__(self, code: str, message: str, status: int = 422):
        message = scrub(message)
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.status = status


_OBJECT_REPR = re.compile(r"<[^<>]*? at 0x[0-9a-fA-F]+>")
_TEMP_MEMBER = re.compile(r"""(?:[A-Za-z]:)?[^\s'"<>]*kiln-ingest-[^\s'"<>/\\]+[/\\]member-\d+""")


def scrub(message: str, paths: tuple[str, ...] = ()) -> str:
    """A message without temporary paths or object addresses (they say nothing to the user, and leak the
    server's layout): ``<_io.BytesIO object at 0x7f...>`` -> ``the data``, a path under the temp directory
    (where zip members are extracted, where the API stages uploads) -> ``a file in the upload``."""
    message = _OBJECT_REPR.sub("the data", message)
    message = _TEMP_MEMBER.sub("a file in the upload", message)
    for p in sorted({p for p in paths if p and p != os.sep}, key=len, reverse=True):
        message = message.replace(p, "the upload")
    for root in {tempfile.gettempdir(), os.path.realpath(tempfile.gettempdir())}:
        if root and root != os.sep and root in message:
            message = re.sub(re.escape(root) + r"""[^\s'"<>]*""", "a file in the upload", message)
    return message


#: Every code :func:`workers.gltf.reader.ingest_file` raises, with its HTTP status.
ERROR_CODES: dict[str, int] = {
    "not_gltf": 415,  # unknown magic, or JSON that is not an object with "asset"
    "truncated_glb": 422,  # GLB header/chunk lengths larger than the file
    "broken_json": 422,  # JSON syntax error, bad UTF-8, NaN/Infinity literals
    "json_too_deep": 422,  # nesting deeper than IngestLimits.max_json_depth
    "broken_zip": 422,  # unreadable archive, CRC error, duplicate member names
    "multiple_models": 422,  # a zip with more than one .gltf/.glb
    "external_uri": 422,  # http:, file:, UNC, absolute paths
    "path_traversal": 422,  # ".." in a URI or zip member name, absolute zip member names
    "missing_resource": 422,  # a referenced buffer or image is not in the upload
    "invalid_gltf": 422,  # structural errors: bad indices, ranges, accessor types
    "invalid_image": 422,  # an image PIL cannot decode, or not PNG/JPEG/WebP
    "non_finite": 422,  # NaN/inf positions or UVs after transforms
    "absurd_magnitude": 422,  # |world position| > MAX_COORD, emissive x strength > MAX_EMISSIVE, light intensity
    # > MAX_LIGHT_INTENSITY or colour > MAX_LIGHT_COLOR (a scale of 1e20, an emissive of 1e60: garbage, not a scene)
    "negative_emissive": 422,  # an emissiveFactor component or emissiveStrength below 0 (negative light)
    "negative_light": 422,  # a KHR_lights_punctual light with a negative colour component or intensity
    "zero_extent": 422,  # every triangle in one point (the bounds' diagonal below MIN_EXTENT)
    "degenerate_triangles": 422,  # every triangle has zero area (all on lines or points)
    "text_buffer": 422,  # a buffer holding text, not binary numbers (a Git LFS pointer committed in its place)
    "no_triangles": 422,  # nothing to bake
    "unsupported": 422,  # a feature refused with a reason (glTF 1.0, minVersion 2.1, encrypted zip)
    "unsupported_extension": 422,  # extensionsRequired we cannot honour
    "too_large": 413,  # upload larger than IngestLimits.max_bytes
    "too_many_triangles": 413,
    "zip_bomb": 413,
    "decoded_too_large": 413,  # Draco/meshopt data decoding to more than IngestLimits.max_decoded_bytes
    "image_too_large": 413,
    "unreadable_upload": 500,  # the upload path itself cannot be read (a server fault, not bad input)
}


def err(code: str, message: str) -> IngestError:
    """An :class:`IngestError` with the status :data:`ERROR_CODES` gives ``code``."""
    return IngestError(code, message, ERROR_CODES[code])


def invalid(message: str) -> IngestError:
    """``invalid_gltf``: a structural error in the document."""
    return err("invalid_gltf", message)


def plural(n: int, text: str) -> str:
    """``"3 point primitive(s) ignored"`` -> ``"3 point primitives ignored"`` (singular for 1)."""
    return f"{n} " + text.replace("(s)", "" if n == 1 else "s")
