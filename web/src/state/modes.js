/**
 * The GI modes the viewer knows (DESIGN "Runtime shading"), what each needs from a bake, and the uniforms
 * its shader reads. A mode lights up when every artifact it needs is in the bake's `artifacts` list AND its
 * shader file exists in proto/glsl; otherwise the UI says why ("not baked" / "shader not written yet").
 *
 * `needs` entries are artifact names, or {prefix} for families (`cluster_sh_<k>_<c>`, `prt_*`). The mask and
 * PRT modes list what workers/stages/{masks,compress,prt}.py write; their bindings copy
 * workers/render/shading.py prepare_mode (proto/glsl/README.md "Texture bindings of the new modes").
 * `textures` (an object, or a function of the bake's artifact names and the artifacts loaded so far) maps a
 * sampler uniform to an artifact and how to upload it: 'volume' (3D, linear filtering, CLAMP_TO_EDGE),
 * 'volume-nearest', 'atlas' (2D, linear), 'stack' (a list of probe volumes concatenated along z:
 * gi_grid.glsl giStackedUVW) or 'probe-data' ([relocated positions, states] -> RGBA32F xyz + non-OFF flag,
 * NEAREST). `uniforms({grid, names, info, artifacts})` gives the mode's other uniforms, as
 * workers/render/shading.py prepare_mode binds them. `defines(names, artifacts, caps)` (optional) gives the
 * preprocessor #defines of the mode's shader: KILN_SH_L2 where the bake has the L2 volumes (shOrder below).
 */
import { atlasColumns } from '../math/atlas.js';
const CHANNELS = ['r', 'g', 'b'];

/** K, the number of clusters: cluster_sh_{k}_r for k = 0, 1, ... in the artifact names. */
export function clusterCount(names) {
  const set = new Set(names);
  let k = 0;
  while (set.has(`cluster_sh_${k}_r`)) k += 1;
  return k;
}

/** The `cluster_sh_{k}_{c}` names in stacking order (k0 r, k0 g, k0 b, k1 r, ...: gi_mask.glsl). */
const clusterShNames = (names) => Array.from({ length: clusterCount(names) }, (_, k) => CHANNELS.map((c) => `cluster_sh_${k}_${c}`)).flat();

/** The `cluster_sh_l2_{k}` names in stacking order (gi_mask.glsl uClusterShL2). */
const clusterShL2Names = (names) => Array.from({ length: clusterCount(names) }, (_, k) => `cluster_sh_l2_${k}`);

/**
 * Deepest stacked 3D texture built for L2 cluster volumes without knowing the device (workers/render/shading.py
 * MAX_3D_TEXTURE_DEPTH); the viewer passes the device's MAX_3D_TEXTURE_SIZE as caps.max3D.
 */
export const MAX_3D_TEXTURE_DEPTH = 2048;

/**
 * SH order a mode shades with for a bake (docs/architecture.md "Runtime SH evaluation"): 2 where the bake has the
 * L2 volumes the mode reads (leaking: `sh_l2`; mask modes: `cluster_sh_l2_{k}` for every cluster, their stack of
 * 7·K·(nz + 2) slices within caps.max3D when caps.nz is known; prt: the 9 coefficients of an L2 basis), else 1.
 * caps.shOrder = 1 forces L1. As workers/render/shading.py prepare_mode decides.
 */
export function shOrder(modeId, names = [], artifacts = {}, caps = {}) {
  if (caps.shOrder === 1) return 1;
  const set = new Set(names);
  if (modeId === 'leaking') return set.has('sh_l2') ? 2 : 1;
  if (modeId === 'mask' || modeId === 'mask_normalized') {
    const K = clusterCount(names);
    if (!K || !clusterShL2Names(names).every((n) => set.has(n))) return 1;
    const depth = caps.nz ? 7 * K * (caps.nz + 2) : 0;
    return depth <= (caps.max3D || MAX_3D_TEXTURE_DEPTH) ? 2 : 1;
  }
  if (modeId === 'prt') {
    const basis = artifacts.prt?.sh?.basis;
    if (basis) return basis.length === 9 ? 2 : 1;
    return names.some((n) => /^prt_sh_basis_c8_/.test(n)) ? 2 : 1;
  }
  return 1;
}

