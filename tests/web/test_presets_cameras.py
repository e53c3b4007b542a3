"""Presets in the bake form and review cameras in the viewer, in a real browser against a real `kiln serve`:
choosing a preset fills the form and the server's estimate follows (the numbers shown); a bake of a closed scene
opened in a NEW browser context starts at the scene's first review camera, inside the room, looking at geometry
(pixel statistics against the background); the camera list jumps between views (the pixels change); "Save this
view as a review camera" appends the view to GET /v1/scenes/{id}/cameras.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tests.web.conftest import ROOT, _new_page
from tests.web.test_viewer import _after, _field, _scene, _shot, _stats

pytestmark = pytest.mark.timeout(300)

PRESETS = {p["id"]: p for p in json.loads((ROOT / "proto" / "presets.json").read_text())["presets"]}
ROOM = np.array([[0.0, 0.0, 0.0], [4.0, 2.5, 3.0]])   # the metal-room's inside (workers/procedural.py)


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


@pytest.fixture(scope="module")
def room(kiln_server, tmp_path_factory):
    """The metal-room (a closed room: no other browser test uses it, so its review cameras are ours), baked with
    the preview preset plus a small evaluation (the evaluate stage places the review cameras)."""
    glb = _scene(tmp_path_factory.mktemp("presets-cameras"), "metal-room")
    sid = kiln_server.api("/v1/scenes", "POST", content=glb.read_bytes(), headers={"X-Filename": glb.name})["id"]
    kiln_server.api(f"/v1/scenes/{sid}/cameras", "PUT", json={"cameras": []})   # automatic cameras, whatever ran before
    config = _merge(PRESETS["preview"]["config"],
                    {"evaluate": {"enabled": True, "cameras": 3, "surface_points": 256, "spp": 8, "previews": 0}})
    b = kiln_server.api("/v1/bakes", "POST", json={"scene_id": sid, "config": config})
    b = kiln_server.wait_bake(b["id"], timeout=240)
    assert b["status"] == "succeeded", b.get("error")
    cams = kiln_server.api(f"/v1/scenes/{sid}/cameras")
    assert cams["source"] == "auto" and len(cams["cameras"]) >= 2, cams
    return {"glb": glb, "scene": sid, "bake": b["id"], "cameras": cams["cameras"]}


def _estimate(page) -> dict:
    d = page.eval_on_selector("#bake-estimate", "e => ({...e.dataset, text: e.textContent})")
    m = re.search(r"(\d+) probes", d["text"])
    assert m and d["text"].startswith("Estimate:"), d["text"]
    assert int(m.group(1)) == int(d["probes"]), d   # the number shown is the server's
    return {"probes": int(d["probes"]), "seconds": float(d["seconds"]), "memory": int(d["peakMemoryBytes"]),
            "bytes": int(d["artifactBytes"]), "bundle": int(d["bundleBytes"]), "preset": d["preset"], "text": d["text"]}


def _sent(page) -> dict:
    """The config the form would send, less an empty light list (the scene section is not a preset's)."""
    config = page.evaluate("window.kiln.configForm.config()")
    if config.get("scene") == {"lights": []}:
        del config["scene"]
    return config


def _choose(page, preset: str, kiln_server, scene_id: str) -> dict:
    page.select_option("#bake-preset", preset)
    page.wait_for_function(f"document.getElementById('bake-estimate').dataset.preset === '{preset}'", timeout=30000)
    est = _estimate(page)
    # what the server estimates for the form's config now (dry run: nothing is started)
    config = page.evaluate("window.kiln.configForm.config()")
    dry = kiln_server.api("/v1/bakes?dry_run=true", "POST", json={"scene_id": scene_id, "config": config})["estimate"]
    assert (est["probes"], est["seconds"], est["memory"], est["bytes"], est["bundle"]) == (
        dry["probes"], dry["seconds"], dry["peak_memory_bytes"], dry["artifact_bytes"], dry["bundle_bytes"]), (est, dry)
    assert "bundle download" in est["text"] and 0 < est["bundle"] < est["bytes"], est
    return est


def test_a_preset_fills_the_form_and_the_estimate_follows(page, kiln_server, room, shots):
    page.goto("/")
    page.wait_for_selector("#config-form .config-form")
    page.set_input_files("#scene-file", str(room["glb"]))
    page.wait_for_selector("#upload-status.ok", timeout=30000)
    page.wait_for_function("document.getElementById('bake-estimate').dataset.probes", timeout=30000)
    # the defaults are the medium preset
    assert page.input_value("#bake-preset") == "medium"
    medium = _estimate(page)
    assert medium["probes"] == 24000 and medium["preset"] == "medium"

    preview = _choose(page, "preview", kiln_server, room["scene"])
    assert page.input_value('#config-form input[name="place.budget"]') == "2000"
    assert page.input_value('#config-form input[name="trace.rays_per_probe"]') == "64"
    assert page.input_value('#config-form input[name="visibility.samples_per_cell"]') == "4"
    assert not page.is_checked('#config-form input[name="evaluate.enabled"]')
    assert "2000 probes" in preview["text"]
    assert _sent(page) == PRESETS["preview"]["config"]  # what the form sends: only what differs from the defaults
    page.locator("#config-form .preset-row").screenshot(path=str(shots / "preset-preview-picker.png"))
    page.locator("#bake-estimate").screenshot(path=str(shots / "preset-preview-estimate.png"))

    production = _choose(page, "production", kiln_server, room["scene"])
    assert page.input_value('#config-form input[name="place.budget"]') == "48000"
    assert page.input_value('#config-form input[name="trace.rays_per_probe"]') == "384"
    assert page.is_checked('#config-form input[name="evaluate.enabled"]')
    assert not page.locator('#config-form input[name="visibility.samples_per_cell"]').is_enabled()  # automatic again
    assert "48000 probes" in production["text"]
    for key in ("probes", "seconds", "memory", "bytes"):
        assert preview[key] < medium[key] < production[key], (key, preview, medium, production)
    assert "over the server" not in production["text"]   # production fits the default limits

    # a value changed by hand: no preset any more ("custom"); the estimate follows that too
    _field(page, "trace.rays_per_probe").fill("200")
    page.wait_for_function("document.getElementById('bake-estimate').dataset.preset === 'custom'", timeout=30000)
    assert page.input_value("#bake-preset") == ""
    assert _estimate(page)["seconds"] < production["seconds"]
    # back to medium: the defaults again (nothing differs)
    _choose(page, "medium", kiln_server, room["scene"])
    assert _sent(page) == {}
    assert not page.kiln_errors, page.kiln_errors


def _open(page, bake_id: str):
    page.goto("/#/dashboard")
    page.wait_for_selector("#viewer-canvas", state="attached")
    _after(page, lambda: page.goto(f"/#/viewer/{bake_id}"), "direct")


def _frame(page, action, shots, name) -> np.ndarray:
    """`action`, then a frame drawn after it (direct mode), as a screenshot."""
    _after(page, action, "direct")
    return _shot(page.locator("#viewer-canvas"), shots / name)


def _geometry_fraction(img: np.ndarray, background: np.ndarray) -> float:
    return float((np.abs(img - background).max(-1) > 8).mean())


def test_first_view_is_the_first_review_camera_inside_the_room(browser, kiln_server, room, shots):
    cams = room["cameras"]
    ctx, page = _new_page(browser, kiln_server.url)   # a new context: no file, no state from the bake page
    try:
        _open(page, room["bake"])
        assert page.get_attribute("#viewer-canvas", "data-scene") == "server"
        page.wait_for_function("document.getElementById('stream-label').textContent === 'volumes loaded'", timeout=60000)
        assert page.get_attribute("#viewer-canvas", "data-camera") == "0"
        state = page.evaluate("window.kiln.viewer.viewState()")
        pos = np.array(state["position"])
        np.testing.assert_allclose(pos, cams[0]["position"], atol=1e-6)
        assert np.all(pos > ROOM[0]) and np.all(pos < ROOM[1]), f"the first view is not inside the room: {pos}"
        direction = np.subtract(state["target"], state["position"])
        want = np.subtract(cams[0]["target"], cams[0]["position"])
        assert np.dot(direction, want) / np.linalg.norm(direction) / np.linalg.norm(want) > 0.9999
        assert state["fov_y"] == pytest.approx(cams[0]["fov_y"] or 60)
        # the camera list: every review camera, then the automatic view
        buttons = page.locator("#cam-list button").evaluate_all("e => e.map(b => b.dataset.cam)")
        assert buttons == [*map(str, range(len(cams))), "auto"]
        first = _frame(page, lambda: page.evaluate("window.kiln.viewer.invalidate()"), shots, "review-cam-0.png")
        # the background colour: a view from far outside looking away from the scene
        background = _frame(page, lambda: page.evaluate("window.kiln.viewer.setView({position: [60, 1, 1.5], target: [90, 1, 1.5]})"),
                            shots, "review-background.png")
        bg = np.median(background.reshape(-1, 3), axis=0)
        assert _geometry_fraction(background, bg) < 0.01
        s = _stats(first)
        frac = _geometry_fraction(first, bg)
        assert frac > 0.95 and s["mean"] > 20 and s["std"] > 6 and s["levels"] > 20, \
            f"the first view does not look at lit geometry: {frac:.3f} of the pixels unlike the background, {s}"

        # jump to the second camera: another view
        second = _frame(page, lambda: page.click('#cam-list button[data-cam="1"]'), shots, "review-cam-1.png")
        assert page.get_attribute("#viewer-canvas", "data-camera") == "1"
        np.testing.assert_allclose(page.evaluate("window.kiln.viewer.viewState()")["position"], cams[1]["position"], atol=1e-6)
        assert _geometry_fraction(second, bg) > 0.9
        diff = np.abs(second - first).mean()
        assert diff > 8, f"camera 2 shows the same picture as camera 1 (mean abs difference {diff:.2f})"
        # and back to the first: the same picture as at the start
        again = _frame(page, lambda: page.click('#cam-list button[data-cam="0"]'), shots, "review-cam-0-again.png")
        assert np.abs(again - first).mean() < 2
        assert not page.kiln_errors, page.kiln_errors
    finally:
        ctx.close()


def test_save_this_view_as_a_review_camera(browser, kiln_server, room, shots):
    before = kiln_server.api(f"/v1/scenes/{room['scene']}/cameras")
    ctx, page = _new_page(browser, kiln_server.url)
    try:
        _open(page, room["bake"])
        n = len(before["cameras"])
        view = {"position": [3.6, 1.7, 2.6], "target": [0.5, 0.6, 0.4]}
        img = _frame(page, lambda: page.evaluate("v => window.kiln.viewer.setView(v)", view), shots, "review-saved-view.png")
        page.click("#cam-save")
        page.wait_for_selector("#cam-note.ok", timeout=30000)
        assert "Saved" in page.inner_text("#cam-note")
        after = kiln_server.api(f"/v1/scenes/{room['scene']}/cameras")
        assert after["source"] == "stored" and len(after["cameras"]) == n + 1
        # the scene's cameras before it, in order, then this view (glTF coordinates, degrees)
        for old, new in zip(before["cameras"], after["cameras"]):
            np.testing.assert_allclose(new["position"], old["position"], atol=1e-9)
            np.testing.assert_allclose(new["target"], old["target"], atol=1e-9)
        saved = after["cameras"][-1]
        np.testing.assert_allclose(saved["position"], view["position"], atol=1e-6)
        d, want = np.subtract(saved["target"], saved["position"]), np.subtract(view["target"], view["position"])
        assert np.dot(d, want) / np.linalg.norm(d) / np.linalg.norm(want) > 0.9999
        assert saved["fov_y"] == pytest.approx(page.evaluate("window.kiln.viewer.camera.fov"))
        # it is in the camera list, marked as the current one, and jumps back to this view
        btn = f'#cam-list button[data-name="{saved["name"]}"]'
        assert page.locator(btn).count() == 1 and "active" in page.get_attribute(btn, "class")
        assert page.locator("#cam-list button").count() == n + 2
        _frame(page, lambda: page.click('#cam-list button[data-cam="0"]'), shots, "review-away.png")
        back = _frame(page, lambda: page.click(btn), shots, "review-saved-again.png")
        assert np.abs(back - img).mean() < 2
        assert not page.kiln_errors, page.kiln_errors
    finally:
        ctx.close()
        kiln_server.api(f"/v1/scenes/{room['scene']}/cameras", "PUT", json={"cameras": []})   # leave the scene as found
