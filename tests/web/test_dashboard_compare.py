"""The dashboard compares like with like, in a real browser against a real `kiln serve`: a scene's thresholds
stored through the dashboard (PUT /v1/scenes/{id}/thresholds) and checked per bake by the server, a chart per
evaluate metric with a point per bake and the threshold's line, and for two bakes an A/B slider over the same
camera's previews (canvas pixels read back), their difference image and the quality deltas with standard errors
(paired: both bakes share the cached reference).
Two tiny evaluated bakes of one scene that differ in their probe grid."""
from __future__ import annotations

import pytest

from tests.web.test_viewer import _scene

pytestmark = pytest.mark.timeout(300)

METRIC = "mask_normalized.rmse"
EV = {"enabled": True, "cameras": 1, "previews": 1, "width": 64, "height": 48, "spp": 2, "repeats": 1, "flip": False,
      "surface_points": 256, "modes": ["leaking", "mask_normalized"]}
CFGS = [{"place": {"counts": [3, 2, 2]}, "trace": {"rays_per_probe": 32}, "visibility": {"samples_per_cell": 2},
         "masks": {"sweeps": 10}, "evaluate": EV},
        {"place": {"counts": [6, 3, 4]}, "trace": {"rays_per_probe": 64}, "visibility": {"samples_per_cell": 2},
         "masks": {"sweeps": 10}, "evaluate": EV}]

PIXEL_JS = """([sel, x]) => { const c = document.querySelector(sel); const ctx = c.getContext('2d');
  const d = ctx.getImageData(0, 0, c.width, c.height).data; const out = [];
  for (let y = 0; y < c.height; y++) { const i = (y * c.width + x) * 4; out.push([d[i], d[i + 1], d[i + 2]]); }
  return out; }"""


@pytest.fixture(scope="module")
def two_bakes(kiln_server, tmp_path_factory):
    glb = _scene(tmp_path_factory.mktemp("dash-compare"))
    with open(glb, "rb") as f:
        scene = kiln_server.api("/v1/scenes", "POST", files={"file": (glb.name, f, "model/gltf-binary")})
    ids = [kiln_server.api("/v1/bakes", "POST", json={"scene_id": scene["id"], "config": c})["id"] for c in CFGS]
    bakes = [kiln_server.wait_bake(i, timeout=200) for i in ids]
    for b in bakes:
        assert b["status"] == "succeeded", b.get("error")
    return {"scene": scene, "glb": glb, "bakes": bakes}


def _set_slider(page, fraction: float):
    """Drag on the A/B canvas as a person would: press at the middle, move to `fraction` of its width, release."""
    page.locator("#ab-canvas").scroll_into_view_if_needed()
    box = page.locator("#ab-canvas").bounding_box()
    y = box["y"] + box["height"] / 2
    page.mouse.move(box["x"] + box["width"] / 2, y)
    page.mouse.down()
    # past the edge for 0 and 1 (the canvas keeps the pointer while the button is down)
    over = 5 if fraction >= 1 else -5 if fraction <= 0 else 0
    page.mouse.move(box["x"] + box["width"] * fraction + over, y, steps=4)
    page.mouse.up()


