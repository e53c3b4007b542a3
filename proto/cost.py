"""The cost model: what a bake will take — peak memory, disk, seconds — before it is accepted.

One model for every side: the API refuses a bake over the server's budget (422 ``over_budget``,
``KILN_MAX_BAKE_MEMORY_MB``, ``KILN_MAX_BAKE_SECONDS``, ``KILN_MAX_BAKE_DISK_MB``), ``POST
/v1/bakes?dry_run=true`` returns the estimate (the artist UI shows it), the queue takes each stage's
timeout and queue (long or short) from it. Pure functions of the scene summary (``triangles``,
``bounds``, and ``bytes`` of the stored normalized scene when known) and the :class:`BakeConfig`;
no I/O, no numpy.

What drives each stage (P probes, R rays per probe, N = P·R probe rays, T triangles, F visibility-field
samples = cells × S³, K clusters, C PRT configurations, M measurement points):

========== ============================================= ===============================================
stage      seconds                                       memory (beyond the worker's own footprint)
========== ============================================= ===============================================
ingest     scene load                                    the scene (its stored bytes ~ 4 x T x 100 B)
place      planning rays (automatic grid) + BVH build    the scene + BVH
relocate   iterations × N rays                           N rays (hits), chunked temporaries (up to 1 M rays)
trace      N rays + depth moments                        N rays, hits kept (20 B a ray), P x depth texels
light      N' (shading, 8 occlusion rays a hit) × bounces N' hits and radiance, chunked temporaries (1 M rays);
           N' = N (1 + light.extra_rays), the adaptive rays
visibility F × 8 corner rays × visibility.rays            F × 8 (θ) per shard; the join F × 9
anneal     sweeps × P + F (edge loss)                    F × 9
masks      F × K                                         F × K floats
clusters   P × K                                         P × K cluster SH volumes
compress   F × K                                         F × K
prt        C × (M + N bounces) + lightmap texels         a batch × N + C × (P × SH + lightmap texels)
reference  (points × spp + preview px × preview_spp) × ~3  the preview G-buffers and reference images
           path vertices (path tracer, Russian roulette);
           check-point normals × check_spp paths
evaluate   points × modes + preview px × modes × draws    W × H per mode of the previews, points × modes
========== ============================================= ===============================================

The automatic grid (``place.counts`` and ``place.spacing`` both None) is estimated at its upper bound:
``place.budget`` probes, and the visibility samples per cell it may choose (at most 16 and at most the field
budget of 12 M samples, :mod:`workers.kernels.autogrid`), since neither is known before the place stage
has cast its planning rays: F at most P x S³ for a given S, else min(P x 16³, max(12 M, P x 4³)) (with fewer
probes than the budget it may choose a larger S). Light bounces until converged are estimated at :data:`EXPECTED_BOUNCES`
(capped by ``light.max_bounces`` or set by ``light.bounces``).

Calibration (``tests/bench/bench_cost.py``, each stage in a forked work-horse): see :data:`CALIBRATION`.
The memory coefficients below are fitted to those bakes (a linear program: the smallest estimate that is at least
every measured stage) so that the memory estimate is an upper bound of every measured stage (by at most 61%) and
bake peak (by at most 39%); the time estimates are rougher (a loaded machine, see there).

Bytes (``artifact_bytes``: every file a stage writes to the store, internal ones included; ``bundle_bytes``: the
bundle's) are the stored files: the visibility shards' internal ``npy`` parts raw (9 B a field sample), the fields'
Zstandard-compressed volumes by the surface law F^(2/3) fitted in :data:`BYTES_CALIBRATION` (θ and the masks are
constant away from surfaces, which Zstandard stores almost for free), the cluster volumes per probe, the baked scene
at most the stored scene's bytes, the depth moments at most DEPTH_STORED of their RG16F bytes, the light stage's
arrays at their stored formats (irradiance RGB9E5, half-float SH) without Zstandard.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from proto.models import BakeConfig

# --------------------------------------------------------------------------------------------- constants

MB = 2**20

FIELD_BUDGET = 12_000_000
"""The automatic grid's cap on probes × S³ (workers.kernels.autogrid.FIELD_BUDGET)."""

AUTO_MAX_S = 16
AUTO_MIN_S = 4
EXPECTED_BOUNCES = 26
"""Bounces assumed for a light stage that runs until converged (measured: 3 on zdm2, 8-26 on the procedural
scenes; a bright closed room needs more, up to light.max_bounces)."""

WORKER_FOOTPRINT = 100 * MB
"""RSS of a work-horse before its stage allocates anything (forked from a worker that imported workers.jobs;
measured 76-90 MB). Part of ``peak_memory_bytes``."""

LONG_STAGE_SECONDS = 30.0
"""Stages estimated above this go to the long queue (``kiln-long``); prt always does. Since the reference is its own
stage, cached per scene (issue 13), evaluate and reference go by their estimates like the others."""

