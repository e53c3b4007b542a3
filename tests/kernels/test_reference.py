"""The reference at G-buffer pixels and points (workers/kernels/reference.py), closed forms."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from workers.kernels.reference import exitant_radiance


def test_exitant_radiance_is_emission_plus_albedo_over_pi_times_irradiance():
    gb = SimpleNamespace(emission=np.full((2, 2, 3), 0.5, np.float32), albedo=np.full((2, 2, 3), 0.25, np.float32),
                         shaded=np.array([[True, False], [True, True]]))
    e_dir, e_ind = np.full((2, 2, 3), 2.0), np.full((2, 2, 3), 1.0)
    out = exitant_radiance(gb, e_dir, e_ind)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], 0.5 + 0.25 / math.pi * 3.0, rtol=1e-6)
    np.testing.assert_array_equal(out[0, 1], 0.0)                      # not shaded (a back face, no geometry)
