// Rectilinear probe grids (manifest grid.layers = [xs, ys, zs], bake-frame metres; proto/glsl/probe_grid.glsl
// giGridIndex): the CPU mirror (math/sh.js gridIndex and what reads it), the uGridLayers texture and its plumbing
// (renderer.js setGrid, @kiln/three gi.js), and three's LightProbeGrid of a rectilinear bake (grid.js: resampled).
import { describe, expect, it } from 'vitest';
import { FloatType, NearestFilter, RedFormat, Vector3 } from 'three';
import {
  gridIndex, gridLayers, gridMinGaps, gridPoint, layerCoord, probeGridUVW, probeTexel, sampleShL2, SH_L2_TEXELS,
} from '../src/math/sh.js';
import { gridLayersTexture } from '../src/renderer/textures.js';
import { GIRenderer } from '../src/renderer/renderer.js';
import { bakeGrid, gridPointWorld } from '../src/view/viewer.js';
import { gridSummary } from '../src/state/stats.js';
import { fitsProbeGrid, padShL2, probeGridBox, resampleShL2 } from '../kiln-three/src/grid.js';
import { KilnGI } from '../kiln-three/src/gi.js';
import { KilnBundle } from '../kiln-three/src/bundle.js';

const UNIFORM = { origin: [-0.54, -0.25, 0.1], spacing: [1.0164, 0.75, 0.5], counts: [10, 5, 6] };
/** A rectilinear grid: uneven gaps on x and z, an even y, spacing the mean gap. */
const LAYERS = [[0, 0.1, 1.0, 2.0], [0.5, 1.0, 1.5], [-1, -0.9, -0.4, 0.6, 0.7]];
const RECT = {
  origin: LAYERS.map((L) => L[0]), counts: LAYERS.map((L) => L.length),
  spacing: LAYERS.map((L) => (L[L.length - 1] - L[0]) / (L.length - 1)), layers: LAYERS,
};

function rng(seed) {
  let s = seed >>> 0;
  return () => { s = (s * 1664525 + 1013904223) >>> 0; return s / 2 ** 32; };
}

