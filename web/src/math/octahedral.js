/**
 * CPU mirror of proto/glsl/octahedral.glsl and of workers/kernels/octahedral.py: octahedral encoding with
 * the fold on +Z (Cigolle et al. 2014; the octahedral probe maps of DDGI-I §3.1) and the atlas tiling of
 * proto/bundle.md 5.1.
 */

const signNotZero = (v) => (v >= 0 ? 1 : -1);

/** Direction [x, y, z] (non-zero) -> [u, v] in [-1, 1]². */
export function octEncode(d) {
  const l1 = Math.abs(d[0]) + Math.abs(d[1]) + Math.abs(d[2]);
  const px = d[0] / l1, py = d[1] / l1;
  if (d[2] < 0) return [(1 - Math.abs(py)) * signNotZero(px), (1 - Math.abs(px)) * signNotZero(py)];
  return [px, py];
}

/** [u, v] -> unit direction. */
export function octDecode(uv) {
  const u = Math.min(1, Math.max(-1, uv[0]));
  const v = Math.min(1, Math.max(-1, uv[1]));
  const z = 1 - Math.abs(u) - Math.abs(v);
  let x = u, y = v;
  if (z < 0) { x = (1 - Math.abs(v)) * signNotZero(u); y = (1 - Math.abs(u)) * signNotZero(v); }
  const len = Math.hypot(x, y, z);
  return [x / len, y / len, z / len];
}

/** Direction of interior texel (row r, column c) of an n x n map (0-based, without border). */
export function octTexelDirection(r, c, n) {
  return octDecode([((c + 0.5) * 2) / n - 1, ((r + 0.5) * 2) / n - 1]);
}

/**
 * Where probe (i, j, k)'s tile starts in an atlas of tiles of t = n + 2 texels: row j·t, column (k·nx + i)·t.
 * @returns {{row: number, col: number}}
 */
export function atlasTileOrigin(i, j, k, nx, n) {
  const t = n + 2;
  return { row: j * t, col: (k * nx + i) * t };
}

/**
 * Value of interior texel (r, c) of probe (i, j, k)'s tile in an atlas (parsed KTX2: width, components, data).
 * @returns {number[]}
 */
export function atlasTexel(atlas, i, j, k, r, c, nx, n) {
  const { row, col } = atlasTileOrigin(i, j, k, nx, n);
  const base = ((row + 1 + r) * atlas.width + (col + 1 + c)) * atlas.components;
  return Array.from(atlas.data.subarray(base, base + atlas.components));
}
