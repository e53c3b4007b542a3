// @kiln/three (web/kiln-three): the pure parts — the Kiln grid -> three.js LightProbeGrid mapping (box, resolution,
// padding), the stacking of volumes, and the GLSL handed to three's onBeforeCompile.
import { describe, expect, it } from 'vitest';
import { DataUtils } from 'three';
import { cellSize, frameMatrix, isIdentityFrame, padShL2, probeGridBox, resampleShL2, shRotationL2, threeTexelCoord, SH_L2_TEXELS } from '../kiln-three/src/grid.js';
import { GLSL_SOURCES } from '../src/renderer/shaders.js';
import { KilnBundle } from '../kiln-three/src/bundle.js';
import { IRRADIANCE_HOOK, modeGLSL, stackRecords } from '../kiln-three/src/gi.js';

const GRID = { origin: [-0.54, -0.25, 0.1], spacing: [1.0164, 0.75, 0.5], counts: [10, 5, 6] };

function rng(seed) {
  let s = seed >>> 0;
  return () => { s = (s * 1664525 + 1013904223) >>> 0; return s / 2 ** 32; };
}

/** An sh_l2-layout atlas whose value encodes (sub-volume, probe, channel), padding slices copied as Kiln writes them. */
function atlas(counts) {
  const [nx, ny, nz] = counts;
  const data = new Float32Array(SH_L2_TEXELS * (nz + 2) * ny * nx * 4);
  for (let s = 0; s < SH_L2_TEXELS; s++) {
    for (let z = 0; z < nz + 2; z++) {
      const k = Math.min(nz - 1, Math.max(0, z - 1));
      for (let j = 0; j < ny; j++) {
        for (let i = 0; i < nx; i++) {
          for (let c = 0; c < 4; c++) data[((((s * (nz + 2) + z) * ny + j) * nx + i) * 4) + c] = 1000 * s + 100 * k + 10 * j + i + c / 10;
        }
      }
    }
  }
  return data;
}

/** GL LINEAR sampling with CLAMP_TO_EDGE of channel 0 of an RGBA 3D texture at texel coordinate t (centres at +0.5). */
function trilinear(data, [W, H, D], t) {
  const idx = [0, 1, 2].map((a) => t[a] - 0.5);
  const dim = [W, H, D];
  const lo = idx.map((x, a) => Math.floor(x));
  const f = idx.map((x, a) => x - lo[a]);
  const at = (a, v) => Math.min(dim[a] - 1, Math.max(0, v));
  let out = 0;
  for (let c = 0; c < 8; c++) {
    const o = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
    const w = o.reduce((acc, b, a) => acc * (b ? f[a] : 1 - f[a]), 1);
    const [x, y, z] = o.map((b, a) => at(a, lo[a] + b));
    out += w * data[((z * H + y) * W + x) * 4];
  }
  return out;
}

/** three's lightprobes_pars_fragment lookup of sub-volume s (its uvw clamp and atlas z, without the normal offset). */
function threeSample(data, box, p, s) {
  const [nx, ny, nz] = box.resolution;
  const uvw = p.map((x, a) => Math.min(1 - 0.5 / box.resolution[a], Math.max(0.5 / box.resolution[a], (x - box.min[a]) / box.size[a])));
  const depth = SH_L2_TEXELS * (nz + 2);
  const z = ((uvw[2] * nz + 1 + s * (nz + 2)) / depth) * depth;
  return trilinear(data, [nx, ny, depth], [uvw[0] * nx, uvw[1] * ny, z]);
}

/** Kiln's gi_grid.glsl lookup (giProbeTexel + giPaddedStackedUVW) of sub-volume s in the atlas as stored. */
function kilnSample(data, grid, p, s) {
  const [nx, ny, nz] = grid.counts;
  const t = p.map((x, a) => Math.min(grid.counts[a] - 0.5, Math.max(0.5, (x - grid.origin[a]) / grid.spacing[a] + 0.5)));
  return trilinear(data, [nx, ny, SH_L2_TEXELS * (nz + 2)], [t[0], t[1], t[2] + 1 + s * (nz + 2)]);
}

