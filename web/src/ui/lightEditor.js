/**
 * The lights and sky part of the bake form, for people: a light's type is chosen (a point light to start
 * with), intensities carry their physical unit (cd for bulbs and spots, lx for the sun) with hints, cone
 * angles and the sun's elevation/azimuth are degrees, colours are colour pickers (sRGB shown, linear sent).
 * Each control is {el, get(), set(value)} like the generic ones of configForm.js; get() returns exactly what
 * the config takes (LightConfig in radians, sky as linear RGB radiance).
 */
import {
  LIGHT_TYPES, SPOT_DEFAULTS, defaultLight, degToRad, hexToLinear, linearToHex, radToDegRounded, skyControls, skyRadiance,
  sunAngles, sunDirection,
} from '../state/lighting.js';
import { clear, h } from './dom.js';

const num = (v) => (v === '' || v === null || v === undefined || !Number.isFinite(Number(v)) ? null : Number(v));

function numberInput(name, value, { step = 'any', min, max, title } = {}) {
  return h('input', { type: 'number', step, min, max, name, value: value == null ? '' : String(value), title });
}

function vec3Inputs(name, value, onChange) {
  const ins = [0, 1, 2].map((i) => numberInput(`${name}.${i}`, value ? value[i] : '', { title: ['x', 'y', 'z'][i] }));
  ins.forEach((i) => { i.classList.add('tuple-item'); i.addEventListener('input', onChange); });
  return {
    el: h('span.tuple', ins.map((i, k) => [h('span.axis', ['x', 'y', 'z'][k]), i])),
    get: () => ins.map((i) => num(i.value)),
    set: (v) => ins.forEach((i, k) => { i.value = v && v[k] != null ? String(v[k]) : ''; }),
  };
}

function line(label, control, { hint = '', unit = '', cls = '', title = '' } = {}) {
  return h(`div.light-row${cls ? `.${cls}` : ''}`, h('label.light-label', { title: title || hint }, label),
    h('div.light-control', control, unit ? h('span.unit', ` ${unit}`) : null, hint ? h('div.help', hint) : null));
}

/**
 * One light's controls.
 * @param {string} path  e.g. "scene.lights.0"
 * @param {object} value  a LightConfig (radians)
 * @param {{onChange: Function, onRemove: Function, onPlace?: Function, bounds: () => number[][]|null}} opts
 */
function lightEntry(path, value, { onChange, onRemove, onPlace, bounds, index }) {
  let v = { ...defaultLight(value?.type || 'point', bounds()), ...(value || {}) };
  let color = [...(v.color || [1, 1, 1])];
  const type = h('select', { name: `${path}.type` }, Object.entries(LIGHT_TYPES).map(([k, t]) => h('option', { value: k }, t.label)));
  const position = vec3Inputs(`${path}.position`, v.position, onChange);
  const direction = vec3Inputs(`${path}.direction`, v.direction, onChange);
  const sun = sunAngles(v.direction || sunDirection(45, 30));
  const elevation = numberInput(`${path}.sun_elevation`, sun.elevation, { min: -90, max: 90, title: 'degrees above the horizon' });
  const azimuth = numberInput(`${path}.sun_azimuth`, sun.azimuth, { min: 0, max: 360, title: 'compass degrees: 0 = sun towards −Z, 90 = towards +X' });
  const picker = h('input', { type: 'color', name: `${path}.color`, value: linearToHex(color), title: 'colour (shown sRGB, sent as linear RGB)' });
  const intensity = numberInput(`${path}.intensity`, v.intensity, { min: 0, max: 1e9 });
  const unit = h('span.unit');
  const hint = h('div.help');
  const inner = numberInput(`${path}.inner_cone_angle`, radToDegRounded(v.inner_cone_angle ?? 0), { min: 0, max: 90, title: 'degrees from the axis: full brightness inside' });
  const outer = numberInput(`${path}.outer_cone_angle`, radToDegRounded(v.outer_cone_angle ?? Math.PI / 4), { min: 0, max: 90, title: 'degrees from the axis: dark outside' });
  const rangeOn = h('input', { type: 'checkbox', title: 'limit the light\'s reach (unchecked: infinite, physical falloff)' });
  const range = numberInput(`${path}.range`, v.range ?? '', { min: 0 });
  const placeBtn = onPlace ? h('button.small', { type: 'button', dataset: { place: path }, title: 'open the 3D view and click a surface: the light goes 0.3 m in front of it' }, 'Place in 3D view…') : null;
  type.value = v.type;
  rangeOn.checked = v.range != null;
  range.disabled = !rangeOn.checked;

  const rows = {
    position: line('Position', h('span', position.el, h('span.unit', ' m '), placeBtn), { hint: 'metres, +Y up (glTF)' }),
    direction: line('Aim (direction)', direction.el, { hint: 'the direction the light shines, e.g. 0, −1, 0 = straight down' }),
    sun: line('Sun position', h('span', h('label', 'elevation ', elevation, ' °'), ' ', h('label', 'azimuth ', azimuth, ' °')),
      { hint: 'elevation: degrees above the horizon (90 = overhead); azimuth: 0° = sun towards −Z, 90° = towards +X' }),
    cone: line('Cone', h('span', h('label', 'inner ', inner, ' °'), ' ', h('label', 'outer ', outer, ' °')),
      { hint: 'half-angles from the beam axis in degrees: full brightness inside the inner cone, none outside the outer' }),
  };
  const el = h('fieldset.list-entry.light-entry', { dataset: { path, type: v.type } },
    h('legend', `Light ${index + 1} `, h('button.small', { type: 'button', on: { click: onRemove } }, 'remove')),
    line('Type', type),
    rows.position, rows.direction, rows.sun,
    line('Colour', picker),
    h('div.light-row', h('label.light-label', 'Intensity'), h('div.light-control', intensity, unit, hint)),
    rows.cone,
    line('Range', h('span', h('label.set', rangeOn, ' limit '), range), { unit: 'm', hint: 'unchecked: the light reaches everywhere (physical 1/d² falloff)' }));

  function sync() {
    const t = type.value;
    el.dataset.type = t;
    unit.textContent = ` ${LIGHT_TYPES[t].unit}`;
    unit.title = LIGHT_TYPES[t].unitName;
    hint.textContent = LIGHT_TYPES[t].hint;
    rows.position.hidden = t === 'directional';
    rows.direction.hidden = t !== 'spot';
    rows.sun.hidden = t !== 'directional';
    rows.cone.hidden = t !== 'spot';
  }
  let prevType = v.type;
  type.addEventListener('change', () => {
    const t = type.value;
    if (num(intensity.value) === LIGHT_TYPES[prevType].intensity || num(intensity.value) == null) intensity.value = String(LIGHT_TYPES[t].intensity);
    if (t !== 'directional' && position.get().some((x) => x == null)) position.set(defaultLight(t, bounds()).position);
    if (t === 'spot' && direction.get().some((x) => x == null)) direction.set([0, -1, 0]);
    if (t === 'spot' && prevType !== 'spot' && !num(inner.value)) {  // a new spot: the spot's cone, not a point light's unused one
      inner.value = String(SPOT_DEFAULTS.inner);
      outer.value = String(SPOT_DEFAULTS.outer);
    }
    prevType = t;
    sync();
    onChange();
  });
  picker.addEventListener('input', () => { color = hexToLinear(picker.value); onChange(); });
  rangeOn.addEventListener('change', () => { range.disabled = !rangeOn.checked; if (rangeOn.checked && !range.value) range.value = '10'; onChange(); });
  for (const i of [intensity, elevation, azimuth, inner, outer, range]) i.addEventListener('input', onChange);
  sync();

  return {
    el,
    get() {
      const t = type.value;
      const out = { type: t, position: null, direction: null, color: [...color], intensity: num(intensity.value), range: rangeOn.checked ? num(range.value) : null,
        inner_cone_angle: 0, outer_cone_angle: Math.PI / 4 };
      if (t !== 'directional') out.position = position.get();
      if (t === 'spot') {
        out.direction = direction.get();
        out.inner_cone_angle = degToRad(num(inner.value) ?? 0);
        out.outer_cone_angle = degToRad(num(outer.value) ?? 45);
      }
      if (t === 'directional') out.direction = sunDirection(num(elevation.value) ?? 45, num(azimuth.value) ?? 0);
      return out;
    },
    /** Move the light (a click in the 3D view, the gizmo). */
    setPosition(p) { position.set(p.map((x) => Math.round(x * 1000) / 1000)); },
  };
}

