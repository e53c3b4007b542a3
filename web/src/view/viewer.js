/**
 * Per-frame orchestration of the viewer (glTF-Sample-Viewer's "view" layer): opens a bake (and the scene
 * file when this session uploaded it), streams the artifacts the GI modes need with progress, switches
 * modes, drives the cameras and renders on demand. The renderer is the only GL code; the UI only listens.
 */
import { Box3, Mesh, MeshBasicMaterial, Object3D, PerspectiveCamera, SphereGeometry, Vector3 } from 'three';
import { TransformControls } from 'three/addons/controls/TransformControls.js';
import { ArtifactLoader, loadArtifacts } from '../loader/artifacts.js';
import { loadSceneBytes, loadSceneFile } from '../loader/scene.js';
import { GIRenderer } from '../renderer/renderer.js';
import { hasShader } from '../renderer/shaders.js';
import { probeDataTexture, stackedVolumeTexture, textureFromKTX2, wrapAtlas } from '../renderer/textures.js';
import { atlasColumns } from '../math/atlas.js';
import { parseNpy } from '../loader/npy.js';
import { tableFromKTX2 } from '../loader/ktx2.js';
import { directVector, packPrtCoefficients, relightCoefficients } from '../math/prt.js';
import { frameMatrix, mapLight, pointsToWorld, toBake, toWorld } from '../math/frame.js';
import { gridLayers, gridMinGaps, gridPoint } from '../math/sh.js';
import { GI_MODES, MAX_LIGHTS, PRT_MAX_GROUPS, PROBE_SH_TEXTURES, modeArtifacts, modeAvailability, modeDefines, modeTextures } from '../state/modes.js';
import { lightCoverage } from '../state/lighting.js';
import { SHADOW_CUBES, SHADOW_DIRS } from '../renderer/shadows.js';
import { autoCamera, viewScale } from './autocamera.js';
import { createControls } from './cameras.js';
import { buildLightMarkers, disposeMarkers, pickSurface } from './lightMarkers.js';

/** The renderer's light limits (a pass's lights, shadow maps), for the Lights panel's note (state/lighting.js). */
const LIGHT_LIMITS = { maxLights: MAX_LIGHTS, cubes: SHADOW_CUBES, dirs: SHADOW_DIRS };

/**
 * The grid of a bake, from its place stage's stats (the manifest's `grid`): counts, origin and spacing in the bake
 * frame, `layers` ([xs, ys, zs], bake-frame metres, of a rectilinear grid, checked by math/sh.js gridLayers; null for
 * a uniform grid: probe (i, j, k) at origin + spacing · (i, j, k)) and `frame` (`{yaw_deg, matrix, ...}`, world ->
 * bake; null for a bake without one: the identity; math/frame.js frameMatrix).
 */
export function bakeGrid(bake) {
  const place = (bake?.stages || []).find((s) => s.name === 'place');
  const st = place && place.stats;
  if (!st || !st.counts) return null;
  return { counts: st.counts, origin: st.origin, spacing: st.spacing, layers: gridLayers(st), frame: st.frame || null };
}

/**
 * The world position of grid point (i, j, k) (fractional indices allowed): math/sh.js gridPoint (origin + spacing · ijk,
 * or the layers of a rectilinear grid) is in the bake frame, turned into the world by Mᵀ.
 */
export function gridPointWorld(grid, ijk) {
  return toWorld(frameMatrix(grid), gridPoint(grid, ijk));
}

/**
 * The probe spheres' world positions: `positions` (probe_positions_relocated, bake frame, `stride` numbers per
 * probe, xyz first) turned by Mᵀ; n·3 floats.
 */
export function probeWorldPositions(grid, positions, stride = 3) {
  const [nx, ny, nz] = grid.counts;
  return pointsToWorld(frameMatrix(grid), positions, stride, nx * ny * nz);
}

/**
 * A world light (the relight gizmo's) in the bake frame, where the PRT measurement points are (directVector):
 * position M·x, direction M·d.
 */
export function lightInBakeFrame(grid, light) {
  return mapLight(frameMatrix(grid), light, toBake);
}

