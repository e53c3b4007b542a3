/**
 * The dashboard's like-with-like views (DOM; the numbers come from state/quality.js):
 * - metricChart: one evaluate metric over a scene's bakes in time order (SVG: a point per bake with its ±stderr,
 *   a dashed line per stored threshold on that metric, points of bakes that fail it in red);
 * - abView: two bakes' previews of the same camera and mode on one canvas split by a draggable slider (A left,
 *   B right), their difference |B − A| amplified on a second canvas, the scale stated;
 * - deltaTable: quality metrics B − A with standard errors and which bake is better.
 */
import { betterWay, chartScales, diffGain, diffImage, gatesFor, metricDeltas, splitColumn } from '../state/quality.js';
import { h, shortId, formatTime } from './dom.js';
import './compareViews.css';

const SVG = 'http://www.w3.org/2000/svg';
function s(tag, attrs = {}, ...children) {
  const el = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) if (v != null) el.setAttribute(k, String(v));
  for (const c of children) if (c) el.append(typeof c === 'string' ? document.createTextNode(c) : c);
  return el;
}

export const fmtNum = (v) => (v == null ? '–' : Math.abs(v) >= 1000 || (Math.abs(v) < 0.01 && v !== 0) ? v.toExponential(2) : Number(v.toFixed(4)).toString());

/**
 * `bakes` in time order ({id, created, metrics}); `gates` the scene's ({text, metric, op, value}); `results`
 * bake id -> {text -> passed} (the server's check). Bakes without the metric are left out.
 */
export function metricChart(key, bakes, gates, results, { width = 260, height = 130 } = {}) {
  const pts = bakes.filter((b) => Number.isFinite(b.metrics?.[key])).map((b) => ({
    bake: b, value: b.metrics[key], stderr: Number.isFinite(b.metrics[`${key}_stderr`]) ? b.metrics[`${key}_stderr`] : null,
    time: b.created,
  }));
  const own = gatesFor(key, gates);
  const sc = chartScales(pts, own.map((g) => g.value), { width, height, pad: 18 });
  const svg = s('svg', { class: 'metric-chart', width, height, viewBox: `0 0 ${width} ${height}`, 'data-metric': key,
    'data-points': pts.length, role: 'img', 'aria-label': `${key} over ${pts.length} bakes` });
  svg.append(s('rect', { x: 0, y: 0, width, height, fill: '#fff' }));
  svg.append(s('text', { x: 4, y: 12, class: 'chart-title' }, `${key} ${betterWay(key) === 'one' ? '(→ 1)' : '↓'}`));
  svg.append(s('text', { x: width - 4, y: 12, class: 'chart-axis', 'text-anchor': 'end' }, fmtNum(sc.max)));
  svg.append(s('text', { x: width - 4, y: height - 4, class: 'chart-axis', 'text-anchor': 'end' }, fmtNum(sc.min)));
  if (sc.timed) {   // the x axis is time: the first and the last bake's
    svg.append(s('text', { x: 4, y: height - 4, class: 'chart-axis chart-time', 'data-time': sc.t0 }, formatTime(sc.t0)));
    svg.append(s('text', { x: width / 2, y: height - 4, class: 'chart-axis chart-time', 'text-anchor': 'middle',
      'data-time': sc.t1 }, `→ ${formatTime(sc.t1)}`));
  }
  for (const g of own) {
    const y = sc.y(g.value);
    svg.append(s('line', { class: 'threshold', x1: 0, x2: width, y1: y, y2: y, 'data-gate': g.text, 'data-value': g.value },
      s('title', {}, `threshold: fails when ${g.text}`)));
    svg.append(s('text', { x: 4, y: y - 3, class: 'threshold-label' }, `${g.op} ${fmtNum(g.value)}`));
  }
  if (pts.length > 1) {
    svg.append(s('polyline', { class: 'series', fill: 'none', points: pts.map((p, i) => `${sc.x(i)},${sc.y(p.value)}`).join(' ') }));
  }
  pts.forEach((p, i) => {
    const x = sc.x(i);
    if (p.stderr != null) svg.append(s('line', { class: 'stderr', x1: x, x2: x, y1: sc.y(p.value - p.stderr), y2: sc.y(p.value + p.stderr) }));
    const failed = own.some((g) => results?.[p.bake.id]?.[g.text] === false);
    svg.append(s('circle', { class: `point${failed ? ' failed' : ''}`, cx: x, cy: sc.y(p.value), r: 3.5, 'data-bake': p.bake.id, 'data-value': p.value },
      s('title', {}, `${shortId(p.bake.id)} · ${formatTime(p.bake.created)}: ${fmtNum(p.value)}${p.stderr != null ? ` ± ${fmtNum(p.stderr)}` : ''}${failed ? ' — fails a threshold' : ''}`)));
  });
  return svg;
}

