"""Synthetic θ fields on the refined grid for the Mask Decomposition kernel tests
(test_mask_field.py, test_coloring.py, test_mask_fit.py)."""
from __future__ import annotations

import numpy as np


def random_field(counts, S, seed=0, p_visible=0.6, p_dc=0.1):
    """(theta (Z, Y, X, 8) uint8, dont_care (Z, Y, X) bool) for ``counts`` probes and S samples per cell axis:
    θ mostly 255 (``p_visible``) or random, 30% zeroed; a ``p_dc`` fraction of samples don't-care."""
    cells = np.maximum(np.asarray(counts) - 1, 1)
    shape = (cells[2] * S, cells[1] * S, cells[0] * S)
    rng = np.random.default_rng(seed)
    theta = np.where(rng.random(shape + (8,)) < p_visible, 255, rng.integers(0, 256, shape + (8,))).astype(np.uint8)
    theta[rng.random(shape + (8,)) < 0.3] = 0
    dc = rng.random(shape) < p_dc
    return theta, dc
