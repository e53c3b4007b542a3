"""Shared fixtures: paths to ../shared, procedural scenes, and a real Kiln service
(embedded Redis + real RQ worker processes + the FastAPI app)."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


def shared_path(*parts: str) -> Path:
    """A path under ../shared, or skip the test saying why."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"{p} is absent (tests read real scenes from ../shared beside the checkout)")
    return p


SMALL_BAKE = {"place": {"budget": 300}, "trace": {"rays_per_probe": 32, "relocate_iterations": 1},
              "visibility": {"samples_per_cell": 2}, "masks": {"sweeps": 10}, "evaluate": {"enabled": False}}
"""The cheap end of each costly section, for a test about what happens around a bake (queues, restarts, faults,
auth, events, the cache, exit codes) rather than about its quality: an automatic grid of at most 300 probes,
32 rays per probe, 2 visibility samples per cell, 10 annealing sweeps, no evaluation. The default config (an
automatic grid of up to 24,000 probes, 256 rays, a path-traced reference) takes minutes of the CI's 2 cores."""

SMALL_EVALUATE = {"enabled": True, "cameras": 1, "width": 32, "height": 24, "spp": 2, "repeats": 1, "previews": 0,
                  "surface_points": 32, "modes": ["direct", "leaking"]}
"""An evaluate section for SMALL_BAKE where a test needs the reference and evaluate stages to run: one camera,
32x24 pixels, 32 surface points at 2 paths, two modes, one timed repeat, no previews."""


def small_bake(**sections: dict) -> dict:
    """SMALL_BAKE with ``sections`` laid over it key by key: ``small_bake(place={"counts": [5, 5, 5]})`` keeps the
    budget (unused with counts) and the other cheap sections; a section SMALL_BAKE lacks is added as given."""
    out = {name: dict(values) for name, values in SMALL_BAKE.items()}
    for name, values in sections.items():
        out[name] = {**out.get(name, {}), **values}
    return out


UNLIT = small_bake(scene={"sky": [0, 0, 0], "use_scene_lights": False}, place={"counts": [3, 3, 3]},
                   visibility={"slabs": 2})
"""A tiny bake with the scene's own lights dropped and a black sky: nothing lights it, the ingest stage warns
``unlit_scene``."""


def as_toml(config: dict) -> str:
    """A config of sections of scalars and lists (no nested tables) as TOML text, for the CLI's ``--config``."""
    return "".join(f"[{name}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in values.items())
                   for name, values in config.items())


@pytest.fixture(scope="session")
def scene_files(tmp_path_factory) -> dict[str, Path]:
    """The procedural scenes written once as .glb files."""
    from workers.procedural import SCENES, write_scene

    d = tmp_path_factory.mktemp("scenes")
    out = {}
    for name in SCENES:
        out[name] = d / f"{name}.glb"
        write_scene(name, out[name])
    return out


class Service:
    """A running Kiln: embedded Redis, N worker processes, the app behind a TestClient."""

    def __init__(self, data: Path, workers: int = 2, env: dict | None = None):
        from server.supervisor import EmbeddedRedis

        self.data = data
        self.redis = EmbeddedRedis(data)
        self.redis.start()
        self.n_workers = workers
        self.extra_env = env or {}
        self.pool = None
        self.client = None
        self.keys = ""

    def start_workers(self, n: int | None = None, env: dict | None = None):
        from server.supervisor import WorkerPool

        e = dict(os.environ, KILN_DATA=str(self.data), REDIS_URL=self.redis.url, PYTHONUNBUFFERED="1")
        e.update(self.extra_env)
        e.update(env or {})
        self.pool = WorkerPool(self.n_workers if n is None else n, e)
        self.pool.start()

    def stop_workers(self):
        if self.pool:
            self.pool.stop()
            self.pool = None

    def start_app(self, api_keys: str = ""):
        from fastapi.testclient import TestClient

        from server.config import Settings
        from server.main import create_app

        self.keys = api_keys
        settings = Settings(data=self.data, redis_url=self.redis.url, api_keys=api_keys, recover_interval_s=0.5)
        client = TestClient(create_app(settings))
        client.__enter__()
        self.client = client
        return client

    def stop_app(self):
        if self.client:
            self.client.__exit__(None, None, None)
            self.client = None

    def close(self):
        self.stop_app()
        self.stop_workers()
        self.redis.stop()

    def wait_bake(self, bake_id: str, timeout: float = 240.0, headers: dict | None = None,
                  until=("succeeded", "failed", "cancelled")) -> dict:
        """The bake once its status is in ``until``. ``timeout`` (s) bounds a hang, it measures nothing: a default
        config bake on a loaded 2-core machine takes minutes."""
        deadline = time.monotonic() + timeout
        while True:
            b = self.client.get(f"/v1/bakes/{bake_id}", headers=headers or {}).json()
            if b.get("status") in until:
                return b
            if time.monotonic() > deadline:
                raise AssertionError(f"bake {bake_id} still {b.get('status')} after {timeout}s: {b}")
            time.sleep(0.1)

    def upload(self, path: Path, headers: dict | None = None):
        with open(path, "rb") as f:
            return self.client.post("/v1/scenes", content=f.read(),
                                    headers={"X-Filename": path.name, **(headers or {})})


@pytest.fixture
def service(tmp_path):
    svc = Service(tmp_path / "data")
    try:
        yield svc
    finally:
        svc.close()


@pytest.fixture
def running(service):
    """A service with 2 workers and the app started (open, no API keys)."""
    service.start_workers()
    service.start_app()
    return service