# -- memory, bytes (fitted, see CALIBRATION) ----------------------------------------------------------------
LIB_RAYS = 135 * MB            # Embree, its threads and the numba kernels, loaded by every ray-casting stage
LIB_NUMBA = 150 * MB           # numba kernels of anneal, masks and compress (compiled on first use: +30 - 50 MB)
LIB_SMALL = 12 * MB            # stages that only load and write arrays
LIB_EVAL = 250 * MB            # moderngl on EGL (Mesa llvmpipe) + the path tracer
SCENE_BYTES_PER_TRIANGLE = 112 # the stored normalized scene without textures (triangles, normals, uv0, material)
SCENE_MEM_PER_TRIANGLE = 300   # the loaded scene, its Embree BVH and material tables
SCENE_MEM_PER_BYTE = 2.0       # textures and other stored arrays, loaded (+ derived)
RAY_MEM = {"relocate": 40, "trace": 24, "light": 233}    # per probe ray at the stage's peak (hits, per-ray arrays;
#                                light: 185 measured, + 36 for the SH gather's (9,) float32 basis per hit, light stage 11,
#                                + 12 for the previous bounce's E_indirect per hit (the tail added at the stop, stage 12)
RAY_MEM_EXTRA_CHUNKED = 450    # per adaptive ray of the light stage, up to RAY_MEM_CHUNK of them, beyond RAY_MEM: their
#                                hits are shaded (hit_surfaces' chunked temporaries) while the trace's are held (measured
#                                2026-12-05, bench_cost.py: medium 752 -> 1050 MB for 0.59 M extra rays, defaults 366 ->
#                                499 MB for 0.2 M; big_room 1405 -> 1739 MB for 2.4 M: about 140 B a ray at scale)
RAY_MEM_CHUNKED = {"relocate": 215, "light": 315}        # more per ray up to RAY_MEM_CHUNK rays: the temporaries the
RAY_MEM_CHUNK = 1 << 20                                  # stage bounds (relocation's rescue and optimizer; the light's
                                                         # float64 chunks of 1-2 M hits, kernels.probe_hits)
TRACE_FIXED_MEM = 20 * MB      # the trace stage beyond LIB_RAYS
LIGHT_FIXED_MEM = 40 * MB      # the light stage beyond LIB_RAYS: its numba kernels (spot lights, L2 deringing)
DEPTH_MEM_PER_TEXEL = 78       # trace: per probe and bordered depth-moment texel (the maps and their sums)
VIS_FIXED_MEM = 8 * MB         # a visibility shard beyond LIB_RAYS: its numba kernels
VIS_CHUNK_SAMPLES = (1 << 21) // 8                       # workers.kernels.visibility.CHUNK_RAYS / 8 corners
VIS_CHUNK_MEM = 130 * MB       # a full chunk of visibility rays (bounded by CHUNK_RAYS)
VIS_MEM_PER_SAMPLE = 12        # θ and don't-care of a shard's samples
FIELD_MEM_PER_SAMPLE = {"visibility": 44, "anneal": 15, "masks": 60, "compress": 27}
FIELD_MEM_PER_SAMPLE_CLUSTER = {"masks": 4, "compress": 1}
MASK_MEM_PER_PROBE_CLUSTER = 2050   # clusters: each cluster's L1 and L2 SH volumes over the probes, as it builds them
CLUSTER_SECONDS_PER_PROBE_CLUSTER = 6e-6   # clusters: 0.5 s at zdm2's 20,387 probes x K = 4 (measured 0.03-0.13 s)
PATH_CHUNK = 1 << 18          # paths in flight per wavefront chunk (workers.kernels.pathtrace.DEFAULT_MAX_PATHS)
PATH_BYTES = 512              # bytes per path in flight (ibid.)
PRT_FIXED_MEM = 100 * MB      # the measurement points, the lightmap's atlas (xatlas), the prt kernels
PRT_MEM_PER_CONFIG_RAY = 92    # the batched bounce loop: a batch's configurations' radiance on every probe ray
PRT_MEM_PER_CONFIG_TEXEL = 48  # every configuration's lightmap texels, and their fit (float64)
PRT_MEM_PER_RAY = 256          # the DDGI sampler as a sparse matrix, a row per probe-ray hit
PRT_BATCH_BYTES = 256 << 20    # kernels.prt_dataset.BATCH_BYTES: per-ray radiance of one batch of configurations
EVAL_MEM_PER_PIXEL = 4600      # G-buffer, reference accumulators, every mode's image and FLIP, per pixel
EVAL_MEM_PER_POINT_MODE = 1100 # evaluate: a mode reconstructed at a surface point, its metrics and bootstrap

# -- seconds on this 2-core machine (fitted, see CALIBRATION) -------------------------------------------------
RAY_STAGE_OVERHEAD_S = 0.5     # loading Embree and the numba kernels, reading inputs, writing artifacts
STAGE_OVERHEAD_S = 0.15
PLANNING_SECONDS = 1.0         # the automatic grid's ~200 k planning rays (x the scene's ray-cost scale)
RELOCATE_SECONDS_PER_RAY = 0.25e-6         # per probe ray and iteration (x ray-cost scale)
TRACE_SECONDS_PER_RAY = 1.0e-6             # per probe ray, depth moments included (x ray-cost scale)
LIGHT_SECONDS_PER_HIT = 1.25e-6            # direct light and the cage-probe occlusion rays, once (x ray-cost scale)
LIGHT_SECONDS_PER_HIT_BOUNCE = 0.6e-6      # one bounce of shading and gathering, per probe ray
VIS_SECONDS_PER_RAY = 0.35e-6              # visibility: per occlusion ray (8 per sample and visibility.rays)
FIELD_SECONDS_PER_SAMPLE = {"visibility": 0.15e-6, "anneal": 0.15e-6, "masks": 1.0e-6, "compress": 2.0e-6}
ANNEAL_SECONDS_PER_PROBE_SWEEP = 0.1e-6
PRT_SECONDS_PER_CONFIG_RAY_BOUNCE = 0.11e-6
PRT_SECONDS_PER_CONFIG_TEXEL = 2.3e-6
PRT_SECONDS_PER_CONFIG_POINT = 9e-5        # direct light (shadow rays) per configuration and measurement sample
EVAL_FIXED_SECONDS = 1.0                   # EGL context and shader compiles (with previews), camera placement
EVAL_STAGE_SECONDS = 2.0                   # evaluate: loading the reference and the bake, setting up the modes
EVAL_SECONDS_PER_PATH_BOUNCE = 2.8e-6      # the path-traced reference, per path vertex (x ray-cost scale)
EVAL_SECONDS_PER_PIXEL_PASS = 1e-6         # each mode's shading pass, per repeat
EVAL_FLIP_SECONDS_PER_PIXEL = 5e-6         # FLIP, per mode
EVAL_PATH_VERTICES = 3.0                   # mean vertices of a reference path (64 bounces, roulette from vertex 3)
EVAL_SECONDS_PER_POINT_MODE = 2e-5         # a mode reconstructed at a point, with the metrics' bootstrap

