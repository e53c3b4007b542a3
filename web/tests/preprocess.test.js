import { describe, expect, it } from 'vitest';
import { readdirSync, readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { formatCompileErrors, preprocess, ShaderSourceError } from '../src/renderer/preprocess.js';

const GLSL = fileURLToPath(new URL('../../proto/glsl/', import.meta.url));
const sources = Object.fromEntries(readdirSync(GLSL).filter((f) => f.endsWith('.glsl')).map((f) => [f, readFileSync(GLSL + f, 'utf8')]));

describe('GLSL preprocessor', () => {
  it('puts the version line first and resolves includes once', () => {
    const { code, lineMap } = preprocess('scene.frag.glsl', sources, { slots: { mode: 'mode_leaking.glsl' }, defines: { MAX_LIGHTS: 8 } });
    const lines = code.split('\n');
    expect(lines[0]).toBe('#version 300 es');
    expect(code).toContain('#define MAX_LIGHTS 8');
    expect(code.match(/const float PI =/g)).toHaveLength(1);  // common.glsl included by several files, once
    expect(code).toContain('uniform highp sampler3D uShR;');
    expect(code).not.toMatch(/#include/);
    const at = lines.findIndex((l) => l.includes('float shIrradianceL1Channel'));
    expect(lineMap[at].file).toBe('sh.glsl');
  });

  it('targets desktop GLSL for the Python renderer', () => {
    const { code } = preprocess('scene.frag.glsl', sources, { target: 'desktop', slots: { mode: 'mode_direct.glsl' } });
    expect(code.startsWith('#version 330\n')).toBe(true);
    expect(code).not.toContain('precision highp');
  });

  it('every mode file defines giIndirectIrradiance and has no #version', () => {
    for (const f of Object.keys(sources).filter((x) => x.startsWith('mode_'))) {
      expect(sources[f]).toMatch(/vec3 giIndirectIrradiance\(vec3 \w+, vec3 \w+\)/);
      expect(sources[f]).not.toMatch(/#\s*version/);
    }
  });

  it('refuses unknown files, unbound slots, cycles and #version lines', () => {
    expect(() => preprocess('x.glsl', { 'x.glsl': '#include "nope.glsl"' })).toThrow(/unknown shader file nope.glsl/);
    expect(() => preprocess('x.glsl', { 'x.glsl': '#include "@mode"' })).toThrow(ShaderSourceError);
    expect(() => preprocess('a.glsl', { 'a.glsl': '#include "b.glsl"', 'b.glsl': '#include "a.glsl"' })).toThrow(/cycle/);
    expect(() => preprocess('a.glsl', { 'a.glsl': '#version 300 es' })).toThrow(/version/);
  });

  it('names the file and line of a compile error, with numbered source', () => {
    const { code, lineMap } = preprocess('a.glsl', { 'a.glsl': 'void f() {}\n#include "b.glsl"', 'b.glsl': 'int x\nint y;' });
    const n = code.split('\n').indexOf('int x') + 1;
    const text = formatCompileErrors(`ERROR: 0:${n}: syntax error`, code, lineMap);
    expect(text).toContain('b.glsl:1: syntax error');
    expect(text).toContain(`>${String(n).padStart(5)} | int x`);
  });
});
