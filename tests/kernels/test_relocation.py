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


def test_settled_probes_are_those_no_rotation_would_move():
    """Row 0: open air (nearest front face 3 m, no back face); row 1: a front face 0.15 m away, within 2 x the move
    threshold 0.1 (min spacing 1 m); row 2: inside, nearest back face 5 m away, beyond 1.5 x its reach (limit
    (0.45, 0.45, 0.45): 0.78 m); row 3: inside, back face 0.5 m away (it may get out); row 4: open air but it moved
    this iteration; row 5: one back face among front faces (not inside: not settled by either rule)."""
    from workers.kernels.relocation import settled

    t = np.array([[3.0, 4.0, 5.0, INF], [0.15, 4.0, 5.0, 5.0], [5.0, 6.0, 7.0, 2.0], [0.5, 6.0, 7.0, 2.0],
                  [3.0, 4.0, 5.0, INF], [3.0, 4.0, 5.0, 5.0]])
    back = np.array([[False] * 4, [False] * 4, [True, True, True, False], [True, True, True, False], [False] * 4,
                     [True, False, False, False]])
    moved = np.array([False, False, False, False, True, False])
    got = settled(np.zeros((6, 3)), t, back, moved, np.full(3, 0.45), 1.0, 0.25)
    np.testing.assert_array_equal(got, [True, False, True, False, False, False])
    # an offset already taken adds to the reach: 5 m is within 1.5 x (0.78 + 3) m
    got = settled(np.array([[0, 0, 0]] * 2 + [[3.0, 0, 0]] + [[0, 0, 0]] * 3, float), t, back, moved,
                  np.full(3, 0.45), 1.0, 0.25)
    assert not got[2]


def _exit_candidates_vectorized(base, positions, t, back, tri, dirs, normals, limit, margin, k, box=None):
    """The numpy version :func:`exit_candidates` replaced (its greedy loop over the rays of all probes at once)."""
    P, R = t.shape
    cand, ok = np.zeros((P, k, 3)), np.zeros((P, k), bool)
    d = np.asarray(dirs, np.float64)
    tc = np.asarray(t, np.float64)
    use = np.asarray(back, bool) & np.isfinite(tc)
    n = np.asarray(normals, np.float64)[np.where(use, tri, 0)]
    n *= np.where(np.einsum("crj,rj->cr", n, d) < 0, -1.0, 1.0)[..., None]
    c = positions[:, None, :] + d[None] * np.where(use, tc, 0.0)[..., None] + margin * n
    use &= np.all(np.abs(c - base[:, None, :]) <= limit, axis=2)
    if box is not None:
        use &= np.all((c >= box[0]) & (c <= box[1]), axis=2)
    dist = np.where(use, np.linalg.norm(c - base[:, None, :], axis=2), np.inf)
    order = np.argsort(dist, axis=1, kind="stable")
    rows, got = np.arange(P), np.zeros(P, np.int64)
    for j in range(R):
        r = order[:, j]
        q = c[rows, r]
        take = use[rows, r] & (got < k)
        near = np.linalg.norm(cand - q[:, None, :], axis=2) < margin
        take &= ~np.any(near & ok, axis=1)
        cand[rows[take], got[take]] = q[take]
        ok[rows[take], got[take]] = True
        got[take] += 1
    return cand, ok


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exit_candidates_equal_the_vectorized_version(seed):
    """The numba loop picks the same candidates as the numpy version it replaced, on random rays (duplicates within
    the margin, exits beyond the limit and the box, misses)."""
    from workers.kernels.relocation import exit_candidates

    rng = np.random.default_rng(seed)
    P, R, T = 40, 48, 30
    d = rng.normal(size=(R, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normals = rng.normal(size=(T, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t = np.round(rng.uniform(0.05, 1.5, (P, R)), 1)            # rounded: equal distances, ties in the order
    t[rng.random((P, R)) < 0.2] = np.inf
    back = rng.random((P, R)) < 0.6
    tri = np.where(np.isfinite(t), rng.integers(0, T, (P, R)), -1)
    base = rng.normal(size=(P, 3))
    positions = base + rng.uniform(-0.2, 0.2, (P, 3))
    box = (base.min(axis=0) - 0.5, base.max(axis=0))
    for bx in (None, box):
        want = _exit_candidates_vectorized(base, positions, t, back, tri, d, normals, np.full(3, 0.9), 0.2, 6, bx)
        got = exit_candidates(base, positions, t, back, tri, d, normals, np.full(3, 0.9), 0.2, 6, bx)
        np.testing.assert_array_equal(got[1], want[1])
        np.testing.assert_array_equal(got[0], want[0])
        assert want[1].sum() > P                                 # several candidates a probe: the greedy loop ran
