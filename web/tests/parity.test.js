// Cross-language parity: the JS KTX2 loader and the SH / octahedral math decode proto/fixtures (written by
// tests/proto/make_fixtures.py from the Python kernels) to the same numbers.
import { describe, expect, it } from 'vitest';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { parseKTX2, tableFromKTX2, texelsAsNumbers } from '../src/loader/ktx2.js';
import {
  probeGridUVW, sampleShL2, sampleVolumeTrilinear, shIrradianceL1, shIrradianceL1Nonlinear, shIrradianceL2, shL2Unpack,
} from '../src/math/sh.js';
import { atlasTexel, octDecode, octEncode, octTexelDirection } from '../src/math/octahedral.js';

const FIX = fileURLToPath(new URL('../../proto/fixtures/', import.meta.url));
const expected = JSON.parse(readFileSync(FIX + 'expected.json', 'utf8'));
const load = (f) => parseKTX2(new Uint8Array(readFileSync(FIX + f)));
const f32 = Math.fround;

describe('KTX2 loader on the Python-written fixtures', () => {
  for (const v of expected.volumes) {
    it(`decodes ${v.file} (${v.format})`, () => {
      const tex = load(v.file);
      expect(tex.format).toBe(v.format);
      expect([tex.width, tex.height, tex.depth, tex.components]).toEqual([v.width, v.height, v.depth, v.components]);
      expect(tex.is3D).toBe(v.depth > 0);
      expect(tex.data.length).toBe(v.width * v.height * Math.max(v.depth, 1) * tex.valuesPerTexel);
      const got = Array.from(texelsAsNumbers(tex));
      expect(got.length).toBe(v.values.length);
      // float32 values are exact; halves decode exactly to the float64 of numpy's float16
      got.forEach((x, i) => expect(x).toBe(tex.kind === 'float' ? f32(v.values[i]) : v.values[i]));
    });
  }

  it('keeps the packed irradiance as one word per texel and reads a table in its manifest shape', () => {
    const irr = load('irr_b10g11r11_zstd.ktx2');
    expect([irr.kind, irr.valuesPerTexel, irr.data.constructor.name]).toEqual(['ufloat-packed', 1, 'Uint32Array']);
    const e5 = load('irr_e5b9g9r9_zstd.ktx2');
    expect([e5.vkFormat, e5.kind, e5.valuesPerTexel, e5.data.constructor.name]).toEqual([123, 'ufloat-packed', 1, 'Uint32Array']);
    const v = expected.volumes.find((x) => x.file === 'table_r32i_zstd.ktx2');
    const t = tableFromKTX2(load(v.file), [2, 2, 3]);        // any shape with the level's 12 values
    expect(t.shape).toEqual([2, 2, 3]);
    expect(t.dtype).toBe('int32');
    expect(Array.from(t.data)).toEqual(v.values);
    expect(() => tableFromKTX2(load(v.file), [5, 3])).toThrow(/does not fit/);
  });

  it('reads key/value data and the Zstandard flag', () => {
    const tex = load('volume_r8_zstd.ktx2');
    expect(tex.supercompression).toBe(2);
    expect(tex.kv.KTXwriter).toMatch(/^Kiln proto\.ktx2/);
    expect(tex.kv.KTXwriterScParams).toMatch(/--zstd \d+/);
  });

  it('refuses what is not in the subset, with a reason', () => {
    const good = new Uint8Array(readFileSync(FIX + 'volume_rgba32f.ktx2'));
    const bad = good.slice(); bad[0] = 0;
    expect(() => parseKTX2(bad)).toThrow(/identifier/);
    const fmt = good.slice(); new DataView(fmt.buffer).setUint32(12, 131, true);  // a BC format
    expect(() => parseKTX2(fmt)).toThrow(/unsupported vkFormat 131/);
    expect(() => parseKTX2(good.slice(0, good.length - 4))).toThrow(/shorter/);
    const extra = new Uint8Array(good.length + 4); extra.set(good);
    expect(() => parseKTX2(extra)).toThrow(/after the level/);
    const z = new Uint8Array(readFileSync(FIX + 'volume_r8_zstd.ktx2'));
    const zlen = new DataView(z.buffer).getUint32(96, true);
    const wrong = z.slice(); new DataView(wrong.buffer).setUint32(96, zlen + 1, true);
    expect(() => parseKTX2(wrong)).toThrow(/uncompressedByteLength/);
  });
});

