#!/usr/bin/env bash
# Idempotent setup: Debian packages (when root and missing), a venv in .venv, the project
# and its test dependencies. Re-running it does nothing that is already done.
# KILN_EXTRAS picks the pyproject extras: `test` (the default; it pulls api, worker and render) or, for
# scripts/serve.sh, `api,worker,render` (what `kiln serve` runs: the API, the workers, the evaluate renderer).
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS=${KILN_EXTRAS:-test}

# Debian packages Kiln needs at run time: a venv, OpenMP for embree, EGL + Mesa (llvmpipe) for the
# headless moderngl renderer of the evaluate stage.
DEB_PACKAGES="python3-venv python3-dev libgomp1 libegl1 libegl-mesa0 libgl1-mesa-dri"
# Optional: installed when root and missing; otherwise only mentioned (the browser tests in tests/web skip
# without Chromium, which Playwright drives as /usr/bin/chromium).
DEB_OPTIONAL="chromium"

log() { printf 'kiln setup: %s\n' "$*" >&2; }
# apt_get: apt-get that waits (bounded, with a message) while another process holds the apt/dpkg lock
. scripts/apt_lock.sh

missing=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in $DEB_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
fi
PY=${PYTHON:-python3}
if ! command -v "$PY" >/dev/null 2>&1; then missing+=(python3); fi
# Only packages a venv cannot do without are fatal; with a working `python3 -m venv` (pyenv,
# a custom build) the Debian python3-venv/-dev packages are not needed.
need_apt=()
for p in "${missing[@]:-}"; do
  case "$p" in
    python3|python3-venv) "$PY" -m venv --help >/dev/null 2>&1 || need_apt+=("$p") ;;
    python3-dev) "$PY" -c 'import sysconfig,os,sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"],"Python.h")))' 2>/dev/null || need_apt+=("$p") ;;
    "") ;;
    *) need_apt+=("$p") ;;
  esac
done
if [ ${#need_apt[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    log "installing Debian packages: ${need_apt[*]}"
    apt_get update -qq
    apt_get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
  else
    log "missing Debian packages: ${need_apt[*]}"
    log "run as root: apt-get install -y ${need_apt[*]}   (then re-run this command)"
    exit 1
  fi
fi

opt_missing=()
case ",$EXTRAS," in *,test,*) ;; *) DEB_OPTIONAL="" ;; esac   # Chromium is for the browser tests only
if command -v dpkg-query >/dev/null 2>&1; then
  for p in $DEB_OPTIONAL; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || opt_missing+=("$p")
  done
fi
if [ ${#opt_missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    log "installing optional Debian packages: ${opt_missing[*]}"
    { apt_get update -qq &&
      apt_get install -y -qq --no-install-recommends "${opt_missing[@]}" >/dev/null; } ||
      log "could not install ${opt_missing[*]}: the browser tests will be skipped"
  else
    log "optional Debian packages missing: ${opt_missing[*]} (the browser tests will be skipped; as root: apt-get install -y ${opt_missing[*]})"
  fi
fi

"$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' || {
  log "Python 3.11 or newer is needed ($("$PY" --version 2>&1) found); set PYTHON=/path/to/python3.11"; exit 1; }

if [ ! -x .venv/bin/python ]; then
  log "creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.kiln-installed
want=$(cat pyproject.toml | sha256sum | cut -d' ' -f1)
have=$(cat "$stamp" 2>/dev/null || true)
# installed for this pyproject with these extras, or with `test` (a superset of every other extra)
if { [ "$have" != "$want $EXTRAS" ] && [ "$have" != "$want test" ]; } ||
   ! .venv/bin/python -c 'import server.cli, persist' 2>/dev/null; then
  log "installing Kiln and its dependencies into .venv (extras: $EXTRAS)"
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q -e ".[$EXTRAS]"
  echo "$want $EXTRAS" > "$stamp"
fi

# The web viewer (web/): `npm ci` when the lock file changed, `npm run build` when any input of the build
# changed (web sources, the shaders in proto/glsl). Stamps live in web/node_modules (git-ignored).
if [ -f web/package.json ]; then
  if ! command -v npm >/dev/null 2>&1; then
    log "npm is needed to build the web viewer: apt-get install -y nodejs npm"; exit 1
  fi
  lock_hash=$(sha256sum web/package-lock.json | cut -d' ' -f1)
  if [ ! -f web/node_modules/.kiln-lock ] || [ "$(cat web/node_modules/.kiln-lock)" != "$lock_hash" ]; then
    log "installing the web viewer's npm packages"
    (cd web && npm ci --no-audit --no-fund --loglevel=error)
    echo "$lock_hash" > web/node_modules/.kiln-lock
  fi
  build_hash=$(find web/src web/index.html web/kiln-three web/vite.config.js web/package-lock.json proto/glsl proto/gi_modes.json -type f -print0 |
    LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)
  if [ ! -f web/dist/index.html ] || [ ! -f web/dist/kiln-three/example/index.html ] || [ ! -f web/node_modules/.kiln-build ] ||
     [ "$(cat web/node_modules/.kiln-build)" != "$build_hash" ]; then
    log "building the web viewer (web/dist)"
    (cd web && npm run --silent build >/dev/null)
    echo "$build_hash" > web/node_modules/.kiln-build
  fi
fi

# Compile the bake's numba kernels and the preview shaders (Mesa's shader cache) once per change of the code
# (workers/warmup.py: small bakes of three procedural scenes), so that the first bake after an install does not spend
# half its time compiling (two-rooms: 65 s -> 33 s). KILN_SKIP_WARMUP=1 skips it; a failure here only warns (the
# kernels then compile on first use).
if [ "${KILN_SKIP_WARMUP:-0}" != 1 ]; then
  warm_hash=$( { find workers proto -type f \( -name '*.py' -o -name '*.glsl' -o -name '*.json' \) -print0 |
                   LC_ALL=C sort -z | xargs -0 sha256sum;
                 cat "$stamp"; } | sha256sum | cut -d' ' -f1)
  if [ "$(cat .venv/.kiln-warm 2>/dev/null || true)" != "$warm_hash" ]; then
    log "compiling the bake kernels and shaders (numba, Mesa; once per change of the code; about 30 s)"
    if .venv/bin/python -m workers.warmup --quiet; then
      echo "$warm_hash" > .venv/.kiln-warm
    else
      log "warning: the warm-up bake failed; the kernels will compile on a bake's first use"
    fi
  fi
fi
