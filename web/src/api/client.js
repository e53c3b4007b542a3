/**
 * The Kiln REST API (README "REST API (v1)") as plain async functions. Every error becomes an ApiError
 * carrying the server's machine-readable code and human sentence; nothing else in the web app calls fetch
 * on /v1 directly.
 */
import { SSEParser } from './sse.js';

const KEY_STORAGE = 'kiln-api-key';

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

export class KilnApi {
  constructor({ base = '', storage = globalThis.localStorage } = {}) {
    this.base = base;
    this.storage = storage;
    this.key = (storage && storage.getItem(KEY_STORAGE)) || '';
  }

  setKey(key) {
    this.key = (key || '').trim();
    if (this.storage) {
      if (this.key) this.storage.setItem(KEY_STORAGE, this.key);
      else this.storage.removeItem(KEY_STORAGE);
    }
  }

  headers(extra = {}) {
    return this.key ? { ...extra, Authorization: `Bearer ${this.key}` } : { ...extra };
  }

  url(path) {
    return this.base + path;
  }

  async request(path, { method = 'GET', body, json, headers = {}, signal } = {}) {
    const init = { method, headers: this.headers(headers), signal };
    if (json !== undefined) {
      init.body = JSON.stringify(json);
      init.headers['Content-Type'] = 'application/json';
    } else if (body !== undefined) {
      init.body = body;
    }
    let r;
    try {
      r = await fetch(this.url(path), init);
    } catch (e) {
      if (e.name === 'AbortError') throw e;
      throw new ApiError(0, 'unreachable', `cannot reach the Kiln server (${e.message})`);
    }
    if (r.status === 204) return null;
    const text = await r.text();
    let data = null;
    try { data = text ? JSON.parse(text) : null; } catch { data = null; }
    if (!r.ok) {
      const err = data && data.error;
      throw new ApiError(r.status, err ? err.code : `http_${r.status}`, err ? err.message : `HTTP ${r.status} ${r.statusText}`);
    }
    return data;
  }

  configSchema() { return this.request('/v1/config/schema'); }
  health() { return this.request('/healthz'); }
  listScenes(limit = 200) { return this.request(`/v1/scenes?limit=${limit}`); }
  getScene(id) { return this.request(`/v1/scenes/${encodeURIComponent(id)}`); }
  listBakes({ sceneId, status, limit = 200, offset = 0 } = {}) {
    const q = new URLSearchParams({ limit: String(limit), offset: String(offset) });
    if (sceneId) q.set('scene_id', sceneId);
    if (status) q.set('status', status);
    return this.request(`/v1/bakes?${q}`);
  }
  getBake(id) { return this.request(`/v1/bakes/${encodeURIComponent(id)}`); }
  createBake(sceneId, config) { return this.request('/v1/bakes', { method: 'POST', json: { scene_id: sceneId, config } }); }
  /** The server's estimate of a bake, nothing started: {estimate: {probes, seconds, peak_memory_bytes, artifact_bytes, ...}, limits, over_budget}. */
  estimateBake(sceneId, config) { return this.request('/v1/bakes?dry_run=true', { method: 'POST', json: { scene_id: sceneId, config } }); }
  cancelBake(id) { return this.request(`/v1/bakes/${encodeURIComponent(id)}/cancel`, { method: 'POST' }); }
  deleteBake(id) { return this.request(`/v1/bakes/${encodeURIComponent(id)}`, { method: 'DELETE' }); }
  artifactPath(bakeId, name) { return `/v1/bakes/${encodeURIComponent(bakeId)}/artifacts/${encodeURIComponent(name)}`; }
  bundlePath(bakeId) { return `/v1/bakes/${encodeURIComponent(bakeId)}/bundle`; }

  /** Upload a File (multipart, so the server learns its name). */
  uploadScene(file, { signal } = {}) {
    const form = new FormData();
    form.append('file', file, file.name);
    return this.request('/v1/scenes', { method: 'POST', body: form, signal });
  }

  /**
   * Follow a bake's events. Calls onEvent(type, data) for `progress`, `status` and `deleted` events.
   * Without a key it uses EventSource; with one, fetch-streaming of the same endpoint (EventSource cannot
   * send an Authorization header). Returns a function that stops following. Resolves `done` when the
   * stream ends.
   */
  followBake(id, onEvent, { onError } = {}) {
    const path = this.url(`/v1/bakes/${encodeURIComponent(id)}/events`);
    let stopped = false;
    if (!this.key && typeof EventSource !== 'undefined') {
      const es = new EventSource(path);
      const handler = (type) => (ev) => {
        let data = null;
        try { data = JSON.parse(ev.data); } catch { /* not JSON */ }
        onEvent(type, data);
        if (type !== 'progress') es.close();
      };
      for (const t of ['progress', 'status', 'deleted']) es.addEventListener(t, handler(t));
      es.onerror = () => {
        if (es.readyState === EventSource.CLOSED && !stopped && onError) onError(new ApiError(0, 'events_closed', 'the event stream closed'));
      };
      return () => { stopped = true; es.close(); };
    }
    const ctrl = new AbortController();
    (async () => {
      try {
        const r = await fetch(path, { headers: this.headers({ Accept: 'text/event-stream' }), signal: ctrl.signal });
        if (!r.ok) {
          const body = await r.json().catch(() => null);
          throw new ApiError(r.status, body?.error?.code || `http_${r.status}`, body?.error?.message || `HTTP ${r.status}`);
        }
        const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
        const parser = new SSEParser();
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          for (const ev of parser.push(value)) {
            let data = null;
            try { data = JSON.parse(ev.data); } catch { /* not JSON */ }
            onEvent(ev.event, data);
          }
        }
      } catch (e) {
        if (e.name !== 'AbortError' && onError) onError(e);
      }
    })();
    return () => { stopped = true; ctrl.abort(); };
  }
}
