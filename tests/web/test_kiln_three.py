"""@kiln/three (web/kiln-three): a baked bundle in a plain three.js page, pixel-checked against the Python renderer.

One small bake of two-rooms (a 20 cd point light in room A; room B lit only through the door) is written as a bundle
folder by ``kiln bake``; the example page (web/dist/kiln-three/example/, built by ``npm run build``) loads it from a
static server exactly as an app would (manifest.json, KTX2 through three's KTX2Loader, the scene glb through
GLTFLoader) and renders fixed cameras into an RGBA32F target (linear radiance, ``window.kiln.renderLinear``). The
same cameras are rendered by workers/render (moderngl G-buffer + the proto/glsl mode, the evaluate stage's pass).

Compared: the GI contribution, three's (GI on) − (GI off) against Kiln's albedo/π · E_indirect — the direct light
cancels, so what is checked is the bake's indirect light as three shades it — and, for one mode, the whole frame
(direct with three's shadow maps + GI) against the Python pass (Embree shadow rays). Metric: relative L1 over the
pixels both see (the Python G-buffer's shaded pixels, eroded by one pixel against silhouette raster differences)
whose Python value is lit: Σ|three − python| / Σ python.

Leaking GI goes through three's own LightProbeGrid, whose shader reads the probes half a cell along the normal
(lightprobes_pars_fragment); the Python side evaluates Kiln's leaking mode at the same offset point, so the check
is of the layout, bounds, resolution and L2 evaluation, not of the two lookups' difference (measured alongside).
MeshLambertMaterial is Kiln's Lambertian surface exactly; MeshStandardMaterial takes a share of the light for its
specular lobe (three's multiscattering energy split), so its tolerance is wider and its number printed.
"""
from __future__ import annotations

import base64
import functools
import hashlib
import http.server
import json
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import as_toml, small_bake
from tests.web.conftest import ROOT

EXAMPLE = ROOT / "web" / "dist" / "kiln-three" / "example" / "index.html"
W, H = 96, 72
# camera in room B looking through the door into room A (glTF coordinates, metres), and one in room A
CAMERAS = {"b_to_door": ((6.8, 1.4, 3.3), (3.0, 1.0, 1.6)), "a_corner": ((0.5, 2.2, 3.5), (3.0, 0.8, 1.0))}
FOV = 60.0
BAKE = small_bake(place={"counts": [10, 4, 5]}, trace={"rays_per_probe": 64}, visibility={"samples_per_cell": 4},
                  masks={"sweeps": 20})
"""Every stage a GI mode reads, on a 10 x 4 x 5 grid (about 15 s of stages here)."""


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory, scene_files) -> Path:
    d = tmp_path_factory.mktemp("kiln-three")
    (d / "bake.toml").write_text(as_toml(BAKE))
    kiln = Path(sys.executable).with_name("kiln")
    out = d / "bundle"
    r = subprocess.run([str(kiln), "bake", str(scene_files["two-rooms"]), "--config", str(d / "bake.toml"),
                        "--out", str(out), "--cache", str(d / "cache")], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def half_bundle_dir(bundle_dir, tmp_path_factory) -> Path:
    """The bundle with every 2- and 4-channel float32 KTX2 volume rewritten as RGBA16F / RG16F with Zstandard (the
    formats issue 17 moves to), manifest updated (sha256, bytes, meta.ktx2); the rest copied as is."""
    from proto.bundle import load_artifact, read_manifest, with_artifact, write_artifact, write_manifest

    out = tmp_path_factory.mktemp("kiln-three-half") / "bundle"
    shutil.copytree(bundle_dir, out)
    manifest = read_manifest(out)
    for a in manifest.artifacts:
        if a.format == "ktx2" and a.dtype == "float32" and a.shape[-1] in (2, 4):
            arr = load_artifact(out / a.file, a)
            if a.meta.get("stored_border") == 0:            # loaded with the tile borders: store as the stage did
                from proto.atlas import atlas_strip_border
                arr = atlas_strip_border(arr, a.meta["texels"])
            info = write_artifact(out, a.name, arr.astype(np.float16), a.stage, zstd_level=10, description=a.description,
                                  meta={k: v for k, v in a.meta.items() if k != "ktx2"})
            manifest = with_artifact(manifest, info)
    write_manifest(out, manifest)
    return out


TURN_DEG = 30.0
"""Yaw of the turned twin of the bundle (degrees about +Y)."""


def _ry(deg: float) -> np.ndarray:
    """R_y(θ) (3, 3): bake frame -> world; the manifest's grid.frame.matrix is its transpose (world -> bake)."""
    t = np.radians(deg)
    return np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])


