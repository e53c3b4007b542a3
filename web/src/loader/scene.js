/**
 * The scene, loaded with three's GLTFLoader: from the File the user dropped in this session
 * (`loadSceneFile`: .glb and .gltf (data URIs) load directly; a .zip is unzipped in memory and its .gltf's
 * relative URIs are served from the zip's entries), or from the bake's `scene` artifact, the GLB the ingest
 * stage writes of the normalized scene (`loadSceneBytes`; the server keeps no copy of the original upload).
 */
import { LoadingManager } from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { unzipSync } from 'three/addons/libs/fflate.module.js';

export class SceneLoadError extends Error {}

function parseWith(loader, data, path) {
  return new Promise((resolve, reject) => loader.parse(data, path, resolve, (e) => reject(new SceneLoadError(e.message || String(e)))));
}

/** @param {File|Blob & {name: string}} file  @returns {Promise<import('three').Group>} the glTF's scene */
export async function loadSceneFile(file) {
  const name = (file.name || '').toLowerCase();
  const buf = await file.arrayBuffer();
  if (name.endsWith('.zip')) {
    const entries = unzipSync(new Uint8Array(buf));
    const paths = Object.keys(entries).filter((p) => !p.startsWith('__MACOSX/'));
    const main = paths.find((p) => p.toLowerCase().endsWith('.gltf')) || paths.find((p) => p.toLowerCase().endsWith('.glb'));
    if (!main) throw new SceneLoadError('the zip holds no .gltf or .glb');
    const dir = main.includes('/') ? main.slice(0, main.lastIndexOf('/') + 1) : '';
    const urls = new Map();
    const manager = new LoadingManager();
    manager.setURLModifier((url) => {
      const rel = decodeURIComponent(url.replace(/^\.\//, ''));
      const key = dir + rel;
      if (!entries[key]) return url;
      if (!urls.has(key)) urls.set(key, URL.createObjectURL(new Blob([entries[key]])));
      return urls.get(key);
    });
    const loader = new GLTFLoader(manager);
    try {
      const data = main.toLowerCase().endsWith('.glb') ? entries[main].buffer : new TextDecoder().decode(entries[main]);
      return (await parseWith(loader, data, '')).scene;
    } finally {
      for (const u of urls.values()) URL.revokeObjectURL(u);
    }
  }
  const loader = new GLTFLoader();
  return (await parseWith(loader, buf, '')).scene;
}

/**
 * The baked scene from the server: the bake's `scene` artifact (GLB bytes written by the ingest stage,
 * workers/scene_glb.py), so a bake shows its geometry in any session, not only the one that uploaded it.
 * @param {Uint8Array|ArrayBuffer} bytes  @returns {Promise<import('three').Group>}
 */
export async function loadSceneBytes(bytes) {
  const u8 = bytes instanceof Uint8Array ? bytes : new Uint8Array(bytes);
  const buf = u8.byteOffset === 0 && u8.byteLength === u8.buffer.byteLength ? u8.buffer : u8.slice().buffer;
  return (await parseWith(new GLTFLoader(), buf, '')).scene;
}
