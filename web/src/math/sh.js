/**
 * CPU mirror of proto/glsl/sh.glsl (L1 and L2 radiance SH -> irradiance, Ramamoorthi & Hanrahan 2001 eq 7-8) and
 * of the probe-grid mapping of proto/glsl/probe_grid.glsl and gi_grid.glsl (the sh_l2 layout). Points and normals are in
 * the bake frame (math/frame.js), as the shaders' giIndirectIrradiance takes them. Used by the viewer's CPU-side views and by the
 * parity tests against proto/fixtures (written by Python with workers/kernels/sh.py).
 */

export const SH_C0 = 0.282095;     // 1/(2√π), Y00
export const SH_C1 = 0.488603;     // √(3/(4π)), band 1
export const SH_IRR_C0 = 0.886227; // π · c0
export const SH_IRR_C1 = 1.023328; // (2π/3) · c1
export const SH_IRR_C2 = 0.858086; // (π/4) · c2, c2 = ½√(15/π) = 1.092548 (xy, yz, xz)
export const SH_IRR_C3 = 0.247708; // (π/4) · c3, c3 = ¼√(5/π) = 0.315392 (3z² − 1)
export const SH_IRR_C4 = 0.429043; // (π/4) · c4, c4 = ¼√(15/π) = 0.546274 (x² − y²)
export const SH_L2_TEXELS = 7;     // RGBA texels (padded sub-volumes) per probe of an sh_l2 volume

/** The 9 real SH basis values at unit d = [x, y, z] (three.js order and constants, workers/kernels/sh.py _sh_basis). */
export function shBasisL2([x, y, z]) {
  return [SH_C0, SH_C1 * y, SH_C1 * z, SH_C1 * x, 1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1),
    1.092548 * x * z, 0.546274 * (x * x - y * y)];
}

/**
 * Irradiance of one colour channel from its L1 coefficients [L0, L1(y), L1(z), L1(x)] (bundle.md 5.1)
 * for a unit normal n = [x, y, z]. Constant radiance L gives π·L.
 */
export function shIrradianceL1Channel(c, n) {
  return SH_IRR_C0 * c[0] + SH_IRR_C1 * (c[1] * n[1] + c[2] * n[2] + c[3] * n[0]);
}

/** RGB irradiance from the three channel vectors (as the sh_l1_r/g/b volumes store them), linear evaluation. */
export function shIrradianceL1(r, g, b, n) {
  return [shIrradianceL1Channel(r, n), shIrradianceL1Channel(g, n), shIrradianceL1Channel(b, n)];
}

/**
 * The non-linear L1 reconstruction (Hazel 2017; sh.glsl's default shIrradianceL1, workers/kernels/sh.py
 * sh_irradiance_l1_nonlinear): same mean as the linear one, never negative.
 */
export function shIrradianceL1NonlinearChannel(c, n) {
  const R0 = SH_IRR_C0 * c[0];
  if (R0 <= 0) return 0;
  const R1 = [0.5 * SH_IRR_C1 * c[3], 0.5 * SH_IRR_C1 * c[1], 0.5 * SH_IRR_C1 * c[2]];
  const len = Math.hypot(R1[0], R1[1], R1[2]);
  if (len <= 1e-6 * R0) return R0;
  const r = Math.min(len / R0, 1);
  const q = Math.min(Math.max(0.5 * (1 + (R1[0] * n[0] + R1[1] * n[1] + R1[2] * n[2]) / len), 0), 1);
  const p = 1 + 2 * r;
  const a = (1 - r) / (1 + r);
  return R0 * (a + (1 - a) * (p + 1) * q ** p);
}

/** RGB irradiance, non-linear L1 reconstruction. */
export function shIrradianceL1Nonlinear(r, g, b, n) {
  return [r, g, b].map((c) => shIrradianceL1NonlinearChannel(c, n));
}

/**
 * uvw of point p in a probe volume: ((p - origin)/spacing + 0.5)/counts (bundle.md section 5). p is in the bake frame
 * (the grid's; a world point of a bake with grid.frame goes through math/frame.js toBake first).
 */
export function probeGridUVW(p, grid) {
  return [0, 1, 2].map((a) => ((p[a] - grid.origin[a]) / grid.spacing[a] + 0.5) / grid.counts[a]);
}

/**
 * Hardware-style trilinear sample (CLAMP_TO_EDGE) of a probe volume at uvw; volume.data has
 * width·height·depth·components values, x fastest. Returns `components` numbers.
 */
