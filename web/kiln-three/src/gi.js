/**
 * Kiln's GI in a plain three.js app (proto/bundle.md; DESIGN "Runtime shading").
 *
 * - Leaking probe GI through three's own LightProbeGrid: the bundle's `sh_l2` (already three's atlas layout,
 *   proto/bundle.md 5.1 "L2 layout") becomes the grid's texture, its box and resolution from the manifest grid
 *   (grid.js). Any lit three material (MeshStandardMaterial, MeshPhysicalMaterial, MeshLambertMaterial, ...) then
 *   gets the bake's indirect light with no change to the material.
 * - Kiln's own modes (mask GI, normalized mask GI, DDGI; also leaking as Kiln shades it) as a material extension:
 *   `extend(material)` adds, through `onBeforeCompile`, the mode's proto/glsl file (the same GLSL the Kiln viewer and
 *   the Python renderer compile; which artifact binds to which sampler, the #defines and the uniform values come from
 *   proto/gi_modes.json through web/src/state/modes.js) and one call that adds giIndirectIrradiance(p, n) to three's
 *   `irradiance` right after `lights_fragment_maps`: three then applies its own diffuse BRDF to it, as it does to a
 *   light map or a light probe.
 * - The bake frame (manifest `grid.frame`, grid.js frameMatrix): every probe artifact is in the world turned about +Y
 *   by a yaw fitted to the walls. The extension hands the mode uGiFrame·p, uGiFrame·n and giViewDir = uGiFrame·v
 *   (`uniform mat3 uGiFrame`, world -> bake; the identity for a bake without a frame). three's LightProbeGrid is an
 *   axis-aligned world box that ignores any rotation (its shader compares the world position with a world box and
 *   evaluates the SH at the world normal; the box follows `position` only): for a turned bake createProbeGrid
 *   resamples the SH onto a world-aligned grid (grid.js resampleShL2: Kiln's lookup at M·p, the SH turned to the world).
 * - A rectilinear grid (manifest `grid.layers` = [xs, ys, zs]: probe (i, j, k) at (xs[i], ys[j], zs[k])): the modes
 *   read the layers from `uniform sampler2D uGridLayers` (R32F, max(counts) x 3; probe_grid.glsl giGridIndex, on where
 *   `uGridRectilinear`); three's LightProbeGrid, whose cells are all alike, gets the SH resampled as for a turned bake.
 */
import { Matrix3 } from 'three';
import { LightProbeGridWebGL } from 'three/addons/lighting/LightProbeGridWebGL.js';
import { GI_MODES, MODE_SAMPLERS, modeAvailability, modeById, modeDefines, modeTextures, MAX_3D_TEXTURE_DEPTH } from '../../src/state/modes.js';
import { GLSL_SOURCES, hasShader } from '../../src/renderer/shaders.js';
import { preprocess } from '../../src/renderer/preprocess.js';
import { gridLayersTexture, probeDataTexture, textureFromKTX2, wrapAtlas } from '../../src/renderer/textures.js';
import { atlasColumns } from '../../src/math/atlas.js';
import { gridLayers } from '../../src/math/sh.js';
import { fitsProbeGrid, frameMatrix, padShL2, probeGridBox, resampleShL2 } from './grid.js';

/** Modes `setMode` takes: 'off', 'grid' (leaking through three's LightProbeGrid) and Kiln's GLSL modes. */
export const EXTENSION_MODES = ['leaking', 'ddgi', 'mask', 'mask_normalized'];

/** The GLSL added to three's fragment shader after `#include <lights_fragment_maps>`: world-space p and n as three's
 * own lights_fragment_begin derives them for its probe grids, and the view direction, turned into the bake frame by
 * uGiFrame (world -> bake) before the mode sees them. */
export const IRRADIANCE_HOOK = `
#if defined( RE_IndirectDiffuse )
	{
		vec3 kilnP = ( ( vec4( geometryPosition, 1.0 ) - viewMatrix[ 3 ] ) * viewMatrix ).xyz;
		vec3 kilnN = inverseTransformDirection( geometryNormal, viewMatrix );
		giViewDir = uGiFrame * normalize( cameraPosition - kilnP );
		irradiance += uKilnIndirectScale * giIndirectIrradiance( uGiFrame * kilnP, uGiFrame * kilnN );
	}
#endif
`;

