"""The ``kiln`` command line.

Exit codes (stable, for build tools):

| code | meaning |
|---|---|
| 0 | success |
| 1 | internal error (a bug; the message says what) |
| 2 | usage error (bad arguments) |
| 3 | bad input: the scene or the config was refused (the message names the reason or field) |
| 4 | the bake failed or was cancelled |
| 5 | the server could not be reached or answered unexpectedly |
| 6 | ``kiln bake --strict`` only: the bake succeeded (bundle written) but carries warnings |
| 7 | ``kiln bake --fail-on`` only: the bake succeeded (bundle written) but a quality gate failed (server/gates.py) |

``kiln bake`` prints each warning of the bake (the manifest's ``warnings``) to stderr as
``kiln: warning [code] message``, with or without ``--json``.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_INPUT, EXIT_BAKE, EXIT_SERVER, EXIT_WARNINGS = 0, 1, 2, 3, 4, 5, 6
EXIT_GATES = 7


class CliError(Exception):
    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.exit_code, self.message = code, message


# --------------------------------------------------------------------------- config


def load_presets() -> dict[str, dict]:
    """The bake presets (Preview / Medium / Production) of proto/presets.json, one file for the web form and
    ``--preset``, by id in file order: ``{id: {"id", "label", "description", "config"}}`` (partial configs)."""
    import proto

    try:
        doc = json.loads((Path(proto.__file__).parent / "presets.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return {p["id"]: p for p in doc.get("presets", [])}


def _merge(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``: tables merge key by key, anything else (numbers, lists) is replaced."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_config(path: str | None, preset: str | None = None):
    """BakeConfig from a TOML (or JSON) file on top of a preset's partial config (the file's values win);
    CliError(EXIT_INPUT) naming the field on error."""
    import tomllib

    from pydantic import ValidationError

    from proto.models import BakeConfig

    data: dict = {}
    if preset is not None:
        presets = load_presets()
        if preset not in presets:
            raise CliError(EXIT_USAGE, f"unknown preset {preset!r} (one of: {', '.join(presets) or 'none'})")
        data = json.loads(json.dumps(presets[preset]["config"]))
    if path is not None:
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as e:
            raise CliError(EXIT_INPUT, f"cannot read config {path}: {e.strerror}")
        try:
            data = _merge(data, json.loads(text) if p.suffix == ".json" else tomllib.loads(text))
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
            raise CliError(EXIT_INPUT, f"config {path} is not valid {'JSON' if p.suffix == '.json' else 'TOML'}: {e}")
    try:
        return BakeConfig.model_validate(data)
    except ValidationError as e:
        errs = e.errors()
        parts = []
        for err in errs[:5]:
            loc = ".".join(str(x) for x in err["loc"]) or "config"
            msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"]
            parts.append(f"{loc}: {msg}")
        what = f"config {path}" if path is not None else "config"
        raise CliError(EXIT_INPUT, f"invalid {what}{f' (preset {preset})' if preset else ''}: " + "; ".join(parts))


# --------------------------------------------------------------------------- progress


class Progress:
    """Progress on stderr, one step per stage: a live bar on a terminal; elsewhere (a CI log, a file) one line per
    stage as it finishes, so that logs hold no redrawn bars. Silent with ``enabled=False`` (``--quiet``)."""

    def __init__(self, stages: list[str], enabled: bool = True, interactive: bool | None = None):
        from tqdm import tqdm

        self.stages = stages
        self.enabled = enabled
        self.interactive = sys.stderr.isatty() if interactive is None else interactive
        self.total = len(stages)
        self.bar = tqdm(total=self.total, file=sys.stderr, unit="stage", disable=not (enabled and self.interactive),
                        bar_format="{l_bar}{bar}| {n:.2f}/{total} stages [{elapsed}]")
        self.done: dict[str, float] = {}
        self.t0 = time.monotonic()

    def set_total(self, total: int) -> None:
        self.total = total
        self.bar.total = total

    def update(self, stage: str, fraction: float) -> None:
        before = self.done.get(stage, 0.0)
        self.done[stage] = max(before, fraction)
        if self.enabled and not self.interactive and before < 1.0 <= fraction:
            finished = sum(1 for v in self.done.values() if v >= 1.0)
            print(f"kiln: [{finished}/{self.total}] {stage} done ({time.monotonic() - self.t0:.1f} s)",
                  file=sys.stderr, flush=True)
        self.bar.set_description(stage)
        self.bar.n = sum(self.done.values())
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


# --------------------------------------------------------------------------- bake


def _default_cache() -> Path:
    base = os.environ.get("KILN_CACHE") or os.path.join(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"), "kiln")
    return Path(base)


@contextlib.contextmanager
def _with_files(scene: Path):
    """The file to ingest or upload for ``scene``: the model itself, or (when it references buffers or images on
    disk) a temporary zip of it and those files (:mod:`workers.gltf.pack`), removed afterwards."""
    from workers.gltf.pack import MissingFile, pack_model

    with tempfile.TemporaryDirectory(prefix="kiln-pack-") as tmp:
        out = Path(tmp) / f"{scene.stem}.zip"
        try:
            packed = pack_model(scene, out)
        except MissingFile as e:
            raise CliError(EXIT_INPUT, f"{scene}: missing_resource: {e}")
        except OSError as e:
            raise CliError(EXIT_INPUT, f"{scene}: cannot pack the files it references: {e.strerror or e}")
        yield out if packed else scene


def bake_local(args) -> int:
    from persist.export import export_bundle
    from persist.store import Store
    from proto.stages import expand
    from workers.gltf import IngestError, ingest_file
    from workers.pipeline import bake_local as run
    from workers.stages.base import StageError

    gates = _parse_gates(args)
    config = load_config(args.config, args.preset)
    if args.jobs is not None and args.jobs < 1:
        raise CliError(EXIT_USAGE, f"--jobs must be at least 1, got {args.jobs}")
    if not Path(args.scene).is_file():
        raise CliError(EXIT_INPUT, f"no such file: {args.scene}")
    try:
        with _with_files(Path(args.scene)) as path:
            scene = ingest_file(path, filename=Path(args.scene).name)
    except IngestError as e:
        raise CliError(EXIT_INPUT, f"{args.scene}: {e.code}: {e.message}")
    store = Store(Path(args.cache) / "store")
    prog = Progress([s.name for s in expand(config)], enabled=not args.quiet)
    try:
        manifest = run(store, scene, config, report=prog.update,
                       **({} if args.jobs is None else {"concurrency": args.jobs}))
    except StageError as e:
        raise CliError(EXIT_BAKE, f"bake failed: {e.code}: {e.message}")
    finally:
        prog.close()
    export_bundle(store, manifest, args.out)
    data = manifest.model_dump(mode="json")
    _print_result(args, data)
    return _apply_gates(args, data, gates, _report_warnings(args, data["warnings"]))


def _print_result(args, manifest: dict) -> None:
    if args.json:
        sys.stdout.write(json.dumps(manifest, indent=1) + "\n")
        return
    stages = ", ".join(f"{s['name']} {s['seconds']:.2f}s{' (cached)' if s.get('cached') else ''}"
                       for s in manifest["stages"])
    print(f"baked scene {manifest['scene']['id'][:12]} -> {args.out} ({len(manifest['artifacts'])} artifacts; {stages})")


def _report_warnings(args, warnings: list[dict]) -> int:
    """Print each warning to stderr; the exit code: EXIT_WARNINGS with ``--strict`` and any warning."""
    for w in warnings:
        print(f"kiln: warning [{w.get('code')}] {w.get('message')}", file=sys.stderr)
    if warnings and getattr(args, "strict", False):
        print(f"kiln: --strict: the bake has {len(warnings)} warning{'s' if len(warnings) != 1 else ''} "
              f"(bundle written to {args.out})", file=sys.stderr)
        return EXIT_WARNINGS
    return EXIT_OK


def bake_remote(args) -> int:
    import httpx

    gates = _parse_gates(args)
    config = load_config(args.config, args.preset)
    scene = Path(args.scene)
    if not scene.is_file():
        raise CliError(EXIT_INPUT, f"no such file: {args.scene}")
    headers = {"Authorization": f"Bearer {args.api_key}"} if args.api_key else {}
    base = args.server.rstrip("/")
    try:
        with httpx.Client(base_url=base, headers=headers, timeout=httpx.Timeout(60.0, connect=10.0)) as c:
            with _with_files(scene) as path, open(path, "rb") as f:
                r = c.post("/v1/scenes", content=f, headers={"X-Filename": path.name,
                                                             "Content-Type": "application/octet-stream"})
            scene_body = _check(r, EXIT_INPUT)
            r = c.post("/v1/bakes", json={"scene_id": scene_body["id"], "config": config.model_dump(mode="json")})
            bake = _check(r, EXIT_INPUT)
            bake_id = bake["id"]
            prog = Progress([], enabled=not args.quiet)
            try:
                final = _follow(c, bake_id, prog)
            finally:
                prog.close()
            if final["status"] != "succeeded":
                err = final.get("error") or {}
                reason = f"{err.get('stage')}: {err.get('code')}: {err.get('message')}" if err else final["status"]
                raise CliError(EXIT_BAKE, f"bake {bake_id} {final['status']}: {reason}")
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            zpath = out / f".kiln-bundle-{bake_id}.zip"
            with c.stream("GET", f"/v1/bakes/{bake_id}/bundle") as r:
                if r.status_code != 200:
                    r.read()
                    _check(r, EXIT_SERVER)
                with open(zpath, "wb") as f:
                    for chunk in r.iter_bytes():
                        f.write(chunk)
            _extract(zpath, out)
            zpath.unlink()
            manifest = json.loads((out / "manifest.json").read_text())
    except httpx.HTTPError as e:
        raise CliError(EXIT_SERVER, f"cannot talk to {base}: {e}")
    _print_result(args, manifest)
    # the bundle's manifest carries them; a server from before warnings has them on the bake at most
    warnings = manifest.get("warnings") if "warnings" in manifest else final.get("warnings") or []
    return _apply_gates(args, manifest, gates, _report_warnings(args, warnings))


def _parse_gates(args) -> list:
    """The ``--fail-on`` gates, parsed before anything runs (a bad one is a usage error)."""
    from server.gates import GateError, parse_gates

    try:
        return parse_gates(getattr(args, "fail_on", None))
    except GateError as e:
        raise CliError(EXIT_USAGE, str(e))


def _apply_gates(args, manifest: dict, gates: list, code: int) -> int:
    """Check the gates against the manifest's metrics, write ``--junit``; EXIT_GATES when one failed (before
    ``--strict``'s EXIT_WARNINGS), else ``code``."""
    from server.gates import check, junit_xml, manifest_metrics

    if not gates and not getattr(args, "junit", None):
        return code
    metrics = manifest_metrics(manifest)
    failed = check(gates, metrics)
    for g in gates:
        print(f"kiln: gate {'FAILED' if g.failed else 'passed'}: {g.describe()}", file=sys.stderr)
    if getattr(args, "junit", None):
        try:
            Path(args.junit).write_bytes(junit_xml(gates, manifest, metrics))
        except OSError as e:
            raise CliError(EXIT_INPUT, f"cannot write --junit {args.junit}: {e.strerror}")
    if failed:
        print(f"kiln: {len(failed)} of {len(gates)} gate{'s' if len(gates) != 1 else ''} failed "
              f"(bundle written to {args.out})", file=sys.stderr)
        return EXIT_GATES
    return code


