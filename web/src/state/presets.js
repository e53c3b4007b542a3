/**
 * Bake presets (Preview / Medium / Production): partial bake configs in proto/presets.json, the one file the
 * CLI's `kiln bake --preset` reads too. Pure functions: a preset applied to the form's values (the defaults,
 * then the preset; the scene's lighting and the seed stay as the person set them), and which preset the
 * form's values are (null once a value differs: "custom").
 */
import presetsDoc from '../../../proto/presets.json';

/** [{id, label, description, config}] in the file's order. */
export const PRESETS = presetsDoc.presets;

/** Top-level config keys a preset leaves alone: the scene's lights, sky and materials, and the seed. */
export const KEPT = ['scene', 'seed'];

const clone = (v) => (v === undefined ? undefined : JSON.parse(JSON.stringify(v)));
const isTable = (v) => v !== null && typeof v === 'object' && !Array.isArray(v);

/** `over` on top of `base` (new object): tables merge key by key, anything else (numbers, lists) is replaced. */
export function mergeConfig(base, over) {
  const out = clone(base) ?? {};
  for (const [k, v] of Object.entries(over || {})) {
    out[k] = isTable(v) && isTable(out[k]) ? mergeConfig(out[k], v) : clone(v);
  }
  return out;
}

/** Deep equality that ignores key order (form values and schema defaults list keys differently). */
export function sameValue(a, b) {
  if (a === b) return true;
  if (Array.isArray(a) || Array.isArray(b)) {
    return Array.isArray(a) && Array.isArray(b) && a.length === b.length && a.every((x, i) => sameValue(x, b[i]));
  }
  if (isTable(a) && isTable(b)) {
    const keys = new Set([...Object.keys(a), ...Object.keys(b)]);
    return [...keys].every((k) => sameValue(a[k], b[k]));
  }
  return false;
}

/**
 * The form values after choosing `preset`: `defaults` (the form's defaults, shaped like the config), the
 * KEPT sections of `values`, then the preset's partial config.
 */
export function applyPreset(defaults, values, preset) {
  const out = clone(defaults) ?? {};
  for (const k of KEPT) if (values && k in values) out[k] = clone(values[k]);
  return mergeConfig(out, preset?.config || {});
}

/** The id of the preset `values` are (applied over the same defaults), or null: a custom config. */
export function presetOf(presets, defaults, values) {
  const hit = (presets || []).find((p) => sameValue(applyPreset(defaults, values, p), values));
  return hit ? hit.id : null;
}

/** The preset with this id, or null. */
export function findPreset(id, presets = PRESETS) {
  return (presets || []).find((p) => p.id === id) || null;
}
