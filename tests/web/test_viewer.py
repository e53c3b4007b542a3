"""The web app in a real browser against a real `kiln serve`: upload, bake, every GI mode on screen, debug
views, refusals shown in words, the dashboard and the compare view.

Pixels are checked, not just the DOM: a blank or black canvas fails. Screenshots are saved under the
pytest tmp dir (the `shots` fixture prints where) so a person can look at them.
"""
from __future__ import annotations

import io
import re
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from tests.conftest import UNLIT
from tests.web.conftest import ROOT

pytestmark = pytest.mark.timeout(240)

# A fast bake that still exercises every stage: the automatic grid under the preview preset's budget (2,000 probes,
# not the default 24,000), coarser θ, fewer annealing sweeps, and the evaluation (on by default, as the dashboard
# tests want) at fewer paths and surface points.
FAST = {"place.budget": "2000", "visibility.samples_per_cell": "4", "masks.sweeps": "200", "evaluate.spp": "8",
        "evaluate.surface_points": "256"}


def _scene(tmp_path, name="two-rooms"):
    out = tmp_path / f"{name}.glb"
    r = subprocess.run([sys.executable, "-m", "server.cli", "scenes", "make", name, str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)


def _stats(img: np.ndarray) -> dict:
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    return {"mean": float(lum.mean()), "std": float(lum.std()), "lit": float((lum > 12).mean()),
            "levels": int(len(np.unique(lum.round())))}


def _assert_not_blank(img: np.ndarray, what: str):
    s = _stats(img)
    assert s["mean"] > 20 and s["std"] > 6 and s["lit"] > 0.3 and s["levels"] > 20, f"{what} looks blank or black: {s}"


def _shot(locator, path) -> np.ndarray:
    png = locator.screenshot()
    path.write_bytes(png)
    return _pixels(png)


def _frames(page) -> int:
    return int(page.get_attribute("#viewer-canvas", "data-frames") or 0)


def _after(page, action, mode: str):
    """Do `action`, then wait until `mode` is on screen in a frame drawn after it (the viewer renders on demand)."""
    n = _frames(page)
    action()
    page.wait_for_selector(f"#viewer-canvas[data-ready-mode={mode}]", timeout=60000)
    page.wait_for_function(
        f"(c => Number(c.dataset.frames) > {n} && c.dataset.shownMode === '{mode}')(document.getElementById('viewer-canvas'))",
        timeout=30000)


def _field(page, name: str):
    """The input of a config field, its folded sections opened (as a person clicks the section titles) and,
    for a field that is unset by default (automatic), its "set" box ticked."""
    sel = f'#config-form input[name="{name}"]'
    page.eval_on_selector(sel, """e => {
        for (let d = e.closest('details'); d; d = d.parentElement.closest('details')) d.open = true;
        const set = e.disabled && e.closest('.nullable')?.querySelector(':scope > label.set > input');
        if (set && !set.checked) set.click();
    }""")
    return page.locator(sel)


def _fill_config(page, values: dict):
    for name, value in values.items():
        _field(page, name).fill(value)


def _upload_and_bake(page, glb, config: dict, checks=()) -> str:
    page.goto("/")
    page.wait_for_selector("#config-form .config-form")
    page.set_input_files("#scene-file", str(glb))
    page.wait_for_selector("#upload-status.ok, #upload-status.error", timeout=30000)
    assert "ready" in page.inner_text("#upload-status"), page.inner_text("#upload-status")
    for name in checks:
        _field(page, name).check()
    _fill_config(page, config)
    page.click("#start-bake")
    page.wait_for_selector("#bake-status.ok, #bake-status.error", timeout=30000)
    status = page.inner_text("#bake-status")
    assert status.startswith("Bake "), status
    # this bake's card (the session's server lists earlier tests' bakes too)
    card = page.wait_for_selector(f'.bake-card[data-status=succeeded][data-bake^="{status.split()[1]}"]', timeout=120000)
    return card.get_attribute("data-bake")


def test_a_gltf_dropped_with_its_files_uploads_as_one_zip(page, kiln_server):
    """A .gltf with its .bin beside it, picked together (loader/pack.js zips them in the browser): the server reads
    the whole model; picked alone, the page says which file is missing."""
    from tests.conftest import shared_path

    model = shared_path("scenes", "cornell-box-mcguire-khr-lights", "CornellBox-Original.gltf")
    page.goto("/")
    page.wait_for_selector("#config-form .config-form")
    page.set_input_files("#scene-file", [str(model), str(model.with_suffix(".bin"))])
    page.wait_for_selector("#upload-status.ok, #upload-status.error", timeout=30000)
    text = page.inner_text("#upload-status")
    assert "CornellBox-Original.zip ready: 36 triangles, 1 light" in text, text
    page.set_input_files("#scene-file", [str(model), str(model.parent / "LICENSE.txt")])
    page.wait_for_selector("#upload-status.error", timeout=30000)
    text = page.inner_text("#upload-status")
    assert "buffer 0 'CornellBox-Original.bin' is not among the dropped files" in text, text


def test_bad_upload_and_bad_config_are_shown_in_words(page, tmp_path, kiln_server):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF" + (2).to_bytes(4, "little") + (10**9).to_bytes(4, "little") + b"\x00" * 40)
    page.goto("/")
    page.wait_for_selector("#config-form .config-form")
    page.set_input_files("#scene-file", str(bad))
    page.wait_for_selector("#upload-status.error", timeout=30000)
    text = page.inner_text("#upload-status")
    assert "Upload refused" in text and "truncated_glb" in text, text
    # a config the server refuses: the 422 message lands on the field it names
    page.set_input_files("#scene-file", str(_scene(tmp_path)))
    page.wait_for_selector("#upload-status.ok", timeout=30000)
    _field(page, "trace.rays_per_probe").fill("5")
    page.click("#start-bake")
    page.wait_for_selector("#bake-status.error", timeout=30000)
    field = page.locator('.field[data-path="trace.rays_per_probe"]')
    assert "has-error" in field.get_attribute("class")
    assert "greater than or equal to 16" in field.locator(".field-error").inner_text()
    assert not page.kiln_errors, page.kiln_errors


def test_upload_bake_and_view_every_mode(page, tmp_path, kiln_server, shots):
    bake_id = _upload_and_bake(page, _scene(tmp_path), FAST)
    stages = page.locator(f'.bake-card[data-bake="{bake_id}"] .stage')
    assert stages.count() >= 6 and all(s == "succeeded" for s in stages.evaluate_all("e => e.map(x => x.dataset.status)"))
    _after(page, lambda: page.click(f'a[data-open="{bake_id}"]'), "direct")
    page.wait_for_function("document.getElementById('stream-label').textContent === 'volumes loaded'", timeout=60000)
    canvas = page.locator("#viewer-canvas")

    available = page.locator("#mode-list button[data-available='1']").evaluate_all("e => e.map(x => x.dataset.mode)")
    assert {"direct", "leaking"} <= set(available), available
    images = {}
    for mode in available:
        _after(page, lambda: page.click(f"#mode-list button[data-mode={mode}]"), mode)
        images[mode] = _shot(canvas, shots / f"mode-{mode}.png")
        _assert_not_blank(images[mode], f"mode {mode}")
    # modes that cannot be shown say why and cannot be picked (PRT is off in the default config)
    for btn in page.locator("#mode-list button[data-available='0']").all():
        assert btn.is_disabled() and re.search(r"not baked|shader not written yet", btn.inner_text()), btn.inner_text()
    assert "not baked" in page.inner_text("#mode-list button[data-mode=prt]")
    d, lk = images["direct"], images["leaking"]
    diff = np.abs(d - lk).mean()
    assert diff > 4, f"direct and leaking look the same (mean abs difference {diff:.2f})"
    assert _stats(lk)["mean"] > _stats(d)["mean"] + 2, "the leaking probes add no light"
    _after(page, lambda: page.click("#mode-list button[data-mode=leaking]"), "leaking")
    frame = page.inner_text("#frame-time")
    assert re.match(r"\d+\.\d\d ms \((GPU timer query|wall clock)\)", frame), frame

    # the fly camera moves with the keyboard
    view = page.evaluate("window.kiln.viewer.viewState()")
    page.click("#cam-fly")
    before = page.evaluate("window.kiln.viewer.camera.position.toArray()")
    # hold W until the camera has moved 5 cm (frames take 0.2-0.5 s on SwiftShader: no fixed wait)
    page.keyboard.down("w")
    try:
        page.wait_for_function("b => { const a = window.kiln.viewer.camera.position.toArray();"
                               " return Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]) > 0.05; }",
                               arg=before, timeout=10000)
    finally:
        page.keyboard.up("w")
    after = page.evaluate("window.kiln.viewer.camera.position.toArray()")
    assert np.linalg.norm(np.subtract(after, before)) > 0.05, (before, after)
    page.click("#cam-orbit")
    # back to the first view: how far the held key flew depends on the frame time (0.5-1.6 s a frame on SwiftShader,
    # with the suite's other worker busy), and the views below must not (the clusters view needs both rooms in sight)
    page.evaluate("v => window.kiln.viewer.setView(v)", view)

    # indirect only: the SH volume itself, smooth and non-black
    _after(page, lambda: page.select_option("#viewer-output", "indirect"), "leaking")
    _assert_not_blank(_shot(canvas, shots / "leaking-indirect-only.png"), "indirect only")
    page.select_option("#viewer-output", "shaded")

    # probes coloured by state: ACTIVE green, and OFF red where the grid has probes inside walls (the
    # automatic grid fills the rooms' free space: it may have none)
    _after(page, lambda: page.check("#show-probes"), "leaking")
    img = _shot(canvas, shots / "probes-by-state.png")
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    assert ((g > 120) & (r < 90) & (b < 110)).sum() > 50, "no ACTIVE (green) probes on screen"
    n_off = page.evaluate("Array.from(window.kiln.viewer.artifacts.probe_states.data).filter(x => x === 0).length")
    if n_off > 20:
        assert ((r > 120) & (g < 80)).sum() > 50, f"no OFF (red) probes on screen ({n_off} in the grid)"
    _after(page, lambda: page.select_option("#probe-coloring", "sh"), "leaking")
    _shot(canvas, shots / "probes-by-sh.png")
    page.uncheck("#show-probes")

    # debug images: the irradiance atlas, the depth atlas, a θ slice and a slice of the dense masks
    for view, name in (("irradiance", "atlas-irradiance"), ("depth", "atlas-depth"), ("theta", "theta-slice"),
                       ("masks", "mask-slice")):
        page.select_option("#debug-view", view)
        page.wait_for_selector(f"#debug-image[data-view={view}]:not([hidden])", timeout=30000)
        img = _shot(page.locator("#debug-image"), shots / f"{name}.png")
        assert img.std() > 5, f"debug view {view} is flat"
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 2, "the mask slice has hardly any distinct colours"

    # the clusters view (MD Fig 2): probe spheres in a palette of 8 colours, >= 2 clusters on screen
    page.select_option("#debug-view", "clusters")
    page.wait_for_function("document.getElementById('debug-note').textContent.includes('coloured by cluster')")
    _after(page, lambda: page.evaluate("window.kiln.viewer.invalidate()"), "leaking")
    with_probes = _shot(canvas, shots / "probes-by-cluster.png")
    page.select_option("#debug-view", "")  # back to the colouring before (hidden probes)
    _after(page, lambda: page.evaluate("window.kiln.viewer.invalidate()"), "leaking")
    without = _pixels(canvas.screenshot())
    sphere = (np.abs(with_probes - without).sum(-1) > 40) & (with_probes.max(-1) > 60)
    palette = np.array([[.90, .10, .29], [.24, .71, .29], [.26, .39, .85], [1, .88, .10], [.96, .51, .19],
                        [.57, .12, .71], [.27, .94, .94], [.94, .20, .90]])
    chroma = with_probes[sphere] / with_probes[sphere].max(-1, keepdims=True)
    nearest = np.linalg.norm(chroma[:, None] - (palette / palette.max(-1, keepdims=True))[None], axis=-1)
    hits = np.bincount(nearest.argmin(1)[nearest.min(1) < 0.12], minlength=8)
    print("cluster colours on screen (pixels):", hits.tolist())
    assert (hits > 40).sum() >= 2, f"fewer than 2 cluster colours on screen: {hits.tolist()}"
    page.screenshot(path=str(shots / "viewer-page.png"))
    assert not page.kiln_errors, page.kiln_errors

    # the same bake opened in a fresh session: no scene file, the geometry comes from the bake's `scene`
    # artifact (tests/web/test_artist.py checks it in a new browser context)
    page.goto(f"/#/viewer/{bake_id}")
    page.reload()
    page.wait_for_selector("#viewer-canvas[data-ready-mode=direct]", timeout=60000)
    assert page.get_attribute("#viewer-canvas", "data-scene") == "server"
    assert "empty scene" not in page.inner_text("#viewer-note")
    page.wait_for_function("document.getElementById('stream-label').textContent === 'volumes loaded'", timeout=60000)
    _after(page, lambda: page.evaluate("window.kiln.viewer.invalidate()"), "direct")
    _assert_not_blank(_shot(canvas, shots / "fresh-session-scene.png"), "the bake in a fresh session")
    # every volume came from the Cache API this time (ETag = the sha256 the bake lists); only the scene GLB,
    # never fetched by the session that had the file, from the network
    stats = page.evaluate("window.kiln.viewer.loader.stats")
    assert stats["cached"] >= 5 and stats["network"] <= 1, stats


def test_dashboard_lists_bakes_and_compares_two(page, tmp_path, kiln_server, shots):
    glb = _scene(tmp_path)
    first = _upload_and_bake(page, glb, FAST)
    # a second bake of the same scene with another grid, through the form
    _fill_config(page, {"place.counts.0": "6", "place.counts.1": "4", "place.counts.2": "4"})
    page.click("#start-bake")
    page.wait_for_selector("#bake-status.ok", timeout=30000)
    second = page.inner_text("#bake-status").split()[1]
    page.wait_for_selector(f'.bake-card[data-status=succeeded][data-bake^="{second}"]', timeout=120000)

    page.goto("/#/dashboard")
    page.wait_for_selector("#bake-table tbody tr[data-bake]", timeout=30000)
    page.wait_for_function("document.querySelectorAll('#bake-table tbody tr[data-bake]').length >= 2", timeout=30000)
    ids = page.locator("#bake-table tbody tr[data-bake]").evaluate_all("e => e.map(x => x.dataset.bake)")
    assert first in ids and any(i.startswith(second) for i in ids)
    header = page.inner_text("#bake-table thead")
    for col in ("status", "place", "trace", "light", "visibility", "total", "artifact size", "probes"):
        assert col in header, header
    row = page.inner_text(f'#bake-table tr[data-bake="{first}"]')
    assert "succeeded" in row and "KiB" in row or "MiB" in row, row

    second_id = next(i for i in ids if i.startswith(second))
    page.check(f'input[data-pick="{first}"]')
    page.check(f'input[data-pick="{second_id}"]')
    page.wait_for_selector("#compare .compare-card >> nth=1")
    cards = page.locator("#compare .compare-card").evaluate_all("e => e.map(x => x.dataset.bake)")
    assert sorted(cards) == sorted([first, second_id])
    table = page.inner_text("#compare-table")
    assert "bake seconds" in table and "artifact size MiB" in table
    assert "place.counts" in page.inner_text("#config-delta")
    # evaluate is on by default: both bakes carry previews of the same review camera, side by side
    page.wait_for_selector("#compare-previews tbody tr[data-mode]", timeout=10000)
    assert page.locator("#compare-previews-none").count() == 0
    assert page.locator("#compare-previews tbody tr[data-mode] img").count() >= 2
    page.wait_for_selector("#chart[data-points] canvas", timeout=10000)
    assert int(page.get_attribute("#chart", "data-points")) >= 2
    page.screenshot(path=str(shots / "dashboard.png"), full_page=True)
    assert not page.kiln_errors, page.kiln_errors


def test_glsl_matches_the_python_kernels_on_the_gpu(page, kiln_server):
    """proto/glsl's sh.glsl, probe_grid.glsl (hardware trilinear filtering of RGBA32F volumes) and
    octahedral.glsl, run by this browser's WebGL2, give the numbers workers/kernels gave (proto/fixtures)."""
    import json

    fx = json.loads((ROOT / "proto" / "fixtures" / "expected.json").read_text())
    page.goto("/")
    page.wait_for_function("!!(window.kiln && window.kiln.glslParity)")
    got = page.evaluate("fx => window.kiln.glslParity(fx)", fx)
    s = fx["sh"]
    # shIrradianceL1 is the non-linear L1 reconstruction; the linear one is checked too
    np.testing.assert_allclose(np.asarray(got["sh"]).ravel(), s["irradiance_nonlinear"], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got["shLinear"]).ravel(), s["irradiance"], rtol=1e-5, atol=1e-5)
    want = [smp["irradiance_nonlinear"][str(n)] for smp in s["samples"] for n in range(len(s["normals"]))]
    # hardware filtering weights may be quantized (8 fractional bits on many GPUs): a looser tolerance
    np.testing.assert_allclose(np.asarray(got["trilinear"]), np.asarray(want), rtol=1e-2, atol=1e-2)
    l2 = fx["sh_l2"]                                   # L2: sh.glsl shIrradianceL2Packed, gi_grid.glsl padded stack
    np.testing.assert_allclose(np.asarray(got["shL2"]).ravel(), l2["irradiance"], rtol=1e-5, atol=1e-5)
    want2 = [smp["irradiance"][str(n)] for smp in l2["samples"] for n in range(len(l2["normals"]))]
    np.testing.assert_allclose(np.asarray(got["shL2Trilinear"]), np.asarray(want2), rtol=1e-2, atol=1e-2)
    o = fx["octahedral"]
    np.testing.assert_allclose(np.asarray(got["octEncode"]), o["encoded"], atol=1e-5)
    np.testing.assert_allclose(np.asarray(got["octDecode"]), o["decoded"], atol=1e-5)
    # a rectilinear grid (uGridLayers, probe_grid.glsl giGridIndex): GLSL = JavaScript = Python (grid_coord), at the
    # probes, between layers and past the outer layers
    from workers.kernels.grid import grid_coord

    r = got["rectilinear"]
    layers = [np.asarray(L, np.float64) for L in r["layers"]]
    counts = [len(L) for L in layers]
    py = grid_coord(np.asarray(r["points"]), counts, [L[0] for L in layers], [0.0] * 3, layers)
    for key in ("gridIndex", "uvw", "texel"):
        np.testing.assert_allclose(np.asarray(r[key]["glsl"]), np.asarray(r[key]["js"]), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(r["gridIndex"]["glsl"]), np.where(np.asarray(counts) > 1, py, 0.0),
                               rtol=1e-5, atol=1e-5)
    if r["shL2Trilinear"]["js"]:
        np.testing.assert_allclose(np.asarray(r["shL2Trilinear"]["glsl"]), np.asarray(r["shL2Trilinear"]["js"]),
                                   rtol=1e-2, atol=1e-2)


