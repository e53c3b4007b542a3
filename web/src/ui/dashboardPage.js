/**
 * The dashboard (DESIGN "Who uses it" 3): bakes per scene in a table (scene name, status, probes, K, lights,
 * one column per stage's time, artifact size, and the evaluate stage's metrics with units, lower is better),
 * two picked bakes side by side with deltas, and a chart of any value across a scene's bakes over time
 * (uPlot). Preview images open full size on click.
 *
 * Like with like (compareViews.js): per scene, its stored quality thresholds (GET/PUT /v1/scenes/{id}/thresholds,
 * editable here, pass/fail per bake from the server's gates check in the table's "thresholds" column) and a small
 * chart per evaluate metric over the scene's bakes in time order with each threshold drawn as a line; for two
 * ticked bakes an A/B slider over the same camera's previews, their difference image and the quality deltas
 * with standard errors and which is better.
 */
import uPlot from 'uplot';
import 'uplot/dist/uPlot.min.css';
import {
  artifactBytes, bakeSeconds, bakeWarnings, chartValues, clusterCount, compareBakes, comparePreviews, configDelta, formatBytes, formatSeconds, lightCount,
  metricColumns, metricInfo, probeCount, sceneLabel, stageGroups,
} from '../state/stats.js';
import { clear, formatTime, h, shortId } from './dom.js';
import { abView, deltaTable, metricChart } from './compareViews.js';
import { gatesFor } from '../state/quality.js';
import { warningBadge, warningList } from './warnings.js';

const fmt = (v) => (v == null ? '–' : Math.abs(v) >= 1000 || (Math.abs(v) < 0.01 && v !== 0) ? v.toExponential(3) : Number(v.toFixed(4)).toString());