const l2Defines = (id) => (names, artifacts, caps) => (shOrder(id, names, artifacts, caps) === 2 ? { KILN_SH_L2: true } : {});

/** The probe spheres' SH colouring reads the L1 volumes (probe.frag.glsl, texelFetch per probe). */
export const PROBE_SH_TEXTURES = { uShR: ['sh_l1_r', 'volume'], uShG: ['sh_l1_g', 'volume'], uShB: ['sh_l1_b', 'volume'] };

/**
 * Mask atlas uniforms (S, block size T, border_lo): the atlas artifact's meta when the bake lists it, else the
 * compress stage's stats (block_size, border_lo, border_hi: S = T - border_lo - border_hi; older bakes without them:
 * layout "shared" -> borders 0, 1; "bordered" -> 1, 1), else S from the dense masks' shape and the compress stage's
 * layout (proto/bundle.md 5.2: "cell", T = S).
 */
export function maskParams({ names, info, bake, grid }) {
  const meta = info('mask_atlas_0123')?.meta || info('mask_indirection')?.meta;
  if (meta && meta.block_size) {
    return { S: Number(meta.samples_per_cell), T: Number(meta.block_size), lo: Number(meta.border_lo ?? 0) };
  }
  const st = (bake?.stages || []).find((x) => x.name === 'compress')?.stats;
  if (st && st.block_size) {
    const borders = { cell: [0, 0], shared: [0, 1], bordered: [1, 1] }[st.layout] || [0, 0];
    const lo = Number(st.border_lo ?? borders[0]);
    const hi = Number(st.border_hi ?? borders[1]);
    return { S: Number(st.block_size) - lo - hi, T: Number(st.block_size), lo };
  }
  const shape = info('masks_0123')?.shape;  // (Z, Y, X, 4), X = (nx - 1) · S
  const nx = grid?.counts?.[0] || 2;
  const S = shape ? Math.round(shape[2] / Math.max(1, nx - 1)) : Number(bake?.config?.visibility?.samples_per_cell ?? 1);
  return { S, T: S, lo: 0 };
}

/**
 * uMaskOffset: refined samples the mask lookup moves along n + v (per axis; workers/kernels/samplers.MASK_OFFSET_SAMPLES,
 * proto/glsl/gi_mask.glsl). A constant: the lookup works in the refined grid's own units.
 */
export const MASK_OFFSET_SAMPLES = 1.0;

/** The mask modes' cluster SH binding: the L2 stack (uClusterShL2) or the L1 one (uClusterSh). */
function clusterShTextures(id, names, artifacts, caps) {
  return shOrder(id, names, artifacts, caps) === 2 ? { uClusterShL2: [clusterShL2Names(names), 'stack'] }
    : { uClusterSh: [clusterShNames(names), 'stack'] };
}

function maskUniforms(ctx) {
  const { S, T, lo } = maskParams(ctx);
  return { uClusterCount: clusterCount(ctx.names), uMaskS: S, uMaskT: T, uMaskLo: lo, uMaskOffset: MASK_OFFSET_SAMPLES };
}

/** uDdgiBias = 0.75 · D · 0.3, D = min spacing over axes with spacing > 0 (workers/kernels/ddgi.bias_scale). */
export function ddgiBias(spacing, selfShadowBias = 0.3) {
  const pos = (spacing || []).filter((s) => s > 0);
  return 0.75 * (pos.length ? Math.min(...pos) : 0) * selfShadowBias;
}

/**
 * The PRT basis volume names, stacked k slowest (mode_prt.glsl): all 9 coefficients of an L2 bake (the shader
 * then sums and evaluates L2, KILN_SH_L2), else (or with caps.shOrder = 1) the 4 of L1; g = 0..G-1.
 */
