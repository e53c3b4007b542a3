/**
 * Lights and sky as an artist sets them, and the config the server takes (proto/models.py LightConfig,
 * SceneSection.sky). Pure functions: degrees <-> radians, sRGB colour pickers <-> linear RGB, a sun given by
 * elevation and azimuth <-> the direction its light travels, sensible physical defaults per light type, and
 * the warnings shown before a bake starts (a light outside the scene, nothing lighting the scene) — the same
 * rules the ingest stage applies after the fact (workers/stages/lighting.py).
 */

export const degToRad = (d) => (Number(d) * Math.PI) / 180;
export const radToDeg = (r) => (Number(r) * 180) / Math.PI;

/** Degrees shown in the form: radians rounded to 0.01° (what a person typed comes back unchanged). */
export const radToDegRounded = (r) => Math.round(radToDeg(r) * 100) / 100;

/** KHR_lights_punctual units per light type, the default intensity and a hint for people. */
export const LIGHT_TYPES = {
  point: {
    label: 'Point (bulb)', unit: 'cd', unitName: 'candela', intensity: 100,
    hint: 'candela (lumens ÷ 4π): a 40 W-equivalent bulb ≈ 35 cd, 60 W ≈ 65 cd, 100 W ≈ 130 cd',
  },
  spot: {
    label: 'Spot', unit: 'cd', unitName: 'candela', intensity: 400,
    hint: 'candela along the beam: a halogen spot ≈ 300-1500 cd, a stage light far more',
  },
  directional: {
    label: 'Sun (directional)', unit: 'lx', unitName: 'lux', intensity: 10000,
    hint: 'lux on a surface facing the sun: overcast ≈ 1,000-10,000 lx, direct sunlight ≈ 100,000 lx',
  },
};

/** Cone defaults of a spot light, degrees (the config takes radians). */
export const SPOT_DEFAULTS = { inner: 30, outer: 45 };
/** Default sun: 45° above the horizon, from azimuth 30°. */
export const SUN_DEFAULTS = { elevation: 45, azimuth: 30 };

/** The centre of scene bounds [[minx, miny, minz], [maxx, maxy, maxz]] at 80 % of its height (a ceiling lamp). */
export function lampPosition(bounds) {
  if (!bounds) return [0, 2, 0];
  const [lo, hi] = bounds;
  return [(lo[0] + hi[0]) / 2, lo[1] + 0.8 * (hi[1] - lo[1]), (lo[2] + hi[2]) / 2].map((x) => Math.round(x * 1000) / 1000);
}

/**
 * The direction sunlight travels (unit, glTF frame: +Y up) for a sun `elevation` degrees above the horizon at
 * compass `azimuth` degrees (0° = the sun towards −Z, 90° = towards +X).
 */
export function sunDirection(elevation, azimuth) {
  const el = degToRad(elevation), az = degToRad(azimuth);
  const toSun = [Math.sin(az) * Math.cos(el), Math.sin(el), -Math.cos(az) * Math.cos(el)];
  return toSun.map((x) => (Math.abs(x) < 1e-12 ? 0 : -x));
}

/** Inverse of sunDirection: {elevation, azimuth} in degrees of a direction (need not be unit). */
export function sunAngles(direction) {
  const n = Math.hypot(...direction) || 1;
  const [x, y, z] = direction.map((c) => -c / n);  // towards the sun
  const elevation = radToDeg(Math.asin(Math.max(-1, Math.min(1, y))));
  let azimuth = radToDeg(Math.atan2(x, -z));
  if (azimuth < 0) azimuth += 360;
  return { elevation: Math.round(elevation * 100) / 100, azimuth: Math.round(azimuth * 100) / 100 % 360 };
}

/** sRGB transfer function (IEC 61966-2-1), one channel in [0, 1]. */
export const srgbToLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
export const linearToSrgb = (c) => (c <= 0.0031308 ? c * 12.92 : 1.055 * c ** (1 / 2.4) - 0.055);

/** '#rrggbb' (what <input type=color> gives, sRGB) -> linear RGB [0..1]^3. */
export function hexToLinear(hex) {
  const m = /^#?([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(hex || '');
  if (!m) return [1, 1, 1];
  return m.slice(1).map((x) => Math.round(srgbToLinear(parseInt(x, 16) / 255) * 1e6) / 1e6);
}

/** Linear RGB -> '#rrggbb' for a colour picker; components above 1 are scaled down together first. */
export function linearToHex(rgb) {
  const peak = Math.max(...rgb, 0);
  const scale = peak > 1 ? 1 / peak : 1;
  return `#${rgb.map((c) => Math.round(Math.min(1, Math.max(0, linearToSrgb(c * scale))) * 255).toString(16).padStart(2, '0')).join('')}`;
}

/**
 * Sky radiance (linear RGB, SceneSection.sky) from a colour picker and a strength: colour (linear) × strength.
 * An open sky lights a surface facing it with π × radiance (lux in the lights' units).
 */
export function skyRadiance(hex, strength) {
  const s = Math.max(0, Number(strength) || 0);
  return hexToLinear(hex).map((c) => Math.round(c * s * 1e6) / 1e6);
}