def test_thresholds_charts_ab_slider_difference_and_deltas(page, kiln_server, two_bakes, shots):
    sid = two_bakes["scene"]["id"]
    a, b = two_bakes["bakes"]                    # a is the older
    va, vb = a["metrics"][METRIC], b["metrics"][METRIC]
    assert va != vb, (va, vb)
    mid = (va + vb) / 2                          # one bake above it (fails), one below (passes)

    page.goto(f"/#/dashboard?scene={sid}")
    box = f'.scene-charts[data-scene="{sid}"]'
    page.wait_for_selector(f"{box} textarea.thresholds-input", timeout=30000)
    # the scene's name, not its hash
    assert two_bakes["glb"].name in page.inner_text(f"{box} h3")

    # a bad threshold: refused in words, nothing stored
    page.fill(f"{box} textarea.thresholds-input", f"{METRIC} >> 1")
    page.click(f"{box} button.save-thresholds")
    page.wait_for_selector(f"{box} .thresholds-msg.error", timeout=10000)
    assert ">> 1" in page.inner_text(f"{box} .thresholds-msg")
    assert kiln_server.api(f"/v1/scenes/{sid}/thresholds")["thresholds"] == []

    page.fill(f"{box} textarea.thresholds-input", f"{METRIC} > {mid:.9g}")
    page.click(f"{box} button.save-thresholds")
    chart = f'{box} svg.metric-chart[data-metric="{METRIC}"]'
    page.wait_for_selector(f"{chart} line.threshold", state="attached", timeout=10000)
    assert kiln_server.api(f"/v1/scenes/{sid}/thresholds")["thresholds"] == [f"{METRIC} > {mid:.9g}"]

    # the chart: a point per bake in time order, the threshold's line between them, the failing bake in red
    pts = page.locator(f"{chart} circle.point").evaluate_all(
        "e => e.map(c => ({bake: c.dataset.bake, cx: +c.getAttribute('cx'), cy: +c.getAttribute('cy'), failed: c.classList.contains('failed')}))")
    # (other tests of the session may bake the same scene file: the same content, the same scene id)
    pts = [p for p in pts if p["bake"] in (a["id"], b["id"])]
    assert [p["bake"] for p in pts] == [a["id"], b["id"]] and pts[0]["cx"] < pts[1]["cx"], pts
    line_y = float(page.get_attribute(f"{chart} line.threshold", "y1"))
    assert min(p["cy"] for p in pts) < line_y < max(p["cy"] for p in pts), (pts, line_y)
    failing = a if va > mid else b
    assert [p["bake"] for p in pts if p["failed"]] == [failing["id"]], pts
    # the table's thresholds column: the server's check
    for x in (a, b):
        want = "fail" if x is failing else "pass"
        assert page.get_attribute(f'#bake-table tr[data-bake="{x["id"]}"] td.gates-cell', "data-gates") == want

    # two bakes picked: the A/B view
    for x in (a, b):
        page.check(f'input[data-pick="{x["id"]}"]')
    page.wait_for_selector("#ab-canvas[data-ready]", timeout=30000)
    assert page.get_attribute("#ab-canvas", "data-pair").endswith("/mask_normalized")
    w = page.evaluate("document.getElementById('ab-canvas').width")
    assert w == 64
    _set_slider(page, 1.0)
    assert int(page.get_attribute("#ab-canvas", "data-split")) == w
    all_a = {x: page.evaluate(PIXEL_JS, ["#ab-canvas", x]) for x in range(0, w - 1)}
    _set_slider(page, 0.0)
    assert int(page.get_attribute("#ab-canvas", "data-split")) == 0
    all_b = {x: page.evaluate(PIXEL_JS, ["#ab-canvas", x]) for x in range(1, w)}
    cols = [x for x in range(1, w - 1) if all_a[x] != all_b[x]]
    assert cols, "the two bakes' previews are identical"
    x = cols[len(cols) // 2]
    _set_slider(page, min(1.0, (x + 4) / w))       # the split right of x: A shows at x
    assert int(page.get_attribute("#ab-canvas", "data-split")) > x
    assert page.evaluate(PIXEL_JS, ["#ab-canvas", x]) == all_a[x]
    _set_slider(page, max(0.0, (x - 4) / w))       # left of x: B shows there
    assert int(page.get_attribute("#ab-canvas", "data-split")) < x
    assert page.evaluate(PIXEL_JS, ["#ab-canvas", x]) == all_b[x]

    # the difference image: non-empty where the bakes differ, its scale stated
    assert int(page.get_attribute("#ab-diff", "data-nonzero")) > 0
    diff_col = page.evaluate(PIXEL_JS, ["#ab-diff", x])
    assert any(sum(p) > 0 for p in diff_col), diff_col
    gain = int(page.get_attribute("#ab-diff", "data-gain"))
    assert gain in (1, 2, 4, 8, 16) and f"× {gain}" in page.inner_text("#ab-diff-scale")
    assert int(page.get_attribute("#ab-diff", "data-max")) * gain <= 255 or gain == 1

    # the deltas: values with standard errors and which is better; both bakes were scored against one cached
    # reference (same scene, lighting, evaluate settings), so the server pairs their standard errors
    cmp = kiln_server.api(f"/v1/compare?a={a['id']}&b={b['id']}")
    assert cmp["paired"]["paired"] is True and cmp["paired"]["points"] > 0, cmp["paired"]
    for key in (METRIC, "mask_normalized.mean_ratio", "leaking.rmse"):
        d = cmp["metrics"][key]
        quad = (a["metrics"][f"{key}_stderr"] ** 2 + b["metrics"][f"{key}_stderr"] ** 2) ** 0.5
        # the shared noise counted once: measured 0.18-0.31 of sqrt(seA² + seB²) here
        assert d["delta_stderr"] is not None and 0 <= d["delta_stderr"] < quad, (key, d, quad)
    page.wait_for_selector('#delta-table[data-paired="true"]', timeout=30000)
    rows = page.locator("#delta-table tbody tr")
    assert rows.count() >= 2
    row = page.locator(f'#delta-table tr[data-metric="{METRIC}"]')
    assert row.get_attribute("data-paired") == "true"
    cells = row.locator("td").all_inner_texts()
    assert "±" in cells[1] and "±" in cells[3], cells
    se_shown = float(cells[3].split("±")[1].strip().rstrip(" *"))
    assert se_shown == pytest.approx(cmp["metrics"][METRIC]["delta_stderr"], rel=0.05, abs=1e-4), (cells, cmp)
    better = "b" if vb < va else "a"
    assert row.get_attribute("data-better") == better and f"{better.upper()} better" in cells[4], cells
    page.locator("#compare").screenshot(path=str(shots / "dashboard-ab.png"))
    page.locator(box).screenshot(path=str(shots / "dashboard-scene-charts.png"))
    assert not page.kiln_errors, page.kiln_errors
