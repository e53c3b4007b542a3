/**
 * Reads a Kiln bundle (proto/bundle.md) over HTTP: `manifest.json`, then each artifact by the file the manifest
 * names. What an artifact is comes from the manifest and the file itself, never from its name or a fixed format:
 *
 * - KTX2 (section 4): three's `KTX2Loader` (uncompressed or Zstandard; RGBA32F, RGBA16F, RG, R, RGBA8 ...). The
 *   formats it refuses (RGB32F probe positions, the integer formats) go through Kiln's own reader
 *   (web/src/loader/ktx2.js), picked by the vkFormat in the file's header, so a bundle that moves an artifact from
 *   float32 to half floats or to another supported format loads with no code change.
 * - npy (section 3) through web/src/loader/npy.js, json as JSON, glb (section 5.5) through three's `GLTFLoader`.
 *
 * Every array artifact comes back as a *record* in the shape of web/src/loader/ktx2.js `parseKTX2` ({kind: 'float' |
 * 'half' | 'unorm' | 'uint' | 'sint', components, width, height, depth, is3D, data}: x fastest, then y, then z), plus
 * `texture` when three's loader made one, so the texture builders of web/src/renderer/textures.js apply unchanged.
 */
import { FloatType, HalfFloatType, RGBAFormat, RGFormat, RedFormat, UnsignedByteType } from 'three';
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { parseKTX2 } from '../../src/loader/ktx2.js';
import { withStoredBorder } from '../../src/math/atlas.js';
import { parseNpy } from '../../src/loader/npy.js';

/** vkFormats three's KTX2Loader (r187) turns into raw Data(3D)Textures (proto/bundle.md 4.3, column "three.js"). */
export const KTX2LOADER_FORMATS = new Set([9, 16, 37, 43, 76, 83, 97, 100, 103, 109]);

/** Newest bundle format_version this reader knows (proto/models.py FORMAT_VERSION). */
export const FORMAT_VERSION = 1;

export class BundleError extends Error {}

const COMPONENTS = { [RedFormat]: 1, [RGFormat]: 2, [RGBAFormat]: 4 };

/** vkFormat of a KTX2 file (UInt32 at byte 12, proto/bundle.md 4.1). */
export function ktx2VkFormat(bytes) {
  const b = bytes instanceof Uint8Array ? bytes : new Uint8Array(bytes);
  if (b.byteLength < 16) throw new BundleError('KTX2 file shorter than its header');
  return new DataView(b.buffer, b.byteOffset, 16).getUint32(12, true);
}

/** A record (see the module doc) of a texture three's KTX2Loader returned. */
export function recordFromTexture(tex) {
  const img = tex.image;
  const kind = tex.type === FloatType ? 'float' : tex.type === HalfFloatType ? 'half' : tex.type === UnsignedByteType ? 'unorm' : null;
  if (!kind) throw new BundleError(`KTX2Loader gave texture type ${tex.type}: not a Kiln format`);
  const components = COMPONENTS[tex.format];
  if (!components) throw new BundleError(`KTX2Loader gave texture format ${tex.format}: not a Kiln format`);
  const depth = tex.isData3DTexture ? img.depth : 0;
  return { kind, components, typeSize: img.data.BYTES_PER_ELEMENT, width: img.width, height: img.height, depth,
    is3D: !!tex.isData3DTexture, data: img.data, texture: tex };
}

export class KilnBundle {
  /**
   * @param {string} base  URL of the bundle folder (where manifest.json is), with or without the trailing slash
   * @param {object} manifest  its parsed manifest.json
   * @param {{renderer: import('three').WebGLRenderer, fetch?: typeof fetch}} options
   */
  constructor(base, manifest, { renderer, fetch: fetchFn = globalThis.fetch.bind(globalThis), fileUrl = null } = {}) {
    this.base = base.endsWith('/') ? base : `${base}/`;
    this.manifest = manifest;
    this.fileUrl = fileUrl;   // (artifact info) -> URL relative to base; default: its file name in the folder
    this.fetch = fetchFn;
    this.renderer = renderer;
    this.ktx2 = renderer ? new KTX2Loader().detectSupport(renderer) : null;
    this.byName = new Map(manifest.artifacts.map((a) => [a.name, a]));
    this.cache = new Map();
  }

  /** Fetch and check manifest.json at `base`. */
  static async load(base, options = {}) {
    const f = options.fetch || globalThis.fetch.bind(globalThis);
    const url = new URL('manifest.json', new URL(base.endsWith('/') ? base : `${base}/`, globalThis.location?.href)).href;
    const r = await f(url);
    if (!r.ok) throw new BundleError(`${url}: HTTP ${r.status}`);
    const manifest = await r.json();
    if (!(manifest.format_version <= FORMAT_VERSION)) {
      throw new BundleError(`bundle format_version ${manifest.format_version} is newer than this reader's ${FORMAT_VERSION}`);
    }
    if (!manifest.grid || !manifest.artifacts) throw new BundleError('manifest.json without grid or artifacts');
    return new KilnBundle(base, manifest, options);
  }

