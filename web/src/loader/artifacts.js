/**
 * Streams bake artifacts from /v1/bakes/{id}/artifacts/{name} with progress, cached by ETag in the Cache
 * API. Artifacts are content-addressed (ETag = "sha256"), so an entry whose ETag equals the sha256 the bake
 * lists is used without touching the network; any other cached entry is revalidated with If-None-Match
 * (304 -> the cached bytes). Where the Cache API is missing (not a secure context) it falls back to plain
 * fetches.
 */
import { parseKTX2 } from './ktx2.js';
import { withStoredBorder } from '../math/atlas.js';

const CACHE_NAME = 'kiln-artifacts-v1';

async function openCache() {
  try {
    if (typeof caches === 'undefined') return null;
    return await caches.open(CACHE_NAME);
  } catch {
    return null;  // e.g. opaque origins
  }
}

/** Read a Response body with progress callbacks: onProgress(bytesSoFar, totalOrNull). */
async function readWithProgress(response, onProgress, expectedBytes) {
  const total = Number(response.headers.get('Content-Length')) || expectedBytes || null;
  if (!response.body || !onProgress) return new Uint8Array(await response.arrayBuffer());
  const reader = response.body.getReader();
  const chunks = [];
  let got = 0;
  for (;;) {
    const { value, done } = await reader.read();
    if (done) break;
    chunks.push(value);
    got += value.byteLength;
    onProgress(got, total);
  }
  const out = new Uint8Array(got);
  let o = 0;
  for (const c of chunks) { out.set(c, o); o += c.byteLength; }
  return out;
}

export class ArtifactLoader {
  /** @param {import('../api/client.js').KilnApi} api */
  constructor(api) {
    this.api = api;
    this.cachePromise = openCache();
    this.stats = { network: 0, cached: 0, revalidated: 0 };
  }

  /**
   * Bytes of one artifact.
   * @param {string} bakeId
   * @param {{name: string, sha256?: string, bytes?: number}} info  from the bake's `artifacts` list
   * @param {(got: number, total: number|null) => void} [onProgress]
   * @returns {Promise<Uint8Array>}
   */
  async bytes(bakeId, info, onProgress) {
    const url = new URL(this.api.url(this.api.artifactPath(bakeId, info.name)), location.href).href;
    const cache = await this.cachePromise;
    const want = info.sha256 ? `"${info.sha256}"` : null;
    let cached = null;
    if (cache) {
      cached = await cache.match(url);
      if (cached && want && cached.headers.get('ETag') === want) {
        this.stats.cached += 1;
        const buf = new Uint8Array(await cached.arrayBuffer());
        if (onProgress) onProgress(buf.byteLength, buf.byteLength);
        return buf;
      }
    }
    const headers = this.api.headers();
    const etag = cached && cached.headers.get('ETag');
    if (etag) headers['If-None-Match'] = etag;
    const r = await fetch(url, { headers, cache: 'no-store' });
    if (r.status === 304 && cached) {
      this.stats.revalidated += 1;
      const buf = new Uint8Array(await cached.arrayBuffer());
      if (onProgress) onProgress(buf.byteLength, buf.byteLength);
      return buf;
    }
    if (!r.ok) {
      const body = await r.json().catch(() => null);
      throw new Error(body?.error?.message || `artifact ${info.name}: HTTP ${r.status}`);
    }
    const buf = await readWithProgress(r, onProgress, info.bytes);
    this.stats.network += 1;
    const tag = r.headers.get('ETag');
    if (cache && tag) {
      try {
        await cache.put(url, new Response(buf, { headers: { ETag: tag, 'Content-Type': r.headers.get('Content-Type') || '' } }));
      } catch { /* quota: keep going without the cache */ }
    }
    return buf;
  }

  async ktx2(bakeId, info, onProgress) {
    // a DDGI atlas stored without its tile borders comes back with them (proto/bundle.md 5.1)
    return withStoredBorder(parseKTX2(await this.bytes(bakeId, info, onProgress)), info);
  }

  async json(bakeId, info, onProgress) {
    return JSON.parse(new TextDecoder().decode(await this.bytes(bakeId, info, onProgress)));
  }
}

/**
 * Loads a set of artifacts concurrently and reports the combined progress (bytes of all of them, from the
 * sizes the bake lists). Returns {name: decoded} in the order asked.
 * @param {ArtifactLoader} loader
 * @param {string} bakeId
 * @param {{name: string, format: string, bytes: number, sha256: string}[]} infos
 * @param {(fraction: number, label: string) => void} onProgress
 */
export async function loadArtifacts(loader, bakeId, infos, onProgress) {
  const total = infos.reduce((s, a) => s + (a.bytes || 0), 0) || 1;
  const got = new Map();
  const report = (label) => {
    const sum = [...got.values()].reduce((s, x) => s + x, 0);
    onProgress && onProgress(Math.min(1, sum / total), label);
  };
  const out = {};
  await Promise.all(infos.map(async (info) => {
    const progress = (n) => { got.set(info.name, n); report(info.name); };
    if (info.format === 'ktx2') out[info.name] = await loader.ktx2(bakeId, info, progress);
    else if (info.format === 'json') out[info.name] = await loader.json(bakeId, info, progress);
    else out[info.name] = await loader.bytes(bakeId, info, progress);
    got.set(info.name, info.bytes || 0);
    report(info.name);
  }));
  return out;
}
