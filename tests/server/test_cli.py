"""The ``kiln`` CLI as a build tool calls it: real processes, exit codes, stdout/stderr contracts.
Also ``kiln serve`` end to end: embedded Redis, workers, HTTP, and Ctrl-C leaving no orphans."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import httpx
import psutil
import pytest

from proto import bundle
from proto.models import PlaceSection
from tests.conftest import UNLIT, as_toml, shared_path, small_bake
from tests.serve_process import free_port, spawn_serve, stop_serve

KILN = [sys.executable, "-m", "server.cli"]


def kiln(*args, cwd=None, env=None, timeout=120):
    e = dict(os.environ, **(env or {}))
    return subprocess.run([*KILN, *map(str, args)], capture_output=True, text=True, cwd=cwd, env=e, timeout=timeout)


def test_scenes_make_and_list(tmp_path):
    r = kiln("scenes", "list")
    assert r.returncode == 0 and "two-rooms" in r.stdout and "sealed-box" in r.stdout
    r = kiln("scenes", "make", "sealed-box", tmp_path / "s.glb")
    assert r.returncode == 0 and (tmp_path / "s.glb").read_bytes()[:4] == b"glTF"
    r = kiln("scenes", "make", "nope", tmp_path / "x.glb")
    assert r.returncode == 2 and "unknown scene" in r.stderr and not (tmp_path / "x.glb").exists()


def test_bake_local_json_and_cache(tmp_path, scene_files):
    cache = tmp_path / "cache"
    cfg = tmp_path / "bake.toml"
    cfg.write_text(as_toml(small_bake(place={"counts": [4, 3, 5]})) + '[scene]\nsky = [0.5, 0.5, 0.5]\n'
                   '[[scene.lights]]\ntype = "directional"\ndirection = [0, -1, 0]\nintensity = 2.0\n')
    r = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out", "--json",
             "--cache", cache)
    assert r.returncode == 0, r.stderr
    manifest = json.loads(r.stdout)  # stdout is only the manifest
    assert [s["name"] for s in manifest["stages"]][:2] == ["ingest", "place"]
    assert all(s["cached"] is False for s in manifest["stages"])
    # progress went to stderr; not a terminal there (a captured pipe, as in CI): one line per finished stage, no
    # redrawn bar; stages run two at a time (each when what it reads is done), so the lines come in finishing order
    names = [s["name"] for s in manifest["stages"]]
    done = [ln for ln in r.stderr.splitlines() if ln.startswith("kiln: [")]
    assert sorted(ln.split("] ")[1].split(" done")[0] for ln in done) == sorted(names), r.stderr
    assert [ln.split("]")[0] for ln in done] == [f"kiln: [{i}/{len(names)}" for i in range(1, len(names) + 1)]
    assert "\r" not in r.stderr
    arts = {a["name"]: a for a in manifest["artifacts"]}
    assert arts["probe_positions"]["shape"] == [5, 3, 4, 3] and arts["probe_positions"]["format"] == "ktx2"
    m, arrays = bundle.open_bundle(tmp_path / "out")
    assert arrays["lights"]["sky"] == [0.5, 0.5, 0.5]
    assert [l["type"] for l in arrays["lights"]["lights"]] == ["point", "directional"]
    assert m.scene.triangles == manifest["scene"]["triangles"]
    # again: every stage from cache, identical artifacts; --jobs 1: one stage after the other, in run order
    r2 = kiln("bake", scene_files["two-rooms"], "--config", cfg, "--out", tmp_path / "out2", "--json",
              "--cache", cache, "--jobs", "1")
    m2 = json.loads(r2.stdout)
    done = [ln for ln in r2.stderr.splitlines() if ln.startswith("kiln: [")]
    assert [ln.split("] ")[1].split(" done")[0] for ln in done] == names, r2.stderr
    assert all(s["cached"] for s in m2["stages"])
    assert [a["sha256"] for a in m2["artifacts"]] == [a["sha256"] for a in manifest["artifacts"]]


def test_bake_local_real_scene(tmp_path):
    scene = shared_path("scenes", "cornell-box-mcguire-khr-lights", "CornellBox-Original.gltf")
    # a .gltf with its .bin beside it, as it lies on disk: the CLI packs the files it references
    # (workers/gltf/pack.py) and reads them through the zip path
    # the default grid (the default budget: the spacing the rooms ask for); the other sections cheap
    cfg = tmp_path / "small.json"
    cfg.write_text(json.dumps(small_bake(place={"budget": PlaceSection().budget})))
    r = kiln("bake", scene, "--config", cfg, "--out", tmp_path / "out", "--json", "--cache", tmp_path / "c",
             "--quiet")
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout)
    assert m["scene"]["lights"] == 1 and m["scene"]["triangles"] >= 30
    # the default grid is chosen from the scene (workers/kernels/autogrid.py) and says why
    auto = m["grid"]["auto"]
    assert 8 ** 3 < math.prod(m["grid"]["counts"]) <= auto["budget"] and "room scale" in auto["reason"]
    assert 4 <= auto["samples_per_cell"] <= 16


def _gltf_missing_bin(d):
    (d / "m.gltf").write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "gone%20away.bin",
                                                                                      "byteLength": 4}]}))
    return d / "m.gltf"


@pytest.mark.parametrize("make_input, code, words", [
    (lambda d: d / "missing.glb", 3, "no such file"),
    (_gltf_missing_bin, 3, "missing_resource: buffer 0 'gone away.bin' does not exist beside the model"),
    (lambda d: (d / "bad.glb").write_bytes(b"not a model at all") and d / "bad.glb", 3, "not_gltf"),
])
def test_bake_bad_scene_exit_codes(tmp_path, make_input, code, words):
    r = kiln("bake", make_input(tmp_path), "--out", tmp_path / "out", "--cache", tmp_path / "c")
    assert r.returncode == code
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kiln: error:") and words in lines[0]
    assert r.stdout == ""


def test_bake_bad_config_names_the_field(tmp_path, scene_files):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[place]\ncounts = [4, 4]\n")
    r = kiln("bake", scene_files["cornell"], "--config", cfg, "--out", tmp_path / "o", "--cache", tmp_path / "c")
    assert r.returncode == 3 and "place.counts" in r.stderr
    cfg.write_text("[plaec]\ncounts = [4, 4, 4]\n")
    r = kiln("bake", scene_files["cornell"], "--config", cfg, "--out", tmp_path / "o", "--cache", tmp_path / "c")
    assert r.returncode == 3 and "plaec: unknown field" in r.stderr
    cfg.write_text("[place\n")
    r = kiln("bake", scene_files["cornell"], "--config", cfg, "--out", tmp_path / "o", "--cache", tmp_path / "c")
    assert r.returncode == 3 and "not valid TOML" in r.stderr
    r = kiln("bake", scene_files["cornell"])
    assert r.returncode == 2  # --out is required
    r = kiln("bake", scene_files["cornell"], "--out", tmp_path / "o", "--cache", tmp_path / "c", "--jobs", "0")
    assert r.returncode == 2 and "--jobs must be at least 1" in r.stderr and not (tmp_path / "o").exists()


def test_serve_bake_through_server_and_ctrl_c(tmp_path, scene_files):
    proc, url = spawn_serve(tmp_path / "data", workers=2, log=tmp_path / "serve.log")
    try:
        kids = psutil.Process(proc.pid).children(recursive=True)
        names = " ".join(" ".join(k.cmdline()) for k in kids)
        assert "redis-server" in names and names.count("server.cli worker") >= 2
        # the workers (and so their forked work-horses) yield the CPU to the API: niceness 10
        workers = [k for k in kids if "server.cli worker" in " ".join(k.cmdline())]
        deadline = time.monotonic() + 30
        while any(w.nice() < 10 for w in workers):
            assert time.monotonic() < deadline, [w.nice() for w in workers]
            time.sleep(0.1)

        cfg = tmp_path / "small.json"                   # the automatic grid, small
        cfg.write_text(json.dumps(small_bake()))
        r = kiln("bake", scene_files["cornell"], "--server", url, "--config", cfg, "--out", tmp_path / "out",
                 "--json")
        assert r.returncode == 0, r.stderr
        m = json.loads(r.stdout)
        assert m["bake_id"] and [s["name"] for s in m["stages"]][:2] == ["ingest", "place"]
        n = len(m["stages"])                             # the server's progress, one line per finished stage
        assert f"kiln: [{n}/{n}] " in r.stderr and "\r" not in r.stderr, r.stderr
        _, arrays = bundle.open_bundle(tmp_path / "out")
        counts = m["grid"]["counts"]                     # the automatic grid, as the manifest says
        assert arrays["probe_positions"].shape == (counts[2], counts[1], counts[0], 3) and "auto" in m["grid"]
        # bad input through the server: a one-line reason, exit 3
        bad = tmp_path / "bad.glb"
        bad.write_bytes(b"glTF" + (2).to_bytes(4, "little") + (10**9).to_bytes(4, "little") + b"\x00" * 40)
        r = kiln("bake", bad, "--server", url, "--out", tmp_path / "o2")
        assert r.returncode == 3 and "truncated_glb" in r.stderr, r.stderr
        # the minimal page is served
        assert "Upload a scene" in httpx.get(url + "/").text
    finally:
        stop_serve(proc, strict=True)  # Ctrl-C
    time.sleep(0.5)
    alive = [k for k in kids if k.is_running() and k.status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"orphans left running: {[k.cmdline() for k in alive]}"
    assert proc.returncode in (0, 130)  # 130: the conventional status after Ctrl-C (uvicorn re-raises SIGINT)


@pytest.mark.parametrize("args, env, words", [
    (["--nice", "25"], {}, "must be in 0..19, got 25"),
    ([], {"KILN_WORKER_NICE": "high"}, "KILN_WORKER_NICE must be an integer"),
])
def test_worker_bad_niceness(tmp_path, args, env, words):
    r = kiln("worker", "--data", tmp_path / "d", *args, env={"REDIS_URL": "unix:///nonexistent", **env}, timeout=60)
    assert r.returncode == 2 and words in r.stderr, r.stderr


def test_serve_refuses_open_public_bind(tmp_path):
    env = {"KILN_API_KEYS": ""}
    r = kiln("serve", "--host", "0.0.0.0", "--data", tmp_path / "d", env=env, timeout=30)
    assert r.returncode == 2 and "refusing to bind" in r.stderr


def test_bake_server_unreachable(tmp_path, scene_files):
    r = kiln("bake", scene_files["cornell"], "--server", f"http://127.0.0.1:{free_port()}", "--out", tmp_path / "o")
    assert r.returncode == 5 and "cannot talk to" in r.stderr


UNLIT_TOML = as_toml(UNLIT)


def _warning_lines(stderr: str) -> list[str]:
    return [l for l in stderr.splitlines() if l.startswith("kiln: warning [")]


def test_bake_warnings_on_stderr_and_strict_exit_code(tmp_path, scene_files):
    cfg = tmp_path / "unlit.toml"
    cfg.write_text(UNLIT_TOML)
    common = ("--config", cfg, "--cache", tmp_path / "cache", "--quiet")
    r = kiln("bake", scene_files["two-rooms"], *common, "--out", tmp_path / "o1", "--json")
    assert r.returncode == 0, r.stderr
    manifest = json.loads(r.stdout)  # stdout is still only the manifest, now with its warnings
    assert [w["code"] for w in manifest["warnings"]] == ["unlit_scene"]
    lines = _warning_lines(r.stderr)
    assert len(lines) == 1 and lines[0].startswith("kiln: warning [unlit_scene] nothing lights the scene"), r.stderr
    # --strict: exit 6, the bundle still written (and the warnings still printed)
    r = kiln("bake", scene_files["two-rooms"], *common, "--out", tmp_path / "o2", "--strict")
    assert r.returncode == 6, r.stderr
    assert _warning_lines(r.stderr) == lines and "--strict" in r.stderr
    m, _ = bundle.open_bundle(tmp_path / "o2")
    assert [w.code for w in m.warnings] == ["unlit_scene"]
    # a bake without warnings passes --strict
    cfg.write_text(UNLIT_TOML.replace("sky = [0, 0, 0]", "sky = [0.3, 0.3, 0.3]"))
    r = kiln("bake", scene_files["two-rooms"], *common, "--out", tmp_path / "o3", "--strict")
    assert r.returncode == 0 and not _warning_lines(r.stderr), r.stderr


def test_bake_warnings_through_the_server(tmp_path, scene_files):
    cfg = tmp_path / "unlit.toml"
    cfg.write_text(UNLIT_TOML)
    proc, url = spawn_serve(tmp_path / "data", workers=1, log=tmp_path / "serve.log")
    try:
        r = kiln("bake", scene_files["two-rooms"], "--server", url, "--config", cfg, "--out", tmp_path / "o1",
                 "--json", "--quiet")
        assert r.returncode == 0, r.stderr
        assert [w["code"] for w in json.loads(r.stdout)["warnings"]] == ["unlit_scene"]
        lines = _warning_lines(r.stderr)
        assert len(lines) == 1 and lines[0].startswith("kiln: warning [unlit_scene] "), r.stderr
        r = kiln("bake", scene_files["two-rooms"], "--server", url, "--config", cfg, "--out", tmp_path / "o2",
                 "--strict", "--quiet")
        assert r.returncode == 6 and _warning_lines(r.stderr) == lines, r.stderr
        assert (tmp_path / "o2" / "manifest.json").exists()
    finally:
        stop_serve(proc)


def test_progress_is_a_bar_on_a_terminal_and_lines_elsewhere(capsys):
    from server.cli import Progress

    for interactive in (True, False):
        p = Progress(["ingest", "light"], interactive=interactive)
        for stage in ("ingest", "light"):
            p.update(stage, 0.5)
            p.update(stage, 1.0)
            p.update(stage, 1.0)                   # a repeated final report prints nothing more
        p.close()
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.startswith("kiln: [")]
        if interactive:
            assert "stages" in err and "\r" in err and not lines     # tqdm's redrawn bar
        else:
            assert [ln.split(" (")[0] for ln in lines] == ["kiln: [1/2] ingest done", "kiln: [2/2] light done"]
            assert "\r" not in err
    p = Progress(["ingest"], enabled=False, interactive=False)    # --quiet
    p.update("ingest", 1.0)
    p.close()
    assert capsys.readouterr().err == ""
