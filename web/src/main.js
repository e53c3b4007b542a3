/**
 * The Kiln web app: upload and bake, the WebGL2 viewer, the dashboard. Routes live in the hash
 * (#/bake, #/viewer/<bake>?mode=&cam=, #/dashboard?scene=) so the server serves one static page.
 */
import './style.css';
import { KilnApi } from './api/client.js';
import { createStore, INITIAL_STATE } from './state/store.js';
import { createBakePage } from './ui/bakePage.js';
import { createDashboardPage } from './ui/dashboardPage.js';
import { h } from './ui/dom.js';
import { createViewerPage } from './ui/viewerPage.js';

const api = new KilnApi();
const store = createStore(INITIAL_STATE);

const app = {
  api,
  store,
  sessionFiles: new Map(),  // scene id -> the File uploaded in this session (the server keeps no original)
  follows: new Map(),       // bake id -> stop function
  viewer: null,
  configForm: null,
  async refreshScenes() {
    const { items } = await api.listScenes();
    store.set({ scenes: items });
  },
  mergeBake(b) {
    if (!b || !b.id) return;
    store.set((s) => ({ bakes: { ...s.bakes, [b.id]: { ...(s.bakes[b.id] || {}), ...b } } }));
  },
  followBake(id) {
    if (this.follows.has(id)) return;
    const stop = api.followBake(id, async (type, data) => {
      if (data && data.id) this.mergeBake(data);
      if (type === 'status' || type === 'deleted') {
        stop();
        this.follows.delete(id);
        if (type === 'status') {
          try { this.mergeBake(await api.getBake(id)); } catch { /* deleted meanwhile */ }
        }
      }
    }, {
      onError: async () => {
        this.follows.delete(id);
        try { this.mergeBake(await api.getBake(id)); } catch { /* gone */ }
      },
    });
    this.follows.set(id, stop);
    api.getBake(id).then((b) => this.mergeBake(b)).catch(() => {});
  },
};
window.kiln = app;  // for the console and the browser tests
// GLSL parity on this device (tests/web compare with the Python kernels through proto/fixtures)
app.glslParity = async (fixtures) => (await import('./renderer/selftest.js')).glslParity(fixtures);

const keyInput = h('input#api-key', { type: 'password', placeholder: 'API key (empty: open server)', autocomplete: 'off', value: api.key });
keyInput.addEventListener('change', () => { api.setKey(keyInput.value); boot().then(route); });
const nav = h('nav',
  h('a', { href: '#/bake', dataset: { page: 'bake' } }, 'Upload & bake'),
  h('a', { href: '#/viewer', dataset: { page: 'viewer' } }, 'Viewer'),
  h('a', { href: '#/dashboard', dataset: { page: 'dashboard' } }, 'Dashboard'));
const banner = h('p#banner.error');
const pages = { bake: createBakePage(app), viewer: createViewerPage(app), dashboard: createDashboardPage(app) };
document.getElementById('boot')?.remove();
document.getElementById('app').append(
  h('header', h('h1', h('a', { href: '#/bake' }, 'Kiln')), nav, h('span.spacer'), h('a', { href: '/docs' }, 'API docs'), keyInput),
  banner,
  h('main', Object.values(pages).map((p) => p.el)));

function parseRoute() {
  const raw = location.hash.replace(/^#\/?/, '');
  const [path, query] = raw.split('?');
  const [page, id] = path.split('/');
  return { page: pages[page] ? page : 'bake', params: { id: id || null, query: new URLSearchParams(query || '') } };
}

async function route() {
  const { page, params } = parseRoute();
  for (const [name, p] of Object.entries(pages)) p.el.hidden = name !== page;
  nav.querySelectorAll('a').forEach((a) => a.classList.toggle('active', a.dataset.page === page));
  store.set({ route: { page, params } });
  try {
    await pages[page].show(params);
  } catch (e) {
    banner.textContent = e.message;
  }
}

async function boot() {
  banner.textContent = '';
  try {
    await app.refreshScenes();
    const { items } = await api.listBakes({ limit: 20 });
    for (const b of items) { app.mergeBake(b); if (b.status === 'queued' || b.status === 'running') app.followBake(b.id); }
  } catch (e) {
    banner.textContent = e.status === 401 || e.status === 403 ? `${e.message} — set your API key (top right).` : e.message;
  }
}

window.addEventListener('hashchange', route);
pages.bake.init();
boot().then(route);