/** Scene bounds of a bake, from its ingest stage's stats. */
export function bakeBounds(bake) {
  const ingest = (bake?.stages || []).find((s) => s.name === 'ingest');
  return ingest?.stats?.bounds || null;
}

/**
 * A first exposure for a bake: the light stage's mean probe irradiance (what the probes saw: indirect) plus
 * the median over grid points of the unshadowed direct irradiance of the lights (KHR units, as lights.glsl),
 * so that a surface of albedo 0.75 receiving that displays near mid-grey after the ACES curve. Returns EV
 * (log2 of the exposure) in 0.25 steps, 0 when nothing is known.
 */
export function autoExposureEV(bake, lights = []) {
  const light = (bake?.stages || []).find((s) => s.name === 'light');
  const e = light?.stats?.mean_irradiance;
  let total = Array.isArray(e) ? (e[0] + e[1] + e[2]) / 3 : 0;
  const grid = bakeGrid(bake);
  if (grid && lights.length) {
    const [nx, ny, nz] = grid.counts;
    const vals = [];
    const step = Math.max(1, Math.round(Math.cbrt((nx * ny * nz) / 512)));  // at most ~512 points
    for (let k = 0; k < nz; k += step) for (let j = 0; j < ny; j += step) for (let i = 0; i < nx; i += step) {
      const p = gridPointWorld(grid, [i, j, k]);  // the lights are world
      let sum = 0;
      for (const l of lights) {
        const c = l.color || [1, 1, 1];
        const I = (l.intensity ?? 1) * (c[0] + c[1] + c[2]) / 3;
        if (l.type === 'directional') { sum += I; continue; }
        const d2 = l.position.reduce((s2, x, a) => s2 + (x - p[a]) ** 2, 0);
        sum += I / Math.max(d2, 1e-2);
      }
      vals.push(sum);
    }
    vals.sort((a, b) => a - b);
    total += vals[Math.floor(vals.length / 2)] || 0;
  }
  if (!(total > 0)) return 0;
  const exposure = 0.6 / ((0.75 / Math.PI) * total);
  return Math.max(-10, Math.min(10, Math.round(Math.log2(exposure) * 4) / 4));
}

/** KHR_lights_punctual lights of a loaded glTF, in the form of the `lights` artifact. */
export function gltfLights(root) {
  const out = [];
  if (!root) return out;
  root.updateMatrixWorld(true);
  root.traverse((o) => {
    if (!o.isLight) return;
    const p = new Vector3().setFromMatrixPosition(o.matrixWorld);
    const c = [o.color.r, o.color.g, o.color.b];
    if (o.isPointLight) out.push({ type: 'point', position: p.toArray(), color: c, intensity: o.intensity, range: o.distance || null });
    else if (o.isSpotLight || o.isDirectionalLight) {
      const t = new Vector3().setFromMatrixPosition(o.target.matrixWorld);
      const d = t.sub(p).normalize().toArray();
      if (o.isDirectionalLight) out.push({ type: 'directional', direction: d, color: c, intensity: o.intensity });
      else {
        out.push({
          type: 'spot', position: p.toArray(), direction: d, color: c, intensity: o.intensity, range: o.distance || null,
          outer_cone_angle: o.angle, inner_cone_angle: o.angle * (1 - o.penumbra),
        });
      }
    }
  });
  return out;
}

