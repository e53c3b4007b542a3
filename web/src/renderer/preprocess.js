/**
 * The GLSL preprocessor of proto/glsl (contract in proto/glsl/README.md): adds the version line for the
 * target, resolves `#include "file.glsl"` (once per program) and `#include "@slot"`, and keeps a line map
 * so compile errors name the file and line. Pure: sources come in as a map of file name -> text.
 */

export class ShaderSourceError extends Error {}

const TARGETS = {
  webgl2: ['#version 300 es', 'precision highp float;', 'precision highp int;', 'precision highp sampler2D;',
    'precision highp sampler3D;', 'precision highp usampler3D;', '#define KILN_WEBGL2 1'],
  desktop: ['#version 330', '#define KILN_DESKTOP 1'],
};

const INCLUDE = /^\s*#\s*include\s+"([^"]+)"\s*(\/\/.*)?$/;
const VERSION = /^\s*#\s*version\b/;

/**
 * @param {string} entry  file name of the shader's main file (e.g. "scene.frag.glsl")
 * @param {Record<string, string>} sources  file name -> GLSL text
 * @param {{target?: 'webgl2'|'desktop', slots?: Record<string, string>, defines?: Record<string, string|number|boolean>}} options
 * @returns {{code: string, lineMap: {file: string, line: number}[]}}  lineMap[i] = origin of output line i + 1
 */
export function preprocess(entry, sources, { target = 'webgl2', slots = {}, defines = {} } = {}) {
  const header = TARGETS[target];
  if (!header) throw new ShaderSourceError(`unknown shader target ${target}`);
  const out = [];
  const lineMap = [];
  for (const line of header) { out.push(line); lineMap.push({ file: '<header>', line: 0 }); }
  for (const [name, value] of Object.entries(defines)) {
    if (value === false || value === undefined || value === null) continue;
    out.push(`#define ${name}${value === true ? '' : ` ${value}`}`);
    lineMap.push({ file: '<defines>', line: 0 });
  }
  const included = new Set();
  const expand = (file, chain) => {
    if (chain.includes(file)) throw new ShaderSourceError(`include cycle: ${[...chain, file].join(' -> ')}`);
    if (included.has(file)) return;
    const text = sources[file];
    if (text === undefined) {
      const from = chain.length ? ` (included from ${chain[chain.length - 1]})` : '';
      throw new ShaderSourceError(`unknown shader file ${file}${from}`);
    }
    included.add(file);
    text.split(/\r?\n/).forEach((line, i) => {
      if (VERSION.test(line)) throw new ShaderSourceError(`${file}:${i + 1}: #version belongs to the preprocessor`);
      const m = INCLUDE.exec(line);
      if (!m) { out.push(line); lineMap.push({ file, line: i + 1 }); return; }
      let target = m[1];
      if (target.startsWith('@')) {
        const bound = slots[target.slice(1)];
        if (!bound) throw new ShaderSourceError(`${file}:${i + 1}: slot ${target} is not bound`);
        target = bound;
      }
      expand(target, [...chain, file]);
    });
  };
  expand(entry, []);
  return { code: out.join('\n') + '\n', lineMap };
}

/**
 * A compile log with each error's source line, numbered, and its origin (file:line), in the spirit of
 * glTF-Sample-Viewer's webgl.js. Accepts logs of the form `ERROR: 0:LINE: message`.
 */
export function formatCompileErrors(log, code, lineMap, context = 2) {
  const lines = code.split('\n');
  const parts = [];
  for (const entry of String(log).split('\n')) {
    const m = /^(?:ERROR|WARNING):\s*\d+:(\d+):\s*(.*)$/.exec(entry.trim());
    if (!m) { if (entry.trim()) parts.push(entry.trim()); continue; }
    const n = Number(m[1]);
    const origin = lineMap[n - 1];
    parts.push(`${origin ? `${origin.file}:${origin.line}` : `line ${n}`}: ${m[2]}`);
    for (let k = Math.max(1, n - context); k <= Math.min(lines.length, n + context); k++) {
      parts.push(`${k === n ? '>' : ' '}${String(k).padStart(5)} | ${lines[k - 1]}`);
    }
  }
  return parts.join('\n');
}
