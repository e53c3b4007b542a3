"""When the light stage stops its bounces: the tail waited for (light stage ≤ 11) against the tail added (stage 12).

    .venv/bin/python tests/bench/bench_convergence.py [--scenes two-storey,two-rooms,rooms-unequal,cornell,sealed-box,zdm2,living-room]
        [--tolerance 0.005] [--json OUT.json]

Per scene (a scene of bench_fidelity.py: a procedural one, or a real one of ``../shared/scenes`` with its points
file's lights and sky, e.g. zdm2 with the sun and sky of bench_evaluate.py, living-room with two point lights and a
sky; skipped with a message when that folder is absent), the pipeline runs to the light stage with the default config
plus those additions, and the light stage iterates
to a residual of 1e-5 (:data:`TRUTH_TOLERANCE`), handing every bounce's maps to this script (its gather is wrapped).
Both stopping rules are then played on the same sequence of maps — the bounce loop's maps up to a stop do not depend
on the rule — with the functions the stage calls (:mod:`workers.kernels.convergence`):

- *waited*: stop at the first bounce whose ``relative_tail`` residual (the light still to come) is below the
  tolerance; the maps as they are;
- *added*: stop at the first bounce whose ``extrapolated_tail`` residual is below it; the maps plus ``factor`` ×
  their last increment (as :func:`workers.kernels.bounce.integrate` adds it).

It prints per scene the bounces of each rule and the error of its maps against the last ones: the largest over the
probes that matter (brighter than 1e-6 of the brightest) of ``Σ|E − E_∞| / Σ|E_∞|``, and the 99th percentile.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "bench"))

import bench_fidelity as BF  # noqa: E402
import workers.stages.light as light_stage  # noqa: E402
from proto.models import BakeConfig  # noqa: E402
from workers.kernels.convergence import RELEVANT_FLOOR, extrapolated_tail, relative_tail  # noqa: E402

TRUTH_TOLERANCE = 1e-5


def bounce_maps(name: str, work: Path) -> np.ndarray:
    """(bounces, P, t, t, 3) float32: the light stage's maps after each bounce, iterated to TRUTH_TOLERANCE."""
    snaps: list[np.ndarray] = []
    original = light_stage.integrate_one

    def integrate_one(index, miss, albedo, e_direct, dirs, states, n, gather, **kw):
        class Capture:                 # the stage's gather, keeping the maps it is handed (bounce b - 1's)
            reads_sh = getattr(gather, "reads_sh", False)

            def __call__(self, maps, sh=None):
                snaps.append(maps.copy())
                return gather(maps, sh) if self.reads_sh else gather(maps)
        kw.update(tolerance=TRUTH_TOLERANCE, max_bounces=int(os.environ.get("KILN_BENCH_MAX_BOUNCES", 400)))
        out = original(index, miss, albedo, e_direct, dirs, states, n, Capture(), **kw)
        snaps.append(out[0].copy())
        return out

    pfile = BF.DATA / f"{name}.points.json"
    pdoc = json.loads(pfile.read_text()) if pfile.exists() else {}
    src = BF.source_of(pdoc)              # a real scene, read where it lies
    if src is not None and not src.exists():
        raise FileNotFoundError(f"{src} (../shared/scenes absent)")
    light_stage.integrate_one = integrate_one
    try:                                  # the fidelity bench's additions: lights and sky (zdm2: bench_evaluate's)
        BF.bake(name, work, None, pdoc.get("config") or {}, src, until="light")
    finally:
        light_stage.integrate_one = original
    return np.stack(snaps)


def play(maps: np.ndarray, tol: float) -> dict:
    """Both stopping rules on one sequence of maps (module doc)."""
    truth = maps[-1].astype(np.float64)
    P = truth.shape[0]
    tot = np.abs(truth).reshape(P, -1).sum(1)
    matters = (tot >= RELEVANT_FLOOR * tot.max()) & (tot > 0)

    def error(m):
        e = np.abs(m - truth).reshape(P, -1).sum(1)[matters] / tot[matters]
        return float(e.max()), float(np.percentile(e, 99))

    out, deltas = {}, []
    for b in range(1, maps.shape[0]):
        new = maps[b - 1].astype(np.float64)
        prev = maps[b - 2].astype(np.float64) if b > 1 else np.zeros_like(new)
        value = np.abs(new).reshape(P, -1, 1, 3).sum(axis=(1, 3))
        deltas = (deltas + [np.abs(new - prev).reshape(P, -1, 1, 3).sum(axis=1)])[-4:]
        if "waited" not in out and relative_tail([d.sum(-1) for d in deltas], value)[0][0] < tol:
            out["waited"] = {"bounces": b, "error_max_p99": error(new)}
        res, factor = extrapolated_tail(deltas, value)
        if "added" not in out and res[0] < tol:
            out["added"] = {"bounces": b, "error_max_p99": error(new + (new - prev) * factor[:, 0][:, None, None, :]),
                            "error_without_tail": error(new)[0]}
        if len(out) == 2:
            break
    out["truth_bounces"] = maps.shape[0]
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="two-storey,two-rooms,rooms-unequal,cornell,sealed-box,zdm2,living-room")
    ap.add_argument("--tolerance", type=float, default=BakeConfig().light.tolerance)
    ap.add_argument("--json")
    args = ap.parse_args()
    results = {}
    print(f"{'scene':<15}{'waited: bounces':>16}{'max err':>9}{'p99':>9}{'added: bounces':>16}{'max err':>9}"
          f"{'p99':>9}{'(no tail)':>11}")
    for name in args.scenes.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            try:
                maps = bounce_maps(name, Path(tmp))
            except FileNotFoundError as e:
                print(f"{name:<15}skipped: {e}")
                continue
        r = results[name] = play(maps, args.tolerance)
        w, a = r.get("waited"), r.get("added")
        cells = [f"{w['bounces']:>16}{w['error_max_p99'][0]:>9.2%}{w['error_max_p99'][1]:>9.3%}" if w else f"{'-':>34}",
                 f"{a['bounces']:>16}{a['error_max_p99'][0]:>9.2%}{a['error_max_p99'][1]:>9.3%}"
                 f"{a['error_without_tail']:>11.2%}" if a else f"{'-':>45}"]
        print(f"{name:<15}" + "".join(cells), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"tolerance": args.tolerance, "scenes": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