def _turn_glb(src: Path, dst: Path, deg: float) -> None:
    """Write `src` (GLB) to `dst` with its scene's root nodes under one new root turned by R_y(deg) about the world
    origin: meshes and their KHR_lights_punctual lights turn together; the BIN chunk is kept byte for byte."""
    b = src.read_bytes()
    n_json = int.from_bytes(b[12:16], "little")
    assert b[16:20] == b"JSON"
    gltf = json.loads(b[20:20 + n_json])
    rest = b[20 + n_json:]                                      # the BIN chunk, header included
    scene = gltf["scenes"][gltf.get("scene", 0)]
    half = np.radians(deg) / 2
    gltf["nodes"].append({"name": "kiln-test-turn", "rotation": [0.0, float(np.sin(half)), 0.0, float(np.cos(half))],
                          "children": scene["nodes"]})
    scene["nodes"] = [len(gltf["nodes"]) - 1]
    j = json.dumps(gltf, separators=(",", ":")).encode()
    j += b" " * (-len(j) % 4)
    body = len(j).to_bytes(4, "little") + b"JSON" + j + rest
    dst.write_bytes(b[:8] + (12 + len(body)).to_bytes(4, "little") + body)


@pytest.fixture(scope="module")
def turned_bundle_dir(bundle_dir, tmp_path_factory) -> Path:
    """The bundle as a bake in a turned bake frame would be: the scene (glb) turned by R_y(TURN_DEG) about the world
    origin, every probe artifact as it was (so the old world is the bake frame), and the manifest's
    grid.frame = {yaw_deg, matrix: R_y(TURN_DEG)ᵀ (world -> bake, row-major)}; the scene artifact's bytes/sha256
    updated."""
    out = tmp_path_factory.mktemp("kiln-three-turned") / "bundle"
    shutil.copytree(bundle_dir, out)
    manifest = json.loads((out / "manifest.json").read_text())
    scene = next(a for a in manifest["artifacts"] if a["name"] == "scene")
    glb = out / scene["file"]
    _turn_glb(bundle_dir / scene["file"], glb, TURN_DEG)
    scene["bytes"] = glb.stat().st_size
    scene["sha256"] = hashlib.sha256(glb.read_bytes()).hexdigest()
    manifest["grid"]["frame"] = {"yaw_deg": TURN_DEG, "matrix": _ry(TURN_DEG).T.tolist(), "source": "config",
                                 "reason": "test: the scene turned, the bake frame its old world"}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return out


@pytest.fixture(scope="module")
def site(bundle_dir, half_bundle_dir, turned_bundle_dir, tmp_path_factory):
    """A static server of web/dist (the example and its assets), the bundle at /bundle/, its half-float twin at
    /bundle-half/, its turned twin at /bundle-turned/."""
    if not EXAMPLE.exists():
        pytest.skip(f"{EXAMPLE} is not built (cd web && npm run build)")
    root = tmp_path_factory.mktemp("site")
    for name in ("assets", "kiln-three"):
        (root / name).symlink_to(ROOT / "web" / "dist" / name)
    (root / "bundle").symlink_to(bundle_dir)
    (root / "bundle-half").symlink_to(half_bundle_dir)
    (root / "bundle-turned").symlink_to(turned_bundle_dir)

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(root)))
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{srv.server_port}"
    finally:
        srv.shutdown()
        srv.server_close()


