/**
 * GLSL parity on the real GPU path: runs proto/glsl's sh.glsl (L1 and L2), probe_grid.glsl and gi_grid.glsl (with
 * hardware trilinear filtering of RGBA32F 3D textures; the padded sh_l2 stack) and octahedral.glsl on a throwaway WebGL2 context and reads the results
 * back, for the browser tests to compare with the Python kernels' numbers in proto/fixtures/expected.json.
 * Needs EXT_color_buffer_float (to read float results back).
 * The fixture's points and normals are grid coordinates (the bake frame): no uGiFrame is involved here; the frame's
 * mapping is covered by web/tests/frame.test.js and tests/render/test_shading.py.
 * The fixture's grid is uniform (uGridRectilinear false, a 1 x 3 uGridLayers as the renderer binds it). A rectilinear
 * grid (probe_grid.glsl giGridIndex reading uGridLayers) is checked against the JS mirror (math/sh.js gridIndex,
 * probeTexel, sampleShL2) on layers made here over the fixture's counts: `rectilinear` in the result.
 */
import { preprocess } from './preprocess.js';
import { GLSL_SOURCES } from './shaders.js';
import { gridIndex, probeGridUVW, probeTexel, sampleShL2, shIrradianceL2 } from '../math/sh.js';

/**
 * Rectilinear layers over a grid's counts (bake frame, metres): layer i of axis a at origin + spacing · (i + 0.35 sin 2.1i),
 * gaps from 0.3 to 1.7 spacings, the first at the origin.
 * @param {{origin: number[], spacing: number[], counts: number[]}} grid
 * @returns {number[][]}
 */
export function parityLayers(grid) {
  return [0, 1, 2].map((a) => Array.from({ length: grid.counts[a] }, (_, i) => grid.origin[a] + grid.spacing[a] * (i + 0.35 * Math.sin(2.1 * i))));
}

const VERT = `#version 300 es
void main() { vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2); gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0); }`;

const FRAG = `// parity entry (web/src/renderer/selftest.js)
#include "sh.glsl"
#include "octahedral.glsl"
#include "probe_grid.glsl"
#include "gi_grid.glsl"
uniform highp sampler2D uIn;  // column = case, rows = inputs
uniform highp sampler3D uShL2;  // the sh_l2 fixture (three.js LightProbeGrid layout)
uniform highp sampler3D uShR;
uniform highp sampler3D uShG;
uniform highp sampler3D uShB;
uniform int uTest;
out vec4 fragColor;
void main() {
  int i = int(gl_FragCoord.x);
  vec4 a = texelFetch(uIn, ivec2(i, 0), 0);
  vec4 b = texelFetch(uIn, ivec2(i, 1), 0);
  vec4 c = texelFetch(uIn, ivec2(i, 2), 0);
  vec4 d = texelFetch(uIn, ivec2(i, 3), 0);
  if (uTest == 0) fragColor = vec4(shIrradianceL1(a, b, c, d.xyz), 1.0);
  else if (uTest == 1) {
    vec3 uvw = probeGridUVW(a.xyz);
    fragColor = vec4(shIrradianceL1(texture(uShR, uvw), texture(uShG, uvw), texture(uShB, uvw), b.xyz), 1.0);
  } else if (uTest == 2) fragColor = vec4(octEncode(a.xyz), 0.0, 1.0);
  else if (uTest == 3) fragColor = vec4(octDecode(a.xy), 1.0);
  else if (uTest == 7) fragColor = vec4(giGridIndex(a.xyz), 1.0);   // the continuous probe index, unclamped
  else if (uTest == 8) fragColor = vec4(probeGridUVW(a.xyz), 1.0);
  else if (uTest == 9) fragColor = vec4(giProbeTexel(a.xyz), 1.0);
  else if (uTest == 5) {  // L2 of one probe: its 7 texels (rows 0-6 via texelFetch of uShL2), normal in row 0
    ivec3 pr = ivec3(a.xyz);
    int slices = int(uGridCounts.z) + 2;
    vec4 s[7];
    for (int t = 0; t < 7; ++t) s[t] = texelFetch(uShL2, ivec3(pr.xy, pr.z + 1 + t * slices), 0);
    fragColor = vec4(shIrradianceL2Packed(s[0], s[1], s[2], s[3], s[4], s[5], s[6], b.xyz), 1.0);
  } else if (uTest == 6) {  // L2 at a world point: 7 trilinear fetches, as mode_leaking.glsl (unclamped)
    vec3 tx = giProbeTexel(a.xyz);
    vec4 s[7];
    for (int t = 0; t < 7; ++t) s[t] = texture(uShL2, giPaddedStackedUVW(tx, float(t), 7.0));
    fragColor = vec4(shIrradianceL2Packed(s[0], s[1], s[2], s[3], s[4], s[5], s[6], b.xyz), 1.0);
  }
  else fragColor = vec4(shIrradianceL1LinearChannel(a, d.xyz), shIrradianceL1LinearChannel(b, d.xyz),
                        shIrradianceL1LinearChannel(c, d.xyz), 1.0);
}`;