/** The entry compiled into three's fragment shader: the view-direction global every hook sets, then the mode. */
const ENTRY = 'kiln_three.glsl';
const ENTRY_SOURCE = '#include "gi_view.glsl"\n#include "@mode"\n';

/** A declaration of the bake-frame uniform (proto/glsl/gi_view.glsl declares it once the shared GLSL has the frame). */
const FRAME_DECLARATION = /\buniform\s+(?:(?:highp|mediump|lowp)\s+)?mat3\s+uGiFrame\s*;/;

/**
 * The GLSL of a Kiln mode for three's fragment shader: proto/glsl preprocessed (web/src/renderer/preprocess.js) for
 * WebGL2 without the #version line (three writes its own), with the mode's #defines, and `uniform mat3 uGiFrame;`
 * (IRRADIANCE_HOOK's world -> bake rotation) exactly once: added here where the shared GLSL does not declare it. Pure.
 */
export function modeGLSL(shaderFile, defines = {}) {
  const { code } = preprocess(ENTRY, { ...GLSL_SOURCES, [ENTRY]: ENTRY_SOURCE }, { target: 'webgl2', slots: { mode: shaderFile }, defines });
  const body = code.slice(code.indexOf('\n') + 1);
  return FRAME_DECLARATION.test(body) ? body : `uniform mat3 uGiFrame;  // world -> bake frame (grid.frame.matrix)\n${body}`;
}

/** A record (bundle.js) stacked along z with others of the same size and kind (gi_grid.glsl giStackedUVW). */
export function stackRecords(records) {
  if (!records.length) throw new Error('no volumes to stack');
  const r0 = records[0];
  for (const r of records) {
    if (r.kind !== r0.kind || r.width !== r0.width || r.height !== r0.height || r.depth !== r0.depth || r.components !== r0.components) {
      throw new Error(`stacked volumes differ: ${r.kind} ${r.width}x${r.height}x${r.depth} vs ${r0.kind} ${r0.width}x${r0.height}x${r0.depth}`);
    }
  }
  const per = r0.data.length;
  const data = new r0.data.constructor(per * records.length);
  records.forEach((r, s) => data.set(r.data, s * per));
  return { ...r0, texture: undefined, data, depth: Math.max(1, r0.depth) * records.length, is3D: true };
}

export class KilnGI {
  /**
   * @param {import('./bundle.js').KilnBundle} bundle
   * @param {import('three').WebGLRenderer} renderer
   * @param {{pad?: number}} [options]  pad: probe layers added around the LightProbeGrid (grid.js padShL2)
   */
  constructor(bundle, renderer, { pad = 1 } = {}) {
    this.bundle = bundle;
    this.renderer = renderer;
    this.pad = pad;
    const gl = renderer.getContext();
    this.caps = {
      max3D: gl.getParameter(gl.MAX_3D_TEXTURE_SIZE) || MAX_3D_TEXTURE_DEPTH,
      maxTexture: gl.getParameter(gl.MAX_TEXTURE_SIZE) || 4096,
      nz: bundle.grid.counts[2],
    };
    this.floatLinear = renderer.extensions.has('OES_texture_float_linear');
    this.mode = 'off';
    this.probeGrid = null;
    this.materials = new Set();
    this.code = '';
    const g = bundle.grid;
    /** World -> bake frame, row-major rows (manifest grid.frame.matrix; the identity without a frame). */
    this.frame = frameMatrix(g);
    /** A rectilinear grid's layers ([xs, ys, zs], metres, bake frame; checked), null for a uniform grid. */
    this.layers = gridLayers(g);
    this.uniforms = {
      uKilnIndirectScale: { value: 1 },
      // Matrix3.set takes rows and stores GLSL's column-major elements: uGiFrame * p_world = M · p_world = p_bake
      uGiFrame: { value: new Matrix3().set(...this.frame[0], ...this.frame[1], ...this.frame[2]) },
      uGridOrigin: { value: g.origin.slice() }, uGridSpacing: { value: g.spacing.slice() }, uGridCounts: { value: g.counts.slice() },
      // a rectilinear grid's layers (probe_grid.glsl giGridIndex); a 1 x 3 dummy texture for a uniform grid
      uGridRectilinear: { value: !!this.layers }, uGridLayers: { value: gridLayersTexture(this.layers) },
    };
    // a slot for every sampler any mode declares: one a program declares but no binding fills (the weights in plain
    // mask GI) then gets three's empty texture of its type instead of unit 0, where a
    // texture of the other type would make the draw fail
    for (const name of MODE_SAMPLERS) this.uniforms[name] = { value: null };
  }

