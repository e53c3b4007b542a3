"""Reference noise benchmark (issue 13): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_reference_noise.py [--seeds 10] [--points 2048] [--work DIR]

Bakes two-rooms once with the default config (evaluate on; kept in --work), keeps every mode's values at the
reference's surface points, then re-runs the reference stage's path tracing at those same points with `--seeds`
other seeds (pilot, first pass with the pilot's Russian-roulette control variate, refinement chosen on the pilot —
as workers/stages/reference.py does) and scores the accurate modes against each. Prints, per metric, the spread of
the values across the references (the true standard error) next to the mean standard error the metrics report,
and the summed variance of the points' luminance estimates across references against the mean reported s².
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from persist.store import Store  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels import metrics as MT  # noqa: E402
from workers.kernels import point_metrics as PM  # noqa: E402
from workers.kernels.pathtrace import scene_eps  # noqa: E402
from workers.kernels.reference import irradiance_at_points, pilot_spp, refine_points, tail_guess  # noqa: E402
from workers.procedural import write_scene  # noqa: E402
from workers.raycast import caster_for_scene  # noqa: E402
from workers.stages.reference import BATCH_POINTS, RR_DEPTH  # noqa: E402

MODES = ("ddgi", "mask_normalized", "leaking")


def bake(work: Path) -> tuple[dict, dict, object, dict, BakeConfig]:
    """The default bake of two-rooms: (reference points' columns, {mode: values there}, scene, lights, config)."""
    glb = work / "two-rooms.glb"
    write_scene("two-rooms", glb)
    store, scene = Store(work / "store"), ingest_file(glb)
    sid = store.put_bytes(scene.to_bytes())
    c = BakeConfig.model_validate({"evaluate": {"enabled": True, "previews": 0}})
    saved = {}
    orig = PM.point_summary

    def spy(modes, recon, pts, seed):
        saved.update(recon=dict(recon), pts=dict(pts))
        return orig(modes, recon, pts, seed)

    PM.point_summary = spy
    try:
        for st, _ in plan(sid, c):
            rec, _ = pipeline.execute_stage(store, sid, c, st.name, lambda f: None)
            if st.name == "ingest":
                lights = pipeline._lazy(store, rec)["lights"]
    finally:
        PM.point_summary = orig
    return saved["pts"], saved["recon"], scene, lights, c


def reference(scene, pts, idx, lights, c: BakeConfig, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference stage's surface-point passes at ``pts[idx]`` with ``seed``: (e_indirect, stderr) (n, 3)."""
    ev = c.evaluate
    spp, dark, bounces = int(ev.spp), int(ev.dark_spp), int(ev.bounces or 64)
    caster, eps = caster_for_scene(scene), scene_eps(scene)
    P, N, G = (pts[k][idx] for k in ("position", "normal", "geo_normal"))
    d = pts["e_direct"][idx]

    def trace(i, n, s, tail=None):
        return irradiance_at_points(scene, P[i], N[i], G[i], lights["lights"], sky=lights["sky"], spp=n,
                                    bounces=bounces, seed=s, rr_depth=RR_DEPTH, caster=caster, eps=eps,
                                    batch_points=BATCH_POINTS, tail=tail)

    every = np.arange(len(idx))
    n_pilot = pilot_spp(spp)
    _, p_ind, p_err, _ = trace(every, n_pilot, seed + 0x30000)
    tail = tail_guess(p_ind)
    _, e_ind, err, _ = trace(every, spp, seed, tail)
    e_ind, err, _ = refine_points(lambda i, n: trace(i, n, seed + 0x20000 + n, tail[i])[1:3], d, e_ind, err, spp,
                                  dark, pilot=(p_ind, p_err, n_pilot))
    return e_ind, err


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--points", type=int, default=2048, help="the first this many reference points")
    ap.add_argument("--work", type=Path, default=Path("/tmp/kiln-bench-reference-noise"))
    ap.add_argument("--save", type=Path, default=None, help="write every reference and the modes' values here (npz)")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pts, recon, scene, lights, c = bake(args.work)
    print(f"bake {time.perf_counter() - t0:.1f} s", flush=True)
    idx = np.arange(min(args.points, len(pts["position"])))
    sub = {k: v[idx] for k, v in pts.items()}
    exposure = MT.exposure_for(PM.radiance(sub["e_direct"], sub["e_indirect"], sub["albedo"],
                                           sub["emission"]).reshape(-1, 1, 3))
    vals = {m: {k: [] for k in ("rmse", "indirect_relative_rmse", "mean_ratio")} for m in MODES}
    errs = {m: {k: [] for k in vals[m]} for m in MODES}
    lum, s2, refs = [], [], []
    for k in range(args.seeds):
        t = time.perf_counter()
        e, s = reference(scene, pts, idx, lights, c, 1000 + 7919 * k)
        lum.append(MT.luminance(e))
        refs.append((e, s))
        s2.append((s @ MT.REC709) ** 2)
        cache: dict = {}
        for m in MODES:
            r = PM.metrics_with_stderr(recon[m][idx], e, s, sub["e_direct"], sub["albedo"], sub["emission"],
                                       seed=k, exposure=exposure, cache=cache)
            for q in vals[m]:
                vals[m][q].append(r[q])
                errs[m][q].append(r[f"{q}_stderr"])
        print(f"seed {k}: {time.perf_counter() - t:.1f} s, ddgi indirect_relative_rmse "
              f"{vals['ddgi']['indirect_relative_rmse'][-1]:.4f} ± {errs['ddgi']['indirect_relative_rmse'][-1]:.4f}",
              flush=True)
    out = {"seeds": args.seeds, "points": int(len(idx)),
           "summed_variance": float(np.var(lum, axis=0, ddof=1).sum()), "summed_mean_s2": float(np.mean(s2, 0).sum())}
    for m in MODES:
        for q in vals[m]:
            v, e = np.asarray(vals[m][q], float), np.asarray(errs[m][q], float)
            out[f"{m}.{q}"] = {"mean": float(v.mean()), "spread": float(v.std(ddof=1)),
                               "mean_reported_stderr": float(e.mean()),
                               "relative_spread": float(v.std(ddof=1) / abs(v.mean())),
                               "relative_reported": float(e.mean() / abs(v.mean()))}
            rel = 100 * v.std(ddof=1) / abs(v.mean())
            print(f"{m}.{q}: mean {v.mean():.5f} spread {v.std(ddof=1):.5f} ({rel:.2f}%)"
                  f"  reported {e.mean():.5f} ({100 * e.mean() / abs(v.mean()):.2f}%)")
    print(f"points' luminance: summed variance across references {out['summed_variance']:.4g}, "
          f"summed mean reported s² {out['summed_mean_s2']:.4g}")
    print(json.dumps(out))
    if args.save:
        np.savez(args.save, e_indirect=np.array([r[0] for r in refs]), stderr=np.array([r[1] for r in refs]),
                 **{f"mode_{m}": recon[m][idx] for m in MODES}, **{f"pts_{k}": v for k, v in sub.items()})


if __name__ == "__main__":
    main()