describe('octahedral convention (fold on +Z) and atlas tiling', () => {
  const close = (a, b, eps = 1e-6) => a.forEach((x, i) => expect(x).toBeCloseTo(b[i], 6));
  it('encodes like workers.kernels.octahedral.oct_encode', () => {
    expected.octahedral.dirs.forEach((d, i) => close(octEncode(d), expected.octahedral.encoded[i]));
  });
  it('decodes like oct_decode', () => {
    expected.octahedral.uv.forEach((uv, i) => close(octDecode(uv), expected.octahedral.decoded[i]));
  });
  it('finds every probe tile and texel direction in the atlas', () => {
    const a = expected.atlas;
    const tex = load(a.file);
    expect([tex.width, tex.height]).toEqual([a.width, a.height]);
    expect(tex.is3D).toBe(false);
    const [nx, ny, nz] = a.counts;
    const n = a.texels;
    for (let k = 0; k < nz; k++) for (let j = 0; j < ny; j++) for (let i = 0; i < nx; i++) {
      for (let r = 0; r < n; r++) for (let c = 0; c < n; c++) {
        const t = atlasTexel(tex, i, j, k, r, c, nx, n);
        expect(t[0]).toBe((k * ny + j) * nx + i);  // the probe this tile belongs to
        const dir = octTexelDirection(r, c, n);
        const py = a.texel_directions.slice((r * n + c) * 3, (r * n + c) * 3 + 3);
        dir.forEach((x, q) => { expect(x).toBeCloseTo(py[q], 6); expect(t[1 + q]).toBeCloseTo(x, 6); });
      }
    }
    // the border mirrors the interior (RTXGI): top row = first interior row with columns flipped
    const row0 = (c) => Array.from(tex.data.subarray(c * 4, c * 4 + 4));
    const interior = (r, c) => Array.from(tex.data.subarray(((1 + r) * tex.width + 1 + c) * 4, ((1 + r) * tex.width + 2 + c) * 4));
    for (let c = 1; c <= n; c++) expect(row0(c)).toEqual(interior(0, n - c));
  });
});

describe('L1 SH irradiance', () => {
  const s = expected.sh;
  const vols = s.files.map(load);
  const grid = s.grid;
  const [W, H, D] = grid.counts;
  it('the r/g/b volumes hold the coefficients in the documented order', () => {
    const coeffs = s.coeffs;  // (D, H, W, 4, 3) float32
    for (let p = 0; p < W * H * D; p++) for (let q = 0; q < 4; q++) for (let c = 0; c < 3; c++) {
      expect(vols[c].data[p * 4 + q]).toBe(f32(coeffs[(p * 4 + q) * 3 + c]));
    }
  });
  it('evaluates like workers.kernels.sh.sh_irradiance for every probe and normal', () => {
    const N = s.normals.length;
    for (let p = 0; p < W * H * D; p++) {
      const ch = vols.map((v) => Array.from(v.data.subarray(p * 4, p * 4 + 4)));
      s.normals.forEach((nrm, ni) => {
        const e = shIrradianceL1(ch[0], ch[1], ch[2], nrm);
        e.forEach((x, c) => expect(x).toBeCloseTo(s.irradiance[(p * N + ni) * 3 + c], 4));
        const enl = shIrradianceL1Nonlinear(ch[0], ch[1], ch[2], nrm);   // sh_irradiance_l1_nonlinear
        enl.forEach((x, c) => expect(x).toBeCloseTo(s.irradiance_nonlinear[(p * N + ni) * 3 + c], 4));
      });
    }
  });
  it('maps world points to uvw and samples trilinearly like the GPU', () => {
    for (const smp of s.samples) {
      const uvw = probeGridUVW(smp.p, grid);
      uvw.forEach((x, a) => expect(x).toBeCloseTo(smp.uvw[a], 10));
      const ch = vols.map((v) => sampleVolumeTrilinear(v, uvw));
      ch.forEach((c4, c) => c4.forEach((x, q) => expect(x).toBeCloseTo(smp.coeffs_rgb[c][q], 5)));
      s.normals.forEach((nrm, ni) => {
        shIrradianceL1(ch[0], ch[1], ch[2], nrm).forEach((x, c) => expect(x).toBeCloseTo(smp.irradiance[ni][c], 4));
      });
    }
  });
});