def _check(r, code: int) -> dict:
    if r.status_code < 400:
        return r.json()
    try:
        err = r.json()["error"]
        msg = f"{err['code']}: {err['message']}"
    except Exception:
        msg = f"HTTP {r.status_code}"
    raise CliError(code if r.status_code < 500 else EXIT_SERVER, f"server refused ({r.status_code}): {msg}")


def _follow(c, bake_id: str, prog: Progress) -> dict:
    """Follow the bake over SSE until it ends; returns the final bake."""
    import httpx

    try:
        with c.stream("GET", f"/v1/bakes/{bake_id}/events", timeout=httpx.Timeout(None, connect=10.0)) as r:
            event = None
            for line in r.iter_lines():
                if line.startswith("event:"):
                    event = line[6:].strip()
                elif line.startswith("data:") and event in ("progress", "status"):
                    snap = json.loads(line[5:])
                    if prog.total != len(snap["stages"]):
                        prog.set_total(len(snap["stages"]))
                    for s in snap["stages"]:
                        prog.update(s["name"], s["progress"] if s["status"] != "succeeded" else 1.0)
                    if event == "status":
                        break
    except httpx.HTTPError:
        pass  # fall back to polling below
    while True:
        b = _check(c.get(f"/v1/bakes/{bake_id}"), EXIT_SERVER)
        if b["status"] in ("succeeded", "failed", "cancelled"):
            return b
        time.sleep(0.5)


