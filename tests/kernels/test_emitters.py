"""Emitter sampling for the path tracer (workers/kernels/emitters.py): the pmf, MIS weights, visibility."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.kernels.test_pathtrace import _material, _scene
from workers.kernels.emitters import Emitters
from workers.raycast import RayCaster

# two emitting triangles of area 2 and 0.5 facing +z (Le 1 and 4), one black floor triangle facing +z
TRIS = [[[-1, -1, 1], [1, -1, 1], [1, 1, 1]], [[0, 0, 2], [1, 0, 2], [0, 1, 2]], [[-9, -9, 0], [9, -9, 0], [0, 9, 0]]]


def _emitters(double_sided=False):
    mats = [_material(0.5, 1.0, double_sided), _material(0.5, 4.0, double_sided), _material(0.5, 0.0)]
    return _scene(TRIS, mats, material=[0, 1, 2])


def test_pmf_is_area_times_emission():
    em = Emitters(_emitters())
    np.testing.assert_array_equal(em.tri, [0, 1])
    np.testing.assert_allclose(em.area[:2], [2.0, 0.5])
    np.testing.assert_allclose(em.tri_pmf, [2.0 / 4.0, 2.0 / 4.0, 0.0])   # power 2·1 and 0.5·4
    assert em.cdf[-1] == 1.0 and em.total_area == pytest.approx(2.5) and bool(em)
    assert not Emitters(_scene(TRIS[2:], [_material(0.5)]))


def test_bsdf_weights_power_heuristic():
    """w_b = p_b² / (p_b² + p_l²) with p_l = pmf · t² / (area · |cos θ_e|), p_b = cos θ_s / π; 1 off emitters."""
    em = Emitters(_emitters())
    tri = np.array([0, 2])
    d = np.array([[0, 0, -1.0], [0, 0, -1.0]])
    w = em.bsdf_weights(tri, np.array([2.0, 1.0]), d, prev_cos=np.array([1.0, 1.0]))
    p_l, p_b = 0.5 * 4.0 / 2.0, 1 / math.pi
    np.testing.assert_allclose(w, [p_b ** 2 / (p_b ** 2 + p_l ** 2), 1.0])


@pytest.mark.parametrize("double_sided", [False, True])
def test_irradiance_needs_the_front_face_and_a_clear_line(double_sided):
    """Below the emitters, facing up: they are seen from behind (0 unless double-sided). Above them, facing down:
    seen from the front. Every estimate is >= 0."""
    s = _emitters(double_sided)
    em, caster = Emitters(s), RayCaster(s.triangles)
    n = 4096
    pid = np.arange(n, dtype=np.uint64)
    below = em.irradiance(s, caster, np.tile([0.0, 0.0, 0.5], (n, 1)), np.tile([0.0, 0.0, 1.0], (n, 1)),
                          np.tile([0.0, 0.0, 1.0], (n, 1)), pid, 3, 1, 1e-4)
    above = em.irradiance(s, caster, np.tile([0.0, 0.0, 3.0], (n, 1)), np.tile([0.0, 0.0, -1.0], (n, 1)),
                          np.tile([0.0, 0.0, -1.0], (n, 1)), pid, 3, 1, 1e-4)
    assert above.shape == (n, 3) and np.all(above >= 0) and above.mean() > 0
    assert (below.mean() > 0) == double_sided
