"""Wall time of the GI modes' GLSL passes on a uniform and on a rectilinear grid (llvmpipe here): run by hand.

    .venv/bin/python tests/bench/bench_grid_pass.py [--size 640x480] [--repeats 5]

Bakes the two-rooms test bake of tests/render (9 x 4 x 5 probes, 2 bounces, S = 4), then shades 640 x 480 random
points (positions in the grid box, random normals) through each mode's GLSL (workers/render/shading.py, the
viewer's shaders) and prints the median wall time of ``draw(); ctx.finish()`` per mode (llvmpipe's timer queries are
wrong), with the grid as baked and with its layers moved by up to ±0.3 spacing (tests/render/test_shading.py
``_rectilinear``: the same arrays read through uGridLayers, compiled with ``#define KILN_GRID_RECTILINEAR``).

Measured (2026-12-06, this machine; ms, uniform / rectilinear, one run): leaking 21.4 / 22.2, mask_normalized
42.9 / 51.2, ddgi 46.4 / 50.9. Earlier the same day, by a scratch script of the same passes: the uniform passes with the
layer lookup behind a run-time ``if (uGridRectilinear)`` instead of the #define 26.9 / 65.9 / 66.7 ms, without any
rectilinear code 23.0 / 49.7 / 50.7.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.render.conftest import bake_arrays, bake_grid, mask_meta  # noqa: E402
from tests.render.test_shading import CFG, _rectilinear  # noqa: E402
from tests.workers.test_probes import bake_until  # noqa: E402
from workers.procedural import make_scene  # noqa: E402
from workers.render.context import create_context  # noqa: E402
from workers.render.shading import GBufferInputs, ShadingRenderer, prepare_mode  # noqa: E402

MODES = ("leaking", "mask_normalized", "ddgi")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    W, H = (int(x) for x in args.size.split("x"))
    work = Path(tempfile.mkdtemp(prefix="kiln-gridpass-"))
    glb = make_scene("two-rooms")
    (work / "two-rooms.glb").write_bytes(glb if isinstance(glb, bytes) else glb[0])
    cfg = {**CFG, "trace": {"rays_per_probe": 64}, "masks": {"clusters": 4, "sweeps": 100}}
    _, s = bake_until(work, work / "two-rooms.glb", cfg, "compress")
    arrays, grid = bake_arrays(s), bake_grid(s)
    ctx = create_context()
    rng = np.random.default_rng(0)
    lo, hi = np.array(CFG["place"]["box"]["min"]), np.array(CFG["place"]["box"]["max"])
    p = (lo + rng.random((H * W, 3)) * (hi - lo)).reshape(H, W, 3).astype(np.float32)
    n = rng.normal(size=(H, W, 3))
    n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    gb = GBufferInputs(p, n, np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.ones((H, W), bool))
    print(f"{'mode':<17}{'uniform ms':>12}{'rectilinear ms':>16}")
    for mode in MODES:
        row = []
        for g in (grid, _rectilinear(grid)):
            r = ShadingRenderer(ctx)
            try:
                r.set_mode(prepare_mode(mode, arrays, g, mask_meta=mask_meta(s)))
                r.set_gbuffer(gb)
                r.render(mode, output=1, eye=(4.0, 1.5, 2.0))               # compile, upload
                ts = []
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    r.draw(mode, output=1, eye=(4.0, 1.5, 2.0))
                    ctx.finish()
                    ts.append(time.perf_counter() - t0)
                row.append(1000 * float(np.median(ts)))
            finally:
                r.release()
        print(f"{mode:<17}{row[0]:>12.1f}{row[1]:>16.1f}")


if __name__ == "__main__":
    main()
