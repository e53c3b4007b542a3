/**
 * Dashboard numbers from bake objects (GET /v1/bakes/{id}): time per stage, total bake time, artifact size
 * (sum of artifact bytes), probes, K, lights, flattened metrics with their units, and deltas between two
 * bakes. Pure functions.
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

/** The bytes of the bake's artifacts on disk (the bundle's size): named "artifact size" for people. */
export const artifactBytes = memoryBytes;

/**
 * Catalog metrics that repeat a column of their own (stage times: one column per stage; artifact_bytes:
 * "artifact size"), left out of the metric columns and the chart's list.
 */
export const isDerivedMetric = (key) => key.startsWith('stage_seconds.') || key === 'artifact_bytes';

/** The metrics of the evaluate stage shown by default ("key metrics"); the rest on request. */
export const KEY_METRICS = ['rmse', 'flip', 'leak', 'pass_ms'];

/**
 * Union of metric keys over bakes, sorted, without the derived ones; `which` = 'key' keeps KEY_METRICS
 * (and the time ratios), 'none' none, 'all' every one.
 */
export function metricColumns(bakes, which = 'all') {
  const keys = new Set();
  for (const b of bakes) Object.keys(flattenMetrics(b.metrics)).forEach((k) => { if (!isDerivedMetric(k)) keys.add(k); });
  const all = [...keys].sort();
  if (which === 'none') return [];
  if (which === 'key') return all.filter((k) => KEY_METRICS.includes(k.split('.').pop()) && !k.startsWith('ratio.'));
  return all;
}

const METRIC_INFO = {
  rmse: { label: 'RMSE', unit: '', help: 'tone-mapped colour error against the path-traced reference, 0..1 (MD §4.2)' },
  flip: { label: 'FLIP', unit: '', help: 'perceptual error against the reference, 0..1' },
  leak: { label: 'leak', unit: '', help: 'fraction of indirect light where the reference has none (light through walls)' },
  indirect_relative_rmse: { label: 'indirect error', unit: '×', help: 'RMSE of the indirect light relative to the reference\'s' },
  indirect_excess: { label: 'excess indirect', unit: 'lx', help: 'mean indirect light above the reference\'s' },
  gi_fetches_per_pixel: { label: 'GI fetches', unit: '/px', help: 'texture fetches of the GI lookup per pixel' },
  pass_fetches_per_pixel: { label: 'fetches', unit: '/px', help: 'texture fetches of the whole shading pass per pixel' },
  pass_ms: { label: 'shading pass', unit: 'ms', help: 'GPU time of the full-screen shading pass (median)' },
  texture_bytes: { label: 'GI textures', unit: 'bytes', help: 'memory of the mode\'s GI textures' },
};

/**
 * A metric key ("mask.rmse", "ratio.mask_over_leaking.pass_ms") in words: {mode, label, unit, help,
 * lowerIsBetter, bytes, header}. Every metric the evaluate stage writes is an error, a cost or a ratio of
 * costs: lower is better.
 */
export function metricInfo(key) {
  const parts = key.split('.');
  const name = parts[parts.length - 1];
  const known = METRIC_INFO[name] || { label: name.replace(/_/g, ' '), unit: '', help: '' };
  let mode = parts.length > 1 ? parts[0] : '';
  let { label, unit, help } = known;
  if (parts[0] === 'ratio' && parts.length === 3) {
    mode = parts[1].replace('_over_', ' / ');
    label = `${known.label} ratio`;
    unit = '×';
    help = `${known.label} of ${parts[1].replace('_over_', ' over ')}`;
  }
  const bytes = unit === 'bytes';
  const header = `${mode ? `${mode} ` : ''}${label}${unit && !bytes ? ` (${unit})` : ''} ↓`;
  return { key, mode, label, unit, help: `${help}${help ? '; ' : ''}lower is better`, lowerIsBetter: true, bytes, header };
}

/** The scene's name for people: the uploaded file's name, else the start of its id. */
export function sceneLabel(scenes, id) {
  const s = (scenes || []).find((x) => x.id === id);
  return s && s.filename ? s.filename : id ? id.slice(0, 10) : '';
}

/** Probes in the bake's grid (nx·ny·nz from the place stage), null before it ran. */
export function probeCount(bake) {
  const st = (bake?.stages || []).find((s) => s.name === 'place')?.stats;
  const c = st?.counts || bake?.manifest?.grid?.counts;
  return Array.isArray(c) ? c.reduce((a, b) => a * b, 1) : null;
}

/** K, the mask clusters of the bake (config masks.clusters, default 4); null without a masks stage. */
export function clusterCount(bake) {
  if (!(bake?.stages || []).some((s) => s.name === 'anneal' || s.name === 'masks')) return null;
  return bake?.config?.masks?.clusters ?? 4;
}

/** Lights the bake used (the file's and the config's, ingest stage), else the config's count. */
export function lightCount(bake) {
  const st = (bake?.stages || []).find((s) => s.name === 'ingest')?.stats;
  if (st && Number.isFinite(st.lights)) return st.lights;
  const l = bake?.config?.scene?.lights;
  return Array.isArray(l) ? l.length : null;
}

/** Every numeric series the chart can plot for a bake: derived ones plus metrics. */
export function chartValues(bake) {
  const out = { 'bake seconds': bakeSeconds(bake), 'artifact size MiB': memoryBytes(bake) != null ? memoryBytes(bake) / 2 ** 20 : null,
    probes: probeCount(bake) };
  for (const [g, v] of Object.entries(stageGroups(bake))) out[`${g} seconds`] = v.seconds;
  const metrics = Object.fromEntries(Object.entries(flattenMetrics(bake.metrics)).filter(([k]) => !isDerivedMetric(k)));
  return { ...out, ...metrics };
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

/**
 * One line about a bake's probe grid (its place stage's stats): probe count, spacing (the largest of the axes'; of a
 * rectilinear grid, `layers`, the range of its gaps between neighbouring layers), and the turn of the bake frame
 * (`frame.yaw_deg`, proto/bundle.md 5) when the grid follows walls at an angle to the file's axes. '' before place.
 */
export function gridSummary(bake) {
  const st = (bake?.stages || []).find((s) => s.name === 'place')?.stats;
  if (!st || !Array.isArray(st.counts)) return '';
  const n = st.counts.reduce((a, b) => a * b, 1);
  const sp = Math.max(...(st.spacing || [0]));
  const yaw = Number(st.frame?.yaw_deg) || 0;
  const gaps = Array.isArray(st.layers)
    ? st.layers.flatMap((L) => Array.from(L || [], Number).slice(1).map((x, i) => x - Number(L[i]))).filter((g) => g > 0) : [];
  let out = gaps.length
    ? `${n.toLocaleString('en-US')} probes, ${Math.min(...gaps).toFixed(2)}–${Math.max(...gaps).toFixed(2)} m apart (rectilinear layers)`
    : `${n.toLocaleString('en-US')} probes, ${sp.toFixed(2)} m apart`;
  if (yaw) out += `; grid turned ${yaw.toFixed(1)}° about the vertical to follow the walls`;
  return out;
}