export function sampleVolumeTrilinear(volume, uvw) {
  const { width: W, height: H, depth: D, components: C, data } = volume;
  const size = [W, H, Math.max(D, 1)];
  const i0 = [], f = [];
  for (let a = 0; a < 3; a++) {
    const s = uvw[a] * size[a] - 0.5;  // texel centres at integer + 0.5
    const fl = Math.floor(s);
    i0.push(fl);
    f.push(s - fl);
  }
  const clampi = (v, n) => Math.min(n - 1, Math.max(0, v));
  const out = new Array(C).fill(0);
  for (let corner = 0; corner < 8; corner++) {
    const d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
    let w = 1;
    const idx = [];
    for (let a = 0; a < 3; a++) {
      w *= d[a] ? f[a] : 1 - f[a];
      idx.push(clampi(i0[a] + d[a], size[a]));
    }
    if (w === 0) continue;
    const base = ((idx[2] * H + idx[1]) * W + idx[0]) * C;
    for (let c = 0; c < C; c++) out[c] += w * data[base + c];
  }
  return out;
}

/**
 * L2 irradiance of one colour channel from its 9 radiance coefficients (three.js order, workers/kernels/sh.py table)
 * for a unit normal n: Ramamoorthi & Hanrahan 2001 eq 7, E(n) = Σ Â_l L_lm Y_lm(n), with eq 8's clamped-cosine
 * kernel Â_0 = π, Â_1 = 2π/3, Â_2 = π/4 folded into SH_IRR_C0..C4. Constant radiance L gives π·L. Not clamped.
 */
export function shIrradianceL2Channel(c, n) {
  const [x, y, z] = n;
  return SH_IRR_C0 * c[0]                                              // Â_0 Y00
    + SH_IRR_C1 * (c[1] * y + c[2] * z + c[3] * x)                      // Â_1 Y1m
    + SH_IRR_C2 * (c[4] * x * y + c[5] * y * z + c[7] * x * z)          // Â_2 Y2m, m = -2, -1, 1
    + SH_IRR_C3 * (3 * z * z - 1) * c[6]                                // Â_2 Y20
    + SH_IRR_C4 * (x * x - y * y) * c[8];                               // Â_2 Y22
}

/** RGB L2 irradiance (sh.glsl shIrradianceL2) from 9 coefficients given as [r, g, b] each. */
export function shIrradianceL2(coeffs, n) {
  return [0, 1, 2].map((ch) => shIrradianceL2Channel(coeffs.map((c) => c[ch]), n));
}

/** The 9 [r, g, b] coefficients of the 28 numbers of a probe's 7 sh_l2 texels (c0.rgb, c1.rgb, ..., c8.rgb, 0). */
export function shL2Unpack(texels) {
  const flat = texels.flat();
  return Array.from({ length: 9 }, (_, k) => flat.slice(3 * k, 3 * k + 3));
}

/**
 * Texel coordinate of bake-frame point p (as probeGridUVW) in a probe volume, clamped to the border texel centres (gi_grid.glsl
 * giProbeTexel): clamp((p - origin)/spacing + 0.5, 0.5, counts - 0.5), 0.5 on one-probe axes.
 */
export function probeTexel(p, grid) {
  return [0, 1, 2].map((a) => {
    const live = grid.counts[a] > 1 && grid.spacing[a] > 0;
    const t = (live ? (p[a] - grid.origin[a]) / grid.spacing[a] : 0) + 0.5;
    return Math.min(grid.counts[a] - 0.5, Math.max(0.5, t));
  });
}

/**
 * The 9 [r, g, b] L2 coefficients at bake-frame point p (as probeGridUVW; the normal they are evaluated for is in the
 * bake frame too) from an sh_l2 volume (three.js LightProbeGrid layout:
 * 7 sub-volumes of nz + 2 z slices, proto/bundle.md 5.1), 7 trilinear fetches as gi_grid.glsl giPaddedStackedUVW
 * and workers/kernels/samplers.py sh_l2_sample read it.
 */
export function sampleShL2(volume, p, grid) {
  const [nx, ny, nz] = grid.counts;
  const t = probeTexel(p, grid);
  const slices = nz + 2;
  const texels = [];
  for (let s = 0; s < SH_L2_TEXELS; s++) {
    texels.push(sampleVolumeTrilinear(volume, [t[0] / nx, t[1] / ny, (t[2] + 1 + s * slices) / (slices * SH_L2_TEXELS)]));
  }
  return shL2Unpack(texels);
}
