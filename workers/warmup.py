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

Nothing here is needed for correctness: without it the kernels compile on first use, as before.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["WARMUP_CONFIG", "warm_up"]

WARMUP_CONFIG = {
    "place": {"budget": 64},
    "evaluate": {"enabled": True, "surface_points": 64, "spp": 16, "dark_spp": 64, "check_spp": 16,
                 "width": 64, "height": 48, "previews": 1,
                 "points": {"points": [[0.5, 0.5, 0.5]]}},
}
"""The default config but small: every stage of the default plan runs (a check point too), in seconds once
compiled."""


def warm_up(report=print) -> dict[str, float]:
    """Bake the procedural Cornell box with :data:`WARMUP_CONFIG` through every stage of the plan in a temporary
    store; returns ``{stage: seconds}`` (first-call compile time included)."""
    from persist.store import Store
    from proto.models import BakeConfig
    from proto.stages import plan
    from workers import pipeline
    from workers.gltf import ingest_file
    from workers.procedural import write_scene

    secs: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="kiln-warmup-") as tmp:
        tmp = Path(tmp)
        write_scene("cornell", tmp / "cornell.glb")
        store = Store(tmp / "store")
        sid = store.put_bytes(ingest_file(tmp / "cornell.glb").to_bytes())
        cfg = BakeConfig.model_validate(WARMUP_CONFIG)
        for st, _ in plan(sid, cfg):
            t0 = time.perf_counter()
            pipeline.execute_stage(store, sid, cfg, st.name, lambda f: None)
            secs[st.name] = time.perf_counter() - t0
            report(f"  {st.name}: {secs[st.name]:.1f} s")
    return secs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m workers.warmup", description=__doc__.splitlines()[0])
    ap.add_argument("--quiet", action="store_true", help="print only the total")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    warm_up(report=(lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True)))
    print(f"kiln warm-up: kernels compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
