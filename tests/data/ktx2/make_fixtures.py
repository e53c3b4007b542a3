"""Write the KTX2 (KHR_texture_basisu) fixtures of tests/workers/gltf/test_materials.py.

Run by hand, not by the tests: ``pip install alktx2`` (Basis Universal's encoder), then
``python tests/data/ktx2/make_fixtures.py``. The tests decode the committed files with the transcoder Kiln
uses (opengl-basisu) and compare with :func:`quadrants`, the picture encoded here.

- ``quadrants-etc1s.ktx2``: ETC1S (BasisLZ supercompression), sRGB, with mipmaps;
- ``quadrants-uastc-zstd.ktx2``: UASTC LDR 4x4, Zstandard supercompression, sRGB, with mipmaps.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
COLOURS = [(200, 40, 40, 255), (40, 200, 40, 255), (40, 40, 200, 255), (220, 220, 220, 255)]


def quadrants(size: int = 16) -> np.ndarray:
    """(size, size, 4) uint8 RGBA: top-left, top-right, bottom-left, bottom-right in :data:`COLOURS` order
    (row 0 is the top of the image, as glTF and KHR_texture_basisu store it)."""
    img = np.zeros((size, size, 4), np.uint8)
    h = size // 2
    img[:h, :h], img[:h, h:], img[h:, :h], img[h:, h:] = (np.array(c, np.uint8) for c in COLOURS)
    return img


def main() -> None:
    import alktx2

    img = quadrants()
    raw = img.tobytes()
    files = {
        "quadrants-etc1s.ktx2": dict(codec="etc1s", quality=128),
        "quadrants-uastc-zstd.ktx2": dict(codec="uastc", zstd_supercompression_level=9),
    }
    for name, opts in files.items():
        data = alktx2.encode_raw_rgba_to_ktx2(raw, img.shape[1], img.shape[0], False, srgb=True, mipmaps=True, **opts)
        (HERE / name).write_bytes(data)
        print(name, len(data), "bytes", alktx2.inspect_ktx2(data)["basis_tex_format_name"])


if __name__ == "__main__":
    main()