def test_api_key_streams_progress_without_eventsource_and_cancels(page_keys, tmp_path, kiln_server_keys, shots):
    """With an API key the app follows a bake by fetch-streaming the SSE endpoint (EventSource cannot send
    the Authorization header), can cancel it, and streams artifacts with the key."""
    from tests.web.conftest import API_KEY

    page = page_keys
    page.goto("/")
    page.wait_for_selector("#banner:text-matches('API key')", timeout=30000)
    page.fill("#api-key", API_KEY)
    page.press("#api-key", "Enter")
    page.wait_for_function("document.getElementById('banner').textContent === ''", timeout=30000)
    assert page.evaluate("localStorage.getItem('kiln-api-key')") == API_KEY
    page.wait_for_selector("#config-form .config-form")
    page.set_input_files("#scene-file", str(_scene(tmp_path)))
    page.wait_for_selector("#upload-status.ok", timeout=30000)
    # a slow bake: watch its stages move, then cancel it
    _fill_config(page, {"seed": "7", "place.counts.0": "24", "place.counts.1": "12", "place.counts.2": "12",
                        "trace.rays_per_probe": "2048"})
    page.click("#start-bake")
    card = page.wait_for_selector(".bake-card[data-status=running]", timeout=60000)
    bake_id = card.get_attribute("data-bake")
    page.wait_for_selector(f'.bake-card[data-bake="{bake_id}"] .stage[data-status=succeeded]', timeout=60000)
    page.click(f'button[data-cancel="{bake_id}"]')
    page.wait_for_selector(f'.bake-card[data-bake="{bake_id}"][data-status=cancelled]', timeout=30000)
    assert kiln_server_keys.api(f"/v1/bakes/{bake_id}", headers={"Authorization": f"Bearer {API_KEY}"})["status"] == "cancelled"
    # the events went through fetch with the header, never EventSource (a resource-timing entry appears
    # once the stream has closed, after the final status event)
    page.wait_for_function("performance.getEntriesByType('resource').some(e => e.name.includes('/events'))",
                           timeout=30000)
    used = page.evaluate("performance.getEntriesByType('resource').filter(e => e.name.includes('/events')).map(e => e.initiatorType)")
    assert used and set(used) == {"fetch"}, used
    # a quick bake to the end, then its volumes with the key
    _fill_config(page, {"seed": "8", "place.counts.0": "8", "place.counts.1": "8", "place.counts.2": "8",
                        "trace.rays_per_probe": "256", **FAST})
    page.click("#start-bake")
    page.wait_for_selector("#bake-status.ok", timeout=30000)
    short = page.inner_text("#bake-status").split()[1]
    page.wait_for_selector(f'.bake-card[data-status=succeeded][data-bake^="{short}"]', timeout=120000)
    _after(page, lambda: page.click(f'.bake-card[data-bake^="{short}"] a[data-open]'), "direct")
    _after(page, lambda: page.click("#mode-list button[data-mode=leaking]"), "leaking")
    _assert_not_blank(_shot(page.locator("#viewer-canvas"), shots / "api-key-leaking.png"), "leaking with an API key")
    assert not page.kiln_errors, page.kiln_errors


