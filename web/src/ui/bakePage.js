/**
 * "Upload and bake": drop or pick a .glb/.gltf/.zip (the API's refusal shown in words), pick a scene,
 * fill the config form generated from the JSON Schema, start a bake, follow it stage by stage over SSE,
 * cancel it, open it in the viewer.
 */
import { createConfigForm } from './configForm.js';
import { clear, h, shortId } from './dom.js';
import { bakeWarnings, formatSeconds } from '../state/stats.js';
import { warningBadge, warningList } from './warnings.js';

const ACTIVE = new Set(['queued', 'running']);

export function createBakePage(app) {
  const { api, store } = app;
  const fileInput = h('input#scene-file', { type: 'file', accept: '.glb,.gltf,.zip' });
  const uploadStatus = h('p#upload-status.status', { role: 'status' });
  const drop = h('div#drop.drop', h('p', 'Drop a ', h('code', '.glb'), ', ', h('code', '.gltf'), ' (embedded data) or ', h('code', '.zip'), ' here, or ', h('label.button', fileInput, 'choose a file')));
  const sceneSelect = h('select#scene-select');
  const sceneInfo = h('p#scene-info.muted');
  const formHolder = h('div#config-form', h('p.muted', 'Loading the config schema…'));
  const startBtn = h('button#start-bake.primary', { type: 'button' }, 'Start bake');
  const bakeStatus = h('p#bake-status.status', { role: 'status' });
  const progressList = h('div#bake-progress');
  let form = null;

  const el = h('section.page#page-bake',
    h('h2', 'Upload a scene'), drop, uploadStatus,
    h('h2', 'Bake'),
    h('div.row', h('label', 'Scene ', sceneSelect), sceneInfo),
    formHolder,
    h('div.row', startBtn, bakeStatus),
    h('h2', 'Bakes in progress and recent'),
    progressList);

  async function upload(file) {
    uploadStatus.className = 'status';
    uploadStatus.textContent = `Uploading ${file.name} (${(file.size / 1024).toFixed(0)} KiB)…`;
    try {
      const s = await api.uploadScene(file);
      app.sessionFiles.set(s.id, file);
      uploadStatus.className = 'status ok';
      uploadStatus.textContent = `Scene ${shortId(s.id)} ready: ${s.triangles} triangles, ${s.lights} lights, ${s.materials} materials` +
        (s.warnings && s.warnings.length ? ` (warnings: ${s.warnings.join('; ')})` : '');
      await app.refreshScenes();
      store.set({ currentSceneId: s.id });
    } catch (e) {
      uploadStatus.className = 'status error';
      uploadStatus.textContent = `Upload refused: ${e.message}${e.code ? ` (${e.code})` : ''}`;
    }
  }
  fileInput.addEventListener('change', () => { if (fileInput.files[0]) upload(fileInput.files[0]); fileInput.value = ''; });
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    const f = e.dataTransfer.files[0];
    if (f) upload(f);
  });

  sceneSelect.addEventListener('change', () => store.set({ currentSceneId: sceneSelect.value || null }));

  startBtn.addEventListener('click', async () => {
    const sceneId = store.get().currentSceneId;
    bakeStatus.className = 'status';
    if (!sceneId) { bakeStatus.className = 'status error'; bakeStatus.textContent = 'Upload or pick a scene first.'; return; }
    if (!form) return;
    form.clearErrors();
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
    sceneInfo.textContent = s ? `bounds ${JSON.stringify(s.bounds)} · ${s.lights} lights` : '';
  }

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
        h('div.bake-head', h('code', shortId(b.id)), ' ', h('span.badge', { dataset: { status: b.status } }, b.status), ' ',
          warningBadge(warnings), ' ',
          h('span.muted', `scene ${shortId(b.scene_id)}`), h('span.spacer'), actions),
        err,
        warningList(warnings),
        h('div.stages', (b.stages || []).map(stageRow))));
    }
  }

  store.subscribe((s, prev) => {
    if (s.scenes !== prev.scenes || s.currentSceneId !== prev.currentSceneId) renderScenes();
    if (s.bakes !== prev.bakes) renderBakes();
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
        clear(formHolder).append(form.el);
      } catch (e) {
        clear(formHolder).append(h('p.error', `Could not load the config schema: ${e.message}`));
      }
    },
    show() {},
  };
}
