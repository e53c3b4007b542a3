"""The bake pipeline: which stages run in which order, their cache keys, and running one.

Each stage's output is keyed by a hash of its name and version, the config sections it
reads, and the keys of the stages it reads (the first stage reads the scene id). Keys are
known before anything runs, so a bake whose every stage is in the store finishes at once,
and a config that changes only a later stage's section re-runs only that stage and those
after it (DESIGN "Data flow").

Both the RQ jobs (:mod:`workers.jobs`) and the CLI's in-process bake call
:func:`execute_stage`; neither holds any math.
"""
from __future__ import annotations

import queue
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

from persist.store import Store
from proto import bundle
from proto.models import ArtifactInfo, BakeConfig, Manifest
from proto.stages import STAGE_BY_NAME, build_manifest, plan
from workers.scene import NormalizedScene
from workers.stages.base import LazyArtifacts, StageContext, StageOutput
from workers.stages.anneal import run_anneal
from workers.stages.clusters import run_clusters
from workers.stages.compress import run_compress
from workers.stages.evaluate import run_evaluate
from workers.stages.lighting import run_lighting
from workers.stages.masks import run_masks
from workers.stages.light import run_light
from workers.stages.place import run_place
from workers.stages.prt import run_prt
from workers.stages.reference import run_reference
from workers.stages.relocate import run_relocate
from workers.stages.trace import run_trace
from workers.stages.visibility import run_visibility, run_visibility_slab

RUNNERS: dict[str, Callable[[StageContext], StageOutput]] = {
    "ingest": run_lighting,  # public name kept (manifests, cache keys); module workers/stages/lighting.py
    "place": run_place,
    "relocate": run_relocate,
    "trace": run_trace,
    "light": run_light,
    "visibility": run_visibility,
    "anneal": run_anneal,
    "masks": run_masks,
    "clusters": run_clusters,
    "compress": run_compress,
    "prt": run_prt,
    "reference": run_reference,
    "evaluate": run_evaluate,
}
SHARD_RUNNERS: dict[str, Callable[[StageContext], StageOutput]] = {"visibility": run_visibility_slab}
"""Runners of the shards of sharded stages (``StageDef.shards_from``), by stage name."""
assert set(RUNNERS) == set(STAGE_BY_NAME), "every stage in proto.stages needs a runner"
assert all(STAGE_BY_NAME[n].shards_from for n in SHARD_RUNNERS)


def load_scene(store: Store, scene_id: str) -> NormalizedScene:
    return NormalizedScene.from_bytes(store.read_bytes(scene_id))


FRAME_STAGES = frozenset({"place", "relocate", "trace", "light", "visibility", "anneal", "masks", "clusters",
                          "compress", "prt", "evaluate"})
"""The stages that work in the bake frame (:mod:`workers.kernels.frame`): their ``ctx.scene`` is the scene turned by
the place section's yaw, and (all but evaluate) their ``ingest`` input's lights and bounds are turned likewise.
``ingest`` and ``reference`` stay in the world frame (the reference is shared by bakes of any probe config);
evaluate maps the reference's world points into the frame at its GI lookups. Their cache keys follow the frame:
it is a function of the scene and the ``place`` section, which every one of them reads through ``place``'s key."""


def framed_scene(scene: NormalizedScene, config: BakeConfig) -> NormalizedScene:
    """``scene`` in the bake frame of ``config.place`` (:func:`workers.kernels.frame.choose_frame`); the choice is
    on the result's ``frame`` attribute (the place stage records it)."""
    from workers.kernels.frame import choose_frame, frame_of, rotate_scene

    info = choose_frame(scene.triangles, config.place)
    out = rotate_scene(scene, frame_of({"frame": info}))
    out.frame = info
    return out