# The MD stages run in the default config (masks + compress); PRT small: 16 configurations, 32 points, 4 slots.
PRT = {**FAST, "prt.configurations": "16", "prt.measurement_points": "32", "prt.basis": "4", "prt.lightmap": "0"}
ALL_MODES = ("direct", "leaking", "ddgi", "mask", "mask_normalized", "prt")


def _look(page, position, target):
    page.evaluate("([p, t]) => { window.kiln.viewer.controls.lookAt(p, t); window.kiln.viewer.invalidate(); }",
                  [list(position), list(target)])


def _prt_expected(kiln_server, bake_id, light) -> np.ndarray:
    """u (n, 3) of workers/prt_relight for one light, with the browser's unshadowed direct vector."""
    import httpx

    from workers.kernels import prt as kprt
    from workers.kernels.shading import direct_irradiance

    from proto.bundle import load_artifact
    from proto.models import ArtifactInfo

    infos = {a["name"]: a for a in httpx.get(f"{kiln_server.url}/v1/bakes/{bake_id}", timeout=30).json()["artifacts"]}

    def array(name):      # KTX2 tables (npy in older bakes), in the manifest's shape
        r = httpx.get(f"{kiln_server.url}/v1/bakes/{bake_id}/artifacts/{name}", timeout=30)
        r.raise_for_status()
        return load_artifact(r.content, ArtifactInfo(**infos[name]))

    table, offsets, T = array("prt_points").astype(np.float64), array("prt_point_offsets"), array("prt_sh_transfer")
    sec = httpx.get(f"{kiln_server.url}/v1/bakes/{bake_id}/artifacts/prt", timeout=30).json()
    e = direct_irradiance(table[:, :3], table[:, 3:6], [light], None, 1e-3)  # caster None: unshadowed
    x = kprt.group_mean(table[:, 6:9] / np.pi * e, offsets.astype(np.int64))
    xa = np.concatenate([x, kprt.direct_norm(x, 0, sec.get("norm", "l2"))[None]], axis=0)   # ‖x‖: the bake's norm
    return np.einsum("cnm,mc->nc", T.astype(np.float64), xa)


