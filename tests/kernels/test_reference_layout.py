"""The reference tables' layout (workers/kernels/reference_layout.py): writer and reader agree."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from workers.kernels.reference_layout import (GBUFFER_CHANNELS, POINT_COLUMNS, pack_gbuffer, point_column,
                                              point_columns, point_table, unpack_gbuffer)


def test_point_table_round_trip():
    rng = np.random.default_rng(0)
    surface = {k: rng.normal(size=(5, 3)) for k in POINT_COLUMNS[:6]}
    e = [rng.normal(size=(5, 3)) for _ in range(3)]
    table = point_table(surface, *e)
    assert table.shape == (5, 27) and table.dtype == np.float32
    cols = point_columns(table)
    assert list(cols) == list(POINT_COLUMNS)
    for k, v in {**surface, "e_direct": e[0], "e_indirect": e[1], "stderr": e[2]}.items():
        np.testing.assert_allclose(cols[k], v.astype(np.float32))
        np.testing.assert_array_equal(point_column(table, k), cols[k])
    assert point_table({k: np.zeros((0, 3)) for k in POINT_COLUMNS[:6]}, *e).shape == (0, 27)


def test_gbuffer_round_trip():
    rng = np.random.default_rng(1)
    planes = {k: rng.normal(size=(4, 6, 3)).astype(np.float32) for k in GBUFFER_CHANNELS[:-1]}
    gb = SimpleNamespace(**planes, shaded=rng.random((4, 6)) < 0.5)
    packed = pack_gbuffer(gb)
    assert packed.shape == (4, 6, 16) and packed.dtype == np.float32
    out = unpack_gbuffer(packed)
    for k, v in planes.items():
        np.testing.assert_array_equal(out[k], v)
    np.testing.assert_array_equal(out["shaded"], gb.shaded)