def _extract(zpath: Path, out: Path) -> None:
    import zipfile

    with zipfile.ZipFile(zpath) as z:
        for m in z.infolist():
            name = Path(m.filename)
            if name.is_absolute() or ".." in name.parts or len(name.parts) != 1:
                raise CliError(EXIT_SERVER, f"the bundle holds an unexpected path {m.filename!r}")
            from proto.atomic import atomic_write_bytes
            atomic_write_bytes(out / name.name, z.read(m))


# --------------------------------------------------------------------------- other commands


def cmd_serve(args) -> int:
    from server.config import is_loopback
    from server.supervisor import serve

    _refuse_open_public(args.host, is_loopback)
    return serve(args.host, args.port, args.workers, Path(args.data), os.environ.get("REDIS_URL"))


def _refuse_open_public(host: str, is_loopback) -> None:
    from server.config import get_settings

    try:
        settings = get_settings()
    except Exception as e:
        raise CliError(EXIT_USAGE, f"bad settings: {_settings_error(e)}")
    if settings.open:
        print("kiln: WARNING: no API keys configured (KILN_API_KEYS): the server is open", file=sys.stderr)
        if not is_loopback(host):
            raise CliError(EXIT_USAGE, f"refusing to bind {host} with no API keys; set KILN_API_KEYS=team:key,... "
                                       "or bind 127.0.0.1")


