"""The ``place`` stage: the grid of the config as a volume, its stats, and the probe limit."""
from __future__ import annotations

import numpy as np
import pytest

from proto.models import MAX_PROBES, BakeConfig
from workers.kernels.grid import grid_layout, grid_positions
from workers.stages.base import LazyArtifacts, StageContext, StageError
from workers.stages.place import run_place

BOUNDS = [[-1.0, 0.0, 2.0], [3.0, 2.0, 4.0]]


def _ctx(place: dict) -> StageContext:
    def no_scene():
        raise AssertionError("a grid by counts or spacing casts no rays")
    return StageContext(BakeConfig.model_validate({"place": place}), no_scene,
                        {"ingest": LazyArtifacts({"bounds": BOUNDS}, {})}, lambda f: None)


def test_counts_grid_volume_and_stats():
    out = run_place(_ctx({"counts": [5, 3, 2]}))
    counts, origin, spacing = grid_layout(np.asarray(BOUNDS), BakeConfig.model_validate(
        {"place": {"counts": [5, 3, 2]}}).place)
    (art,) = out.artifacts
    assert art.name == "probe_positions" and art.meta == {"counts": [5, 3, 2]}
    np.testing.assert_array_equal(art.data, grid_positions(counts, origin, spacing))
    assert out.stats == {"counts": [5, 3, 2], "origin": origin.tolist(), "spacing": spacing.tolist(), "probes": 30}


def test_too_many_probes():
    with pytest.raises(StageError) as e:
        run_place(_ctx({"spacing": float(1.0 / np.cbrt(MAX_PROBES))}))      # 4 x 2 x 2 m: about 16x the limit
    assert e.value.code == "too_many_probes"
