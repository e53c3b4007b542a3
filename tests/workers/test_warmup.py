"""workers.warmup: the install-time bake that compiles the numba kernels (scripts/setup.sh runs it)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from proto.models import BakeConfig
from proto.stages import plan
from workers.procedural import ALL_SCENES
from workers.warmup import WARMUP_CONFIG, WARMUP_SCENES, warm_up

ROOT = Path(__file__).resolve().parents[2]


def test_warm_up_runs_every_stage_of_the_default_plan_with_evaluate_on():
    lines = []
    secs = warm_up(report=lines.append)
    expected = []
    for name, extra in WARMUP_SCENES:
        assert name in ALL_SCENES
        cfg = BakeConfig.model_validate({**WARMUP_CONFIG, **extra})
        assert cfg.evaluate.enabled and cfg.evaluate.points is not None
        expected += [f"{name}/{st.name}" for st, _ in plan("0" * 64, cfg)]
    assert list(secs) == expected
    assert {"light", "masks", "compress", "reference", "evaluate"} <= {k.split("/")[1] for k in secs}
    assert len(lines) == len(expected) and all(v >= 0 for v in secs.values())


def test_warm_up_draws_at_sizes_that_are_not_powers_of_two():
    """llvmpipe compiles a shader variant per power-of-two-ness of its textures: a default bake's grid and previews
    are not powers of two, so the warm-up's are not either (workers/warmup.py)."""
    cfg = BakeConfig.model_validate(WARMUP_CONFIG)
    sides = [*cfg.place.counts, cfg.evaluate.width, cfg.evaluate.height]
    assert all(n & (n - 1) for n in sides), sides
    assert cfg.place.counts[0] * cfg.place.counts[1] * cfg.place.counts[2] > 4000     # thousands of probes
    d = BakeConfig().evaluate
    assert d.width & (d.width - 1) and d.height & (d.height - 1)


def test_warm_up_cli_exits_0_and_says_so():
    r = subprocess.run([sys.executable, "-m", "workers.warmup", "--quiet", "--scenes", "cornell"], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "kiln warm-up: kernels and shaders compiled in" in r.stderr