def _open(browser, site, cam, bundle="bundle", page="kiln-three/example/index.html", **params):
    ctx = browser.new_context(viewport={"width": 320, "height": 240})
    pg = ctx.new_page()
    errors = []
    pg.on("pageerror", lambda e: errors.append(f"pageerror: {e}"))
    pg.on("console", lambda m: errors.append(f"console.error: {m.text}")
          if m.type == "error" and "favicon" not in m.text and "Failed to load resource" not in m.text else None)
    (px, py, pz), (tx, ty, tz) = CAMERAS[cam] if isinstance(cam, str) else cam
    q = "&".join([f"bundle=../../{bundle}/" if bundle else "", f"cam={px},{py},{pz},{tx},{ty},{tz}", f"fov={FOV}"]
                 + [f"{k}={v}" for k, v in params.items()])
    pg.goto(f"{site}/{page}?{q}")
    pg.wait_for_function("window.kiln !== undefined || document.getElementById('status').textContent.startsWith('error')",
                         timeout=120_000)
    status = pg.evaluate("document.getElementById('status').textContent")
    assert not status.startswith("error"), (status, errors)
    pg.kiln_errors = errors
    return ctx, pg


def _three(pg, mode: str, material: str) -> np.ndarray:
    """(H, W, 3) linear radiance of the example page in `mode` with `material`, row 0 = top."""
    pg.evaluate(f"(async () => {{ window.kiln.setMaterial('{material}'); await window.kiln.setMode('{mode}'); }})()")
    raw = pg.evaluate(f"window.kiln.renderLinear({W}, {H})")
    return np.frombuffer(base64.b64decode(raw), np.float32).reshape(H, W, 4)[..., :3].astype(np.float64)


class PythonView:
    """The Python renderer (workers/render) at one camera of the bundle: G-buffer once, then modes."""

    def __init__(self, bundle_dir: Path, cam: str):
        from proto.bundle import open_bundle
        from workers.gltf import ingest_file
        from workers.render.cameras import Camera, fit_clip_planes
        from workers.render.context import create_context
        from workers.render.gbuffer import GBufferRenderer

        self.manifest, self.arrays = open_bundle(bundle_dir)
        if "mask_atlas" in self.arrays:      # the masks the (possibly lossy) atlas stands for: what the runtime reads
            from workers.kernels.mask_atlas import decompress_channels

            meta = next(a.meta for a in self.manifest.artifacts if a.name == "mask_atlas")
            self.arrays = dict(self.arrays)
            for n, v in zip(("masks_0123", "masks_4567"), decompress_channels(self.arrays["mask_atlas"],
                                                                               self.arrays["mask_indirection"], meta)):
                self.arrays[n] = v
        self.scene = ingest_file(bundle_dir / "scene.glb")
        pos, target = CAMERAS[cam]
        self.cam = fit_clip_planes(Camera(position=pos, target=target, fov_y=FOV, width=W, height=H),
                                   bounds=np.asarray(self.scene.bounds))
        self.ctx = create_context()
        gr = GBufferRenderer(self.scene, self.ctx)
        try:
            self.gb = gr.render(self.cam)
        finally:
            gr.release()
        self.lights = self.arrays["lights"]["lights"]
        self.grid = self.manifest.grid

    def _shader(self, mode: str, positions=None, shadow=None):
        from workers.render.shading import GBufferInputs, ShadingRenderer, prepare_mode

        kw = {}
        if mode.startswith("mask"):
            meta = next(a.meta for a in self.manifest.artifacts if a.name == "mask_atlas")
            kw["mask_meta"] = {k: meta[k] for k in ("samples_per_cell", "block_size", "border_lo")}
        if mode == "ddgi":
            kw["self_shadow_bias"] = self.manifest.config["light"]["self_shadow_bias"]
        sr = ShadingRenderer(self.ctx, self.lights)
        sr.set_mode(prepare_mode(mode, self.arrays, self.grid, **kw))
        g = self.gb
        sr.set_gbuffer(GBufferInputs(g.position if positions is None else positions, g.normal, g.albedo, g.emission,
                                     g.shaded, shadow))
        return sr

    def gi(self, mode: str, normal_offset: bool = False) -> np.ndarray:
        """albedo/π · E_indirect of `mode` (H, W, 3); with normal_offset the lookup at p + n·spacing/2 (three's
        LightProbeGrid lookup point)."""
        g = self.gb
        pos = g.position + g.normal * (0.5 * np.asarray(self.grid["spacing"])) if normal_offset else None
        sr = self._shader(mode, pos)
        try:
            e = sr.render(mode, 1, self.cam.position).astype(np.float64)
        finally:
            sr.release()
        return g.albedo * e / np.pi

    def full(self, mode: str) -> np.ndarray:
        """Radiance: emission + albedo/π (E_direct · Embree shadow rays + E_indirect), (H, W, 3)."""
        from workers.kernels.pathtrace import scene_eps
        from workers.raycast import caster_for_scene
        from workers.render.shading import shadow_masks

        g = self.gb
        sm = np.ones(g.shaded.shape + (len(self.lights),), np.uint8)
        sel = g.shaded
        sm[sel] = shadow_masks(g.position[sel].astype(np.float64), g.normal[sel].astype(np.float64), self.lights,
                               caster_for_scene(self.scene), scene_eps(self.scene))
        sr = self._shader(mode, shadow=sm)
        try:
            return sr.render(mode, 0, self.cam.position).astype(np.float64)
        finally:
            sr.release()

    def mask(self) -> np.ndarray:
        from scipy.ndimage import binary_erosion

        return binary_erosion(self.gb.shaded, iterations=1)

    def close(self):
        self.ctx.release()


