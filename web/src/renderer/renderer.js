/**
 * The renderer: the only module that touches WebGL (through three.js). It owns the shared uniforms (lights,
 * probe grid, GI textures, exposure), replaces the glTF's materials with our proto/glsl programs for the
 * current GI mode, draws the probe spheres, and times frames.
 */
import { isUnlitMesh } from './unlit.js';
import {
  Color, DoubleSide, GLSL3, FrontSide, Group, InstancedBufferAttribute, InstancedBufferGeometry, Matrix3, Mesh, RawShaderMaterial,
  Scene, SphereGeometry, Vector3, Vector4, WebGLRenderer,
} from 'three';
import { formatCompileErrors } from './preprocess.js';
import { GLSL_SOURCES, shaderSource } from './shaders.js';
import { preprocess } from './preprocess.js';
import probeClusterFrag from './glsl/probe_cluster.frag.glsl?raw';
import { MASK_BLEND, MASK_SEEN_THRESHOLD, MAX_LIGHTS, MODE_SAMPLERS, PRT_MAX_GROUPS } from '../state/modes.js';
import { FrameTimer } from './timer.js';
import { gridLayersTexture } from './textures.js';
import { gridLayers } from '../math/sh.js';
import { ShadowMaps } from './shadows.js';

const LIGHT_TYPES = { point: 0, spot: 1, directional: 2 };
const OUTPUTS = { shaded: 0, indirect: 1, direct: 2, albedo: 3 };

export class ShaderCompileError extends Error {}

/** ACES fit + sRGB of a linear colour, as tonemap.glsl does (for the clear colour). */
function displayColor(rgb, exposure) {
  const aces = (x) => Math.min(1, Math.max(0, (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)));
  const srgb = (c) => (c <= 0.0031308 ? c * 12.92 : 1.055 * c ** (1 / 2.4) - 0.055);
  return rgb.map((c) => srgb(aces(Math.max(0, c) * exposure)));
}

export class GIRenderer {
  /** @param {HTMLCanvasElement} canvas */
  constructor(canvas, { onError } = {}) {
    this.three = new WebGLRenderer({ canvas, antialias: true, powerPreference: 'high-performance' });
    this.three.setPixelRatio(Math.min(2, globalThis.devicePixelRatio || 1));
    this.gl = this.three.getContext();
    this.onError = onError || ((e) => console.error(e));
    this.sources = new Map();  // preprocessed code -> line map, to name files in compile errors
    this.three.debug.onShaderError = (gl, program, vs, fs) => this.reportShaderError(gl, vs, fs);
    this.floatLinear = this.three.extensions.has('OES_texture_float_linear');
    this.max3DTextureSize = this.gl.getParameter(this.gl.MAX_3D_TEXTURE_SIZE) || 256;  // the L2 cluster stack's limit
    this.maxTextureSize = this.gl.getParameter(this.gl.MAX_TEXTURE_SIZE) || 4096;   // wider DDGI atlases are re-packed
    this.timer = new FrameTimer(this.gl);
    this.lightsVec = () => Array.from({ length: MAX_LIGHTS }, () => new Vector4());
    this.shared = {
      uSpecularGI: { value: 1 },   // the bake's scene.specular_gi: 0 none, 1 metals, 2 all (material.glsl)
      uMaxAlbedo: { value: 0 },    // the bake's scene.max_albedo, 0 = no clamp
      uExposure: { value: 1 },
      uIndirectScale: { value: 1 },
      uOutput: { value: 0 },
      uLightCount: { value: 0 },
      uLightPosType: { value: this.lightsVec() },
      uLightDirRange: { value: this.lightsVec() },
      uLightColor: { value: this.lightsVec() },
      uLightCone: { value: this.lightsVec() },
      uGridOrigin: { value: new Vector3() },
      uGridSpacing: { value: new Vector3(1, 1, 1) },
      uGridCounts: { value: new Vector3(1, 1, 1) },
      // a rectilinear grid's layers (probe_grid.glsl giGridIndex; setGrid): off, and a 1 x 3 dummy so the sampler
      // always has an R32F texture (the scene programs' samplers: 2 material maps + 6 shadow maps + at most 4 of a
      // mode (mask) + this one = 13 of WebGL2's minimum 16 MAX_TEXTURE_IMAGE_UNITS)
      uGridRectilinear: { value: false },
      uGridLayers: { value: gridLayersTexture(null) },
      // world -> bake frame (proto/glsl/gi_view.glsl; math/frame.js): GLSL ES has no uniform initializers, so the
      // identity is set here (an unset mat3 is 0); setFrame replaces it
      uGiFrame: { value: new Matrix3() },
      // the GI modes' scalar uniforms (workers/render/shading.py prepare_mode); setModeUniforms sets them
      uDdgiBias: { value: 0 },
      uIrradianceTexels: { value: 8 },
      uDepthTexels: { value: 16 },
      uIrradianceColumns: { value: 0 },  // tiles per row of a re-packed (too wide) DDGI atlas, 0 = as stored
      uDepthColumns: { value: 0 },
      uClusterCount: { value: 1 },
      uMaskS: { value: 1 },
      uMaskT: { value: 2 },
      uMaskLo: { value: 0 },
      uMaskOffset: { value: 0 },
      uMaskSeen: { value: MASK_SEEN_THRESHOLD },
      uMaskBlend: { value: new Float32Array(MASK_BLEND) },
      uPrtGroups: { value: 0 },
      uPrtCoef: { value: new Float32Array(3 * PRT_MAX_GROUPS * 4) },
      ...ShadowMaps.uniforms(MAX_LIGHTS),
    };
    this.shadowsEnabled = true;
    this.shadowsDirty = true;
    this.shadows = null;
    this.lights = [];
    // uniform name -> {value: texture}; every slot any mode or the probe shader binds exists from the start,
    // so programs compiled before a texture arrives still pick it up
    // (a sampler left null gets three.js' empty texture of its type: the K <= 4 atlas, plain mask's weights)
    this.modeTextures = {};
    for (const name of MODE_SAMPLERS) this.modeTextures[name] = { value: null };
    this.world = new Scene();
    this.overlay = new Group();  // gizmos: drawn, but hidden from the shadow passes
    this.overlay.name = 'kiln:overlay';
    this.world.add(this.overlay);
    this.sceneRoot = null;
    this.materials = new Map();  // original material -> our RawShaderMaterial
    this.modeShader = 'mode_direct.glsl';
    this.modeDefines = {};  // the GI mode shader's #defines (state/modes.js modeDefines: KILN_SH_L2)
    this.probeMesh = null;
    this.sky = [0, 0, 0];
    this.updateClearColor();
  }

