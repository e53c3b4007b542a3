"""RQ job entry points — the only RQ-aware module of the workers.

A bake is one job per stage (``depends_on`` the jobs of the stages it reads: ``proto.stages.dependencies``),
then :func:`finish_bake`. Jobs take ids and plain JSON, load inputs from the store, call
:func:`workers.pipeline.execute_stage`, and record progress and outcome in the catalog.

Failure handling:

- a :class:`StageError` (bad input) is recorded on the bake as ``{stage, code, message}``
  and not retried;
- deterministic failures are not retried either: ``out_of_memory`` (the stage passed the work-horse's
  memory limit, below) and ``timeout`` (the stage's job timeout, which follows the cost model's estimate);
- any other exception is retried by RQ (``Retry``); the last attempt records
  ``{stage, code: "internal", message}``;
- a work-horse killed mid-stage (SIGKILL) is retried by RQ's worker; artifacts are
  content-addressed and renamed into place, so the killed attempt leaves nothing visible. A horse killed
  for its memory, or by its worker for a cancel (RQ ``stop-job``), is not retried; one that dies on its last
  attempt is recorded (``worker_died``), so recovery does not re-enqueue it for ever (:func:`make_worker`,
  :func:`horse_killed`).

Memory limit (:func:`limit_memory`): in a work-horse, each stage runs under ``RLIMIT_AS`` (an allocation past
it raises ``MemoryError``) and a watchdog thread on its RSS; the limit is the smaller of the job's
``meta["memory_limit_bytes"]`` (the API's ``KILN_MAX_BAKE_MEMORY_MB``) and the worker's own
``KILN_MAX_BAKE_MEMORY_MB``. Both count the horse's whole resident memory, as the cost model's
``peak_memory_bytes`` does; the address-space limit adds :data:`AS_SLACK` for what the libraries reserve
without touching (Embree's and numba's threads: 300-600 MB of address space, measured).

The data directory comes from ``KILN_DATA`` (catalog ``kiln.db`` + ``store/``).
"""
from __future__ import annotations

import os
import resource
import signal
import threading
import time
import traceback
from functools import lru_cache
from pathlib import Path

from persist.catalog import TERMINAL, Catalog
from persist.store import Store
from proto.models import BakeConfig
from proto.stages import finalize_bake
from workers import pipeline
from workers.stages.base import Cancelled, StageError

PROGRESS_INTERVAL_S = 0.2
"""Seconds between progress writes to the catalog (and cancellation checks)."""

AS_SLACK = 1 << 30
"""Address space allowed beyond the memory limit: libraries reserve more than they touch (see the module doc)."""
WATCHDOG_INTERVAL_S = 0.05

IN_WORK_HORSE = False
"""Set by the worker of :func:`make_worker` in its forked work-horse: only there may a stage limit the process's
memory (``kiln bake`` in-process and tests calling :func:`run_stage` directly are left alone)."""


@lru_cache(maxsize=4)
def _env(data_dir: str) -> tuple[Catalog, Store]:
    root = Path(data_dir)
    return Catalog(root / "kiln.db"), Store(root / "store")


def data_env() -> tuple[Catalog, Store]:
    data = os.environ.get("KILN_DATA")
    if not data:
        raise RuntimeError("KILN_DATA is not set: the worker does not know its data directory")
    return _env(str(Path(data).resolve()))


def _current_job():
    from rq import get_current_job
    return get_current_job()


def _fault_delay(stage: str | None = None, config: BakeConfig | None = None) -> float:
    """Fault-injection hook for tests: seconds to pause inside every stage (``KILN_FAULT_STAGE_DELAY=1.5``), or
    in the named stages only (``KILN_FAULT_STAGE_DELAY=prt=30,light=2``; prt and evaluate only when the bake
    enables them). The pause reports no progress."""
    raw = os.environ.get("KILN_FAULT_STAGE_DELAY", "0").strip()
    try:
        if "=" not in raw:
            return float(raw or 0)
        for pair in raw.split(","):
            name, _, secs = pair.partition("=")
            if stage is not None and name.strip() == stage.split(".")[0]:
                section = getattr(config, name.strip(), None)
                if not getattr(section, "enabled", True):
                    return 0.0
                return float(secs)
    except ValueError:
        pass
    return 0.0


