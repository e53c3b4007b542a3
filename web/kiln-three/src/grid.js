/**
 * Pure mapping between a Kiln probe grid (manifest `grid`: origin, spacing, counts; proto/bundle.md section 5) and
 * three.js' LightProbeGrid (examples/jsm/lighting/LightProbeGridWebGL.js, ShaderChunk lightprobes_pars_fragment).
 *
 * Kiln puts probe (i, j, k) at origin + spacing·(i, j, k) (metres, glTF frame: +Y up, right-handed). three puts its
 * probes at the cell centres of its box: probe i at min + (i + ½)·size/resolution. So the box of a Kiln grid is
 * origin − spacing/2 … origin + spacing·(counts − ½) with resolution = counts, and three's
 * uvw = (p − min)/size equals Kiln's ((p − origin)/spacing + ½)/counts: the same texel coordinate, the same trilinear
 * weights (MD eq 2's φ_i). The atlas is Kiln's `sh_l2` as stored (7 sub-volumes of nz + 2 slices along z).
 *
 * Two differences remain, both three's shader: (1) it offsets the lookup by half a probe spacing along the normal
 * (its leak mitigation; Kiln's leaking mode has none), (2) a point whose offset lookup falls outside the box gets no
 * grid light at all, where Kiln clamps to the border probes. `padShL2` answers (2): one more layer of probes on every
 * side, copies of the border layer, so three's box grows by a cell per side and, inside the old box plus one cell,
 * three reads exactly what Kiln's clamped lookup reads.
 *
 * Two kinds of bake three's grid cannot hold as they are, both resampled onto an axis-aligned world grid about the
 * bake's spacing (resampleShL2; fitsProbeGrid decides): a turned bake (`grid.frame`, yaw ≠ 0: three's box is
 * world-aligned) and a rectilinear one (`grid.layers` = [xs, ys, zs]: probe (i, j, k) at (xs[i], ys[j], zs[k]), gaps
 * that differ from layer to layer, where three's cells are all alike).
 */
import { DataUtils } from 'three';
import { gridLayers, sampleShL2, shBasisL2 } from '../../src/math/sh.js';
import { frameMatrix, isIdentity } from '../../src/math/frame.js';

/** Sub-volumes of the L2 layout (9 coefficients × rgb + one 0 = 28 numbers = 7 RGBA texels per probe). */
export const SH_L2_TEXELS = 7;

const vec = (v, n = 3) => {
  const a = Array.from(v ?? [], Number);
  if (a.length !== n || !a.every(Number.isFinite)) throw new RangeError(`expected ${n} finite numbers, got ${JSON.stringify(v)}`);
  return a;
};

/**
 * Cell size per axis: the grid spacing, or on a one-probe axis (counts 1, spacing often 0) the largest spacing of the
 * other axes (1 m when none): any positive size gives three's clamp the single texel there.
 */
export function cellSize(grid) {
  const s = vec(grid.spacing);
  const c = vec(grid.counts);
  const live = s.filter((x, a) => x > 0 && c[a] > 1);
  const fallback = live.length ? Math.max(...live) : 1;
  return s.map((x, a) => (x > 0 && c[a] > 1 ? x : fallback));
}

/**
 * Whether three's LightProbeGrid holds a Kiln grid's probes as they are (probeGridBox, padShL2): its bake frame is the
 * world (no grid.frame, or yaw 0) and the grid is uniform (no grid.layers). Otherwise createProbeGrid resamples the
 * SH onto an axis-aligned world grid (resampleShL2). Throws a RangeError for a malformed frame or layers.
 * @param {{origin: number[], spacing: number[], counts: number[], layers?: number[][]|null, frame?: object}} grid
 *   manifest.grid
 * @returns {boolean}
 */
export function fitsProbeGrid(grid) {
  return isIdentity(frameMatrix(grid)) && gridLayers(grid) === null;
}

/**
 * three.js LightProbeGrid box of a Kiln grid (a uniform one: a rectilinear grid's probes do not sit at three's cell
 * centres, the box of this one spans its outer layers ± half the mean spacing; fitsProbeGrid, resampleShL2).
 * @param {{origin: number[], spacing: number[], counts: number[]}} grid  manifest.grid
 * @param {number} [pad=0]  extra probe layers per side (padShL2 with the same pad)
 * @returns {{min: number[], max: number[], center: number[], size: number[], resolution: number[]}}  metres; the
 *   arguments of `new LightProbeGridWebGL(...size, ...resolution)` placed at `center`.
 */
