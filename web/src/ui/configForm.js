/**
 * The bake-config form, generated from the server's JSON Schema (state/schema.js builds the field tree).
 * Sections fold; numbers carry the schema's bounds; nullable fields have a "set" checkbox; lists of objects
 * (lights) add and remove entries; anything exotic is edited as JSON. Errors from a 422 land on the field
 * the message names (data-path = the dotted config path).
 *
 * For people (state/formLabels.js): labels in words, help lines without paper references (those go to the
 * tooltip), advanced fields folded under "Advanced"; lights and sky have their own controls (ui/lightEditor.js:
 * a type, physical units, degrees, colour pickers).
 *
 * Presets (Preview / Medium / Production, proto/presets.json through state/presets.js, the file `kiln bake --preset`
 * reads): choosing one fills the form (the defaults, then the preset; lights, sky and seed stay); the picker shows
 * "custom" once a value differs from every preset.
 */
import { buildFieldTree, configDiff, fieldErrors, walkFields } from '../state/schema.js';
import { OPEN_SECTIONS, fieldUi, humanize } from '../state/formLabels.js';
import { PRESETS, applyPreset, findPreset, presetOf } from '../state/presets.js';
import { clear, h } from './dom.js';
import { createLightList, createSkyControl } from './lightEditor.js';

const clone = (v) => (v === undefined ? undefined : JSON.parse(JSON.stringify(v)));

function hint(node) {
  const parts = [];
  if (node.min !== undefined) parts.push(`≥ ${node.min}`);
  if (node.exclusiveMin !== undefined) parts.push(`> ${node.exclusiveMin}`);
  if (node.max !== undefined) parts.push(`≤ ${node.max}`);
  if (node.exclusiveMax !== undefined) parts.push(`< ${node.exclusiveMax}`);
  return parts.join(', ');
}

/** A control for one node: {el, get(), set(value)}. `ctx`: the form's shared state (scene bounds, hooks). */
function control(node, onChange, ctx = {}) {
  if (node.path === 'scene.lights' && node.kind === 'list') {
    const c = createLightList({ onChange, bounds: () => ctx.bounds || null, onPlace: (i) => ctx.onPlaceLight && ctx.onPlaceLight(i) });
    ctx.lights = c;
    return c;
  }
  if (node.path === 'scene.sky' && node.kind === 'tuple') return createSkyControl(onChange);
  switch (node.kind) {
    case 'integer':
    case 'number': {
      const input = h('input', {
        type: 'number', step: node.kind === 'integer' ? '1' : 'any', min: node.min ?? node.exclusiveMin, max: node.max ?? node.exclusiveMax,
        title: hint(node), name: node.path, on: { input: onChange },
      });
      return {
        el: input,
        get: () => (input.value === '' ? null : Number(input.value)),
        set: (v) => { input.value = v === null || v === undefined ? '' : String(v); },
      };
    }
    case 'boolean': {
      const input = h('input', { type: 'checkbox', name: node.path, on: { change: onChange } });
      return { el: input, get: () => input.checked, set: (v) => { input.checked = !!v; } };
    }
    case 'string': {
      const input = h('input', { type: 'text', name: node.path, on: { input: onChange } });
      return { el: input, get: () => input.value, set: (v) => { input.value = v ?? ''; } };
    }
    case 'enum': {
      const select = h('select', { name: node.path, on: { change: onChange } },
        node.options.map((o) => h('option', { value: JSON.stringify(o) }, String(o))));
      return { el: select, get: () => JSON.parse(select.value), set: (v) => { select.value = JSON.stringify(v); } };
    }
    case 'tuple': {
      const parts = node.items.map((it) => control(it, onChange, ctx));
      parts.forEach((p) => p.el.classList.add('tuple-item'));
      return {
        el: h('span.tuple', parts.map((p) => p.el)),
        get: () => parts.map((p) => p.get()),
        set: (v) => parts.forEach((p, i) => p.set(v ? v[i] : null)),
      };
    }
    case 'nullable': {
      const inner = control(node.inner, onChange, ctx);
      const on = h('input', { type: 'checkbox', title: 'set this value (unchecked: automatic / none)' });
      const sync = () => { inner.el.classList.toggle('disabled', !on.checked); inner.el.querySelectorAll?.('input,select,textarea').forEach((e) => { e.disabled = !on.checked; }); if (inner.el.matches?.('input,select,textarea')) inner.el.disabled = !on.checked; };
      on.addEventListener('change', () => { sync(); onChange(); });
      let lastValue = null;
      return {
        el: h('span.nullable', h('label.set', on, ' set'), ' ', inner.el),
        get: () => (on.checked ? inner.get() : null),
        set: (v) => {
          on.checked = v !== null && v !== undefined;
          if (on.checked) { inner.set(v); lastValue = v; } else if (lastValue === null) inner.set(node.inner.default ?? null);
          sync();
        },
      };
    }
    case 'list': {
      if (node.item.kind === 'enum') {  // a set of choices: checkboxes
        const boxes = node.item.options.map((o) => ({ o, box: h('input', { type: 'checkbox', on: { change: onChange } }) }));
        return {
          el: h('span.choices', boxes.map(({ o, box }) => h('label', box, ` ${o} `))),
          get: () => boxes.filter((b) => b.box.checked).map((b) => b.o),
          set: (v) => boxes.forEach((b) => { b.box.checked = (v || []).includes(b.o); }),
        };
      }
      const list = h('div.list');
      let entries = [];
      const noun = fieldUi(node).label.replace(/s$/, '').toLowerCase() || 'entry';  // "Cameras" -> "camera", never a class name
      const addBtn = h('button.small', { type: 'button' }, `+ add a ${noun}`);
      const render = (values) => {
        clear(list);
        entries = values.map((v, idx) => {
          const sub = objectFields({ ...node.item, path: `${node.path}.${idx}` }, onChange, true, ctx);
          sub.set(v);
          const rm = h('button.small', { type: 'button', on: { click: () => { const cur = entries.map((e) => e.get()); cur.splice(idx, 1); render(cur); onChange(); } } }, 'remove');
          list.append(h('fieldset.list-entry', { dataset: { path: `${node.path}.${idx}` } }, h('legend', `${humanize(noun)} ${idx + 1} `, rm), sub.el));
          return sub;
        });
      };
      addBtn.addEventListener('click', () => { const cur = entries.map((e) => e.get()); cur.push(clone(node.item.default)); render(cur); onChange(); });
      return { el: h('div', list, addBtn), get: () => entries.map((e) => e.get()), set: (v) => render(v || []) };
    }
    case 'object':
      return objectFields(node, onChange, false, ctx);
    default: {
      const ta = h('textarea', { rows: 2, name: node.path, on: { input: onChange } });
      return {
        el: ta,
        get: () => { try { return JSON.parse(ta.value || 'null'); } catch { return ta.value; } },
        set: (v) => { ta.value = JSON.stringify(v ?? null); },
      };
    }
  }
}