def _env_memory_limit() -> int | None:
    try:
        mb = int(os.environ.get("KILN_MAX_BAKE_MEMORY_MB", "0"))
    except ValueError:
        return None
    return mb * 2**20 if mb > 0 else None


def memory_limit_bytes(job=None) -> int | None:
    """The memory limit of the stage job ``job``: the smaller of its meta's and this worker's (or None)."""
    limits = [_env_memory_limit()]
    if job is not None:
        limits.append((job.meta or {}).get("memory_limit_bytes"))
    limits = [int(v) for v in limits if v]
    return min(limits) if limits else None


def _proc_status() -> dict[str, int]:
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            k, _, v = line.partition(":")
            if k in ("VmRSS", "VmSize", "VmHWM"):
                out[k] = int(v.split()[0]) * 1024
    return out


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class MemoryWatchdog(threading.Thread):
    """Kills this work-horse when its RSS passes ``limit`` (after recording ``out_of_memory`` on the bake).

    The backstop of ``RLIMIT_AS`` for memory that C code allocates outside numpy (it may not raise
    MemoryError, or the address-space slack may let it through); sampled every 50 ms.
    """

    def __init__(self, limit: int, on_exceeded):
        super().__init__(name="kiln-memory-watchdog", daemon=True)
        self.limit, self.on_exceeded = limit, on_exceeded
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(WATCHDOG_INTERVAL_S):
            rss = _rss()
            if rss > self.limit:
                try:
                    self.on_exceeded(rss)
                finally:
                    os.kill(os.getpid(), signal.SIGKILL)


def limit_memory(limit: int | None, on_exceeded) -> MemoryWatchdog | None:
    """In a work-horse: cap the address space (``RLIMIT_AS``) and start the RSS watchdog; returns it."""
    if not limit or not IN_WORK_HORSE:
        return None
    st = _proc_status()
    headroom = max(limit - st["VmRSS"], 64 * 2**20)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    want = st["VmSize"] + headroom + AS_SLACK
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    resource.setrlimit(resource.RLIMIT_AS, (want, hard))
    dog = MemoryWatchdog(limit, on_exceeded)
    dog.start()
    return dog


def _oom_message(stage: str, limit: int, rss: int | None = None) -> str:
    used = f" (its resident memory reached {rss / 2**20:.0f} MB)" if rss else ""
    return (f"stage {stage} needed more memory than the limit of {limit / 2**20:.0f} MB per stage{used}; "
            "use fewer probes, rays or visibility samples (POST /v1/bakes?dry_run=true estimates a config)")


