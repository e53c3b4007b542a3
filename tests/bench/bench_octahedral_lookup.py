"""How much an octahedral irradiance map's bilinear lookup blurs irradiance across directions, by map size and by
how the normals stand to the map's axes.

    .venv/bin/python tests/bench/bench_octahedral_lookup.py [--trials 300] [--sizes 8,12,16] [--json F]

Run by hand (not part of the test command). Why: thick-wall turned 30° with the grid in the world axes
(``bench_rotated_gather.py --bounces 1``) reads its near-wall probes' first bounce 5.5% above Kiln's path tracer
(8 texels; 3.9% at 14, 3.1% at 24), before any gather: the maps' lookup, not the rays. This isolates the lookup: the
radiance is a small bright cone (25° half angle, 1.0) over a dim surround (0.02), the texels hold the exact cosine
convolution at their centres (dense Fibonacci quadrature: no ray noise), and :func:`bilinear_sample` reads the 6
axis normals turned by a yaw about +Y against the exact irradiance there. Printed per map size and yaw: all normals,
the dimmer half of them (facing away from or across the light: where the lookup reads high), the brighter half.

What it does not show: texels least-squares fitted for this lookup read this case within 0.6% on the axes and 2% at
an angle, yet leave ``bench_rotated_gather.py``'s first-bounce excess unchanged (docs/architecture.md, "Tried next
and not kept"): the turned interiors' excess is not this blur.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from workers.kernels.octahedral import add_border, bilinear_sample, oct_texel_directions  # noqa: E402
from workers.kernels.sampling import fibonacci_sphere  # noqa: E402

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def yaw(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def measure(sizes, yaws, trials: int, seed: int = 0, quadrature: int = 100_000) -> list[dict]:
    dense = fibonacci_sphere(quadrature).astype(np.float64)
    rng = np.random.default_rng(seed)
    lights = rng.normal(size=(trials, 3))
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    cos_cone = math.cos(math.radians(25.0))
    out = []
    for n in sizes:
        texels = oct_texel_directions(n).reshape(-1, 3).astype(np.float64)
        for deg in yaws:
            normals = AXES @ yaw(deg).T
            est, exact = np.zeros((trials, 6)), np.zeros((trials, 6))
            for i, d0 in enumerate(lights):
                radiance = np.where(dense @ d0 > cos_cone, 1.0, 0.02)

                def irradiance(nrm):
                    return 4 * math.pi / len(dense) * (np.maximum(0.0, nrm @ dense.T) * radiance).sum(axis=1)

                m = add_border(irradiance(texels).reshape(1, n, n, 1))[0]
                est[i], exact[i] = bilinear_sample(m, normals)[:, 0], irradiance(normals)
            dim = exact < np.median(exact)
            out.append({"texels": n, "yaw": deg, "all": float(est.sum() / exact.sum()),
                        "dim_half": float(est[dim].sum() / exact[dim].sum()),
                        "bright_half": float(est[~dim].sum() / exact[~dim].sum())})
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=300, help="light directions (random, seeded)")
    ap.add_argument("--sizes", default="8,12,16", help="interior texels per side, comma-separated")
    ap.add_argument("--yaws", default="0,15,30,45", help="degrees about +Y, comma-separated")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows = measure([int(s) for s in args.sizes.split(",")], [float(y) for y in args.yaws.split(",")], args.trials)
    print(f"{'texels':>6} {'yaw':>5} {'all':>7} {'dim half':>9} {'bright half':>12}   (lookup / exact irradiance)")
    for r in rows:
        print(f"{r['texels']:>6} {r['yaw']:>5g} {r['all']:>7.3f} {r['dim_half']:>9.3f} {r['bright_half']:>12.3f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