describe('probeGridBox', () => {
  it('puts the Kiln probes at the centres of three\'s cells', () => {
    const box = probeGridBox(GRID);
    expect(box.resolution).toEqual([10, 5, 6]);
    for (let a = 0; a < 3; a++) {
      expect(box.min[a]).toBeCloseTo(GRID.origin[a] - GRID.spacing[a] / 2, 12);
      expect(box.max[a]).toBeCloseTo(GRID.origin[a] + GRID.spacing[a] * (GRID.counts[a] - 0.5), 12);
      expect(box.size[a] / box.resolution[a]).toBeCloseTo(GRID.spacing[a], 12);   // three's probeSpacing
      expect(box.center[a]).toBeCloseTo((box.min[a] + box.max[a]) / 2, 12);
    }
  });

  it('gives three the texel coordinate Kiln computes, padded or not', () => {
    const r = rng(7);
    for (const pad of [0, 1, 2]) {
      const box = probeGridBox(GRID, pad);
      expect(box.resolution).toEqual(GRID.counts.map((n) => n + 2 * pad));
      for (let n = 0; n < 50; n++) {
        const p = GRID.origin.map((o, a) => o + (r() * 1.4 - 0.2) * GRID.spacing[a] * GRID.counts[a]);
        const t = threeTexelCoord(box, p);
        p.forEach((x, a) => expect(t[a]).toBeCloseTo((x - GRID.origin[a]) / GRID.spacing[a] + 0.5 + pad, 9));
      }
    }
  });

  it('keeps a one-probe axis finite', () => {
    const g = { origin: [0, 1, 0], spacing: [0.5, 0, 0.25], counts: [4, 1, 3] };
    expect(cellSize(g)).toEqual([0.5, 0.5, 0.25]);
    const box = probeGridBox(g);
    expect(box.size.every((x) => x > 0 && Number.isFinite(x))).toBe(true);
    expect(box.min[1]).toBeCloseTo(0.75, 12);
    expect(box.max[1]).toBeCloseTo(1.25, 12);
    expect(cellSize({ origin: [0, 0, 0], spacing: [0, 0, 0], counts: [1, 1, 1] })).toEqual([1, 1, 1]);
  });

  it('refuses malformed grids', () => {
    expect(() => probeGridBox({ ...GRID, counts: [10, 0, 6] })).toThrow(RangeError);
    expect(() => probeGridBox({ ...GRID, origin: [0, NaN, 0] })).toThrow(RangeError);
    expect(() => probeGridBox({ ...GRID, spacing: [1, 1] })).toThrow(RangeError);
  });
});

describe('padShL2', () => {
  const counts = [4, 3, 5];
  const src = atlas(counts);

  it('adds border copies and keeps the layout', () => {
    const { data, counts: c, depth } = padShL2(src, counts, 1);
    expect(c).toEqual([6, 5, 7]);
    expect(depth).toBe(SH_L2_TEXELS * 9);
    expect(data).toBeInstanceOf(Float32Array);
    const [mx, my, mz] = c;
    const get = (s, z, y, x) => data[(((s * (mz + 2) + z) * my + y) * mx + x) * 4];
    expect(get(0, 1, 0, 0)).toBe(0);                  // padded corner = probe (0, 0, 0)
    expect(get(3, 2, 1, 1)).toBe(3000);               // first interior probe of sub-volume 3
    expect(get(6, mz, my - 1, mx - 1)).toBe(6000 + 100 * 4 + 10 * 2 + 3);   // last probe
    expect(get(2, 0, 2, 3)).toBe(get(2, 1, 2, 3));    // the sub-volume's own padding slices
    expect(get(2, mz + 1, 2, 3)).toBe(get(2, mz, 2, 3));
  });

  it('keeps half-float bits as they are', () => {
    const half = Uint16Array.from(src, (x) => x % 65536);
    const out = padShL2(half, counts, 2).data;
    expect(out).toBeInstanceOf(Uint16Array);
    expect(out.length).toBe(SH_L2_TEXELS * (5 + 4 + 2) * (3 + 4) * (4 + 4) * 4);
  });

  it('makes three\'s lookup equal Kiln\'s clamped lookup up to a cell outside the probes', () => {
    const g = { origin: [0.3, -0.2, 1.0], spacing: [0.8, 0.6, 0.5], counts };
    const { data } = padShL2(src, counts, 1);
    const box = probeGridBox(g, 1);
    const plain = probeGridBox(g, 0);
    const r = rng(3);
    let outside = 0;
    for (let n = 0; n < 200; n++) {
      const p = g.origin.map((o, a) => o + (r() * (counts[a] + 1) - 1) * g.spacing[a]);   // probes' box ± 1 cell
      const s = n % SH_L2_TEXELS;
      expect(threeSample(data, box, p, s)).toBeCloseTo(kilnSample(src, g, p, s), 6);
      if (p.some((x, a) => x < plain.min[a] || x > plain.max[a])) outside += 1;
    }
    expect(outside).toBeGreaterThan(20);   // the test reached points the unpadded box leaves unlit
    // unpadded, inside the probes' box: the same
    const q = [0.9, 0.4, 1.7];
    expect(threeSample(src, plain, q, 4)).toBeCloseTo(kilnSample(src, g, q, 4), 6);
  });

  it('refuses an atlas of the wrong size', () => {
    expect(() => padShL2(src.subarray(4), counts)).toThrow(RangeError);
  });
});

