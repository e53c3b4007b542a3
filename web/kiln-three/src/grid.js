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
 */

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
 * three.js LightProbeGrid box of a Kiln grid.
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

/**
 * The bake frame of a grid (manifest `grid.frame`, the place stage's stats `frame`; proto/bundle.md 5): M (world ->
 * bake, row-major) and whether it is the identity. One reader for the viewer and @kiln/three: web/src/math/frame.js.
 */
export { frameMatrix, isIdentity as isIdentityFrame } from '../../src/math/frame.js';