/** Inverse of skyRadiance: {hex, strength} of a sky radiance (strength = its largest component). */
export function skyControls(sky) {
  const s = Math.max(...(sky || [0, 0, 0]), 0);
  if (!(s > 0)) return { hex: '#ffffff', strength: 0 };
  return { hex: linearToHex(sky.map((c) => c / s)), strength: Math.round(s * 1e6) / 1e6 };
}

/** A new light of `type` with sensible defaults (config form, radians): a lamp near the ceiling, a sun at 45°. */
export function defaultLight(type = 'point', bounds = null) {
  const t = LIGHT_TYPES[type] ? type : 'point';
  const light = { type: t, position: null, direction: null, color: [1, 1, 1], intensity: LIGHT_TYPES[t].intensity, range: null,
    inner_cone_angle: 0, outer_cone_angle: Math.PI / 4 };
  if (t !== 'directional') light.position = lampPosition(bounds);
  if (t === 'spot') {
    light.direction = [0, -1, 0];
    light.inner_cone_angle = degToRad(SPOT_DEFAULTS.inner);
    light.outer_cone_angle = degToRad(SPOT_DEFAULTS.outer);
  }
  if (t === 'directional') light.direction = sunDirection(SUN_DEFAULTS.elevation, SUN_DEFAULTS.azimuth);
  return light;
}

/** Fraction of the bounds' diagonal a light may lie outside them (workers/stages/lighting.py LIGHT_BOUNDS_MARGIN). */
export const LIGHT_BOUNDS_MARGIN = 0.1;

/** Whether a position lies within scene bounds grown by `margin` × their diagonal. */
export function insideBounds(position, bounds, margin = LIGHT_BOUNDS_MARGIN) {
  if (!bounds || !position) return true;
  const [lo, hi] = bounds;
  const m = margin * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  return position.every((x, i) => x >= lo[i] - m && x <= hi[i] + m);
}

const fmt = (v) => `(${v.map((x) => Number(x).toPrecision(3).replace(/\.?0+$/, '')).join(', ')})`;

/**
 * Warnings to show before a bake starts: [{code, message, path}] (path: the config field to fix).
 * @param {object} config  the form's full values (BakeConfig shape)
 * @param {{bounds?: number[][], lights?: number, emissive_materials?: number}|null} scene  the scene record
 */
export function preBakeWarnings(config, scene) {
  const out = [];
  const sec = config?.scene || {};
  const lights = sec.lights || [];
  const bounds = scene?.bounds || null;
  lights.forEach((l, i) => {
    if (l.type === 'directional' || !l.position) return;
    if (!insideBounds(l.position, bounds)) {
      out.push({
        code: 'light_outside_scene', path: `scene.lights.${i}`,
        message: `Light ${i + 1} (${l.type}) at ${fmt(l.position)} m is outside the scene, which spans ${fmt(bounds[0])} … ${fmt(bounds[1])} m: `
          + 'it will light little or nothing. Positions are metres, +Y up.',
      });
    }
  });
  const sceneLights = sec.use_scene_lights === false ? 0 : Number(scene?.lights || 0);
  const sky = Math.max(...(sec.sky || [0, 0, 0]));
  const emissive = scene?.emissive_materials;
  if (scene && !lights.length && !sceneLights && !(sky > 0) && emissive === 0) {
    const dropped = scene.lights && sec.use_scene_lights === false
      ? ` (the file's ${scene.lights} light${scene.lights === 1 ? ' is' : 's are'} switched off by “Use the file's lights”)` : '';
    out.push({
      code: 'unlit_scene', path: 'scene.lights',
      message: `Nothing lights this scene: no lights${dropped}, no emissive surfaces and a black sky. The bake would be black: add a light or raise the sky strength.`,
    });
  }
  return out;
}

/**
 * What the viewer's direct light leaves out of a bake's lights (the renderer's limits: `maxLights` a pass, as
 * lights.glsl MAX_LIGHTS; shadow maps for the first `cubes` point/spot and `dirs` directional lights among those
 * drawn, as renderer/shadows.js). '' when it draws them all, shadowed; else a sentence for the Lights panel. The
 * baked GI and the evaluate stage's pictures hold every light whatever this says.
 * @param {{type: string}[]} lights
 * @param {{maxLights: number, cubes: number, dirs: number}} limits
 */
export function lightCoverage(lights, { maxLights, cubes, dirs }) {
  const list = (lights || []).filter((l) => l && ['point', 'spot', 'directional'].includes(l.type));
  const drawn = list.slice(0, maxLights);
  const local = drawn.filter((l) => l.type !== 'directional').length;
  const sun = drawn.length - local;
  const unshadowed = Math.max(0, local - cubes) + Math.max(0, sun - dirs);
  const parts = [];
  if (list.length > drawn.length) {
    parts.push(`The viewer draws the direct light of the first ${drawn.length} of the bake's ${list.length} lights `
      + `(${maxLights} a pass); the baked GI and the evaluate stage's pictures hold all ${list.length}.`);
  }
  if (unshadowed > 0) {
    parts.push(`${unshadowed} of the ${drawn.length} drawn ${unshadowed === 1 ? 'lights is' : 'lights are'} unshadowed here `
      + `(shadow maps for ${cubes} point/spot and ${dirs} directional lights).`);
  }
  return parts.join(' ');
}
