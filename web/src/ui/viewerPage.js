/**
 * The viewer page: the canvas, the GI mode switch (each mode lights up only when the bake has its artifacts),
 * cameras, probes, exposure, the streaming progress bar, the frame-time readout, and debug images.
 */
import { Viewer } from '../view/viewer.js';
import { drawDepthAtlas, drawIrradianceAtlas, drawThetaSlice } from './debugImages.js';
import { clear, h, shortId } from './dom.js';

export function createViewerPage(app) {
  const { api, store } = app;
  const canvas = h('canvas#viewer-canvas', { tabindex: 0 });
  const note = h('p#viewer-note.note');
  const progress = h('progress#stream-progress', { max: 1, value: 0 });
  const progressLabel = h('span#stream-label.muted');
  const modeList = h('div#mode-list.modes');
  const modeError = h('p#mode-error.error');
  const prtNote = h('p#prt-note.muted', { hidden: true });
  const frameTime = h('span#frame-time', '–');
  const shaderError = h('pre#shader-error.error');
  const bakeSelect = h('select#viewer-bake');
  const header = h('div#viewer-header');
  const output = h('select#viewer-output', ['shaded', 'indirect', 'direct', 'albedo'].map((o) => h('option', { value: o }, o === 'shaded' ? 'shaded (direct + GI)' : `${o} only`)));
  const exposure = h('input#viewer-exposure', { type: 'range', min: -4, max: 4, step: 0.25, value: 0 });
  const exposureLabel = h('span.muted', 'EV 0');
  const shadowsBox = h('input#viewer-shadows', { type: 'checkbox', checked: true });
  const camOrbit = h('button.small#cam-orbit', { type: 'button', dataset: { cam: 'orbit' } }, 'Orbit');
  const camFly = h('button.small#cam-fly', { type: 'button', dataset: { cam: 'fly' } }, 'Fly (WASD QE, drag)');
  const camLink = h('button.small#cam-link', { type: 'button' }, 'Link to this view');
  const probesBox = h('input#show-probes', { type: 'checkbox' });
  const probeColor = h('select#probe-coloring', h('option', { value: 'state' }, 'by state (OFF red / ACTIVE green / SLEEPING blue)'), h('option', { value: 'sh' }, 'by own SH irradiance'));
  const debugSelect = h('select#debug-view', h('option', { value: '' }, '— none —'), h('option', { value: 'irradiance' }, 'irradiance atlas'), h('option', { value: 'depth' }, 'depth atlas (mean distance)'), h('option', { value: 'theta' }, 'θ slices (visibility)'));
  const debugCanvas = h('canvas#debug-image');
  const debugHolder = h('div.debug-overlay', { hidden: true }, debugCanvas);
  const debugControls = h('div#debug-controls');
  const debugNote = h('p#debug-note.muted');
  const gpuInfo = h('p#gpu-info.muted');

  const el = h('section.page#page-viewer',
    h('div.viewer-layout',
      h('div.viewer-main', canvas, h('div.overlay', h('span', 'frame ', frameTime)), debugHolder),
      h('aside.viewer-panel',
        header,
        h('label', 'Bake ', bakeSelect),
        note,
        h('div.progress-row', progress, progressLabel),
        h('h3', 'GI mode'), modeList, modeError, prtNote,
        h('h3', 'Display'),
        h('div.row', h('label', 'Output ', output)),
        h('div.row', h('label', 'Exposure ', exposure), exposureLabel),
        h('div.row', h('label', shadowsBox, ' shadowed direct light (shadow maps)')),
        h('h3', 'Camera'),
        h('div.row', camOrbit, camFly, camLink),
        h('h3', 'Probes'),
        h('div.row', h('label', probesBox, ' show probes'), probeColor),
        h('h3', 'Debug images'),
        h('div.row', debugSelect), debugControls, debugNote,
        shaderError, gpuInfo)));

  let viewer = null;
  let status = {};
  let openId = null;

  function renderModes() {
    clear(modeList);
    const modes = viewer ? viewer.modes() : [];
    for (const m of modes) {
      const active = status.mode === m.id;
      const shown = status.shownMode === m.id;
      const btn = h('button.mode', {
        type: 'button', disabled: !m.available, dataset: { mode: m.id, available: m.available ? '1' : '0' },
        title: m.available ? (m.tooltip || m.label) : `${m.reason}${m.missing.length ? `: ${m.missing.join(', ')}` : ''}`,
        on: { click: () => { setMode(m.id); } },
      }, m.label, m.available ? null : h('span.reason', ` ${m.reason}`));
      if (active) btn.classList.add('active');
      if (active && !shown) btn.classList.add('loading');
      modeList.append(btn);
    }
  }

  async function setMode(id) {
    try {
      await viewer.setMode(id);
      updateHash();
    } catch (e) {
      modeError.textContent = e.message;
    }
  }

  function onStatus(patch) {
    Object.assign(status, patch);
    if ('frameMs' in patch && patch.frameMs != null) frameTime.textContent = `${patch.frameMs.toFixed(2)} ms (${status.frameSource})`;
    if ('loading' in patch) {
      progress.value = patch.loading;
      progress.classList.toggle('done', patch.loading >= 1);
      progressLabel.textContent = patch.loading >= 1 ? 'volumes loaded' : `streaming ${patch.loadingLabel || ''} ${(patch.loading * 100).toFixed(0)}%`;
    }
    if ('note' in patch) note.textContent = patch.note || '';
    if ('exposureEV' in patch) { exposure.value = String(patch.exposureEV); exposureLabel.textContent = `EV ${patch.exposureEV}`; }
    if ('modeError' in patch) modeError.textContent = patch.modeError || '';
    if ('shaderError' in patch) shaderError.textContent = patch.shaderError || '';
    if ('rendererInfo' in patch) gpuInfo.textContent = `${patch.rendererInfo.renderer} · float linear filtering: ${patch.rendererInfo.floatLinear ? 'yes' : 'no (half floats)'} · frame time: ${patch.rendererInfo.timer}`;
    if ('modes' in patch || 'mode' in patch || 'shownMode' in patch) renderModes();
    if ('shownMode' in patch) canvas.dataset.readyMode = patch.shownMode;
    if ('prt' in patch || 'relightMs' in patch) {
      prtNote.hidden = !status.prt;
      const p = status.prtLight ? status.prtLight.map((x) => x.toFixed(2)).join(', ') : '';
      prtNote.textContent = `Relight light at (${p}) · coefficients in ${(status.relightMs ?? 0).toFixed(2)} ms · `
        + 'drag the gizmo to move it. Direct light at the measurement points is unshadowed in the browser '
        + '(the server relight traces shadow rays).';
      prtNote.title = prtNote.textContent;
    }
  }

  function ensureViewer() {
    if (viewer) return viewer;
    viewer = new Viewer({ canvas, api, onStatus, onError: (e) => { shaderError.textContent = e.message; } });
    app.viewer = viewer;
    return viewer;
  }

  function updateHash() {
    if (!viewer || !openId) return;
    const c = viewer.cameraState();
    const q = new URLSearchParams({ mode: viewer.mode, cam: [...c.position, ...c.target].map((x) => x.toFixed(3)).join(',') });
    history.replaceState(null, '', `#/viewer/${openId}?${q}`);
  }

  async function renderBakeSelect(current) {
    try {
      const { items } = await api.listBakes({ status: 'succeeded', limit: 100 });
      clear(bakeSelect);
      bakeSelect.append(h('option', { value: '' }, '— pick a succeeded bake —'));
      for (const b of items) bakeSelect.append(h('option', { value: b.id }, `${shortId(b.id)} · scene ${shortId(b.scene_id)} · ${new Date(b.created * 1000).toLocaleString()}`));
      bakeSelect.value = current || '';
    } catch { /* the header shows errors elsewhere */ }
  }
  bakeSelect.addEventListener('change', () => { if (bakeSelect.value) location.hash = `#/viewer/${bakeSelect.value}`; });

  output.addEventListener('change', () => viewer && viewer.set({ output: output.value }));
  exposure.addEventListener('input', () => { exposureLabel.textContent = `EV ${exposure.value}`; if (viewer) { viewer.userExposure = true; viewer.set({ exposure: 2 ** Number(exposure.value) }); } });
  camOrbit.addEventListener('click', () => { viewer.setCameraMode('orbit'); camOrbit.classList.add('active'); camFly.classList.remove('active'); });
  camFly.addEventListener('click', () => { viewer.setCameraMode('fly'); camFly.classList.add('active'); camOrbit.classList.remove('active'); canvas.focus(); });
  camLink.addEventListener('click', async () => {
    updateHash();
    try { await navigator.clipboard.writeText(location.href); camLink.textContent = 'Link copied'; } catch { camLink.textContent = 'Link in the address bar'; }
    setTimeout(() => { camLink.textContent = 'Link to this view'; }, 1500);
  });
  shadowsBox.addEventListener('change', () => viewer.set({ shadows: shadowsBox.checked }));
  probesBox.addEventListener('change', () => viewer.setProbes({ visible: probesBox.checked }));
  probeColor.addEventListener('change', () => viewer.setProbes({ coloring: probeColor.value }));

  async function showDebug() {
    const which = debugSelect.value;
    clear(debugControls);
    debugNote.textContent = '';
    debugCanvas.hidden = !which;
    debugHolder.hidden = !which;
    if (!which || !viewer?.bake) return;
    const need = { irradiance: ['irradiance'], depth: ['depth_moments'], theta: ['theta_0123', 'theta_4567', 'dont_care'] }[which];
    const missing = need.filter((n) => !viewer.artifactInfo(n) && n !== 'dont_care');
    if (missing.length) { debugNote.textContent = `not baked: ${missing.join(', ')}`; debugCanvas.hidden = true; debugHolder.hidden = true; return; }
    debugNote.textContent = 'loading…';
    const got = await viewer.fetch(need.filter((n) => viewer.artifactInfo(n)));
    debugNote.textContent = '';
    debugCanvas.dataset.view = which;
    debugCanvas.style.aspectRatio = '';
    if (which === 'irradiance') {
      drawIrradianceAtlas(debugCanvas, got.irradiance);
      debugNote.textContent = `${got.irradiance.width}×${got.irradiance.height} RGBA32F: one ${got.irradiance.height / viewer.bake.stages.find((s) => s.name === 'place').stats.counts[1]}-texel tile per probe (row j, column k·nx + i); scaled to the 99th percentile`;
    } else if (which === 'depth') {
      drawDepthAtlas(debugCanvas, got.depth_moments);
      debugNote.textContent = `${got.depth_moments.width}×${got.depth_moments.height} RG32F: mean ray distance per octahedral texel (black near, white far)`;
    } else {
      const vols = { theta0123: got.theta_0123, theta4567: got.theta_4567, dontCare: got.dont_care || null };
      const axis = h('select#theta-axis', ['z', 'y', 'x'].map((a) => h('option', { value: a }, `${a} slice`)));
      const corner = h('select#theta-corner', [...Array(8).keys()].map((c) => h('option', { value: c }, `corner ${c} (${c & 1},${(c >> 1) & 1},${(c >> 2) & 1})`)));
      const slice = h('input#theta-slice', { type: 'range', min: 0, value: 0 });
      const label = h('span.muted');
      const draw = () => {
        const n = { z: vols.theta0123.depth, y: vols.theta0123.height, x: vols.theta0123.width }[axis.value];
        slice.max = String(n - 1);
        const i = Math.min(n - 1, Number(slice.value));
        drawThetaSlice(debugCanvas, vols, Number(corner.value), axis.value, i);
        // show the slice in world proportions (cells are rarely cubes)
        const sp = viewer.renderer.grid?.spacing || [1, 1, 1];
        const [a, b] = { z: [0, 1], y: [0, 2], x: [2, 1] }[axis.value];
        debugCanvas.style.aspectRatio = String((debugCanvas.width * sp[a]) / (debugCanvas.height * sp[b]));
        label.textContent = `${axis.value} = ${i} / ${n - 1} · θ white = visible, black = occluded, red = inside geometry`;
      };
      slice.value = String(Math.floor(vols.theta0123.depth / 2));
      [axis, corner].forEach((e) => e.addEventListener('change', draw));
      slice.addEventListener('input', draw);
      debugControls.append(h('div.row', axis, corner), h('div.row', slice, label));
      draw();
    }
  }
  debugSelect.addEventListener('change', () => showDebug().catch((e) => { debugNote.textContent = e.message; }));

  return {
    el,
    async show(params) {
      const v = ensureViewer();
      requestAnimationFrame(() => v.resize());
      const id = params.id || null;
      const q = params.query || new URLSearchParams();
      if (id === openId && id) return;
      openId = id;
      status = {};
      shaderError.textContent = '';
      debugSelect.value = '';
      debugCanvas.hidden = true;
      debugHolder.hidden = true;
      clear(debugControls);
      renderBakeSelect(id);
      let bake = null;
      clear(header);
      if (id) {
        try {
          bake = await api.getBake(id);
          app.mergeBake(bake);
        } catch (e) {
          header.append(h('p.error', `Could not open bake ${shortId(id)}: ${e.message}`));
        }
      }
      if (bake) {
        header.append(h('h2', 'Bake ', h('code', shortId(bake.id))), h('p.muted', `scene ${shortId(bake.scene_id)} · ${bake.status}`));
        if (bake.status !== 'succeeded') header.append(h('p.note', `This bake is ${bake.status}: only the artifacts of finished stages can be shown.`));
      } else if (!id) {
        header.append(h('p.muted', 'Pick a bake to view (or upload and bake a scene first).'));
      }
      const cam = (q.get('cam') || '').split(',').map(Number);
      const camera = cam.length === 6 && cam.every(Number.isFinite) ? { position: cam.slice(0, 3), target: cam.slice(3) } : undefined;
      probesBox.checked = !(bake && app.sessionFiles.has(bake.scene_id));
      progress.value = 0;
      progressLabel.textContent = '';
      await v.open({ bake, sceneFile: bake ? app.sessionFiles.get(bake.scene_id) || null : null, camera, mode: q.get('mode') || undefined });
      if (probesBox.checked !== v.state.probes) v.setProbes({ visible: probesBox.checked });
      renderModes();
    },
  };
}