describe('L2 SH irradiance (sh_l2: three.js LightProbeGrid layout)', () => {
  const e = expected.sh_l2;
  const vol = load(e.file);
  const [W, H, D] = e.grid.counts;
  const N = e.normals.length;
  const slices = D + 2;
  const texels = (i, j, k) => Array.from({ length: 7 }, (_, t) => {
    const base = ((((t * slices + 1 + k) * H + j) * W) + i) * 4;
    return Array.from(vol.data.subarray(base, base + 4));
  });
  it('the volume is 7 padded sub-volumes of the 27 coefficients, c0.rgb first', () => {
    expect([vol.width, vol.height, vol.depth, vol.components]).toEqual([W, H, 7 * slices, 4]);
    expect(e.atlas_shape).toEqual([7 * slices, H, W, 4]);
    for (let k = 0; k < D; k++) for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
      const c = shL2Unpack(texels(i, j, k));
      const p = (k * H + j) * W + i;
      c.forEach((rgb, q) => rgb.forEach((x, ch) => expect(x).toBe(f32(e.coeffs[(p * 9 + q) * 3 + ch]))));
    }
    // padding slices copy the nearest data slice
    const at = (z, j, i) => Array.from(vol.data.subarray(((z * H + j) * W + i) * 4, ((z * H + j) * W + i) * 4 + 4));
    for (let t = 0; t < 7; t++) {
      expect(at(t * slices, 1, 2)).toEqual(at(t * slices + 1, 1, 2));
      expect(at(t * slices + D + 1, 1, 2)).toEqual(at(t * slices + D, 1, 2));
    }
  });
  it('evaluates like workers.kernels.sh.sh_irradiance_l2 for every probe and normal', () => {
    for (let k = 0; k < D; k++) for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
      const c = shL2Unpack(texels(i, j, k));
      const p = (k * H + j) * W + i;
      e.normals.forEach((nrm, ni) => {
        shIrradianceL2(c, nrm).forEach((x, ch) => expect(x).toBeCloseTo(e.irradiance[(p * N + ni) * 3 + ch], 5));
      });
    }
  });
  it('samples the padded stack trilinearly like samplers.sh_l2_sample (7 fetches)', () => {
    for (const smp of e.samples) {
      const c = sampleShL2(vol, smp.p, e.grid);
      c.forEach((rgb, q) => rgb.forEach((x, ch) => expect(x).toBeCloseTo(smp.coeffs[q][ch], 5)));
      e.normals.forEach((nrm, ni) => shIrradianceL2(c, nrm).forEach((x, ch) => expect(x).toBeCloseTo(smp.irradiance[ni][ch], 4)));
    }
  });
  it('constant radiance gives π·L; the clamped-cosine lobe its exact irradiance (to L2\'s band limit)', () => {
    e.normals.forEach((nrm, ni) => {
      shIrradianceL2(e.constant.coeffs, nrm).forEach((x, ch) => expect(x).toBeCloseTo(Math.PI * e.constant.radiance[ch], 3));
      const lobe = shIrradianceL2(e.cosine_lobe.coeffs.map((v) => [v, v, v]), nrm)[0];
      expect(lobe).toBeCloseTo(e.cosine_lobe.irradiance[ni], 5);   // the folded constants have 6 digits
      expect(Math.abs(lobe - e.cosine_lobe.exact[ni])).toBeLessThan(0.02);
    });
  });
});

describe('SH order per mode (state/modes.js shOrder, as workers/render/shading.py prepare_mode)', () => {
  it('L2 where the bake has the L2 volumes, else L1; caps can force L1 or rule out a too deep stack', async () => {
    const { shOrder, modeById, modeTextures, modeDefines, prtBasisNames } = await import('../src/state/modes.js');
    const l1 = ['sh_l1_r', 'sh_l1_g', 'sh_l1_b', 'cluster_sh_0_r', 'cluster_sh_0_g', 'cluster_sh_0_b', 'cluster_sh_1_r', 'cluster_sh_1_g', 'cluster_sh_1_b'];
    const l2 = [...l1, 'sh_l2', 'cluster_sh_l2_0', 'cluster_sh_l2_1'];
    expect(shOrder('leaking', l1)).toBe(1);
    expect(shOrder('leaking', l2)).toBe(2);
    expect(shOrder('leaking', l2, {}, { shOrder: 1 })).toBe(1);
    expect(shOrder('mask', l2, {}, { nz: 8, max3D: 2048 })).toBe(2);
    expect(shOrder('mask', l2, {}, { nz: 8, max3D: 256 })).toBe(2);         // 7 · K · (nz + 2) = 140 fits
    expect(shOrder('mask', l2, {}, { nz: 8, max3D: 128 })).toBe(1);         // ... not in 128: L1
    expect(shOrder('mask', [...l2, 'cluster_sh_2_r'], {}, {})).toBe(1);      // cluster 2 has no L2 volume
    const leaking = modeById('leaking');
    expect(modeTextures(leaking, l2)).toEqual({ uShL2: ['sh_l2', 'volume'] });
    expect(Object.keys(modeTextures(leaking, l1))).toEqual(['uShR', 'uShG', 'uShB']);
    expect(modeDefines(leaking, l2)).toEqual({ KILN_SH_L2: true });
    expect(modeDefines(leaking, l1)).toEqual({});
    expect(modeTextures(modeById('mask'), l2).uClusterShL2).toEqual([['cluster_sh_l2_0', 'cluster_sh_l2_1'], 'stack']);
    const basis = Array.from({ length: 9 }, (_, k) => [`prt_sh_basis_c${k}_g0`]);
    expect(prtBasisNames({ sh: { basis } })).toHaveLength(9);
    expect(prtBasisNames({ sh: { basis } }, { shOrder: 1 })).toHaveLength(4);
    expect(modeDefines(modeById('prt'), [], { prt: { sh: { basis } } })).toEqual({ KILN_SH_L2: true });
  });
});

