/**
 * The GI modes the viewer knows (DESIGN "Runtime shading"), what each needs from a bake, and the uniforms
 * its shader reads. A mode lights up when every artifact it needs is in the bake's `artifacts` list AND its
 * shader file exists in proto/glsl; otherwise the UI says why ("not baked" / "shader not written yet").
 *
 * `needs` entries are artifact names, or {prefix} for families (`cluster_sh_<k>_<c>`, `prt_*`). The mask and
 * PRT modes list what workers/stages/{masks,anneal,prt}.py write; their shaders and texture bindings come
 * with the evaluate issue (add `textures` here, the GLSL in proto/glsl).
 * `textures` maps a sampler uniform to an artifact and how to upload it: 'volume' (3D, linear filtering,
 * CLAMP_TO_EDGE) or 'atlas' (2D, linear).
 */
export const GI_MODES = [
  { id: 'direct', label: 'Direct only', shader: 'mode_direct.glsl', needs: [], textures: {} },
  {
    id: 'leaking', label: 'Leaking SH', shader: 'mode_leaking.glsl',
    needs: ['sh_l1_r', 'sh_l1_g', 'sh_l1_b'],
    textures: { uShR: ['sh_l1_r', 'volume'], uShG: ['sh_l1_g', 'volume'], uShB: ['sh_l1_b', 'volume'] },
  },
  {
    id: 'ddgi', label: 'DDGI (ray-traced visibility)', shader: 'mode_ddgi.glsl',
    needs: ['irradiance', 'depth_moments', 'probe_offsets', 'probe_states'],
    textures: { uIrradianceAtlas: ['irradiance', 'atlas'], uDepthAtlas: ['depth_moments', 'atlas'],
      uProbeOffsets: ['probe_offsets', 'volume-nearest'], uProbeStates: ['probe_states', 'volume-nearest'] },
  },
  {
    id: 'mask', label: 'Mask GI', shader: 'mode_mask.glsl',
    needs: ['masks_0123', 'clusters', { prefix: 'cluster_sh_' }], textures: {},
  },
  {
    id: 'mask_normalized', label: 'Mask GI (normalized)', shader: 'mode_mask_normalized.glsl',
    needs: ['masks_0123', 'clusters', 'cluster_weights_0123', { prefix: 'cluster_sh_' }], textures: {},
  },
  { id: 'prt', label: 'PRT relighting', shader: 'mode_prt.glsl', needs: ['prt', { prefix: 'prt_' }], textures: {} },
];

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

/** Artifacts to stream for a mode (those its textures bind). */
export function modeArtifacts(mode) {
  return [...new Set(Object.values(mode.textures).map(([name]) => name))];
}
