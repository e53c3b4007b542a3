"""proto/atlas.py: DDGI atlases stored without their tile borders, and load_artifact adding them back."""
from __future__ import annotations

import numpy as np

from proto.atlas import add_border, atlas_add_border, atlas_strip_border
from proto.bundle import load_artifact, write_artifact
from proto.ktx2 import pack_e5b9g9r9, unpack_e5b9g9r9
from workers.kernels.grid import pack_atlas, unpack_atlas
from workers.kernels.octahedral import add_border as kernel_add_border


def test_border_is_the_kernels_and_the_atlas_round_trips():
    rng = np.random.default_rng(2)
    maps = rng.standard_normal((3 * 2 * 4, 5, 5, 2)).astype(np.float32)       # 3 x 2 x 4 probes, n = 5
    bordered = kernel_add_border(maps)
    assert np.array_equal(add_border(maps), bordered)
    atlas = pack_atlas(bordered, [3, 2, 4])
    inner = atlas_strip_border(atlas, 5)
    assert inner.shape == (2 * 5, 4 * 3 * 5, 2) and np.array_equal(inner, pack_atlas(maps, [3, 2, 4]))
    assert np.array_equal(atlas_add_border(inner, 5), atlas)
    assert np.array_equal(atlas_add_border(inner[..., 0], 5), atlas[..., 0])         # one channel, 2 axes


def test_load_artifact_adds_the_border_of_a_stripped_atlas(tmp_path):
    """What the light stage writes (E5B9G9R9 interior tiles, meta.stored_border 0) loads as the bordered atlas the
    samplers and renderers read; the manifest shape is the file's."""
    rng = np.random.default_rng(3)
    counts, n = [4, 3, 2], 8
    maps = unpack_e5b9g9r9(pack_e5b9g9r9(rng.uniform(0, 5, (24, n, n, 3))))
    inner = pack_atlas(maps, counts)
    info = write_artifact(tmp_path, "irradiance", inner, "light", vk_format="E5B9G9R9_UFLOAT_PACK32",
                          meta={"tile": n + 2, "texels": n, "stored_border": 0})
    assert info.shape == [3 * n, 8 * n, 3]
    got = load_artifact(tmp_path / info.file, info)
    assert got.shape == (3 * (n + 2), 8 * (n + 2), 3)
    assert np.array_equal(unpack_atlas(got, counts, n + 2), kernel_add_border(maps))
    plain = write_artifact(tmp_path, "other", inner, "light", vk_format="E5B9G9R9_UFLOAT_PACK32",
                           meta={"tile": n + 2, "texels": n})                  # no stored_border: as stored
    assert np.array_equal(load_artifact(tmp_path / plain.file, plain), inner)