describe('mask lookup offset (workers/kernels/samplers.MASK_OFFSET_SAMPLES)', () => {
  it('is one refined sample, whatever the grid', async () => {
    const { modeById, MASK_OFFSET_SAMPLES } = await import('../src/state/modes.js');
    expect(MASK_OFFSET_SAMPLES).toBe(1);
    const mask = modeById('mask_normalized');
    const u = mask.uniforms({ names: ['cluster_sh_0_r'], info: () => undefined, grid: { counts: [5, 4, 3], spacing: [1, 0.25, 2] },
      bake: { stages: [{ name: 'compress', stats: { block_size: 8, layout: 'cell', border_lo: 0, border_hi: 0 } }] } });
    expect(u).toMatchObject({ uMaskOffset: 1, uMaskS: 8, uMaskT: 8, uMaskLo: 0, uClusterCount: 1 });
  });
});

describe('mask atlas parameters (workers/kernels/mask_atlas.py, older compress.py layouts)', () => {
  it('reads the atlas meta, else the compress stats, else the dense masks', async () => {
    const { maskParams } = await import('../src/state/modes.js');
    const none = () => undefined;
    const meta = { samples_per_cell: 8, block_size: 8, border_lo: 0 };
    expect(maskParams({ names: [], info: (n) => (n === 'mask_atlas' ? { meta } : undefined) })).toEqual({ S: 8, T: 8, lo: 0 });
    const bake = (stats) => ({ stages: [{ name: 'compress', stats }] });
    expect(maskParams({ names: [], info: none, bake: bake({ block_size: 8, layout: 'cell', border_lo: 0, border_hi: 0 }) })).toEqual({ S: 8, T: 8, lo: 0 });
    expect(maskParams({ names: [], info: none, bake: bake({ block_size: 9, layout: 'shared' }) })).toEqual({ S: 8, T: 9, lo: 0 });
    expect(maskParams({ names: [], info: none, bake: bake({ block_size: 10, layout: 'bordered' }) })).toEqual({ S: 8, T: 10, lo: 1 });
    const masks = (n) => (n === 'masks_0123' ? { shape: [16, 24, 32, 4] } : undefined);
    expect(maskParams({ names: [], info: masks, grid: { counts: [5, 4, 3] } })).toEqual({ S: 8, T: 8, lo: 0 });
  });
});

