"""Stage plumbing (workers/stages/base.py): lazily loaded artifacts."""
from __future__ import annotations

import numpy as np

from workers.stages.base import LazyArtifacts


def test_lazy_artifacts_release_frees_the_loaded_copy_and_loads_again():
    # the light stage releases the trace hits and depth moments once it is done with them (peak memory at scale)
    loads = []
    lazy = LazyArtifacts({}, {"a": lambda: loads.append("a") or np.arange(3)})
    first = lazy["a"]
    assert lazy["a"] is first and loads == ["a"]
    lazy.release("a", "not-loaded")
    again = lazy["a"]
    assert again is not first and np.array_equal(again, first) and loads == ["a", "a"]
