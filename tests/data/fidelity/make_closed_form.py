"""Closed-form references for the fidelity benchmark (tests/bench/bench_fidelity.py), no Blender needed:

    .venv/bin/python tests/data/fidelity/make_closed_form.py

``furnace`` (workers.procedural: open space, one 1 mm triangle 1 km below, no lights) under a uniform sky of
radiance L = 1 (``scene.sky = [1, 1, 1]``, the only config the bench adds to the default): every receiver, whatever
its normal, gets E = ∫ L cos θ dω over its hemisphere = π·L (W/m², the sky's radiance in glTF's units), less what the
triangle hides, at most (its area 5e-7 m² / d²) / π of it: ≤ 4e-4 at the 2 cm the points keep from it. A white
furnace: every GI mode must return the sky exactly, at the default grid's probes (the automatic grid puts them around
the scene's only geometry, the triangle: 2 x 1 x 2 at 5 cm), between them and far outside the grid (lookups clamped
to its edge). Writes ``furnace.points.json`` and ``furnace.closed-form.reference.json`` here, in the format of
make_references.py's points and Cycles files (``E_probe_rgb`` per receiver = point x axis normal).
"""
from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))

from workers.procedural import make_scene  # noqa: E402

SKY = [1.0, 1.0, 1.0]
DIRS = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
Y = -1000.0   # the triangle's plane (x, z in [0, 1 mm])
REGIONS = {
    # between the default grid's four probes, 2 cm above and below the triangle's plane and beside it
    "in-grid": [(-0.02, Y + 0.02, -0.02), (0.02, Y - 0.02, 0.02), (0.02, Y + 0.02, -0.02), (-0.02, Y, 0.02)],
    # 1 m and 10 m away: the lookups clamp to the grid's edge
    "outside-1m": [(0.0, Y + 1.0, 0.0), (1.0, Y, 0.0), (0.0, Y - 1.0, 0.7)],
    "outside-10m": [(10.0, Y + 3.0, -5.0), (-7.0, Y - 6.0, 6.0)],
}


def main() -> int:
    data = make_scene("furnace")
    sha = hashlib.sha256(data).hexdigest()
    pts, regions = [], {}
    for name, plist in REGIONS.items():
        regions[name] = []
        for p in plist:
            d = math.dist(p, (0.0005, Y, 0.0005))
            assert d >= 0.02, (name, p, d)
            regions[name].append(len(pts))
            pts.append([float(x) for x in p])
    config = {"scene": {"sky": SKY}}
    (HERE / "furnace.points.json").write_text(json.dumps(
        {"scene": "furnace", "points": pts, "regions": regions, "glb_sha256": sha, "config": config}, indent=1) + "\n")
    e = np.tile(np.pi * np.asarray(SKY), (len(pts), len(DIRS), 1))            # [point][normal] RGB
    ref = {"scene": "furnace", "material": "closed-form", "oracle": "closed form: E = pi * L_sky for every normal",
           "settings": {"samples": "exact", "bounces": "all", "sky": SKY, "closed_form": True},
           "seeds": [], "glb_sha256": sha, "config": config, "points": pts, "dirs": DIRS, "regions": regions,
           "units": "E in W/m^2 (sky radiance in W/(m^2 sr)); RGB per receiver; dirs = the 6 axis normals per point",
           "E_probe_rgb": e.tolist(), "E_indirect_rgb": e.tolist(),
           "E_probe_note": "the sky seen by a receiver: a probe holds it, the GI modes return it"}
    (HERE / "furnace.closed-form.reference.json").write_text(json.dumps(ref) + "\n")
    print(f"wrote furnace.points.json and furnace.closed-form.reference.json ({len(pts)} points x 6 normals)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