export function prtBasisNames(section, caps = {}) {
  if (!section?.sh?.basis) return [];
  const C = section.sh.basis.length === 9 && caps.shOrder !== 1 ? 9 : 4;
  return section.sh.basis.slice(0, C).flat();
}

export const GI_MODES = [
  { id: 'direct', label: 'Direct only', shader: 'mode_direct.glsl', needs: [], textures: {} },
  {
    id: 'leaking', label: 'Leaking SH', shader: 'mode_leaking.glsl',
    needs: ['sh_l1_r', 'sh_l1_g', 'sh_l1_b'],
    // L2 (sh_l2, three.js LightProbeGrid layout, one texture) where the bake has it, else the L1 volumes
    textures: (names, artifacts, caps) => (shOrder('leaking', names, artifacts, caps) === 2
      ? { uShL2: ['sh_l2', 'volume'] } : { ...PROBE_SH_TEXTURES }),
    defines: l2Defines('leaking'),
  },
  {
    // workers/render/shading.py prepare_mode("ddgi")
    id: 'ddgi', label: 'DDGI (ray-traced visibility)', shader: 'mode_ddgi.glsl',
    needs: ['irradiance', 'depth_moments', 'probe_positions_relocated', 'probe_states'],
    textures: {
      uIrradianceAtlas: ['irradiance', 'atlas'], uDepthAtlas: ['depth_moments', 'atlas'],
      uProbeData: [['probe_positions_relocated', 'probe_states'], 'probe-data'],
    },
    // caps.maxTexture: the device's MAX_TEXTURE_SIZE; a wider atlas is bound re-packed (renderer/textures.js
    // wrapAtlas, kind 'atlas') and these columns tell the shader its layout (shading.py wrap_atlas)
    uniforms: ({ grid, artifacts, caps = {} }) => {
      const ny = grid.counts[1];
      const tIrr = Math.floor(artifacts.irradiance.height / ny);
      const tDep = Math.floor(artifacts.depth_moments.height / ny);
      const max = caps.maxTexture || Infinity;
      return {
        uDdgiBias: ddgiBias(grid.spacing), uIrradianceTexels: tIrr - 2, uDepthTexels: tDep - 2,
        uIrradianceColumns: atlasColumns(artifacts.irradiance.width, tIrr, max),
        uDepthColumns: atlasColumns(artifacts.depth_moments.width, tDep, max),
      };
    },
  },
  {
    // workers/render/shading.py prepare_mode("mask")
    id: 'mask', label: 'Mask GI', shader: 'mode_mask.glsl',
    needs: ['mask_indirection', 'mask_atlas_0123', { prefix: 'cluster_sh_' }],
    textures: (names, artifacts, caps) => ({
      uMaskIndirection: ['mask_indirection', 'volume-nearest'], uMaskAtlas0123: ['mask_atlas_0123', 'volume'],
      ...(clusterCount(names) > 4 ? { uMaskAtlas4567: ['mask_atlas_4567', 'volume'] } : {}),
      ...clusterShTextures('mask', names, artifacts, caps),
    }),
    defines: l2Defines('mask'),
    uniforms: maskUniforms,
  },
  {
    id: 'mask_normalized', label: 'Mask GI (normalized)', shader: 'mode_mask_normalized.glsl',
    needs: ['mask_indirection', 'mask_atlas_0123', 'cluster_weights_0123', { prefix: 'cluster_sh_' }],
    textures: (names, artifacts, caps) => ({
      uMaskIndirection: ['mask_indirection', 'volume-nearest'], uMaskAtlas0123: ['mask_atlas_0123', 'volume'],
      ...(clusterCount(names) > 4 ? { uMaskAtlas4567: ['mask_atlas_4567', 'volume'] } : {}),
      ...clusterShTextures('mask_normalized', names, artifacts, caps),
      uClusterWeights: [clusterCount(names) > 4 ? ['cluster_weights_0123', 'cluster_weights_4567'] : ['cluster_weights_0123'], 'stack'],
    }),
    defines: l2Defines('mask_normalized'),
    uniforms: maskUniforms,
  },
  {
    // workers/render/shading.py prepare_mode("prt"); the coefficients come from the viewer's relight
    // (math/prt.js) every time the light gizmo moves
    id: 'prt', label: 'PRT relighting', shader: 'mode_prt.glsl',
    tooltip: 'PRT relighting: drag the light gizmo; the browser recomputes the coefficients every move. '
      + 'The direct light at the measurement points is unshadowed here (the server relight traces shadow rays), '
      + 'so a light behind a wall still feeds the other room.',
    needs: ['prt', 'prt_points', 'prt_point_offsets', 'prt_sh_transfer', { prefix: 'prt_sh_basis_' }],
    // the basis names are in the `prt` json: resolved by the viewer once it has the section
    textures: (names, artifacts = {}, caps = {}) => ({
      uPrtBasis: [artifacts.prt ? prtBasisNames(artifacts.prt, caps)
        : names.filter((n) => (shOrder('prt', names, artifacts, caps) === 2 ? /^prt_sh_basis_c[0-8]_/ : /^prt_sh_basis_c[0-3]_/).test(n)), 'stack'],
    }),
    defines: l2Defines('prt'),
    prerequisites: ['prt', 'prt_lights', 'prt_points', 'prt_point_offsets', 'prt_sh_transfer'],  // fetched first: `prt` names the basis
    uniforms: ({ artifacts }) => ({ uPrtGroups: Math.ceil(Number(artifacts.prt.basis) / 4) }),
  },
];