export function probeGridBox(grid, pad = 0) {
  const o = vec(grid.origin);
  const n = vec(grid.counts).map((x) => {
    if (!Number.isInteger(x) || x < 1) throw new RangeError(`grid counts must be positive integers, got ${grid.counts}`);
    return x;
  });
  const s = cellSize(grid);
  const min = o.map((x, a) => x - s[a] * (0.5 + pad));
  const max = o.map((x, a) => x + s[a] * (n[a] - 0.5 + pad));
  return {
    min, max,
    size: max.map((x, a) => x - min[a]),
    center: max.map((x, a) => (x + min[a]) / 2),
    resolution: n.map((x) => x + 2 * pad),
  };
}

/**
 * Texel coordinate (texel centres at integer + ½, before the clamp) of world point p in three's grid of box `box`:
 * (p − min)/size·resolution. For pad = 0 it equals Kiln's (p − origin)/spacing + ½ (proto/bundle.md 5.1).
 */
export function threeTexelCoord(box, p) {
  return vec(p).map((x, a) => ((x - box.min[a]) / box.size[a]) * box.resolution[a]);
}

/**
 * The `sh_l2` atlas with `pad` extra probe layers on every side, each a copy of the nearest border probe, in the same
 * layout (7 sub-volumes stacked along z, each nz' + 2 slices with its own padding slices).
 * @param {ArrayLike<number>} data  the atlas texels, RGBA, x fastest: (7·(nz + 2), ny, nx, 4) as stored
 *   (Float32Array for RGBA32F, Uint16Array of half-float bits for RGBA16F: values are copied, never converted)
 * @param {number[]} counts  [nx, ny, nz]
 * @param {number} [pad=1]
 * @returns {{data: ArrayLike<number>, counts: number[], depth: number}}  the same typed array type; counts + 2·pad;
 *   depth = 7·(nz' + 2) slices
 */
export function padShL2(data, counts, pad = 1) {
  const [nx, ny, nz] = vec(counts);
  const expected = SH_L2_TEXELS * (nz + 2) * ny * nx * 4;
  if (data.length !== expected) throw new RangeError(`sh_l2 of ${data.length} values, expected 7·(nz+2)·ny·nx·4 = ${expected}`);
  const [mx, my, mz] = [nx + 2 * pad, ny + 2 * pad, nz + 2 * pad];
  const out = new data.constructor(SH_L2_TEXELS * (mz + 2) * my * mx * 4);
  const clamp = (v, n) => Math.min(n - 1, Math.max(0, v));
  for (let s = 0; s < SH_L2_TEXELS; s++) {
    for (let z = 0; z < mz + 2; z++) {           // z = 0 and mz + 1: the sub-volume's own padding slices
      const k = clamp(clamp(z - 1, mz) - pad, nz);
      for (let y = 0; y < my; y++) {
        const j = clamp(y - pad, ny);
        for (let x = 0; x < mx; x++) {
          const i = clamp(x - pad, nx);
          const src = (((s * (nz + 2) + 1 + k) * ny + j) * nx + i) * 4;
          const dst = (((s * (mz + 2) + z) * my + y) * mx + x) * 4;
          out[dst] = data[src]; out[dst + 1] = data[src + 1]; out[dst + 2] = data[src + 2]; out[dst + 3] = data[src + 3];
        }
      }
    }
  }
  return { data: out, counts: [mx, my, mz], depth: SH_L2_TEXELS * (mz + 2) };
}

/** x of A x = b (n × n, row-major arrays; Gaussian elimination with partial pivoting). */
function solve(A, b) {
  const n = b.length;
  const m = A.map((r, i) => [...r, b[i]]);
  for (let c = 0; c < n; c++) {
    let p = c;
    for (let r = c + 1; r < n; r++) if (Math.abs(m[r][c]) > Math.abs(m[p][c])) p = r;
    [m[c], m[p]] = [m[p], m[c]];
    for (let r = c + 1; r < n; r++) {
      const f = m[r][c] / m[c][c];
      for (let k = c; k <= n; k++) m[r][k] -= f * m[c][k];
    }
  }
  const x = new Array(n).fill(0);
  for (let r = n - 1; r >= 0; r--) {
    let v = m[r][n];
    for (let k = r + 1; k < n; k++) v -= m[r][k] * x[k];
    x[r] = v / m[r][r];
  }
  return x;
}

