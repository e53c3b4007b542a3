"""The default probe grid, chosen from the scene: where its rooms are, how large they are, how thin its walls.

A fixed 8x8x8 grid over the bounds is wrong for almost every scene: a building on a ground slab five times its
width gets probe columns 143 m apart, a small apartment gets probes a metre apart with walls 10 cm thick. The
light a probe bake carries is right when probes are a fraction of a room apart (measured on two rooms: 1.00-1.01
of Cycles at 0.25 m, 1.3-3.9x at the default grid), and leak-free when the visibility field samples both sides
of every wall.

So the grid is planned from rays, before any probe exists (:func:`analyze_free_space`):

1. **Planning points**: a jittered lattice of about ``n_points`` over the scene bounds (one step on every
   axis). Each point casts ``n_dirs`` rays (a rotated spherical Fibonacci set). A point whose rays mostly hit
   back faces is inside a solid (dropped). Above an open ground plane half the rays escape; a point that sees
   geometry in at least ``NEAR`` of its directions is near something light can bounce between (a wall, a
   building, a street), and one that sees it in at least ``ENCLOSED`` stands in an enclosed space.
2. **Box**: the scene is "enclosed" when at least half of the near points are enclosed (rooms, a building on a
   slab), else "open" (a town, a terrain, objects on a floor). An enclosed scene's box is the bounds of the
   near points, grown by one lattice step — the building and its surroundings, not its ground slab; an open
   scene's box is the scene bounds, grown to the room scale ``ℓ`` (step 3) along any axis where it is thinner than
   that, centred on it: a lone floor or a flat terrain tile has no extent along its normal, and its one layer of
   probes lay in the plane itself (a 10 m ground plane under a sun and a sky read 0 in every mode but leaking, mean
   ratio 0.19-0.20; now 0.99-1.00, and sideways irradiance 2 m above it 1.0 instead of 1.12 of the reference).
3. **Spacing**: the room scale ``ℓ`` = the median over enclosed points of the mean free distance of their rays
   (a 4 x 3 x 4 m room gives about 1.5 m); spacing = ``ℓ / ROOM_DIVISIONS`` (8: about 0.19 m in such a
   room; 6 left the shadow pockets of a real Cornell box 1.12x Cycles and the dark room 5 cm behind two-rooms-vc's
   shared wall 1.10x, 8 gives 0.96-1.095 and 1.05 at about 2.2x the probes, 10 gives 0.98-1.06 and 1.02 at 3.6x
   and about 3x the bake time: tests/bench/bench_fidelity.py), and coarser where the probe budget requires:
   ``s ≥ (V / budget)^(1/3)`` for the box volume V (a uniform grid: the budget binds on large levels — the
   manifest says so). V is the whole box, solid included, on purpose: ``place.budget`` is the most probes the
   grid holds (the presets' and the server's cost estimates rest on it), and a probe in a solid costs memory in
   every volume and its rays in relocate and trace. Counting only the free volume ``V_free = f·V`` (``f`` the
   fraction of planning points in the box outside solids, recorded as ``free_fraction``) was measured on
   zdm2-sauerbraten (``f`` = 0.47): 1.63 m instead of 2.19 m, but 44,850 probes instead of 20,387 (12,057 OFF)
   and 1.9x the bake's CPU time (99 s instead of 52 s, tests/bench/bench_offprobes.py ``--full``), still 1.65x
   the 0.98 m its rooms asked at room scale / 6 (0.74 m at / 8) — no uniform grid meets that within the budget. The record gives the spacing the free
   volume would allow (``spacing_free_volume``, 1.52 m on zdm2) and its probe count (51,168), both before the layer
   fit of step 4 (which stretches the spacing by up to 12% and drops layers over the budget: the bake above).
   Where the budget binds, step 4b makes the grid rectilinear rather than finer everywhere.
4. **Layers between walls**: per axis, the grid's phase (and its spacing, within -12%..+12% of the chosen
   one; never finer while the budget binds) is chosen so that axis-aligned faces (walls, floors, ceilings,
   weighted by area) lie as far as possible from probe layers: a thin wall sits midway between two layers
   (:func:`fit_layers`), not inside one.
4b. **Layers in front of thin walls** (a budget-bound enclosed scene): midway is right while layers are a fraction
   of a room apart, but at a budget-bound spacing the first layer stands far from the wall, and near a thin wall
   between a lit and a dark room the light changes faster than that (apartments, 45 rooms at 0.51 m: the dark room
   5 / 10 cm from the shared wall read 1.22 / 1.20 of Cycles; a uniform grid shifted to put its first layer 5 cm from
   the face read 1.05, but one phase per axis serves one facing of the walls). So the grid becomes **rectilinear**
   (per-axis layer coordinates, ``grid.layers``; :mod:`workers.kernels.grid`; every sampler reads it through the
   continuous layer index, ``probe_grid.glsl`` ``giGridIndex``): along each axis a layer :data:`WALL_DISTANCE` x the
   fill spacing in front of both faces of every thin wall or slab (two large faces looking apart at most
   :data:`THIN_WALL` x the spacing apart: :func:`thin_wall_layers`), the rest filled evenly at most the fill spacing
   apart, a layer within a quarter spacing of a lone large face (a thick wall, the ground) moved a quarter spacing
   from it (:func:`fill_layers`); the fill spacing grows until the budget holds. An axis without thin walls keeps
   the uniform fit; so does a scene bound less than :data:`RECTILINEAR_FACTOR` x. apartments: 1.05 / 1.03 / 0.94 at
   5 / 10 / 25 cm, middle 0.99, in 47 s as before
   (``tests/bench/bench_fidelity.py``). Anchoring lone faces too was measured and dropped: the cell behind a face
   then holds one strip of free space a sample wide, and the visibility field's S samples per cell miss it
   (godot-living-room's walls read 0 in the mask modes).
5. **Walls**: rays from enclosed points continue past their first hit; where a ray enters a solid through a
   front face and leaves through a back face, the distance is that wall's thickness. The 5th percentile ``w``
   sets the visibility field's samples per cell, ``S = ceil(2 s / w)`` within [4, 16], so that samples lie on
   both sides of the thinnest walls (MD §3.4: θ is sampled on a refined grid of S per cell axis), and no more
   than the field budget allows (``probes × S³ ≤ FIELD_BUDGET``).

Everything is deterministic for a seed. Ray work goes through the caster given (no I/O here).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.kernels.sampling import fibonacci_sphere, random_rotation

__all__ = ["FreeSpace", "analyze_free_space", "choose_grid", "ENCLOSED", "ROOM_DIVISIONS", "DEFAULT_BUDGET"]

ENCLOSED = 0.9
"""A point is in an enclosed space when at least this fraction of its rays hit geometry."""

NEAR = 0.6
"""A point is near geometry when it sees more than a ground plane (an infinite plane alone: 0.5)."""

INSIDE_BACKFACES = 0.25
"""A point is inside a solid when more than this fraction of its rays hit back faces (DDGI-P §5's test)."""

ROOM_DIVISIONS = 8.0
"""Probes per room scale: spacing = median mean-free-distance / ROOM_DIVISIONS (module doc, step 3: why 8)."""

DEFAULT_BUDGET = 24_000
"""Probes of a default grid (the 60 s default-bake target on 2 cores for a 60k-triangle interior)."""

FIELD_BUDGET = 12_000_000
"""Visibility-field samples (probes x S³, 8 occlusion rays each) the automatic S may ask for."""


@dataclass
class FreeSpace:
    """What the planning rays found (N lattice points, R rays each)."""

    points: np.ndarray          # (N, 3) float64 lattice points, world space
    inside: np.ndarray          # (N,) bool inside a solid
    hit_fraction: np.ndarray    # (N,) float rays that hit anything
    mean_free: np.ndarray       # (N,) float64 mean hit distance of the rays that hit (m), nan if none
    wall_thickness: np.ndarray  # (W,) float64 thicknesses found (m)
    step: np.ndarray            # (3,) lattice step (m)
    rays: int                   # rays cast
    planes: tuple = ((), (), ())  # per axis: (positions (k,), areas (k,)[, signs (k,)]) of the axis-aligned faces


def analyze_free_space(caster, bounds, double_sided=None, *, n_points: int = 4096, n_dirs: int = 48,
                       seed: int = 0) -> FreeSpace:
    """Cast planning rays from a jittered lattice over ``bounds`` (2, 3) (see the module doc, steps 1 and 4).

    ``double_sided`` (T,) bool: back faces of double-sided triangles count as front faces (a plane has no
    inside), as in the relocate stage.
    """
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    ext = np.maximum(hi - lo, 0.0)
    diag = float(np.linalg.norm(ext)) or 1.0
    rng = np.random.default_rng(np.uint64(seed) ^ np.uint64(0xA070_6A1D))
    live = ext > 1e-3 * diag
    # one lattice step on every axis, from the volume (a flat 40 x 3 x 40 m scene gets ~36 x 3 x 36 points)
    vol = float(np.prod(ext[live])) if live.any() else 0.0
    h = (vol / n_points) ** (1.0 / max(int(live.sum()), 1)) if vol > 0 else diag
    n_axis = np.where(live, np.maximum(1, np.round(ext / max(h, 1e-12))).astype(np.int64), 1)
    step = np.where(n_axis > 1, ext / np.maximum(n_axis, 1), 0.0)
    axes = [lo[a] + (np.arange(n_axis[a]) + 0.5) * step[a] if n_axis[a] > 1 else np.array([(lo[a] + hi[a]) / 2])
            for a in range(3)]
    gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    pts += (rng.random(pts.shape) - 0.5) * step * 0.8                          # jitter within the cell
    N = pts.shape[0]
    dirs0 = fibonacci_sphere(n_dirs)
    rot = random_rotation(rng)
    dirs = dirs0 @ rot.T
    o = np.repeat(pts, n_dirs, axis=0)
    d = np.tile(dirs, (N, 1))
    h = caster.intersect(o, d)
    hit = h.tri >= 0
    back = h.backface & hit
    if double_sided is not None and len(double_sided):
        back &= ~np.asarray(double_sided, bool)[np.maximum(h.tri, 0)]
    hit_r, back_r = hit.reshape(N, n_dirs), back.reshape(N, n_dirs)
    t = np.where(hit, h.t, np.nan).reshape(N, n_dirs).astype(np.float64)
    inside = back_r.mean(axis=1) > INSIDE_BACKFACES
    frac = hit_r.mean(axis=1)
    n_hit = hit_r.sum(axis=1)
    mean_free = np.where(n_hit > 0, np.where(hit_r, t, 0.0).sum(axis=1) / np.maximum(n_hit, 1), np.nan)
    rays = N * n_dirs
    # wall thickness: from enclosed points, front-face first hits continue to the next hit
    enclosed = ~inside & (frac >= ENCLOSED)
    sel = (np.repeat(enclosed, n_dirs) & hit & ~back)
    idx = np.flatnonzero(sel)
    thick = np.zeros(0)
    if idx.size:
        if idx.size > 200_000:
            idx = rng.choice(idx, 200_000, replace=False)
        eps = 1e-5 * diag
        h2 = caster.intersect(o[idx], d[idx], tnear=h.t[idx].astype(np.float64) + eps)
        rays += idx.size
        exits = (h2.tri >= 0) & h2.backface
        if double_sided is not None and len(double_sided):
            exits &= ~np.asarray(double_sided, bool)[np.maximum(h2.tri, 0)]
        thick = (h2.t[exits].astype(np.float64) - h.t[idx][exits].astype(np.float64))
        thick = thick[thick > 0]
    return FreeSpace(points=pts, inside=inside, hit_fraction=frac, mean_free=mean_free, wall_thickness=thick,
                     step=step, rays=rays, planes=axis_planes(caster.triangles))


def axis_planes(triangles) -> tuple:
    """Per axis a: the a-coordinates, areas (m²) and facings (+1: the face looks towards +a) of the triangles facing
    ±a (|n_a| > 0.99): the walls, floors and ceilings a probe layer should not sit on (architecture is mostly
    axis-aligned), and in front of which a budget-bound grid puts a layer (:func:`thin_wall_layers`)."""
    t = np.asarray(triangles, np.float64)
    if t.shape[0] == 0:
        return ((np.zeros(0), np.zeros(0), np.zeros(0)),) * 3
    c = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = 0.5 * np.linalg.norm(c, axis=1)
    n = np.divide(c, 2 * area[:, None], out=np.zeros_like(c), where=area[:, None] > 0)
    out = []
    for a in range(3):
        sel = np.abs(n[:, a]) > 0.99
        out.append((t[sel, :, a].mean(axis=1), area[sel], np.sign(n[sel, a])))
    return tuple(out)


def layer_phase(positions: np.ndarray, weights: np.ndarray, spacing: float, candidates: int = 48) -> tuple[float, float]:
    """The offset φ ∈ [0, s) of probe layers ``φ + k·s`` that keeps them farthest from the given planes, and its
    score: the area-weighted mean of d / (s/2) over the planes (1: every plane midway between two layers).
    A thin wall midway between two layers puts a probe at most half a spacing from a point on either side
    (instead of a layer inside the wall, relocated or OFF, and the next one a whole spacing away)."""
    if positions.size == 0 or spacing <= 0:
        return 0.0, 0.0
    phases = (np.arange(candidates) + 0.5) / candidates * spacing
    frac = np.mod(positions[None, :] - phases[:, None], spacing)            # (C, k) in [0, s)
    d = np.minimum(frac, spacing - frac)
    score = (d * weights[None, :]).sum(axis=1) / (max(float(weights.sum()), 1e-30) * spacing / 2)
    # the score is piecewise linear in φ: equal scores along a plateau differ only by float rounding, which moves
    # with numpy/BLAS builds (two-rooms' x phase flipped 0.107 -> 0.140 m with numpy 2.4, dark room 5 cm from the
    # wall 1.07 -> 1.09x Cycles); rounded, the first phase of a plateau wins on every build (its middle: 1.09, 1.12)
    best = int(np.argmax(np.round(score, 9)))
    return float(phases[best]), float(score[best])


def _binned_planes(pos: np.ndarray, w: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Plane positions merged to ``resolution`` (their areas summed): a few hundred instead of every triangle."""
    if pos.size == 0:
        return pos, w
    key = np.round(pos / resolution).astype(np.int64)
    uniq, inv = np.unique(key, return_inverse=True)
    return uniq * resolution, np.bincount(inv, weights=w)


def fit_layers(pos: np.ndarray, w: np.ndarray, lo: float, hi: float, s0: float,
               stretch=(0.88, 1.12), steps: int = 25) -> tuple[float, float, float]:
    """Per axis: the spacing s ∈ s0·[stretch] and phase φ whose layers keep the walls midway (best
    :func:`layer_phase` score); returns (s, first layer at or below ``lo``, score)."""
    best = (s0, lo, -1.0)
    for f in np.linspace(stretch[0], stretch[1], steps):
        sp = s0 * float(f)
        phi, score = layer_phase(pos, w, sp)
        if score > best[2] + 1e-9:
            best = (sp, lo - float(np.mod(lo - phi, sp)), score)
    return best


WALL_DISTANCE = 0.2
"""A budget-bound grid's layer in front of a thin wall stands this fraction of the fill spacing from its face (module
doc, step 4b). apartments' dark room 5 / 10 / 25 cm from the shared wall, with its first layer at a given distance in
front of the face (bench_fidelity): 5 cm 1.05 / 1.07 / 1.03, 10 cm 1.12 / 1.10 / 1.04, midway (18 cm at 0.51 m)
1.22 / 1.20 / 1.06; with this rule at 0.12 (6.7 cm) 0.95 / 0.93 / 0.86, at 0.2 (10.8 cm) 1.05 / 1.03 / 0.94."""

WALL_AREA = 0.05
"""A face plane counts as a wall when its area is at least this fraction of the box's cross-section across the axis
(a wall or a floor, not a shelf)."""

RECTILINEAR_FACTOR = 2.0
"""Step 4b applies where the budget holds an enclosed scene's spacing at this many times what its rooms ask or more
(apartments 2.5x, zdm2 3.0x). Below it the uniform fit is kept: corridor-l (1.45x) read 0.96-1.04 of Cycles in every
region with it and 0.91-1.07 rectilinear (leg1-far 0.979 -> 0.908); living-room (1.38x) and sun-window (1.79x)
0.95-1.05 uniform (bench_fidelity, 2026-12-06)."""

MAX_FILL = 1.5
"""Step 4b gives up (the uniform fit stays) when its fill spacing would have to exceed this many times the uniform
grid's to hold the thin walls' layers within the budget: a scene of many thin walls (offices, cubicles) would trade
the rooms' resolution for the walls'."""

THIN_WALL = 0.5
"""A wall is thin when its two faces are at most this fraction of the fill spacing apart: a layer on each side."""


def thin_wall_layers(pos, area, sign, lo: float, hi: float, s: float, cross: float, *,
                     distance: float = WALL_DISTANCE, min_area: float = WALL_AREA,
                     thin: float = THIN_WALL) -> tuple[list[float], np.ndarray]:
    """Along one axis: the layers ``distance·s`` in front of both faces of every thin wall, and the large faces'
    coordinates (module doc, step 4b).

    pos, area, sign : (k,) the axis-aligned faces (:func:`axis_planes`: coordinate, m², facing ±1); cross : the
    box's cross-section across the axis (m²). A thin wall is a large face looking towards −a at ``w0`` and one
    looking towards +a at ``w1``, ``0 < w1 − w0 ≤ thin·s`` (a wall, a slab between storeys): its layers are
    ``w0 − distance·s`` and ``w1 + distance·s`` (those inside (lo, hi)). The cell between them holds the wall and
    its two thin strips of free space, which the visibility field's S samples per cell then resolve; a lone face
    (a thick wall, the ground) gets none: a layer right in front of it would leave the cell behind it one sample
    of free space.
    """
    pos, area, sign = (np.asarray(x, np.float64) for x in (pos, area, sign))
    if pos.size == 0 or hi - lo <= 0 or s <= 0:
        return [], np.zeros(0)
    res = s / 50
    key = np.round(pos / res).astype(np.int64) * 2 + (sign > 0)
    uniq, inv = np.unique(key, return_inverse=True)
    farea = np.bincount(inv, weights=area)
    fpos = np.bincount(inv, weights=pos * area) / np.maximum(farea, 1e-30)
    up = uniq % 2 == 1
    big = farea >= min_area * cross
    lows, highs = np.sort(fpos[big & ~up]), np.sort(fpos[big & up])
    out, paired = [], set()
    for w0 in lows:
        j = np.searchsorted(highs, w0, side="right")
        if j < highs.size and highs[j] - w0 <= thin * s:
            paired.update((float(w0), float(highs[j])))
            for x in (w0 - distance * s, highs[j] + distance * s):
                if lo < x < hi:
                    out.append(float(x))
    lone = np.array(sorted(float(f) for f in fpos[big] if float(f) not in paired))
    return sorted(set(out)), lone


def fill_layers(anchors: list[float], lone: np.ndarray, lo: float, hi: float, s: float) -> np.ndarray:
    """Layers from ``lo`` to ``hi`` through the anchors, the gaps filled evenly at most ``s`` apart (an end within s/4
    of an anchor is dropped: the anchor stands for it); then a layer nearer than s/4 to a lone face (a thick wall, the
    ground: ``lone``) is moved to s/4 from it, away from it, within its neighbours — the cell behind a face needs
    free space for its visibility samples."""
    fixed = []
    for x in sorted(anchors):                   # anchors of neighbouring walls within s/20: one layer between them
        if fixed and x - fixed[-1] < s / 20:
            fixed[-1] = (fixed[-1] + x) / 2
        else:
            fixed.append(x)
    knots = ([lo] if not fixed or fixed[0] - lo >= s / 4 else []) + fixed \
        + ([hi] if not fixed or hi - fixed[-1] >= s / 4 else [])
    out = [knots[0]]
    for a, b in zip(knots[:-1], knots[1:]):
        k = max(int(math.ceil((b - a) / s - 1e-9)), 1)
        out.extend(a + (b - a) * (np.arange(1, k + 1) / k))
    L = np.asarray(out, np.float64)
    anchored = np.zeros(L.size, bool)
    for x in fixed:
        anchored |= np.isclose(L, x, rtol=0, atol=1e-9)
    for f in lone:
        for i in np.flatnonzero(~anchored & (np.abs(L - f) < s / 4)):
            want = f + (s / 4 if L[i] >= f else -s / 4)
            left = L[i - 1] if i > 0 else -np.inf
            right = L[i + 1] if i + 1 < L.size else np.inf
            if left < want < right:
                L[i] = want
    return L


def choose_grid(bounds, fs: FreeSpace, *, budget: int = DEFAULT_BUDGET, min_spacing: float = 0.0,
                divisions: float = ROOM_DIVISIONS, field_budget: int = FIELD_BUDGET,
                rectilinear: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Counts (3,), origin (3,), spacing (3,) of the default grid and the record of why (``grid.auto``).

    See the module doc, steps 2-4. The record: ``box`` (min, max), ``kind`` ("enclosed" or "open"),
    ``enclosed_fraction``, ``room_scale`` (m), ``spacing_wanted`` and ``spacing`` (m), ``budget``,
    ``budget_bound`` (bool), ``wall_thickness_p5`` (m or None), ``samples_per_cell``, ``free_fraction`` (of the
    planning points in the box, outside solids), ``budget_volume`` ("box": the volume the budget is spread over,
    solid included), ``spacing_free_volume`` (m) and ``probes_free_volume`` (what spreading it over the free volume
    alone would give, before the layer fit; the spacing when the budget does not bind), ``rectilinear`` (bool, step
    4b) and then ``wall_layers`` (anchored layers per axis), ``spacing_fill`` (m) and ``layers`` (per axis the layer
    coordinates; the place stage moves them to its stats' ``layers``), and ``reason``.

    ``min_spacing`` (m): a floor on the wanted spacing; 0 (the default) sets none. Any length fixed in metres is
    wrong for some scene: the floor of 0.05 m that stood here gave a 4 x 3 x 4 cm model of two-rooms (a tabletop or
    dollhouse diorama at its real size) a 4 x 3 x 3 grid, 1.82x the reference's light, where the same scene at 1:1
    and at 100:1 bakes alike (tests/workers/test_autogrid.py). The probe count is bounded by ``budget`` whatever
    the scale.
    """
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    free = ~fs.inside
    near = free & (fs.hit_fraction >= NEAR)              # sees more than a ground plane: where light bounces
    enclosed = free & (fs.hit_fraction >= ENCLOSED)
    if near.sum() >= 2:
        p = fs.points[near]
        blo = np.maximum(p.min(axis=0) - fs.step, lo)
        bhi = np.minimum(p.max(axis=0) + fs.step, hi)
        sel = near
    else:
        blo, bhi = lo.copy(), hi.copy()
        sel = free
    frac_enclosed = float(enclosed.sum()) / max(int(sel.sum()), 1)
    kind = "enclosed" if frac_enclosed >= 0.5 else "open"
    if kind == "open":                               # light reaches everywhere: probes everywhere
        blo, bhi = lo.copy(), hi.copy()
    mf = fs.mean_free[sel]
    scale = float(np.nanmedian(mf)) if np.isfinite(mf).any() else float(np.linalg.norm(hi - lo)) / 4
    ext = np.maximum(bhi - blo, 0.0)
    if not math.isfinite(scale) or scale <= 0:
        scale = float(np.linalg.norm(ext)) / 4 or 1.0
    thin = (ext < scale) if kind == "open" else np.zeros(3, bool)
    if thin.any():                                   # module doc, step 2: a thin open scene's box spans the room scale
        centre, half = (blo + bhi) / 2, np.maximum(ext, scale) / 2
        blo, bhi = np.where(thin, centre - half, blo), np.where(thin, centre + half, bhi)
        ext = np.maximum(bhi - blo, 0.0)
    wanted = max(scale / divisions, float(min_spacing))
    live = ext[ext > 1e-9]
    volume = float(np.prod(live)) if live.size else 0.0

    def count(sp):
        return int(np.prod([math.ceil(e / sp - 1e-9) + 1 if e > 1e-9 else 1 for e in ext]))

    def fit(b):                                      # the spacing that fits b probes over the box
        sp = wanted
        if count(sp) > b and live.size:
            sp = max(sp, (volume / b) ** (1.0 / live.size))
            while count(sp) > b:                     # rounding of the per-axis counts
                sp *= 1.02
        return sp

    s = fit(budget)
    bound_now = s > wanted * 1.0001
    in_box = np.all((fs.points >= blo - 1e-9) & (fs.points <= bhi + 1e-9), axis=1)
    free_fraction = float((~fs.inside[in_box]).mean()) if in_box.any() else 1.0
    # not used (module doc, step 3): the budget spread over the free volume alone, i.e. budget / f probes in the box
    s_free = fit(budget / max(free_fraction, 1e-3))
    counts = np.array([math.ceil(e / s - 1e-9) + 1 if e > 1e-9 else 1 for e in ext], np.int64)
    spacing = np.where(counts > 1, s, 0.0)
    origin = (blo + bhi) / 2 - spacing * (counts - 1) / 2
    phases = [None, None, None]
    scores = [None, None, None]
    for a in range(3):                              # layers midway between walls (see fit_layers)
        pos_a, w_a = fs.planes[a][:2] if len(fs.planes) == 3 else ((), ())
        pos_a, w_a = np.asarray(pos_a, np.float64), np.asarray(w_a, np.float64)
        keep = (pos_a >= blo[a] - s) & (pos_a <= bhi[a] + s)
        if counts[a] < 2 or not keep.any():
            continue
        pa, wa = _binned_planes(pos_a[keep], w_a[keep], s / 200)
        # shrink no axis while the budget binds (more probes), stretch at most 12%
        sp, first, score = fit_layers(pa, wa, blo[a], bhi[a], s, stretch=(1.0, 1.12) if bound_now else (0.88, 1.12))
        spacing[a] = sp
        origin[a] = first
        counts[a] = int(math.ceil((bhi[a] - first) / sp - 1e-9)) + 1
        phases[a], scores[a] = float(np.mod(first, sp)), score
    while int(np.prod(counts)) > budget:            # the stretch may add a layer: drop the axis' last
        a = int(np.argmax(counts))
        counts[a] -= 1
    layers, wall_counts, s_fill = None, None, None
    if rectilinear and kind == "enclosed" and s >= RECTILINEAR_FACTOR * wanted \
            and all(len(fs.planes[a]) == 3 for a in range(3)):
        # module doc, step 4b: a layer in front of both faces of every thin wall, the rest filled (an axis without
        # thin walls: the uniform fit); the fill spacing grows until the budget holds them
        cross = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])

        def build(sf):
            out = []
            for ax in range(3):
                if ext[ax] <= 1e-9:
                    out.append((np.array([(blo[ax] + bhi[ax]) / 2]), 0))
                    continue
                pos_a, w_a, sg_a = (np.asarray(x, np.float64) for x in fs.planes[ax])
                keep = (pos_a >= blo[ax] - sf) & (pos_a <= bhi[ax] + sf)
                anchors, lone = thin_wall_layers(pos_a[keep], w_a[keep], sg_a[keep], blo[ax], bhi[ax], sf,
                                                 max(cross[ax], 1e-30))
                if anchors:
                    out.append((fill_layers(anchors, lone, blo[ax], bhi[ax], sf), len(anchors)))
                    continue
                first, sp = blo[ax], sf                     # no thin wall across this axis: the uniform fit
                if keep.any():
                    pa, wa = _binned_planes(pos_a[keep], w_a[keep], sf / 200)
                    sp, first, _ = fit_layers(pa, wa, blo[ax], bhi[ax], sf, stretch=(1.0, 1.12))
                out.append((first + sp * np.arange(int(math.ceil((bhi[ax] - first) / sp - 1e-9)) + 1), 0))
            return out

        sf = s
        built = build(sf)
        while int(np.prod([len(L) for L, _ in built])) > budget and sf < MAX_FILL * s:
            sf *= 1.03
            built = build(sf)
        fits = int(np.prod([len(L) for L, _ in built])) <= budget
        if fits and sum(n for _, n in built):           # else the uniform fit stays (too many walls for the budget)
            layers = [L for L, _ in built]
            wall_counts = [int(n) for _, n in built]
            s_fill = float(sf)
            counts = np.array([len(L) for L in layers], np.int64)
            origin = np.array([L[0] for L in layers], np.float64)
            spacing = np.array([(L[-1] - L[0]) / (len(L) - 1) if len(L) > 1 else 0.0 for L in layers], np.float64)
    thick = fs.wall_thickness
    w5 = float(np.percentile(thick, 5)) if thick.size >= 20 else None
    s = float(spacing[counts > 1].max()) if (counts > 1).any() else s       # the coarsest axis, after fitting
    if s_fill is not None:
        s = s_fill                                   # a rectilinear grid: its fill spacing (the largest gaps)
    S = 8 if w5 is None else int(min(16, max(4, math.ceil(2.0 * s / max(w5, 1e-6)))))
    n_probes = int(np.prod(counts))
    s_budget = max(4, int((field_budget / max(n_probes, 1)) ** (1.0 / 3.0)))    # θ costs 8 rays a sample
    field_bound = S > s_budget
    S = min(S, s_budget)
    bound = bound_now
    reason = (f"{kind} scene: room scale {scale:.3g} m (median free distance of the planning rays) / "
              f"{divisions:g} = {wanted:.3g} m")
    if bound:
        reason += (f"; the budget of {budget} probes sets {s:.3g} m (coarser than the rooms ask"
                   + (f"; rectilinear: {sum(wall_counts)} layers {WALL_DISTANCE * s:.3g} m in front of the faces "
                      "of thin walls and slabs" if layers is not None else "; a uniform grid"))
        if free_fraction < 0.95:
            reason += (f"; the budget counts the whole box, {1 - free_fraction:.0%} of it solid: spread over the free "
                       f"volume alone it would give {s_free:.3g} m and {count(s_free)} probes")
        reason += ")"
    if thin.any():
        reason += (f"; the box grown to the room scale along {'/'.join('xyz'[a] for a in range(3) if thin[a])} "
                   "(a thin open scene: light above a floor, not only in its plane)")
    if w5 is not None:
        reason += f"; thinnest walls {w5:.3g} m -> {S} visibility samples per cell"
        if field_bound:
            reason += f" (the field budget of {field_budget} samples allows no more)"
    auto = {"box": [blo.tolist(), bhi.tolist()], "kind": kind, "enclosed_fraction": frac_enclosed,
            "room_scale": scale, "spacing_wanted": wanted, "spacing": s, "budget": int(budget),
            "budget_bound": bool(bound), "wall_thickness_p5": w5, "free_fraction": free_fraction,
            "budget_volume": "box", "spacing_free_volume": float(s_free), "probes_free_volume": count(s_free),
            "layer_phase": phases, "layer_score": scores, "spacing_per_axis": [float(x) for x in spacing], "samples_per_cell": S, "reason": reason,
            "planning_rays": int(fs.rays), "rectilinear": layers is not None}
    if layers is not None:
        auto.update(wall_layers=wall_counts, spacing_fill=s_fill, layers=[[float(x) for x in L] for L in layers])
    return counts, origin, spacing, auto