describe('gridIndex (probe_grid.glsl giGridIndex)', () => {
  it('is (p − origin)/spacing on a uniform grid, bit for bit', () => {
    const r = rng(1);
    for (let n = 0; n < 50; n++) {
      const p = UNIFORM.origin.map((o, a) => o + (r() * 1.6 - 0.3) * UNIFORM.spacing[a] * UNIFORM.counts[a]);
      const g = gridIndex(p, UNIFORM);
      g.forEach((x, a) => expect(x).toBe((p[a] - UNIFORM.origin[a]) / UNIFORM.spacing[a]));
      probeGridUVW(p, UNIFORM).forEach((x, a) => expect(x).toBe(((p[a] - UNIFORM.origin[a]) / UNIFORM.spacing[a] + 0.5) / UNIFORM.counts[a]));
      expect(gridIndex(p, { ...UNIFORM, layers: null })).toEqual(g);
    }
  });

  it('is the layer coordinate on a rectilinear axis, extrapolated linearly past the outer layers', () => {
    const L = [0, 0.1, 1.0, 2.0];
    expect(layerCoord(0.05, L)).toBeCloseTo(0.5, 12);
    expect(layerCoord(0.55, L)).toBeCloseTo(1.5, 12);
    expect(layerCoord(-0.1, L)).toBeCloseTo(-1, 12);
    expect(layerCoord(2.5, L)).toBeCloseTo(3.5, 12);
    L.forEach((x, i) => expect(layerCoord(x, L)).toBe(i));            // a probe's layer: its index exactly
    const at = (x) => gridIndex([x, 1.0, -0.9], RECT);
    expect(at(0.05)[0]).toBeCloseTo(0.5, 12);
    expect(at(0.55)[0]).toBeCloseTo(1.5, 12);
    expect(at(-0.1)[0]).toBeCloseTo(-1, 12);
    expect(at(2.5)[0]).toBeCloseTo(3.5, 12);
    expect(at(0.55).slice(1)).toEqual([1, 1]);
    // two layers: a uniform axis of that gap
    expect(layerCoord(1.75, [1, 1.5])).toBeCloseTo(1.5, 12);
  });

  it('is 0 on a one-probe axis, rectilinear or not', () => {
    expect(gridIndex([3, 7, -2], { origin: [0, 1, 0], spacing: [0.5, 0, 0.25], counts: [4, 1, 3] })).toEqual([6, 0, -8]);
    const g = { origin: [0, 2, 0], spacing: [0.5, 0, 1], counts: [3, 1, 2], layers: [[0, 0.2, 1], [2], [0, 1]] };
    gridIndex([0.6, 9, 0.25], g).forEach((x, a) => expect(x).toBeCloseTo([1.5, 0, 0.25][a], 12));
    probeGridUVW([0.6, 9, 0.25], g).forEach((x, a) => expect(x).toBeCloseTo([2 / 3, 0.5, 0.375][a], 12));
    expect(gridIndex([0.6, 9, 0.25], g)[1]).toBe(0);
  });

  it('gives probeGridUVW and the clamped probe texel of a rectilinear grid', () => {
    const p = [0.55, 1.25, 0.1];
    const g = gridIndex(p, RECT);
    expect(g[0]).toBeCloseTo(1.5, 12);
    expect(g[1]).toBeCloseTo(1.5, 12);
    expect(g[2]).toBeCloseTo(2.5, 12);          // between -0.4 and 0.6
    probeGridUVW(p, RECT).forEach((x, a) => expect(x).toBeCloseTo((g[a] + 0.5) / RECT.counts[a], 12));
    probeTexel(p, RECT).forEach((x, a) => expect(x).toBeCloseTo(g[a] + 0.5, 12));
    // past the outer layers the index extrapolates, the texel clamps to the border probes' centres
    expect(gridIndex([-0.1, 0, 1.2], RECT).map((x) => +x.toFixed(9))).toEqual([-1, -1, 9]);
    expect(probeTexel([-0.1, 0, 1.2], RECT)).toEqual([0.5, 0.5, 4.5]);
  });

  it('is inverted by gridPoint: the layers at integer indices, piecewise linear between', () => {
    for (let k = 0; k < 5; k++) for (let j = 0; j < 3; j++) for (let i = 0; i < 4; i++) {
      expect(gridPoint(RECT, [i, j, k])).toEqual([LAYERS[0][i], LAYERS[1][j], LAYERS[2][k]]);
      expect(gridIndex(gridPoint(RECT, [i, j, k]), RECT)).toEqual([i, j, k]);
    }
    const r = rng(4);
    for (let n = 0; n < 50; n++) {
      const g = RECT.counts.map((c) => r() * (c + 1) - 1);
      gridIndex(gridPoint(RECT, g), RECT).forEach((x, a) => expect(x).toBeCloseTo(g[a], 10));
    }
    expect(gridPoint(UNIFORM, [2, 1.5, -1])).toEqual([0, 1, 2].map((a) => UNIFORM.origin[a] + UNIFORM.spacing[a] * [2, 1.5, -1][a]));
    expect(gridMinGaps(UNIFORM)).toEqual(UNIFORM.spacing);
    gridMinGaps(RECT).forEach((x, a) => expect(x).toBeCloseTo([0.1, 0.5, 0.1][a], 12));
  });

  it('makes trilinear filtering at the texel coordinate the rectilinear grid\'s trilinear interpolation', () => {
    // an sh_l2 volume whose probes hold a function linear in the bake-frame position: every lookup between the
    // layers reads that function exactly (trilinear between layers reproduces linear functions)
    const [nx, ny, nz] = RECT.counts;
    const f = (q, t) => 0.3 + 0.1 * t + (1 + t) * q[0] - 0.5 * q[1] + (2 - 0.1 * t) * q[2];
    const data = new Float32Array(SH_L2_TEXELS * (nz + 2) * ny * nx * 4);
    for (let z = 0; z < nz + 2; z++) for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
      const k = Math.min(nz - 1, Math.max(0, z - 1));
      const q = gridPoint(RECT, [i, j, k]);
      for (let t = 0; t < 27; t++) data[((((t >> 2) * (nz + 2) + z) * ny + j) * nx + i) * 4 + (t & 3)] = f(q, t);
    }
    const volume = { width: nx, height: ny, depth: SH_L2_TEXELS * (nz + 2), components: 4, data };
    const r = rng(6);
    for (let n = 0; n < 40; n++) {
      const p = LAYERS.map((L) => L[0] + r() * (L[L.length - 1] - L[0]));
      const c = sampleShL2(volume, p, RECT);
      for (let t = 0; t < 27; t++) expect(c[Math.floor(t / 3)][t % 3]).toBeCloseTo(f(p, t), 5);
    }
    // read as a uniform grid of the mean spacing, the same volume is off
    const p = [0.05, 1.0, -0.2];
    expect(Math.abs(sampleShL2(volume, p, { ...RECT, layers: null })[0][0] - f(p, 0))).toBeGreaterThan(0.05);
  });
});