# -- stored bytes (Zstandard; fitted, see BYTES_CALIBRATION) --------------------------------------------------------
ARTIFACT_HEADER = 320          # a KTX2 file's header, DFD, key/value data and Zstandard frame (all-zero volume: 298 B)
NPY_HEADER = 128
# bytes x F^(2/3) (F field samples): the visibility join's three volumes together (theta_0123, theta_4567,
# dont_care), each RGBA8 mask volume (masks_0123, masks_4567), the mask atlas per cluster
THETA_SURFACE_BYTES = 17
MASK_SURFACE_BYTES = 30
ATLAS_SURFACE_BYTES_PER_CLUSTER = 5
INDIRECTION_BYTES_PER_CELL_GROUP = 4     # mask_indirection, per cell and group of 4 clusters (raw 8)
CLUSTER_L1_BYTES_PER_PROBE = 36          # the 3K cluster_sh_{k}_{r,g,b} together: 1.5x one cluster's raw 24 B
CLUSTER_L2_BYTES_PER_PROBE = 56          # the K cluster_sh_l2_{k} together: one cluster's raw (7 RGBA16F texels
                                         # a probe, and 2 padding slices)
CLUSTER_WEIGHT_BYTES_PER_PROBE = 1       # cluster_weights_0123 (+ _4567), each (raw 8)
DEPTH_STORED = 0.65                      # depth_moments (RG16F) as stored / raw: 0.08 - 0.60 measured (0.60 on a
                                         # 4x4x4 grid, 0.38 at 8x4x8, 0.08 on zdm2 at 64x32x64)

CALIBRATION = """
Measured with ``tests/bench/bench_cost.py`` (each stage forked from a warm process, as RQ runs a work-horse, on
this project's shared 2-core machine, loaded by other jobs (load average 4 - 6) while it ran; the measurements are
kept in ``tests/bench/cost_calibration.json``) on 15 bakes: the procedural cornell (1,036 triangles) and two-rooms
(352) at 64 - 18,432 probes, 64 - 1,024 rays per probe (up to 4.7 M probe rays: ``big_room``, a closed room where
every ray hits), S = 2 - 12, one and four slabs, PRT with 64 - 128 configurations and lightmaps of 0 - 256², the
evaluate stage and its reference at their defaults (2,048 surface points x 192 paths, one 160x120 preview) and at
8,192 points without previews; and zdm2-sauerbraten (58,772 triangles) at 12,800 probes (spacing 2.5 m), at 3,360
probes with evaluate, and on its automatic grid (budget 3,000: 2,850 probes, S = 16, 9.3 M field samples). The 13
bakes of :data:`BYTES_CALIBRATION` (``tests/bench/cost_bytes.json``, the same code) hold the fit too.

Estimate / measured (``bench_cost.py --check tests/bench/cost_calibration.json`` prints every stage):

- peak memory of a bake (its largest work-horse's RSS, the starting footprint included): 1.01x - 1.39x (median
  1.09x; the 13 byte bakes 1.01x - 1.54x, median 1.17x); per stage (157 stages) 1.00x - 1.61x, median 1.23x (the 172
  of the byte bakes 1.00x - 1.59x): an upper bound of every one. Per stage: relocate 1.02 - 1.44, trace 1.01 - 1.17,
  light 1.01 - 1.49, the visibility shards 1.00 - 1.26, anneal 1.01 - 1.27, masks 1.05 - 1.36, compress 1.09 - 1.61,
  prt 1.01 - 1.12, reference 1.04 - 1.18, evaluate 1.00 - 1.28. The loosest: zdm2's automatic grid (its field bound,
  12 M samples, where it chose 9.3 M), and the ray stages of open scenes (zdm2, living-room: a ray that misses holds
  less than a hit; the light stage is fitted to closed rooms). Before this fit (the model fitted to last cycle's code)
  the same rows measured 0.65x - 1.80x per stage (34 of 157 under: the light stage 0.81x on two-rooms, trace 0.73x
  on zdm2, relocate 0.75x at 1,024 rays, masks 0.65x at 18,432 probes, prt 0.87x, reference 0.77x without previews)
  and 0.81x - 1.49x per bake (8 of 15 under).
- what the light stage holds beyond the footprint and ``LIB_RAYS`` is not linear in the probe rays: 495 B a ray at
  1.2 M rays (medium), 260 B at 4.7 M (big_room); relocation likewise (and its rescue pass depends on how many probes start
  inside walls: 240 B a ray at 1,024 rays per probe, 70 B on big_room). Both are modelled as a per-ray term and bounded temporaries
  (``RAY_MEM_CHUNKED`` up to ``RAY_MEM_CHUNK`` rays); beyond the largest bake measured (4.7 M rays) the per-ray
  term is extrapolated.
- the first bake after a checkout compiles the numba kernels in its work-horses (``cache=True`` writes them next to
  the sources): ``tiny`` ran first here, +15 - 50 MB a stage over the same bake with the kernels cached (anneal +50,
  light +34, masks, compress and a visibility shard +28 - 30, relocate +15); the fixed footprints cover it.
- seconds of a bake: 0.8x - 3.0x (median 1.2x), but ``tiny`` (0.16x: it compiled the kernels, 27 s for a 4 s
  bake). Per stage 0.06x - 22x; 50 of 157 stages ran longer than estimated on the loaded machine (17 of 171 when
  the previous calibration was measured): the seconds were not refitted but the compress stage (its numba channel
  atlas: 0.3 - 23 s, 2 - 2.5 µs a field sample on zdm2 at S = 16, where it was estimated at 0.12 µs: now 2 µs and the
  0.5 s of a stage that loads numba kernels) and the evaluate stage's fixed 2 s (loading the reference and the
  bake: 2.4 - 4.9 s measured where it was estimated at 1.4 - 1.5 s).

Large configurations are extrapolated: the memory terms are linear in what they hold (probe rays, field samples,
probes x clusters, PRT configurations x probe rays); the largest calibrated bakes (4.7 M probe rays, 12 M field
samples, 64 PRT configurations on 0.3 M rays) bound what is confirmed. zdm2 at 64x32x64 (33.5 M probe rays, sun and
sky; docs/architecture.md "Scale": peak RSS 4.5 GB, the light stage 3.6 GB) is estimated at 6.4 GB (light 6.3 GB;
11.5 GB before this fit). Times on a busier or faster machine differ:
stage timeouts are 4x the estimate + 60 s, at least 2 minutes (:func:`stage_timeout`).
"""