export function createDashboardPage(app) {
  const { api, store } = app;
  const sceneSelect = h('select#dash-scene');
  const refreshBtn = h('button.small#dash-refresh', { type: 'button' }, 'Refresh');
  const table = h('table#bake-table.data');
  const compare = h('div#compare');
  const chartMetric = h('select#chart-metric');
  const chartHolder = h('div#chart');
  const sceneCharts = h('div#scene-charts');
  const msg = h('p#dash-msg.muted');
  const metricSet = h('select#dash-metrics', { title: 'which evaluate metrics get a column' },
    h('option', { value: 'key' }, 'key metrics (RMSE, FLIP, leak, shading time)'), h('option', { value: 'all' }, 'all metrics'), h('option', { value: 'none' }, 'no metrics'));
  const zoomImg = h('img#image-zoom-img', { alt: '' });
  const zoomCaption = h('p.zoom-caption');
  const zoom = h('div#image-zoom.zoom-overlay', { hidden: true, title: 'click to close', on: { click: () => { zoom.hidden = true; } } }, zoomImg, zoomCaption);
  const el = h('section.page#page-dashboard',
    zoom,
    h('h2', 'Bakes'),
    h('div.row', h('label', 'Scene ', sceneSelect), refreshBtn, h('label', 'Metrics ', metricSet), msg),
    h('div.table-wrap', table),
    h('p.muted', 'Tick two bakes to compare them.'),
    compare,
    h('h2', 'Quality per scene'),
    h('p.muted', 'Each evaluate metric over the scene\'s bakes (oldest left), ± its standard error; dashed red: a stored threshold (a bake fails it when the comparison holds; red points fail).'),
    sceneCharts,
    h('h2', 'Over time'),
    h('div.row', h('label', 'Value ', chartMetric)),
    chartHolder);

  const details = new Map();  // id -> full bake (with artifacts); finished bakes do not change
  let bakes = [];
  let picked = [];
  let plot = null;
  let objectUrls = [];  // previews fetched with the API key (an <img> cannot send the Authorization header)
  let compareToken = 0;
  let thresholds = new Map();  // scene id -> GET /v1/scenes/{id}/thresholds

  async function fullBake(b) {
    const done = ['succeeded', 'failed', 'cancelled'].includes(b.status);
    if (done && details.has(b.id)) return details.get(b.id);
    const full = await api.getBake(b.id);
    details.set(b.id, full);
    return full;
  }

  async function load() {
    msg.textContent = 'loading…';
    const sceneId = sceneSelect.value || undefined;
    try {
      const { items } = await api.listBakes({ sceneId, limit: 200 });
      // fetch the full records (artifacts -> memory) a few at a time
      const out = new Array(items.length);
      let next = 0;
      await Promise.all([0, 1, 2, 3].map(async () => {
        while (next < items.length) { const i = next++; out[i] = await fullBake(items[i]).catch(() => items[i]); }
      }));
      bakes = out.sort((a, b) => (a.created || 0) - (b.created || 0));
      picked = picked.filter((id) => bakes.some((b) => b.id === id));
      msg.textContent = `${bakes.length} bake${bakes.length === 1 ? '' : 's'}`;
      await loadThresholds();
      renderTable();
      renderSceneCharts();
      renderCompare();
      renderChartOptions();
      renderChart();
    } catch (e) {
      msg.textContent = e.message;
    }
  }

  async function loadThresholds() {
    const ids = [...new Set(bakes.map((b) => b.scene_id))];
    if (sceneSelect.value && !ids.includes(sceneSelect.value)) ids.push(sceneSelect.value);
    const next = new Map();
    await Promise.all(ids.map(async (id) => {
      try { next.set(id, await api.request(`/v1/scenes/${encodeURIComponent(id)}/thresholds`)); } catch { /* scene deleted */ }
    }));
    thresholds = next;
  }

  /** bake id -> {gate text -> passed} of the scene's thresholds (the server's gates check). */
  function gateResults(sceneId) {
    const out = {};
    for (const r of thresholds.get(sceneId)?.bakes || []) out[r.bake_id] = Object.fromEntries(r.results.map((x) => [x.text, x.passed]));
    return out;
  }

  function gatesCell(b) {
    const doc = thresholds.get(b.scene_id);
    const r = doc?.bakes.find((x) => x.bake_id === b.id);
    if (!doc || !doc.thresholds.length || !r) return h('td.gates-cell', { dataset: { gates: 'none' } }, '–');
    const failed = r.results.filter((x) => !x.passed);
    return h('td.gates-cell', { dataset: { gates: r.passed ? 'pass' : 'fail' }, title: r.results.map((x) => `${x.passed ? '✓' : '✗'} ${x.message}`).join('\n') },
      h('span.badge', { dataset: { gates: r.passed ? 'pass' : 'fail' } }, r.passed ? `pass ${r.results.length}/${r.results.length}` : `fail ${failed.length}/${r.results.length}`));
  }

  function thresholdsEditor(sceneId) {
    const doc = thresholds.get(sceneId);
    const input = h('textarea.thresholds-input', { rows: 3, dataset: { scene: sceneId }, placeholder: 'one per line, e.g. mask_normalized.leak > 0.05', spellcheck: false });
    input.value = (doc?.thresholds || []).join('\n');
    const out = h('span.thresholds-msg.muted', doc?.thresholds.length ? `${doc.thresholds.length} stored` : 'none stored');
    const save = h('button.small.save-thresholds', { type: 'button', dataset: { scene: sceneId } }, 'Save thresholds');
    save.addEventListener('click', async () => {
      const list = input.value.split('\n').map((x) => x.trim()).filter(Boolean);
      out.textContent = 'saving…';
      try {
        const d = await api.request(`/v1/scenes/${encodeURIComponent(sceneId)}/thresholds`, { method: 'PUT', json: { thresholds: list } });
        thresholds.set(sceneId, d);
        renderTable();
        renderSceneCharts();
      } catch (e) {
        out.textContent = e.message;
        out.className = 'thresholds-msg error';
      }
    });
    return h('div.thresholds-editor', h('label', 'Thresholds (fail when true; METRIC OP NUMBER, * matches any text) ', h('br'), input), ' ', save, ' ', out);
  }

  function renderSceneCharts() {
    clear(sceneCharts);
    const scenes = store.get().scenes;
    const ids = [...new Set(bakes.map((b) => b.scene_id))];
    if (!ids.length) { sceneCharts.append(h('p.muted', 'No bakes yet.')); return; }
    for (const sid of ids) {
      const own = bakes.filter((b) => b.scene_id === sid && b.status === 'succeeded');
      const gates = thresholds.get(sid)?.gates || [];
      const keys = metricColumns(own, metricSet.value === 'none' ? 'key' : metricSet.value).filter((k) => !k.endsWith('_stderr') && !k.startsWith('ratio.'));
      for (const k of Object.keys(own.reduce((m, b) => Object.assign(m, b.metrics || {}), {}))) {
        if (!keys.includes(k) && !k.endsWith('_stderr') && gatesFor(k, gates).length) keys.push(k);
      }
      const results = gateResults(sid);
      sceneCharts.append(h('div.scene-charts', { dataset: { scene: sid } },
        h('h3', sceneLabel(scenes, sid), ' ', h('span.muted.small', `${own.length} succeeded bake${own.length === 1 ? '' : 's'}`)),
        thresholdsEditor(sid),
        keys.length ? h('div.chart-grid', keys.map((k) => metricChart(k, own, gates, results))) : h('p.muted', 'No evaluate metrics (bake with evaluate.enabled).')));
    }
  }

  function renderScenes() {
    const { scenes } = store.get();
    const cur = sceneSelect.value;
    clear(sceneSelect);
    sceneSelect.append(h('option', { value: '' }, 'all scenes'));
    for (const s of scenes) sceneSelect.append(h('option', { value: s.id }, `${s.filename || shortId(s.id)} · ${s.triangles} tris · ${shortId(s.id)}`));
    sceneSelect.value = cur;
  }

  function renderTable() {
    const groups = [];
    for (const b of bakes) for (const g of Object.keys(stageGroups(b))) if (!groups.includes(g)) groups.push(g);
    const metrics = metricColumns(bakes, metricSet.value);
    const infos = metrics.map(metricInfo);
    const scenes = store.get().scenes;
    clear(table);
    // two header rows: groups (stage times in seconds, metrics: lower is better), then one column each
    table.append(h('thead',
      h('tr.group-row', h('th', { colSpan: 9 }), groups.length ? h('th.group', { colSpan: groups.length, title: 'wall-clock seconds per stage; ⟳ = taken from the cache (time of the original run)' }, 'stage time (s)') : null,
        h('th', { colSpan: 2 }), metrics.length ? h('th.group', { colSpan: metrics.length, title: 'evaluate stage, means over its cameras' }, 'quality and cost — lower is better ↓') : null),
      h('tr',
        h('th', ''), h('th', 'bake'), h('th', 'scene'), h('th', 'created'), h('th', 'status'),
        h('th', { title: 'the scene\'s stored thresholds checked against the bake (server/gates.py)' }, 'thresholds'),
        h('th.num', { title: 'probes in the grid (nx × ny × nz)' }, 'probes'), h('th.num', { title: 'mask clusters (masks.clusters)' }, 'K'),
        h('th.num', { title: 'lights the bake used: the file\'s and the config\'s' }, 'lights'),
        groups.map((g) => h('th.num.stage-col', { dataset: { stage: g }, title: `seconds in stage ${g}` }, g)),
        h('th.num', { title: 'seconds from start to finish' }, 'total (s)'), h('th.num', { title: 'bytes of the bake\'s artifacts on disk (the bundle)' }, 'artifact size'),
        infos.map((m) => h('th.num.metric', { dataset: { metric: m.key }, title: `${m.key}: ${m.help}` }, m.header)))));
    const body = h('tbody');
    for (const b of [...bakes].reverse()) {
      const sg = stageGroups(b);
      const box = h('input', { type: 'checkbox', checked: picked.includes(b.id), dataset: { pick: b.id } });
      box.addEventListener('change', () => {
        picked = box.checked ? [...picked.filter((x) => x !== b.id), b.id].slice(-2) : picked.filter((x) => x !== b.id);
        table.querySelectorAll('input[data-pick]').forEach((i) => { i.checked = picked.includes(i.dataset.pick); });
        renderCompare();
      });
      const flat = chartValues(b);
      const warnings = bakeWarnings(b);
      body.append(h('tr', { dataset: { bake: b.id, status: b.status, warnings: String(warnings.length) } },
        h('td', box),
        h('td', b.status === 'succeeded' ? h('a', { href: `#/viewer/${b.id}` }, h('code', shortId(b.id))) : h('code', shortId(b.id))),
        h('td.scene-name', { title: `scene ${b.scene_id}` }, sceneLabel(scenes, b.scene_id)),
        h('td', formatTime(b.created)),
        h('td.status-cell', h('span.badge', { dataset: { status: b.status } }, b.status), ' ', warningBadge(warnings),
          b.error ? h('div.error.small', `${b.error.stage}: ${b.error.code}`) : null, warningList(warnings)),
        gatesCell(b),
        h('td.num', probeCount(b) ?? '–'), h('td.num', clusterCount(b) ?? '–'), h('td.num', lightCount(b) ?? '–'),
        groups.map((g) => h('td.num', { title: sg[g]?.cached ? 'cached (time of the original run)' : '' }, sg[g] ? `${formatSeconds(sg[g].seconds)}${sg[g].cached ? ' ⟳' : ''}` : '–')),
        h('td.num', formatSeconds(bakeSeconds(b))),
        h('td.num', formatBytes(artifactBytes(b))),
        infos.map((m) => h('td.num.metric', m.bytes ? formatBytes(flat[m.key]) : fmt(flat[m.key])))));
    }
    table.append(body);
    if (!bakes.length) table.append(h('tbody', h('tr', h('td', { colSpan: 11 }, 'No bakes for this scene yet.'))));
  }

  /** An <img> of a PNG artifact: a plain URL, or with an API key set, fetched with the header into an object URL. */
  function artifactImage(bakeId, name, alt, token) {
    const img = h('img.eval-img', { alt, title: `${alt} (click to enlarge)`, dataset: { artifact: name } });
    img.addEventListener('click', () => {
      if (!img.src) return;
      zoomImg.src = img.src;
      zoomCaption.textContent = alt;
      zoom.hidden = false;
    });
    const path = api.url(api.artifactPath(bakeId, name));
    if (!api.key) {
      img.src = path;
      return img;
    }
    fetch(path, { headers: api.headers() })
      .then((r) => { if (!r.ok) throw new Error(`HTTP ${r.status}`); return r.blob(); })
      .then((blob) => {
        if (token !== compareToken) return;
        const url = URL.createObjectURL(blob);
        objectUrls.push(url);
        img.src = url;
      })
      .catch((e) => { img.alt = `${alt}: ${e.message}`; img.classList.add('failed'); });
    return img;
  }

  /** A PNG artifact's pixels (fetched with the API key when one is set). */
  async function loadBitmap(bakeId, name) {
    const r = await fetch(api.url(api.artifactPath(bakeId, name)), { headers: api.headers() });
    if (!r.ok) throw new Error(`${name}: HTTP ${r.status}`);
    return createImageBitmap(await r.blob());
  }

  function renderPreviews(a, b, token) {
    const rows = comparePreviews(a, b);
    if (!rows.length) return h('p.muted#compare-previews-none', 'no previews: bake with evaluate.enabled');
    const cell = (x, p, which) => {
      const name = p && p[which];
      return h('td', name ? artifactImage(x.id, name, `${shortId(x.id)} ${p.camera} ${p.mode}${which === 'error' ? ' error' : ''}`, token) : h('span.muted', '–'));
    };
    return h('table.data#compare-previews', h('thead', h('tr', h('th', 'camera · mode'), h('th', `A ${shortId(a.id)}`), h('th', `B ${shortId(b.id)}`),
      h('th', 'A error'), h('th', 'B error'))),
    h('tbody', rows.map((r) => h('tr', { dataset: { camera: r.camera, mode: r.mode } },
      h('td', `${r.camera} · ${r.mode}`), cell(a, r.a, 'name'), cell(b, r.b, 'name'),
      r.mode === 'reference' ? [h('td'), h('td')] : [cell(a, r.a, 'error'), cell(b, r.b, 'error')]))));
  }

  function renderCompare() {
    clear(compare);
    compareToken += 1;
    for (const u of objectUrls) URL.revokeObjectURL(u);
    objectUrls = [];
    if (picked.length !== 2) return;
    const [a, b] = picked.map((id) => bakes.find((x) => x.id === id)).sort((x, y) => (x.created || 0) - (y.created || 0));
    if (!a || !b) return;
    const card = (x) => h('div.compare-card', { dataset: { bake: x.id } },
      h('h3', h('code', shortId(x.id)), ' ', h('span.badge', { dataset: { status: x.status } }, x.status), ' ', warningBadge(bakeWarnings(x))),
      warningList(bakeWarnings(x)),
      h('p.muted', `${formatTime(x.created)} · scene ${sceneLabel(store.get().scenes, x.scene_id)}`),
      h('p', `bake ${formatSeconds(bakeSeconds(x))} · artifact size ${formatBytes(artifactBytes(x))} · ${(x.artifacts || []).length} artifacts · ${probeCount(x) ?? '?'} probes`),
      x.status === 'succeeded' ? h('a.button.small', { href: `#/viewer/${x.id}` }, 'view') : null);
    const rows = compareBakes(a, b);
    const cfg = configDelta(a.config, b.config);
    // the deltas at once with independent standard errors, then paired ones from GET /v1/compare (same reference)
    const deltaHolder = h('div#delta-holder', deltaTable(a, b));
    const token = compareToken;
    api.request(`/v1/compare?a=${encodeURIComponent(a.id)}&b=${encodeURIComponent(b.id)}`).then((cmp) => {
      if (token !== compareToken || !cmp?.paired?.paired) return;
      clear(deltaHolder);
      deltaHolder.append(deltaTable(a, b, cmp));
    }).catch(() => { /* not evaluated yet (409) or gone: the independent errors stay */ });
    compare.append(h('h2', 'Compare'),
      h('div.compare-cards', card(a), card(b)),
      h('h3', 'Values (B − A)'),
      h('table.data#compare-table', h('thead', h('tr', h('th', ''), h('th.num', `A ${shortId(a.id)}`), h('th.num', `B ${shortId(b.id)}`), h('th.num', 'delta'), h('th.num', 'relative'))),
        h('tbody', rows.map((r) => h('tr', { dataset: { name: r.name } },
          h('td', r.name), h('td.num', fmt(r.a)), h('td.num', fmt(r.b)),
          h('td.num', { className: r.delta > 0 ? 'num up' : r.delta < 0 ? 'num down' : 'num' }, r.delta == null ? '–' : `${r.delta > 0 ? '+' : ''}${fmt(r.delta)}`),
          h('td.num', r.relative == null ? '–' : `${r.relative > 0 ? '+' : ''}${(r.relative * 100).toFixed(1)}%`))))),
      h('h3', 'Quality B − A (standard errors from the evaluate stage)'),
      deltaHolder,
      h('h3', 'A/B on the same camera'),
      abView(a, b, comparePreviews(a, b), (id, name) => loadBitmap(id, name)),
      h('h3', 'Previews (evaluate stage; error heatmaps 0 … 0.25)'),
      renderPreviews(a, b, compareToken),
      h('h3', 'Config differences'),
      cfg.length ? h('table.data#config-delta', h('tbody', cfg.map((d) => h('tr', h('td', h('code', d.path)), h('td', JSON.stringify(d.a)), h('td', JSON.stringify(d.b)))))) : h('p.muted', 'Same config.'));
  }

  function renderChartOptions() {
    const names = new Set();
    for (const b of bakes) for (const [k, v] of Object.entries(chartValues(b))) if (v != null) names.add(k);
    const cur = chartMetric.value || 'bake seconds';
    clear(chartMetric);
    for (const n of [...names].sort()) chartMetric.append(h('option', { value: n }, n));
    chartMetric.value = names.has(cur) ? cur : [...names][0] || '';
  }

  function renderChart() {
    if (plot) { plot.destroy(); plot = null; }
    clear(chartHolder);
    const name = chartMetric.value;
    const pts = bakes.filter((b) => b.created && chartValues(b)[name] != null).map((b) => [b.created, chartValues(b)[name]]);
    if (!name || pts.length === 0) { chartHolder.append(h('p.muted', 'Nothing to plot yet.')); return; }
    // uPlot wants increasing x: bakes created in the same second get nudged apart
    for (let i = 1; i < pts.length; i++) if (pts[i][0] <= pts[i - 1][0]) pts[i][0] = pts[i - 1][0] + 1e-3;
    const width = Math.max(320, chartHolder.clientWidth || 800);
    plot = new uPlot({
      width, height: 260,
      scales: { x: { time: true } },
      series: [{}, { label: name, stroke: '#d9642b', width: 2, points: { show: true, size: 7, fill: '#d9642b' } }],
      axes: [{}, { label: name }],
    }, [pts.map((p) => p[0]), pts.map((p) => p[1])], chartHolder);
    chartHolder.dataset.points = String(pts.length);
  }

  sceneSelect.addEventListener('change', () => { picked = []; load(); });
  metricSet.addEventListener('change', () => { renderTable(); renderSceneCharts(); });
  document.addEventListener('keydown', (e) => { if (e.key === 'Escape') zoom.hidden = true; });
  refreshBtn.addEventListener('click', load);
  chartMetric.addEventListener('change', renderChart);
  store.subscribe((s, prev) => { if (s.scenes !== prev.scenes) { renderScenes(); if (bakes.length) { renderTable(); renderSceneCharts(); } } });

  return {
    el,
    async show(params) {
      renderScenes();
      const q = params.query || new URLSearchParams();
      if (q.get('scene')) sceneSelect.value = q.get('scene');
      await load();
    },
  };
}