  /** The probe grid: {origin, spacing, counts} (metres, bake frame; proto/bundle.md 5), `layers` ([xs, ys, zs], metres)
   * where the grid is rectilinear (probe (i, j, k) at (xs[i], ys[j], zs[k]); spacing then the mean gap), and `frame`
   * ({yaw_deg, matrix, source, reason}; grid.js frameMatrix) where the bake frame is the world turned about +Y. */
  get grid() { return this.manifest.grid; }

  /** Artifact names in the manifest. */
  get names() { return [...this.byName.keys()]; }

  has(name) { return this.byName.has(name); }

  /** The manifest's ArtifactInfo of `name` (or undefined). */
  info(name) { return this.byName.get(name); }

  url(name) {
    const a = this.byName.get(name);
    if (!a) throw new BundleError(`the bundle has no artifact ${name}`);
    return new URL(this.fileUrl ? this.fileUrl(a) : a.file, new URL(this.base, globalThis.location?.href)).href;
  }

  /**
   * A bake on a Kiln server instead of a bundle folder: `GET {server}/v1/bakes/{id}` (the artifact list; the grid, its
   * bake frame `frame` and a rectilinear grid's `layers` where there are, from the place stage's stats, the bounds
   * from the ingest stage's, as the manifest has them) and each artifact from `/v1/bakes/{id}/artifacts/{name}`.
   * headers: e.g. {Authorization: 'Bearer KEY'}.
   */
  static async fromServer(server, bakeId, { headers = {}, ...options } = {}) {
    const f = options.fetch || globalThis.fetch.bind(globalThis);
    const authed = (url, init = {}) => f(url, { ...init, headers: { ...headers, ...(init.headers || {}) } });
    const base = new URL(`v1/bakes/${encodeURIComponent(bakeId)}/`, new URL(server.endsWith('/') ? server : `${server}/`, globalThis.location?.href)).href;
    const r = await authed(base.slice(0, -1));
    if (!r.ok) throw new BundleError(`${base}: HTTP ${r.status}`);
    const bake = await r.json();
    if (bake.status !== 'succeeded') throw new BundleError(`bake ${bakeId} is ${bake.status}, not succeeded`);
    const stats = (name) => (bake.stages || []).find((st) => st.name === name)?.stats || {};
    const { counts, origin, spacing, frame, layers } = stats('place');
    // frame: the bake frame, as grid.frame; layers: a rectilinear grid's, as grid.layers (both absent when not there)
    const grid = { counts, origin, spacing, ...(layers ? { layers } : {}), ...(frame ? { frame } : {}) };
    const manifest = { format_version: FORMAT_VERSION, bake_id: bake.id, config: bake.config, grid,
      scene: { bounds: stats('ingest').bounds }, stages: bake.stages, artifacts: bake.artifacts };
    if (!counts) throw new BundleError(`bake ${bakeId} has no probe grid (no place stage stats)`);
    return new KilnBundle(base, manifest, { ...options, fetch: authed, fileUrl: (a) => `artifacts/${encodeURIComponent(a.name)}` });
  }

  async bytes(name) {
    const url = this.url(name);
    const r = await this.fetch(url);
    if (!r.ok) throw new BundleError(`${url}: HTTP ${r.status}`);
    const bytes = new Uint8Array(await r.arrayBuffer());
    const want = this.byName.get(name).bytes;
    if (want !== undefined && bytes.byteLength !== want) {
      throw new BundleError(`${name}: ${bytes.byteLength} bytes, the manifest says ${want}`);
    }
    return bytes;
  }

  /** An artifact decoded (cached): KTX2 and npy as a record, json as an object, glb as its bytes. */
  artifact(name) {
    // a DDGI atlas stored without its tile borders comes back with them (proto/bundle.md 5.1)
    if (!this.cache.has(name)) this.cache.set(name, this._decode(name).then((r) => withStoredBorder(r, this.byName.get(name))));
    return this.cache.get(name);
  }

  async _decode(name) {
    const { format } = this.byName.get(name) || {};
    if (format === 'json') return JSON.parse(new TextDecoder().decode(await this.bytes(name)));
    const bytes = await this.bytes(name);
    if (format === 'npy') {
      const a = parseNpy(bytes);
      const shape = a.shape;
      const components = shape.length >= 4 ? shape[shape.length - 1] : 1;
      const kind = a.data instanceof Float32Array ? 'float' : 'raw';
      return { kind, components, width: shape[2] ?? 1, height: shape[1] ?? 1, depth: shape[0] ?? 0, is3D: shape.length >= 3,
        data: a.data, shape };
    }
    if (format !== 'ktx2') return bytes;
    const vk = ktx2VkFormat(bytes);
    if (this.ktx2 && KTX2LOADER_FORMATS.has(vk)) {
      const tex = await new Promise((resolve, reject) => this.ktx2.parse(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength), resolve, reject));
      tex.name = name;
      return recordFromTexture(tex);
    }
    return parseKTX2(bytes);  // RGB32F, integer formats: Kiln's reader (web/src/loader/ktx2.js)
  }

  /** The baked scene (artifact `scene`, glb) through GLTFLoader: the gltf result ({scene, ...}). */
  async loadScene() {
    if (!this.has('scene')) throw new BundleError('the bundle has no `scene` artifact (bundles from before it existed)');
    return new GLTFLoader().loadAsync(this.url('scene'));
  }
}