def test_md_ddgi_and_prt_modes_and_relight(page, tmp_path, kiln_server, shots):
    """Every GI mode of a bake with the MD stages and PRT on screen; leaking leaks into room B where the
    visibility-aware modes do not; the PRT light gizmo relights with the server's transfer."""
    bake_id = _upload_and_bake(page, _scene(tmp_path), PRT, checks=["prt.enabled"])
    _after(page, lambda: page.click(f'a[data-open="{bake_id}"]'), "direct")
    page.wait_for_function("document.getElementById('stream-label').textContent === 'volumes loaded'", timeout=60000)
    canvas = page.locator("#viewer-canvas")
    available = page.locator("#mode-list button[data-available='1']").evaluate_all("e => e.map(x => x.dataset.mode)")
    assert set(ALL_MODES) <= set(available), available

    images = {}
    for mode in ALL_MODES:
        _after(page, lambda: page.click(f"#mode-list button[data-mode={mode}]"), mode)
        images[mode] = _shot(canvas, shots / f"md-{mode}.png")
        _assert_not_blank(images[mode], f"mode {mode}")
    assert not page.inner_text("#shader-error"), page.inner_text("#shader-error")
    for mode in ALL_MODES[1:]:
        diff = np.abs(images[mode] - images["direct"]).mean()
        assert diff > 2, f"{mode} looks like direct only (mean abs difference {diff:.2f})"
    assert page.get_attribute("#mode-list button[data-mode=prt]", "title").lower().count("unshadowed")

    # room B, looking at the shared wall from its far corner: only the door lets light in, leaking SH
    # volumes leak room A's light through the 5 cm wall
    _look(page, (7.8, 1.5, 3.8), (4.05, 1.2, 0.6))
    room_b, wall = {}, {}
    for mode in ("leaking", "ddgi", "mask", "mask_normalized"):
        _after(page, lambda: page.click(f"#mode-list button[data-mode={mode}]"), mode)
        img = _shot(canvas, shots / f"room-b-{mode}.png")
        room_b[mode] = _stats(img)["mean"]
        h, w = img.shape[:2]
        # the shared wall above and left of the door, room B side: no direct light reaches it
        wall[mode] = _stats(img[int(0.1 * h):int(0.4 * h), :int(0.2 * w)])["mean"]
    print("room B mean brightness:", room_b, "shared wall region:", wall)
    assert wall["leaking"] > wall["mask"] + 20, wall
    assert wall["leaking"] > wall["ddgi"] + 40, wall
    # normalized mask GI reads its masks in front of the wall (n + v), so it does not leak there either
    assert wall["leaking"] > wall["mask_normalized"] + 40, wall
    assert room_b["leaking"] > room_b["mask"] + 3, room_b

    # PRT relight: move the light into room B; the browser's coefficients match numpy's, room B lights up
    _after(page, lambda: page.click("#mode-list button[data-mode=prt]"), "prt")
    before = _shot(canvas, shots / "room-b-prt-light-a.png")
    light = page.evaluate("window.kiln.viewer.prt.light")
    got = np.asarray(page.evaluate("Array.from(window.kiln.viewer.prt.u)")).reshape(-1, 3)
    np.testing.assert_allclose(got, _prt_expected(kiln_server, bake_id, light), rtol=1e-4, atol=1e-6)
    _after(page, lambda: page.evaluate("window.kiln.viewer.setPrtLight([6.0, 2.4, 2.0])"), "prt")
    after = _shot(canvas, shots / "room-b-prt-light-b.png")
    light = page.evaluate("window.kiln.viewer.prt.light")
    assert light["position"] == [6.0, 2.4, 2.0]
    got = np.asarray(page.evaluate("Array.from(window.kiln.viewer.prt.u)")).reshape(-1, 3)
    np.testing.assert_allclose(got, _prt_expected(kiln_server, bake_id, light), rtol=1e-4, atol=1e-6)
    assert _stats(after)["mean"] > _stats(before)["mean"] + 10, (_stats(before), _stats(after))
    _assert_not_blank(after, "prt with the light in room B")
    assert not page.kiln_errors, page.kiln_errors


