"""Data-driven PRT benchmark (issue "Data-driven PRT"): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_prt.py [--scenario front|room] [--configs 128] [--points 256]
        [--basis 16] [--grid 8x8x8] [--rays 256] [--lightmap 256] [--heldout 16] [--png /tmp/kiln_prt_rmse.png]

On ../shared/scenes/cornell-box-vinc3r (4410 triangles, TEXCOORD_1 on the box, the block, Suzanne and one
logo piece; xatlas UVs for the rest) this

1. bakes ingest .. light with the real pipeline (8x8x8 probes, 256 rays), then the ``prt`` stage in this
   process (N configurations, M measurement points, n basis, a lightmap² lightmap target), timing it and
   writing its artifacts in the bundle format (the part of a stage the pipeline adds); PRT Table 1 reports
   6.48 min (CPU) for its Cornell box with N = 128; our target is 30 s;
2. times ``workers.prt_relight.relight`` (median and 95th percentile of 200 calls after a warm-up): on the
   bake itself, and on a model of a 16x32x16 SH volume (the bake's measurement points and transfer, random
   basis volumes of that size: latency does not depend on their values); target 5 ms;
3. draws held-out lighting configurations from the same scenario (another seed; uniform in the box: the
   dataset's ``near_surface`` share is not applied to them, they are the ordinary case), computes the light
   stage's result for each (``light.integrate`` on the cached hits, emission excluded, sky 0), and reports
   the RMSE of the relit probe SH and lightmap against it for n = 1 .. 64 basis, next to the RMSE of
   projecting the reference onto the same basis (PRT Fig 14), as a table, a PNG plot and JSON.

Scenarios: ``front`` (default) puts point and spot lights in front of the open side of the box
(x in [-2, 2], y in [0.2, 2.8], z in [2.5, 5] m), spots aimed into the scene — "lights around the asset"
as in the paper; ``room`` uses the scene bounds (lights inside the room; lights close to a wall make the
direct field at a few hundred points a poor predictor, PRT §7).
Numba kernels are compiled (or loaded from cache) by a small warm-up bake first, outside the timings.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto import bundle  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from proto.stages import plan  # noqa: E402
from persist.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers import prt_relight  # noqa: E402
from workers.gltf import ingest_file  # noqa: E402
from workers.kernels import prt as kprt  # noqa: E402
from workers.kernels.prt_scenario import random_light_configurations  # noqa: E402
from workers.stages.base import StageContext  # noqa: E402
from workers.stages.prt import prt_dataset, prt_output  # noqa: E402
from tests.workers.prt_reference import light_stage_reference  # noqa: E402

SCENE_DIR = ROOT.parent / "shared" / "scenes" / "cornell-box-vinc3r"
GLTF = "cornellBox-2.80-Eevee-gltf.gltf"
SCENARIOS = {
    "front": {"types": ["point", "spot"], "count": 1, "box": {"min": [-2.0, 0.2, 2.5], "max": [2.0, 2.8, 5.0]},
              "intensity_min": 5.0, "intensity_max": 50.0},
    "room": {"types": ["point"], "count": 1, "intensity_min": 1.0, "intensity_max": 10.0},
}
BASIS_COUNTS = (1, 2, 4, 8, 16, 32, 64)


def zip_scene(dest: Path) -> Path:
    """The .gltf with its .bin and textures as one zip (what a user uploads)."""
    doc = json.loads((SCENE_DIR / GLTF).read_text())
    with zipfile.ZipFile(dest, "w") as z:
        z.write(SCENE_DIR / GLTF, GLTF)
        for key in ("buffers", "images"):
            for obj in doc.get(key, []):
                uri = obj.get("uri", "")
                if uri and not uri.startswith("data:") and (SCENE_DIR / uri).is_file():
                    z.write(SCENE_DIR / uri, uri)
    return dest


def bake_until_light(store: Store, scene, cfg: BakeConfig):
    """Run ingest .. light in this process; returns ({stage: LazyArtifacts}, {stage: seconds})."""
    sid = store.put_bytes(scene.to_bytes())
    out, secs = {}, {}
    for st, _ in plan(sid, cfg):
        if st.name.startswith("visibility"):
            continue
        t = time.perf_counter()
        rec, _ = pipeline.execute_stage(store, sid, cfg, st.name)
        secs[st.name] = time.perf_counter() - t
        out[st.name] = pipeline._lazy(store, rec)
        if st.name == "light":
            break
    return out, secs


def timeit(fn, reps: int = 200) -> dict:
    fn()
    fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    ts = np.array(ts) * 1e3
    return {"p50_ms": float(np.median(ts)), "p95_ms": float(np.percentile(ts, 95)), "min_ms": float(ts.min())}


def synthetic_model(model: prt_relight.PrtModel, counts=(16, 32, 16), seed: int = 0) -> prt_relight.PrtModel:
    """The bake's measurement points and SH transfer with random basis volumes for a bigger grid."""
    nx, ny, nz = counts
    K, n = model.coefficients, model.sh.slots.shape[1]
    rng = np.random.default_rng(seed)
    slots = rng.standard_normal((nx * ny * nz * K, n)).astype(np.float32)
    return prt_relight.PrtModel(section=model.section, points=model.points,
                                sh=prt_relight._Target(slots, model.sh.transfer), counts=(nx, ny, nz),
                                coefficients=K, lightmap=model.lightmap, lm_texels=model.lm_texels,
                                lm_res=model.lm_res)


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def plot_png(path: Path, rows: list[dict]) -> None:
    """RMSE (relative to the reference RMS, log scale) against basis count, drawn with PIL."""
    from PIL import Image, ImageDraw

    W, H, L, R, T, B = 720, 480, 80, 170, 30, 60
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    series = [("sh relit", "sh_relit_rel", (200, 40, 40), False), ("sh projection", "sh_proj_rel", (200, 40, 40), True),
              ("lightmap relit", "lm_relit_rel", (40, 90, 200), False),
              ("lightmap projection", "lm_proj_rel", (40, 90, 200), True)]
    vals = [r[k] for r in rows for _, k, _, _ in series if r.get(k)]
    lo = 10 ** math.floor(math.log10(max(min(vals), 1e-6)))
    hi = 10 ** math.ceil(math.log10(max(vals)))
    ns = [r["basis"] for r in rows]

    def xy(n, v):
        x = L + (W - L - R) * (math.log2(n) - math.log2(ns[0])) / max(math.log2(ns[-1]) - math.log2(ns[0]), 1e-9)
        y = T + (H - T - B) * (math.log10(hi) - math.log10(max(v, lo))) / (math.log10(hi) - math.log10(lo))
        return x, y

    d.rectangle([L, T, W - R, H - B], outline="black")
    e = lo
    while e <= hi * 1.0001:
        _, y = xy(ns[0], e)
        d.line([L - 4, y, L, y], fill="black")
        d.text((8, y - 6), f"{e:.0e}", fill="black")
        e *= 10
    for n in ns:
        x, _ = xy(n, lo)
        d.line([x, H - B, x, H - B + 4], fill="black")
        d.text((x - 6, H - B + 8), str(n), fill="black")
    d.text((W // 2 - 80, H - 25), "basis elements (mean included)", fill="black")
    d.text((L, 8), "relative RMSE vs the light stage (held-out lights)", fill="black")
    for i, (label, key, col, dashed) in enumerate(series):
        pts = [xy(r["basis"], r[key]) for r in rows if r.get(key)]
        for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
            if dashed:
                for s in range(0, 10, 2):
                    a, b = s / 10, (s + 1) / 10
                    d.line([x0 + (x1 - x0) * a, y0 + (y1 - y0) * a, x0 + (x1 - x0) * b, y0 + (y1 - y0) * b],
                           fill=col, width=2)
            else:
                d.line([x0, y0, x1, y1], fill=col, width=2)
        for x, y in pts:
            d.ellipse([x - 3, y - 3, x + 3, y + 3], outline=col)
        ly = T + 10 + 18 * i
        for s0 in range(10, 35, 6 if dashed else 25):
            d.line([W - R + s0, ly, W - R + min(s0 + (3 if dashed else 25), 35), ly], fill=col, width=2)
        d.text((W - R + 40, ly - 6), label, fill="black")
    img.save(path)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), default="front")
    ap.add_argument("--configs", type=int, default=128)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--basis", type=int, default=16)
    ap.add_argument("--grid", default="8x8x8")
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--lightmap", type=int, default=256)
    ap.add_argument("--heldout", type=int, default=16)
    ap.add_argument("--ridge", type=float, default=None, help="λ of eq 14 (default: prt.ridge's)")
    ap.add_argument("--norm", choices=("l1", "l2"), default=None, help="‖x‖ of §4.2 (default: prt.norm's)")
    ap.add_argument("--ridge-folds", type=int, default=None, help="cross-validated λ (default: prt.ridge_folds's)")
    ap.add_argument("--near", type=float, default=None,
                    help="share of the dataset's lights near a surface (default: prt.scenario.near_surface's)")
    ap.add_argument("--supersampling", type=int, default=1)
    ap.add_argument("--png", default=str(Path(tempfile.gettempdir()) / "kiln_prt_rmse.png"))
    args = ap.parse_args(argv)
    if not (SCENE_DIR / GLTF).exists():
        print(f"{SCENE_DIR} is absent: nothing to benchmark")
        return {}
    counts = [int(c) for c in args.grid.split("x")]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # warm-up (numba compile/cache load) on a tiny bake, untimed
        scene = ingest_file(zip_scene(tmp / "cornell.zip"))
        warm = BakeConfig.model_validate({"place": {"counts": [2, 2, 2]}, "trace": {"rays_per_probe": 16},
                                          "prt": {"enabled": True, "configurations": 4, "measurement_points": 8,
                                                  "lightmap": 16, "basis": 4}})
        w_in, _ = bake_until_light(Store(tmp / "warm"), scene, warm)
        prt_output(StageContext(warm, lambda: scene, w_in, lambda f: None),
                   prt_dataset(StageContext(warm, lambda: scene, w_in, lambda f: None)))

        cfg = BakeConfig.model_validate({
            "place": {"counts": counts}, "trace": {"rays_per_probe": args.rays},
            "prt": {"enabled": True, "configurations": args.configs, "measurement_points": args.points,
                    "basis": args.basis, "lightmap": args.lightmap, "supersampling": args.supersampling,
                    **({"ridge": args.ridge} if args.ridge is not None else {}),
                    **({"norm": args.norm} if args.norm else {}),
                    **({"ridge_folds": args.ridge_folds} if args.ridge_folds is not None else {}),
                    "scenario": {**SCENARIOS[args.scenario],
                                 **({"near_surface": args.near} if args.near is not None else {})}}})
        t_ingest = time.perf_counter()
        scene = ingest_file(zip_scene(tmp / "cornell2.zip"))
        t_ingest = time.perf_counter() - t_ingest
        inputs, secs = bake_until_light(Store(tmp / "store"), scene, cfg)
        ctx = StageContext(cfg, lambda: scene, inputs, lambda f: None)
        t0 = time.perf_counter()
        ds = prt_dataset(ctx)
        out = prt_output(ctx, ds, t0)
        t_stage = time.perf_counter() - t0
        t1 = time.perf_counter()
        infos = [a.write(tmp / "bundle", "prt") for a in out.artifacts]
        t_write = time.perf_counter() - t1
        bake = {"ingest_upload_s": t_ingest, **{f"{k}_s": v for k, v in secs.items()},
                "prt_stage_s": t_stage, "prt_write_s": t_write,
                "prt_total_s": t_stage + t_write,
                "chain_total_s": t_ingest + sum(secs.values()) + t_stage + t_write,
                "prt_artifact_bytes": sum(i.bytes for i in infos),
                **{f"prt_{k}": v for k, v in out.stats.items() if k.endswith("seconds")},
                "front_hits": out.stats["front_hits"], "bounces_mean": out.stats["bounces_mean"],
                "lightmap_texels": out.stats["lightmap_texels"], "warnings": out.stats["warnings"]}

        # relight latency
        arrays = {a.name: a.data for a in out.artifacts}
        model = prt_relight.PrtModel.from_arrays(arrays)
        caster = ds.probes["caster"]
        lights = ds.configs[0]
        latency = {
            "bake_sh_only": timeit(lambda: prt_relight.relight(model, lights, caster, lightmap=False)),
            "bake_sh_and_lightmap": timeit(lambda: prt_relight.relight(model, lights, caster)),
            "direct_vector_only": timeit(lambda: prt_relight.direct_vector(model, lights, caster)),
        }
        big = synthetic_model(model)
        latency["sh_16x32x16"] = timeit(lambda: prt_relight.relight(big, lights, caster, lightmap=False))
        latency["sh_16x32x16_and_lightmap"] = timeit(lambda: prt_relight.relight(big, lights, caster))

        # quality against the light stage, held-out lights
        rng = np.random.default_rng([cfg.seed, 0xBEEF])
        sc = cfg.prt.scenario
        bounds = scene.bounds
        box = (sc.box.min, sc.box.max) if sc.box else (bounds[0], bounds[1])
        held = random_light_configurations(rng, sc.model_dump(), args.heldout, box[0], box[1],
                                                inside=caster.inside_parity, target_box=(bounds[0], bounds[1]))
        t_ref = time.perf_counter()
        refs = [light_stage_reference(ds, L, cfg.light) for L in held]
        t_ref = time.perf_counter() - t_ref
        xs = [prt_relight.direct_vector(model, L, caster) for L in held]
        N, P, K = ds.sh.shape[:3]
        nmax = max(BASIS_COUNTS)
        fa = (cfg.prt.ridge, cfg.prt.gamma, cfg.prt.channels, cfg.prt.norm, cfg.prt.ridge_folds)
        fit_sh = kprt.fit(ds.direct, ds.sh.reshape(N, P * K, 3), nmax, *fa)
        fit_lm = (kprt.fit(ds.direct, ds.texels, nmax, *fa)
                  if ds.texels is not None and ds.texels.shape[1] else None)
        sh_true = [r[0].reshape(-1, 3) for r in refs]
        sh_rms = float(np.sqrt(np.mean(np.square(sh_true))))
        lm_true = [r[1] for r in refs] if fit_lm else None
        lm_rms = float(np.sqrt(np.mean(np.square(lm_true)))) if fit_lm else None
        rows = []
        for n in BASIS_COUNTS:
            f = fit_sh.truncated(n)
            row = {"basis": n,
                   "sh_relit": rmse([kprt.reconstruct(f, x) for x in xs], sh_true),
                   "sh_proj": rmse([kprt.project(f, x, y) for x, y in zip(xs, sh_true)], sh_true)}
            if fit_lm:
                g = fit_lm.truncated(n)
                row["lm_relit"] = rmse([kprt.reconstruct(g, x) for x in xs], lm_true)
                row["lm_proj"] = rmse([kprt.project(g, x, y) for x, y in zip(xs, lm_true)], lm_true)
            for k in ("sh_relit", "sh_proj"):
                row[k + "_rel"] = row[k] / sh_rms
            for k in ("lm_relit", "lm_proj"):
                if k in row:
                    row[k + "_rel"] = row[k] / lm_rms
            rows.append(row)
        # the shipped model (basis = args.basis) through relight(), float32 path, for the record
        shipped = rmse([prt_relight.relight(model, L, caster)["probe_sh"].reshape(-1, 3) for L in held], sh_true)

    print(f"\nPRT on cornell-box-vinc3r, scenario {args.scenario}: N = {args.configs}, M = {args.points}, "
          f"n = {args.basis}, grid {args.grid} x {args.rays} rays, lightmap {args.lightmap}^2, ridge {cfg.prt.ridge:g},"
          f" norm {cfg.prt.norm}, ridge folds {cfg.prt.ridge_folds}, near share {cfg.prt.scenario.near_surface:g}"
          f" (λ used {arrays['prt']['sh']['ridge_used']})")
    print("\nbake (seconds)")
    for k in ("ingest_upload_s", "place_s", "relocate_s", "trace_s", "light_s", "prt_stage_s", "prt_write_s",
              "prt_total_s", "chain_total_s"):
        if k in bake:
            print(f"  {k:28s} {bake[k]:8.2f}")
    for k, v in bake.items():
        if k.startswith("prt_") and k.endswith("seconds"):
            print(f"    {k:26s} {v:8.2f}")
    print(f"  front hits {bake['front_hits']}, mean bounces {bake['bounces_mean']:.1f}, "
          f"lightmap texels {bake['lightmap_texels']}, PRT artifacts {bake['prt_artifact_bytes'] / 1e6:.1f} MB")
    print("\nrelight latency (ms)          p50      p95")
    for k, v in latency.items():
        print(f"  {k:26s} {v['p50_ms']:8.3f} {v['p95_ms']:8.3f}")
    print(f"\nRMSE vs the light stage, {args.heldout} held-out configurations (reference in {t_ref:.1f} s); "
          f"reference RMS: SH {sh_rms:.4g}" + (f", lightmap {lm_rms:.4g}" if lm_rms else ""))
    print("  basis  SH relit   SH proj  ratio  " + ("  LM relit   LM proj  ratio" if fit_lm else ""))
    for r in rows:
        ratio = r["sh_relit"] / max(r["sh_proj"], 1e-30)
        line = f"  {r['basis']:5d} {r['sh_relit']:9.4g} {r['sh_proj']:9.4g} {ratio:6.2f}"
        if "lm_relit" in r:
            line += f" {r['lm_relit']:9.4g} {r['lm_proj']:9.4g} {r['lm_relit'] / max(r['lm_proj'], 1e-30):6.2f}"
        print(line)
    print(f"  shipped model (n = {args.basis}) through relight(): SH RMSE {shipped:.4g}")
    plot_png(Path(args.png), rows)
    print(f"\nplot: {args.png}")
    result = {"scene": "cornell-box-vinc3r", "args": vars(args), "bake": bake, "relight_latency": latency,
              "rmse": rows, "sh_rms": sh_rms, "lm_rms": lm_rms, "shipped_sh_rmse": shipped,
              "reference_seconds": t_ref}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
