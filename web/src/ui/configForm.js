/**
 * The bake-config form, generated from the server's JSON Schema (state/schema.js builds the field tree).
 * Sections fold; numbers carry the schema's bounds; nullable fields have a "set" checkbox; lists of objects
 * (lights) add and remove entries; anything exotic is edited as JSON. Errors from a 422 land on the field
 * the message names (data-path = the dotted config path).
 */
import { buildFieldTree, configDiff, fieldErrors, walkFields } from '../state/schema.js';
import { clear, h } from './dom.js';

const clone = (v) => (v === undefined ? undefined : JSON.parse(JSON.stringify(v)));

function hint(node) {
  const parts = [];
  if (node.min !== undefined) parts.push(`≥ ${node.min}`);
  if (node.exclusiveMin !== undefined) parts.push(`> ${node.exclusiveMin}`);
  if (node.max !== undefined) parts.push(`≤ ${node.max}`);
  if (node.exclusiveMax !== undefined) parts.push(`< ${node.exclusiveMax}`);
  return parts.join(', ');
}

/** A control for one node: {el, get(), set(value)}. */
function control(node, onChange) {
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
      const parts = node.items.map((it) => control(it, onChange));
      parts.forEach((p) => p.el.classList.add('tuple-item'));
      return {
        el: h('span.tuple', parts.map((p) => p.el)),
        get: () => parts.map((p) => p.get()),
        set: (v) => parts.forEach((p, i) => p.set(v ? v[i] : null)),
      };
    }
    case 'nullable': {
      const inner = control(node.inner, onChange);
      const on = h('input', { type: 'checkbox', title: 'set this value (unchecked: none)' });
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
      const addBtn = h('button.small', { type: 'button' }, `+ add ${node.item.title || 'entry'}`);
      const render = (values) => {
        clear(list);
        entries = values.map((v, idx) => {
          const sub = objectFields({ ...node.item, path: `${node.path}.${idx}` }, onChange, true);
          sub.set(v);
          const rm = h('button.small', { type: 'button', on: { click: () => { const cur = entries.map((e) => e.get()); cur.splice(idx, 1); render(cur); onChange(); } } }, 'remove');
          list.append(h('fieldset.list-entry', { dataset: { path: `${node.path}.${idx}` } }, h('legend', `${node.item.title || 'entry'} ${idx + 1} `, rm), sub.el));
          return sub;
        });
      };
      addBtn.addEventListener('click', () => { const cur = entries.map((e) => e.get()); cur.push(clone(node.item.default)); render(cur); onChange(); });
      return { el: h('div', list, addBtn), get: () => entries.map((e) => e.get()), set: (v) => render(v || []) };
    }
    case 'object':
      return objectFields(node, onChange, false);
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
  return h('div.field', { dataset: { path: node.path } },
    h('label.field-label', { title: node.description }, node.title || node.key),
    h('div.field-control', ctl.el, node.description ? h('div.help', node.description) : null, h('div.field-error')));
}

function objectFields(node, onChange, flat) {
  const ctls = node.children.map((c) => ({ c, ctl: control(c, onChange) }));
  const body = h('div.object', ctls.map(({ c, ctl }) => (c.kind === 'object' ? ctl.el : row(c, ctl))));
  const el = flat ? body : h('details.section', { dataset: { path: node.path }, open: node.path === 'place' || node.path === 'scene' },
    h('summary', node.title || node.key, node.description ? h('span.help', ` — ${node.description.split('\n')[0]}`) : null),
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
  const onChange = () => { form && form.clearErrors(); };
  const top = objectFields({ ...tree, children: tree.children }, onChange, true);
  top.set(tree.default);
  const el = h('div.config-form', general, top.el,
    h('div.form-actions', h('button.small', { type: 'button', on: { click: () => { top.set(tree.default); onChange(); } } }, 'reset to defaults')));
  form = {
    el, tree,
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
    /** Set one value by dotted path (used by tests and by "presets"). */
    set(path, value) {
      const v = top.get();
      const keys = path.split('.');
      let o = v;
      for (const k of keys.slice(0, -1)) o = o[k];
      o[keys[keys.length - 1]] = value;
      top.set(v);
    },
  };
  return form;
}