EVAL = {"evaluate": {"enabled": True, "cameras": 1, "width": 64, "height": 48, "spp": 2, "repeats": 1, "flip": False},
        "place": {"counts": [6, 3, 4]}, "visibility": {"samples_per_cell": 4}}


def test_dashboard_compares_evaluate_previews(page, tmp_path, kiln_server, shots):
    """Two small bakes with the evaluate stage: the compare view shows their PNG previews side by side."""
    glb = _scene(tmp_path)
    with open(glb, "rb") as f:
        scene = kiln_server.api("/v1/scenes", "POST", files={"file": (glb.name, f, "model/gltf-binary")})
    ids = []
    for rays in (64, 32):
        cfg = {**EVAL, "trace": {"rays_per_probe": rays}}
        ids.append(kiln_server.api("/v1/bakes", "POST", json={"scene_id": scene["id"], "config": cfg})["id"])
    for i in ids:
        b = kiln_server.wait_bake(i, timeout=150)   # under pytest-timeout's 240 s, so a stall prints its stages
        assert b["status"] == "succeeded", b.get("error")
    page.goto(f"/#/dashboard?scene={scene['id']}")
    for i in ids:
        page.wait_for_selector(f'input[data-pick="{i}"]', timeout=30000)
        page.check(f'input[data-pick="{i}"]')
    page.wait_for_selector("#compare-previews img", timeout=10000)
    loaded = "e => e.filter(i => i.complete && i.naturalWidth > 0).length"
    page.wait_for_function(f"({loaded})([...document.querySelectorAll('#compare-previews img')]) >= 2", timeout=20000)
    imgs = page.locator("#compare-previews img")
    widths = imgs.evaluate_all("e => e.map(i => i.naturalWidth)")
    assert sum(w > 0 for w in widths) >= 2, widths
    # the first row's two previews, each decoded (the wait above may have counted two images of other rows)
    first = "[...document.querySelectorAll('#compare-previews tbody tr:first-child img')]"
    page.wait_for_function(f"({loaded})({first}) >= 2", timeout=20000)
    row = page.locator("#compare-previews tbody tr").first
    assert row.locator("img").count() >= 2 and all(w > 0 for w in row.locator("img").evaluate_all("e => e.map(i => i.naturalWidth)"))
    assert page.locator("#compare-previews img[data-artifact$=_error]").count() >= 2  # the error heatmaps
    # large enough to read, and full size on a click
    shown = imgs.evaluate_all("e => e.map(i => i.getBoundingClientRect().width)")
    assert min(shown) >= 200, shown  # four columns side by side on a 1280 px page (was ~120 px)
    imgs.first.click()
    page.wait_for_selector("#image-zoom:not([hidden])")
    assert page.evaluate("document.getElementById('image-zoom-img').getBoundingClientRect().width") >= 600
    page.click("#image-zoom")
    page.wait_for_selector("#image-zoom[hidden]", state="attached")
    page.locator("#compare").screenshot(path=str(shots / "compare-previews.png"))
    assert not page.kiln_errors, page.kiln_errors