export class Viewer {
  /**
   * @param {{canvas: HTMLCanvasElement, api: import('../api/client.js').KilnApi, onStatus?: Function, onError?: Function}} opts
   */
  constructor({ canvas, api, onStatus = () => {}, onError = (e) => console.error(e) }) {
    this.canvas = canvas;
    this.api = api;
    this.onStatus = onStatus;
    this.onError = onError;
    this.renderer = new GIRenderer(canvas, { onError: (e) => { this.status({ shaderError: e.message }); onError(e); } });
    this.camera = new PerspectiveCamera(60, 1, 0.02, 500);
    this.controls = createControls(this.camera, canvas, () => this.invalidate());
    this.controls.setMode('orbit');
    this.loader = new ArtifactLoader(api);
    this.bake = null;
    this.artifacts = {};        // name -> decoded artifact (KTX2 parsed / JSON)
    this.loading = new Map();   // name -> promise
    this.mode = 'direct';
    this.shownMode = null;
    this.frames = 0;
    this.dirty = true;
    this.state = { exposure: 1, output: 'shaded', probes: false, probeColoring: 'state', shadows: true };
    this.resizeObserver = new ResizeObserver(() => this.resize());
    this.resizeObserver.observe(canvas);
    this.resize();
    this.last = performance.now();
    this.running = true;
    const loop = (t) => {
      if (!this.running) return;
      const dt = Math.min(0.1, (t - this.last) / 1000);
      this.last = t;
      const moving = this.controls.update(dt);
      if (this.dirty || moving) this.renderNow();
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  status(patch) { this.onStatus(patch); }

  invalidate() { this.dirty = true; }

  resize() {
    const w = Math.max(1, this.canvas.clientWidth), h = Math.max(1, this.canvas.clientHeight);
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.invalidate();
  }

  renderNow() {
    this.dirty = false;
    const ms = this.renderer.render(this.camera);
    this.frames += 1;
    this.canvas.dataset.frames = String(this.frames);
    this.canvas.dataset.shownMode = this.shownMode || 'direct';
    this.status({ frameMs: ms, frameSource: this.renderer.timer.source, frames: this.frames });
    if (ms != null && this.renderer.timer.ext && this.renderer.timer.pending.length) setTimeout(() => this.status({ frameMs: this.renderer.timer.poll() }), 50);
  }

  artifactInfo(name) {
    return (this.bake?.artifacts || []).find((a) => a.name === name) || null;
  }

  /** The modes and whether each can be shown for this bake. */
  modes() {
    const names = (this.bake?.artifacts || []).map((a) => a.name);
    return GI_MODES.map((m) => ({ ...m, ...modeAvailability(m, names, hasShader) }));
  }

  /**
   * Open a bake (may be null: just a scene) with the scene file uploaded in this session (may be null).
   * `camera` (a review camera, a linked view; fov_y in degrees, default 60): the first view; none: autocamera.js.
   * @param {{bake: object|null, sceneFile: File|null, camera?: {position: number[], target: number[], fov_y?: number}, mode?: string}} opts
   */
  async open({ bake, sceneFile, camera, mode }) {
    const gen = (this.generation = (this.generation || 0) + 1);
    const stale = () => gen !== this.generation;  // another open() started meanwhile: drop this one's results
    this.bake = bake;
    this.artifacts = {};
    this.loading = new Map();
    this.mode = 'direct';
    this.renderer.setModeShader('mode_direct.glsl');
    this.shownMode = 'direct';
    let root = null;
    let note = '';
    let sceneSource = null;  // 'file' (uploaded in this session) | 'server' (the bake's `scene` artifact) | null
    if (sceneFile) {
      try {
        root = await loadSceneFile(sceneFile);
        sceneSource = 'file';
      } catch (e) {
        note = `could not load ${sceneFile.name} in the browser: ${e.message}`;
      }
    }
    if (!root && bake && this.artifactInfo('scene')) {
      try {
        // the GLB the ingest stage wrote; progress stays below 1 ("volumes loaded" is for the GI volumes)
        const info = this.artifactInfo('scene');
        const bytes = await this.loader.bytes(bake.id, info, (got, total) => {
          if (!stale()) this.status({ loading: Math.min(0.99, got / (total || info.bytes || 1)), loadingLabel: 'scene' });
        });
        root = await loadSceneBytes(bytes);
        sceneSource = 'server';
        note = '';
      } catch (e) {
        note = `could not load the baked scene: ${e.message}`;
      }
    } else if (!root && bake && !note) {
      note = 'This bake has no scene artifact (baked before bundles carried the scene) and the file is not in this browser session: showing the probes over an empty scene.';
    }
    if (stale()) return;
    this.sceneSource = sceneSource;
    this.canvas.dataset.scene = sceneSource || 'none';
    this.editLightList = null;
    if (this.editGizmo) { this.editGizmo.enabled = false; this.editGizmo.getHelper().visible = false; }
    this.renderer.setScene(root);
    this.root = root;
    const grid = bakeGrid(bake);
    if (grid) this.renderer.setGrid(grid);
    this.renderer.setFrame(frameMatrix(grid));  // the GI modes' lookups in the bake frame (identity without one)
    const bounds = bakeBounds(bake);
    const cam = camera || autoCamera(root, bounds);
    const size = bounds ? Math.hypot(...bounds[1].map((x, i) => x - bounds[0][i])) : 10;
    const scale = viewScale(size);        // clip planes and fly speed follow the scene's size, whatever its unit
    this.camera.near = scale.near;
    this.camera.far = scale.far;
    this.camera.updateProjectionMatrix();
    this.controls.fly.speed = scale.speed;
    this.setView(cam);
    this.userExposure = false;
    const ev = autoExposureEV(bake, gltfLights(root));
    this.set({ exposure: 2 ** ev });
    this.status({ exposureEV: ev, note, modes: this.modes(), mode: this.mode, shownMode: 'direct', grid, hasScene: !!root, rendererInfo: this.renderer.info });
    // direct light at once: the scene's own lights now, the bake's resolved lights (+ config lights, sky) soon
    this.bakeLights = gltfLights(root);
    this.renderer.setLights(this.bakeLights);
    this.status({ lightNote: lightCoverage(this.bakeLights, LIGHT_LIMITS) });
    this.setLightMarkers(this.bakeLights);
    this.renderer.setSky([0, 0, 0]);
    this.renderer.setMaterialOptions((bake && bake.config && bake.config.scene) || {});
    this.prt = null;
    this.prtLightsOn = false;
    this.showGizmo(false);
    this.invalidate();
    if (!bake) return;
    if (this.artifactInfo('lights')) {
      const lights = await this.fetch(['lights']);
      if (stale()) return;
      this.bakeLights = lights.lights.lights || [];
      if (!this.prtLightsOn) this.renderer.setLights(this.bakeLights);
      this.status({ lightNote: lightCoverage(this.bakeLights, LIGHT_LIMITS) });
      if (!this.editLightList) this.setLightMarkers(this.bakeLights);
      this.renderer.setSky(lights.lights.sky || [0, 0, 0]);
      if (!this.userExposure) {
        const ev = autoExposureEV(bake, lights.lights.lights || []);
        this.set({ exposure: 2 ** ev });
        this.status({ exposureEV: ev });
      }
      this.invalidate();
    }
    // stream the probe data and every available mode's volumes in the background, with progress
    // clusters: MD anneal (colouring); sh_l1_*: the probe spheres' SH colouring (L1, whatever the modes use)
    const wanted = ['probe_positions_relocated', 'probe_states', 'clusters', 'sh_l1_r', 'sh_l1_g', 'sh_l1_b'];
    const names = (bake.artifacts || []).map((a) => a.name);
    for (const m of this.modes()) if (m.available) wanted.push(...modeArtifacts(m, names, this.artifacts, this.shCaps()));
    const stream = this.fetch(wanted.filter((n) => this.artifactInfo(n)))
      .then(() => { if (!stale()) this.buildProbes(); })
      .catch((e) => this.onError(e));
    if (!root) this.setProbes({ visible: true });
    if (mode && mode !== 'direct') await this.setMode(mode);
    await stream;
  }

  /** Fetch and decode artifacts (each once), reporting combined progress. */
  async fetch(names) {
    const artifacts = this.artifacts, loading = this.loading, bake = this.bake;  // of this open(): a later one replaces them
    const todo = names.filter((n) => !(n in artifacts) && !loading.has(n));
    if (todo.length) {
      const infos = todo.map((n) => {
        const info = (bake?.artifacts || []).find((a) => a.name === n);
        if (!info) throw new Error(`bake ${bake?.id} has no artifact ${n}`);
        return info;
      });
      const report = (f, label) => { if (bake === this.bake) this.status({ loading: f, loadingLabel: label }); };
      const p = loadArtifacts(this.loader, bake.id, infos, report)
        .then((got) => { Object.assign(artifacts, got); report(1, ''); });
      for (const n of todo) loading.set(n, p);
    }
    await Promise.all(names.map((n) => loading.get(n)));
    return Object.fromEntries(names.map((n) => [n, artifacts[n]]));
  }

  buildProbes() {
    const grid = bakeGrid(this.bake);
    const pos = this.artifacts.probe_positions_relocated;
    if (!grid || !pos) return;
    const states = this.artifacts.probe_states ? this.artifacts.probe_states.data : null;
    const radius = 0.12 * Math.min(...gridMinGaps(grid));   // the spacing; a rectilinear grid's smallest layer gap
    const clusters = this.artifacts.clusters ? this.artifacts.clusters.data : null;
    const positions = probeWorldPositions(grid, pos.data, pos.components);  // bake frame -> world
    this.renderer.setProbes({ positions, stride: 3, states, clusters, counts: grid.counts, radius });
    if (this.artifacts.sh_l1_r) this.bindTextures(PROBE_SH_TEXTURES);
    this.renderer.setProbeDisplay({ visible: this.state.probes, coloring: this.state.probeColoring });
    this.invalidate();
  }

  artifactNames() {
    return (this.bake?.artifacts || []).map((a) => a.name);
  }

  /**
   * What decides a mode's SH order besides the artifact names (state/modes.js shOrder): the device's largest 3D
   * texture and the grid's nz (the L2 cluster stack is 7·K·(nz + 2) deep).
   */
  shCaps() {
    const grid = bakeGrid(this.bake);
    return { max3D: this.renderer.max3DTextureSize, maxTexture: this.renderer.maxTextureSize,
      nz: grid ? Number(grid.counts[2]) : 0 };
  }

  /** Upload and bind a mode's textures (as workers/render/shading.py prepare_mode) and set its uniforms. */
  bindModeTextures(mode) {
    const names = this.artifactNames();
    if (!this.bindTextures(modeTextures(mode, names, this.artifacts, this.shCaps()))) return false;
    if (mode.uniforms) {
      const grid = bakeGrid(this.bake);
      this.renderer.setModeUniforms(mode.uniforms({ grid, names, bake: this.bake, info: (n) => this.artifactInfo(n),
        artifacts: this.artifacts, caps: this.shCaps() }));
    }
    return true;
  }

  /** A DDGI atlas as bound: re-packed when wider than the device allows (math/atlas.js, textures.js wrapAtlas). */
  atlasFor(name) {
    const a = this.artifacts[name];
    const grid = bakeGrid(this.bake);
    const t = Math.floor(a.height / Number(grid.counts[1]));
    return wrapAtlas(a, grid.counts, atlasColumns(a.width, t, this.renderer.maxTextureSize));
  }

  /** Upload and bind {uniform: [artifact name | names, kind]} (false while an artifact is not loaded yet). */
  bindTextures(map) {
    const textures = {};
    const options = { floatLinear: this.renderer.floatLinear };
    for (const [uniform, [src, kind]] of Object.entries(map)) {
      const list = Array.isArray(src) ? src : [src];
      if (list.some((n) => !this.artifacts[n])) return false;
      const key = `${kind}:${list.join(',')}`;
      if (this.renderer.hasTextures([uniform]) && this.renderer.modeTextures[uniform].value.userData.artifact === key) continue;
      let tex;
      if (kind === 'stack') tex = stackedVolumeTexture(list.map((n) => this.artifacts[n]), options);
      else if (kind === 'probe-data') tex = probeDataTexture(this.artifacts[list[0]], this.artifacts[list[1]]);
      else if (kind === 'atlas') tex = textureFromKTX2(this.atlasFor(list[0]), options);
      else tex = textureFromKTX2(this.artifacts[list[0]], { ...options, filter: kind.endsWith('nearest') ? 'nearest' : 'linear' });
      tex.userData.artifact = key;
      textures[uniform] = tex;
    }
    this.renderer.setTextures(textures);
    return true;
  }

  // ------------------------------------------------------------------ PRT relighting
  /**
   * Parse the PRT arrays once (KTX2 tables, or npy in older bakes: points, offsets, transfer) and place the
   * relight light (world): the bake's first point light (`lights` is world), else the centre of the grid (mapped to
   * the world) with the first scenario light's colour and intensity (`prt_lights` is in the bake frame: only its
   * colour and intensity are used here).
   */
  setupPrt() {
    if (this.prt) return this.prt;
    const sec = this.artifacts.prt;
    if (sec.channels !== 'mono' || (sec.gamma !== null && sec.gamma !== undefined)) {
      throw new Error(`PRT relighting in the viewer needs a mono, linear basis (got channels ${sec.channels}, gamma ${sec.gamma})`);
    }
    const table = (n) => {
      const a = this.artifacts[n];
      if (a && a.shape) return a;
      return a && a.vkFormat !== undefined ? tableFromKTX2(a, this.artifactInfo(n)?.shape) : parseNpy(a);
    };
    const points = table(sec.points || 'prt_points');
    const offsets = table(sec.point_offsets || 'prt_point_offsets');
    const transfer = table(sec.sh?.transfer || 'prt_sh_transfer');
    const n = Number(sec.basis);
    if (transfer.shape[0] !== 3 || transfer.shape[1] !== n) throw new Error(`prt_sh_transfer has shape ${transfer.shape}, want (3, ${n}, M + 1)`);
    const grid = bakeGrid(this.bake);
    const base = (this.bakeLights || []).find((l) => l.type === 'point');
    const scenario = (this.artifacts.prt_lights?.configurations || []).flat().find((l) => l.type === 'point');
    const centre = grid ? gridPointWorld(grid, grid.counts.map((c) => (c - 1) / 2)) : [0, 1, 0];
    const light = {
      type: 'point', position: [...(base?.position || centre)], color: [...(base?.color || scenario?.color || [1, 1, 1])],
      intensity: base?.intensity ?? scenario?.intensity ?? 10, range: base?.range ?? null,
    };
    this.prt = { section: sec, n, points: points.data, offsets: offsets.data, transfer: transfer.data, light, x: null, u: null };
    return this.prt;
  }

  /**
   * Recompute the PRT coefficients for the relight light (unshadowed direct at the measurement points, which are in
   * the bake frame: the world light is turned into it first). The direct light drawn stays the world light.
   */
  relight() {
    const p = this.prt;
    if (!p) return null;
    const t0 = performance.now();
    p.x = directVector(p.points, p.offsets, [lightInBakeFrame(bakeGrid(this.bake), p.light)]);
    p.u = relightCoefficients(p.transfer, p.n, p.x, p.section.norm || 'l2');
    this.renderer.setModeUniforms({ uPrtCoef: packPrtCoefficients(p.u, p.n, PRT_MAX_GROUPS) });
    if (this.mode === 'prt') this.renderer.setLights([p.light]);
    p.ms = performance.now() - t0;
    this.status({ relightMs: p.ms, prtLight: p.light.position });
    this.invalidate();
    return p;
  }

  /** Move the relight light (world position, metres); the gizmo follows. */
  setPrtLight(position) {
    if (!this.prt) throw new Error('no PRT relighting loaded (switch to the PRT mode first)');
    this.prt.light.position = [...position];
    if (this.gizmoTarget) this.gizmoTarget.position.fromArray(position);
    return this.relight();
  }

  showGizmo(on) {
    if (on && !this.gizmo) {
      const target = new Object3D();
      const marker = new Mesh(new SphereGeometry(1, 16, 12), new MeshBasicMaterial({ color: 0xffee88 }));
      target.add(marker);
      this.gizmoTarget = target;
      this.gizmoMarker = marker;
      const tc = new TransformControls(this.camera, this.canvas);
      tc.attach(target);
      tc.addEventListener('dragging-changed', (e) => { this.controls.orbit.enabled = !e.value && this.controls.mode === 'orbit'; });
      tc.addEventListener('objectChange', () => {
        if (!this.prt) return;
        this.prt.light.position = target.position.toArray();
        this.relight();
      });
      tc.addEventListener('change', () => this.invalidate());
      this.gizmo = tc;
      this.renderer.overlay.add(target);  // the overlay casts no shadows (the marker encloses the light)
      this.renderer.overlay.add(tc.getHelper());
    }
    if (!this.gizmo) return;
    const visible = !!on && !!this.prt;
    if (visible) {
      this.gizmoTarget.position.fromArray(this.prt.light.position);
      const grid = bakeGrid(this.bake);
      const r = grid ? 0.08 * Math.min(...gridMinGaps(grid).filter((x) => x > 0)) : 0.05;
      this.gizmoMarker.scale.setScalar(r || 0.05);
    }
    this.gizmoTarget.visible = visible;
    this.gizmo.getHelper().visible = visible;
    this.gizmo.enabled = visible;
    this.invalidate();
  }

  /** Switch GI mode; resolves once the mode is on screen (its volumes streamed and bound). */
  async setMode(id) {
    const mode = this.modes().find((m) => m.id === id);
    if (!mode) throw new Error(`unknown GI mode ${id}`);
    if (!mode.available) { this.status({ modeError: `${mode.label}: ${mode.reason}${mode.missing.length ? ` (${mode.missing.join(', ')})` : ''}` }); return false; }
    this.mode = id;
    this.status({ mode: id, modeError: '' });
    if (mode.prerequisites) await this.fetch(mode.prerequisites.filter((n) => this.artifactInfo(n)));
    if (this.mode !== id) return false;
    const optional = new Set(mode.prerequisites || []);
    await this.fetch(modeArtifacts(mode, this.artifactNames(), this.artifacts, this.shCaps()).filter((n) => !optional.has(n) || this.artifactInfo(n)));
    if (this.mode !== id) return false;  // the user moved on meanwhile
    if (id === 'prt') {
      try {
        this.setupPrt();
      } catch (e) {
        this.mode = this.shownMode || 'direct';
        this.status({ mode: this.mode, modeError: e.message });
        return false;
      }
    }
    this.bindModeTextures(mode);
    if (id === 'prt') this.relight();  // PRT mode: the relight light alone, direct and indirect
    else if (this.prtLightsOn) this.renderer.setLights(this.bakeLights || []);
    this.prtLightsOn = id === 'prt';
    this.showGizmo(id === 'prt');
    // KILN_SH_L2 where the bake has the L2 volumes (the default evaluation, docs/architecture.md); the layer lookup
    // of a rectilinear grid is compiled only for such a bake (probe_grid.glsl KILN_GRID_RECTILINEAR)
    const defines = modeDefines(mode, this.artifactNames(), this.artifacts, this.shCaps());
    if (bakeGrid(this.bake)?.layers) defines.KILN_GRID_RECTILINEAR = true;
    this.renderer.setModeShader(mode.shader, defines);
    this.shownMode = id;
    this.renderer.compile(this.camera);
    this.invalidate();
    this.status({ shownMode: id, prt: id === 'prt' });
    return true;
  }

  set(patch) {
    Object.assign(this.state, patch);
    if ('exposure' in patch) this.renderer.setExposure(patch.exposure);
    if ('output' in patch) this.renderer.setOutput(patch.output);
    if ('shadows' in patch) this.renderer.setShadows(patch.shadows);
    this.renderer.setProbeDisplay({ visible: this.state.probes, coloring: this.state.probeColoring });
    this.invalidate();
  }

  setProbes({ visible, coloring }) {
    const patch = {};
    if (visible !== undefined) patch.probes = visible;
    if (coloring !== undefined) patch.probeColoring = coloring;
    this.set(patch);
    this.status({ probes: this.state.probes, probeColoring: this.state.probeColoring });
  }

  setCameraMode(mode) {
    this.controls.setMode(mode);
    this.status({ cameraMode: mode });
    this.invalidate();
  }

  cameraState() {
    return { position: this.camera.position.toArray(), target: this.controls.orbit.target.toArray() };
  }

  /** Look from `position` at `target` (glTF coordinates, metres) with a vertical field of view of `fov_y` degrees. */
  setView({ position, target, fov_y: fovY }) {
    this.camera.fov = Number.isFinite(fovY) && fovY > 1 && fovY < 179 ? fovY : 60;
    this.camera.updateProjectionMatrix();
    this.controls.lookAt(position, target);
    this.invalidate();
  }

  /**
   * The view as a review camera: position, a target the camera looks at (in fly mode the orbit target is left
   * behind: a point as far in front of the camera), fov_y (degrees); glTF coordinates.
   */
  viewState() {
    const position = this.camera.position.clone();
    const forward = new Vector3(0, 0, -1).applyQuaternion(this.camera.quaternion);
    const dist = Math.max(0.25, position.distanceTo(this.controls.orbit.target));
    const target = position.clone().addScaledVector(forward, dist);
    return { position: position.toArray(), target: target.toArray(), fov_y: this.camera.fov };
  }

  /** The automatic first view (autocamera.js: inside a room for closed scenes, outside for open ones). */
  autoView() {
    return autoCamera(this.root, bakeBounds(this.bake));
  }

  // ------------------------------------------------------------------ lights on screen, placing lights
  /** Draw markers for `lights` (every mode; the overlay casts no shadows). */
  setLightMarkers(lights) {
    if (this.lightMarkers) { this.renderer.overlay.remove(this.lightMarkers); disposeMarkers(this.lightMarkers); }
    this.lightMarkers = buildLightMarkers(lights || [], bakeBounds(this.bake) || this.sceneBounds());
    this.lightMarkers.visible = this.state.lightMarkers !== false;
    this.renderer.overlay.add(this.lightMarkers);
    this.canvas.dataset.lightMarkers = String((lights || []).length);
    this.invalidate();
  }

  /** Show or hide the light markers. */
  showLightMarkers(on) {
    this.state.lightMarkers = !!on;
    if (this.lightMarkers) this.lightMarkers.visible = !!on;
    this.invalidate();
  }

  /** [[min], [max]] of the loaded scene's geometry (when no bake says it). */
  sceneBounds() {
    if (!this.root) return null;
    const b = new Box3().setFromObject(this.root);
    return b.isEmpty() ? null : [b.min.toArray(), b.max.toArray()];
  }

  /** The surface under a canvas pixel and the light position PLACE_OFFSET in front of it (lightMarkers.js). */
  pick(clientX, clientY) {
    return pickSurface(this.root, this.camera, this.canvas, clientX, clientY);
  }

  /**
   * Lights being edited (the bake form's): drawn instead of the bake's, with a drag gizmo on light `active`
   * (null: none). `onMove(index, position)` while it is dragged. `editLights(null)` goes back to the bake's lights.
   */
  editLights(lights, active = null, onMove = null) {
    this.editLightList = lights;
    this.setLightMarkers(lights || this.bakeLights || []);
    if (!this.editGizmo) {
      const target = new Object3D();
      const tc = new TransformControls(this.camera, this.canvas);
      tc.attach(target);
      tc.addEventListener('dragging-changed', (e) => { this.controls.orbit.enabled = !e.value && this.controls.mode === 'orbit'; this.gizmoDragging = e.value; });
      tc.addEventListener('objectChange', () => { if (this.onEditMove) this.onEditMove(this.editIndex, target.position.toArray()); });
      tc.addEventListener('change', () => this.invalidate());
      this.renderer.overlay.add(target);
      this.renderer.overlay.add(tc.getHelper());
      this.editGizmo = tc;
      this.editTarget = target;
    }
    const l = lights && active != null ? lights[active] : null;
    const on = !!(l && l.position);
    this.editIndex = active;
    this.onEditMove = onMove;
    if (on) this.editTarget.position.fromArray(l.position);
    this.editGizmo.enabled = on;
    this.editGizmo.getHelper().visible = on;
    this.invalidate();
  }

  dispose() {
    this.running = false;
    this.resizeObserver.disconnect();
    this.renderer.three.dispose();
  }
}