def rel_l1(a: np.ndarray, b: np.ndarray, sel: np.ndarray) -> float:
    """Σ|a − b| / Σ b over the selected pixels (all channels)."""
    return float(np.abs(a[sel] - b[sel]).sum() / max(b[sel].sum(), 1e-30))


@pytest.fixture(scope="module")
def views(bundle_dir):
    from workers.render.context import RenderUnavailable

    try:
        out = {c: PythonView(bundle_dir, c) for c in CAMERAS}
    except RenderUnavailable as e:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL for the Python renderer: {e}")
    yield out
    for v in out.values():
        v.close()


# Tolerances (relative L1 over the lit pixels). Measured on this bake (llvmpipe for Python, SwiftShader for Chromium):
# Lambert 0.0002-0.004 for every mode (float rounding, SwiftShader vs llvmpipe filtering), MeshStandardMaterial
# 0.017-0.025 (three's specular energy split), whole frames 0.0002-0.015 (shadow-map edges against shadow rays).
LAMBERT_TOL, STANDARD_TOL, FRAME_TOL = 0.01, 0.05, 0.03
RESAMPLED_TOL = 0.08
"""three's LightProbeGrid of a turned bake (resampled onto world cells, grid.js resampleShL2) against the unturned
bundle's in the lit room (measured 0.051 on the 10 x 4 x 5 grid): one more trilinear filter over the cells, and
three's half-cell offset along the normal over other cells."""


@pytest.fixture(scope="module")
def pages(browser, site):
    out = {c: _open(browser, site, c) for c in CAMERAS}
    yield {c: pg for c, (_, pg) in out.items()}
    for c, (ctx, pg) in out.items():
        assert not pg.kiln_errors, pg.kiln_errors
        ctx.close()


def _lit(view, py):
    sel = view.mask()
    lum = py.sum(-1)
    return sel & (lum > 0.02 * lum[sel].mean())


