"""Mask Decomposition spatial cost (MD Table 2) and the mask GI payload: run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_md.py [--runs living-room:16x32x16,zdm2:16x32x16,zdm2:32x16x32]
        [--store DIR] [--points 4096]

Scenes (../shared/scenes): godot-living-room's living_room.glb with the two point lights and sky of
tests/data/fidelity/living-room.points.json (the scene has no lights), a house-like interior as MD's Table 2 scene;
zdm2-sauerbraten with a sun and a sky. Each run bakes through the real pipeline up to ``compress`` (S = 8, K = 4,
1000 sweeps, evaluate off; ``--store`` keeps the stage cache between runs) and measures:

* **Compression ratio** = dense mask bytes (``masks_0123`` [+ ``masks_4567``] as R8G8B8A8, uncompressed: what MD
  Table 2's "Mask m" row counts) / (atlas + indirection bytes). "raw": the textures uncompressed (GPU memory);
  "stored": the KTX2 files as the bundle stores them (Zstandard supercompression). Before = the RGBA cell-block
  atlas (``workers/kernels/compress.py`` layout "cell", zstd 3, the format up to issue 17); after = the channel-block
  atlas (``workers/kernels/mask_atlas.py``), lossless and at the bake's ``masks.compress_tolerance``.
* **Mask GI payload per probe** = the file bytes of cluster SH (L1 ``cluster_sh_{k}_{c}`` and L2 ``cluster_sh_l2_{k}``),
  ``cluster_weights_*``, ``mask_atlas*`` and ``mask_indirection`` / probe count. Before: RGBA32F volumes without
  supercompression and the RGBA cell atlas; after: RGBA16F + zstd 19 and the channel atlas as baked.
* **GI error added**: RMSE over rgb at area-uniform surface points (``surface_points.area_points``, views = normals)
  of mask and normalized mask GI (L2, the runtime default; Python samplers = the GLSL) read from the stored
  artifacts, against float32 cluster volumes and the uncompressed masks, relative to the reference's mean; also each
  cause alone (half floats; the tolerance's merged mask blocks).
* **Fetches per pixel** at the same points (the formulas of ``proto/glsl/gi_mask.glsl``): before 1 + A + 7z
  (+ A normalized), after 2G + 2y + 7z (+ A), y = channels stored in the atlas at the pixel's cell.

The table is printed, then the same numbers as one JSON line.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto.ktx2 import encode_ktx2  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels import samplers as SM  # noqa: E402
from workers.kernels.compress import compress_masks, mask_lookups  # noqa: E402
from workers.kernels.mask_atlas import FIRST_SLOT, codes_of, compress_channels, decompress_channels  # noqa: E402
from workers.kernels.mask_fit import cluster_volumes  # noqa: E402
from workers.kernels.sh import sh_l2_atlas  # noqa: E402
from workers.kernels.surface_points import area_points  # noqa: E402

SHARED = ROOT.parent / "shared" / "scenes"
LIVING = json.loads((ROOT / "tests" / "data" / "fidelity" / "living-room.points.json").read_text())
SCENES = {
    "living-room": (SHARED / "godot-living-room" / "living_room.glb", LIVING["config"]["scene"]),
    "zdm2": (SHARED / "zdm2-sauerbraten" / "zdm2.glb",
             {"lights": [{"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0}],
              "sky": [0.3, 0.35, 0.4]}),
}
PAPER = {"scene": "a house with rooms and windows, 16x32x16 probes, K = 4, 8^3 mask samples per cell",
         "K-probes (4 cluster SH volumes)": 0.84e6, "compressed mask": 1.08e6, "ratio": "about 10x (1/16 in §3.4.2)"}
BEFORE_ZSTD = 3   # the compress stage's level up to issue 17


def bake(store: Store, scene, counts, lighting, tolerance=None) -> tuple[dict, dict]:
    masks = {"clusters": 4, "sweeps": 1000, **({} if tolerance is None else {"compress_tolerance": tolerance})}
    cfg = BakeConfig.model_validate({
        "place": {"counts": counts}, "scene": lighting, "light": {"bounces": 3},
        "visibility": {"samples_per_cell": 8}, "masks": masks, "evaluate": {"enabled": False}})
    sid = store.put_bytes(scene.to_bytes())
    recs, times = {}, {}
    for st in [s for s, _ in plan(sid, cfg)]:
        t0 = time.perf_counter()
        recs[st.name] = (pipeline.execute_stage(store, sid, cfg, st.name)[0], None)
        times[st.name] = time.perf_counter() - t0
        recs[st.name] = (recs[st.name][0], pipeline._lazy(store, recs[st.name][0]))
        if st.name == "compress":
            break
    return recs, times


def file_bytes(a, zstd) -> int:
    return len(encode_ktx2(np.ascontiguousarray(a), zstd_level=zstd))


def gi(mode, arrays, grid, pts, nrm):
    return np.maximum(SM.irradiance(mode, arrays, grid, pts, nrm, views=nrm), 0.0)


def run(name: str, counts, store: Store, n_points: int, tolerance=None) -> dict:
    path, lighting = SCENES[name]
    scene = ingest_file(path)
    recs, times = bake(store, scene, counts, lighting, tolerance)
    lazy = {k: v[1] for k, v in recs.items()}
    info = {a["name"]: a for st in ("masks", "clusters", "compress") for a in recs[st][0]["artifacts"]}
    place = lazy["place"].stats
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}
    P = int(np.prod(place["counts"]))
    K = int(lazy["masks"].stats["clusters"])
    S = int(lazy["masks"].stats["samples_per_cell"])
    masks = [np.asarray(lazy["masks"][n]) for n in ("masks_0123", "masks_4567") if n in lazy["masks"]]
    dense = int(sum(v.nbytes for v in masks))
    comp = lazy["compress"].stats

    # compression: before (RGBA cell blocks), after lossless and as baked (channel blocks)
    cell = compress_masks(masks, counts, S, layout="cell")
    before_raw = int(sum(a.nbytes for a in cell.atlases) + cell.indirection.nbytes)
    before_stored = int(sum(file_bytes(a, BEFORE_ZSTD) for a in cell.atlases)
                        + file_bytes(cell.indirection, BEFORE_ZSTD))
    lossless = compress_channels(masks, counts, S, K)
    ll_stored = file_bytes(lossless.atlas, 19) + file_bytes(lossless.indirection, 19)
    after_raw = int(comp["compressed_bytes"])
    after_stored = int(info["mask_atlas"]["bytes"] + info["mask_indirection"]["bytes"])

    # cluster volumes: before float32 (recomputed as the masks stage made them), after as stored
    light, states = lazy["light"], lazy["trace"]["probe_states"].reshape(-1)
    g = lazy["anneal"]["clusters"].reshape(-1).astype(np.int64)
    sh1 = np.stack([light[f"sh_l1_{c}"] for c in "rgb"], axis=-1).astype(np.float32)
    v1, w = cluster_volumes(sh1, g, K, states)
    v2, _ = cluster_volumes(np.asarray(light["probe_sh"], np.float32), g, K, states)
    ref = {f"cluster_sh_{k}_{c}": v1[k][..., i] for k in range(K) for i, c in enumerate("rgb")}
    ref.update({f"cluster_sh_l2_{k}": sh_l2_atlas(v2[k]) for k in range(K)})
    for q in range(len(masks)):
        wq = np.zeros(w.shape[:3] + (4,), np.float32)
        part = w[..., 4 * q:4 * q + 4]
        wq[..., :part.shape[-1]] = part
        ref[f"cluster_weights_{'0123' if q == 0 else '4567'}"] = wq
    sh_names = [n for n in ref if n.startswith("cluster_sh")]
    w_names = [n for n in ref if n.startswith("cluster_weights")]
    sh_before = sum(file_bytes(ref[n], None) for n in sh_names)
    w_before = sum(file_bytes(ref[n], None) for n in w_names)
    sh_after = sum(info[n]["bytes"] for n in sh_names)
    w_after = sum(info[n]["bytes"] for n in w_names)

    # GI error added, at surface points (L2, the runtime default)
    sp = area_points(scene, n_points, seed=0)
    pts, nrm = sp["position"], sp["normal"]
    stored = {n: np.asarray(lazy["clusters"][n]) for n in sh_names + w_names}
    decomp = decompress_channels(np.asarray(lazy["compress"]["mask_atlas"]),
                                 np.asarray(lazy["compress"]["mask_indirection"]),
                                 {"samples_per_cell": S, "clusters": K})
    mset = lambda vols: {"masks_0123": vols[0], **({"masks_4567": vols[1]} if len(vols) > 1 else {})}  # noqa: E731
    variants = {"reference": {**ref, **mset(masks)}, "half": {**stored, **mset(masks)},
                "masks": {**ref, **mset(decomp)}, "stored": {**stored, **mset(decomp)}}
    err = {}
    for mode in ("mask", "mask_normalized"):
        e0 = gi(mode, variants["reference"], grid, pts, nrm)
        mean = float(e0.mean())
        d = {v: gi(mode, variants[v], grid, pts, nrm) - e0 for v in ("half", "masks", "stored")}
        err[mode] = {"mean_irradiance": mean, **{v: float(np.sqrt((x ** 2).mean()) / mean) for v, x in d.items()},
                     "max_point": float(np.abs(d["stored"]).max() / mean)}

    # fetches per pixel (gi_mask.glsl), L2
    m = SM.mask_values(decomp, pts, nrm, grid, 1.0, nrm)[:, :K]
    z = (m > 0).sum(axis=1)
    A = -(-K // 4)
    _, cellc = mask_lookups(pts, counts, grid["origin"], grid["spacing"], S)
    ci = cellc.astype(np.int64)
    codes = codes_of(np.asarray(lazy["compress"]["mask_indirection"]), K)
    y = (codes[ci[:, 2], ci[:, 1], ci[:, 0]] >= FIRST_SLOT).sum(1)
    fetches = {"before": {"mask": float((1 + A + 7 * z).mean()), "mask_normalized": float((1 + 2 * A + 7 * z).mean())},
               "after": {"mask": float((2 * A + 2 * y + 7 * z).mean()),
                         "mask_normalized": float((3 * A + 2 * y + 7 * z).mean())},
               "clusters_sampled": float(z.mean()), "stored_channels": float(y.mean())}
    return {
        "scene": name, "counts": list(counts), "probes": P, "S": S, "K": K, "points": int(len(pts)),
        "tolerance": comp["tolerance"], "max_block_error": comp["max_block_error"],
        "dense_bytes": dense,
        "before": {"atlas_raw": int(sum(a.nbytes for a in cell.atlases)),
                   "indirection_raw": int(cell.indirection.nbytes),
                   "raw": before_raw, "stored": before_stored, "ratio_raw": dense / before_raw,
                   "ratio_stored": dense / before_stored, "unique_blocks": cell.stats["unique_blocks"],
                   "cluster_sh_bytes": sh_before, "weights_bytes": w_before,
                   "payload_per_probe": (sh_before + w_before + before_stored) / P},
        "after_lossless": {"raw": int(lossless.stats["compressed_bytes"]), "stored": ll_stored,
                           "ratio_raw": lossless.stats["ratio"], "ratio_stored": dense / ll_stored,
                           "atlas_blocks": lossless.stats["atlas_blocks"]},
        "after": {"atlas_raw": int(comp["atlas_bytes"]), "indirection_raw": int(comp["indirection_bytes"]),
                  "atlas_stored": int(info["mask_atlas"]["bytes"]),
                  "indirection_stored": int(info["mask_indirection"]["bytes"]),
                  "raw": after_raw, "stored": after_stored, "ratio_raw": dense / after_raw,
                  "ratio_stored": dense / after_stored,
                  "atlas_blocks": comp["atlas_blocks"], "constant_zero": comp["constant_zero"],
                  "constant_one": comp["constant_one"], "channel_blocks": comp["channel_blocks"],
                  "cluster_sh_bytes": int(sh_after), "weights_bytes": int(w_after),
                  "payload_per_probe": (sh_after + w_after + after_stored) / P},
        "gi_error": err, "fetches": fetches,
        "seconds": {k: round(v, 2) for k, v in times.items() if k in ("anneal", "masks", "compress")},
    }


def table(rows: list[dict]) -> list[str]:
    out = ["MD Table 2 spatial cost (bytes). ratio = dense RGBA8 mask bytes / (atlas + indirection); raw = textures "
           "uncompressed (GPU), stored = KTX2 files with zstd as in the bundle.",
           f"{'run':>22s} {'dense':>11s} {'atlas':>10s} {'indir':>8s} {'raw x':>6s} {'stored':>9s} {'stored x':>8s} "
           f"{'clusterSH':>10s} {'weights':>8s} {'B/probe':>8s}"]
    for r in rows:
        run = f"{r['scene']} {'x'.join(map(str, r['counts']))}"
        b, a, ll = r["before"], r["after"], r["after_lossless"]
        out.append(f"{run + ' before':>22s} {r['dense_bytes']:11,d} {b['atlas_raw']:10,d} {b['indirection_raw']:8,d} "
                   f"{b['ratio_raw']:6.2f} {b['stored']:9,d} {b['ratio_stored']:8.1f} {b['cluster_sh_bytes']:10,d} "
                   f"{b['weights_bytes']:8,d} {b['payload_per_probe']:8.1f}")
        out.append(f"{'lossless channels':>22s} {'':11s} {'':10s} {'':8s} {ll['ratio_raw']:6.2f} {ll['stored']:9,d} "
                   f"{ll['ratio_stored']:8.1f}")
        out.append(f"{'after':>22s} {'':11s} {a['atlas_raw']:10,d} {a['indirection_raw']:8,d} {a['ratio_raw']:6.2f} "
                   f"{a['stored']:9,d} {a['ratio_stored']:8.1f} {a['cluster_sh_bytes']:10,d} {a['weights_bytes']:8,d} "
                   f"{a['payload_per_probe']:8.1f}")
    out.append("")
    out.append(f"{'run':>22s} {'tol':>8s} {'GI err mask':>12s} {'normalized':>11s} {'(half':>7s} {'masks)':>7s} "
               f"{'fetches mask before/after':>26s} {'normalized':>12s}")
    for r in rows:
        e, f = r["gi_error"], r["fetches"]
        run = f"{r['scene']} {'x'.join(map(str, r['counts']))}"
        out.append(f"{run:>22s} {int(r['tolerance'] * 255 + 1e-9):4d}/255 "
                   f"{100 * e['mask']['stored']:11.3f}% {100 * e['mask_normalized']['stored']:10.3f}% "
                   f"{100 * e['mask_normalized']['half']:6.3f}% {100 * e['mask_normalized']['masks']:6.3f}% "
                   f"{f['before']['mask']:12.2f} / {f['after']['mask']:5.2f}      "
                   f"{f['before']['mask_normalized']:5.2f} / {f['after']['mask_normalized']:5.2f}")
    out.append(f"paper (MD Table 2, 16x32x16, K = 4): K-probes {PAPER['K-probes (4 cluster SH volumes)']:,.0f} B, "
               f"compressed mask {PAPER['compressed mask']:,.0f} B, ratio {PAPER['ratio']}")
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", default="living-room:16x32x16,zdm2:16x32x16,zdm2:32x16x32")
    ap.add_argument("--store", default=None, help="stage cache folder (default: a temporary one)")
    ap.add_argument("--points", type=int, default=4096)
    ap.add_argument("--tolerance", type=float, default=None, help="masks.compress_tolerance (default: the config's)")
    args = ap.parse_args()
    runs = [(r.split(":")[0], [int(x) for x in r.split(":")[1].split("x")]) for r in args.runs.split(",")]
    missing = [SCENES[n][0] for n, _ in runs if not SCENES[n][0].exists()]
    if missing:
        print(f"skipped: {missing} absent (the benchmark reads ../shared/scenes)")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(args.store or tmp)
        rows = [run(n, c, store, args.points, args.tolerance) for n, c in runs]
    print("\n".join(table(rows)))
    print(json.dumps({"paper": PAPER, "runs": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