  get info() {
    const gl = this.gl;
    const dbg = gl.getExtension('WEBGL_debug_renderer_info');
    return {
      renderer: dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
      floatLinear: this.floatLinear,
      timer: this.timer.source,
    };
  }

  /**
   * Preprocessed source for a RawShaderMaterial. three.js puts its own `#define SHADER_NAME` lines before
   * the source and writes the version line itself (glslVersion GLSL3), so ours is dropped here.
   */
  source(entry, slots = {}) {
    const scene = entry === 'scene.frag.glsl';
    const defines = { MAX_LIGHTS, KILN_SHADOWS: this.shadowsEnabled && scene, ...(scene ? this.modeDefines : {}) };
    const s = shaderSource(entry, { slots, defines });
    const code = s.code.slice(s.code.indexOf('\n') + 1);
    this.sources.set(code, s.lineMap.slice(1));
    return code;
  }

  reportShaderError(gl, vs, fs) {
    const parts = [];
    for (const sh of [vs, fs]) {
      if (gl.getShaderParameter(sh, gl.COMPILE_STATUS)) continue;
      const full = gl.getShaderSource(sh);
      let map = [];
      for (const [code, lm] of this.sources) {  // our code is the tail of what three compiled
        if (!full.endsWith(code)) continue;
        const prefix = full.slice(0, full.length - code.length).split('\n').length - 1;
        map = [...Array.from({ length: prefix }, () => ({ file: '<three.js prefix>', line: 0 })), ...lm];
        break;
      }
      parts.push(formatCompileErrors(gl.getShaderInfoLog(sh), full, map));
    }
    const err = new ShaderCompileError(`GLSL compile error\n${parts.join('\n\n')}`);
    this.lastShaderError = err;
    this.onError(err);
  }

  setSize(width, height) {
    this.three.setSize(width, height, false);
  }

  setExposure(x) { this.shared.uExposure.value = x; this.updateClearColor(); }
  setOutput(name) { this.shared.uOutput.value = OUTPUTS[name] ?? 0; }

  /** The bake's material options (config.scene.specular_gi, max_albedo), as the bake read the scene. */
  setMaterialOptions(scene = {}) {
    this.shared.uSpecularGI.value = { none: 0, metals: 1, all: 2 }[scene.specular_gi ?? 'metals'] ?? 1;
    this.shared.uMaxAlbedo.value = scene.max_albedo ?? 0;
  }