def framed_ingest(ingest: LazyArtifacts, scene: NormalizedScene) -> LazyArtifacts:
    """The ``ingest`` stage's outputs seen from the bake frame of ``scene`` (a :func:`framed_scene`): ``lights``
    turned, ``stats["bounds"]`` the turned scene's box. Unchanged in the world frame."""
    from workers.kernels.frame import frame_of, rotate_lights

    M = frame_of({"frame": getattr(scene, "frame", None)})
    if M is None:
        return ingest

    def lights():
        doc = ingest["lights"]
        return {**doc, "lights": rotate_lights(doc["lights"], M)}

    loaders = {n: (lambda n=n: ingest[n]) for n in ingest.names()}
    loaders["lights"] = lights
    return LazyArtifacts({**ingest.stats, "bounds": scene.bounds.tolist()}, loaders)


WRITE_THREADS = 4
"""Threads that write one stage's artifacts (each one's encoding, hashing and fsync overlap the others')."""


def _lazy(store: Store, record: dict) -> LazyArtifacts:
    loaders = {}
    for a in record["artifacts"]:
        info = ArtifactInfo(**a)
        loaders[info.name] = (lambda info=info: bundle.load_artifact(store.blob_path(info.sha256), info))
    return LazyArtifacts(record.get("stats", {}), loaders)


BLAS_THREADS = 1
"""OpenBLAS threads in a process that runs stages (:func:`limit_blas_threads`). The stages' matrix products are small
(zdm2: the light stage's per-bounce maps and SH, 0.6 s of a 43 s bake) and run beside other stages (two in
:func:`bake_local`, one per worker beside the other worker's); OpenBLAS's own threads spin while they wait, which on
this 2-core machine cost the bake CPU time: zdm2 with the default (2 threads) 44.4 / 47.6 / 46.6 s, 64-70 CPU-s of
user time; with 1, 42.5 / 42.4 / 45.8 s, 58-64 CPU-s (alternated). The products' float32 sums then come in another
order: the trace and light stages' arrays move by float32 rounding (stored half floats by an ulp), every metric of
``eval_metrics`` by less than 1e-4 of itself; and a bake's floats no longer depend on the machine's core count."""
_blas_limited = False


def limit_blas_threads() -> None:
    """Set OpenBLAS (numpy's and scipy's BLAS) to :data:`BLAS_THREADS` threads for the rest of this process, once
    (threadpoolctl; a no-op where none is loaded)."""
    global _blas_limited
    if _blas_limited:
        return
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=BLAS_THREADS, user_api="blas")
    _blas_limited = True


def execute_stage(store: Store, scene_id: str, config: BakeConfig, stage: str,
                  report: Callable[[float], None] = lambda f: None,
                  namespace: str | None = None) -> tuple[dict, bool]:
    """Run one stage (or take it from the store). Returns ``(stage record, cached)``.

    Upstream stages must already be in the store. The record is
    ``{"stage", "cache_key", "seconds", "stats", "artifacts": [ArtifactInfo dicts]}``. ``namespace``: the
    cache namespace (the bake's team on the server, :func:`proto.stages.plan`).
    """
    planned = plan(scene_id, config, namespace)
    keys = {st.name: key for st, key in planned}
    st = next(s for s, _ in planned if s.name == stage)
    key = keys[stage]
    rec = store.get_stage(key)
    if rec is not None:
        return rec, True
    limit_blas_threads()
    inputs = {}
    for dep in st.inputs:
        dep_rec = store.get_stage(keys[dep])
        if dep_rec is None:
            raise RuntimeError(f"stage {stage} needs {dep}, which is not in the store")
        inputs[dep] = _lazy(store, dep_rec)
    framed = (st.parent or st.name) in FRAME_STAGES

    def scene_loader() -> NormalizedScene:
        scene = load_scene(store, scene_id)
        scene.max_albedo = config.scene.max_albedo        # material options of the bake (workers.kernels.materials)
        scene.specular_gi = config.scene.specular_gi
        if framed:
            scene = framed_scene(scene, config)
        return scene

    ctx = StageContext(config=config, scene_loader=scene_loader, inputs=inputs, report=report,
                       shard=st.shard, shard_count=st.shard_count)
    if framed and "ingest" in inputs and (st.parent or st.name) != "evaluate":
        inputs["ingest"] = framed_ingest(inputs["ingest"], ctx.scene)
        ctx.frame = getattr(ctx.scene, "frame", None)
    t0 = time.perf_counter()
    out = (SHARD_RUNNERS[st.parent] if st.shard is not None else RUNNERS[st.name])(ctx)
    seconds = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(dir=store.root / "tmp") as tmp:
        def put(art) -> dict:
            info = art.write(tmp, stage)
            store.put_file(Path(tmp) / info.file, move=True, sha256=info.sha256)
            return info.model_dump()

        # encoding (zstd, PNG) and fsync release the GIL: a stage's artifacts are written side by side, in order
        if len(out.artifacts) > 1:
            with ThreadPoolExecutor(min(WRITE_THREADS, len(out.artifacts))) as pool:
                infos = list(pool.map(put, out.artifacts))
        else:
            infos = [put(a) for a in out.artifacts]
    rec = {"stage": stage, "cache_key": key, "seconds": seconds, "stats": out.stats, "artifacts": infos}
    store.put_stage(key, rec)
    return rec, False


