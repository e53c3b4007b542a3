"""Probe states (workers/kernels/classification.py, DDGI-P §6.1-6.2 Fig 10)."""
from __future__ import annotations

import numpy as np

from workers.kernels.classification import classify
from workers.kernels.grid import ACTIVE, OFF, SLEEPING


def test_off_active_sleeping():
    t = np.array([[0.1, 0.2, 0.3, 0.4],           # all back faces: inside geometry
                  [0.5, np.inf, 3.0, 3.0],        # a front face within the cell diagonal
                  [2.0, np.inf, 3.0, 3.0],        # nothing near
                  [np.inf] * 4])                  # open space
    back = np.array([[True] * 4, [False] * 4, [False] * 4, [False] * 4])
    states = classify(t, back, cell_diagonal=1.0, backface_fraction=0.25)
    assert states.dtype == np.uint8
    np.testing.assert_array_equal(states, [OFF, ACTIVE, SLEEPING, SLEEPING])


def test_back_faces_do_not_count_as_near_and_the_fraction_is_strict():
    t = np.array([[0.1, 5.0, 5.0, 5.0], [0.1, 0.1, 5.0, 5.0]])
    back = np.array([[True, False, False, False], [True, True, False, False]])
    # 1/4 back faces = 0.25, not more: outside; its only near hit is a back face: SLEEPING. 2/4: OFF
    np.testing.assert_array_equal(classify(t, back, 1.0, 0.25), [SLEEPING, OFF])


def test_infinite_diagonal_makes_every_probe_with_a_front_hit_active():
    t = np.array([[1e6, np.inf], [np.inf, np.inf]])
    back = np.zeros((2, 2), bool)
    np.testing.assert_array_equal(classify(t, back, np.inf, 0.25), [ACTIVE, SLEEPING])
