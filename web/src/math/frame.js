/**
 * The bake frame (the manifest's `grid.frame`, the place stage's stats `frame`): the world (glTF) turned about +Y by
 * a yaw fitted to the walls. Every probe artifact (grid origin/spacing/counts, probe positions, SH and mask volumes,
 * DDGI atlases, PRT points and `prt_lights`) is in the bake frame. `matrix` M is row-major, world -> bake:
 * p_bake[i] = Σ_j M[i][j] · p_world[j], for positions (about the world origin, no translation) and directions alike;
 * a pure rotation, so bake -> world is Mᵀ. A bake without `frame` (older bakes, yaw 0) is the identity.
 *
 * Consumers: the shaders' uGiFrame (proto/glsl/gi_view.glsl; renderer.js setFrame, kiln-three gi.js), the probe
 * spheres and the PRT relight light (view/viewer.js). Python: workers/render/shading.py frame_matrix.
 */

export const IDENTITY = Object.freeze([Object.freeze([1, 0, 0]), Object.freeze([0, 1, 0]), Object.freeze([0, 0, 1])]);

/** R_y(θ)ᵀ for θ = `deg` degrees: the bake frame's M from its yaw alone. */
function fromYaw(deg) {
  const t = (Number(deg) * Math.PI) / 180;
  if (!Number.isFinite(t)) throw new RangeError(`bake frame: yaw_deg must be a finite number, got ${JSON.stringify(deg)}`);
  const c = Math.cos(t), s = Math.sin(t);
  return [[c, 0, -s], [0, 1, 0], [s, 0, c]];
}

/**
 * M (3 rows of 3 numbers, world -> bake) of a grid (`{counts, origin, spacing, frame?}`), of its `frame`
 * (`{yaw_deg, matrix, ...}`) or of a matrix; null / no frame -> the identity. A frame without `matrix` gives
 * R_y(yaw_deg)ᵀ. Throws a RangeError unless M is a finite rotation (M Mᵀ = I within 1e-4, det +1) agreeing with the
 * frame's `yaw_deg` (1e-3; a transposed matrix is refused). The viewer's and @kiln/three's reader.
 */
export function frameMatrix(source) {
  if (source == null) return IDENTITY;
  let f = Array.isArray(source) ? { matrix: source } : source;
  if (!('matrix' in f) && !('yaw_deg' in f)) f = f.frame;      // a grid
  if (f == null || (f.matrix == null && f.yaw_deg == null)) return IDENTITY;
  if (f.matrix == null) return fromYaw(f.yaw_deg);
  const rows = Array.from(f.matrix, (r) => Array.from(r ?? [], Number));
  if (rows.length !== 3 || rows.some((r) => r.length !== 3 || r.some((x) => !Number.isFinite(x)))) {
    throw new RangeError(`bake frame: want a finite 3x3 matrix, got ${JSON.stringify(f.matrix)}`);
  }
  for (let i = 0; i < 3; i++) {
    for (let j = 0; j < 3; j++) {
      const d = rows[i][0] * rows[j][0] + rows[i][1] * rows[j][1] + rows[i][2] * rows[j][2];
      if (Math.abs(d - (i === j ? 1 : 0)) > 1e-4) throw new RangeError(`bake frame: ${JSON.stringify(rows)} is not a rotation`);
    }
  }
  const [a, b, c] = rows;
  const det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
  if (det < 0) throw new RangeError(`bake frame: ${JSON.stringify(rows)} is a reflection, not a rotation`);
  if (f.yaw_deg != null) {
    const y = fromYaw(f.yaw_deg);
    if (rows.some((r, i) => r.some((x, j) => Math.abs(x - y[i][j]) > 1e-3))) {
      throw new RangeError(`bake frame: ${JSON.stringify(rows)} is not R_y(${f.yaw_deg}°)ᵀ (world -> bake, row-major)`);
    }
  }
  return rows;
}

/** True for the identity (within 1e-9): the bake frame is the world. */
export function isIdentity(m) {
  return m.every((r, i) => r.every((x, j) => Math.abs(x - (i === j ? 1 : 0)) <= 1e-9));
}

/** M · v: a world point or direction in the bake frame. */
export function toBake(m, v) {
  return [0, 1, 2].map((i) => m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]);
}

/** Mᵀ · v: a bake-frame point or direction in the world. */
export function toWorld(m, v) {
  return [0, 1, 2].map((i) => m[0][i] * v[0] + m[1][i] * v[1] + m[2][i] * v[2]);
}

/**
 * n bake-frame points (`data`, `stride` numbers per point, xyz first) in the world: a new Float32Array of n·3.
 * `n` defaults to all of `data`.
 */
export function pointsToWorld(m, data, stride = 3, n = Math.floor(data.length / stride)) {
  const out = new Float32Array(n * 3);
  for (let p = 0; p < n; p++) {
    const x = data[p * stride], y = data[p * stride + 1], z = data[p * stride + 2];
    for (let i = 0; i < 3; i++) out[p * 3 + i] = m[0][i] * x + m[1][i] * y + m[2][i] * z;
  }
  return out;
}

/**
 * The 9 numbers of uGiFrame (proto/glsl/gi_view.glsl) in GLSL's column-major order, so that uGiFrame * p_world =
 * M · p_world: column j = M's column j. (three.js Matrix3.set(...M rows) stores the same elements.)
 */
export function frameUniform(m) {
  return Float32Array.from([0, 1, 2].flatMap((j) => [m[0][j], m[1][j], m[2][j]]));
}

/**
 * A KHR light (the `lights` artifact's form) moved by `map` (toBake / toWorld): position and direction turned, the
 * rest kept. Returns a new object.
 */
export function mapLight(m, light, map) {
  const out = { ...light };
  if (light.position) out.position = map(m, light.position);
  if (light.direction) out.direction = map(m, light.direction);
  return out;
}
