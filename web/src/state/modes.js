/**
 * The GI modes the viewer knows (DESIGN "Runtime shading"), what each needs from a bake, and the uniforms
 * its shader reads. A mode lights up when every artifact it needs is in the bake's `artifacts` list AND its
 * shader file exists in proto/glsl; otherwise the UI says why ("not baked" / "shader not written yet").
 *
 * The mode table is proto/gi_modes.json, one file with the Python renderer (workers/render/shading.py prepare_mode
 * reads it through proto/gi_modes.py): per mode its shader, `needs` (artifact names; `prefix*` for families such as
 * `cluster_sh_<k>_<c>`), its textures (sampler uniform -> artifact names and kind), the names of its other uniforms
 * and its #defines; with it the shared constants (DDGI-P eq 2's B default and 0.75, the mask lookup offset, limits).
 * Here each mode gets `needs` as {prefix} objects, `textures(names, artifacts, caps)` -> {uniform: [artifact name |
 * names, kind]} with kind 'volume' (3D, linear filtering, CLAMP_TO_EDGE), 'volume-nearest', 'atlas' (2D, linear),
 * 'stack' (a list of probe volumes concatenated along z: gi_grid.glsl giStackedUVW) or 'probe-data' ([relocated
 * positions, states] -> RGBA32F xyz + non-OFF flag, NEAREST), `defines(names, artifacts, caps)` (KILN_SH_L2 where the
 * bake has the L2 volumes, shOrder below; KILN_MASK_CLUSTERS = K) and `uniforms({grid, names, bake, info,
 * artifacts, caps})`, the values of the uniforms the table lists, computed as workers/render/shading.py does.
 */
import { atlasColumns } from '../math/atlas.js';
import spec from '../../../proto/gi_modes.json';

const CONST = Object.fromEntries(Object.entries(spec.constants).map(([k, v]) => [k, v.value]));
const CHANNELS = spec.patterns.channels;

/** The mode table of proto/gi_modes.json by id (shader, needs, textures, uniforms, defines). */
export const MODE_SPECS = Object.fromEntries(spec.modes.map((m) => [m.id, m]));

/** Lights a shading pass takes (lights.glsl MAX_LIGHTS) and PRT basis groups of 4 (mode_prt.glsl KILN_PRT_MAX_GROUPS). */
export const MAX_LIGHTS = CONST.max_lights;
export const PRT_MAX_GROUPS = CONST.prt_max_groups;

/** K, the number of clusters: cluster_sh_{k}_r for k = 0, 1, ... in the artifact names. */
export function clusterCount(names) {
  const set = new Set(names);
  let k = 0;
  while (set.has(`cluster_sh_${k}_r`)) k += 1;
  return k;
}

/**
 * Artifact names of a proto/gi_modes.json pattern: {k} over the clusters 0..K-1, {c} over r, g, b, {q} over the
 * groups of 4 clusters ('0123', '4567'); the first placeholder varies slowest (proto/gi_modes.py expand).
 */
export function expandPattern(pattern, K) {
  const values = { k: Array.from({ length: K }, (_, k) => String(k)), c: CHANNELS,
    q: spec.patterns.cluster_groups.slice(0, Math.ceil(K / 4)) };
  let out = [pattern];
  for (const [, key] of pattern.matchAll(/\{([kcq])\}/g)) {
    out = out.flatMap((n) => values[key].map((v) => n.replace(`{${key}}`, v)));
  }
  return out;
}

/**
 * Deepest stacked 3D texture built for L2 cluster volumes without knowing the device (proto/gi_modes.json
 * max_3d_texture_depth); the viewer passes the device's MAX_3D_TEXTURE_SIZE as caps.max3D.
 */
export const MAX_3D_TEXTURE_DEPTH = CONST.max_3d_texture_depth;

/**
 * SH order a mode shades with for a bake (docs/architecture.md "Runtime SH evaluation"): 2 where the bake has the
 * L2 volumes the mode reads (its `l2_needs`: leaking `sh_l2`; mask modes `cluster_sh_l2_{k}` for every cluster, their
 * stack of 7·K·(nz + 2) slices within caps.max3D when caps.nz is known; prt: the 9 coefficients of an L2 basis),
 * else 1. caps.shOrder = 1 forces L1. As workers/render/shading.py prepare_mode decides.
 */