  setSky(sky) {
    this.sky = sky || [0, 0, 0];
    this.updateClearColor();
  }

  updateClearColor() {
    const s = this.sky;
    const c = Math.max(...s) > 0 ? displayColor(s, this.shared.uExposure.value) : [0.105, 0.117, 0.137];
    this.three.setClearColor(new Color().setRGB(c[0], c[1], c[2], 'srgb'), 1);  // display-encoded: sRGB in, sRGB out
  }

  /**
   * Lights in the form of the `lights` artifact / workers.scene: {type, position, direction (travel),
   * color, intensity, range, inner_cone_angle, outer_cone_angle}. Only the first MAX_LIGHTS are used.
   */
  setLights(lights) {
    const u = this.shared;
    const list = (lights || []).filter((l) => l.type in LIGHT_TYPES).slice(0, MAX_LIGHTS);
    u.uLightCount.value = list.length;
    list.forEach((l, i) => {
      const p = l.position || [0, 0, 0];
      const d = l.direction || [0, 0, -1];
      const dl = Math.hypot(...d) || 1;
      const c = l.color || [1, 1, 1];
      const I = l.intensity ?? 1;
      u.uLightPosType.value[i].set(p[0], p[1], p[2], LIGHT_TYPES[l.type]);
      u.uLightDirRange.value[i].set(d[0] / dl, d[1] / dl, d[2] / dl, l.range && Number.isFinite(l.range) ? l.range : 0);
      u.uLightColor.value[i].set(c[0] * I, c[1] * I, c[2] * I, 0);
      const inner = l.inner_cone_angle ?? 0, outer = l.outer_cone_angle ?? Math.PI / 4;
      u.uLightCone.value[i].set(Math.cos(inner), Math.cos(outer), 0, 0);
    });
    this.lights = list;
    this.shadowsDirty = true;
  }

  /** Shadowed direct light on or off (recompiles the scene programs). */
  setShadows(on) {
    if (this.shadowsEnabled === !!on) return;
    this.shadowsEnabled = !!on;
    this.shadowsDirty = true;
    const frag = this.source('scene.frag.glsl', { mode: this.modeShader });
    for (const m of this.materials.values()) { m.fragmentShader = frag; m.needsUpdate = true; }
  }

  /**
   * The probe grid of the GI lookups (probe_grid.glsl): origin, spacing (metres, bake frame), counts, and a
   * rectilinear grid's `layers` ([xs, ys, zs], metres; math/sh.js gridLayers checks them) as uGridRectilinear and the
   * uGridLayers texture (textures.js gridLayersTexture; a 1 x 3 dummy for a uniform grid). The old layers texture is
   * disposed.
   * @param {{origin: number[], spacing: number[], counts: number[], layers?: number[][]|null}} grid
   */
  setGrid(grid) {
    const layers = gridLayers(grid);
    this.shared.uGridOrigin.value.fromArray(grid.origin);
    this.shared.uGridSpacing.value.fromArray(grid.spacing);
    this.shared.uGridCounts.value.fromArray(grid.counts);
    const old = this.shared.uGridLayers.value;
    this.shared.uGridLayers.value = gridLayersTexture(layers);
    this.shared.uGridRectilinear.value = !!layers;
    if (old) old.dispose();
    this.grid = grid;
  }

  /**
   * The bake frame: M (3 rows, world -> bake; math/frame.js frameMatrix of the bake's grid) as uGiFrame, so that
   * uGiFrame * p_world = M · p_world in the scene and probe shaders. The identity for a bake without `grid.frame`.
   * @param {number[][]} m
   */
  setFrame(m) {
    this.shared.uGiFrame.value.set(...m[0], ...m[1], ...m[2]);  // Matrix3.set takes rows, stores columns (GLSL's order)
    this.frame = m;
  }

  /** Bind textures by uniform name (shared by every scene material and the probe spheres). */
  setTextures(textures) {
    for (const [name, tex] of Object.entries(textures)) {
      if (!this.modeTextures[name]) throw new Error(`no texture slot ${name} (declare it in state/modes.js)`);
      const slot = this.modeTextures[name];
      if (slot.value && slot.value !== tex) slot.value.dispose();
      slot.value = tex;
    }
  }

