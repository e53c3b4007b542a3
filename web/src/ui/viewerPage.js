/**
 * The viewer page: the canvas, the GI mode switch (each mode lights up only when the bake has its artifacts),
 * cameras, probes, exposure, the streaming progress bar, the frame-time readout, and debug images.
 * Lights are drawn in every mode; "Place a light" adds or moves a light of the bake form by clicking a surface
 * (0.3 m in front of it) and dragging the gizmo.
 *
 * Review cameras (view/reviewCameras.js): the first view is the scene's first review camera (GET
 * /v1/scenes/{id}/cameras, then the bake's own evaluate cameras; none: autocamera.js), a button per camera jumps
 * to it, and "Save this view as a review camera" appends the current view with PUT /v1/scenes/{id}/cameras.
 */
import { Viewer } from '../view/viewer.js';
import { drawDepthAtlas, drawIrradianceAtlas, drawMaskSlice, drawThetaSlice } from './debugImages.js';
import { clear, h, shortId } from './dom.js';
import { bakeWarnings, gridSummary, sceneLabel } from '../state/stats.js';
import { defaultLight } from '../state/lighting.js';
import { warningList } from './warnings.js';
import { appendCameraBody, bakeReviewCameras, mergeReviewCameras } from '../view/reviewCameras.js';

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
  const camList = h('div#cam-list.row.cam-list', { title: 'the scene\'s review cameras: the views its evaluated bakes are scored from' });
  const camSave = h('button.small#cam-save', { type: 'button', title: 'add this view (position, target, field of view) to the scene\'s review cameras (PUT /v1/scenes/{id}/cameras): later evaluated bakes of the scene are scored from it too' }, 'Save this view as a review camera');
  const camNote = h('p#cam-note.muted');
  const probesBox = h('input#show-probes', { type: 'checkbox' });
  const gridNote = h('p.muted#grid-note');
  const probeColor = h('select#probe-coloring', h('option', { value: 'state' }, 'by state (OFF red / ACTIVE green / SLEEPING blue)'), h('option', { value: 'sh' }, 'by own SH irradiance'),
    h('option', { value: 'cluster' }, 'by MD cluster (8 colours; OFF dark)'));
  const debugSelect = h('select#debug-view', h('option', { value: '' }, '— none —'), h('option', { value: 'irradiance' }, 'irradiance atlas'), h('option', { value: 'depth' }, 'depth atlas (mean distance)'), h('option', { value: 'theta' }, 'θ slices (visibility)'),
    h('option', { value: 'clusters' }, 'clusters (probe spheres by MD cluster)'), h('option', { value: 'masks' }, 'mask channels (dense masks slice)'));
  const debugCanvas = h('canvas#debug-image');
  const debugHolder = h('div.debug-overlay', { hidden: true }, debugCanvas);
  const debugControls = h('div#debug-controls');
  const debugNote = h('p#debug-note.muted');
  const gpuInfo = h('p#gpu-info.muted');
  const warningsBanner = h('div#viewer-warnings.warnings-banner', { role: 'alert', hidden: true });
  const lightsBox = h('input#show-lights', { type: 'checkbox', checked: true });
  const placeBtn = h('button.small#place-light', { type: 'button', title: 'click a surface of the scene: a point light of the bake form goes 0.3 m in front of it' }, 'Place a light…');
  const placeDone = h('button.small#place-done', { type: 'button', hidden: true }, 'Done placing');
  const placeNote = h('p#place-note.muted');
  const lightNote = h('p#light-note.note', { hidden: true });

  const el = h('section.page#page-viewer',
    warningsBanner,
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
        h('div.row', h('span.muted', 'Review cameras')), camList,
        h('div.row', camSave), camNote,
        h('h3', 'Lights'),
        h('div.row', h('label', lightsBox, ' show lights'), placeBtn, placeDone),
        placeNote, lightNote,
        h('h3', 'Probes'),
        h('div.row', h('label', probesBox, ' show probes'), probeColor),
        gridNote,
        h('h3', 'Debug images'),
        h('div.row', debugSelect), debugControls, debugNote,
        shaderError, gpuInfo)));

  let viewer = null;
  let status = {};
  let openId = null;

  // ------------------------------------------------------------------ review cameras: a list to jump between, save
  let review = { sceneId: null, bakeCams: [], cams: [] };

  async function fetchReviewDoc(sceneId) {
    return api.request(`/v1/scenes/${encodeURIComponent(sceneId)}/cameras`);
  }

  /** The scene's review cameras and this bake's (the scene's first); none when the scene is unknown. */
  async function loadReviewCameras(sceneId, bake) {
    const bakeCams = bakeReviewCameras(bake);
    let doc = null;
    if (sceneId) { try { doc = await fetchReviewDoc(sceneId); } catch { /* the bake's own, if any */ } }
    review = { sceneId, bakeCams, cams: mergeReviewCameras(doc, bakeCams), source: doc?.source || null };
    return review.cams;
  }

  function markCamera(key) {
    canvas.dataset.camera = key == null ? '' : String(key);
    camList.querySelectorAll('button').forEach((b) => b.classList.toggle('active', b.dataset.cam === String(key)));
  }

  function renderCamList(active = null) {
    clear(camList);
    const fmt = (v) => v.map((x) => x.toFixed(2)).join(', ');
    review.cams.forEach((c, i) => {
      camList.append(h('button.small.cam', {
        type: 'button', dataset: { cam: String(i), name: c.name, source: c.source },
        title: `${c.name} (${c.source}): from (${fmt(c.position)}) towards (${fmt(c.target)})${c.fov_y ? `, ${c.fov_y.toFixed(0)}° vertical` : ''}`,
        on: { click: () => jumpTo(i) },
      }, `${i + 1}. ${c.name}`));
    });
    camList.append(h('button.small.cam', { type: 'button', dataset: { cam: 'auto' }, title: 'the viewer\'s own first view: inside a room for closed scenes, outside for open ones', on: { click: () => jumpTo('auto') } }, 'automatic view'));
    camSave.disabled = !review.sceneId;
    markCamera(active);
  }

  function jumpTo(key) {
    if (!viewer) return;
    const cam = key === 'auto' ? viewer.autoView() : review.cams[key];
    if (!cam) return;
    viewer.setView(cam);
    markCamera(key);
    updateHash();
  }

  camSave.addEventListener('click', async () => {
    if (!viewer || !review.sceneId) { camNote.textContent = 'Open a bake or a scene first.'; return; }
    camSave.disabled = true;
    try {
      const view = viewer.viewState();
      const body = appendCameraBody(await fetchReviewDoc(review.sceneId), view);
      const doc = await api.request(`/v1/scenes/${encodeURIComponent(review.sceneId)}/cameras`, { method: 'PUT', json: body });
      review.cams = mergeReviewCameras(doc, review.bakeCams);
      review.source = doc.source;
      const saved = body.cameras[body.cameras.length - 1].name;
      const i = review.cams.findIndex((c) => c.name === saved);
      renderCamList(i >= 0 ? i : null);
      camNote.className = 'muted ok';
      camNote.textContent = `Saved as review camera ${i + 1} (“${saved}”) of the scene: later evaluated bakes of this scene are scored from its ${doc.cameras.length} review cameras.`;
    } catch (e) {
      camNote.className = 'error';
      camNote.textContent = `Not saved: ${e.message}`;
    } finally {
      camSave.disabled = !review.sceneId;
    }
  });

  /** The banner above the canvas listing the opened bake's warnings (hidden when it has none). */
  function renderWarnings(bake) {
    const warnings = bakeWarnings(bake);
    clear(warningsBanner);
    warningsBanner.hidden = !warnings.length;
    warningsBanner.dataset.warnings = String(warnings.length);
    if (!warnings.length) return;
    warningsBanner.append(
      h('strong', `⚠ This bake has ${warnings.length} warning${warnings.length === 1 ? '' : 's'}: it is probably not what you wanted.`),
      warningList(warnings));
  }

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
    if ('lightNote' in patch) { lightNote.textContent = patch.lightNote || ''; lightNote.hidden = !patch.lightNote; }
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
      for (const b of items) bakeSelect.append(h('option', { value: b.id }, `${sceneLabel(store.get().scenes, b.scene_id)} · ${shortId(b.id)} · ${new Date(b.created * 1000).toLocaleString()}`));
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

  // ------------------------------------------------------------------ lights: show, place by clicking, drag
  let placing = null;  // {index: number|null}: placing the bake form's light `index` (null: a new one)
  const formLights = () => (app.configForm ? app.configForm.values().scene.lights || [] : []);
  const fmtP = (p) => p.map((x) => (x !== 0 && Math.abs(x) < 0.1 ? x.toPrecision(2) : x.toFixed(2))).join(', ');
  lightsBox.addEventListener('change', () => viewer && viewer.showLightMarkers(lightsBox.checked));

  function onGizmoMove(index, p) {
    app.configForm.setLightPosition(index, p);
    viewer.editLights(formLights(), index, onGizmoMove);
    placeNote.textContent = `Light ${index + 1} at (${fmtP(p)}) m. Start the bake on “Upload & bake”.`;
  }

  function startPlacing(index = null) {
    if (!viewer) return;
    if (!app.configForm) { placeNote.textContent = 'The bake form is not loaded yet.'; return; }
    if (!viewer.root) { placeNote.textContent = 'No scene geometry is loaded to click on.'; return; }
    placing = { index };
    canvas.dataset.placing = '1';
    placeDone.hidden = false;
    lightsBox.checked = true;
    viewer.showLightMarkers(true);
    viewer.editLights(formLights(), index, onGizmoMove);
    placeNote.textContent = index == null
      ? 'Click a surface: a point light goes 0.3 m in front of it, or 15% of your distance to it when nearer (then drag the gizmo to adjust).'
      : `Click a surface to move light ${index + 1} there (0.3 m in front of it, or 15% of your distance to it when nearer), or drag the gizmo.`;
  }

  function stopPlacing() {
    placing = null;
    delete canvas.dataset.placing;
    placeDone.hidden = true;
    if (viewer) viewer.editLights(null);
  }
  placeBtn.addEventListener('click', () => startPlacing(null));
  placeDone.addEventListener('click', () => { stopPlacing(); placeNote.textContent = ''; });

  let down = null;
  canvas.addEventListener('pointerdown', (e) => { down = { x: e.clientX, y: e.clientY, gizmo: !!viewer?.editGizmo?.axis }; });
  canvas.addEventListener('pointerup', (e) => {
    const d = down;
    down = null;
    if (!placing || !d || d.gizmo || viewer.gizmoDragging || Math.hypot(e.clientX - d.x, e.clientY - d.y) > 4) return;  // a drag, not a click
    const hit = viewer.pick(e.clientX, e.clientY);
    if (!hit) { placeNote.textContent = 'Nothing there: click a surface of the scene.'; return; }
    let index = placing.index;
    if (index == null) {
      index = app.configForm.addLight({ ...defaultLight('point'), position: hit.position.map((x) => Math.round(x * 1e6) / 1e6) });
      placing.index = index;
    } else {
      app.configForm.setLightPosition(index, hit.position);
    }
    viewer.lastPick = hit;
    viewer.editLights(formLights(), index, onGizmoMove);
    placeNote.textContent = `Light ${index + 1} placed at (${fmtP(hit.position)}) m, ${Number(hit.offset.toPrecision(2))} m off the surface. Drag the gizmo to adjust, `
      + 'click again to move it, or “Done placing”. Start the bake on “Upload & bake”.';
  });

  /**
   * A slice view of RGBA8 (Z, Y, X, 4) volumes: axis, a selector (θ corner / mask channel) and a slider;
   * `paint(axis, selector, index)` draws on the debug canvas; `legend` labels it.
   */
  function sliceControls(vol, { id, options, paint, legend }) {
    const axis = h(`select#${id}-axis`, ['z', 'y', 'x'].map((a) => h('option', { value: a }, `${a} slice`)));
    const pick = h(`select#${id}-${id === 'theta' ? 'corner' : 'channel'}`, options.map(([v, text]) => h('option', { value: v }, text)));
    const slice = h(`input#${id}-slice`, { type: 'range', min: 0, value: 0 });
    const label = h('span.muted');
    const draw = () => {
      const n = { z: vol.depth, y: vol.height, x: vol.width }[axis.value];
      slice.max = String(n - 1);
      const i = Math.min(n - 1, Number(slice.value));
      paint(axis.value, pick.value, i);
      // show the slice in world proportions (cells are rarely cubes)
      const sp = viewer.renderer.grid?.spacing || [1, 1, 1];
      const [a, b] = { z: [0, 1], y: [0, 2], x: [2, 1] }[axis.value];
      debugCanvas.style.aspectRatio = String((debugCanvas.width * sp[a]) / (debugCanvas.height * sp[b]));
      label.textContent = `${axis.value} = ${i} / ${n - 1} · ${legend(pick.value)}`;
    };
    slice.value = String(Math.floor(vol.depth / 2));
    [axis, pick].forEach((e) => e.addEventListener('change', draw));
    slice.addEventListener('input', draw);
    debugControls.append(h('div.row', axis, pick), h('div.row', slice, label));
    draw();
  }

  /** Debug views and the cluster colouring are offered only when the bake has their artifacts. */
  const DEBUG_NEEDS = { irradiance: 'irradiance', depth: 'depth_moments', theta: 'theta_0123', clusters: 'clusters', masks: 'masks_0123' };
  function updateDebugOptions() {
    const has = (n) => !!viewer?.artifactInfo(n);
    for (const opt of debugSelect.options) {
      const need = DEBUG_NEEDS[opt.value];
      opt.disabled = !!need && !has(need);
      opt.title = opt.disabled ? `not baked: ${need}` : '';
    }
    const clusterOpt = [...probeColor.options].find((o) => o.value === 'cluster');
    clusterOpt.disabled = !has('clusters');
    clusterOpt.title = clusterOpt.disabled ? 'not baked: clusters' : '';
  }

  let coloringBeforeClusters = null;  // the probe colouring to restore when the clusters view is left

  async function showDebug() {
    const which = debugSelect.value;
    clear(debugControls);
    debugNote.textContent = '';
    if (coloringBeforeClusters && which !== 'clusters' && viewer) {
      const prev = coloringBeforeClusters;
      coloringBeforeClusters = null;
      probeColor.value = prev.coloring;
      probesBox.checked = prev.visible;
      viewer.setProbes({ coloring: prev.coloring, visible: prev.visible });
    }
    const image = !!which && which !== 'clusters';  // the clusters view is drawn in 3D, on the probe spheres
    debugCanvas.hidden = !image;
    debugHolder.hidden = !image;
    if (!which || !viewer?.bake) return;
    const need = {
      irradiance: ['irradiance'], depth: ['depth_moments'], theta: ['theta_0123', 'theta_4567', 'dont_care'],
      clusters: ['clusters'], masks: ['masks_0123', 'masks_4567'],
    }[which];
    const optional = new Set(['dont_care', 'masks_4567']);
    const missing = need.filter((n) => !viewer.artifactInfo(n) && !optional.has(n));
    if (missing.length) { debugNote.textContent = `not baked: ${missing.join(', ')}`; debugCanvas.hidden = true; debugHolder.hidden = true; return; }
    debugNote.textContent = 'loading…';
    const got = await viewer.fetch(need.filter((n) => viewer.artifactInfo(n)));
    debugNote.textContent = '';
    debugCanvas.dataset.view = which;
    debugCanvas.style.aspectRatio = '';
    if (which === 'irradiance') {
      drawIrradianceAtlas(debugCanvas, got.irradiance);
      debugNote.textContent = `${got.irradiance.width}×${got.irradiance.height} ${got.irradiance.format}: one ${got.irradiance.height / viewer.bake.stages.find((s) => s.name === 'place').stats.counts[1]}-texel tile per probe (row j, column k·nx + i); scaled to the 99th percentile`;
    } else if (which === 'depth') {
      drawDepthAtlas(debugCanvas, got.depth_moments);
      debugNote.textContent = `${got.depth_moments.width}×${got.depth_moments.height} ${got.depth_moments.format}: mean ray distance per octahedral texel (black near, white far)`;
    } else if (which === 'theta') {
      const vols = { theta0123: got.theta_0123, theta4567: got.theta_4567, dontCare: got.dont_care || null };
      sliceControls(vols.theta0123, {
        id: 'theta',
        options: [...Array(8).keys()].map((c) => [c, `corner ${c} (${c & 1},${(c >> 1) & 1},${(c >> 2) & 1})`]),
        paint: (axis, corner, i) => drawThetaSlice(debugCanvas, vols, Number(corner), axis, i),
        legend: () => 'θ white = visible, black = occluded, red = inside geometry',
      });
    } else if (which === 'masks') {
      const vols = { masks0123: got.masks_0123, masks4567: got.masks_4567 || null };
      const K = Number(viewer.artifactInfo('clusters')?.meta?.clusters) || (vols.masks4567 ? 8 : 4);
      const channels = [...Array(vols.masks4567 ? Math.min(8, K) : Math.min(4, K)).keys()];
      sliceControls(vols.masks0123, {
        id: 'mask',
        options: [['rgb', 'RGB = m0, m1, m2'], ...channels.map((k) => [k, `channel ${k} (m${k})`])],
        paint: (axis, ch, i) => drawMaskSlice(debugCanvas, vols, ch, axis, i),
        legend: (ch) => (ch === 'rgb' ? 'red m0, green m1, blue m2 (white: 255 = unread / don\'t care)' : `m${ch}: black 0, white 1`),
      });
      debugNote.textContent = `${vols.masks0123.width}×${vols.masks0123.height}×${vols.masks0123.depth} RGBA8 refined grid, K = ${K}`;
    } else {
      // clusters: the probe spheres coloured by their cluster, in the 3D view
      if (!coloringBeforeClusters) coloringBeforeClusters = { coloring: probeColor.value, visible: probesBox.checked };
      probeColor.value = 'cluster';
      probesBox.checked = true;
      viewer.setProbes({ coloring: 'cluster', visible: true });
      const K = viewer.artifactInfo('clusters')?.meta?.clusters;
      debugNote.textContent = `probe spheres coloured by cluster${K ? ` (K = ${K})` : ''}: 0 red, 1 green, 2 blue, 3 yellow, 4 orange, 5 purple, 6 cyan, 7 magenta; OFF probes dark`;
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
      if (coloringBeforeClusters) {
        probeColor.value = coloringBeforeClusters.coloring;
        v.setProbes({ coloring: coloringBeforeClusters.coloring });
        coloringBeforeClusters = null;
      }
      debugCanvas.hidden = true;
      debugHolder.hidden = true;
      clear(debugControls);
      renderBakeSelect(id);
      stopPlacing();
      placeNote.textContent = '';
      let bake = null;
      clear(header);
      renderWarnings(null);
      // #/viewer?scene=<id>&place=<light index|new>: a scene not baked yet (the file of this session, else the
      // geometry of its latest bake), to place the bake form's lights on
      const sceneParam = id ? null : q.get('scene');
      const place = q.get('place');
      if (id) {
        try {
          bake = await api.getBake(id);
          app.mergeBake(bake);
        } catch (e) {
          header.append(h('p.error', `Could not open bake ${shortId(id)}: ${e.message}`));
        }
      } else if (sceneParam && !app.sessionFiles.has(sceneParam)) {
        try {
          const { items } = await api.listBakes({ sceneId: sceneParam, status: 'succeeded', limit: 1 });
          if (items[0]) bake = await api.getBake(items[0].id);
        } catch { /* no geometry then: said below */ }
      }
      const sceneName = (sid) => sceneLabel(store.get().scenes, sid);
      if (bake) {
        renderWarnings(bake);
        header.append(h('h2', 'Bake ', h('code', shortId(bake.id))),
          h('p.muted', { title: `scene ${bake.scene_id}` }, h('span.scene-name', sceneName(bake.scene_id)), ` · ${bake.status}`));
        if (bake.status !== 'succeeded') header.append(h('p.note', `This bake is ${bake.status}: only the artifacts of finished stages can be shown.`));
      } else if (sceneParam) {
        header.append(h('h2', 'Scene ', h('span.scene-name', sceneName(sceneParam))),
          h('p.muted', app.sessionFiles.has(sceneParam) ? 'Not baked yet: place lights, then start the bake on “Upload & bake”.'
            : 'This scene has no succeeded bake and its file is not in this browser session: upload it again to place lights on it.'));
      } else if (!id) {
        header.append(h('p.muted', 'Pick a bake to view (or upload and bake a scene first).'));
      }
      const cam = (q.get('cam') || '').split(',').map(Number);
      const linked = cam.length === 6 && cam.every(Number.isFinite) ? { position: cam.slice(0, 3), target: cam.slice(3) } : undefined;
      progress.value = 0;
      progressLabel.textContent = '';
      const sceneId = bake ? bake.scene_id : sceneParam;
      // the first view: a linked one, else the scene's first review camera, else the automatic one
      camNote.className = 'muted';
      camNote.textContent = '';
      const reviews = await loadReviewCameras(sceneId, bake);
      if (openId !== id) return;  // another bake was opened meanwhile
      const camera = linked || reviews[0];
      renderCamList(linked ? null : reviews.length ? 0 : 'auto');
      await v.open({ bake, sceneFile: sceneId ? app.sessionFiles.get(sceneId) || null : null, camera, mode: q.get('mode') || undefined });
      gridNote.textContent = gridSummary(bake);
      probesBox.checked = !v.root;  // probes alone over an empty scene; over the geometry on demand
      if (probesBox.checked !== v.state.probes) v.setProbes({ visible: probesBox.checked });
      v.showLightMarkers(lightsBox.checked);
      renderModes();
      updateDebugOptions();
      if (place !== null) startPlacing(place === '' || place === 'new' ? null : Number(place));
    },
  };
}
