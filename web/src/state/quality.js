/**
 * Pure helpers of the dashboard's like-with-like views: which stored threshold (a gate of server/gates.py, as
 * GET /v1/scenes/{id}/thresholds returns it: {text, metric, op, value}) belongs on which metric's chart, which of
 * two bakes is better on a metric (with the standard errors of the evaluate stage, `<key>_stderr`), the chart's
 * scales, and the A/B difference image. The pass/fail of a gate is the server's (gates.check); nothing here
 * re-implements it.
 */

/** A gate's metric pattern as a RegExp: `*` matches any text (fnmatch, as gates.check; `?` one character). */
export function patternRegExp(pattern) {
  const esc = String(pattern).replace(/[.+^${}()|[\]\\]/g, '\\$&').replace(/\*/g, '.*').replace(/\?/g, '.');
  return new RegExp(`^${esc}$`);
}

/** The gates whose metric (or pattern) names `key`. */
export function gatesFor(key, gates) {
  return (gates || []).filter((g) => patternRegExp(g.metric).test(key));
}

/** Which way is better for a metric key: 'lower' (errors, leak, costs), 'one' (mean_ratio: closer to 1). */
export function betterWay(key) {
  const name = String(key).split('.').pop();
  return name === 'mean_ratio' ? 'one' : 'lower';
}

/** 'a', 'b' or 'same': which value is better for `key` (betterWay). */
export function betterOf(key, a, b) {
  if (a == null || b == null || a === b) return 'same';
  const score = betterWay(key) === 'one' ? (v) => Math.abs(v - 1) : (v) => v;
  const sa = score(a), sb = score(b);
  return sa === sb ? 'same' : sb < sa ? 'b' : 'a';
}

/** Quality metrics the delta table lists: their name (last part) and that it is an error-like metric. */
export const QUALITY_METRICS = ['rmse', 'flip', 'leak', 'mean_ratio', 'indirect_relative_rmse', 'indirect_excess'];

/**
 * The evaluate metrics of two bakes (flat `bake.metrics`), B − A with standard errors: rows
 * {key, a, b, seA, seB, delta, se, paired, better, significant} for every quality metric both have, sorted.
 * `pairedSe` ({key: stderr}, GET /v1/compare's `delta_stderr`): the delta's standard error when both bakes were
 * scored against the same reference, whose noise they share (`paired` true); otherwise `se` is
 * sqrt(seA² + seB²) (null where a bake lacks its `_stderr`), which counts that noise twice. `significant`
 * |delta| > 2·se (null without se).
 */
export function metricDeltas(a, b, pairedSe = null) {
  const ma = a?.metrics || {}, mb = b?.metrics || {};
  const num = (v) => (typeof v === 'number' && Number.isFinite(v) ? v : null);
  const keys = Object.keys(ma).filter((k) => !k.endsWith('_stderr') && QUALITY_METRICS.includes(k.split('.').pop())
    && num(ma[k]) != null && num(mb[k]) != null).sort();
  return keys.map((key) => {
    const x = ma[key], y = mb[key];
    const seA = num(ma[`${key}_stderr`]), seB = num(mb[`${key}_stderr`]);
    const ps = num(pairedSe?.[key]);
    const se = ps != null ? ps : seA != null && seB != null ? Math.sqrt(seA * seA + seB * seB) : null;
    const delta = y - x;
    const better = betterOf(key, x, y);
    return { key, a: x, b: y, seA, seB, delta, se, paired: ps != null, better,
      significant: se == null ? null : Math.abs(delta) > 2 * se };
  });
}

/**
 * Scales of a small chart: points [{value, stderr?}] in time order at x = index, and horizontal lines at the
 * threshold values. Returns {x(i), y(v), min, max} mapping into [pad, width − pad] × [height − pad, pad].
 */
export function chartScales(points, lines, { width = 240, height = 120, pad = 16 } = {}) {
  const vals = [];
  for (const p of points) {
    vals.push(p.value);
    if (p.stderr != null) vals.push(p.value - p.stderr, p.value + p.stderr);
  }
  for (const v of lines) vals.push(v);
  let min = Math.min(...vals), max = Math.max(...vals);
  if (!Number.isFinite(min)) { min = 0; max = 1; }
  if (max - min < 1e-12) { const d = Math.abs(max) * 0.1 || 1; min -= d; max += d; }
  const span = max - min;
  min -= span * 0.08; max += span * 0.08;
  const n = points.length;
  // x: the bakes' times (`time`, seconds) when every point has one and they differ, else their order
  const times = points.map((p) => p.time);
  const t0 = Math.min(...times), t1 = Math.max(...times);
  const timed = n > 1 && times.every(Number.isFinite) && t1 > t0;
  const x = (i) => (n <= 1 ? width / 2
    : pad + ((timed ? (times[i] - t0) / (t1 - t0) : i / (n - 1)) * (width - 2 * pad)));
  const y = (v) => height - pad - ((v - min) / (max - min)) * (height - 2 * pad);
  return { x, y, min, max, timed, t0, t1 };
}

/**
 * |A − B| per channel × gain of two RGBA pixel arrays of the same size (ImageData.data), alpha opaque.
 * Returns {data, max, nonzero}: the amplified image, the largest difference (0..255, before the gain) and how many
 * pixels differ at all.
 */
export function diffImage(a, b, gain = 8) {
  const out = new Uint8ClampedArray(a.length);
  let max = 0, nonzero = 0;
  for (let i = 0; i < a.length; i += 4) {
    let any = false;
    for (let c = 0; c < 3; c++) {
      const d = Math.abs(a[i + c] - b[i + c]);
      if (d > max) max = d;
      if (d) any = true;
      out[i + c] = d * gain;
    }
    out[i + 3] = 255;
    if (any) nonzero += 1;
  }
  return { data: out, max, nonzero };
}

/**
 * The amplification of the difference image: the largest power of two (1 … 16) that keeps the largest
 * difference `max` (0..255) from saturating, so small differences show and large ones are not all white.
 */
export function diffGain(max) {
  if (!(max > 0)) return 16;
  return Math.min(16, Math.max(1, 2 ** Math.floor(Math.log2(255 / max))));
}

/** The canvas column where the A/B slider splits the view (A left of it, B from it): 0..width. */
export function splitColumn(width, fraction) {
  return Math.round(Math.min(1, Math.max(0, fraction)) * width);
}