describe('the mode table is proto/gi_modes.json (one source with workers/render/shading.py prepare_mode)', () => {
  const grid = { counts: [3, 2, 2], spacing: [0.5, 0.25, 1], origin: [0, 0, 0] };
  const K = 5;
  const names = ['sh_l1_r', 'sh_l1_g', 'sh_l1_b', 'sh_l2', 'mask_indirection', 'mask_atlas',
    'cluster_weights_0123', 'cluster_weights_4567', 'irradiance', 'depth_moments', 'probe_positions_relocated', 'probe_states',
    ...Array.from({ length: K }, (_, k) => [`cluster_sh_${k}_r`, `cluster_sh_${k}_g`, `cluster_sh_${k}_b`, `cluster_sh_l2_${k}`]).flat()];
  const artifacts = { irradiance: { width: 96, height: 16 }, depth_moments: { width: 192, height: 32 },
    prt: { basis: 4, sh: { basis: Array.from({ length: 9 }, (_, k) => [`prt_sh_basis_c${k}_g0`]) } } };
  const bake = (B) => ({ config: { light: { self_shadow_bias: B } },
    stages: [{ name: 'compress', stats: { block_size: 2, layout: 'cell', border_lo: 0, border_hi: 0 } }] });

  it('every mode binds the textures, uniforms and defines the table lists', async () => {
    const { GI_MODES, MODE_SPECS, MODE_SAMPLERS, modeTextures, modeDefines } = await import('../src/state/modes.js');
    const spec = (await import('../../proto/gi_modes.json')).default;
    expect(GI_MODES.map((m) => m.id)).toEqual(spec.modes.map((m) => m.id));
    for (const mode of GI_MODES) {
      const table = MODE_SPECS[mode.id];
      expect(mode.shader).toBe(table.shader);
      const tex = modeTextures(mode, names, artifacts, { nz: 2 });
      // the table's textures at SH order 2 (this bake has the L2 volumes), the second atlas and weights with K = 5
      const want = table.textures.filter((t) => (t.sh_order ?? 2) === 2).map((t) => t.uniform);
      expect(Object.keys(tex)).toEqual(want);
      for (const t of table.textures.filter((x) => want.includes(x.uniform))) expect(tex[t.uniform][1]).toBe(t.kind);
      for (const u of Object.keys(tex)) expect(MODE_SAMPLERS).toContain(u);
      const uniforms = mode.uniforms ? Object.keys(mode.uniforms({ grid, names, bake: bake(0.3), info: () => undefined, artifacts })) : [];
      // uPrtCoef: set by the viewer's relight on every light move (viewer.js relight)
      expect([...uniforms, ...(mode.id === 'prt' ? ['uPrtCoef'] : [])].sort()).toEqual([...table.uniforms].sort());
      expect(Object.keys(modeDefines(mode, names, artifacts, { nz: 2 })).sort()).toEqual(Object.keys(table.defines).sort());
    }
    expect(modeDefines(GI_MODES.find((m) => m.id === 'mask'), names, artifacts, { nz: 2 })).toEqual({ KILN_SH_L2: true, KILN_MASK_CLUSTERS: K });
    expect(modeTextures(GI_MODES.find((m) => m.id === 'mask_normalized'), names, artifacts, { nz: 2 }).uClusterWeights)
      .toEqual([['cluster_weights_0123', 'cluster_weights_4567'], 'stack']);
  });

  it("DDGI's B is the bake's light.self_shadow_bias (DDGI-P eq 2), the default only where a bake does not say", async () => {
    const { modeById, ddgiBias, selfShadowBias, SELF_SHADOW_BIAS } = await import('../src/state/modes.js');
    const ddgi = modeById('ddgi');
    const u = (b) => ddgi.uniforms({ grid, names, bake: b, info: () => undefined, artifacts }).uDdgiBias;
    expect(SELF_SHADOW_BIAS).toBe(0.3);
    expect(u(bake(0.8))).toBeCloseTo(0.75 * 0.25 * 0.8, 12);      // workers/kernels/ddgi.bias_scale(spacing, 0.8)
    expect(u(bake(0))).toBe(0);
    expect(u({})).toBeCloseTo(0.75 * 0.25 * 0.3, 12);
    expect(u(bake(0.8))).not.toBeCloseTo(u({}), 6);
    expect(selfShadowBias({ config: { light: { self_shadow_bias: 1.5 } } })).toBe(1.5);
    expect(ddgiBias([0, 2, 0.5], 1)).toBe(0.375);                   // D over axes with spacing > 0
  });
});

describe('packed irradiance uploads', () => {
  it('uploads E5B9G9R9 as RGB9_E5 and B10G11R11 as R11F_G11F_B10F, words as stored', async () => {
    const { textureFromKTX2 } = await import('../src/renderer/textures.js');
    const three = await import('three');
    const e5 = load('irr_e5b9g9r9_zstd.ktx2');
    const t5 = textureFromKTX2(e5);
    expect([t5.format, t5.type]).toEqual([three.RGBFormat, three.UnsignedInt5999Type]);
    expect(t5.image.data).toBe(e5.data);
    const t11 = textureFromKTX2(load('irr_b10g11r11_zstd.ktx2'));
    expect([t11.format, t11.type]).toEqual([three.RGBFormat, three.UnsignedInt101111Type]);
  });
});