def _settings_error(e: Exception) -> str:
    """A settings error in one line, naming the variable (a ValidationError's own text spans lines)."""
    errs = getattr(e, "errors", None)
    if callable(errs):
        parts = []
        for err in errs():
            loc = ".".join(str(x) for x in err.get("loc", ()))
            msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
            parts.append(msg if not loc or msg.startswith("KILN_") else f"KILN_{loc.upper()}: {msg}")
        return "; ".join(parts)
    return str(e)


def cmd_api(args) -> int:
    import uvicorn

    from server.config import Settings, export_env, is_loopback
    from server.main import create_app

    _refuse_open_public(args.host, is_loopback)
    settings = Settings(data=Path(args.data).resolve(), redis_url=os.environ.get("REDIS_URL"))
    if not settings.redis_url:
        raise CliError(EXIT_USAGE, "kiln api needs REDIS_URL (kiln serve starts an embedded Redis)")
    export_env(settings)
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level="info")
    return EXIT_OK


WORKER_NICE = 10
"""Default niceness of a worker process and its work-horses: on a machine shared with the API (``kiln serve``),
bakes yield the CPU to HTTP requests (``bench_service.py`` measures GET p99 at nice 0 and at this)."""


def _lower_priority(nice: int | None) -> None:
    """Set this process's niceness to ``nice`` (inherited by RQ's forked work-horses); 0 leaves it alone.

    ``None``: ``KILN_WORKER_NICE``, else :data:`WORKER_NICE`. Never raises the priority above what it is.
    """
    if nice is None:
        env = os.environ.get("KILN_WORKER_NICE", str(WORKER_NICE))
        try:
            nice = int(env)
        except ValueError:
            raise CliError(EXIT_USAGE, f"KILN_WORKER_NICE must be an integer in 0..19, got {env!r}") from None
    if not 0 <= nice <= 19:
        raise CliError(EXIT_USAGE, f"the worker's niceness must be in 0..19, got {nice}")
    if nice == 0:
        return
    try:
        os.setpriority(os.PRIO_PROCESS, 0, max(nice, os.getpriority(os.PRIO_PROCESS, 0)))
    except OSError as e:  # not permitted here: run at the priority we have
        print(f"kiln worker: could not set niceness {nice}: {e}", file=sys.stderr)


def cmd_worker(args) -> int:
    _lower_priority(args.nice)   # first, before the imports: the worker never runs a job at full priority
    import socket

    import workers.jobs  # (imported before forking, so work-horses start warm)
    from server.queue import LEGACY_QUEUE, LONG_QUEUE, SHORT_QUEUE, connect

    url = os.environ.get("REDIS_URL")
    if not url:
        raise CliError(EXIT_USAGE, "kiln worker needs REDIS_URL")
    if args.data:
        os.environ["KILN_DATA"] = str(Path(args.data).resolve())
    if not os.environ.get("KILN_DATA"):
        raise CliError(EXIT_USAGE, "kiln worker needs --data or KILN_DATA")
    names = {"short": SHORT_QUEUE, "long": LONG_QUEUE}
    wanted = [q.strip() for q in (args.queues or "short,long").split(",") if q.strip()]
    if not wanted or any(q not in names for q in wanted):
        raise CliError(EXIT_USAGE, f"--queues takes short, long or short,long; got {args.queues!r}")
    queues = [names[q] for q in wanted]
    if LONG_QUEUE in queues:
        queues.append(LEGACY_QUEUE)   # jobs left by an earlier version's single queue
    conn = connect(url)
    w = workers.jobs.make_worker(queues, conn, name=f"kiln-{socket.gethostname()}-{os.getpid()}")
    w.work(burst=args.burst, logging_level="WARNING")
    return EXIT_OK


def cmd_scenes_make(args) -> int:
    from workers.procedural import ALL_SCENES as SCENES, write_scene

    if args.name not in SCENES:
        raise CliError(EXIT_USAGE, f"unknown scene {args.name!r}; choose from {', '.join(sorted(SCENES))}")
    write_scene(args.name, args.out)
    print(f"wrote {args.name} to {args.out}", file=sys.stderr)
    return EXIT_OK


