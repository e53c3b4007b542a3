#!/usr/bin/env bash
# Install (idempotent) and start Kiln on its embedded default: embedded Redis, 2 RQ workers,
# the API and page on http://127.0.0.1:8000 . Extra arguments go to `kiln serve`.
set -euo pipefail
cd "$(dirname "$0")/.."
KILN_EXTRAS=${KILN_EXTRAS:-api,worker,render} bash scripts/setup.sh   # what serving needs (not the test tools)
exec .venv/bin/kiln serve "$@"
