/**
 * CPU mirror of proto/glsl/sh.glsl (L1 and L2 radiance SH -> irradiance, Ramamoorthi & Hanrahan 2001 eq 7-8) and
 * of the probe-grid mapping of proto/glsl/probe_grid.glsl and gi_grid.glsl (the sh_l2 layout; uniform and rectilinear
 * grids: gridIndex). Points and normals are in the bake frame (math/frame.js), as the shaders' giIndirectIrradiance
 * takes them. Used by the viewer's CPU-side views and by the parity tests against proto/fixtures (written by Python
 * with workers/kernels/sh.py).
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
 * The layers of a rectilinear grid (`grid.layers`: [xs, ys, zs], bake-frame metres, proto/bundle.md section 5), checked:
 * three arrays of numbers, axis a with grid.counts[a] finite, strictly increasing values (probe (i, j, k) un-relocated
 * at (xs[i], ys[j], zs[k]); xs[0] is grid.origin[0], grid.spacing the mean gap). null for a uniform grid (no `layers`,
 * or null). Throws a RangeError for malformed layers. gridIndex and gridPoint read `grid.layers` unchecked: check a
 * grid from a manifest or an API response here once.
 * @param {{counts: number[], layers?: ArrayLike<number>[]|null}} grid
 * @returns {number[][]|null}
 */
export function gridLayers(grid) {
  const L = grid?.layers;
  if (L == null) return null;
  if (!Array.isArray(L) || L.length !== 3) throw new RangeError(`grid layers: want [xs, ys, zs], got ${JSON.stringify(L)}`);
  return L.map((axis, a) => {
    const v = Array.from(axis ?? [], Number);
    const n = Number(grid.counts[a]);
    if (v.length !== n) throw new RangeError(`grid layers: axis ${a} has ${v.length} layers, counts[${a}] is ${n}`);
    v.forEach((x, i) => {
      if (!Number.isFinite(x)) throw new RangeError(`grid layers: axis ${a} layer ${i} is ${axis[i]}, not a finite number`);
      if (i > 0 && !(x > v[i - 1])) throw new RangeError(`grid layers: axis ${a} is not strictly increasing at layer ${i} (${v[i - 1]}, ${x})`);
    });
    return v;
  });
}

/**
 * Continuous layer index of coordinate x (metres) among the strictly increasing layers L (length n > 1):
 * i + (x − L[i]) / (L[i+1] − L[i]) for the i in [0, n − 2] with L[i] <= x < L[i+1] (i = 0 below L[1], n − 2 at or past
 * L[n − 2]: linear extrapolation beyond the ends, unclamped). probe_grid.glsl giLayerCoord (the same binary search);
 * Python: workers/kernels/grid.py grid_coord.
 */
export function layerCoord(x, L) {
  let lo = 0;
  let hi = L.length - 1;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (L[mid] <= x) lo = mid; else hi = mid;
  }
  return lo + (x - L[lo]) / (L[lo + 1] - L[lo]);
}

/**
 * Continuous probe index [gi, gj, gk] of bake-frame point p (metres), unclamped (probe_grid.glsl giGridIndex): on a
 * uniform grid (p − origin)/spacing, on a rectilinear one (`grid.layers`) the layer coordinate of each axis (layerCoord);
 * 0 on a one-probe axis (counts 1) and on an axis of a uniform grid with spacing <= 0. Probe (i, j, k) has index
 * (i, j, k) exactly; texel coordinate g + 0.5 with trilinear filtering is the grid's trilinear interpolation.
 * @param {number[]} p  bake frame (a world point of a bake with grid.frame goes through math/frame.js toBake first)
 * @param {{origin: number[], spacing: number[], counts: number[], layers?: number[][]|null}} grid
 * @returns {number[]}
 */
export function gridIndex(p, grid) {
  const L = grid.layers;
  return [0, 1, 2].map((a) => {
    if (!(grid.counts[a] > 1)) return 0;
    if (L) return layerCoord(p[a], L[a]);
    return grid.spacing[a] > 0 ? (p[a] - grid.origin[a]) / grid.spacing[a] : 0;
  });
}

/**
 * Bake-frame position (metres) of continuous grid index g = [gi, gj, gk], the inverse of gridIndex: origin + spacing · g
 * on a uniform grid, on a rectilinear one per axis the layers interpolated linearly (layers[a][i] at an integer i,
 * linear extrapolation past the ends; layers[a][0] on a one-probe axis). Probe (i, j, k)'s un-relocated position.
 * @param {{origin: number[], spacing: number[], counts: number[], layers?: number[][]|null}} grid
 * @param {number[]} g
 * @returns {number[]}
 */
export function gridPoint(grid, g) {
  const L = grid.layers;
  return [0, 1, 2].map((a) => {
    if (!L) return grid.origin[a] + grid.spacing[a] * g[a];
    const La = L[a];
    const n = La.length;
    if (n < 2) return La[0];
    if (Number.isInteger(g[a]) && g[a] >= 0 && g[a] < n) return La[g[a]];
    const i = Math.min(n - 2, Math.max(0, Math.floor(g[a])));
    return La[i] + (g[a] - i) * (La[i + 1] - La[i]);
  });
}

/**
 * Per axis, the smallest gap between neighbouring probe layers (metres): the spacing of a uniform grid (0 on a
 * one-probe axis), the smallest layer gap of a rectilinear one (0 on a one-probe axis). For sizes of markers that must
 * not overlap.
 * @returns {number[]}
 */
export function gridMinGaps(grid) {
  const L = grid.layers;
  if (!L) return grid.spacing.slice();
  return L.map((La) => (La.length < 2 ? 0 : Math.min(...La.slice(1).map((x, i) => x - La[i]))));
}

/**
 * uvw of point p in a probe volume: (gridIndex(p) + 0.5)/counts (bundle.md section 5; probe_grid.glsl probeGridUVW):
 * ((p - origin)/spacing + 0.5)/counts on a uniform grid. p is in the bake frame (the grid's; a world point of a bake
 * with grid.frame goes through math/frame.js toBake first). One-probe axes: 0.5.
 */
export function probeGridUVW(p, grid) {
  const g = gridIndex(p, grid);
  return [0, 1, 2].map((a) => (g[a] + 0.5) / grid.counts[a]);
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
 * giProbeTexel): clamp(gridIndex(p) + 0.5, 0.5, counts - 0.5) — clamp((p - origin)/spacing + 0.5, ...) on a uniform grid,
 * the layer coordinate on a rectilinear one — 0.5 on one-probe axes.
 */
export function probeTexel(p, grid) {
  const g = gridIndex(p, grid);
  return [0, 1, 2].map((a) => Math.min(grid.counts[a] - 0.5, Math.max(0.5, g[a] + 0.5)));
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
