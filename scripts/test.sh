#!/usr/bin/env bash
# Install (idempotent) and run the whole test suite. Extra arguments go to pytest.
# pytest's exit code is passed on: 5 ("no tests collected") is a failure too.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# JavaScript unit tests (Vitest: the viewer's KTX2 loader and SH/octahedral math against proto/fixtures)
# first, so that pytest's summary is the last line.
if [ -f web/package.json ]; then (cd web && npm test --silent); fi
# Two pytest processes (pytest-xdist), a test file to each at a time: browser and server tests spend much of their
# time waiting on a served bake or a headless page, so two of them share two cores well (measured: 15:34 -> 7:22 on
# the 2-core CI machine). KILN_TEST_PROCESSES=0 runs in one process (pytest's own output order).
procs=${KILN_TEST_PROCESSES:-2}
if [ "$procs" -gt 0 ] 2>/dev/null; then
  exec .venv/bin/python -m pytest -q -p no:cacheprovider -n "$procs" --dist loadfile "$@"
fi
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
