"""Stage ``anneal``: the probe colouring g of Mask Decomposition (MD §3.3, §3.4 steps 2-3).

Reads ``place`` (grid stats), ``trace`` (``probe_states``) and ``visibility`` (``theta_0123``,
``theta_4567``, ``dont_care``); config ``masks`` (clusters K, coloring, sweeps, regularization λ)
and ``seed``.

1. E(i, j), MD eq 6, for every pair of probes sharing a cell, in one pass over θ
   (:func:`workers.kernels.coloring.edge_loss`; a sum over samples as in the paper, don't-care samples
   weigh 0, OFF probes are left out);
2. ``coloring = "anneal"``: simulated annealing on eq 7 + eq 8 from a convex division of the grid
   into K boxes (:func:`~workers.kernels.coloring.convex_division`), ``sweeps`` Metropolis sweeps over
   the probes at geometrically falling temperatures
   (:func:`~workers.kernels.coloring.temperature_schedule`: with Ē the mean positive E, T0 = 3·Ē,
   T_end = min(1e-3·Ē, 0.1·λ)), seeded by the bake seed; the best colouring seen at a sweep end is kept, so the result
   never ends above the initial loss. ``coloring = "parity"`` (K = 8): eq 4, no annealing.

Outputs
-------
``clusters`` : (nz, ny, nx, 1) uint8, KTX2 R8 — g, the cluster of each probe (0 … K−1; OFF probes keep
    their initial colour and are ignored downstream).
``anneal_loss`` : (sweeps + 1,) float32, a KTX2 table (R32_SFLOAT) — eq 7 + eq 8 of the initial colouring,
    then after each sweep (the current state; the kept colouring is the minimum). Parity: (1,).
stats : ``coloring``, ``clusters``, ``sweeps``, ``edges`` (pairs sharing a cell, OFF excluded),
    ``edge_loss_total`` (Σ E), ``initial_loss``, ``final_loss`` (eq 7 + eq 8 of g),
    ``final_edge_loss`` (eq 7 of g), ``random_loss`` (mean eq 7 of 8 random colourings seeded by the
    bake seed), ``t0``, ``t_end``, ``accepted``, ``cluster_sizes`` (non-OFF probes per cluster),
    ``edge_seconds``, ``anneal_seconds``.
"""
from __future__ import annotations

import time

import numpy as np

from workers.kernels.grid import OFF
from workers.kernels.coloring import anneal, coloring_loss, convex_division, edge_loss, parity_coloring, random_loss
from workers.kernels.mask_field import join_theta
from workers.stages.base import Artifact, StageContext, StageOutput

RANDOM_TRIALS = 8


def run_anneal(ctx: StageContext) -> StageOutput:
    sec = ctx.config.masks
    place = ctx.inputs["place"].stats
    counts = [int(c) for c in place["counts"]]
    nx, ny, nz = counts
    P = nx * ny * nz
    vis = ctx.inputs["visibility"]
    theta = join_theta(vis["theta_0123"], vis["theta_4567"])
    dont_care = vis["dont_care"]
    S = theta.shape[2] // max(nx - 1, 1)                                     # samples per cell axis
    states = ctx.inputs["trace"]["probe_states"].reshape(-1)
    K = int(sec.clusters)

    t0 = time.perf_counter()
    pairs, weights = edge_loss(theta, dont_care, counts, S, states)          # eq 6
    t_edge = time.perf_counter() - t0
    ctx.report(0.2)

    t1 = time.perf_counter()
    if sec.coloring == "parity":                                             # eq 4
        g = parity_coloring(counts)
        e7, e8 = coloring_loss(pairs, weights, g, sec.regularization)
        loss = np.array([e7 + e8])
        info = {"initial_loss": e7 + e8, "final_loss": e7 + e8, "t0": 0.0, "t_end": 0.0, "accepted": 0}
    else:                                                                    # eq 7 + eq 8
        init = convex_division(counts, K, place["spacing"])
        g, loss, info = anneal(pairs, weights, P, K, sweeps=sec.sweeps, regularization=sec.regularization,
                               seed=ctx.config.seed, init=init, states=states)
    t_anneal = time.perf_counter() - t1
    ctx.report(0.9)

    final_edge, _ = coloring_loss(pairs, weights, g)
    rand = random_loss(pairs, weights, P, K, seed=ctx.config.seed, trials=RANDOM_TRIALS)
    on = states != OFF
    stats = {
        "coloring": sec.coloring, "clusters": K, "sweeps": int(loss.shape[0] - 1), "edges": int(pairs.shape[0]),
        "edge_loss_total": float(weights.sum()), "initial_loss": float(info["initial_loss"]),
        "final_loss": float(info["final_loss"]), "final_edge_loss": float(final_edge), "random_loss": rand,
        "t0": float(info["t0"]), "t_end": float(info["t_end"]), "accepted": int(info["accepted"]),
        "cluster_sizes": np.bincount(g[on], minlength=K).tolist(),
        "edge_seconds": t_edge, "anneal_seconds": t_anneal,
    }
    ctx.report(1.0)
    return StageOutput(
        artifacts=[
            Artifact("clusters", g.astype(np.uint8).reshape(nz, ny, nx, 1),
                     description="probe cluster g (MD §3.3), 0..K-1 per probe",
                     meta={"clusters": K, "coloring": sec.coloring}),
            Artifact("anneal_loss", loss.astype(np.float32), table=True,
                     description="eq 7 + eq 8 of the initial colouring and after each annealing sweep"),
        ],
        stats=stats,
    )