BYTES_CALIBRATION = """
Stored bytes measured with ``bench_cost.py --cases bytes`` (``tests/bench/cost_bytes.json``: every file each stage
wrote, its raw size and whether it is internal) on 13 bakes, the defaults (S = 8, K = 4, 256 rays, four slabs)
unless said: cornell 4³ - 12³ probes (S 4 - 12), two-rooms 12x6x8 and 16x8x12 (K 4 and 8), godot-living-room
16x8x16 and 32x16x32, zdm2-sauerbraten 8x4x8, 16x8x16 (S 8 and 16), 32x16x32 and its automatic grid (2,850 probes,
S = 16); zdm2 and living-room with a sun and a sky (as bench_probes bakes them).

- The field volumes (θ, the dense masks, the mask atlas) are 0 or 255 or repeat away from surfaces; what Zstandard
  keeps grows with the samples near surfaces, as F^(2/3) for a scene (F = cells x S³). zdm2, the densest scene
  measured, stores its three θ volumes in 11.2 - 16.0 x F^(2/3) bytes from 8x4x8 to 32x16x32 and at S = 16 (0.27
  down to 0.06 B a sample: per sample it is no constant), each mask volume in 23.0 - 27.6 x F^(2/3), the atlas in
  11.7 - 18.9 x F^(2/3) (K = 4); living-room 1.7 - 7.3, the procedural rooms 0.2 - 9 (the smallest grids, where
  headers count). The model takes 17, 30 and 5 x K: a scene with more surface per volume than zdm2 would be
  under-estimated there.
- Per probe: the 3K L1 cluster volumes 19 - 35 B together (about one SH: each cluster's is 0 elsewhere), the K
  L2 ones 39 - 73 B (at most 0.94 of one cluster's raw volume, 56 (nz + 2) / nz B), the weights and the clusters
  < 1 B; per cell and group of 4 clusters the indirection 0.2 - 3.6 B; every KTX2 file ~300 B of header and frame.
- The visibility shards' ``theta_part`` / ``dont_care_part`` are raw npy (9 B a sample, internal): the largest
  files of a bake (66 MB of zdm2's 32x16x32), so ``artifact_bytes`` stays ~9 B a field sample.
- The baked scene's GLB (in every bundle) is 0.38x - 0.93x the stored scene's bytes.
- The trace stage's ``depth_moments`` (RG16F) store 0.08x - 0.60x their raw bytes (0.60 on a 4x4x4 grid, 0.08 on
  zdm2 at 64x32x64: the ratio falls as probes get closer); the light stage's ``irradiance`` (RGB9E5) 0.0x (unlit) -
  0.93x (cornell: a lit colourful room hardly compresses), so it is counted raw, as are its SH volumes (0.6x - 1.1x).
  Internal: the rays' hits raw npy (20 B a ray), the float32 depth moments 0.45x - 0.62x raw (counted raw).

Estimate / measured (``bench_cost.py --check tests/bench/cost_bytes.json`` prints every stage and bake):

- field stages (visibility with its shards, anneal, masks, compress; 52 of them), bundle bytes: an upper bound of
  every one, zdm2 1.01x - 1.91x, living-room 1.4x - 11x, the procedural rooms up to 87x (a few kB stored: two-rooms'
  3 kB atlas is estimated at 290 kB). Their artifact bytes 1.0x - 1.3x (the raw shards dominate; 1.29x on zdm2's
  automatic grid, estimated at its bound of 12 M samples where it chose 9.3 M).
- trace: bundle 1.1x - 8.3x (living-room's depth moments compress to 0.08x at 32x16x32), artifacts 1.2x - 1.6x;
  light 1.1x - 2.3x but on zdm2's unlit automatic grid (no sun: all zeros, 650x); ingest 1.1x - 2.7x.
- whole bakes: artifact bytes 1.08x - 1.57x, bundle bytes 1.61x - 3.62x; ``tests/workers/test_cost_bytes.py`` holds
  a two-rooms and a zdm2 bake to 1x - 2x and 1x - 4x, and zdm2's field bundle to 1x - 2x. zdm2 at 64x32x64 (not
  in the set) is estimated at 173 MB of bundle for the 47.7 MB it stores (docs/architecture.md "Scale").
- before (the fields' raw bytes: F x 9 for θ, F x K for the masks and again for the atlas, P x 8 for the clusters;
  no scene GLB): the field stages' bundle 0.6x - 1,400x (median 28x) what they stored, whole bundles 0.46x - 29x
  (zdm2 at 8x4x8 under: its 3.5 MB scene GLB was not counted); zdm2 at 64x32x64 was estimated at 1.3 GB of bundle
  for the 47.7 MB it stores.
"""