BAKE_CONCURRENCY = 2
"""Stages :func:`bake_local` runs side by side. The stages form a DAG (``StageDef.inputs``), not a chain: the
reference reads only ingest, visibility's slabs and anneal read no light, so they run beside the light stage,
whose threads leave part of the machine idle (zdm2 on 2 cores: light uses 1.44 of them). Two, as this
machine's cores: each stage's kernels already use every core they can."""


def ready_order(planned: list, done: set[str], started: set[str]) -> list:
    """The stages of ``planned`` (``[(StageDef, key), ...]`` in run order) whose inputs are all ``done`` and that
    have not ``started``, in run order (which puts the chain of probe stages, the longest path, first)."""
    return [st for st, _ in planned if st.name not in started and all(d in done for d in st.inputs)]


def bake_local(store: Store, scene: NormalizedScene, config: BakeConfig,
               report: Callable[[str, float], None] = lambda s, f: None,
               concurrency: int = BAKE_CONCURRENCY) -> Manifest:
    """Run every stage in this process (the CLI's ``kiln bake`` without a server): each as soon as the stages
    it reads are done, up to ``concurrency`` at once (1: one after the other, in run order). The artifacts do
    not depend on the order (each stage reads only its inputs' stored artifacts). The first stage that fails
    stops new ones from starting; those running finish; its exception is raised.

    Stages run on daemon threads and the calling thread only waits for them, so an interrupt (Ctrl+C) there
    returns at once: the running stages are abandoned, and the store holds only complete outputs (each is written
    to a temporary file and renamed, as when a worker is killed)."""
    scene_id = store.put_bytes(scene.to_bytes())
    planned = plan(scene_id, config)
    limit = max(1, int(concurrency))
    cached: dict[str, bool] = {}
    done: set[str] = set()
    started: set[str] = set()
    running: set[str] = set()
    finished: queue.SimpleQueue = queue.SimpleQueue()
    lock = threading.Lock()

    def run_one(name: str) -> None:
        def rep(f: float) -> None:
            with lock:
                report(name, f)
        try:
            rep(0.0)
            _, cached[name] = execute_stage(store, scene_id, config, name, rep)
            rep(1.0)
        except BaseException as e:          # handed to the waiting thread, which raises it
            finished.put((name, e))
        else:
            finished.put((name, None))

    error: BaseException | None = None
    while True:
        if error is None:
            for st in ready_order(planned, done, started)[:max(0, limit - len(running))]:
                started.add(st.name)
                running.add(st.name)
                threading.Thread(target=run_one, args=(st.name,), name=f"kiln-stage-{st.name}", daemon=True).start()
        if not running:
            break
        name, exc = finished.get()                  # interruptible: Ctrl+C raises here
        running.discard(name)
        if exc is not None:
            error = error or exc
        else:
            done.add(name)
    if error is not None:
        raise error
    missing = [st.name for st, _ in planned if st.name not in done]
    if missing:                                     # a cycle in the stage table: a bug, not a user error
        raise RuntimeError(f"stages never became ready: {missing}")
    return build_manifest(store, scene.summary(scene_id), config, cached=cached)