describe('grid layers (manifest grid.layers)', () => {
  it('are checked: three strictly increasing arrays of counts[a] finite numbers; null for a uniform grid', () => {
    expect(gridLayers(UNIFORM)).toBe(null);
    expect(gridLayers({ ...UNIFORM, layers: null })).toBe(null);
    expect(gridLayers(RECT)).toEqual(LAYERS);
    expect(() => gridLayers({ ...RECT, layers: LAYERS.slice(0, 2) })).toThrow(RangeError);
    expect(() => gridLayers({ ...RECT, layers: [LAYERS[0], [0.5, 1.0], LAYERS[2]] })).toThrow(/axis 1 has 2 layers/);
    expect(() => gridLayers({ ...RECT, layers: [[0, 0.1, 0.1, 2], LAYERS[1], LAYERS[2]] })).toThrow(/strictly increasing/);
    expect(() => gridLayers({ ...RECT, layers: [[0, 0.1, NaN, 2], LAYERS[1], LAYERS[2]] })).toThrow(/finite/);
  });

  it('come from the place stage\'s stats into the viewer\'s grid and its world points', () => {
    const bake = (extra) => ({ stages: [{ name: 'place', stats: { counts: RECT.counts, origin: RECT.origin, spacing: RECT.spacing, ...extra } }] });
    const g = bakeGrid(bake({ layers: LAYERS }));
    expect(g.layers).toEqual(LAYERS);
    expect(gridPointWorld(g, [2, 1, 3])).toEqual([1.0, 1.0, 0.6]);
    expect(bakeGrid(bake({})).layers).toBe(null);
    expect(gridPointWorld(bakeGrid(bake({})), [2, 1, 3])).toEqual([0, 1, 2].map((a) => RECT.origin[a] + RECT.spacing[a] * [2, 1, 3][a]));
    expect(gridSummary(bake({ layers: LAYERS }))).toBe('60 probes, 0.10–1.00 m apart (rectilinear layers)');
    expect(gridSummary(bake({}))).toBe('60 probes, 0.67 m apart');
  });

  it('come from a bake on a Kiln server (KilnBundle.fromServer) as grid.layers, absent for a uniform grid', async () => {
    const bake = { id: 'b1', status: 'succeeded', config: {}, artifacts: [],
      stages: [{ name: 'place', stats: { ...RECT } }, { name: 'ingest', stats: { bounds: [[0, 0, 0], [1, 1, 1]] } }] };
    const fetch = async () => ({ ok: true, status: 200, json: async () => bake });
    expect((await KilnBundle.fromServer('http://kiln.test/', 'b1', { fetch })).grid.layers).toEqual(LAYERS);
    bake.stages[0].stats = { ...UNIFORM };
    expect('layers' in (await KilnBundle.fromServer('http://kiln.test/', 'b1', { fetch })).grid).toBe(false);
  });
});