# --------------------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class StageCost:
    name: str
    seconds: float
    memory_bytes: int          # the stage's own peak (beyond the worker's footprint)
    artifact_bytes: int        # what it writes to the store (internal artifacts too)
    bundle_bytes: int          # of which in the bundle
    long: bool                 # runs on the long queue


@dataclass(frozen=True)
class Estimate:
    probes: int
    probes_exact: bool          # False: the automatic grid's upper bound (place.budget)
    samples_per_cell: int
    field_samples: int
    seconds: float              # all stages one after another (shards too)
    peak_memory_bytes: int      # the largest stage + the worker's footprint
    artifact_bytes: int         # disk: every artifact of the bake, internal ones too
    bundle_bytes: int = 0       # of which in the bundle (what a team's stored-bytes quota counts)
    stages: list[StageCost] = field(default_factory=list)

    def public(self) -> dict:
        """The JSON the API returns (``POST /v1/bakes?dry_run=true``: ``{"estimate": ...}``)."""
        return {"probes": self.probes, "probes_exact": self.probes_exact, "seconds": round(self.seconds, 1),
                "peak_memory_bytes": int(self.peak_memory_bytes), "artifact_bytes": int(self.artifact_bytes),
                "bundle_bytes": int(self.bundle_bytes),
                "samples_per_cell": self.samples_per_cell, "field_samples": self.field_samples,
                "stages": [{"name": s.name, "seconds": round(s.seconds, 2), "memory_bytes": int(s.memory_bytes),
                            "artifact_bytes": int(s.artifact_bytes), "queue": "long" if s.long else "short"}
                           for s in self.stages]}

    def stage(self, name: str) -> StageCost | None:
        return next((s for s in self.stages if s.name == name), None)


# --------------------------------------------------------------------------------------------- the grid