function row(node, ctl) {
  const ui = fieldUi(node);
  return h('div.field', { dataset: { path: node.path } },
    h('label.field-label', { title: ui.tooltip }, ui.label, ui.unit ? h('span.unit', ` (${ui.unit})`) : null,
      ui.refs.length ? h('span.ref', { title: ui.tooltip }, ' ⓘ') : null),
    h('div.field-control', ctl.el, ui.help ? h('div.help', ui.help) : null, h('div.field-error')));
}

function objectFields(node, onChange, flat, ctx = {}) {
  const ctls = node.children.map((c) => ({ c, ctl: control(c, onChange, ctx) }));
  const item = ({ c, ctl }) => (c.kind === 'object' ? ctl.el : row(c, ctl));
  // advanced fields of a section (state/formLabels.js) fold under "Advanced"; whole advanced sections stay
  const basic = ctls.filter(({ c }) => c.kind === 'object' || !fieldUi(c).advanced);
  const advanced = ctls.filter((x) => !basic.includes(x));
  const body = h('div.object', basic.map(item),
    advanced.length ? h('details.advanced', { dataset: { path: `${node.path || 'root'}.advanced` } },
      h('summary', `Advanced (${advanced.length})`), advanced.map(item)) : null);
  const ui = fieldUi(node);
  const el = flat ? body : h('details.section', { dataset: { path: node.path }, open: OPEN_SECTIONS.has(node.path) },
    h('summary', { title: ui.tooltip }, ui.label, ui.help ? h('span.help', ` — ${ui.help}`) : null),
    h('div.field-error'), body);
  return {
    el,
    get: () => Object.fromEntries(ctls.map(({ c, ctl }) => [c.key, ctl.get()])),
    set: (v) => ctls.forEach(({ c, ctl }) => ctl.set(v ? v[c.key] : undefined)),
  };
}

