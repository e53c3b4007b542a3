"""Probe rays (workers/raycast/probes.py): one direction set from every probe, back faces and double sides."""
from __future__ import annotations

import numpy as np

from workers.raycast import RayCaster
from workers.raycast.probes import trace_probes

# a 20 m square at z = 1, counter-clockwise seen from z < 1: its front faces the origin
PLANE = np.array([[[-10, -10, 1], [-10, 10, 1], [10, 10, 1]], [[-10, -10, 1], [10, 10, 1], [10, -10, 1]]],
                 np.float32)
DIRS = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0]], np.float32)


def test_hits_misses_and_back_faces():
    caster = RayCaster(PLANE)
    pos = np.array([[0, 0, 0], [0, 0, 3.0]])
    t, tri, u, v, back, seconds = trace_probes(caster, pos, DIRS, np.zeros(2, bool))
    assert t.shape == tri.shape == u.shape == v.shape == back.shape == (2, 3) and seconds >= 0
    np.testing.assert_allclose(t[0], [1.0, np.inf, np.inf])      # probe 0 sees the front at 1 m, misses the rest
    np.testing.assert_allclose(t[1], [np.inf, 2.0, np.inf])      # probe 1 sees the back at 2 m
    np.testing.assert_array_equal(back, [[False, False, False], [False, True, False]])
    np.testing.assert_array_equal(tri >= 0, np.isfinite(t))


def test_double_sided_back_faces_count_as_front():
    caster = RayCaster(PLANE)
    pos = np.array([[0, 0, 3.0]])
    *_, back, _ = trace_probes(caster, pos, DIRS, np.ones(2, bool))
    assert not back.any()
    *_, back, _ = trace_probes(caster, pos, DIRS, np.array([True, False]))  # only the triangle that is hit counts
    hit_tri = trace_probes(caster, pos, DIRS, np.zeros(2, bool))[1][0, 1]
    assert back[0, 1] == (hit_tri == 1)


def test_probes_traced_in_chunks_give_the_same_arrays(monkeypatch):
    # trace_probes casts whole probes PROBE_CHUNK_RAYS rays at a time (bounded memory): any chunking, same results
    import workers.raycast.probes as probes
    caster = RayCaster(PLANE)
    rng = np.random.default_rng(0)
    pos = rng.uniform(-3, 3, (7, 3))
    dirs = rng.normal(size=(5, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ds = np.array([True, False])
    whole = trace_probes(caster, pos, dirs, ds)
    for chunk in (1, 5, 12):                    # under one probe, one probe, two probes and a bit
        monkeypatch.setattr(probes, "PROBE_CHUNK_RAYS", chunk)
        parts = trace_probes(caster, pos, dirs, ds)
        for a, b in zip(whole[:5], parts[:5]):
            np.testing.assert_array_equal(a, b)
    assert (whole[1] >= 0).any() and (whole[1] < 0).any() and whole[4].any()
