"""Probe states from the final probe rays (DDGI-P §6.1-6.3, Fig 10, offline subset; numpy only).

- **OFF** (§6.1): more than ``backface_fraction`` of the rays still hit back faces: the probe is inside
  geometry after relocation and is never used.
- **ACTIVE** (§6.2, Fig 10's "NEWLY VIGILANT"): the closest front face is nearer than ``cell_diagonal``:
  a surface within the probe's cells, which it shades.
- **SLEEPING** (§6.2, Fig 10): nothing that near.

Fig 10 compares the front-face distance with the probe spacing; we use the cell diagonal because a probe
shades every point of its 8 cells. The dynamic-geometry states (Awake, Newly Awake) have no offline
counterpart. States: :data:`workers.kernels.grid.OFF`, ``ACTIVE``, ``SLEEPING``. Consumer: stage ``trace``.
"""
from __future__ import annotations

import numpy as np

from workers.kernels.grid import ACTIVE, OFF, SLEEPING

__all__ = ["classify"]


def classify(t: np.ndarray, back: np.ndarray, cell_diagonal: float, backface_fraction: float) -> np.ndarray:
    """(P,) uint8 probe states (DDGI-P Fig 10).

    Parameters
    ----------
    t : (P, R) float
        Hit distances of the final rays, metres (inf = miss).
    back : (P, R) bool
        The ray hit the back of a single-sided triangle.
    cell_diagonal : float
        Length of a grid cell's diagonal, metres (inf: every probe with a hit is ACTIVE).
    backface_fraction : float
        Fraction of back-face hits above which a probe is inside geometry.
    """
    R = t.shape[1]
    inside = back.sum(axis=1) / R > backface_fraction                         # Fig 10: "if (still in wall): OFF"
    closest_front = np.where(back, np.inf, t).min(axis=1)
    states = np.where(closest_front < cell_diagonal, ACTIVE, SLEEPING).astype(np.uint8)  # Fig 10: frontfaceDistance <
    states[inside] = OFF
    return states
