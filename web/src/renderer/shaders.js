/**
 * The shader library: every proto/glsl file bundled as text by Vite, preprocessed on demand and cached
 * per (entry, slots, defines) — the "small shader cache" of glTF-Sample-Viewer.
 */
import { preprocess } from './preprocess.js';

const files = import.meta.glob('../../../proto/glsl/*.glsl', { query: '?raw', import: 'default', eager: true });

/** file name -> GLSL source, e.g. "mode_leaking.glsl" -> "...". */
export const GLSL_SOURCES = Object.fromEntries(
  Object.entries(files).map(([path, text]) => [path.slice(path.lastIndexOf('/') + 1), text]),
);

/** True when proto/glsl has the file (GI modes light up only when their shader exists). */
export function hasShader(name) {
  return Object.prototype.hasOwnProperty.call(GLSL_SOURCES, name);
}

const cache = new Map();

/** Preprocessed {code, lineMap} for a program stage, cached. */
export function shaderSource(entry, { slots = {}, defines = {} } = {}) {
  const key = JSON.stringify([entry, slots, defines]);
  let hit = cache.get(key);
  if (!hit) {
    hit = preprocess(entry, GLSL_SOURCES, { target: 'webgl2', slots, defines });
    cache.set(key, hit);
  }
  return hit;
}