@pytest.mark.parametrize("cam", list(CAMERAS))
def test_leaking_gi_through_threes_light_probe_grid(pages, views, cam):
    """Mode 'grid': the bundle's sh_l2 as three's LightProbeGrid texture, box and resolution from the manifest grid,
    plain materials. Against Kiln's leaking mode evaluated where three's shader looks (p + n·spacing/2)."""
    pg, view = pages[cam], views[cam]
    py = view.gi("leaking", normal_offset=True)
    sel = _lit(view, py)
    for material, tol in (("lambert", LAMBERT_TOL), ("standard", STANDARD_TOL)):
        off = _three(pg, "off", material)
        on = _three(pg, "grid", material)
        gi = on - off
        err = rel_l1(gi, py, sel)
        print(f"{cam} grid {material}: rel L1 {err:.4f} (GI mean three {gi[sel].mean():.4f}, python {py[sel].mean():.4f}; "
              f"frame mean GI on {on[sel].mean():.4f}, off {off[sel].mean():.4f})")
        assert err <= tol, (material, err)
        assert gi[sel].mean() > 0.1 * on[sel].mean(), "the LightProbeGrid adds no light"
    at_p = view.gi("leaking")  # Kiln's own lookup, no offset: how far three's leak mitigation moves the result
    print(f"{cam} three's half-cell normal offset vs Kiln's leaking lookup: rel L1 {rel_l1(py, at_p, sel):.4f}")


@pytest.mark.parametrize("cam", list(CAMERAS))
def test_kiln_modes_as_a_material_extension(pages, views, cam):
    """Kiln's GLSL modes through onBeforeCompile on MeshLambertMaterial / MeshStandardMaterial: (GI on) − (GI off)
    against the Python pass's albedo/π · E_indirect of the same mode."""
    pg, view = pages[cam], views[cam]
    got = {}
    for material, tol in (("lambert", LAMBERT_TOL), ("standard", STANDARD_TOL)):
        off = _three(pg, "off", material)
        for mode in ("leaking", "mask", "mask_normalized", "ddgi"):
            py = view.gi(mode)
            sel = _lit(view, py)
            gi = _three(pg, mode, material) - off
            err = rel_l1(gi, py, sel)
            print(f"{cam} {mode} {material}: rel L1 {err:.4f} (GI mean three {gi[sel].mean():.4f}, "
                  f"python {py[sel].mean():.4f})")
            assert err <= tol, (mode, material, err)
            assert gi[sel].mean() > 0, (mode, material)
            got[mode, material] = gi
    if cam == "b_to_door":  # room B through the wall: the leak-free modes differ from leaking GI
        sel = views[cam].mask()
        d = rel_l1(got["mask_normalized", "lambert"], got["leaking", "lambert"], sel)
        print(f"{cam} mask_normalized vs leaking: rel L1 {d:.3f}")
        assert d > 0.05


@pytest.mark.parametrize("mode", ["mask_normalized", "ddgi"])
def test_whole_frame_matches_the_python_renderer(pages, views, mode):
    """Direct light (the glTF's KHR_lights_punctual through GLTFLoader, three's shadow maps) + Kiln GI, Lambert,
    against the Python pass (lights.glsl × Embree shadow rays + the same mode)."""
    for cam in CAMERAS:
        pg, view = pages[cam], views[cam]
        three = _three(pg, mode, "lambert")
        py = view.full(mode)
        sel = view.mask()
        err = rel_l1(three, py, sel)
        print(f"{cam} whole frame {mode}: rel L1 {err:.4f} (means {three[sel].mean():.4f}, {py[sel].mean():.4f})")
        assert err <= FRAME_TOL, (cam, err)


def test_a_half_float_bundle_loads_with_no_code_change(browser, site, half_bundle_dir):
    """Formats come from the files: the same page on the RGBA16F / RG16F + Zstandard twin of the bundle (sh_l2, the
    cluster SH and weights, the DDGI atlases) matches the Python renderer reading that twin, every mode."""
    from proto.bundle import read_manifest

    halves = [a.name for a in read_manifest(half_bundle_dir).artifacts if a.meta.get("ktx2", {}).get("vk_format") in (83, 97)]
    assert {"sh_l2", "depth_moments", "cluster_sh_l2_0", "cluster_weights_0123"} <= set(halves), halves
    irr = next(a for a in read_manifest(half_bundle_dir).artifacts if a.name == "irradiance")
    assert irr.meta["ktx2"]["vk_format"] in (97, 123)          # RGBA16F, or RGB9E5 as the light stage writes it
    cam = "b_to_door"
    ctx, pg = _open(browser, site, cam, bundle="bundle-half")
    view = PythonView(half_bundle_dir, cam)
    try:
        off = _three(pg, "off", "lambert")
        for three_mode, mode, offset in (("grid", "leaking", True), ("mask_normalized", "mask_normalized", False),
                                         ("ddgi", "ddgi", False)):
            py = view.gi(mode, normal_offset=offset)
            sel = _lit(view, py)
            err = rel_l1(_three(pg, three_mode, "lambert") - off, py, sel)
            print(f"half-float bundle {three_mode}: rel L1 {err:.4f}")
            assert err <= LAMBERT_TOL, (three_mode, err)
        assert not pg.kiln_errors, pg.kiln_errors
    finally:
        view.close()
        ctx.close()


