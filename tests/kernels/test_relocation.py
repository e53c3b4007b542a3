"""One iteration of the probe position optimizer (workers/kernels/relocation.py, DDGI-P §5 Fig 7), closed forms."""
from __future__ import annotations

import numpy as np
import pytest

from workers.kernels.relocation import relocation_step

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
INF = np.inf


def step(t, back, offsets=None, limit=1.0, min_spacing=1.0, fraction=0.25, dirs=AXES):
    t = np.atleast_2d(np.asarray(t, float))
    back = np.atleast_2d(np.asarray(back, bool))
    off = np.zeros((t.shape[0], 3)) if offsets is None else np.atleast_2d(np.asarray(offsets, float))
    return relocation_step(off, t, back, dirs, np.full(3, limit), min_spacing, fraction)


def test_inside_moves_through_the_closest_back_face_to_the_limit():
    """Fig 7 first branch: closest back face 0.1 m along +x, limit 1 m: scale = 1/0.1 − 1e-3, so the probe
    goes to 0.1 · (10 − 0.001) = 0.9999 m along +x (the per-axis solve; y, z unbounded)."""
    new = step([0.1, 0.5, 0.3, 0.3], [True] * 4)
    np.testing.assert_allclose(new, [[0.1 * (10 - 1e-3), 0, 0]], rtol=1e-12)


def test_inside_stays_when_the_limit_does_not_reach_past_the_back_face():
    """Back face 2 m away, limit 1 m: scale 0.5 − 1e-3 ≤ 1, so no move (Fig 7: "can't move through")."""
    np.testing.assert_array_equal(step([2.0, 3.0, 3.0, 3.0], [True] * 4), np.zeros((1, 3)))


def test_back_face_fraction_is_strict():
    """1 of 4 back faces is not more than 0.25: the probe is outside (far front faces: no move)."""
    np.testing.assert_array_equal(step([0.5, 3, 3, 3], [True, False, False, False]), np.zeros((1, 3)))


def test_close_front_face_steps_toward_the_farthest():
    """Closest front face 0.05 < 0.1 · min spacing, farthest 3 m along −x: step min(0.2 · 1, 3) along −x."""
    np.testing.assert_allclose(step([0.05, 3.0, 1.0, 1.0], [False] * 4), [[-0.2, 0, 0]])
    # the step is at most the farthest front face's distance: 0.15 m
    np.testing.assert_allclose(step([0.05, 0.15, 0.1, 0.1], [False] * 4, min_spacing=1.0), [[-0.15, 0, 0]])


def test_same_surface_within_60_degrees_does_not_move():
    dirs = np.array([[1, 0, 0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0]])   # 30° apart
    np.testing.assert_array_equal(step([0.05, 3.0], [False, False], dirs=dirs), np.zeros((1, 3)))


def test_new_offsets_beyond_the_limit_are_rejected():
    """A step of 0.2 m from an offset of 0.05 m leaves a 0.1 m limit: the old offset is kept (RTXGI)."""
    old = [[0.05, 0, 0]]
    np.testing.assert_array_equal(step([0.05, 3.0, 1.0, 1.0], [False] * 4, offsets=old, limit=0.1), old)


@pytest.mark.parametrize("seed", [0, 1])
def test_probes_are_independent(seed):
    """Each row is its own probe: stacking probes gives each its single-probe result."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.01, 2.0, (5, 4))
    back = rng.random((5, 4)) < 0.4
    together = step(t, back)
    for p in range(5):
        np.testing.assert_array_equal(together[p], step(t[p], back[p])[0])


def test_exit_candidates_nearest_first_within_the_limit_and_distinct():
    """Back-face exits along ±x at 0.5 and 0.8 m, +y at 2 m (beyond a 0.95 m limit), a front face along −y:
    candidates = exit + 0.1 m along the exit face's outward normal, nearest the grid position first."""
    from workers.kernels.relocation import exit_candidates

    t = np.array([[0.5, 0.8, 2.0, 0.3]])
    back = np.array([[True, True, True, False]])
    tri = np.array([[0, 1, 2, 3]])
    normals = np.array([[-1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]], float)   # any orientation: made outward
    cand, ok = exit_candidates(np.zeros((1, 3)), np.zeros((1, 3)), t, back, tri, AXES, normals, np.full(3, 0.95),
                               0.1, k=3)
    np.testing.assert_array_equal(ok, [[True, True, False]])
    np.testing.assert_allclose(cand[0, :2], [[0.6, 0, 0], [-0.9, 0, 0]])
    # from a relocated start, distances still count from the grid position (0.2 m along +x: 0.6 + 0.2 = 0.8 first)
    cand, ok = exit_candidates(np.zeros((1, 3)), np.array([[0.2, 0, 0]]), t, back, tri, AXES, normals,
                               np.full(3, 0.95), 0.1, k=3)
    np.testing.assert_allclose(cand[0, ok[0]], [[-0.7, 0, 0], [0.8, 0, 0]])
    # two exits closer than the margin give one candidate
    cand, ok = exit_candidates(np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.5, 0.55, 3.0, 3.0]]), back, tri,
                               np.array([[1, 0, 0], [1, 0.01, 0], [0, 1, 0], [0, -1, 0]], float), normals,
                               np.full(3, 0.95), 0.1, k=3)
    assert ok.sum() == 1


def test_free_space_needs_few_back_faces_and_no_close_front_face():
    from workers.kernels.relocation import free_space

    t = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [0.04, 1.0, 1.0, 1.0], [np.inf] * 4])
    back = np.array([[False] * 4, [True, False, False, False], [False] * 4, [False] * 4])
    # row 1: 1 of 4 back faces > half of 0.25; row 2: a front face 4 cm away < 0.1 / 2
    np.testing.assert_array_equal(free_space(t, back, 0.1, 0.25), [True, False, False, True])


def test_exit_candidates_stay_in_the_grid_box():
    """A probe of the grid's outer layer (x = 0, the box's lo face) whose nearest exit leads out of the box (−x):
    that candidate is dropped (no cells there), the one inside the box is kept."""
    from workers.kernels.relocation import exit_candidates

    t = np.array([[0.3, 0.1, 3.0, 3.0]])
    back = np.array([[True, True, False, False]])
    tri = np.array([[0, 1, 2, 2]])
    normals = np.array([[1, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    args = (np.zeros((1, 3)), np.zeros((1, 3)), t, back, tri, AXES, normals, np.full(3, 0.95), 0.1)
    cand, ok = exit_candidates(*args, k=2)
    np.testing.assert_allclose(cand[0, ok[0]], [[-0.2, 0, 0], [0.4, 0, 0]])
    cand, ok = exit_candidates(*args, k=2, box=(np.zeros(3), np.ones(3)))
    np.testing.assert_allclose(cand[0, ok[0]], [[0.4, 0, 0]])