export function shOrder(modeId, names = [], artifacts = {}, caps = {}) {
  if (caps.shOrder === 1) return 1;
  const set = new Set(names);
  if (modeId === 'prt') {
    const basis = artifacts.prt?.sh?.basis;
    if (basis) return basis.length === 9 ? 2 : 1;
    return names.some((n) => /^prt_sh_basis_c8_/.test(n)) ? 2 : 1;
  }
  const need = MODE_SPECS[modeId]?.l2_needs;
  if (!need) return 1;
  const K = clusterCount(names);
  if (need.some((p) => p.includes('{')) && !K) return 1;
  if (!need.flatMap((p) => expandPattern(p, K)).every((n) => set.has(n))) return 1;
  if (modeId === 'mask' || modeId === 'mask_normalized') {
    const depth = caps.nz ? 7 * K * (caps.nz + 2) : 0;
    return depth <= (caps.max3D || MAX_3D_TEXTURE_DEPTH) ? 2 : 1;
  }
  return 2;
}

/** The probe spheres' SH colouring reads the L1 volumes (probe.frag.glsl, texelFetch per probe). */
export const PROBE_SH_TEXTURES = { uShR: ['sh_l1_r', 'volume'], uShG: ['sh_l1_g', 'volume'], uShB: ['sh_l1_b', 'volume'] };

/**
 * Mask atlas uniforms (S, block size T, border_lo): the atlas artifact's meta when the bake lists it, else the
 * compress stage's stats (block_size, border_lo, border_hi: S = T - border_lo - border_hi; older bakes without them:
 * layout "shared" -> borders 0, 1; "bordered" -> 1, 1), else S from the dense masks' shape and the compress stage's
 * layout (proto/bundle.md 5.2: "cell", T = S).
 */
