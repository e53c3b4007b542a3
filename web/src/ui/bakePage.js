/**
 * "Upload and bake": drop or pick a .glb/.gltf/.zip, or a .gltf with its .bin and textures (packed into one zip
 * here: loader/pack.js) (the API's refusal shown in words), pick a scene,
 * fill the config form generated from the JSON Schema, start a bake, follow it stage by stage over SSE,
 * cancel it, open it in the viewer. Before the bake starts the page warns about what would make it wrong
 * (a light outside the scene, nothing lighting the scene: state/lighting.js) and asks to confirm. A preset
 * (Preview / Medium / Production, in the form: ui/configForm.js) fills the form; the estimate follows every change.
 */
import { createConfigForm } from './configForm.js';
import { packUpload } from '../loader/pack.js';
import { clear, h, shortId } from './dom.js';
import { preBakeWarnings } from '../state/lighting.js';
import { bakeWarnings, formatBytes, formatSeconds, sceneLabel } from '../state/stats.js';
import { warningBadge, warningList } from './warnings.js';

const ACTIVE = new Set(['queued', 'running']);

export function createBakePage(app) {
  const { api, store } = app;
  const fileInput = h('input#scene-file', { type: 'file', accept: '.glb,.gltf,.zip,.bin,.png,.jpg,.jpeg,.webp,.ktx2', multiple: true });
  const uploadStatus = h('p#upload-status.status', { role: 'status' });
  const drop = h('div#drop.drop', h('p', 'Drop a ', h('code', '.glb'), ', a ', h('code', '.gltf'), ' with its ', h('code', '.bin'), ' and textures, or a ', h('code', '.zip'), ' here, or ', h('label.button', fileInput, 'choose files')));
  const sceneSelect = h('select#scene-select');
  const sceneInfo = h('p#scene-info.muted');
  const formHolder = h('div#config-form', h('p.muted', 'Loading the config schema…'));
  const startBtn = h('button#start-bake.primary', { type: 'button' }, 'Start bake');
  const bakeStatus = h('p#bake-status.status', { role: 'status' });
  const preWarnings = h('div#prebake-warnings.warnings-banner', { role: 'alert', hidden: true });
  const estimate = h('p#bake-estimate.muted', { title: 'the server\'s estimate (POST /v1/bakes?dry_run=true); nothing is started' });
  const placeBtn = h('button.small#place-in-viewer', { type: 'button', title: 'open the scene in the 3D view and click a surface to place a point light' }, 'Place a light in the 3D view…');
  const progressList = h('div#bake-progress');
  let form = null;

  const el = h('section.page#page-bake',
    h('h2', 'Upload a scene'), drop, uploadStatus,
    h('h2', 'Bake'),
    h('div.row', h('label', 'Scene ', sceneSelect), sceneInfo, placeBtn),
    formHolder,
    preWarnings,
    estimate,
    h('div.row', startBtn, bakeStatus),
    h('h2', 'Bakes in progress and recent'),
    progressList);

  async function upload(files) {
    uploadStatus.className = 'status';
    let file;
    try {
      file = await packUpload(files);          // a .gltf with its files: one zip (loader/pack.js)
    } catch (e) {
      uploadStatus.className = 'status error';
      uploadStatus.textContent = `Upload refused: ${e.message}`;
      return;
    }
    if (!file) return;
    uploadStatus.textContent = `Uploading ${file.name} (${(file.size / 1024).toFixed(0)} KiB)…`;
    try {
      const s = await api.uploadScene(file);
      app.sessionFiles.set(s.id, file);
      uploadStatus.className = 'status ok';
      uploadStatus.textContent = `${s.filename || file.name} ready: ${s.triangles} triangles, ${s.lights} light${s.lights === 1 ? '' : 's'}, ${s.materials} material${s.materials === 1 ? '' : 's'} (scene ${shortId(s.id)})` +
        (s.warnings && s.warnings.length ? ` (warnings: ${s.warnings.join('; ')})` : '');
      await app.refreshScenes();
      store.set({ currentSceneId: s.id });
    } catch (e) {
      uploadStatus.className = 'status error';
      uploadStatus.textContent = `Upload refused: ${e.message}${e.code ? ` (${e.code})` : ''}`;
    }
  }
  fileInput.addEventListener('change', () => { const fs = Array.from(fileInput.files); if (fs.length) upload(fs); fileInput.value = ''; });
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    const fs = Array.from(e.dataTransfer.files);
    if (fs.length) upload(fs);
  });

  sceneSelect.addEventListener('change', () => store.set({ currentSceneId: sceneSelect.value || null }));

  const currentScene = () => store.get().scenes.find((x) => x.id === store.get().currentSceneId) || null;
  let confirmed = null;  // the config JSON whose warnings the user accepted with "Bake anyway"

  /** The warnings of the form's config for the picked scene, shown above "Start bake" (before any bake). */
  function renderPreWarnings() {
    const list = form ? preBakeWarnings(form.values(), currentScene()) : [];
    clear(preWarnings);
    preWarnings.hidden = !list.length;
    preWarnings.dataset.warnings = String(list.length);
    if (!list.length) return list;
    preWarnings.append(h('strong', `⚠ Before you bake: ${list.length} thing${list.length === 1 ? '' : 's'} will probably make this bake wrong`),
      h('ul.bake-warnings', list.map((w) => h('li', { dataset: { code: w.code } }, h('code.warn-code', w.code), ' ', w.message))));
    return list;
  }

  let estimateTimer = null;
  let estimateSeq = 0;
  /** The estimate of the form's bake (debounced): probes, time, peak memory, artifact size. */
  function updateEstimate() {
    clearTimeout(estimateTimer);
    estimateTimer = setTimeout(async () => {
      const sceneId = store.get().currentSceneId;
      const seq = ++estimateSeq;
      if (!sceneId || !form) { estimate.textContent = ''; return; }
      try {
        const r = await api.estimateBake(sceneId, form.config());
        if (seq !== estimateSeq) return;
        const e = r.estimate || {};
        // the numbers as the server gave them (for scripts and the browser tests), the words below for people
        Object.assign(estimate.dataset, {
          probes: String(e.probes ?? ''), seconds: String(e.seconds ?? ''), peakMemoryBytes: String(e.peak_memory_bytes ?? ''),
          artifactBytes: String(e.artifact_bytes ?? ''), bundleBytes: String(e.bundle_bytes ?? ''),
          preset: form.preset() || 'custom',
        });
        estimate.textContent = `Estimate: ${e.probes_exact === false ? 'at most ' : ''}${e.probes ?? '?'} probes · about ${formatSeconds(e.seconds)}`
          + ` · peak memory ${formatBytes(e.peak_memory_bytes)} · artifact size ${formatBytes(e.artifact_bytes)}`
          + ` (bundle download ${formatBytes(e.bundle_bytes)})`
          + `${r.over_budget && r.over_budget.length ? ' · over the server\'s budget: the bake would be refused' : ''}`;
        estimate.classList.toggle('error', !!(r.over_budget && r.over_budget.length));
      } catch (err) {
        if (seq === estimateSeq) estimate.textContent = err.status === 422 ? '' : `No estimate: ${err.message}`;
      }
    }, 300);
  }

  startBtn.addEventListener('click', async () => {
    const sceneId = store.get().currentSceneId;
    bakeStatus.className = 'status';
    if (!sceneId) { bakeStatus.className = 'status error'; bakeStatus.textContent = 'Upload or pick a scene first.'; return; }
    if (!form) return;
    form.clearErrors();
    const warned = renderPreWarnings();
    const key = JSON.stringify([sceneId, form.config()]);
    if (warned.length && confirmed !== key) {
      confirmed = key;  // a second click on "Bake anyway" starts it
      startBtn.textContent = 'Bake anyway';
      bakeStatus.className = 'status error';
      bakeStatus.textContent = `Not started: ${warned.map((w) => w.code).join(', ')} (see above). Fix the settings, or click “Bake anyway”.`;
      preWarnings.scrollIntoView({ block: 'nearest' });
      return;
    }
    startBtn.textContent = 'Start bake';
    startBtn.disabled = true;
    try {
      const b = await api.createBake(sceneId, form.config());
      bakeStatus.className = 'status ok';
      bakeStatus.textContent = `Bake ${shortId(b.id)} ${b.status}`;
      app.followBake(b.id);
    } catch (e) {
      bakeStatus.className = 'status error';
      bakeStatus.textContent = `Bake refused: ${e.message}`;
      if (e.status === 422) form.setErrors(e.message);
    } finally {
      startBtn.disabled = false;
    }
  });

  function renderScenes() {
    const { scenes, currentSceneId } = store.get();
    clear(sceneSelect);
    sceneSelect.append(h('option', { value: '' }, scenes.length ? '— pick a scene —' : '— upload a scene first —'));
    for (const s of scenes) {
      const here = app.sessionFiles.has(s.id) ? ' · file in this session' : '';
      sceneSelect.append(h('option', { value: s.id }, `${s.filename || shortId(s.id)} · ${s.triangles} tris · ${shortId(s.id)}${here}`));
    }
    sceneSelect.value = currentSceneId || '';
    const s = scenes.find((x) => x.id === currentSceneId);
    const f = (v) => v.map((x) => Number(x.toFixed(2))).join(', ');
    sceneInfo.textContent = s ? `spans (${f(s.bounds[0])}) … (${f(s.bounds[1])}) m · ${s.lights} light${s.lights === 1 ? '' : 's'} in the file`
      + `${s.emissive_materials ? ` · ${s.emissive_materials} emissive material${s.emissive_materials === 1 ? '' : 's'}` : ''}` : '';
    if (form) { form.setScene(s || null); renderPreWarnings(); updateEstimate(); }
  }

  /** Open the picked scene in the 3D view to place light `index` of the form (null: a new one) by clicking. */
  function placeInViewer(index = null) {
    const id = store.get().currentSceneId;
    if (!id) { bakeStatus.className = 'status error'; bakeStatus.textContent = 'Upload or pick a scene first.'; return; }
    location.hash = `#/viewer?scene=${encodeURIComponent(id)}&place=${index == null ? 'new' : index}`;
  }
  placeBtn.addEventListener('click', () => placeInViewer(null));

  function stageRow(s) {
    const pct = Math.round((s.progress || 0) * 100);
    return h('div.stage', { dataset: { stage: s.name, status: s.status } },
      h('span.stage-name', s.name),
      h('progress', { max: 100, value: pct }),
      h('span.stage-info', `${s.status}${s.cached ? ' (cached)' : ''}${s.seconds != null ? ` · ${formatSeconds(s.seconds)}` : ''}`));
  }

  function renderBakes() {
    const { bakes } = store.get();
    const list = Object.values(bakes).sort((a, b) => (b.created || 0) - (a.created || 0)).slice(0, 12);
    clear(progressList);
    if (!list.length) progressList.append(h('p.muted', 'No bakes yet.'));
    for (const b of list) {
      const actions = [];
      if (ACTIVE.has(b.status)) {
        actions.push(h('button.small', {
          type: 'button', dataset: { cancel: b.id },
          on: { click: async () => { try { app.mergeBake(await api.cancelBake(b.id)); } catch (e) { bakeStatus.className = 'status error'; bakeStatus.textContent = e.message; } } },
        }, 'Cancel'));
      }
      if (b.status === 'succeeded') {
        actions.push(h('a.button.primary', { href: `#/viewer/${b.id}`, dataset: { open: b.id } }, 'Open in viewer'));
        actions.push(h('a.button', { href: api.url(api.bundlePath(b.id)) }, 'Bundle (zip)'));
      }
      const err = b.error ? h('p.error', `${b.error.stage || 'bake'}: ${b.error.code}: ${b.error.message}`) : null;
      const warnings = bakeWarnings(b);
      progressList.append(h('div.bake-card', { dataset: { bake: b.id, status: b.status, warnings: String(warnings.length) } },
        h('div.bake-head', h('strong.scene-name', { title: `scene ${b.scene_id}` }, sceneLabel(store.get().scenes, b.scene_id)), ' ',
          h('code.muted', shortId(b.id)), ' ', h('span.badge', { dataset: { status: b.status } }, b.status), ' ',
          warningBadge(warnings), h('span.spacer'), actions),
        err,
        warningList(warnings),
        h('div.stages', (b.stages || []).map(stageRow))));
    }
  }

  store.subscribe((s, prev) => {
    if (s.scenes !== prev.scenes || s.currentSceneId !== prev.currentSceneId) renderScenes();
    if (s.bakes !== prev.bakes || s.scenes !== prev.scenes) renderBakes();
  });

  return {
    el,
    async init() {
      renderScenes();
      renderBakes();
      try {
        const schema = await api.configSchema();
        form = createConfigForm(schema);
        app.configForm = form;
        form.setScene(currentScene());
        form.onChange(() => {
          renderPreWarnings();
          updateEstimate();
          if (startBtn.textContent !== 'Start bake') { startBtn.textContent = 'Start bake'; confirmed = null; }
        });
        form.onPlaceLight((i) => placeInViewer(i));
        clear(formHolder).append(form.el);
        renderPreWarnings();
        updateEstimate();
      } catch (e) {
        clear(formHolder).append(h('p.error', `Could not load the config schema: ${e.message}`));
      }
    },
    show() {},
  };
}