function compile(gl, type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}

/**
 * @param {object} fx  proto/fixtures/expected.json
 * @returns {{sh: number[][], shLinear: number[][], trilinear: number[][], shL2: number[][], shL2Trilinear: number[][], octEncode: number[][], octDecode: number[][], rectilinear: object, renderer: string}}
 *   rectilinear: {layers, points (bake frame, metres), gridIndex, uvw, texel, shL2Trilinear (per point, then normal)},
 *   each {glsl, js}: the GPU's numbers and math/sh.js's for the same rectilinear grid (parityLayers)
 */
export function glslParity(fx) {
  const canvas = document.createElement('canvas');
  const gl = canvas.getContext('webgl2');
  if (!gl) throw new Error('no WebGL2');
  if (!gl.getExtension('EXT_color_buffer_float')) throw new Error('EXT_color_buffer_float is missing: cannot read float results');
  gl.getExtension('OES_texture_float_linear');
  // the parity program; a rectilinear grid's code is compiled only with KILN_GRID_RECTILINEAR (probe_grid.glsl)
  const build = (defines) => {
    const { code } = preprocess('parity.frag.glsl', { ...GLSL_SOURCES, 'parity.frag.glsl': FRAG }, { defines });
    const pr = gl.createProgram();
    gl.attachShader(pr, compile(gl, gl.VERTEX_SHADER, VERT));
    gl.attachShader(pr, compile(gl, gl.FRAGMENT_SHADER, code));
    gl.linkProgram(pr);
    if (!gl.getProgramParameter(pr, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(pr));
    return pr;
  };
  let prog = build({ MAX_LIGHTS: 8 });
  gl.useProgram(prog);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);

  // the SH volumes of the fixture grid: coeffs (D, H, W, 4, 3) -> one RGBA32F 3D texture per channel
  const s = fx.sh;
  const [W, H, D] = s.grid.counts;
  ['uShR', 'uShG', 'uShB'].forEach((name, ch) => {
    const data = new Float32Array(W * H * D * 4);
    for (let p = 0; p < W * H * D; p++) for (let q = 0; q < 4; q++) data[p * 4 + q] = s.coeffs[(p * 4 + q) * 3 + ch];
    const t = gl.createTexture();
    gl.activeTexture(gl.TEXTURE1 + ch);
    gl.bindTexture(gl.TEXTURE_3D, t);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA32F, W, H, D, 0, gl.RGBA, gl.FLOAT, data);
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR], [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
      [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_R, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_3D, k, v);
    gl.uniform1i(gl.getUniformLocation(prog, name), 1 + ch);
  });
  // the L2 fixture volume: 7·(D + 2) slices of RGBA32F (fx.sh_l2.coeffs packed as workers/kernels/sh.py sh_l2_atlas)
  const l2 = fx.sh_l2;
  let l2Data = null;
  if (l2) {
    const slices = D + 2;
    const data = l2Data = new Float32Array(W * H * 7 * slices * 4);
    for (let k = 0; k < D; k++) for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
      const p = (k * H + j) * W + i;
      for (let q = 0; q < 27; q++) {
        const t = Math.floor(q / 4);
        for (const z of [k + 1, ...(k === 0 ? [0] : []), ...(k === D - 1 ? [D + 1] : [])]) {
          data[(((t * slices + z) * H + j) * W + i) * 4 + (q % 4)] = l2.coeffs[p * 27 + q];
        }
      }
    }
    const t = gl.createTexture();
    gl.activeTexture(gl.TEXTURE4);
    gl.bindTexture(gl.TEXTURE_3D, t);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA32F, W, H, 7 * slices, 0, gl.RGBA, gl.FLOAT, data);
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR], [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
      [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_R, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_3D, k, v);
    gl.uniform1i(gl.getUniformLocation(prog, 'uShL2'), 4);
  }
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridOrigin'), s.grid.origin);
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridSpacing'), s.grid.spacing);
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridCounts'), s.grid.counts);
  gl.uniform1i(gl.getUniformLocation(prog, 'uIn'), 0);
  // probe_grid.glsl's layers (R32F NEAREST, max(counts) x 3, texelFetch): a uniform grid's 1 x 3 dummy, as the renderer
  const setLayers = (layers) => {
    const width = layers ? Math.max(1, ...layers.map((L) => L.length)) : 1;
    const data = new Float32Array(width * 3);
    if (layers) layers.forEach((L, a) => data.set(L, a * width));
    const t = gl.createTexture();
    gl.activeTexture(gl.TEXTURE5);
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.R32F, width, 3, 0, gl.RED, gl.FLOAT, data);
    for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.NEAREST], [gl.TEXTURE_MAG_FILTER, gl.NEAREST], [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE],
      [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_2D, k, v);
    gl.uniform1i(gl.getUniformLocation(prog, 'uGridLayers'), 5);
    gl.uniform1i(gl.getUniformLocation(prog, 'uGridRectilinear'), layers ? 1 : 0);
  };
  setLayers(null);

  const run = (test, rows) => {  // rows: array of 4 arrays of N vec4s
    const n = rows[0].length;
    const input = new Float32Array(n * 4 * 4);
    rows.forEach((row, r) => row.forEach((v, i) => input.set([v[0] ?? 0, v[1] ?? 0, v[2] ?? 0, v[3] ?? 0], (r * n + i) * 4)));
    const tin = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, tin);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, n, 4, 0, gl.RGBA, gl.FLOAT, input);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    const tout = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tout);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, n, 1, 0, gl.RGBA, gl.FLOAT, null);
    const fb = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tout, 0);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, tin);
    gl.viewport(0, 0, n, 1);
    gl.uniform1i(gl.getUniformLocation(prog, 'uTest'), test);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    const out = new Float32Array(n * 4);
    gl.readPixels(0, 0, n, 1, gl.RGBA, gl.FLOAT, out);
    return Array.from({ length: n }, (_, i) => Array.from(out.subarray(i * 4, i * 4 + 4)));
  };

  // 0: per probe and normal, the probe's own coefficients (no filtering)
  const cases = [[], [], [], []];
  for (let p = 0; p < W * H * D; p++) {
    const ch = [0, 1, 2].map((c) => [0, 1, 2, 3].map((q) => s.coeffs[(p * 4 + q) * 3 + c]));
    for (const n of s.normals) { cases[0].push(ch[0]); cases[1].push(ch[1]); cases[2].push(ch[2]); cases[3].push(n); }
  }
  const sh = run(0, cases).map((v) => v.slice(0, 3));          // shIrradianceL1: the non-linear default
  const shLinear = run(4, cases).map((v) => v.slice(0, 3));    // the linear evaluation
  // 1: hardware trilinear at world points, then irradiance per normal
  const tri = [[], [], [], []];
  for (const smp of s.samples) for (const n of s.normals) { tri[0].push(smp.p); tri[1].push(n); tri[2].push([]); tri[3].push([]); }
  const trilinear = run(1, tri).map((v) => v.slice(0, 3));
  // 5, 6: L2 per probe and normal (texelFetch), and at world points (trilinear through the padded stack)
  let shL2 = [], shL2Trilinear = [];
  if (l2) {
    const c5 = [[], [], [], []];
    for (let k = 0; k < D; k++) for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
      for (const n of l2.normals) { c5[0].push([i, j, k]); c5[1].push(n); c5[2].push([]); c5[3].push([]); }
    }
    shL2 = run(5, c5).map((v) => v.slice(0, 3));
    const c6 = [[], [], [], []];
    for (const smp of l2.samples) for (const n of l2.normals) { c6[0].push(smp.p); c6[1].push(n); c6[2].push([]); c6[3].push([]); }
    shL2Trilinear = run(6, c6).map((v) => v.slice(0, 3));
  }
  const o = fx.octahedral;
  const enc = run(2, [o.dirs, o.dirs.map(() => []), o.dirs.map(() => []), o.dirs.map(() => [])]).map((v) => v.slice(0, 2));
  const dec = run(3, [o.uv, o.uv.map(() => []), o.uv.map(() => []), o.uv.map(() => [])]).map((v) => v.slice(0, 3));
  // a rectilinear grid over the fixture's counts: GLSL giGridIndex, probeGridUVW, giProbeTexel and the L2 lookup (7
  // trilinear fetches at the layer coordinate) against the JS mirror (math/sh.js), at the probes (index exactly
  // integer), at points between layers and past the outer layers (the index extrapolates linearly, the texel clamps)
  prog = build({ MAX_LIGHTS: 8, KILN_GRID_RECTILINEAR: true });   // the same textures on the same units
  gl.useProgram(prog);
  ['uShR', 'uShG', 'uShB'].forEach((name, ch) => gl.uniform1i(gl.getUniformLocation(prog, name), 1 + ch));
  if (l2) gl.uniform1i(gl.getUniformLocation(prog, 'uShL2'), 4);
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridOrigin'), s.grid.origin);
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridCounts'), s.grid.counts);
  gl.uniform1i(gl.getUniformLocation(prog, 'uIn'), 0);
  const layers = parityLayers(s.grid);
  const rgrid = { ...s.grid, layers, spacing: layers.map((L, a) => (L.length > 1 ? (L[L.length - 1] - L[0]) / (L.length - 1) : s.grid.spacing[a])) };
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridSpacing'), rgrid.spacing);
  setLayers(layers);
  const points = [];
  for (let k = 0; k < D; k++) for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) points.push([layers[0][i], layers[1][j], layers[2][k]]);
  for (let m = 0; m < 24; m++) {
    points.push(layers.map((L, a) => L[0] + (-0.35 + 1.7 * ((m * 0.6180339887 + 0.37 * a + 0.05) % 1)) * (L[L.length - 1] - L[0])));
  }
  const rows = (pts) => [pts, pts.map(() => []), pts.map(() => []), pts.map(() => [])];
  const rectilinear = {
    layers, points,
    gridIndex: { glsl: run(7, rows(points)).map((v) => v.slice(0, 3)), js: points.map((p) => gridIndex(p, rgrid)) },
    uvw: { glsl: run(8, rows(points)).map((v) => v.slice(0, 3)), js: points.map((p) => probeGridUVW(p, rgrid)) },
    texel: { glsl: run(9, rows(points)).map((v) => v.slice(0, 3)), js: points.map((p) => probeTexel(p, rgrid)) },
    shL2Trilinear: { glsl: [], js: [] },
  };
  if (l2) {
    const volume = { width: W, height: H, depth: 7 * (D + 2), components: 4, data: l2Data };
    const c7 = [[], [], [], []];
    for (const p of points) for (const n of l2.normals) { c7[0].push(p); c7[1].push(n); c7[2].push([]); c7[3].push([]); }
    rectilinear.shL2Trilinear.glsl = run(6, c7).map((v) => v.slice(0, 3));
    rectilinear.shL2Trilinear.js = points.flatMap((p) => { const c = sampleShL2(volume, p, rgrid); return l2.normals.map((n) => shIrradianceL2(c, n)); });
  }
  setLayers(null);
  gl.uniform3fv(gl.getUniformLocation(prog, 'uGridSpacing'), s.grid.spacing);
  const dbg = gl.getExtension('WEBGL_debug_renderer_info');
  const renderer = dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return { sh, shLinear, trilinear, shL2, shL2Trilinear, octEncode: enc, octDecode: dec, rectilinear, renderer };
}