def test_bake_warnings_on_the_card_the_dashboard_and_the_viewer(page, tmp_path, kiln_server, shots):
    glb = _scene(tmp_path)
    sid = kiln_server.api("/v1/scenes", "POST", content=glb.read_bytes(), headers={"X-Filename": glb.name})["id"]
    bid = kiln_server.api("/v1/bakes", "POST", json={"scene_id": sid, "config": UNLIT})["id"]
    b = kiln_server.wait_bake(bid)
    assert b["status"] == "succeeded" and "unlit_scene" in [w["code"] for w in b["warnings"]], b
    n = len(b["warnings"])

    # the bake card on the upload & bake page: a count badge and the messages
    page.goto("/")
    card = f'.bake-card[data-bake="{bid}"]'
    page.wait_for_selector(f"{card} ul.bake-warnings li", timeout=30000)
    assert page.inner_text(f"{card} .warn-badge") == f"⚠ {n} warning{'s' if n != 1 else ''}"
    items = page.locator(f"{card} ul.bake-warnings li")
    assert items.count() == n
    text = page.inner_text(f"{card} ul.bake-warnings")
    assert "unlit_scene" in text and "nothing lights the scene" in text, text
    assert page.get_attribute(card, "data-warnings") == str(n)

    # the dashboard's row
    page.goto("/#/dashboard")
    row = f'#bake-table tr[data-bake="{bid}"]'
    page.wait_for_selector(f"{row} ul.bake-warnings", timeout=30000)
    assert "nothing lights the scene" in page.inner_text(row) and page.inner_text(f"{row} .warn-badge").startswith("⚠")

    # the viewer: a banner listing them above the canvas
    page.goto(f"/#/viewer/{bid}")
    page.wait_for_selector("#viewer-warnings:not([hidden]) ul.bake-warnings li", timeout=30000)
    banner = page.inner_text("#viewer-warnings")
    assert f"{n} warning" in banner and "unlit_scene" in banner and "nothing lights the scene" in banner, banner
    page.screenshot(path=str(shots / "warnings-viewer.png"))
    # a lit bake of the same scene: no unlit_scene, and the banner shows exactly that bake's warnings
    lit = kiln_server.wait_bake(kiln_server.api("/v1/bakes", "POST", json={
        "scene_id": sid, "config": {**UNLIT, "scene": {"sky": [0.3, 0.3, 0.3]}}})["id"])
    assert lit["status"] == "succeeded" and "unlit_scene" not in [w["code"] for w in lit["warnings"]]
    page.goto(f"/#/viewer/{lit['id']}")
    page.wait_for_selector(f"#viewer-header h2:has-text('{lit['id'][:10]}')", timeout=30000)
    assert page.get_attribute("#viewer-warnings", "data-warnings") == str(len(lit["warnings"]))
    assert (page.get_attribute("#viewer-warnings", "hidden") is not None) == (not lit["warnings"])
    assert "nothing lights the scene" not in page.inner_text("#page-viewer")
    assert not page.kiln_errors, page.kiln_errors