def cmd_scenes_list(args) -> int:
    from workers.procedural import ALL_SCENES as SCENES

    for name, desc in sorted(SCENES.items()):
        print(f"{name:12s} {desc}")
    return EXIT_OK


def cmd_schema(args) -> int:
    from proto.export_schema import schema_text

    text = schema_text()
    if args.out:
        Path(args.out).write_text(text)
    else:
        sys.stdout.write(text)
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="kiln", description="Kiln: bake leak-free, relightable probe GI from glTF.")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("serve", help="run the service: embedded Redis (unless REDIS_URL), workers, HTTP API + page")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--workers", type=int, default=2, choices=range(1, 65), metavar="N")
    s.add_argument("--data", default=os.environ.get("KILN_DATA", "data"), help="data directory (default ./data)")
    s.set_defaults(fn=cmd_serve)

    s = sub.add_parser("api", help="run only the HTTP API (needs REDIS_URL)")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--data", default=os.environ.get("KILN_DATA", "data"))
    s.set_defaults(fn=cmd_api)

    s = sub.add_parser("worker", help="run one RQ worker (needs REDIS_URL)")
    s.add_argument("--data", default=None, help="data directory (or KILN_DATA)")
    s.add_argument("--burst", action="store_true", help="exit when the queue is empty")
    s.add_argument("--queues", default=None,
                   help="queues to take jobs from, in order: short,long (default), short, or long "
                        "(kiln-short: most stages; kiln-long: prt and stages estimated long)")
    s.add_argument("--nice", type=int, default=None,
                   help=f"niceness 0..19 of the worker and its work-horses (default {WORKER_NICE}, or "
                        "KILN_WORKER_NICE): bakes yield the CPU to the API on a shared machine")
    s.set_defaults(fn=cmd_worker)

    s = sub.add_parser("bake", help="bake a scene into a bundle (in-process, or through --server)")
    s.add_argument("scene", help=".glb, .gltf or .zip")
    s.add_argument("--config", help="bake config (TOML, or JSON by extension)")
    s.add_argument("--preset", choices=list(load_presets()) or None, default=None,
                   help="start from a preset of proto/presets.json (preview: seconds; medium: the defaults; "
                        "production: denser grid, more rays); values --config gives win over the preset's")
    s.add_argument("--out", required=True, help="output directory for the bundle")
    s.add_argument("--json", action="store_true", help="print only the manifest as JSON on stdout")
    s.add_argument("--server", help="bake through a Kiln server at this URL instead of in-process")
    s.add_argument("--api-key", default=os.environ.get("KILN_API_KEY"), help="API key for --server")
    s.add_argument("--cache", default=str(_default_cache()), help="stage cache directory (in-process bakes)")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="in-process bakes: stages run side by side, at most N at once (default 2; 1: one after "
                        "the other, as little memory as possible); each stage starts when the stages it reads are done")
    s.add_argument("--strict", action="store_true",
                   help=f"exit {EXIT_WARNINGS} when the bake has any warning (the bundle is still written)")
    s.add_argument("--fail-on", action="append", default=[], metavar="GATE",
                   help=f"exit {EXIT_GATES} when this holds for the bake's metrics, e.g. 'mask_normalized.leak > 0.05' "
                        "(METRIC OP NUMBER, OP one of > >= < <= == !=, '*' matches any text; repeatable; a gate "
                        "naming no metric fails too)")
    s.add_argument("--junit", metavar="FILE", help="write JUnit XML: a test case per gate and per GI mode")
    s.set_defaults(fn=lambda a: bake_remote(a) if a.server else bake_local(a))

    s = sub.add_parser("scenes", help="procedural test scenes")
    ss = s.add_subparsers(dest="scenes_cmd", required=True)
    m = ss.add_parser("make", help="write a procedural scene as .glb")
    m.add_argument("name")
    m.add_argument("out")
    m.set_defaults(fn=cmd_scenes_make)
    ls = ss.add_parser("list", help="list the procedural scenes")
    ls.set_defaults(fn=cmd_scenes_list)

    s = sub.add_parser("schema", help="print the bake config's JSON Schema")
    s.add_argument("--out")
    s.set_defaults(fn=cmd_schema)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.fn(args)
    except CliError as e:
        print(f"kiln: error: {e.message}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("kiln: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a bug: still one line, and a non-zero exit
        print(f"kiln: internal error: {type(e).__name__}: {e}", file=sys.stderr)
        if os.environ.get("KILN_DEBUG"):
            raise
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
