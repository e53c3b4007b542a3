/**
 * How the schema-driven bake form (ui/configForm.js) speaks to people: a label in words for each section
 * and field (never a pydantic class name like "SceneSection"), a one-line help text, which fields are
 * folded under "Advanced", and the paper references (DDGI-P §5, MD eq 7, …) moved out of the text into
 * the tooltip. Pure data and functions (tested in web/tests).
 */

/** Per config path: label, help (plain words; the schema's description goes to the tooltip), advanced. */
export const FIELD_UI = {
  seed: { label: 'Random seed', help: 'the same seed and settings bake the same result', advanced: true },

  scene: { label: 'Lights and sky', help: 'what lights the scene: the file\'s own lights, lights you add, and the sky' },
  'scene.lights': { label: 'Lights', help: 'lights added to the ones in the file (bulbs and spots in candela, the sun in lux)' },
  'scene.use_scene_lights': { label: 'Use the file\'s lights', help: 'keep the KHR_lights_punctual lights of the uploaded glTF' },
  'scene.sky': { label: 'Sky', help: '' },  // the sky control says it (ui/lightEditor.js)
  'scene.max_albedo': { label: 'Albedo limit', help: 'clamp how much light each surface reflects (0..1)', advanced: true },
  'scene.specular_gi': { label: 'Specular in GI', help: 'how much of the shiny reflection bounces as diffuse light', advanced: true },

  place: { label: 'Probes', help: 'where light probes sit: a grid over the scene' },
  'place.counts': { label: 'Probe counts (x, y, z)', help: 'probes per axis; leave unset to choose from the scene' },
  'place.spacing': { label: 'Probe spacing', unit: 'm', help: 'metres between probes (instead of counts)' },
  'place.budget': { label: 'Most probes', help: 'upper limit of the automatic grid' },
  'place.box': { label: 'Grid box', unit: 'm', help: 'the box the grid fills; default: the scene (its rooms)', advanced: true },
  'place.padding': { label: 'Padding', help: 'fraction of the box added on each side', advanced: true },
  'place.yaw': { label: 'Grid turn', unit: '°', help: 'turn the probe grid about the vertical axis; default: turned to line up with the walls', advanced: true },

  trace: { label: 'Probe rays', help: 'rays each probe shoots, and moving probes out of walls' },
  'trace.rays_per_probe': { label: 'Rays per probe', help: 'more rays: less noise, longer bake' },
  'trace.relocate_iterations': { label: 'Relocation steps', help: 'how hard probes are pushed out of walls', advanced: true },
  'trace.max_offset': { label: 'Max probe offset', help: 'how far a probe may move, fraction of the spacing', advanced: true },
  'trace.rescue_offset': { label: 'Rescue offset', help: 'how far a probe stuck in a wall may move to free space, fraction of the spacing (0: off)', advanced: true },
  'trace.backface_fraction': { label: 'Inside-wall threshold', help: 'a probe seeing more backfaces than this is switched off', advanced: true },
  'trace.depth_texels': { label: 'Depth map size', unit: 'texels', help: 'per-probe distance map resolution', advanced: true },
  'trace.depth_sharpness': { label: 'Depth sharpness', help: 'how strongly depth tests cut light at walls', advanced: true },

  light: { label: 'Light', help: 'how light bounces between surfaces' },
  'light.bounces': { label: 'Bounces', help: 'a fixed number of bounces; leave unset to bounce until converged' },
  'light.max_bounces': { label: 'Most bounces', help: 'cap when bouncing until converged', advanced: true },
  'light.tolerance': { label: 'Convergence tolerance', help: 'stop when the light unaccounted for (after the estimated remaining bounces are added) is below this fraction', advanced: true },
  'light.irradiance_texels': { label: 'Irradiance map size', unit: 'texels', help: 'per-probe irradiance resolution', advanced: true },
  'light.sh_order': { label: 'SH order', help: 'spherical-harmonics order of the probe output (2 = sharper)', advanced: true },
  'light.self_shadow_bias': { label: 'Self-shadow bias', help: 'offset that keeps surfaces from shadowing themselves', advanced: true },
  'light.near_radius': { label: 'Near-field radius', help: 'geometry this close to a surface (in probe spacings) darkens it as the probes cannot see (0: off)', advanced: true },
  'light.near_rays': { label: 'Near-field rays', help: 'short rays per surface point that find the nearby geometry', advanced: true },
  'light.near_strength': { label: 'Near-field strength', help: 'how much of the nearby geometry\'s shading is applied', advanced: true },

  visibility: { label: 'Leak removal: visibility', help: 'which probes each point can see, so light does not leak through walls' },
  'visibility.samples_per_cell': { label: 'Samples per cell', help: 'resolution of the visibility field; leave unset to pick from the walls' },
  'visibility.rays': { label: 'Rays per sample', help: '1 = sharp, more = soft edges', advanced: true },
  'visibility.jitter': { label: 'Jitter', help: 'softening radius around each probe, fraction of the spacing', advanced: true },
  'visibility.slabs': { label: 'Jobs', help: 'how many parallel jobs compute it (same result)', advanced: true },

  masks: { label: 'Leak removal: masks', help: 'probe clusters and the masks that keep each room\'s light inside it' },
  'masks.clusters': { label: 'Clusters (K)', help: 'mask channels; more separate more rooms' },
  'masks.coloring': { label: 'Clustering', help: 'how probes are grouped into clusters', advanced: true },
  'masks.sweeps': { label: 'Optimizer sweeps', advanced: true },
  'masks.regularization': { label: 'Regularization', advanced: true },
  'masks.sigma': { label: 'Mask blur', unit: 'samples', advanced: true },
  'masks.light_aware': { label: 'Fit masks to the light', advanced: true },
  'masks.light_aware_penalty': { label: 'Light-fit penalty', advanced: true },
  'masks.compress_tolerance': { label: 'Compression tolerance', help: 'largest mask error of a merged block (0 = lossless; default 24/255)', advanced: true },

  prt: { label: 'Relighting (PRT)', help: 'bake a transfer that relights the scene in real time with moved lights' },
  'prt.enabled': { label: 'Bake relighting', help: 'slower bake; adds the PRT mode to the viewer' },
  'prt.scenario': { label: 'Random lights for training', advanced: true },
  'prt.configurations': { label: 'Lighting configurations', help: 'random light setups the transfer learns from' },
  'prt.measurement_points': { label: 'Measurement points', help: 'points on surfaces where light is measured' },
  'prt.supersampling': { label: 'Samples per point', advanced: true },
  'prt.basis': { label: 'Basis size', help: 'transfer vectors kept' },
  'prt.ridge': { label: 'Ridge', advanced: true },
  'prt.gamma': { label: 'Gamma', advanced: true },
  'prt.channels': { label: 'Colour channels', advanced: true },
  'prt.lightmap': { label: 'Lightmap size', unit: 'texels', help: '0 = no lightmap', advanced: true },

  evaluate: { label: 'Quality check', help: 'render previews and error metrics against a path-traced reference' },
  'evaluate.enabled': { label: 'Check quality', help: 'slow: minutes per camera' },
  'evaluate.cameras': { label: 'Cameras', help: 'how many views to check, or a list of cameras' },
  'evaluate.width': { label: 'Width', unit: 'px', advanced: true },
  'evaluate.height': { label: 'Height', unit: 'px', advanced: true },
  'evaluate.fov_y': { label: 'Field of view', unit: '°', advanced: true },
  'evaluate.spp': { label: 'Reference paths per point' },
  'evaluate.check_spp': { label: 'Reference paths per check point', advanced: true },
  'evaluate.dark_spp': { label: 'Reference paths at dark points', help: 'where the leak metrics are measured', advanced: true },
  'evaluate.bounces': { label: 'Reference bounces', advanced: true },
  'evaluate.modes': { label: 'GI modes to check', advanced: true },
  'evaluate.repeats': { label: 'Timing repeats', help: '0: time the preview itself', advanced: true },
  'evaluate.flip': { label: 'FLIP metric', help: 'slow on large images', advanced: true },
};