def test_viewer_ddgi_bias_is_the_bakes(page, tmp_path, kiln_server):
    """Change B (light.self_shadow_bias, DDGI-P eq 2) in a bake: the viewer's uDdgiBias, read back from the page, is
    the one the evaluate pass binds for that bake (workers/render/shading.py prepare_mode on the bake's artifacts
    with its config's B), and not the default B's. Both read proto/gi_modes.json; either ignoring the bake's B fails."""
    import httpx

    from proto import gi_modes
    from proto.bundle import load_artifact
    from proto.models import ArtifactInfo, BakeConfig
    from workers.render.shading import prepare_mode

    glb = _scene(tmp_path)
    with open(glb, "rb") as f:
        scene = kiln_server.api("/v1/scenes", "POST", files={"file": (glb.name, f, "model/gltf-binary")})
    cfg = {"place": {"counts": [6, 3, 4]}, "trace": {"rays_per_probe": 32}, "light": {"self_shadow_bias": 0.8},
           "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 10}, "evaluate": {"enabled": False}}
    bake_id = kiln_server.api("/v1/bakes", "POST", json={"scene_id": scene["id"], "config": cfg})["id"]
    bake = kiln_server.wait_bake(bake_id, timeout=150)
    assert bake["status"] == "succeeded", bake.get("error")
    B = BakeConfig.model_validate(bake["config"]).light.self_shadow_bias   # what the evaluate stage reads
    assert B == 0.8
    arts = {a["name"]: a for a in bake["artifacts"]}
    place = next(st["stats"] for st in bake["stages"] if st["name"] == "place")
    grid = {k: place[k] for k in ("counts", "origin", "spacing")}

    def artifact(name):
        r = httpx.get(f"{kiln_server.url}/v1/bakes/{bake_id}/artifacts/{name}", timeout=30)
        r.raise_for_status()
        return load_artifact(r.content, ArtifactInfo(**arts[name]))

    arrays = {n: artifact(n) for n in ("irradiance", "depth_moments", "probe_positions_relocated", "probe_states")}
    python = prepare_mode("ddgi", arrays, grid, self_shadow_bias=B).uniforms["uDdgiBias"]
    default = prepare_mode("ddgi", arrays, grid).uniforms["uDdgiBias"]
    assert python == pytest.approx(default * 0.8 / gi_modes.SELF_SHADOW_BIAS) and python > default

    page.goto(f"/#/viewer/{bake_id}?mode=ddgi")
    page.wait_for_selector("#viewer-canvas[data-ready-mode=ddgi]", timeout=60000)
    viewer = page.evaluate("window.kiln.viewer.renderer.shared.uDdgiBias.value")
    assert viewer == pytest.approx(python, rel=1e-6), (viewer, python, default)
    assert not page.kiln_errors, page.kiln_errors


# Re-open the viewer on `bake` (its place stats given a `frame`, or not), turn the loaded scene by `yaw` degrees about
# +Y and look from `cam`; indirect light only (the GI lookup), fixed exposure, no light markers. Returns uGiFrame's
# elements and the probe spheres' positions with the bake's relocated positions.
_REOPEN = """async ([frame, yaw, cam]) => {
  const v = window.kiln.viewer;
  const bake = structuredClone(v.bake);
  const place = bake.stages.find((s) => s.name === 'place');
  if (frame) place.stats.frame = frame; else delete place.stats.frame;
  await v.open({ bake, sceneFile: null, camera: cam, mode: 'ddgi' });
  v.root.rotation.y = yaw * Math.PI / 180;
  v.root.updateMatrixWorld(true);
  v.showLightMarkers(false);
  v.set({ output: 'indirect', exposure: 0.7, probes: false });
  v.invalidate();
  const pos = v.artifacts.probe_positions_relocated;
  return { frame: Array.from(v.renderer.shared.uGiFrame.value.elements),
           spheres: Array.from(v.renderer.probeMesh.geometry.attributes.aProbePosition.array),
           relocated: Array.from(pos.data), stride: pos.components };
}"""


def test_viewer_turns_the_gi_lookup_by_the_bake_frame(page, tmp_path, kiln_server, shots):
    """A bake whose place stats carry grid.frame (M = R_y(30°)ᵀ, world -> bake), opened over its scene turned by
    R_y(30°) and seen from the turned camera, shows the same indirect light (ddgi: positions, normals and the view
    direction all enter) as the bake without a frame over the scene as baked: the viewer sets uGiFrame = M (identity
    without a frame) and draws the probe spheres at Mᵀ · (relocated position). The turned scene without the frame
    reads other cells: another picture."""
    glb = _scene(tmp_path)
    with open(glb, "rb") as f:
        scene = kiln_server.api("/v1/scenes", "POST", files={"file": (glb.name, f, "model/gltf-binary")})
    cfg = {"place": {"counts": [6, 3, 4]}, "trace": {"rays_per_probe": 32},
           "visibility": {"samples_per_cell": 2, "slabs": 1}, "masks": {"sweeps": 10}, "evaluate": {"enabled": False}}
    bake_id = kiln_server.api("/v1/bakes", "POST", json={"scene_id": scene["id"], "config": cfg})["id"]
    assert kiln_server.wait_bake(bake_id, timeout=150)["status"] == "succeeded"
    page.goto(f"/#/viewer/{bake_id}?mode=ddgi")
    page.wait_for_selector("#viewer-canvas[data-ready-mode=ddgi]", timeout=60000)
    canvas = page.locator("#viewer-canvas")

    t = np.radians(30.0)
    R = np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
    M = R.T
    frame = {"yaw_deg": 30.0, "matrix": M.tolist()}
    cam = {"position": [6.8, 1.7, 3.3], "target": [1.5, 1.0, 1.0], "fov_y": 60}
    turned = {"position": (R @ cam["position"]).tolist(), "target": (R @ cam["target"]).tolist(), "fov_y": 60}

    def shot(name, frame_, yaw, cam_):
        drawn = "k => Number(document.getElementById('viewer-canvas').dataset.frames) > k"
        n = _frames(page)
        out = page.evaluate(_REOPEN, [frame_, yaw, cam_])
        page.wait_for_function(drawn, arg=n, timeout=30000)
        page.evaluate("window.kiln.viewer.invalidate()")
        page.wait_for_function(drawn, arg=n + 1, timeout=30000)
        return out, _shot(canvas, shots / f"frame-{name}.png")

    plain, a = shot("none", None, 0.0, cam)
    framed, b = shot("yaw30", frame, 30.0, turned)
    _, c = shot("yaw30-without-frame", None, 30.0, turned)
    np.testing.assert_allclose(plain["frame"], np.eye(3).T.ravel(), atol=0)           # identity, never zero
    np.testing.assert_allclose(framed["frame"], M.T.ravel(), atol=1e-7)                # column-major: uGiFrame*p = M p
    k = framed["stride"]
    reloc = np.asarray(framed["relocated"]).reshape(-1, k)[:, :3]
    np.testing.assert_allclose(np.asarray(plain["spheres"]).reshape(-1, 3), reloc, atol=1e-6)
    np.testing.assert_allclose(np.asarray(framed["spheres"]).reshape(-1, 3), reloc @ M, atol=1e-5)  # rows: Mᵀ x
    _assert_not_blank(a, "ddgi indirect light")
    same, other = np.abs(b - a).mean(), np.abs(c - a).mean()
    print(f"mean abs difference: turned with the frame {same:.2f}, turned without it {other:.2f}")
    assert same < 1.5 and np.quantile(np.abs(b - a).max(axis=2), 0.98) <= 24, same
    assert other > 4 * same and other > 3, (same, other)
    assert not page.kiln_errors, page.kiln_errors


_REOPEN_LAYERS = """async ([keep, cam]) => {
  const v = window.kiln.viewer;
  const bake = structuredClone(v.bake);
  const place = bake.stages.find((s) => s.name === 'place');
  if (!keep) delete place.stats.layers;
  await v.open({ bake, sceneFile: null, camera: cam, mode: 'leaking' });
  v.showLightMarkers(false);
  v.set({ output: 'indirect', exposure: 0.7, probes: false });
  v.invalidate();
  const tex = v.renderer.shared.uGridLayers.value.image;
  return { rectilinear: v.renderer.shared.uGridRectilinear.value, width: tex.width, height: tex.height,
           texels: Array.from(tex.data) };
}"""


def test_viewer_reads_a_rectilinear_bake_through_its_layers(page, tmp_path, kiln_server, shots):
    """A real budget-bound bake (two-rooms at place.budget 400: the automatic grid turns rectilinear, autogrid step
    4b) opened in the viewer: its layers reach the shaders (uGridRectilinear, the uGridLayers texture holds the
    place stage's layers), the leaking volume lights the rooms, and the same bake read as a uniform grid (layers
    dropped: origin and mean spacing only) is another picture."""
    glb = _scene(tmp_path)
    with open(glb, "rb") as f:
        scene = kiln_server.api("/v1/scenes", "POST", files={"file": (glb.name, f, "model/gltf-binary")})
    cfg = {"place": {"budget": 400}, "trace": {"rays_per_probe": 32}, "light": {"bounces": 2},
           "visibility": {"samples_per_cell": 4, "slabs": 1}, "masks": {"sweeps": 10}, "evaluate": {"enabled": False}}
    bake_id = kiln_server.api("/v1/bakes", "POST", json={"scene_id": scene["id"], "config": cfg})["id"]
    assert kiln_server.wait_bake(bake_id, timeout=150)["status"] == "succeeded"
    bake = kiln_server.api(f"/v1/bakes/{bake_id}")
    layers = next(s for s in bake["stages"] if s["name"] == "place")["stats"]["layers"]
    page.goto(f"/#/viewer/{bake_id}?mode=leaking")
    page.wait_for_selector("#viewer-canvas[data-ready-mode=leaking]", timeout=60000)
    canvas = page.locator("#viewer-canvas")
    cam = {"position": [7.4, 1.6, 2.0], "target": [2.0, 1.2, 2.0], "fov_y": 70}

    def shot(name, keep):
        drawn = "k => Number(document.getElementById('viewer-canvas').dataset.frames) > k"
        n = _frames(page)
        out = page.evaluate(_REOPEN_LAYERS, [keep, cam])
        page.wait_for_function(drawn, arg=n, timeout=30000)
        page.evaluate("window.kiln.viewer.invalidate()")
        page.wait_for_function(drawn, arg=n + 1, timeout=30000)
        return out, _shot(canvas, shots / f"rectilinear-{name}.png")

    rect, a = shot("layers", True)
    uni, b = shot("uniform", False)
    assert rect["rectilinear"] is True and uni["rectilinear"] is False
    w = rect["width"]
    assert rect["height"] == 3 and w == max(len(L) for L in layers)
    tex = np.asarray(rect["texels"], np.float64).reshape(3, w)
    for ax in range(3):
        np.testing.assert_allclose(tex[ax, :len(layers[ax])], layers[ax], rtol=1e-6, atol=1e-6)
    _assert_not_blank(a, "leaking indirect light on a rectilinear grid")
    diff = np.abs(a - b).mean()
    print(f"mean abs difference, layers vs the same bake read as uniform: {diff:.2f}")
    assert diff > 2, diff
    assert not page.kiln_errors, page.kiln_errors