def test_the_example_reads_a_bake_from_a_kiln_server(browser, kiln_server, scene_files, pages):
    """`kiln serve` serves the example at /app/kiln-three/example/; ?bake=ID loads that bake through the REST API (the
    grid from its place stage, each artifact from /v1/bakes/{id}/artifacts/{name}). The same scene and config as the
    folder bundle: the same frames."""
    glb = scene_files["two-rooms"]
    sid = kiln_server.api("/v1/scenes", "POST", content=glb.read_bytes(), headers={"X-Filename": glb.name})["id"]
    b = kiln_server.wait_bake(kiln_server.api("/v1/bakes", "POST", json={"scene_id": sid, "config": BAKE})["id"],
                              timeout=300)
    assert b["status"] == "succeeded", b.get("error")
    cam = "b_to_door"
    ctx, pg = _open(browser, kiln_server.url, cam, bundle=None, page="app/kiln-three/example/index.html", bake=b["id"])
    try:
        for mode in ("grid", "mask_normalized"):
            served = _three(pg, mode, "lambert") - _three(pg, "off", "lambert")
            folder = _three(pages[cam], mode, "lambert") - _three(pages[cam], "off", "lambert")
            sel = folder.sum(-1) > 0.02 * folder.sum(-1).mean()
            err = rel_l1(served, folder, sel)
            print(f"server bake vs folder bundle, {mode}: rel L1 {err:.4f}")
            assert served[sel].mean() > 0 and err <= LAMBERT_TOL, (mode, err)
        assert not pg.kiln_errors, pg.kiln_errors
    finally:
        ctx.close()


def test_a_mode_taken_back_from_threes_program_cache_keeps_its_gi(browser, site):
    """mask_normalized, then the plain programs ('grid', 'off'), then mask_normalized again (its program from three's
    cache): the same frame. three reuses the uniforms of a material's last compile with a cached program; before
    the fix the plain compile's uniforms came back without Kiln's textures and the GI was 0."""
    ctx, pg = _open(browser, site, "b_to_door")
    try:
        off = _three(pg, "off", "lambert")
        first = _three(pg, "mask_normalized", "lambert") - off
        _three(pg, "grid", "lambert")
        _three(pg, "off", "lambert")
        again = _three(pg, "mask_normalized", "lambert") - off
        sel = first.sum(-1) > 0.02 * first.sum(-1).mean()
        assert sel.sum() > 100 and again[sel].mean() > 0.5 * first[sel].mean()
        np.testing.assert_allclose(again, first, atol=1e-6 * np.abs(first).max())
        assert not pg.kiln_errors, pg.kiln_errors
    finally:
        ctx.close()


