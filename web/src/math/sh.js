/**
 * CPU mirror of proto/glsl/sh.glsl (L1 radiance SH -> irradiance, Ramamoorthi & Hanrahan 2001 eq 7-8) and
 * of the probe-grid mapping of proto/glsl/probe_grid.glsl. Used by the viewer's CPU-side views and by the
 * parity tests against proto/fixtures (written by Python with workers/kernels/sh.py).
 */

export const SH_C0 = 0.282095;     // 1/(2√π), Y00
export const SH_C1 = 0.488603;     // √(3/(4π)), band 1
export const SH_IRR_C0 = 0.886227; // π · c0
export const SH_IRR_C1 = 1.023328; // (2π/3) · c1

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

/** uvw of world point p in a probe volume: ((p - origin)/spacing + 0.5)/counts (bundle.md section 5). */
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