describe('uGridLayers (probe_grid.glsl: R32F, max(counts) x 3, NEAREST, texelFetch)', () => {
  it('holds layer i of axis a at texel (i, a); a 1 x 3 dummy for a uniform grid', () => {
    const t = gridLayersTexture(LAYERS);
    expect([t.image.width, t.image.height]).toEqual([5, 3]);
    expect([t.format, t.type, t.minFilter, t.magFilter, t.generateMipmaps]).toEqual([RedFormat, FloatType, NearestFilter, NearestFilter, false]);
    expect(t.image.data).toBeInstanceOf(Float32Array);
    expect(Array.from(t.image.data)).toEqual([0, 0.1, 1.0, 2.0, 0, 0.5, 1.0, 1.5, 0, 0, -1, -0.9, -0.4, 0.6, 0.7].map(Math.fround));
    const d = gridLayersTexture(null);
    expect([d.image.width, d.image.height, d.format, d.type, d.minFilter]).toEqual([1, 3, RedFormat, FloatType, NearestFilter]);
  });

  it('is set with uGridRectilinear by the viewer\'s renderer (setGrid), the old texture disposed', () => {
    const dummy = gridLayersTexture(null);
    let disposed = 0;
    dummy.addEventListener('dispose', () => { disposed += 1; });
    const r = { shared: { uGridOrigin: { value: new Vector3() }, uGridSpacing: { value: new Vector3() }, uGridCounts: { value: new Vector3() },
      uGridRectilinear: { value: false }, uGridLayers: { value: dummy } } };
    GIRenderer.prototype.setGrid.call(r, RECT);
    expect(disposed).toBe(1);
    expect(r.shared.uGridRectilinear.value).toBe(true);
    expect(r.shared.uGridLayers.value.image.width).toBe(5);
    expect(r.shared.uGridLayers.value.image.data[2 * 5 + 3]).toBe(Math.fround(0.6));
    expect(r.shared.uGridSpacing.value.toArray()).toEqual(RECT.spacing);
    GIRenderer.prototype.setGrid.call(r, UNIFORM);
    expect(r.shared.uGridRectilinear.value).toBe(false);
    expect(r.shared.uGridLayers.value.image.width).toBe(1);
    expect(r.shared.uGridOrigin.value.toArray()).toEqual(UNIFORM.origin);
    expect(() => GIRenderer.prototype.setGrid.call(r, { ...RECT, layers: [[0], [0], [0]] })).toThrow(RangeError);
  });

  it('is one of @kiln/three\'s uniforms (KilnGI), which resamples a rectilinear bake for three\'s LightProbeGrid', () => {
    const renderer = { getContext: () => ({ getParameter: () => 0 }), extensions: { has: () => true } };
    const gi = (grid) => new KilnGI({ grid, names: [] }, renderer);
    const rect = gi(RECT);
    expect(rect.uniforms.uGridRectilinear.value).toBe(true);
    expect(rect.uniforms.uGridLayers.value.image.width).toBe(5);
    expect(rect.uniforms.uGridLayers.value.image.data[4]).toBe(0);   // the rest of row 0 (x has 4 layers)
    expect([rect.probeGridFits, rect.probeGridResampled]).toEqual([false, true]);
    const plain = gi(UNIFORM);
    expect(plain.uniforms.uGridRectilinear.value).toBe(false);
    expect(plain.uniforms.uGridLayers.value.image.width).toBe(1);
    expect([plain.probeGridFits, plain.probeGridResampled]).toEqual([true, false]);
  });
});