def test_a_turned_bake_frame_is_applied_and_threes_grid_is_resampled_for_it(browser, site, pages):
    """grid.frame: the turned twin (scene turned by R_y(30°), probe artifacts as they were, frame = R_y(30°)ᵀ) seen
    from the turned camera gives the unturned bundle's GI through the material extension (uGiFrame · p, n, v), and
    fails to without the frame (uGiFrame = identity). three's LightProbeGrid, which cannot turn, gets the SH resampled
    onto a world-aligned grid (grid.js resampleShL2) and lights the turned twin as the unturned bundle's grid does."""
    cam = "b_to_door"
    R = _ry(TURN_DEG)
    turned_cam = tuple(tuple(float(x) for x in R @ np.asarray(v)) for v in CAMERAS[cam])
    ctx, pg = _open(browser, site, turned_cam, bundle="bundle-turned")
    try:
        st = pg.evaluate("""(() => {
            const k = window.kiln, pgd = k.probeGrid;
            return { probeGrid: !!pgd, resampled: pgd ? pgd.userData.kilnResampled : null, mode: k.gi.mode,
              resolution: pgd ? pgd.userData.kilnBox.resolution : null,
              frame: Array.from(k.gi.uniforms.uGiFrame.value.elements) }; })()""")
        print("turned bundle:", {k: st[k] for k in ("probeGrid", "resampled", "mode", "resolution")})
        assert st["probeGrid"] and st["resampled"] is True and st["mode"] == "grid", st
        # three's Matrix3 elements are column-major: M's columns, so that uGiFrame * p_world = M · p_world
        M = R.T
        np.testing.assert_allclose(st["frame"], M.T.ravel(), atol=1e-6)

        # three's grid of the turned twin (resampled) against three's grid of the unturned bundle, and each against
        # Kiln's own leaking lookup (what both stand for; three's differs by its half-cell offset along the normal)
        for c2 in CAMERAS:
            ctx2, pg2 = (ctx, pg) if c2 == cam else _open(
                browser, site, tuple(tuple(float(x) for x in R @ np.asarray(v)) for v in CAMERAS[c2]), bundle="bundle-turned")
            try:
                off = _three(pages[c2], "off", "lambert")
                ref = _three(pages[c2], "grid", "lambert") - off
                kiln = _three(pages[c2], "leaking", "lambert") - off
                got = _three(pg2, "grid", "lambert") - _three(pg2, "off", "lambert")
            finally:
                if c2 != cam:
                    ctx2.close()
            sel = ref.sum(-1) > 0.02 * ref.sum(-1).mean()
            e_grids, e_turned, e_unturned = rel_l1(got, ref, sel), rel_l1(got, kiln, sel), rel_l1(ref, kiln, sel)
            print(f"{c2}: three's grid, turned (resampled) / unturned: rel L1 {e_grids:.4f}; against Kiln's leaking "
                  f"lookup {e_turned:.4f} / {e_unturned:.4f}")
            assert got[sel].mean() > 0 and e_turned <= e_unturned + 0.02, (c2, e_turned, e_unturned)
            if c2 == "a_corner":     # the lit room: light that varies smoothly, one more trilinear filter apart
                assert e_grids <= RESAMPLED_TOL, (c2, e_grids)
                lit_grids = e_grids
        ref_off, got_off = _three(pages[cam], "off", "lambert"), _three(pg, "off", "lambert")
        for mode in ("leaking", "mask_normalized", "ddgi"):
            ref = _three(pages[cam], mode, "lambert") - ref_off
            got = _three(pg, mode, "lambert") - got_off
            sel = ref.sum(-1) > 0.02 * ref.sum(-1).mean()
            err = rel_l1(got, ref, sel)
            print(f"turned bake frame, {mode}: rel L1 {err:.2e} against the unturned bundle")
            assert got[sel].mean() > 0 and err <= LAMBERT_TOL, (mode, err)
        # the same frame without the frame: the lookups land elsewhere (the check above can fail)
        pg.evaluate("window.kiln.gi.uniforms.uGiFrame.value.identity()")
        for mode in ("leaking", "mask_normalized"):
            ref = _three(pages[cam], mode, "lambert") - ref_off
            got = _three(pg, mode, "lambert") - got_off
            sel = ref.sum(-1) > 0.02 * ref.sum(-1).mean()
            err = rel_l1(got, ref, sel)
            print(f"turned bake frame ignored (uGiFrame = identity), {mode}: rel L1 {err:.4f}")
            assert err > 10 * LAMBERT_TOL and err > 3 * lit_grids, (mode, err, lit_grids)
        assert not pg.kiln_errors, pg.kiln_errors
    finally:
        ctx.close()
