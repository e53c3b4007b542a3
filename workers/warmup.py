"""Compile the bake's numba kernels once, at install time, so that a user's first bake does not pay for it.

    .venv/bin/python -m workers.warmup [--quiet]

Kiln's kernels are numba functions with ``cache=True``: the first call of each compiles it and writes machine code
next to its source (``__pycache__/*.nbi, *.nbc``); every later process loads that in milliseconds. Left to the first
bake, compiling doubled it on this machine (two-rooms with the default config: 65 s in a fresh install, 33 s once
compiled; the evaluate stage alone 7.8 s → 0.5 s; `tests/bench/bench_evaluate.py --cost` read the evaluate share of a
first bake 26.8% instead of 20%). ``scripts/setup.sh`` (both of the README's commands) runs this module once per
change of the code: it bakes the procedural Cornell box (a point light and an emitter panel: next-event estimation,
every GI mode) through every stage of the default plan, evaluate on, at a small probe budget and few reference paths —
the kernels compile for the same argument types whatever the sizes. What is baked is thrown away.

It warms Mesa's shader cache too (``~/.cache/mesa_shader_cache``, or ``MESA_SHADER_CACHE_DIR``). On llvmpipe (this
machine's OpenGL) a shader is not compiled by ``ctx.program`` but at its first draw, once per *variant*: the state it
draws with, which includes the bound textures' shapes (llvmpipe's sampler state records, e.g., whether a side is a
power of two) and which scene features it shades (an emitter, a sun, a sky). The evaluate stage's
previews draw every GI mode, so a first bake on a fresh machine paid its variants: two-rooms' evaluate draws took
3.1 s (evaluate 4.1 s instead of 0.9 s; bench_evaluate --cost read the first bake's evaluate share 25.0%) after the
old warm-up (the Cornell box at a 4 x 4 x 4 grid and 64 x 48 previews); 0.9 s after the Cornell box alone at
5 x 3 x 6 probes and 96 x 72; **0.010 s** after this one (29 s with the numba kernels) (measured with a fresh ``MESA_SHADER_CACHE_DIR`` each time,
2026-12-06; which state made the 0.9 s was not isolated). So the warm-up bakes at a grid and preview size like a
default bake's (thousands of probes, 19 x 11 x 23; no side a power of two) and :data:`WARMUP_SCENES`: a point light and an emitter (the Cornell
box), a point light alone (two-rooms), a sun, a point light and a sky (sealed-box). A scene unlike all of them pays
its remaining variants once, on its first bake; a GPU driver compiles at ``ctx.program`` and never paid this.

Nothing here is needed for correctness: without it the kernels compile on first use, as before.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["WARMUP_CONFIG", "WARMUP_SCENES", "warm_up"]

WARMUP_CONFIG = {
    "place": {"counts": [19, 11, 23]},                 # 4,807 probes, as a default bake's: no side a power of two
    "evaluate": {"enabled": True, "surface_points": 64, "spp": 16, "dark_spp": 64, "check_spp": 16,
                 "width": 96, "height": 72, "previews": 1,
                 "points": {"points": [[0.5, 0.5, 0.5]]}},
}
"""The default config but small: every stage of the default plan runs (a check point too), in seconds once
compiled. Grid counts and preview sides as a default bake's: thousands of probes, no power of two (module doc)."""

WARMUP_SCENES = (("cornell", {}), ("two-rooms", {}), ("sealed-box", {"scene": {"sky": [0.3, 0.35, 0.4]}}))
"""Procedural scenes (:mod:`workers.procedural`) and config additions the warm-up bakes: the kinds of lighting and
materials whose preview shaders llvmpipe compiles as separate variants (module doc)."""


def warm_up(report=print, scenes=None) -> dict[str, float]:
    """Bake each of :data:`WARMUP_SCENES` (those named in ``scenes``, when given) with :data:`WARMUP_CONFIG` through
    every stage of the plan in a temporary store; returns ``{"<scene>/<stage>": seconds}`` (first-call compile time
    included)."""
    from persist.store import Store
    from proto.models import BakeConfig
    from proto.stages import plan
    from workers import pipeline
    from workers.gltf import ingest_file
    from workers.procedural import write_scene

    secs: dict[str, float] = {}
    for name, extra in WARMUP_SCENES:
        if scenes is not None and name not in scenes:
            continue
        with tempfile.TemporaryDirectory(prefix="kiln-warmup-") as tmp:
            tmp = Path(tmp)
            write_scene(name, tmp / f"{name}.glb")
            store = Store(tmp / "store")
            sid = store.put_bytes(ingest_file(tmp / f"{name}.glb").to_bytes())
            cfg = BakeConfig.model_validate({**WARMUP_CONFIG, **extra})
            for st, _ in plan(sid, cfg):
                t0 = time.perf_counter()
                pipeline.execute_stage(store, sid, cfg, st.name, lambda f: None)
                secs[f"{name}/{st.name}"] = time.perf_counter() - t0
                report(f"  {name}: {st.name}: {secs[f'{name}/{st.name}']:.1f} s")
    return secs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m workers.warmup", description=__doc__.splitlines()[0])
    ap.add_argument("--quiet", action="store_true", help="print only the total")
    ap.add_argument("--scenes", default=None, help="comma list: only these of WARMUP_SCENES (default: all)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    warm_up(report=(lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True)),
            scenes=args.scenes.split(",") if args.scenes else None)
    print(f"kiln warm-up: kernels and shaders compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