/** Sections open when the form appears. */
export const OPEN_SECTIONS = new Set(['scene', 'place']);

/** "rays_per_probe" -> "Rays per probe". */
export function humanize(key) {
  const s = String(key || '').replace(/_/g, ' ').trim();
  return s ? s[0].toUpperCase() + s.slice(1) : '';
}

/** A reference to a paper or a design section: "DDGI-P §2.3", "MD eq 7", "PRT §4.1", "Fig 7", "DESIGN stage 1". */
const REF = /\b(?:DDGI-[IP]|MD|PRT|DESIGN|RTXGI)\b(?:\s*(?:§\s*[\d.]+(?:-[\d.]+)?|eq\.?\s*\d+|Fig\.?\s*\d+|stage\s*\d+)(?:\s*(?:,|and|\+)\s*(?:§\s*[\d.]+|eq\.?\s*\d+|Fig\.?\s*\d+))*)*|§\s*[\d.]+(?:-[\d.]+)?|\beq\.?\s*\d+\b|\bFig\.?\s*\d+\b/g;

/**
 * A schema description split into plain text and its references:
 * "relocation limit (DDGI-P §5, Fig 7)" -> {text: "relocation limit", refs: ["DDGI-P §5", "Fig 7"]}.
 */
export function splitReferences(description) {
  const raw = String(description || '');
  const refs = (raw.match(REF) || []).map((r) => r.trim()).filter(Boolean);
  let text = raw.replace(REF, '');
  // parentheses left empty or with only separators / stage names, then stray punctuation
  text = text.replace(/\((?:[\s,;+]|stages?\s+[a-z_+ ]+)*\)/gi, '').replace(/\s+([,;.])/g, '$1').replace(/[,;]\s*([,;)])/g, '$1')
    .replace(/\(\s*[,;]\s*/g, '(').replace(/\s{2,}/g, ' ').replace(/^[\s,;:]+|[\s,;:]+$/g, '').trim();
  return { text, refs };
}

/** Label, help line, tooltip and advanced flag of a field-tree node (state/schema.js). */
export function fieldUi(node) {
  const ui = FIELD_UI[node.path] || {};
  const { text, refs } = splitReferences(node.description);
  const label = ui.label || humanize(node.key);
  const help = 'help' in ui ? ui.help : text;
  const tooltip = [node.description, refs.length ? `References: ${refs.join('; ')}` : '', node.path ? `config: ${node.path}` : '']
    .filter(Boolean).join('\n');
  return { label, help, tooltip, unit: ui.unit || '', advanced: !!ui.advanced, refs };
}
