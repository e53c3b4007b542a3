"""Browser tests: a real `kiln serve` (embedded Redis, real RQ workers, uvicorn) on a free port, driven by
Debian's Chromium through Python Playwright (never `playwright install`: no browser downloads here).

The whole folder is skipped, with the reason, when /usr/bin/chromium or the playwright package is missing
(`apt-get install chromium`; `pip install -e .[test]`), or when the viewer is not built (`scripts/setup.sh`
runs `npm ci && npm run build` in web/). Screenshots go under the pytest tmp dir (printed at the end).
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from tests.serve_process import spawn_serve, stop_serve

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path(os.environ.get("KILN_CHROMIUM", "/usr/bin/chromium"))
WEB_DIST = ROOT / "web" / "dist" / "index.html"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-dev-shm-usage",
]

_why = None
if not CHROMIUM.exists():
    _why = f"{CHROMIUM} is missing (apt-get install -y chromium)"
else:
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        _why = "the playwright package is missing (pip install -e '.[test]')"
if _why is None and not WEB_DIST.exists():
    _why = "web/dist is not built (bash scripts/setup.sh, or: cd web && npm ci && npm run build)"


def pytest_collection_modifyitems(config, items):
    if _why is None:
        return
    here = Path(__file__).parent
    for item in items:
        if Path(str(item.fspath)).is_relative_to(here) and item.module.__name__.split(".")[-1] != "test_fixtures":
            item.add_marker(pytest.mark.skip(reason=_why))


class KilnServer:
    def __init__(self, url: str, proc: subprocess.Popen, log: Path):
        self.url, self.proc, self.log = url, proc, log

    def api(self, path: str, method: str = "GET", **kw):
        r = httpx.request(method, self.url + path, timeout=30, **kw)
        r.raise_for_status()
        return r.json() if r.content else None

    def wait_bake(self, bake_id: str, timeout: float = 90) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            b = self.api(f"/v1/bakes/{bake_id}")
            if b["status"] in ("succeeded", "failed", "cancelled"):
                return b
            if time.monotonic() >= deadline:
                stages = {st["name"]: st.get("status") for st in b.get("stages", [])}
                tail = self.log.read_text(errors="replace")[-3000:] if self.log.exists() else ""
                raise AssertionError(f"bake {bake_id} still {b['status']} after {timeout} s; stages {stages}\n"
                                     f"server log tail:\n{tail}")
            time.sleep(0.2)


@contextlib.contextmanager
def _serve(tmp: Path, api_keys: str = ""):
    """`kiln serve --workers 2` on a free port with its data in `tmp`; stopped with Ctrl-C (SIGINT)."""
    log = tmp / "serve.log"
    proc, url = spawn_serve(tmp / "data", workers=2, api_keys=api_keys, log=log)
    try:
        yield KilnServer(url, proc, log)
    finally:
        stop_serve(proc)


@pytest.fixture(scope="session")
def kiln_server(tmp_path_factory):
    """An open server (no API keys), shared by the tests of the session."""
    if _why:
        pytest.skip(_why)
    with _serve(tmp_path_factory.mktemp("kiln-web")) as srv:
        yield srv


API_KEY = "web-test-key-0123"


@pytest.fixture(scope="module")
def kiln_server_keys(tmp_path_factory):
    """A server that wants an API key (team `web`, key API_KEY)."""
    if _why:
        pytest.skip(_why)
    with _serve(tmp_path_factory.mktemp("kiln-web-keys"), api_keys=f"web:{API_KEY}") as srv:
        yield srv


@pytest.fixture(scope="session")
def browser(tmp_path_factory):
    if _why:
        pytest.skip(_why)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="session")
def shots(tmp_path_factory) -> Path:
    """Folder for screenshots (kept by pytest under its basetemp)."""
    d = tmp_path_factory.mktemp("screenshots")
    yield d
    print(f"\nscreenshots: {d}")


def _new_page(browser, url: str):
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, base_url=url)
    pg = ctx.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(f"pageerror: {e}"))
    # refused requests (4xx the test provokes) log "Failed to load resource": not a script error
    pg.on("console", lambda m: errors.append(f"console.{m.type}: {m.text}")
          if m.type == "error" and "Failed to load resource" not in m.text else None)
    pg.kiln_errors = errors
    return ctx, pg


@pytest.fixture
def page(browser, kiln_server):
    ctx, pg = _new_page(browser, kiln_server.url)
    try:
        yield pg
    finally:
        ctx.close()


@pytest.fixture
def page_keys(browser, kiln_server_keys):
    ctx, pg = _new_page(browser, kiln_server_keys.url)
    try:
        yield pg
    finally:
        ctx.close()
