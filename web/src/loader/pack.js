/**
 * Several dropped files as one upload: a .gltf (or .glb) with the buffers and images it references, packed into a
 * zip in the browser (fflate, stored), each file at the relative path the model names it by — the browser twin of
 * `kiln bake scene.gltf` (workers/gltf/pack.py). The service reads one file per upload: a .glb, a .gltf with
 * data: URIs, or a .zip of a model and its files.
 *
 * A dropped file matches a referenced URI (percent-decoded) by its relative path (a dropped folder's
 * `webkitRelativePath`, less the folder) or else by its base name. URIs with a scheme, absolute or climbing out of
 * the model's folder are left for the server to refuse with its own code.
 */
import { zipSync } from 'three/addons/libs/fflate.module.js';

export class PackError extends Error {}

const MODEL = /\.(gltf|glb)$/i;

/** The glTF JSON of a .gltf's text or a .glb's first chunk; null when it is neither (the server says why). */
export function modelJson(bytes) {
  try {
    const u8 = new Uint8Array(bytes);
    const dv = new DataView(u8.buffer, u8.byteOffset, u8.byteLength);
    if (u8.length >= 20 && dv.getUint32(0, true) === 0x46546c67) {   // 'glTF'
      const n = dv.getUint32(12, true);
      if (dv.getUint32(16, true) !== 0x4e4f534a || 20 + n > u8.length) return null;
      return JSON.parse(new TextDecoder().decode(u8.subarray(20, 20 + n)));
    }
    return JSON.parse(new TextDecoder().decode(u8));
  } catch {
    return null;
  }
}

/** [{rel, what}] of the files a glTF document references (buffers, images), percent-decoded, '/'-separated. */
export function referencedFiles(doc) {
  const out = [];
  if (!doc || typeof doc !== 'object') return out;
  for (const [key, noun] of [['buffers', 'buffer'], ['images', 'image']]) {
    (Array.isArray(doc[key]) ? doc[key] : []).forEach((item, i) => {
      const uri = item && typeof item.uri === 'string' ? item.uri : '';
      if (!uri || uri.slice(0, 5).toLowerCase() === 'data:') return;
      let rel;
      try { rel = decodeURIComponent(uri).replace(/\\/g, '/'); } catch { return; }
      if (rel.split('/')[0].includes(':') || rel.startsWith('/')) return;
      const parts = [];
      for (const p of rel.split('/')) {
        if (p === '..') { if (!parts.length) return; parts.pop(); } else if (p && p !== '.') parts.push(p);
      }
      const norm = parts.join('/');
      if (norm && !out.some((o) => o.rel === norm)) out.push({ rel: norm, what: `${noun} ${i}` });
    });
  }
  return out;
}

const relPath = (f) => {
  const r = f.webkitRelativePath || '';
  return r.includes('/') ? r.slice(r.indexOf('/') + 1) : (f.name || '');
};
const baseName = (p) => p.slice(p.lastIndexOf('/') + 1);

/**
 * The one File to upload for what the user dropped or picked: a single file as it is; a model with its files as
 * `<model>.zip`. Throws PackError (a sentence for the upload status) when there is no model, several, or a file the
 * model references is missing.
 * @param {File[]} files
 * @returns {Promise<File>}
 */
export async function packUpload(files) {
  const list = Array.from(files || []);
  if (list.length <= 1) return list[0];
  const models = list.filter((f) => MODEL.test(f.name || ''));
  if (models.length !== 1) {
    throw new PackError(models.length ? `drop one model at a time (got ${models.map((f) => f.name).join(', ')})`
      : 'none of the dropped files is a .gltf or .glb');
  }
  const model = models[0];
  const bytes = new Uint8Array(await model.arrayBuffer());
  const entries = { [model.name]: [bytes, { level: 0 }] };
  for (const { rel, what } of referencedFiles(modelJson(bytes))) {
    const f = list.find((x) => x !== model && relPath(x) === rel)
      || list.find((x) => x !== model && (x.name || '') === baseName(rel));
    if (!f) throw new PackError(`${model.name}: ${what} '${rel}' is not among the dropped files`);
    entries[rel] = [new Uint8Array(await f.arrayBuffer()), { level: 0 }];
  }
  const stem = model.name.replace(MODEL, '');
  return new File([zipSync(entries)], `${stem}.zip`, { type: 'application/zip' });
}