/**
 * The 9 × 9 matrix R (rows of 9) that turns L2 SH coefficients of the bake frame into the world's: for a function
 * f_bake on directions of the bake frame, f_world(d) = f_bake(M·d) has coefficients c_world = R·c_bake (each
 * colour channel alike). M: world -> bake, 3 rows (frameMatrix). Exact (each band is closed under rotation): the
 * least-squares fit over 64 Fibonacci directions, R = (AᵀA)⁻¹AᵀB with A = Y(d_i), B = Y(M·d_i).
 * @param {number[][]} M
 * @returns {number[][]}
 */
export function shRotationL2(M) {
  const N = 64, A = [], B = [];
  for (let i = 0; i < N; i++) {
    const z = 1 - (2 * i + 1) / N, r = Math.sqrt(Math.max(0, 1 - z * z)), phi = 2 * Math.PI * ((i * 0.6180339887498949) % 1);
    const d = [Math.cos(phi) * r, Math.sin(phi) * r, z];
    const e = M.map((row) => row[0] * d[0] + row[1] * d[1] + row[2] * d[2]);
    A.push(shBasisL2(d));
    B.push(shBasisL2(e));
  }
  const AtA = [...Array(9)].map((_, j) => [...Array(9)].map((__, k) => A.reduce((s, a) => s + a[j] * a[k], 0)));
  const cols = [...Array(9)].map((_, k) => solve(AtA, [...Array(9)].map((__, j) => A.reduce((s, a, i) => s + a[j] * B[i][k], 0))));
  return [...Array(9)].map((_, j) => cols.map((c) => c[j]));
}

/**
 * A turned or rectilinear bake's `sh_l2` resampled onto an axis-aligned world grid, for three's LightProbeGrid (which
 * cannot turn, README "The bake frame", and has uniform cells; fitsProbeGrid). The world box is the axis-aligned box
 * around the turned probes' box (each side `pad` cells past the outer probes or outer layers, as probeGridBox), cut
 * into cells about the bake's spacing (a rectilinear grid's: the mean gap; x and z of a turned bake: the smaller of
 * its x and z spacing). At each world cell centre p the value is Kiln's leaking lookup of the bake at M·p (trilinear
 * over the 8 probes around it — between the layers of a rectilinear grid, math/sh.js gridIndex — clamped to the outer
 * probes, proto/bundle.md 5.1), its SH turned into the world frame (shRotationL2). So three's lookup of the result is
 * Kiln's leaking lookup filtered once more by a trilinear interpolation over the world cells: exact for light that
 * varies linearly in space, a little softer elsewhere (on a rectilinear grid: where its layers are closer than a cell).
 * @param {ArrayLike<number>} data  the `sh_l2` atlas as stored ((7·(nz + 2), ny, nx, 4): Float32Array, or
 *   Uint16Array of half-float bits, read and written as half floats)
 * @param {{origin: number[], spacing: number[], counts: number[], layers?: number[][]|null}} grid  manifest.grid
 *   (bake frame; `layers`: a rectilinear grid's [xs, ys, zs], metres)
 * @param {number[][]} M  world -> bake (frameMatrix(grid); the identity for an unturned rectilinear bake)
 * @param {number} [pad=1]
 * @returns {{data: ArrayLike<number>, box: ReturnType<typeof probeGridBox>, depth: number}}  the world grid's atlas in
 *   the same layout and typed-array type, and its box (the arguments of LightProbeGridWebGL)
 */
