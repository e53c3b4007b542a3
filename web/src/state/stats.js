/**
 * Dashboard numbers from bake objects (GET /v1/bakes/{id}): time per stage, total bake time, memory (sum of
 * artifact bytes), flattened metrics, and deltas between two bakes. Pure functions.
 */

/** Stage name -> seconds (wall, as recorded; cached stages count their original time but are flagged). */
export function stageTimes(bake) {
  const out = {};
  for (const s of bake.stages || []) out[s.name] = { seconds: s.seconds ?? null, cached: !!s.cached, status: s.status };
  return out;
}

/** Sharded stages (visibility.0 … visibility.N-1 + visibility) folded into their group for table columns. */
export function stageGroups(bake) {
  const out = {};
  for (const s of bake.stages || []) {
    const g = s.name.split('.')[0];
    const cur = out[g] || { seconds: 0, cached: true, status: s.status, parts: 0 };
    cur.seconds += s.seconds || 0;
    cur.cached = cur.cached && !!s.cached;
    cur.parts += 1;
    if (s.status !== 'succeeded') cur.status = s.status;
    out[g] = cur;
  }
  return out;
}

/** Seconds from started to finished (wall), else the sum of stage seconds. */
export function bakeSeconds(bake) {
  if (bake.started && bake.finished) return Math.max(0, bake.finished - bake.started);
  const t = (bake.stages || []).reduce((s, x) => s + (x.seconds || 0), 0);
  return t || null;
}

/** Bytes of the bake's artifacts (the bundle's size, manifest aside). null when the list is not known. */
export function memoryBytes(bake) {
  if (!Array.isArray(bake.artifacts)) return null;
  return bake.artifacts.reduce((s, a) => s + (a.bytes || 0), 0);
}

/** {"a.b": number} from nested metrics objects (numbers only; arrays and strings are left out). */
export function flattenMetrics(metrics, prefix = '', out = {}) {
  if (!metrics || typeof metrics !== 'object') return out;
  for (const [k, v] of Object.entries(metrics)) {
    const key = prefix ? `${prefix}.${k}` : k;
    if (typeof v === 'number' && Number.isFinite(v)) out[key] = v;
    else if (v && typeof v === 'object' && !Array.isArray(v)) flattenMetrics(v, key, out);
  }
  return out;
}

/** Union of metric keys over bakes, sorted. */
export function metricColumns(bakes) {
  const keys = new Set();
  for (const b of bakes) Object.keys(flattenMetrics(b.metrics)).forEach((k) => keys.add(k));
  return [...keys].sort();
}

/** Every numeric series the chart can plot for a bake: derived ones plus metrics. */
export function chartValues(bake) {
  const out = { 'bake seconds': bakeSeconds(bake), 'memory MiB': memoryBytes(bake) != null ? memoryBytes(bake) / 2 ** 20 : null };
  for (const [g, v] of Object.entries(stageGroups(bake))) out[`${g} seconds`] = v.seconds;
  return { ...out, ...flattenMetrics(bake.metrics) };
}

/** Rows of (name, a, b, delta, relative) for two bakes over the union of chart values. */
export function compareBakes(a, b) {
  const va = chartValues(a), vb = chartValues(b);
  const names = [...new Set([...Object.keys(va), ...Object.keys(vb)])];
  return names.map((name) => {
    const x = va[name] ?? null, y = vb[name] ?? null;
    const delta = x != null && y != null ? y - x : null;
    const rel = delta != null && x ? delta / Math.abs(x) : null;
    return { name, a: x, b: y, delta, relative: rel };
  });
}

/** Config leaves that differ between two bakes: [{path, a, b}]. */
export function configDelta(a, b, prefix = '') {
  const out = [];
  const keys = new Set([...Object.keys(a || {}), ...Object.keys(b || {})]);
  for (const k of [...keys].sort()) {
    const x = a?.[k], y = b?.[k];
    const path = prefix ? `${prefix}.${k}` : k;
    const isObj = (v) => v && typeof v === 'object' && !Array.isArray(v);
    if (isObj(x) && isObj(y)) out.push(...configDelta(x, y, path));
    else if (JSON.stringify(x) !== JSON.stringify(y)) out.push({ path, a: x, b: y });
  }
  return out;
}

