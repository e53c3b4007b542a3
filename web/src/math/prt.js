/**
 * PRT relighting in the browser (workers/prt_relight.py, PRT eq 10/14): lights -> the direct vector x at the
 * measurement points -> per colour channel u_c = T_c [x_c, ‖x_c‖] -> the prt shader's uPrtCoef uniform.
 *
 * Difference from the server: the direct term at the measurement points is UNSHADOWED here (no ray caster in
 * the browser); workers/prt_relight.py traces shadow rays. Lights behind a wall therefore still "reach" the
 * points of the other room in the browser's relight.
 */

const LIGHT_TYPES = { point: 0, spot: 1, directional: 2 };

/**
 * Unshadowed direct irradiance (rgb) at point p with unit normal n from KHR lights (lights.glsl /
 * workers/kernels/shading.direct_irradiance without shadow rays). Adds into out[0..2].
 */
export function directIrradiance(p, n, lights, out = [0, 0, 0]) {
  for (const l of lights) {
    if (!(l.type in LIGHT_TYPES)) continue;
    const c = l.color || [1, 1, 1];
    const I = l.intensity ?? 1;
    let scale;
    if (l.type === 'directional') {
      const d = l.direction || [0, 0, -1];
      const dl = Math.hypot(d[0], d[1], d[2]) || 1;
      scale = Math.max(0, -(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / dl);
    } else {
      const lp = l.position || [0, 0, 0];
      const tx = lp[0] - p[0], ty = lp[1] - p[1], tz = lp[2] - p[2];
      const d2 = Math.max(tx * tx + ty * ty + tz * tz, 1e-8);
      const d = Math.sqrt(d2);
      const lx = tx / d, ly = ty / d, lz = tz / d;
      scale = Math.max(0, n[0] * lx + n[1] * ly + n[2] * lz) / d2;
      const range = l.range;
      if (range != null && Number.isFinite(range) && range > 0) {
        const w = Math.min(1, Math.max(0, 1 - (d / range) ** 4));
        scale *= w * w;
      }
      if (l.type === 'spot') {
        const dir = l.direction || [0, 0, -1];
        const dl = Math.hypot(dir[0], dir[1], dir[2]) || 1;
        const cosT = -(lx * dir[0] + ly * dir[1] + lz * dir[2]) / dl;
        const ci = Math.cos(l.inner_cone_angle ?? 0), co = Math.cos(l.outer_cone_angle ?? Math.PI / 4);
        const t = Math.min(1, Math.max(0, (cosT - co) / Math.max(1e-3, ci - co)));
        scale *= t * t;
      }
    }
    if (scale > 0) for (let k = 0; k < 3; k++) out[k] += c[k] * I * scale;
  }
  return out;
}

/**
 * x (M·3, row m = point m's rgb): albedo/π · E_direct at the measurement samples, averaged per point.
 * @param {ArrayLike<number>} table  (K, 9) rows: position, normal, albedo
 * @param {ArrayLike<number>} offsets  (M + 1): point m averages rows offsets[m]..offsets[m+1]
 */
export function directVector(table, offsets, lights) {
  const M = offsets.length - 1;
  const x = new Float64Array(M * 3);
  const e = [0, 0, 0];
  for (let m = 0; m < M; m++) {
    const a = Number(offsets[m]), b = Number(offsets[m + 1]);
    let r = 0, g = 0, bl = 0;
    for (let s = a; s < b; s++) {
      const o = s * 9;
      e[0] = e[1] = e[2] = 0;
      directIrradiance([table[o], table[o + 1], table[o + 2]], [table[o + 3], table[o + 4], table[o + 5]], lights, e);
      r += table[o + 6] / Math.PI * e[0];
      g += table[o + 7] / Math.PI * e[1];
      bl += table[o + 8] / Math.PI * e[2];
    }
    const cnt = Math.max(1, b - a);
    x[m * 3] = r / cnt; x[m * 3 + 1] = g / cnt; x[m * 3 + 2] = bl / cnt;  // x, the direct vector (PRT §3, §4.3)
  }
  return x;
}

/**
 * Mono transfer: u (n·3, row j = slot j's rgb) with u_c = T_c [x_c, ‖x_c‖].
 * @param {ArrayLike<number>} transfer  (3, n, M + 1), C order
 * @param {number} n  basis slots
 * @param {Float64Array} x  (M·3) from directVector
 * @param {string} norm  ‖x‖: 'l1' (sum of |x|) or 'l2' (the bundle's prt.norm; absent: 'l2')
 */
export function relightCoefficients(transfer, n, x, norm = 'l2') {
  const M = x.length / 3;
  const u = new Float64Array(n * 3);
  for (let c = 0; c < 3; c++) {
    let len = 0;
    if (norm === 'l1') for (let m = 0; m < M; m++) len += Math.abs(x[m * 3 + c]);
    else {
      for (let m = 0; m < M; m++) len += x[m * 3 + c] ** 2;
      len = Math.sqrt(len);
    }
    for (let j = 0; j < n; j++) {
      const row = (c * n + j) * (M + 1);
      let s = transfer[row + M] * len;
      for (let m = 0; m < M; m++) s += transfer[row + m] * x[m * 3 + c];  // u = M_n x (PRT eq 10), + the ‖x‖ intercept
      u[j * 3 + c] = s;
    }
  }
  return u;
}

/**
 * uPrtCoef of mode_prt.glsl: vec4 [c · maxGroups + g] = u_c of slots 4g..4g+3 (0 past n), flat Float32Array.
 */
export function packPrtCoefficients(u, n, maxGroups = 16) {
  const out = new Float32Array(3 * maxGroups * 4);
  for (let j = 0; j < n; j++) {
    const g = Math.floor(j / 4), s = j % 4;
    if (g >= maxGroups) throw new Error(`prt: at most ${4 * maxGroups} basis slots, got ${n}`);
    for (let c = 0; c < 3; c++) out[(c * maxGroups + g) * 4 + s] = u[j * 3 + c];
  }
  return out;
}