/**
 * @param {object} schema  GET /v1/config/schema
 * @returns {{el: HTMLElement, tree: object, values(): object, config(): object, setErrors(message: string): void,
 *   clearErrors(): void, set(path: string, value: any): void}}
 */
export function createConfigForm(schema) {
  const tree = buildFieldTree(schema);
  const paths = new Set(walkFields(tree).map((n) => n.path));
  const general = h('div.field-error.form-error');
  let form;
  const listeners = [];
  const ctx = { bounds: null, onPlaceLight: null, lights: null };
  const presetSelect = h('select#bake-preset', { title: 'fill the form with a preset (proto/presets.json; the CLI: kiln bake --preset ID)' },
    h('option', { value: '' }, 'custom'), PRESETS.map((p) => h('option', { value: p.id, title: p.description }, p.label)));
  const presetHelp = h('span#preset-help.help');
  const syncPreset = () => {
    const id = presetOf(PRESETS, tree.default, top.get());
    presetSelect.value = id || '';
    presetHelp.textContent = id ? findPreset(id).description : 'your own settings (differs from every preset)';
  };
  const onChange = () => { if (form) { syncPreset(); form.clearErrors(); listeners.forEach((fn) => fn(form)); } };
  const top = objectFields({ ...tree, children: tree.children }, onChange, true, ctx);
  top.set(tree.default);
  presetSelect.addEventListener('change', () => { if (presetSelect.value) form.applyPreset(presetSelect.value); else syncPreset(); });
  const el = h('div.config-form', general,
    h('div.row.preset-row', h('label', { for: 'bake-preset' }, 'Preset '), presetSelect, ' ', presetHelp),
    top.el,
    h('div.form-actions', h('button.small', { type: 'button', on: { click: () => { top.set(tree.default); onChange(); } } }, 'reset to defaults')));
  syncPreset();
  form = {
    el, tree,
    /** Fill the form with preset `id` of proto/presets.json (the defaults, then the preset; lights, sky, seed kept). */
    applyPreset(id) {
      const preset = findPreset(id);
      if (!preset) throw new Error(`unknown preset ${id}`);
      top.set(applyPreset(tree.default, top.get(), preset));
      onChange();
    },
    /** The preset the form's values are (null: custom). */
    preset: () => presetOf(PRESETS, tree.default, top.get()),
    values: () => top.get(),
    config: () => configDiff(tree, top.get()),
    clearErrors() {
      el.querySelectorAll('.field-error').forEach((e) => { e.textContent = ''; });
      el.querySelectorAll('.has-error').forEach((e) => e.classList.remove('has-error'));
    },
    setErrors(message) {
      form.clearErrors();
      for (const { path, message: msg } of fieldErrors(message, paths)) {
        const holder = path ? el.querySelector(`[data-path="${CSS.escape(path)}"]`) : null;
        const slot = holder ? holder.querySelector(':scope > .field-control > .field-error, :scope > .field-error') : general;
        (slot || general).textContent += `${(slot || general).textContent ? '; ' : ''}${holder ? '' : path ? `${path}: ` : ''}${msg}`;
        if (holder) { holder.classList.add('has-error'); let d = holder.closest('details'); while (d) { d.open = true; d = d.parentElement.closest('details'); } }
      }
    },
    /** Call `fn(form)` after every change a person makes. */
    onChange(fn) { listeners.push(fn); },
    /** The scene the form bakes ({bounds, ...} as GET /v1/scenes lists it): defaults for new lights. */
    setScene(scene) { ctx.bounds = scene?.bounds || null; },
    /** `fn(index)` when a light's "Place in 3D view" is clicked. */
    onPlaceLight(fn) { ctx.onPlaceLight = fn; },
    /** Add a light (LightConfig, radians); returns its index in scene.lights. */
    addLight(light) { return ctx.lights.add(light); },
    /** Move light `index` of scene.lights (metres). */
    setLightPosition(index, p) { ctx.lights.setPosition(index, p); },
    /** Set one value by dotted path (used by tests and by "presets"). */
    set(path, value) {
      const v = top.get();
      const keys = path.split('.');
      let o = v;
      for (const k of keys.slice(0, -1)) o = o[k];
      o[keys[keys.length - 1]] = value;
      top.set(v);
      syncPreset();
      listeners.forEach((fn) => fn(form));  // the pre-bake warnings and the estimate follow
    },
  };
  return form;
}
