"""Builds the FastAPI app: routers, error handlers, shared state, and the recovery loop."""
from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from pathlib import Path

import anyio
from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

from persist.catalog import Catalog
from persist.store import Store
from proto.stages import KILN_VERSION
from server import queue
from server.api import errors, openapi
from server.api.guard import Guard
from server.api.jsonbody import FiniteJSONResponse
from server.api.routes import bakes, compare, ops, relight, review, scenes, thresholds
from server.config import Settings, get_settings
from server.ingest_pool import IngestPool
from workers.relight import RelightCache

log = logging.getLogger("kiln.api")
STATIC = Path(__file__).parent / "static"
WEB_DIST = Path(__file__).resolve().parents[1] / "web" / "dist"


async def _recover_loop(app: FastAPI) -> None:
    """Keep every bake moving, from startup on.

    - Every ``ready_interval_s``: enqueue stage jobs RQ left ready but not queued (``queue.drain_ready``).
    - Every ``recover_interval_s``: re-enqueue bakes that lost their jobs (Redis restarted, workers died).
    """
    st = app.state
    first, last_recover = True, -float("inf")
    while True:
        try:
            await asyncio.to_thread(queue.drain_ready, st.redis)
            if time.monotonic() - last_recover >= st.settings.recover_interval_s:
                await asyncio.to_thread(queue.recover, st.redis, st.catalog, 0.0 if first else 10.0,
                                        st.settings.bake_memory_bytes)
                first, last_recover = False, time.monotonic()
        except Exception as e:  # Redis unreachable (it comes back later) or a bug: say so, keep serving
            log.warning("recovery skipped: %s", e)
        await asyncio.sleep(min(st.settings.ready_interval_s, st.settings.recover_interval_s))


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        settings.data.mkdir(parents=True, exist_ok=True)
        app.state.settings = settings
        app.state.catalog = Catalog(settings.data / "kiln.db")
        app.state.store = Store(settings.data / "store")
        app.state.relight_cache = RelightCache()
        if not settings.redis_url:
            raise RuntimeError("REDIS_URL is not set (kiln serve starts an embedded Redis and sets it)")
        app.state.redis = queue.connect(settings.redis_url)
        # sync routes run in anyio's thread pool (40 threads by default): under 50 polling clients that many
        # threads mostly fight over the GIL (GET /v1/bakes/{id}, closed loop: 4 threads 270 req/s, 8: 206,
        # 40: 130); 8 leaves room for the slow sync routes (a bundle zip, a relight)
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.api_threads
        app.state.ingest_pool = IngestPool(settings.ingest_processes, timeout_s=settings.ingest_timeout_s,
                                           per_team=settings.max_uploads_per_team,
                                           tmp_root=settings.data / "ingest-tmp")
        if settings.open:
            log.warning("no API keys configured (KILN_API_KEYS): the server is open to anyone who can reach it")
        task = asyncio.create_task(_recover_loop(app))
        try:
            yield
        finally:
            task.cancel()
            app.state.ingest_pool.shutdown()

    # FastAPIOffline: /docs and /redoc load Swagger UI and ReDoc from Kiln itself, not a CDN (server/api/openapi.py)
    app = FastAPIOffline(title="Kiln", version=KILN_VERSION, lifespan=lifespan, redoc_url=None,
                         default_response_class=FiniteJSONResponse, swagger_ui_parameters=openapi.SWAGGER_UI_PARAMETERS,
                         description="Bake service for leak-free, relightable probe global illumination.")
    errors.install(app)
    openapi.install(app)
    app.add_middleware(Guard)     # the key check and the JSON body cap, before any body byte is read
    app.include_router(ops.router)
    app.include_router(scenes.router)
    app.include_router(bakes.router)
    app.include_router(relight.router)
    app.include_router(compare.router)
    app.include_router(review.router)
    app.include_router(thresholds.router)

    # The built viewer (web/dist, `npm run build`) at / with its assets (relative URLs: ./assets/...); the
    # minimal page in server/static when it has not been built. Both are looked up per request, so building
    # while the server runs takes effect.
    if (WEB_DIST / "index.html").exists():
        app.mount("/app", StaticFiles(directory=WEB_DIST, html=True), name="web")
    app.mount("/assets", StaticFiles(directory=WEB_DIST / "assets", check_dir=False), name="web-assets")

    @app.get("/", include_in_schema=False)
    def index():
        built = WEB_DIST / "index.html"
        return FileResponse(built if built.exists() else STATIC / "index.html",
                            headers={"Cache-Control": "no-cache"})

    return app