def run_stage(bake_id: str, stage: str) -> dict:
    """RQ job: run one stage of a bake. Returns a small JSON summary."""
    from rq.timeouts import JobTimeoutException

    catalog, store = data_env()
    bake = catalog.get_bake(bake_id)
    if bake is None or bake["status"] in TERMINAL:
        return {"skipped": True}
    catalog.set_bake_status(bake_id, "running", only_from=("queued", "running"))
    config = BakeConfig.model_validate(bake["config"])
    now = time.time()
    catalog.update_stage(bake_id, stage, status="running", progress=0.0, pid=os.getpid(), started=now)

    last = [0.0]

    def report(fraction: float) -> None:
        t = time.monotonic()
        if t - last[0] < PROGRESS_INTERVAL_S and fraction < 1.0:
            return
        last[0] = t
        b = catalog.get_bake(bake_id)
        if b is None or b["status"] == "cancelled":
            raise Cancelled()
        catalog.update_stage(bake_id, stage, progress=max(0.0, min(1.0, float(fraction))))

    job = _current_job()
    limit = memory_limit_bytes(job)
    dog = limit_memory(limit, lambda rss: _fail(catalog, bake_id, stage, "out_of_memory",
                                                _oom_message(stage, limit, rss)))
    try:
        delay = _fault_delay(stage, config)
        if delay > 0:
            report(0.01)
            time.sleep(delay)
        _fault_allocate()
        rec, cached = pipeline.execute_stage(store, bake["scene_id"], config, stage, report,
                                             namespace=bake["team"])
    except Cancelled:
        catalog.update_stage(bake_id, stage, status="cancelled", finished=time.time())
        return {"cancelled": True}
    except StageError as e:
        _fail(catalog, bake_id, stage, e.code, e.message)
        if job is not None:
            job.retries_left = 0  # a deterministic input error: retrying cannot help
        raise
    except MemoryError:
        if dog is not None:
            dog.stopped.set()
        _fail(catalog, bake_id, stage, "out_of_memory", _oom_message(stage, limit or 0))
        if job is not None:
            job.retries_left = 0  # the same stage needs the same memory again
        raise
    except JobTimeoutException:
        _fail(catalog, bake_id, stage, "timeout",
              f"stage {stage} ran past its time limit of {job.timeout if job is not None else '?'} s "
              "(set from the bake's cost estimate)")
        if job is not None:
            job.retries_left = 0
        raise
    except Exception as e:
        if job is not None and job.retries_left:
            catalog.update_stage(bake_id, stage, status="retrying")
        else:
            _fail(catalog, bake_id, stage, "internal", f"{type(e).__name__}: {e}")
        traceback.print_exc()
        raise
    finally:
        if dog is not None:
            dog.stopped.set()
    catalog.update_stage(bake_id, stage, status="succeeded", progress=1.0, seconds=rec["seconds"],
                         cached=cached, stats=rec["stats"], finished=time.time())
    return {"stage": stage, "cached": cached, "cache_key": rec["cache_key"]}