export function resampleShL2(data, grid, M, pad = 1) {
  const [nx, ny, nz] = vec(grid.counts);
  const o = vec(grid.origin);
  const s = cellSize(grid);
  const layers = gridLayers(grid);
  const expected = SH_L2_TEXELS * (nz + 2) * ny * nx * 4;
  if (data.length !== expected) throw new RangeError(`sh_l2 of ${data.length} values, expected 7·(nz+2)·ny·nx·4 = ${expected}`);
  const half = data instanceof Uint16Array;
  // Kiln's leaking lookup (math/sh.js sampleShL2: trilinear, clamped to the outer probes) over a float copy
  const volume = { width: nx, height: ny, depth: SH_L2_TEXELS * (nz + 2), components: 4,
    data: half ? Float32Array.from(data, (x) => DataUtils.fromHalfFloat(x)) : data };
  // the turned box (bake frame, pad cells past the outer probes: the first and last layers of a rectilinear grid) and
  // the world box around it
  const bmin = layers ? layers.map((L, a) => L[0] - s[a] * (0.5 + pad)) : o.map((x, a) => x - s[a] * (0.5 + pad));
  const bmax = layers ? layers.map((L, a) => L[L.length - 1] + s[a] * (0.5 + pad))
    : o.map((x, a) => x + s[a] * ([nx, ny, nz][a] - 0.5 + pad));
  const min = [Infinity, Infinity, Infinity], max = [-Infinity, -Infinity, -Infinity];
  for (let c = 0; c < 8; c++) {
    const q = [c & 1 ? bmax[0] : bmin[0], c & 2 ? bmax[1] : bmin[1], c & 4 ? bmax[2] : bmin[2]];
    const w = [0, 1, 2].map((i) => M[0][i] * q[0] + M[1][i] * q[1] + M[2][i] * q[2]);   // Mᵀ·q: bake -> world
    for (let a = 0; a < 3; a++) { min[a] = Math.min(min[a], w[a]); max[a] = Math.max(max[a], w[a]); }
  }
  // world cells: the bake's spacing per axis where the bake frame is the world (an unturned rectilinear bake: the cells
  // then sit at the mean-spacing layers, a uniform grid's probes exactly), x and z the smaller of the two where x and
  // z mix (a turned bake)
  const h = isIdentity(M) ? s.slice() : [Math.min(s[0], s[2]), s[1], Math.min(s[0], s[2])];
  const size = max.map((x, a) => x - min[a]);
  const res = size.map((x, a) => Math.max(1, Math.round(x / h[a])));
  const [mx, my, mz] = res;
  const R = shRotationL2(M);
  const out = new (half ? Uint16Array : Float32Array)(SH_L2_TEXELS * (mz + 2) * my * mx * 4);
  const lookup = { origin: o, spacing: s, counts: [nx, ny, nz], layers };
  for (let z = 0; z < mz; z++) {
    for (let y = 0; y < my; y++) {
      for (let x = 0; x < mx; x++) {
        const p = [min[0] + ((x + 0.5) * size[0]) / mx, min[1] + ((y + 0.5) * size[1]) / my, min[2] + ((z + 0.5) * size[2]) / mz];
        const cb = sampleShL2(volume, M.map((row) => row[0] * p[0] + row[1] * p[1] + row[2] * p[2]), lookup);
        for (let t = 0; t < 28; t++) {      // the world SH R·c per channel, in the stored order c0.rgb, ..., c8.rgb, 0
          const k = Math.floor(t / 3), ch = t % 3;
          const v = t < 27 ? R[k].reduce((acc, r, j) => acc + r * cb[j][ch], 0) : 0;
          const val = half ? DataUtils.toHalfFloat(v) : v;
          const sub = t >> 2;
          for (const zz of z === 0 ? (mz === 1 ? [0, 1, 2] : [0, 1]) : z === mz - 1 ? [z + 1, z + 2] : [z + 1]) {
            out[(((sub * (mz + 2) + zz) * my + y) * mx + x) * 4 + (t & 3)] = val;
          }
        }
      }
    }
  }
  return { data: out, depth: SH_L2_TEXELS * (mz + 2),
    box: { min, max, size, center: max.map((x, a) => (x + min[a]) / 2), resolution: res } };
}

/**
 * The bake frame of a grid (manifest `grid.frame`, the place stage's stats `frame`; proto/bundle.md 5): M (world ->
 * bake, row-major) and whether it is the identity. One reader for the viewer and @kiln/three: web/src/math/frame.js.
 */
export { frameMatrix, isIdentity as isIdentityFrame } from '../../src/math/frame.js';