export function formatBytes(n) {
  if (n == null) return '–';
  const u = ['B', 'KiB', 'MiB', 'GiB'];
  let i = 0;
  let v = n;
  while (v >= 1024 && i < u.length - 1) { v /= 1024; i++; }
  return `${v < 10 && i ? v.toFixed(2) : v < 100 && i ? v.toFixed(1) : Math.round(v)} ${u[i]}`;
}

export function formatSeconds(s) {
  if (s == null) return '–';
  if (s < 1) return `${(s * 1000).toFixed(0)} ms`;
  if (s < 60) return `${s.toFixed(s < 10 ? 2 : 1)} s`;
  return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
}

const EVAL_MODES = ['reference', 'mask_normalized', 'mask', 'ddgi', 'leaking', 'direct', 'prt'];

/**
 * The evaluate stage's PNG previews of a bake (bundle.md 5.4: `eval_<camera>_<mode>` and
 * `eval_<camera>_<mode>_error`; `eval_contact` and the json are left out): [{camera, mode, name, error}]
 * with `error` the heatmap's artifact name (or null), `name` the preview's (or null).
 */
export function evalPreviews(bake) {
  const byKey = new Map();
  for (const a of bake?.artifacts || []) {
    if (!a.name.startsWith('eval_') || (a.format && a.format !== 'png')) continue;
    let rest = a.name.slice(5);
    const isError = rest.endsWith('_error');
    if (isError) rest = rest.slice(0, -6);
    const known = EVAL_MODES.find((m) => rest.endsWith(`_${m}`));
    const cut = known ? rest.length - known.length - 1 : rest.indexOf('_');
    if (cut <= 0) continue;  // eval_contact, eval_metrics, eval_cameras
    const camera = rest.slice(0, cut), mode = rest.slice(cut + 1);
    const key = `${camera}\u0000${mode}`;
    const cur = byKey.get(key) || { camera, mode, name: null, error: null };
    cur[isError ? 'error' : 'name'] = a.name;
    byKey.set(key, cur);
  }
  const order = ['reference', 'direct', 'leaking', 'ddgi', 'mask', 'mask_normalized', 'prt'];
  const rank = (m) => (order.includes(m) ? order.indexOf(m) : order.length);
  return [...byKey.values()].sort((x, y) => x.camera.localeCompare(y.camera, undefined, { numeric: true }) || rank(x.mode) - rank(y.mode)
    || x.mode.localeCompare(y.mode));
}

/**
 * Previews of two bakes side by side: one row per (camera, mode) either has, {camera, mode, a, b} with a/b
 * the evalPreviews entries (null where that bake lacks it). [] unless both bakes have previews.
 */
export function comparePreviews(a, b) {
  const pa = evalPreviews(a), pb = evalPreviews(b);
  if (!pa.length || !pb.length) return [];
  const key = (p) => `${p.camera}\u0000${p.mode}`;
  const ma = new Map(pa.map((p) => [key(p), p])), mb = new Map(pb.map((p) => [key(p), p]));
  const rows = [];
  for (const p of [...pa, ...pb.filter((x) => !ma.has(key(x)))]) rows.push({ camera: p.camera, mode: p.mode, a: ma.get(key(p)) || null, b: mb.get(key(p)) || null });
  return rows;
}

/**
 * The bake's warnings as `[{code, message, stage}]`: `bake.warnings` (GET /v1/bakes[/{id}], the manifest), else
 * gathered from the stages' `stats.warnings` (a server from before top-level warnings), shards folded into their
 * stage and identical ones kept once.
 */
export function bakeWarnings(bake) {
  if (!bake) return [];
  if (Array.isArray(bake.warnings)) return bake.warnings;
  const out = [];
  const seen = new Set();
  for (const s of bake.stages || []) {
    const list = s.stats && s.stats.warnings;
    if (!Array.isArray(list)) continue;
    for (const w of list) {
      const item = { code: String(w?.code ?? 'warning'), message: String(w?.message ?? w ?? ''), stage: s.name.split('.')[0] };
      const key = `${item.code}\u0000${item.message}\u0000${item.stage}`;
      if (!seen.has(key)) { seen.add(key); out.push(item); }
    }
  }
  return out;
}
