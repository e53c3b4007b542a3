/**
 * The bake-config form, generated from the JSON Schema the server publishes (/v1/config/schema, exported
 * from proto.models.BakeConfig by pydantic). Pure functions: the schema -> a tree of field descriptors;
 * form values -> the config to POST (only what differs from the defaults, so defaults that depend on each
 * other, like place.counts vs place.spacing, stay the server's business); a 422 message -> per-field errors.
 */

function resolve(schema, root) {
  let s = schema;
  const seen = new Set();
  while (s && s.$ref) {
    if (seen.has(s.$ref)) throw new Error(`cyclic $ref ${s.$ref}`);
    seen.add(s.$ref);
    const path = s.$ref.replace(/^#\//, '').split('/');
    let target = root;
    for (const p of path) target = target?.[p];
    if (!target) throw new Error(`unresolved $ref ${s.$ref}`);
    const { $ref, ...rest } = s;
    s = { ...target, ...rest };
  }
  return s;
}

const clone = (v) => (v === undefined ? undefined : JSON.parse(JSON.stringify(v)));

/**
 * A field descriptor tree.
 * kinds: object {children}, number/integer {min, max, exclusiveMin, exclusiveMax}, boolean,
 * enum {options}, tuple {items: descriptors}, list {item: descriptor} (arrays of objects or of enums),
 * nullable {inner} (anyOf [X, null]), json (anything else, edited as JSON text).
 * Every node has path (dotted, from the config root), key, title, description, default.
 */
export function buildFieldTree(schema, root = schema, path = '', key = '') {
  const s = resolve(schema, root);
  const base = {
    path, key, title: s.title || key, description: s.description || '',
    default: clone(s.default),
  };
  if (s.anyOf) {
    const options = s.anyOf.map((o) => resolve(o, root));
    const nonNull = options.filter((o) => o.type !== 'null');
    if (nonNull.length === 1 && options.length === 2) {
      const inner = buildFieldTree({ ...nonNull[0], title: s.title, description: s.description }, root, path, key);
      return { ...base, kind: 'nullable', inner };
    }
    return { ...base, kind: 'json' };
  }
  if (s.enum || s.const !== undefined) return { ...base, kind: 'enum', options: s.enum || [s.const] };
  if (s.type === 'object' && s.properties) {
    const children = Object.entries(s.properties).map(([k, sub]) => buildFieldTree(sub, root, path ? `${path}.${k}` : k, k));
    let def = base.default;
    if (def === undefined) def = Object.fromEntries(children.map((c) => [c.key, clone(c.default)]));
    return { ...base, default: def, kind: 'object', children };
  }
  if (s.type === 'integer' || s.type === 'number') {
    return {
      ...base, kind: s.type, min: s.minimum, max: s.maximum, exclusiveMin: s.exclusiveMinimum,
      exclusiveMax: s.exclusiveMaximum,
    };
  }
  if (s.type === 'boolean') return { ...base, kind: 'boolean' };
  if (s.type === 'string') return { ...base, kind: 'string' };
  if (s.type === 'array' && s.prefixItems) {
    const items = s.prefixItems.map((it, i) => buildFieldTree(it, root, `${path}.${i}`, String(i)));
    return { ...base, kind: 'tuple', items };
  }
  if (s.type === 'array' && s.items) {
    const item = buildFieldTree(s.items, root, `${path}.*`, '*');
    if (item.kind === 'object' || item.kind === 'enum') return { ...base, kind: 'list', item, maxItems: s.maxItems, minItems: s.minItems };
  }
  return { ...base, kind: 'json' };
}

/** Every descriptor that gets its own row or section in the form (depth first; tuple items belong to their tuple). */
export function walkFields(node, out = []) {
  out.push(node);
  if (node.kind === 'object') node.children.forEach((c) => walkFields(c, out));
  if (node.kind === 'nullable' && node.inner.kind === 'object') node.inner.children.forEach((c) => walkFields(c, out));
  return out;
}

const equal = (a, b) => JSON.stringify(a) === JSON.stringify(b);

/**
 * The config to send: the leaves of `values` (a plain object shaped like the config) that differ from the
 * defaults of the tree, nested. Whole lists and tuples are sent when they differ.
 */
export function configDiff(tree, values) {
  const walk = (node, value) => {
    if (node.kind === 'object' && value && typeof value === 'object' && !Array.isArray(value)) {
      const out = {};
      for (const c of node.children) {
        if (!(c.key in value)) continue;
        const d = walk(c, value[c.key]);
        if (d !== undefined) out[c.key] = d;
      }
      return Object.keys(out).length ? out : undefined;
    }
    return equal(value, node.default) ? undefined : value;
  };
  return walk(tree, values) || {};
}

/**
 * Split a 422 message of POST /v1/bakes ("config.place.counts.0: Input should be ...; config.place: Value error,
 * give exactly one of counts or spacing") into per-field errors, each on the nearest field the form has.
 * @param {string} message
 * @param {Set<string>|string[]} knownPaths  dotted paths of the form's fields (config root = '')
 * @returns {{path: string, message: string}[]}  path '' = the whole config
 */
export function fieldErrors(message, knownPaths) {
  const known = new Set(knownPaths);
  const out = [];
  const re = /(?:^|;\s*)(config(?:\.[^\s:;]+)*|body|scene_id): /g;
  const hits = [...String(message).matchAll(re)];
  if (!hits.length) return [{ path: '', message: String(message) }];
  hits.forEach((m, i) => {
    const start = m.index + m[0].length;
    const end = i + 1 < hits.length ? hits[i + 1].index : message.length;
    const text = message.slice(start, end).replace(/;\s*$/, '').trim();
    let parts = m[1] === 'config' ? [] : m[1].split('.').slice(1);
    if (m[1] === 'body' || m[1] === 'scene_id') parts = [];
    while (parts.length && !known.has(parts.join('.'))) parts.pop();
    const sub = m[1].split('.').slice(1 + parts.length).join('.');
    out.push({ path: parts.join('.'), message: sub ? `${sub}: ${text}` : text });
  });
  return out;
}