describe('three\'s LightProbeGrid of a rectilinear bake (grid.js)', () => {
  it('fits a uniform unturned grid only', () => {
    expect(fitsProbeGrid(UNIFORM)).toBe(true);
    expect(fitsProbeGrid({ ...UNIFORM, layers: null })).toBe(true);
    expect(fitsProbeGrid(RECT)).toBe(false);
    expect(fitsProbeGrid({ ...UNIFORM, frame: { yaw_deg: 30 } })).toBe(false);
    expect(fitsProbeGrid({ ...UNIFORM, frame: { yaw_deg: 0 } })).toBe(true);
  });

  /** three's lightprobes_pars_fragment lookup of sub-volume s (its uvw clamp and atlas z, no normal offset), channel 0. */
  function threeSample(data, box, p, s) {
    const [nx, ny, nz] = box.resolution;
    const uvw = p.map((x, a) => Math.min(1 - 0.5 / box.resolution[a], Math.max(0.5 / box.resolution[a], (x - box.min[a]) / box.size[a])));
    const D = SH_L2_TEXELS * (nz + 2);
    const t = [uvw[0] * nx - 0.5, uvw[1] * ny - 0.5, uvw[2] * nz + 1 + s * (nz + 2) - 0.5];
    const lo = t.map(Math.floor);
    const dims = [nx, ny, D];
    let out = 0;
    for (let c = 0; c < 8; c++) {
      const o = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
      const w = o.reduce((acc, b, a) => acc * (b ? t[a] - lo[a] : 1 - (t[a] - lo[a])), 1);
      const [x, y, z] = o.map((b, a) => Math.min(dims[a] - 1, Math.max(0, lo[a] + b)));
      out += w * data[((z * ny + y) * nx + x) * 4];
    }
    return out;
  }

  it('resamples onto world cells so three reads Kiln\'s rectilinear lookup (exact for light linear in space)', () => {
    const g = { origin: [-1, 0, 0.5], counts: [6, 4, 5], layers: [[-1, -0.9, -0.3, 0.6, 1.5, 1.6], [0, 0.2, 1.2, 1.5], [0.5, 0.6, 1.4, 2.3, 2.5]] };
    g.spacing = g.layers.map((L) => (L[L.length - 1] - L[0]) / (L.length - 1));
    const [nx, ny, nz] = g.counts;
    const r0 = rng(8);
    const A = [...Array(27)].map(() => r0());
    const B = [...Array(27)].map(() => [r0() - 0.5, r0() - 0.5, r0() - 0.5]);
    const field = (q) => A.map((a, t) => a + B[t][0] * q[0] + B[t][1] * q[1] + B[t][2] * q[2]);
    const src = new Float32Array(SH_L2_TEXELS * (nz + 2) * ny * nx * 4);
    for (let z = 0; z < nz + 2; z++) for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
      const c = field(gridPoint(g, [i, j, Math.min(nz - 1, Math.max(0, z - 1))]));
      for (let t = 0; t < 27; t++) src[((((t >> 2) * (nz + 2) + z) * ny + j) * nx + i) * 4 + (t & 3)] = c[t];
    }
    const I = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    const { data, box } = resampleShL2(src, g, I, 1);
    // the box: the outer layers ± (pad + ½) mean spacings; cells about the mean spacing
    for (let a = 0; a < 3; a++) {
      expect(box.min[a]).toBeCloseTo(g.layers[a][0] - 1.5 * g.spacing[a], 12);
      expect(box.max[a]).toBeCloseTo(g.layers[a][g.counts[a] - 1] + 1.5 * g.spacing[a], 12);
    }
    const r = rng(2);
    let worst = 0, worstPlain = 0;
    const padded = padShL2(src, g.counts, 1).data;
    for (let n = 0; n < 60; n++) {
      // a cell inside the outer layers (three's world cells there all lie between Kiln's outer probes)
      const p = g.layers.map((L) => L[0] + (0.25 + 0.5 * r()) * (L[L.length - 1] - L[0]));
      const want = field(p);
      for (let t = 0; t < 27; t += 4) {
        worst = Math.max(worst, Math.abs(threeSample(data.subarray(t & 3), box, p, t >> 2) - want[t]));
        worstPlain = Math.max(worstPlain, Math.abs(threeSample(padded.subarray(t & 3), probeGridBox(g, 1), p, t >> 2) - want[t]));
      }
    }
    expect(worst).toBeLessThan(1e-4);
    // the atlas as stored in the uniform box of the mean spacing (what three would read without resampling): off
    expect(worstPlain).toBeGreaterThan(0.02);
  });

  it('resamples an unturned grid whose layers are uniform onto its own probes (the padded atlas, as if uniform)', () => {
    const g = { origin: [-0.5, 0.25, 1], spacing: [0.75, 0.5, 0.6], counts: [5, 3, 4] };
    const layered = { ...g, layers: [0, 1, 2].map((a) => Array.from({ length: g.counts[a] }, (_, i) => g.origin[a] + g.spacing[a] * i)) };
    const [nx, ny, nz] = g.counts;
    // 27 coefficients per probe and a 0 (the 28th number, channel w of the last sub-volume), as Kiln writes them
    const perSub = (nz + 2) * ny * nx * 4;
    const src = new Float32Array(SH_L2_TEXELS * perSub).map((_, i) => (i >= 6 * perSub && i % 4 === 3 ? 0 : Math.sin(i * 0.37) + 1));
    for (let s = 0; s < SH_L2_TEXELS; s++) {        // padding slices: copies of the nearest data slice
      for (const [z, from] of [[0, 1], [nz + 1, nz]]) {
        const at = (zz) => ((s * (nz + 2) + zz) * ny) * nx * 4;
        src.copyWithin(at(z), at(from), at(from) + ny * nx * 4);
      }
    }
    const I = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    const { data, box } = resampleShL2(src, layered, I, 1);
    const want = padShL2(src, g.counts, 1).data;
    const plain = probeGridBox(g, 1);
    expect(box.resolution).toEqual(plain.resolution);
    box.min.forEach((x, a) => expect(x).toBeCloseTo(plain.min[a], 12));
    box.size.forEach((x, a) => expect(x).toBeCloseTo(plain.size[a], 12));
    expect(data.length).toBe(want.length);
    const worst = want.reduce((m, x, n) => Math.max(m, Math.abs(data[n] - x)), 0);
    expect(worst).toBeLessThan(1e-5);
  });
});
