"""Evaluate benchmark (Evaluate issue): run by hand, not part of the test command.

    .venv/bin/python tests/bench/bench_evaluate.py [--width 512 --height 384] [--spp 64] [--repeats 7]
        [--zdm2-counts 16x8x16] [--zdm2-cameras 1] [--skip-zdm2] [--skip-two-rooms] [--save DIR]

Bakes (real pipeline up to `compress`, untimed) two-rooms (procedural; its 20 cd point light) and
../shared/scenes/zdm2-sauerbraten (a sun and a sky added: it has none), then runs the evaluate stage with a
hand-built context at 512x384: the whole deferred shading pass (direct light with the shadow mask + GI) per
mode, median wall time of `repeats` (render + ctx.finish(); on this machine Mesa llvmpipe, a CPU rasterizer,
so absolute times are not comparable to the paper's RTX 3070 — the ratios are the point), the GI texture
fetches per pixel, texture bytes, and on two-rooms the quality (RMSE MD §4.2 on tone-mapped LDR, FLIP, leak).
Prints a table next to MD Table 1 and the targets; the last line is the same numbers as JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from proto.models import BakeConfig, EvaluateSection  # noqa: E402
from proto.stages import plan  # noqa: E402
from proto.store import Store  # noqa: E402
from workers import pipeline  # noqa: E402
from workers.ingest import ingest_file  # noqa: E402
from workers.procedural import write_scene  # noqa: E402
from workers.stages.base import StageContext  # noqa: E402
from workers.stages.evaluate import run_evaluate  # noqa: E402

ZDM2 = ROOT.parent / "shared" / "scenes" / "zdm2-sauerbraten" / "zdm2.glb"
SUN = {"type": "directional", "direction": [-0.3, -1.0, -0.2], "intensity": 3.0}
MODES = ("direct", "leaking", "ddgi", "mask", "mask_normalized")
PAPER_MS = {"leaking": 0.09, "mask": 0.11, "visibility (ray-traced, MD)": "0.25-0.38"}


class _Cfg:
    def __init__(self, cfg, evaluate):
        self._c, self.evaluate = cfg, evaluate

    def __getattr__(self, k):
        return getattr(self._c, k)


def bake(scene_path: Path, cfg: dict, work: Path):
    store = Store(work / "store")
    scene = ingest_file(scene_path)
    sid = store.put_bytes(scene.to_bytes())
    c = BakeConfig.model_validate(cfg)
    out = {}
    t0 = time.perf_counter()
    for st, _ in plan(sid, c):
        rec, _ = pipeline.execute_stage(store, sid, c, st.name)
        out[st.name] = pipeline._lazy(store, rec)
        if st.name == "compress":
            break
    return scene, out, c, time.perf_counter() - t0


SAVE: Path | None = None


def evaluate(scene, s, c, ev: dict) -> dict:
    sec = EvaluateSection.model_validate({**ev, "enabled": True})    # the stage is opt-in
    ctx = StageContext(config=_Cfg(c, sec), scene_loader=lambda: scene, inputs=s, report=lambda f: None)
    t0 = time.perf_counter()
    out = run_evaluate(ctx)
    if SAVE is not None:                              # --save: the contact sheet and every preview as PNG
        SAVE.mkdir(parents=True, exist_ok=True)
        for a in out.artifacts:
            if a.format == "png":
                (SAVE / f"{a.name}.png").write_bytes(a.data)
    return {"metrics": out.stats["metrics"], "seconds": time.perf_counter() - t0, "renderer": out.stats["renderer"],
            "cameras": out.stats["cameras"]}


def table(name: str, m: dict) -> list[str]:
    rows = [f"== {name}", f"{'mode':<16}{'pass ms':>10}{'GI fetch/px':>13}{'tex MB':>9}{'RMSE':>9}{'FLIP':>8}"
                           f"{'leak':>8}"]
    for mode in MODES:
        if f"{mode}.pass_ms" not in m:
            continue
        g = lambda k: m.get(f"{mode}.{k}")  # noqa: E731
        fl = g("flip")
        rows.append(f"{mode:<16}{g('pass_ms'):>10.2f}{g('gi_fetches_per_pixel'):>13.1f}"
                    f"{g('texture_bytes') / 1e6:>9.3f}{g('rmse'):>9.4f}{(fl if fl is not None else float('nan')):>8.4f}"
                    f"{g('leak'):>8.3f}")
    ml, mm, md = m.get("leaking.pass_ms"), m.get("mask.pass_ms"), m.get("ddgi.pass_ms")
    if ml and mm and md:
        rows.append(f"ratios: mask/leaking {mm / ml:.2f} (target <= 1.3; MD Table 1: 0.11/0.09 = 1.22), "
                    f"DDGI/mask {md / mm:.2f} (target >= 3; MD: visibility/mask 0.25-0.38/0.11 = 2.3-3.5)")
        d = m.get("direct.pass_ms")
        if d and min(ml, mm, md) > d:   # the GI's own cost: the pass minus the direct-only pass (same run)
            gl, gm, gd = ml - d, mm - d, md - d
            rows.append(f"GI only (pass - direct pass): leaking {gl:.2f} ms, mask {gm:.2f} ms, DDGI {gd:.2f} ms; "
                        f"mask/leaking {gm / gl:.2f}, DDGI/mask {gd / gm:.2f}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=384)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--zdm2-spp", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--zdm2-counts", default="16x8x16")
    ap.add_argument("--skip-zdm2", action="store_true")
    ap.add_argument("--skip-two-rooms", action="store_true")
    ap.add_argument("--zdm2-cameras", type=int, default=1, help="auto-placed cameras in zdm2 (quality needs 3+)")
    ap.add_argument("--save", type=Path, default=None, help="write the PNG previews and contact sheets here")
    args = ap.parse_args()
    global SAVE
    SAVE = args.save
    res = {}
    ev = {"width": args.width, "height": args.height, "repeats": args.repeats, "modes": list(MODES), "cameras": 1}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not args.skip_two_rooms:
            write_scene("two-rooms", tmp / "two-rooms.glb")
            cfg = {"place": {"counts": [9, 4, 5], "box": {"min": [0.2, 0.2, 0.2], "max": [7.85, 2.8, 3.8]}},
                   "trace": {"rays_per_probe": 256}, "light": {"bounces": 3},
                   "visibility": {"samples_per_cell": 8, "slabs": 1}, "masks": {"clusters": 4, "sweeps": 1000}}
            scene, s, c, tb = bake(tmp / "two-rooms.glb", cfg, tmp / "a")
            cam = {"position": [7.5, 1.5, 2.0], "target": [4.05, 1.2, 1.2], "name": "roomb"}
            cam_a = {"position": [0.6, 1.6, 3.4], "target": [4.0, 1.0, 1.0], "name": "rooma"}
            res["two-rooms"] = evaluate(scene, s, c, {**ev, "spp": args.spp, "cameras": [cam_a, cam]})
            res["two-rooms"]["bake_seconds"] = tb
        if not args.skip_zdm2 and ZDM2.exists():
            counts = [int(x) for x in args.zdm2_counts.split("x")]
            cfg = {"place": {"counts": counts}, "scene": {"lights": [SUN], "sky": [0.3, 0.35, 0.4]},
                   "trace": {"rays_per_probe": 128}, "light": {"bounces": 2},
                   "visibility": {"samples_per_cell": 4}, "masks": {"clusters": 4, "sweeps": 300}}
            scene, s, c, tb = bake(ZDM2, cfg, tmp / "b")
            res["zdm2"] = evaluate(scene, s, c, {**ev, "spp": args.zdm2_spp, "flip": False,
                                                 "cameras": args.zdm2_cameras})
            res["zdm2"]["bake_seconds"] = tb
    if not res:
        raise SystemExit("nothing to run: both scenes skipped (or ../shared/scenes/zdm2-sauerbraten is missing)")
    lines = [f"renderer: {next(iter(res.values()))['renderer']}; {args.width}x{args.height}; pass = direct (lights x Embree "
             f"shadow mask) + GI, median of {args.repeats}", f"MD Table 1 (RTX 3070, ms): {PAPER_MS}"]
    for name, r in res.items():
        lines += table(name, r["metrics"])
    m = res.get("two-rooms", {}).get("metrics", {})
    rn, rd, rl = m.get("mask_normalized.rmse"), m.get("ddgi.rmse"), m.get("leaking.rmse")
    if rn is not None and rd and rl:
        lines.append(f"two-rooms quality: RMSE(mask_normalized) = {rn:.4f} = {rn / rd:.2f} x RMSE(DDGI) (target <= 1.1), "
                     f"{rn / rl:.2f} x RMSE(leaking) (target <= 0.5)")
    print("\n".join(lines))
    print(json.dumps(res, default=float))


if __name__ == "__main__":
    main()