/** Every sampler uniform any mode binds (the renderer creates their slots up front). */
export const MODE_SAMPLERS = ['uShR', 'uShG', 'uShB', 'uShL2', 'uIrradianceAtlas', 'uDepthAtlas', 'uProbeData',
  'uMaskIndirection', 'uMaskAtlas0123', 'uMaskAtlas4567', 'uClusterSh', 'uClusterShL2', 'uClusterWeights', 'uPrtBasis'];

/**
 * A mode's {uniform: [artifact name | names, kind]} for a bake's artifact names (and artifacts loaded so far;
 * caps: {max3D, nz, shOrder} as shOrder takes them).
 */
export function modeTextures(mode, names = [], artifacts = {}, caps = {}) {
  return typeof mode.textures === 'function' ? mode.textures(names, artifacts, caps) : mode.textures;
}

/** A mode's shader #defines for a bake (KILN_SH_L2 where it shades with L2). */
export function modeDefines(mode, names = [], artifacts = {}, caps = {}) {
  return mode.defines ? mode.defines(names, artifacts, caps) : {};
}

export function modeById(id) {
  return GI_MODES.find((m) => m.id === id);
}

const needLabel = (n) => (typeof n === 'string' ? n : `${n.prefix}*`);

/**
 * Availability of a mode for a bake.
 * @param {object} mode  a GI_MODES entry
 * @param {string[]} artifactNames  names in the bake's `artifacts` list ([] when there is no bake)
 * @param {(file: string) => boolean} hasShader
 * @returns {{available: boolean, reason: string, missing: string[]}}
 */
export function modeAvailability(mode, artifactNames, hasShader) {
  const names = new Set(artifactNames);
  const missing = mode.needs.filter((n) => (typeof n === 'string' ? !names.has(n) : ![...names].some((a) => a.startsWith(n.prefix))))
    .map(needLabel);
  if (missing.length) return { available: false, reason: 'not baked', missing };
  if (!hasShader(mode.shader)) return { available: false, reason: 'shader not written yet', missing: [] };
  return { available: true, reason: '', missing: [] };
}

/** Artifacts to stream for a mode (those its textures bind, plus its prerequisites). */
export function modeArtifacts(mode, names = [], artifacts = {}, caps = {}) {
  const out = [...(mode.prerequisites || [])];
  for (const [name] of Object.values(modeTextures(mode, names, artifacts, caps))) out.push(...(Array.isArray(name) ? name : [name]));
  return [...new Set(out)];
}
