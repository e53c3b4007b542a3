#!/usr/bin/env bash
# Install (idempotent) and run the whole test suite. Extra arguments go to pytest.
# pytest's exit code is passed on: 5 ("no tests collected") is a failure too.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# JavaScript unit tests (Vitest: the viewer's KTX2 loader and SH/octahedral math against proto/fixtures)
# first, so that pytest's summary is the last line.
if [ -f web/package.json ]; then (cd web && npm test --silent); fi
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