/**
 * Quality metrics B − A with standard errors, and which is better (table#delta-table). `paired`: GET /v1/compare's
 * response, whose `delta_stderr` (same reference: paired) replaces sqrt(stderr A² + stderr B²) where present.
 */
export function deltaTable(a, b, paired = null) {
  const se = paired?.paired?.paired
    ? Object.fromEntries(Object.entries(paired.metrics || {}).map(([k, v]) => [k, v.delta_stderr]))
    : null;
  const rows = metricDeltas(a, b, se);
  if (!rows.length) return h('p.muted#delta-table-none', 'No evaluate metrics in both bakes.');
  const pm = (v, se) => (se == null ? fmtNum(v) : `${fmtNum(v)} ± ${fmtNum(se)}`);
  const word = (r) => {
    if (r.better === 'same') return 'same';
    const arrow = betterWay(r.key) === 'one' ? '→1' : '↓';
    return `${r.better.toUpperCase()} better ${arrow}${r.significant === false ? ' (within 2σ)' : ''}`;
  };
  const pairedAny = rows.some((r) => r.paired);
  const title = pairedAny
    ? 'B − A ± its standard error, paired: both bakes were scored against the same reference, whose noise cancels in the delta (* : not paired, sqrt(stderr A² + stderr B²))'
    : 'B − A ± sqrt(stderr A² + stderr B²)';
  return h('table.data#delta-table', { dataset: { paired: String(pairedAny) } },
    h('thead', h('tr', h('th', 'metric'), h('th.num', `A ${shortId(a.id)}`), h('th.num', `B ${shortId(b.id)}`),
      h('th.num', { title }, pairedAny ? 'B − A ± stderr (paired)' : 'B − A ± stderr'), h('th', { title: 'lower is better; mean_ratio: closer to 1' }, 'better'))),
    h('tbody', rows.map((r) => h('tr', { dataset: { metric: r.key, better: r.better, significant: String(r.significant), paired: String(r.paired) } },
      h('td', r.key), h('td.num', pm(r.a, r.seA)), h('td.num', pm(r.b, r.seB)),
      h('td.num.delta', `${r.delta > 0 ? '+' : ''}${pm(r.delta, r.se)}${pairedAny && !r.paired && r.se != null ? ' *' : ''}`),
      h('td.better', { dataset: { better: r.better } }, word(r))))));
}

/**
 * A/B slider and difference image of preview pairs: `pairs` [{camera, mode, a, b}] (artifact names of both
 * bakes); `load(bakeId, name)` -> Promise<ImageBitmap|HTMLImageElement>.
 */