/**
 * The list of lights (config `scene.lights`).
 * @param {{onChange: Function, bounds: () => number[][]|null, onPlace?: (index: number) => void}} opts
 */
export function createLightList({ onChange, bounds, onPlace }) {
  const list = h('div.list.light-list');
  let entries = [];
  const add = h('button.small#add-light', { type: 'button', title: 'a point light near the ceiling of the scene; change its type, position and intensity below' }, '+ add a light');
  const render = (values) => {
    clear(list);
    entries = values.map((v, idx) => {
      const e = lightEntry(`scene.lights.${idx}`, v, {
        index: idx, bounds, onChange,
        onRemove: () => { const cur = entries.map((x) => x.get()); cur.splice(idx, 1); render(cur); onChange(); },
        onPlace: onPlace ? () => onPlace(idx) : null,
      });
      list.append(e.el);
      return e;
    });
    if (!values.length) list.append(h('p.muted.no-lights', 'No lights added: the scene is lit by the file\'s own lights, emissive surfaces and the sky.'));
  };
  add.addEventListener('click', () => { const cur = entries.map((e) => e.get()); cur.push(defaultLight('point', bounds())); render(cur); onChange(); });
  render([]);
  return {
    el: h('div', list, add),
    get: () => entries.map((e) => e.get()),
    set: (v) => render(v || []),
    /** Add a light (e.g. placed by clicking in the 3D view); returns its index. */
    add(light) { const cur = entries.map((e) => e.get()); cur.push(light); render(cur); onChange(); return cur.length - 1; },
    setPosition(index, p) { if (entries[index]) { entries[index].setPosition(p); onChange(); } },
  };
}

/** Sky colour and strength -> `scene.sky` (linear RGB radiance). */
export function createSkyControl(onChange) {
  let exact = [0, 0, 0];   // what set() was given, kept until the controls are touched (no rounding through the picker)
  const picker = h('input', { type: 'color', name: 'scene.sky.color', value: '#ffffff', title: 'sky colour (shown sRGB, sent as linear RGB)' });
  const strength = h('input', { type: 'number', name: 'scene.sky.strength', min: 0, max: 1e6, step: 'any', value: '0' });
  const touched = () => { exact = null; onChange(); };
  picker.addEventListener('input', touched);
  strength.addEventListener('input', touched);
  return {
    el: h('span.sky-control', h('label', 'colour ', picker), ' ', h('label', 'strength ', strength), h('span.unit', ' cd/m²'),
      h('div.help', 'light from every direction where rays reach open sky (windows, open scenes). 0 = no sky (a closed room lit by '
        + 'its lights). An open sky lights a surface facing it with π × strength lux: an overcast day ≈ 1,000-3,000.')),
    get: () => (exact ? [...exact] : skyRadiance(picker.value, strength.value)),
    set: (v) => { exact = [...(v || [0, 0, 0])]; const c = skyControls(exact); picker.value = c.hex; strength.value = String(c.strength); },
  };
}
