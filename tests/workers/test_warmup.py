"""workers.warmup: the install-time bake that compiles the numba kernels (scripts/setup.sh runs it)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from proto.models import BakeConfig
from proto.stages import plan
from workers.warmup import WARMUP_CONFIG, warm_up

ROOT = Path(__file__).resolve().parents[2]


def test_warm_up_runs_every_stage_of_the_default_plan_with_evaluate_on():
    lines = []
    secs = warm_up(report=lines.append)
    cfg = BakeConfig.model_validate(WARMUP_CONFIG)
    assert cfg.evaluate.enabled and cfg.evaluate.points is not None
    expected = [st.name for st, _ in plan("0" * 64, cfg)]
    assert list(secs) == expected
    assert {"light", "masks", "compress", "reference", "evaluate"} <= set(secs)
    assert len(lines) == len(expected) and all(v >= 0 for v in secs.values())


def test_warm_up_cli_exits_0_and_says_so():
    r = subprocess.run([sys.executable, "-m", "workers.warmup", "--quiet"], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "kiln warm-up: kernels compiled in" in r.stderr