export function abView(a, b, pairs, load) {
  const both = pairs.filter((p) => p.a && p.b);
  if (!both.length) return h('p.muted#ab-none', 'No preview both bakes have.');
  const order = ['mask_normalized', 'mask', 'ddgi', 'prt', 'leaking', 'direct', 'reference'];
  const rank = (m) => (order.includes(m) ? order.indexOf(m) : order.length);
  const sorted = [...both].sort((x, y) => rank(x.mode) - rank(y.mode));
  const pick = h('select#ab-pair', sorted.map((p, i) => h('option', { value: String(i) }, `${p.camera} · ${p.mode}`)));
  const canvas = h('canvas#ab-canvas.ab-canvas', { title: 'drag: A left of the line, B right of it' });
  const slider = h('input#ab-slider', { type: 'range', min: '0', max: '1000', value: '500', title: 'A | B split' });
  const diff = h('canvas#ab-diff.ab-canvas');
  const scale = h('p.muted#ab-diff-scale', '');
  const status = h('span.muted#ab-status', 'loading…');
  let imgs = null; // [ImageData A, ImageData B]
  let token = 0;

  function draw() {
    if (!imgs) return;
    const [ia, ib] = imgs;
    const col = splitColumn(ia.width, Number(slider.value) / 1000);
    const ctx = canvas.getContext('2d');
    ctx.putImageData(ib, 0, 0);
    if (col > 0) ctx.putImageData(ia, 0, 0, 0, 0, col, ia.height);
    ctx.fillStyle = '#ffcc00';
    ctx.fillRect(Math.min(col, ia.width - 1), 0, 1, ia.height);
    canvas.dataset.split = String(col);
  }

  function pixels(img, w, hgt) {
    const c = document.createElement('canvas');
    c.width = w; c.height = hgt;
    const ctx = c.getContext('2d');
    ctx.drawImage(img, 0, 0, w, hgt);
    return ctx.getImageData(0, 0, w, hgt);
  }

  async function show() {
    const t = ++token;
    const p = sorted[Number(pick.value) || 0];
    status.textContent = 'loading…';
    delete canvas.dataset.ready;
    try {
      const [la, lb] = await Promise.all([load(a.id, p.a.name), load(b.id, p.b.name)]);
      if (t !== token) return;
      const w = la.width, hgt = la.height;
      imgs = [pixels(la, w, hgt), pixels(lb, w, hgt)];
      canvas.width = w; canvas.height = hgt;
      diff.width = w; diff.height = hgt;
      const gain = diffGain(diffImage(imgs[0].data, imgs[1].data, 1).max);
      const d = diffImage(imgs[0].data, imgs[1].data, gain);
      diff.getContext('2d').putImageData(new ImageData(d.data, w, hgt), 0, 0);
      diff.dataset.nonzero = String(d.nonzero);
      diff.dataset.max = String(d.max);
      diff.dataset.gain = String(gain);
      scale.textContent = `|B − A| per channel × ${gain}: black = identical, full brightness = a difference of ${Math.ceil(255 / gain)}/255 or more; `
        + `largest difference ${d.max}/255, ${d.nonzero} of ${w * hgt} pixels differ.`;
      canvas.dataset.pair = `${p.camera}/${p.mode}`;
      canvas.dataset.ready = '1';
      status.textContent = `A ${p.a.name} · B ${p.b.name}`;
      draw();
    } catch (e) {
      if (t === token) status.textContent = `previews: ${e.message}`;
    }
  }

  let dragging = false;
  const fromPointer = (e) => {
    const r = canvas.getBoundingClientRect();
    slider.value = String(Math.round(Math.min(1, Math.max(0, (e.clientX - r.left) / r.width)) * 1000));
    draw();
  };
  canvas.addEventListener('pointerdown', (e) => { dragging = true; canvas.setPointerCapture?.(e.pointerId); fromPointer(e); });
  canvas.addEventListener('pointermove', (e) => { if (dragging) fromPointer(e); });
  canvas.addEventListener('pointerup', () => { dragging = false; });
  slider.addEventListener('input', draw);
  pick.addEventListener('change', show);
  show();
  return h('div#ab-view',
    h('div.row', h('label', 'Preview ', pick), status),
    h('div.ab-grid',
      h('figure', h('figcaption', `A ${shortId(a.id)} ◀ slider ▶ B ${shortId(b.id)}`), canvas, slider),
      h('figure', h('figcaption', 'difference |B − A|'), diff, scale)));
}