  /** Whether three's LightProbeGrid holds this bake's probes as they are: its bake frame is the world (no grid.frame,
   * or yaw 0) and its grid is uniform (no grid.layers; grid.js fitsProbeGrid). A turned or rectilinear bake's grid is
   * resampled onto a world grid instead (probeGridResampled). */
  get probeGridFits() { return fitsProbeGrid(this.bundle.grid); }

  /** Whether createProbeGrid resamples the SH onto an axis-aligned world grid (a turned bake frame or a rectilinear
   * grid: grid.js resampleShL2). */
  get probeGridResampled() { return !this.probeGridFits; }

  /** Kiln modes this bundle can shade: [{id, label, available, reason}] (web/src/state/modes.js availability). */
  modes() {
    return GI_MODES.filter((m) => EXTENSION_MODES.includes(m.id))
      .map((m) => ({ id: m.id, label: m.label, ...modeAvailability(m, this.bundle.names, hasShader) }));
  }

  /**
   * The bundle's leaking GI as a three.js LightProbeGrid (add it to the scene; it lights every lit material).
   * Needs the `sh_l2` artifact (light.sh_order 2, the default). Float32 atlases are sampled LINEAR where the device
   * has OES_texture_float_linear, else converted to half floats (textures.js). A turned bake (grid.frame, yaw ≠ 0) or a
   * rectilinear one (grid.layers) gets its SH resampled onto an axis-aligned world grid about the bake's spacing
   * (grid.js resampleShL2; userData.kilnResampled).
   */
  async createProbeGrid() {
    if (!this.bundle.has('sh_l2')) throw new Error('the bundle has no sh_l2 (an L1 bake, light.sh_order = 1): no LightProbeGrid');
    const rec = await this.bundle.artifact('sh_l2');
    const grid = this.bundle.grid;
    // three's box is axis-aligned in the world and its cells uniform: a turned or rectilinear bake's SH resampled onto
    // a world grid (grid.js resampleShL2)
    const { box, data, depth } = this.probeGridFits
      ? { box: probeGridBox(grid, this.pad), ...(this.pad ? padShL2(rec.data, grid.counts, this.pad) : { data: rec.data, depth: rec.depth }) }
      : resampleShL2(rec.data, grid, this.frame, this.pad);
    const tex = textureFromKTX2({ ...rec, data, width: box.resolution[0], height: box.resolution[1],
      depth, is3D: true }, { filter: 'linear', floatLinear: this.floatLinear });
    const pg = new LightProbeGridWebGL(...box.size, ...box.resolution);
    pg.name = 'kiln:probe-grid';
    pg.position.fromArray(box.center);
    pg.updateMatrixWorld();
    pg.updateBoundingBox();
    pg.texture = tex;
    pg.userData.kilnBox = box;
    pg.userData.kilnResampled = this.probeGridResampled;
    pg.visible = this.mode === 'grid';
    this.probeGrid = pg;
    return pg;
  }

  /** Make `material` (any lit three material) shade Kiln's current extension mode. Returns the material. */
  extend(material) {
    const gi = this;
    const previous = material.onBeforeCompile;
    material.onBeforeCompile = function onBeforeCompile(shader, renderer) {
      if (previous) previous.call(this, shader, renderer);
      // every program of the material gets Kiln's uniforms, the plain ones ('off', 'grid') too: three keeps the
      // uniforms of the material's last compile and reuses them with a cached program, so a mode's program taken
      // back from the cache after a plain one was compiled would otherwise read no Kiln textures (no GI)
      Object.assign(shader.uniforms, gi.uniforms);
      if (!gi.code) return;
      if (!shader.fragmentShader.includes('#include <lights_fragment_maps>')) return;  // unlit material
      shader.fragmentShader = `${gi.code}\nuniform float uKilnIndirectScale;\n${shader.fragmentShader.replace(
        '#include <lights_fragment_maps>', `#include <lights_fragment_maps>\n${IRRADIANCE_HOOK}`)}`;
    };
    const key = material.customProgramCacheKey?.bind(material);
    material.customProgramCacheKey = () => `${key ? key() : ''}|kiln:${gi.programKey}`;
    material.needsUpdate = true;
    this.materials.add(material);
    return material;
  }