def _box(summary: dict, config: BakeConfig) -> tuple[list[float], list[float]]:
    sec = config.place
    if sec.box is not None:
        lo, hi = list(sec.box.min), list(sec.box.max)
    else:
        b = summary.get("bounds") or [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
        lo, hi = [float(x) for x in b[0]], [float(x) for x in b[1]]
    pad = [(h - l) * sec.padding for l, h in zip(lo, hi)]
    return [l - p for l, p in zip(lo, pad)], [h + p for h, p in zip(hi, pad)]


def grid_counts(summary: dict, config: BakeConfig) -> tuple[tuple[int, int, int], bool]:
    """Probe counts per axis and whether they are exact (False: the automatic grid's bound, a cube of
    ``place.budget`` probes)."""
    sec = config.place
    if sec.counts is not None:
        return tuple(int(c) for c in sec.counts), True
    if sec.spacing is not None:
        lo, hi = _box(summary, config)
        s = float(sec.spacing)
        counts = []
        for l, h in zip(lo, hi):
            e = h - l
            q = e / s                 # inf for a subnormal spacing (5e-324): clamped like any huge count
            n = (math.ceil(q - 1e-9) + 1 if math.isfinite(q) else 1 << 31) if e > 0 else 1
            counts.append(int(min(max(n, 1), 1 << 31)))
        return tuple(counts), True
    n = max(2, int(sec.budget ** (1 / 3)))
    return (n, n, max(1, math.ceil(sec.budget / (n * n)))), False


def samples_per_cell(config: BakeConfig, probes: int) -> int:
    """S of the visibility field: the config's, else the most the automatic grid may choose."""
    if config.visibility.samples_per_cell is not None:
        return int(config.visibility.samples_per_cell)
    if config.place.counts is not None or config.place.spacing is not None:
        return 8                      # an explicit grid without an automatic choice: the stage's default
    return int(min(AUTO_MAX_S, max(AUTO_MIN_S, int((FIELD_BUDGET / max(probes, 1)) ** (1 / 3)))))


# --------------------------------------------------------------------------------------------- the model


def estimate(summary: dict, config: BakeConfig) -> Estimate:
    """The estimate of one bake of the scene ``summary`` (``triangles``, ``bounds``, optional ``bytes``)."""
    T = max(int(summary.get("triangles") or 0), 1)
    scene_bytes = int(summary.get("bytes") or T * SCENE_BYTES_PER_TRIANGLE)
    extra_bytes = max(scene_bytes - T * SCENE_BYTES_PER_TRIANGLE, 0)      # textures, colours, uv1
    scene_mem = T * SCENE_MEM_PER_TRIANGLE + extra_bytes * SCENE_MEM_PER_BYTE
    rays_scale = math.log2(T + 2) / 10.0     # a ray's cost grows with the BVH's depth

    counts, exact = grid_counts(summary, config)
    nx, ny, nz = counts
    P = nx * ny * nz if exact else config.place.budget      # the automatic grid: at most its budget
    R = config.trace.rays_per_probe
    N = P * R
    S = samples_per_cell(config, P)
    cells = max(nx - 1, 1) * max(ny - 1, 1) * max(nz - 1, 1)
    F = cells * S**3
    if not exact:
        # the automatic grid places at most P probes (fewer cells) and may then choose a larger S: bound F by what it
        # can choose, n S³ <= max(FIELD_BUDGET, n 4³) and <= n 16³ (workers.kernels.autogrid; zdm2 at budget 3,000:
        # 2,850 probes, S = 16, 9.3 M samples where cells x S³ of the cube of P probes gives 8.6 M)
        F = P * S**3 if config.visibility.samples_per_cell is not None else \
            min(P * AUTO_MAX_S**3, max(FIELD_BUDGET, P * AUTO_MIN_S**3))
    K = config.masks.clusters
    B = config.light.bounces or min(config.light.max_bounces, EXPECTED_BOUNCES)
    slabs = config.visibility.slabs
    shards = min(slabs, max(nz - 1, 1))      # slabs beyond the cell layers are empty
    sh_k = 9 if config.light.sh_order == 2 else 4

    st: list[StageCost] = []

    def add(name: str, seconds: float, memory: float, artifacts: float, internal: float = 0.0,
            long: bool | None = None, rays: bool = True):
        seconds += RAY_STAGE_OVERHEAD_S if rays else STAGE_OVERHEAD_S
        st.append(StageCost(name, float(seconds), int(memory), int(artifacts + internal), int(artifacts),
                            bool(seconds > LONG_STAGE_SECONDS if long is None else long)))

    # the lights (JSON) and the baked scene's GLB, at most the stored scene's bytes (measured 0.38x - 0.93x)
    add("ingest", scene_bytes / (200 * MB), LIB_SMALL + scene_bytes * SCENE_MEM_PER_BYTE, 2048 + scene_bytes,
        rays=False)
    if exact:
        add("place", 0.0, LIB_SMALL + scene_bytes * SCENE_MEM_PER_BYTE + P * 24, P * 12, rays=False)
    else:
        add("place", PLANNING_SECONDS * rays_scale, LIB_RAYS + scene_mem + 40 * MB + P * 24, P * 12)
    # the rescue of probes still inside (kernels/relocation.rescue): about one more iteration (zdm2: 36% of the
    # probes inside, each with its rays, their later hits and 6 x 64 test rays)
    rescue = 1 if config.trace.rescue_offset > config.trace.max_offset else 0
    add("relocate", (config.trace.relocate_iterations + rescue) * N * RELOCATE_SECONDS_PER_RAY * rays_scale,
        LIB_RAYS + scene_mem + N * RAY_MEM["relocate"] + min(N, RAY_MEM_CHUNK) * RAY_MEM_CHUNKED["relocate"], P * 24)
    # stored formats (proto/bundle.md 5.1): depth moments RG16F without their tile borders, at most DEPTH_STORED of
    # that with Zstandard; irradiance RGB9E5 without borders, the SH volumes RGBA16F, probe_sh half floats, at their
    # raw bytes (a lit colourful room's irradiance hardly compresses: cornell 0.93x); internal: the float32 bordered
    # depth moments and L1 SH the later stages integrate with (Zstandard, counted raw), the rays' hits (raw npy)
    dn, dt = config.trace.depth_texels, config.trace.depth_texels + 2
    add("trace", N * TRACE_SECONDS_PER_RAY * rays_scale,
        LIB_RAYS + TRACE_FIXED_MEM + scene_mem + N * RAY_MEM["trace"] + P * dt * dt * DEPTH_MEM_PER_TEXEL,
        P * (1 + dn * dn * 4 * DEPTH_STORED) + 2 * ARTIFACT_HEADER,
        internal=N * 20 + config.trace.ray_rotations * R * 12 + P + P * dt * dt * 8 + ARTIFACT_HEADER
        + 4 * NPY_HEADER)
    it = config.light.irradiance_texels
    # the adaptive rays (workers/kernels/adaptive_rays.py): at most light.extra_rays x the probes' rays more, traced,
    # shaded and integrated as the trace's own (the budget is an upper bound; most lit scenes use all of it)
    NL = N * (1.0 + (config.light.extra_rays if config.light.extra_sets > 0 else 0.0))
    add("light", NL * (LIGHT_SECONDS_PER_HIT * rays_scale + B * LIGHT_SECONDS_PER_HIT_BOUNCE)
        + (NL - N) * TRACE_SECONDS_PER_RAY * rays_scale,
        LIB_RAYS + LIGHT_FIXED_MEM + scene_mem + NL * RAY_MEM["light"] + min(N, RAY_MEM_CHUNK) * RAY_MEM_CHUNKED["light"]
        + min(NL - N, RAY_MEM_CHUNK) * RAY_MEM_EXTRA_CHUNKED,
        P * (it * it * 4 + (56 * (nz + 2) / nz if sh_k == 9 else 0) + sh_k * 6 + 24) + 6 * ARTIFACT_HEADER,
        internal=P * 48 + ARTIFACT_HEADER)
    n_shard = F / shards
    chunk = VIS_CHUNK_SAMPLES / config.visibility.rays
    # stored bytes of the fields (BYTES_CALIBRATION): the shards' θ (8 B a sample) and don't-care (1 B) parts raw npy,
    # internal; the joined volumes, the masks and the atlas Zstandard-compressed, by the surface law F^(2/3) (at
    # most their raw bytes)
    surface = F ** (2 / 3)
    G = (K + 3) // 4                          # RGBA8 volumes of 4 clusters each (masks_0123, masks_4567)
    H = ARTIFACT_HEADER
    for i in range(slabs):
        if i < shards:
            add(f"visibility.{i}", n_shard * 8 * config.visibility.rays * VIS_SECONDS_PER_RAY,
                LIB_RAYS + VIS_FIXED_MEM + scene_mem + VIS_CHUNK_MEM * min(1.0, n_shard / chunk)
                + n_shard * VIS_MEM_PER_SAMPLE,
                0, internal=n_shard * 9 + 2 * NPY_HEADER)
        else:
            add(f"visibility.{i}", 0.0, LIB_SMALL, 0, internal=2 * NPY_HEADER, rays=False)
    add("visibility", F * FIELD_SECONDS_PER_SAMPLE["visibility"], LIB_SMALL + F * FIELD_MEM_PER_SAMPLE["visibility"],
        min(F * 9, THETA_SURFACE_BYTES * surface) + 3 * H, rays=False)
    # the clusters (R8, 1 B a probe raw) and the loss after each sweep (float32)
    add("anneal", F * FIELD_SECONDS_PER_SAMPLE["anneal"] + config.masks.sweeps * P * ANNEAL_SECONDS_PER_PROBE_SWEEP,
        LIB_NUMBA + F * FIELD_MEM_PER_SAMPLE["anneal"] + P * 64, P / 2 + 4 * (config.masks.sweeps + 1) + 2 * H)
    # the G dense mask volumes
    add("masks", F * FIELD_SECONDS_PER_SAMPLE["masks"] * max(1.0, K / 4) ** 0.5,
        LIB_NUMBA + F * (FIELD_MEM_PER_SAMPLE["masks"] + K * FIELD_MEM_PER_SAMPLE_CLUSTER["masks"]),
        G * (min(F * 4, MASK_SURFACE_BYTES * surface) + H))
    # the K clusters' SH volumes, each 0 outside its cluster (about one SH a probe as stored): L1 (3K RGBA16F
    # volumes) and for L2 bakes the K L2 atlases (7 (nz + 2) slices); the G weight volumes
    l2 = nx * ny * (nz + 2) * CLUSTER_L2_BYTES_PER_PROBE + K * H if sh_k == 9 else 0
    add("clusters", P * K * CLUSTER_SECONDS_PER_PROBE_CLUSTER, LIB_SMALL + P * K * MASK_MEM_PER_PROBE_CLUSTER,
        P * CLUSTER_L1_BYTES_PER_PROBE + 3 * K * H + l2 + G * (P * CLUSTER_WEIGHT_BYTES_PER_PROBE + H), rays=False)
    # the atlas of the non-constant (cell, cluster) blocks and the indirection (2 G RGBA8 texels a cell)
    add("compress", F * FIELD_SECONDS_PER_SAMPLE["compress"],
        LIB_NUMBA + F * (FIELD_MEM_PER_SAMPLE["compress"] + K * FIELD_MEM_PER_SAMPLE_CLUSTER["compress"]),
        min(F * K, ATLAS_SURFACE_BYTES_PER_CLUSTER * K * surface) + cells * G * INDIRECTION_BYTES_PER_CELL_GROUP
        + 2 * H)   # its numba kernels load like a ray stage's (RAY_STAGE_OVERHEAD_S)
    prt = config.prt
    if prt.enabled:
        C, M = prt.configurations, prt.measurement_points * prt.supersampling * prt.scenario.count
        L2 = prt.lightmap ** 2
        seconds = (C * N * B * PRT_SECONDS_PER_CONFIG_RAY_BOUNCE + C * L2 * PRT_SECONDS_PER_CONFIG_TEXEL
                   + C * M * PRT_SECONDS_PER_CONFIG_POINT * rays_scale / 0.5)
        # configurations are solved in batches of at most 256 MB of per-ray radiance (workers/kernels/prt_dataset.py)
        batch = min(C, max(1, min(64, PRT_BATCH_BYTES // max(N * 12, 1))))
        memory = (LIB_RAYS + PRT_FIXED_MEM + scene_mem + batch * N * PRT_MEM_PER_CONFIG_RAY
                  + C * L2 * PRT_MEM_PER_CONFIG_TEXEL + C * P * sh_k * 12 + N * PRT_MEM_PER_RAY)
        add("prt", seconds, memory, prt.basis * (P * sh_k * 12 + L2 * 16) + C * prt.basis * 4 + T * 24, long=True)
    else:   # disabled: the stage runs and returns at once
        add("prt", 0.0, LIB_SMALL, 0, rays=False, long=False)
    ev = config.evaluate
    if ev.enabled:   # the reference (cached per scene: reads no probe stage) and the metrics at its points
        cams = ev.cameras if isinstance(ev.cameras, int) else len(ev.cameras)
        pv = min(int(ev.previews), cams)                        # cameras with preview images
        px = pv * ev.width * ev.height
        cpn = len(ev.points.points) * (1 if ev.points.normals else 6) if ev.points else 0   # check-point normals
        pts = ev.surface_points + cpn
        # refined surface points (reference.refine_points): dark ones share the first pass's paths again
        # (DARK_BUDGET = 1x), at least dark_spp each (5% of the points at most dark in the scenes measured); the
        # others at most the first pass again (REFINE_BUDGET = 1x) (+ the pilot that chooses them and is the
        # roulette's control variate, a quarter of spp, always run: kernels/reference.pilot_spp)
        dark = max(1.0 * ev.surface_points * ev.spp, 0.05 * ev.surface_points * max(0, ev.dark_spp - ev.spp))
        paths = ev.surface_points * ev.spp * (2.25 if ev.dark_spp > ev.spp else 1.25) + \
            cpn * ev.effective_check_spp() + (dark if ev.dark_spp > ev.spp else 0.0)
        vertices = min(float(ev.bounces or 64), EVAL_PATH_VERTICES)
        modes = len(ev.modes) if ev.modes else 6
        add("reference", (EVAL_FIXED_SECONDS if px else 0.0) + (paths + px * ev.preview_spp) * vertices
            * EVAL_SECONDS_PER_PATH_BOUNCE * rays_scale,
            LIB_EVAL + scene_mem + px * EVAL_MEM_PER_PIXEL + ev.surface_points * ev.spp * 64
            + min(cpn * ev.effective_check_spp(), PATH_CHUNK) * PATH_BYTES, 0, internal=pts * 108 + px * 120)
        # draws per mode and preview: the image and E_indirect, plus a warm-up and `repeats` timed when repeats > 0;
        # EVAL_SECONDS_PER_PIXEL_PASS was calibrated per timed repeat at repeats = 3 (6 draws): half of it a draw
        draws = 2 + (ev.repeats + 1 if ev.repeats else 0)
        seconds = EVAL_STAGE_SECONDS + pts * modes * EVAL_SECONDS_PER_POINT_MODE + px * modes * (
            draws * EVAL_SECONDS_PER_PIXEL_PASS / 2 + (EVAL_FLIP_SECONDS_PER_PIXEL if ev.flip else 0))
        add("evaluate", seconds, LIB_EVAL + scene_mem + px * EVAL_MEM_PER_PIXEL + pts * modes * EVAL_MEM_PER_POINT_MODE + F * 9,
            px * 4 * (2 * modes + 2) + pts * modes * 24,
            internal=ev.surface_points * modes * 12)          # eval_points: float32 RGB per point and mode
    else:
        add("reference", 0.0, LIB_SMALL, 0, rays=False, long=False)
        add("evaluate", 0.0, LIB_SMALL, 0, rays=False, long=False)

    total_s = sum(s.seconds for s in st)
    peak = WORKER_FOOTPRINT + max(s.memory_bytes for s in st)
    disk = sum(s.artifact_bytes for s in st)
    bundle_bytes = sum(s.bundle_bytes for s in st)
    return Estimate(probes=P, probes_exact=exact, samples_per_cell=S, field_samples=F, seconds=total_s,
                    peak_memory_bytes=int(peak), artifact_bytes=int(disk), bundle_bytes=int(bundle_bytes),
                    stages=st)


# --------------------------------------------------------------------------------------------- budget


@dataclass(frozen=True)
class Budget:
    """The server's limits on one bake (``None``: no limit)."""

    memory_bytes: int | None = None
    seconds: float | None = None
    disk_bytes: int | None = None


def over_budget(est: Estimate, budget: Budget) -> list[dict]:
    """What of the estimate is over the budget: ``[{"resource", "estimate", "limit"}]`` (empty: within)."""
    out = []
    if budget.memory_bytes is not None and est.peak_memory_bytes > budget.memory_bytes:
        out.append({"resource": "peak_memory_bytes", "estimate": est.peak_memory_bytes, "limit": budget.memory_bytes})
    if budget.seconds is not None and est.seconds > budget.seconds:
        out.append({"resource": "seconds", "estimate": round(est.seconds, 1), "limit": budget.seconds})
    if budget.disk_bytes is not None and est.artifact_bytes > budget.disk_bytes:
        out.append({"resource": "artifact_bytes", "estimate": est.artifact_bytes, "limit": budget.disk_bytes})
    return out


def stage_timeout(stage: StageCost | None, *, factor: float = 4.0, minimum: float = 120.0,
                  maximum: float = 6 * 3600.0) -> int:
    """The RQ job timeout of a stage: ``factor`` × its estimate, at least ``minimum`` (loading, a busy
    machine), at most ``maximum``."""
    if stage is None:
        return int(minimum)
    return int(min(maximum, max(minimum, factor * stage.seconds + 60.0)))


def as_dict(est: Estimate) -> dict:
    return asdict(est)


def stored_bytes(record: dict) -> tuple[int, int]:
    """What a finished stage stored, the measured side of :class:`StageCost`: ``(artifact_bytes, bundle_bytes)`` of
    its record (``{"artifacts": [ArtifactInfo dicts]}``): every file's bytes, and those of the files the bundle takes
    (not ``meta.internal``, as :func:`proto.stages.build_manifest` selects them)."""
    arts = record["artifacts"]
    return (sum(int(a["bytes"]) for a in arts),
            sum(int(a["bytes"]) for a in arts if not a.get("meta", {}).get("internal")))