  /** Scalar / array uniforms of the GI modes (uDdgiBias, uMaskS, uPrtCoef, ...). */
  setModeUniforms(values) {
    for (const [name, v] of Object.entries(values)) {
      const u = this.shared[name];
      if (!u) throw new Error(`no mode uniform ${name} (declare it in renderer.js shared)`);
      if (ArrayBuffer.isView(u.value)) u.value.set(v); else u.value = v;
    }
  }

  hasTextures(names) {
    return names.every((n) => this.modeTextures[n] && this.modeTextures[n].value);
  }

  sceneMaterial(original) {
    let m = this.materials.get(original);
    if (m) return m;
    const color = original.color ? original.color.clone() : new Color(1, 1, 1);  // linear (GLTFLoader)
    const emissive = original.emissive ? original.emissive.clone().multiplyScalar(original.emissiveIntensity ?? 1) : new Color(0, 0, 0);
    m = new RawShaderMaterial({
      name: `kiln:${original.name || 'material'}`,
      glslVersion: GLSL3,
      vertexShader: this.source('scene.vert.glsl'),
      fragmentShader: this.source('scene.frag.glsl', { mode: this.modeShader }),
      uniforms: {
        ...this.shared,
        ...this.modeTextures,
        uBaseColor: { value: color },
        uBaseColorMap: { value: original.map || null },
        uHasBaseColorMap: { value: !!original.map },
        uEmissive: { value: emissive },
        // glTF's material model as the bake reads it (workers/kernels/materials.py, proto/glsl/material.glsl)
        uBaseAlpha: { value: original.opacity ?? 1 },
        uHasVertexColor: { value: !!original.vertexColors },
        uMetallic: { value: original.metalness ?? 0 },
        uRoughness: { value: original.roughness ?? 1 },
        uMetallicRoughnessMap: { value: original.metalnessMap || original.roughnessMap || null },
        uHasMetallicRoughnessMap: { value: !!(original.metalnessMap || original.roughnessMap) },
        // MASK: GLTFLoader's alphaTest is the cutoff; BLEND (transparent) is baked as a cutout at 0.5
        uAlphaCutoff: { value: original.alphaTest > 0 ? original.alphaTest : (original.transparent ? 0.5 : -1) },
      },
      side: original.side === DoubleSide ? DoubleSide : FrontSide,
    });
    this.materials.set(original, m);
    return m;
  }

  /** Show a loaded glTF scene (or null for none), its materials replaced by ours. */
  setScene(root) {
    if (this.sceneRoot) this.world.remove(this.sceneRoot);
    this.sceneRoot = root;
    this.shadowsDirty = true;
    if (!root) return;
    root.traverse((obj) => {
      if (!obj.isMesh) return;
      if (isUnlitMesh(obj)) { obj.castShadow = false; return; }  // drawn as the file says: the bake left it out
      const geo = obj.geometry;
      if (!geo.attributes.normal) geo.computeVertexNormals();
      const mats = Array.isArray(obj.material) ? obj.material : [obj.material];
      const ours = mats.map((mat) => this.sceneMaterial(mat.userData.kilnOriginal || mat));
      ours.forEach((m, i) => { m.userData.kilnOriginal = mats[i].userData.kilnOriginal || mats[i]; });
      obj.material = Array.isArray(obj.material) ? ours : ours[0];
    });
    this.world.add(root);
  }

  /**
   * Switch the GI mode's shader (file in proto/glsl) and its #defines (KILN_SH_L2: the L2 evaluation); programs are
   * compiled on the next draw.
   */
  setModeShader(file, defines = {}) {
    if (file === this.modeShader && JSON.stringify(defines) === JSON.stringify(this.modeDefines)) return;
    this.modeShader = file;
    this.modeDefines = { ...defines };
    const frag = this.source('scene.frag.glsl', { mode: file });
    for (const m of this.materials.values()) { m.fragmentShader = frag; m.needsUpdate = true; }
  }

  /** The cluster-colouring fragment shader (web-only: src/renderer/glsl), preprocessed like ours. */
  clusterSource() {
    const s = preprocess('probe_cluster.frag.glsl', { ...GLSL_SOURCES, 'probe_cluster.frag.glsl': probeClusterFrag });
    const code = s.code.slice(s.code.indexOf('\n') + 1);
    this.sources.set(code, s.lineMap.slice(1));
    return code;
  }