  /** extend() every mesh material under `root`. */
  extendScene(root) {
    root.traverse((o) => {
      if (!o.isMesh) return;
      for (const m of Array.isArray(o.material) ? o.material : [o.material]) this.extend(m);
    });
  }

  /** Indirect light on (1) or off (0) for the extension modes (the probe grid follows `setMode`). */
  set indirectScale(x) { this.uniforms.uKilnIndirectScale.value = x; }

  get indirectScale() { return this.uniforms.uKilnIndirectScale.value; }

  /**
   * 'off' (no indirect light from Kiln), 'grid' (leaking GI through the LightProbeGrid; createProbeGrid first), or
   * one of EXTENSION_MODES (the material extension; its artifacts are fetched and its textures built here).
   */
  async setMode(id) {
    if (id === 'off' || id === 'grid') {
      if (id === 'grid' && !this.probeGrid) throw new Error('createProbeGrid() first');
      this._setCode(id, '');
    } else {
      const mode = modeById(id);
      if (!mode || !EXTENSION_MODES.includes(id)) throw new Error(`unknown mode ${id}; valid: off, grid, ${EXTENSION_MODES.join(', ')}`);
      const av = modeAvailability(mode, this.bundle.names, hasShader);
      if (!av.available) throw new Error(`mode ${id}: ${av.reason} ${av.missing.join(', ')}`);
      await this._bind(mode);
      const defines = modeDefines(mode, this.bundle.names, {}, this.caps);
      if (this.layers) defines.KILN_GRID_RECTILINEAR = true;   // probe_grid.glsl: the layer lookup only then
      this._setCode(`${id}:${JSON.stringify(defines)}`, modeGLSL(mode.shader, defines));
    }
    this.mode = id;
    if (this.probeGrid) this.probeGrid.visible = id === 'grid';
  }

  _setCode(key, code) {
    this.programKey = key;
    this.code = code;
    for (const m of this.materials) m.needsUpdate = true;
  }

  async _bind(mode) {
    const b = this.bundle;
    const names = b.names;
    const bindings = modeTextures(mode, names, {}, this.caps);
    const load = (n) => b.artifact(n);
    const counts = b.grid.counts;
    const opts = { floatLinear: this.floatLinear };
    const records = {};
    for (const [uniform, [name, kind]] of Object.entries(bindings)) {
      let tex;
      if (kind === 'volume' || kind === 'volume-nearest') {
        const r = records[name] = await load(name);
        tex = textureFromKTX2(r, { ...opts, filter: kind === 'volume' ? 'linear' : 'nearest' });
      } else if (kind === 'atlas') {
        const r = records[name] = await load(name);
        const tile = Math.floor(r.height / counts[1]);
        tex = textureFromKTX2(wrapAtlas(r, counts, atlasColumns(r.width, tile, this.caps.maxTexture)), { ...opts, filter: 'linear' });
      } else if (kind === 'stack') {
        tex = textureFromKTX2(stackRecords(await Promise.all(name.map(load))), { ...opts, filter: 'linear' });
      } else if (kind === 'probe-data') {
        const [pos, states] = await Promise.all(name.map(load));
        tex = probeDataTexture(pos, states);
      } else throw new Error(`proto/gi_modes.json kind ${kind} has no builder here`);
      const slot = this.uniforms[uniform] || (this.uniforms[uniform] = { value: null });
      if (slot.value && slot.value !== tex) slot.value.dispose();
      slot.value = tex;
    }
    const values = mode.uniforms ? mode.uniforms({ grid: b.grid, names, bake: b.manifest, info: (n) => b.info(n),
      artifacts: records, caps: this.caps }) : {};
    for (const [k, v] of Object.entries(values)) {
      if (k === 'uGiFrame') continue;   // this.frame (grid.frame), set once in the constructor
      (this.uniforms[k] || (this.uniforms[k] = { value: null })).value = Array.isArray(v) ? Float32Array.from(v) : v;
    }
  }
}