export function maskParams({ names, info, bake, grid }) {
  const meta = info('mask_atlas')?.meta || info('mask_indirection')?.meta;
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
 * uMaskOffset: refined samples the mask lookup moves along n + v (per axis; proto/gi_modes.json mask_offset_samples,
 * as workers/kernels/samplers.py and proto/glsl/gi_mask.glsl read it). A constant: the lookup works in the refined
 * grid's own units.
 */
export const MASK_OFFSET_SAMPLES = CONST.mask_offset_samples;
/** uMaskSeen, uMaskBlend: the mask lookup's both-sides blend (proto/gi_modes.json mask_seen_threshold, mask_blend;
 * workers/kernels/compress.py lookup_blend). */
export const MASK_SEEN_THRESHOLD = CONST.mask_seen_threshold;
export const MASK_BLEND = CONST.mask_blend;

function maskUniforms(ctx) {
  const { S, T, lo } = maskParams(ctx);
  return { uClusterCount: clusterCount(ctx.names), uMaskS: S, uMaskT: T, uMaskLo: lo, uMaskOffset: MASK_OFFSET_SAMPLES,
    uMaskSeen: MASK_SEEN_THRESHOLD, uMaskBlend: MASK_BLEND };
}

/** B of DDGI-P eq 2 where a bake does not give light.self_shadow_bias (proto/gi_modes.json self_shadow_bias). */
export const SELF_SHADOW_BIAS = CONST.self_shadow_bias;

/**
 * B of DDGI-P eq 2 for a bake: its config's light.self_shadow_bias (the bake record's or the manifest's config, as
 * the evaluate stage reads it), else SELF_SHADOW_BIAS (proto/gi_modes.py self_shadow_bias).
 */
export function selfShadowBias(bake) {
  const b = bake?.config?.light?.self_shadow_bias;
  return b === undefined || b === null ? SELF_SHADOW_BIAS : Number(b);
}

/**
 * uDdgiBias = 0.75 · D · B (metres; DDGI-P eq 2), D = min spacing over axes with spacing > 0
 * (workers/kernels/ddgi.bias_scale; 0.75 is proto/gi_modes.json bias_spacing_fraction).
 */
export function ddgiBias(spacing, selfShadowBiasB = SELF_SHADOW_BIAS) {
  const pos = (spacing || []).filter((s) => s > 0);
  return CONST.bias_spacing_fraction * (pos.length ? Math.min(...pos) : 0) * selfShadowBiasB;  // DDGI-P eq 2
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

/**
 * A mode's {uniform: [artifact name | names, kind]} from proto/gi_modes.json for a bake's artifact names (as
 * proto/gi_modes.py texture_bindings): the textures of the mode's SH order, those with min_clusters only with that
 * many clusters; a one-artifact binding as the name, a stack or probe data as the list. The PRT basis comes from
 * the `prt` section once loaded, before that from the names.
 */
function tableTextures(id, names, artifacts, caps) {
  const order = shOrder(id, names, artifacts, caps);
  const K = clusterCount(names);
  const out = {};
  for (const t of MODE_SPECS[id].textures) {
    if ((t.sh_order ?? order) !== order || K < (t.min_clusters ?? 0)) continue;
    let list;
    if (t.artifacts.length === 1 && t.artifacts[0] === 'prt.sh.basis') {
      list = artifacts.prt ? prtBasisNames(artifacts.prt, caps)
        : names.filter((n) => (order === 2 ? /^prt_sh_basis_c[0-8]_/ : /^prt_sh_basis_c[0-3]_/).test(n));
    } else list = t.artifacts.flatMap((p) => expandPattern(p, K));
    out[t.uniform] = [list.length === 1 && t.kind !== 'stack' ? list[0] : list, t.kind];
  }
  return out;
}

/** A mode's #defines from proto/gi_modes.json: KILN_SH_L2 (bare) at SH order 2, KILN_MASK_CLUSTERS = K. */
function tableDefines(id, names, artifacts, caps) {
  const out = {};
  for (const [name, rule] of Object.entries(MODE_SPECS[id].defines)) {
    if (rule === 'sh_order == 2') {
      if (shOrder(id, names, artifacts, caps) === 2) out[name] = true;
    } else if (rule === 'K') out[name] = clusterCount(names);
    else throw new Error(`proto/gi_modes.json: unknown define rule ${rule}`);
  }
  return out;
}

/** The values of the uniforms proto/gi_modes.json lists for each mode (shading.py prepare_mode computes the same). */
const UNIFORMS = {
  // caps.maxTexture: the device's MAX_TEXTURE_SIZE; a wider atlas is bound re-packed (renderer/textures.js
  // wrapAtlas, kind 'atlas') and these columns tell the shader its layout (shading.py wrap_atlas). B from the bake.
  ddgi: ({ grid, bake, artifacts, caps = {} }) => {
    const ny = grid.counts[1];
    const tIrr = Math.floor(artifacts.irradiance.height / ny);
    const tDep = Math.floor(artifacts.depth_moments.height / ny);
    const max = caps.maxTexture || Infinity;
    return {
      uDdgiBias: ddgiBias(grid.spacing, selfShadowBias(bake)), uIrradianceTexels: tIrr - 2, uDepthTexels: tDep - 2,
      uIrradianceColumns: atlasColumns(artifacts.irradiance.width, tIrr, max),
      uDepthColumns: atlasColumns(artifacts.depth_moments.width, tDep, max),
    };
  },
  mask: maskUniforms,
  mask_normalized: maskUniforms,
  // uPrtCoef comes from the viewer's relight (math/prt.js) every time the light gizmo moves
  prt: ({ artifacts }) => ({ uPrtGroups: Math.ceil(Number(artifacts.prt.basis) / 4) }),
};

/** What only the viewer adds to a mode: a tooltip, artifacts fetched first. */
const VIEWER = {
  prt: {
    tooltip: 'PRT relighting: drag the light gizmo; the browser recomputes the coefficients every move. '
      + 'The direct light at the measurement points is unshadowed here (the server relight traces shadow rays), '
      + 'so a light behind a wall still feeds the other room.',
    prerequisites: ['prt', 'prt_lights', 'prt_points', 'prt_point_offsets', 'prt_sh_transfer'],  // fetched first: `prt` names the basis
  },
};

export const GI_MODES = spec.modes.map((m) => ({
  id: m.id, label: m.label, shader: m.shader,
  needs: m.needs.map((n) => (n.endsWith('*') ? { prefix: n.slice(0, -1) } : n)),
  textures: (names, artifacts = {}, caps = {}) => tableTextures(m.id, names, artifacts, caps),
  defines: (names, artifacts = {}, caps = {}) => tableDefines(m.id, names, artifacts, caps),
  ...(UNIFORMS[m.id] ? { uniforms: UNIFORMS[m.id] } : {}),
  ...(VIEWER[m.id] || {}),
}));

/** Every sampler uniform any mode binds, and the probe spheres' (the renderer creates their slots up front). */
export const MODE_SAMPLERS = [...new Set([...Object.keys(PROBE_SH_TEXTURES),
  ...spec.modes.flatMap((m) => m.textures.map((t) => t.uniform))])];

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