  /**
   * Probe spheres at `positions` (world, metres: the caller maps the bake-frame `probe_positions_relocated` with
   * math/frame.js pointsToWorld; n·stride floats, x fastest probe order), coloured by `states` (n bytes), or by
   * `clusters` (n bytes, bundle.md 5.2; the 'cluster' colouring) when given.
   * @param {{positions: Float32Array, states: Uint8Array|null, clusters?: Uint8Array|null, counts: number[], radius: number}} probes
   */
  setProbes(probes) {
    if (this.probeMesh) { this.world.remove(this.probeMesh); this.probeMesh.geometry.dispose(); this.probeMesh = null; }
    if (!probes) return;
    const [nx, ny, nz] = probes.counts;
    const n = nx * ny * nz;
    const sphere = new SphereGeometry(1, 14, 10);
    const geo = new InstancedBufferGeometry();
    geo.index = sphere.index;
    geo.setAttribute('position', sphere.attributes.position);
    const idx = new Float32Array(n * 3);
    for (let k = 0, p = 0; k < nz; k++) for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++, p++) idx.set([i, j, k], p * 3);
    const pos = new Float32Array(n * 3);
    for (let p = 0; p < n; p++) for (let a = 0; a < 3; a++) pos[p * 3 + a] = probes.positions[p * probes.stride + a];
    geo.setAttribute('aProbePosition', new InstancedBufferAttribute(pos, 3));
    geo.setAttribute('aProbeIndex', new InstancedBufferAttribute(idx, 3));
    const st = new Float32Array(n).fill(1);
    if (probes.states) for (let p = 0; p < n; p++) st[p] = probes.states[p];
    const stateAttr = new InstancedBufferAttribute(st, 1);
    geo.setAttribute('aProbeState', stateAttr);
    geo.instanceCount = n;
    const mat = new RawShaderMaterial({
      name: 'kiln:probes',
      glslVersion: GLSL3,
      vertexShader: this.source('probe.vert.glsl'),
      fragmentShader: this.source('probe.frag.glsl'),
      uniforms: { ...this.shared, ...this.modeTextures, uProbeRadius: { value: probes.radius }, uProbeColoring: { value: 0 } },
    });
    this.probeMesh = new Mesh(geo, mat);
    this.probeMesh.userData = { stateAttr, stateMaterial: mat, clusterAttr: null, clusterMaterial: null };
    if (probes.clusters) this.setProbeClusters(probes.clusters, probes.states);
    this.probeMesh.frustumCulled = false;
    this.probeMesh.visible = false;
    this.world.add(this.probeMesh);
  }

  /** Per-probe cluster indices (the `clusters` artifact), for the 'cluster' colouring; OFF probes drawn dark. */
  setProbeClusters(clusters, states) {
    const ud = this.probeMesh?.userData;
    if (!ud || !clusters) return;
    const n = ud.stateAttr.count;
    const g = new Float32Array(n);
    for (let p = 0; p < n; p++) g[p] = Math.min(7, clusters[p] ?? 0) + (states && states[p] === 0 ? 8 : 0);
    ud.clusterAttr = new InstancedBufferAttribute(g, 1);
    if (!ud.clusterMaterial) {
      ud.clusterMaterial = new RawShaderMaterial({
        name: 'kiln:probes-clusters', glslVersion: GLSL3,
        vertexShader: this.source('probe.vert.glsl'), fragmentShader: this.clusterSource(),
        uniforms: { uProbeRadius: ud.stateMaterial.uniforms.uProbeRadius },
      });
    }
  }

  setProbeDisplay({ visible, coloring }) {
    if (!this.probeMesh) return;
    const ud = this.probeMesh.userData;
    this.probeMesh.visible = !!visible;
    const clusters = coloring === 'cluster' && ud.clusterAttr;
    this.probeMesh.material = clusters ? ud.clusterMaterial : ud.stateMaterial;
    this.probeMesh.geometry.setAttribute('aProbeState', clusters ? ud.clusterAttr : ud.stateAttr);
    ud.stateMaterial.uniforms.uProbeColoring.value = coloring === 'sh' ? 1 : 0;
  }

  /** Draw one frame; returns the latest frame time in ms (GPU when measurable). */
  render(camera) {
    if (this.shadowsEnabled && this.shadowsDirty && this.sceneRoot) {
      this.shadows = this.shadows || new ShadowMaps(this);
      const overlay = this.overlay.visible;
      this.overlay.visible = false;
      this.shadows.update(this.world, this.sceneRoot, this.lights);
      this.overlay.visible = overlay;
      this.shadowsDirty = false;
    }
    this.timer.begin();
    this.three.render(this.world, camera);
    this.timer.end();
    return this.timer.poll();
  }

  /** Compile every program of the current frame now (so a mode switch reports errors at once). */
  compile(camera) {
    this.three.compile(this.world, camera);
  }
}