def _fault_allocate() -> None:
    """Fault-injection hook for tests: allocate and touch ``KILN_FAULT_STAGE_ALLOC_MB`` MB in every stage, in
    blocks of ``KILN_FAULT_STAGE_ALLOC_BLOCK_MB`` (default 16)."""
    try:
        mb = int(os.environ.get("KILN_FAULT_STAGE_ALLOC_MB", "0"))
        block = max(1, int(os.environ.get("KILN_FAULT_STAGE_ALLOC_BLOCK_MB", "16")))
    except ValueError:
        return
    if mb > 0:
        import numpy as np

        blocks = []
        for _ in range(max(1, mb // block)):
            blocks.append(np.ones(block * 2**20, np.uint8))   # touched: resident, as a stage's arrays are
            time.sleep(0.005)
        del blocks


def _fail(catalog: Catalog, bake_id: str, stage: str, code: str, message: str) -> None:
    catalog.update_stage(bake_id, stage, status="failed", finished=time.time())
    catalog.set_bake_status(bake_id, "failed", error={"stage": stage, "code": code, "message": message})


def _stage_of_job(job) -> tuple[str, str] | None:
    """(bake id, stage) of a ``run_stage`` job, or None for other jobs."""
    if job.func_name != "workers.jobs.run_stage" or len(job.args) != 2:
        return None
    return job.args[0], job.args[1]


def horse_killed(job, ret_val: int | None, rusage) -> None:
    """The worker saw the work-horse of ``job`` die (not stopped on request): decide about the retry.

    - the bake is already finished (a cancel, or the memory watchdog recorded ``out_of_memory``): no retry;
    - the horse's peak RSS reached the job's memory limit (the kernel's OOM killer, the watchdog): record
      ``out_of_memory``, no retry;
    - it ran past its timeout (the worker killed it): record ``timeout``, no retry;
    - otherwise RQ retries it; on its last attempt the bake is recorded failed (``worker_died``), so that
      recovery does not re-enqueue it for ever.
    """
    which = _stage_of_job(job)
    if which is None:
        return
    bake_id, stage = which
    catalog, _ = data_env()
    bake = catalog.get_bake(bake_id)
    if bake is None or bake["status"] in TERMINAL:
        job.retries_left = 0
        return
    limit = memory_limit_bytes(job)
    peak = int(rusage.ru_maxrss) * 1024 if rusage is not None else 0
    sig = os.WTERMSIG(ret_val) if ret_val and os.WIFSIGNALED(ret_val) else None
    if limit and peak >= 0.95 * limit:
        job.retries_left = 0
        _fail(catalog, bake_id, stage, "out_of_memory", _oom_message(stage, limit, peak))
        return
    started = getattr(job, "started_at", None)
    if started is not None and job.timeout and job.timeout > 0:
        from rq.utils import now

        if (now() - started).total_seconds() >= job.timeout:
            job.retries_left = 0
            _fail(catalog, bake_id, stage, "timeout", f"stage {stage} ran past its time limit of {job.timeout} s")
            return
    if not job.retries_left:
        why = f"signal {sig}" if sig else f"exit status {ret_val}"
        _fail(catalog, bake_id, stage, "worker_died",
              f"the process running stage {stage} died ({why}) on every attempt")
    else:
        catalog.update_stage(bake_id, stage, status="retrying")


def make_worker(queues: list[str], conn, name: str):
    """The RQ worker of ``kiln worker``: :class:`rq.Worker` that marks its work-horses (memory limits apply
    there only) and decides about retries when a horse dies (:func:`horse_killed`)."""
    from rq import Queue, Worker

    class KilnWorker(Worker):
        def main_work_horse(self, job, queue):
            global IN_WORK_HORSE
            IN_WORK_HORSE = True
            super().main_work_horse(job, queue)

        def handle_work_horse_killed(self, job, retpid, ret_val, rusage):
            super().handle_work_horse_killed(job, retpid, ret_val, rusage)
            try:
                horse_killed(job, ret_val, rusage)
            except Exception:  # deciding must never take the worker down
                traceback.print_exc()

    return KilnWorker([Queue(q, connection=conn) for q in queues], connection=conn, name=name)


def finish_bake(bake_id: str) -> dict:
    """RQ job: after the last stage, write the manifest onto the bake and mark it succeeded."""
    catalog, store = data_env()
    bake = catalog.get_bake(bake_id)
    if bake is None or bake["status"] in TERMINAL:
        return {"skipped": True}
    if any(s["status"] != "succeeded" for s in bake["stages"]):
        # A stage did not finish (cancelled or lost): leave the bake to recovery.
        return {"incomplete": True}
    done = finalize_bake(bake, catalog.get_scene(bake["team"], bake["scene_id"]), store)
    catalog.mark_succeeded(bake_id, done.manifest, done.metrics)
    return {"succeeded": True}


def ingest_upload(path: str, filename: str | None, store_root: str, limits: dict) -> dict:
    """Parse an uploaded file into a normalized scene and store it (runs in a child process of the API).

    Returns ``{"scene_id", "summary"}`` or ``{"error": {"status", "code", "message"}}``; never raises
    for bad input. Run out of process so a huge or hostile upload cannot grow the API's memory.
    """
    from workers.gltf import IngestError, IngestLimits, ingest_file

    # fault injection for tests: uploads named slow* take this many seconds to parse
    delay = float(os.environ.get("KILN_FAULT_INGEST_DELAY", "0") or 0)
    if delay > 0 and (filename or "").startswith("slow"):
        time.sleep(delay)
    limits = dict(limits)
    max_scene = limits.pop("max_scene_bytes", None)
    try:
        scene = ingest_file(path, IngestLimits(**limits), filename=filename)
    except IngestError as e:
        return {"error": {"status": e.status, "code": e.code, "message": e.message}}
    data = scene.to_bytes()
    if max_scene is not None and len(data) > max_scene:
        return {"error": {"status": 413, "code": "scene_too_large", "message": (
            f"'{filename or 'the upload'}' expands to {len(data)} bytes of decoded images and geometry; the limit "
            f"is {max_scene} bytes (KILN_MAX_SCENE_MB)")}}
    scene_id = Store(store_root).put_bytes(data)
    summary = scene.summary(scene_id)
    summary["bytes"] = len(data)
    return {"scene_id": scene_id, "summary": summary}