describe('material extension', () => {
  it('hands three the mode\'s proto/glsl without a version line, view direction first', () => {
    const code = modeGLSL('mode_mask_normalized.glsl', { KILN_SH_L2: true, KILN_MASK_CLUSTERS: 4 });
    expect(code).not.toMatch(/^\s*#\s*version/m);
    expect(code).toMatch(/#define KILN_SH_L2/);
    expect(code).toMatch(/#define KILN_MASK_CLUSTERS 4/);
    expect(code.match(/vec3 giViewDir =/g)).toHaveLength(1);
    expect(code.indexOf('vec3 giViewDir')).toBeLessThan(code.indexOf('vec3 giIndirectIrradiance('));
    expect(modeGLSL('mode_leaking.glsl', { KILN_SH_L2: true })).toMatch(/vec3 giViewDir =/);  // leaking lacks gi_view
    expect(IRRADIANCE_HOOK).toMatch(/irradiance \+= uKilnIndirectScale \* giIndirectIrradiance/);
  });

  it('turns p, n and the view direction into the bake frame: uGiFrame declared exactly once', () => {
    expect(IRRADIANCE_HOOK).toMatch(/giViewDir = uGiFrame \* normalize\( cameraPosition - kilnP \)/);
    expect(IRRADIANCE_HOOK).toMatch(/giIndirectIrradiance\( uGiFrame \* kilnP, uGiFrame \* kilnN \)/);
    const decl = /uniform\s+mat3\s+uGiFrame\s*;/g;
    for (const file of ['mode_leaking.glsl', 'mode_ddgi.glsl', 'mode_mask.glsl', 'mode_mask_normalized.glsl']) {
      expect(modeGLSL(file, { KILN_SH_L2: true }).match(decl)).toHaveLength(1);
    }
    // once the shared gi_view.glsl declares it, the extension adds no second declaration
    const shared = GLSL_SOURCES['gi_view.glsl'];
    try {
      GLSL_SOURCES['gi_view.glsl'] = `uniform mat3 uGiFrame;\n${shared.replace(/uniform\s+mat3\s+uGiFrame\s*;/, '')}`;
      expect(modeGLSL('mode_ddgi.glsl', { KILN_SH_L2: true }).match(decl)).toHaveLength(1);
    } finally {
      GLSL_SOURCES['gi_view.glsl'] = shared;
    }
  });

  it('stacks volumes along z as gi_grid.glsl giStackedUVW reads them', () => {
    const v = (x) => ({ kind: 'half', components: 4, width: 2, height: 1, depth: 1, is3D: true, data: new Uint16Array(8).fill(x) });
    const s = stackRecords([v(1), v(2), v(3)]);
    expect(s.depth).toBe(3);
    expect(s.data).toBeInstanceOf(Uint16Array);
    expect(Array.from(s.data.subarray(8, 16))).toEqual(Array(8).fill(2));
    expect(() => stackRecords([v(1), { ...v(2), width: 3 }])).toThrow();
  });
});

describe('bake frame (grid.frame)', () => {
  const ry = (deg) => {   // R_y(θ): bake -> world
    const t = (deg * Math.PI) / 180;
    return [[Math.cos(t), 0, Math.sin(t)], [0, 1, 0], [-Math.sin(t), 0, Math.cos(t)]];
  };
  const T = (m) => m[0].map((_, j) => m.map((r) => r[j]));
  const mul = (m, v) => m.map((r) => r[0] * v[0] + r[1] * v[1] + r[2] * v[2]);

  it('is the identity without a frame (every bundle before it)', () => {
    expect(isIdentityFrame(frameMatrix(GRID))).toBe(true);
    expect(isIdentityFrame(frameMatrix({ ...GRID, frame: { yaw_deg: 0, matrix: ry(0), source: 'none' } }))).toBe(true);
  });

  it('reads the row-major world -> bake matrix R_y(θ)ᵀ, or builds it from yaw_deg', () => {
    const M = T(ry(30));
    const m = frameMatrix({ ...GRID, frame: { yaw_deg: 30, matrix: M, source: 'walls' } });
    expect(isIdentityFrame(m)).toBe(false);
    const pBake = [1.5, 0.7, -2.25];
    const pWorld = mul(ry(30), pBake);
    mul(m, pWorld).forEach((x, i) => expect(x).toBeCloseTo(pBake[i], 12));
    frameMatrix({ ...GRID, frame: { yaw_deg: 30 } }).flat().forEach((x, i) => expect(x).toBeCloseTo(M.flat()[i], 12));
  });

  it('comes from the place stage\'s stats of a bake on a Kiln server (KilnBundle.fromServer)', async () => {
    const frame = { yaw_deg: 30, matrix: T(ry(30)), source: 'walls', reason: 'test' };
    const bake = { id: 'b1', status: 'succeeded', config: {}, artifacts: [],
      stages: [{ name: 'place', stats: { ...GRID, frame } }, { name: 'ingest', stats: { bounds: [[0, 0, 0], [1, 1, 1]] } }] };
    const seen = [];
    const fetch = async (url) => { seen.push(url); return { ok: true, status: 200, json: async () => bake }; };
    const b = await KilnBundle.fromServer('http://kiln.test/', 'b1', { fetch });
    expect(seen).toEqual(['http://kiln.test/v1/bakes/b1']);
    expect(b.grid.frame).toEqual(frame);
    expect(isIdentityFrame(frameMatrix(b.grid))).toBe(false);
    bake.stages[0].stats = { ...GRID };   // a bake from before the frame: no grid.frame, the identity
    const old = await KilnBundle.fromServer('http://kiln.test/', 'b1', { fetch });
    expect(old.grid.frame).toBeUndefined();
    expect(isIdentityFrame(frameMatrix(old.grid))).toBe(true);
  });

  it('refuses a matrix that is not R_y(yaw)ᵀ, not a rotation, or not 3 x 3', () => {
    expect(() => frameMatrix({ ...GRID, frame: { yaw_deg: 30, matrix: ry(30) } })).toThrow(/not R_y/);   // transposed
    expect(() => frameMatrix({ ...GRID, frame: { matrix: [[-1, 0, 0], [0, 1, 0], [0, 0, 1]] } })).toThrow(/reflection/);
    expect(() => frameMatrix({ ...GRID, frame: { matrix: [[2, 0, 0], [0, 1, 0], [0, 0, 1]] } })).toThrow(/not a rotation/);
    expect(() => frameMatrix({ ...GRID, frame: { matrix: [[1, 0], [0, 1]] } })).toThrow(RangeError);
  });
});

describe('a turned bake resampled for three\'s LightProbeGrid (resampleShL2)', () => {
  const yaw = (deg) => {   // M = R_y(θ)ᵀ, world -> bake
    const t = (deg * Math.PI) / 180;
    return [[Math.cos(t), 0, -Math.sin(t)], [0, 1, 0], [Math.sin(t), 0, Math.cos(t)]];
  };
  const basis = (x, y, z) => [0.282095, 0.488603 * y, 0.488603 * z, 0.488603 * x, 1.092548 * x * y, 1.092548 * y * z,
    0.315392 * (3 * z * z - 1), 1.092548 * x * z, 0.546274 * (x * x - y * y)];
  const unit = (r) => { const v = [r() - 0.5, r() - 0.5, r() - 0.5]; const n = Math.hypot(...v); return v.map((x) => x / n); };
  const mul = (M, v) => M.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);

  it('turns L2 SH exactly: f_world(d) = f_bake(M·d), an orthogonal 9 x 9 matrix, the identity for no turn', () => {
    const r = rng(11);
    for (const deg of [30, -17.5, 90]) {
      const M = yaw(deg);
      const R = shRotationL2(M);
      const c = [...Array(9)].map(() => r() - 0.5);
      const cw = R.map((row) => row.reduce((acc, x, k) => acc + x * c[k], 0));
      for (let n = 0; n < 20; n++) {
        const d = unit(r);
        const world = basis(...d).reduce((acc, y, k) => acc + y * cw[k], 0);
        const bake = basis(...mul(M, d)).reduce((acc, y, k) => acc + y * c[k], 0);
        expect(world).toBeCloseTo(bake, 9);
      }
      // orthogonal up to the basis constants' 6 digits (three's, rounded)
      R.forEach((a, i) => R.forEach((b, j) => expect(a.reduce((acc, x, k) => acc + x * b[k], 0)).toBeCloseTo(i === j ? 1 : 0, 5)));
    }
    shRotationL2(yaw(0)).forEach((row, i) => row.forEach((x, j) => expect(x).toBeCloseTo(i === j ? 1 : 0, 12)));
  });

  // SH that varies linearly with the bake-frame position: coefficient t of the probe at q is A[t] + B[t]·q
  const g = { origin: [-1.2, 0.1, 0.4], spacing: [0.5, 0.4, 0.45], counts: [9, 5, 8] };
  const r0 = rng(5);
  const A = [...Array(27)].map(() => r0());
  const B = [...Array(27)].map(() => [r0() - 0.5, r0() - 0.5, r0() - 0.5]);
  const field = (q) => A.map((a, t) => a + B[t][0] * q[0] + B[t][1] * q[1] + B[t][2] * q[2]);
  function linearAtlas() {
    const [nx, ny, nz] = g.counts;
    const data = new Float32Array(SH_L2_TEXELS * (nz + 2) * ny * nx * 4);
    for (let z = 0; z < nz + 2; z++) {
      const k = Math.min(nz - 1, Math.max(0, z - 1));
      for (let j = 0; j < ny; j++) {
        for (let i = 0; i < nx; i++) {
          const c = field([0, 1, 2].map((a) => g.origin[a] + [i, j, k][a] * g.spacing[a]));
          for (let t = 0; t < 27; t++) data[((((t >> 2) * (nz + 2) + z) * ny + j) * nx + i) * 4 + (t & 3)] = c[t];
        }
      }
    }
    return data;
  }

  it('gives three\'s lookup Kiln\'s light turned into the world (exact for light linear in space)', () => {
    const M = yaw(30);
    const { data, box, depth } = resampleShL2(linearAtlas(), g, M, 1);
    const [mx, my, mz] = box.resolution;
    expect(data).toBeInstanceOf(Float32Array);
    expect(depth).toBe(SH_L2_TEXELS * (mz + 2));
    expect(data.length).toBe(depth * my * mx * 4);
    expect(Math.min(...box.size.map((x, a) => x / box.resolution[a]))).toBeGreaterThan(0.38);   // about the spacing
    const R = shRotationL2(M);
    const r = rng(9);
    let checked = 0;
    for (let n = 0; n < 400 && checked < 60; n++) {
      // world points whose bake-frame point and every world cell around them lie a cell inside the probes
      const q = g.origin.map((o, a) => o + (1.6 + r() * (g.counts[a] - 4.2)) * g.spacing[a]);
      const p = [0, 1, 2].map((i) => M[0][i] * q[0] + M[1][i] * q[1] + M[2][i] * q[2]);
      const cb = field(q);
      const got = [...Array(27)].map((_, t) => threeSample(data.subarray(t & 3), box, p, t >> 2));
      for (let ch = 0; ch < 3; ch++) {
        for (let k = 0; k < 9; k++) {
          const want = R[k].reduce((acc, x, j) => acc + x * cb[3 * j + ch], 0);
          expect(got[3 * k + ch]).toBeCloseTo(want, 4);
        }
      }
      checked += 1;
    }
    expect(checked).toBe(60);
    // the same atlas put in the world box unturned (what three would read without the resampling) is far off
    const plain = threeSample(padShL2(linearAtlas(), g.counts, 1).data.subarray(3), probeGridBox(g, 1), [0.9, 0.9, 1.9], 0);
    const right = R[1].reduce((acc, x, j) => acc + x * field(mul(M, [0.9, 0.9, 1.9]))[3 * j], 0);
    expect(Math.abs(plain - right)).toBeGreaterThan(0.05);
  });

  it('covers the turned probes and keeps half floats as half floats', () => {
    const M = yaw(-33);
    const half = Uint16Array.from(linearAtlas(), (x) => DataUtils.toHalfFloat(x));
    const { data, box } = resampleShL2(half, g, M, 1);
    expect(data).toBeInstanceOf(Uint16Array);
    for (let c = 0; c < 8; c++) {
      const q = [0, 1, 2].map((a) => g.origin[a] + ((c >> a) & 1) * (g.counts[a] - 1) * g.spacing[a]);
      const p = [0, 1, 2].map((i) => M[0][i] * q[0] + M[1][i] * q[1] + M[2][i] * q[2]);
      p.forEach((x, a) => { expect(x).toBeGreaterThan(box.min[a]); expect(x).toBeLessThan(box.max[a]); });
    }
    expect(() => resampleShL2(half.subarray(4), g, M)).toThrow(RangeError);
  });
});
