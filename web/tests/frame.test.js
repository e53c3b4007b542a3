// The bake frame (manifest grid.frame, place stats `frame`; web/src/math/frame.js): the matrix M (row-major, world ->
// bake) read from a bake, uGiFrame's element order, the probe spheres' world positions (Mᵀ) and the PRT relight light
// turned into the bake frame (M) before the direct vector at the bake-frame measurement points.
import { describe, expect, it } from 'vitest';
import { Matrix3, Vector3 } from 'three';
import { IDENTITY, frameMatrix, frameUniform, isIdentity, pointsToWorld, toBake, toWorld } from '../src/math/frame.js';
import { bakeGrid, gridPointWorld, lightInBakeFrame, probeWorldPositions } from '../src/view/viewer.js';
import { directVector } from '../src/math/prt.js';

/** R_y(θ) = [[cos θ, 0, sin θ], [0, 1, 0], [-sin θ, 0, cos θ]]; the bake frame of yaw θ is M = R_y(θ)ᵀ. */
function yaw(deg) {
  const t = (deg * Math.PI) / 180, c = Math.cos(t), s = Math.sin(t);
  return [[c, 0, s], [0, 1, 0], [-s, 0, c]];
}
const transpose = (m) => [0, 1, 2].map((i) => [0, 1, 2].map((j) => m[j][i]));
const M = transpose(yaw(30));
const close = (got, want, tol = 1e-6) => {
  expect(got.length).toBe(want.length);
  want.forEach((w, i) => expect(Math.abs(got[i] - w)).toBeLessThanOrEqual(tol * (1 + Math.abs(w))));
};

/** A bake record as the server returns it, the place stage's stats with (or without) `frame`. */
function bake(frame) {
  const stats = { counts: [3, 2, 2], origin: [0.5, 0.25, -1], spacing: [1, 0.5, 2], ...(frame ? { frame } : {}) };
  return { id: 'b', stages: [{ name: 'place', stats }] };
}

describe('bake frame matrix', () => {
  it('is the identity without grid.frame and grid.frame.matrix as given with one', () => {
    expect(frameMatrix(null)).toBe(IDENTITY);
    expect(frameMatrix(bakeGrid(bake(null)))).toBe(IDENTITY);
    expect(bakeGrid(bake(null)).frame).toBe(null);
    const g = bakeGrid(bake({ yaw_deg: 30, matrix: M, info: 'x' }));
    expect(g.frame.yaw_deg).toBe(30);
    expect(frameMatrix(g)).toEqual(M);
    expect(frameMatrix(g.frame)).toEqual(M);
    expect(frameMatrix(M)).toEqual(M);
    expect(isIdentity(frameMatrix(g))).toBe(false);
    expect(isIdentity(IDENTITY)).toBe(true);
  });

  it('refuses what is not a rotation', () => {
    for (const bad of [[[2, 0, 0], [0, 2, 0], [0, 0, 2]], [[1, 0, 0], [0, 1, 0], [0, 0, -1]], [[1, 0], [0, 1]],
      [[NaN, 0, 0], [0, 1, 0], [0, 0, 1]]]) {
      expect(() => frameMatrix({ matrix: bad })).toThrow(/bake frame/);
    }
  });

  it('uploads uGiFrame so that uGiFrame * p_world = M · p_world (GLSL column-major; three Matrix3.set takes rows)', () => {
    const p = [0.3, -1.2, 2.5];
    const e = frameUniform(M);
    const glsl = [0, 1, 2].map((i) => e[i] * p[0] + e[3 + i] * p[1] + e[6 + i] * p[2]);  // mat3 * vec3, columns e[3j..]
    close(glsl, toBake(M, p));
    close(toBake(M, p), [0, 1, 2].map((i) => M[i][0] * p[0] + M[i][1] * p[1] + M[i][2] * p[2]));
    const m3 = new Matrix3().set(...M[0], ...M[1], ...M[2]);  // what renderer.js setFrame and kiln-three upload
    close(Array.from(m3.elements), Array.from(e));
    close(new Vector3(...p).applyMatrix3(m3).toArray(), toBake(M, p));
    close(toWorld(M, toBake(M, p)), p);
    // M = R_y(30°)ᵀ: world +X is (cos 30°, 0, sin 30°) in the bake frame; the bake frame's +X is R_y(30°) x̂ in the world
    const c = Math.cos(Math.PI / 6), s = Math.sin(Math.PI / 6);
    close(toBake(M, [1, 0, 0]), [c, 0, s]);
    close(toWorld(M, [1, 0, 0]), [c, 0, -s]);
  });
});

describe('the viewer in the bake frame', () => {
  const grid = bakeGrid(bake({ yaw_deg: 30, matrix: M }));
  const n = 3 * 2 * 2;
  const stride = 4;  // RGBA-like rows: xyz + a fourth number, as a KTX2 record may hold them
  const bakePos = Float32Array.from({ length: n * stride }, (_, i) => ((i * 7919) % 101) / 10 - 5);

  it('draws the probe spheres at Mᵀ · (relocated position), in the world', () => {
    const world = probeWorldPositions(grid, bakePos, stride);
    expect(world.length).toBe(n * 3);
    for (let p = 0; p < n; p++) {
      const b = Array.from(bakePos.slice(p * stride, p * stride + 3));
      close(toBake(M, Array.from(world.slice(p * 3, p * 3 + 3))), b, 1e-5);
    }
    // the grid without a frame: positions as stored; with one, not
    const plain = probeWorldPositions(bakeGrid(bake(null)), bakePos, stride);
    for (let p = 0; p < n; p++) close(Array.from(plain.slice(p * 3, p * 3 + 3)), Array.from(bakePos.slice(p * stride, p * stride + 3)));
    expect(Math.max(...world.map((x, i) => Math.abs(x - plain[i])))).toBeGreaterThan(0.5);
    close(Array.from(pointsToWorld(IDENTITY, [1, 2, 3])), [1, 2, 3]);
  });

  it('maps grid points (exposure samples, the PRT default light) to the world', () => {
    const centre = gridPointWorld(grid, grid.counts.map((c) => (c - 1) / 2));
    close(toBake(M, centre), [0.5 + 1, 0.25 + 0.25, -1 + 1]);
    close(gridPointWorld(bakeGrid(bake(null)), [2, 1, 1]), [2.5, 0.75, 1]);
  });

  it('relights the bake-frame measurement points with the world light turned by M', () => {
    // a (K, 9) table: position, normal, albedo; offsets average pairs of rows
    const K = 8;
    const worldRows = [];
    for (let k = 0; k < K; k++) {
      const pos = [Math.sin(k) * 2, 0.5 + (k % 3) * 0.4, Math.cos(k * 1.3) * 2];
      const nl = [Math.cos(k), 0.6, Math.sin(k)];
      const len = Math.hypot(...nl);
      worldRows.push([...pos, ...nl.map((x) => x / len), 0.8, 0.6, 0.4]);
    }
    const bakeTable = Float32Array.from(worldRows.flatMap((r) => [...toBake(M, r.slice(0, 3)), ...toBake(M, r.slice(3, 6)), ...r.slice(6)]));
    const worldTable = Float32Array.from(worldRows.flat());
    const offsets = Int32Array.from([0, 2, 4, 6, 8]);
    const lights = [
      { type: 'point', position: [0.4, 2.0, -0.3], color: [1, 0.8, 0.6], intensity: 12, range: null },
      { type: 'spot', position: [-1.5, 1.8, 0.5], direction: [0.5, -0.8, -0.1], color: [0.5, 0.5, 1], intensity: 30,
        range: 8, inner_cone_angle: 0.3, outer_cone_angle: 0.9 },
      { type: 'directional', direction: [0.6, -0.7, 0.3], color: [1, 1, 1], intensity: 2 },
    ];
    for (const light of lights) {
      const want = directVector(worldTable, offsets, [light]);
      const inBake = lightInBakeFrame(grid, light);
      expect(light.position ?? null).toEqual(lights.find((l) => l.type === light.type).position ?? null);  // not mutated
      const got = directVector(bakeTable, offsets, [inBake]);
      expect(Math.max(...want)).toBeGreaterThan(0);
      close(Array.from(got), Array.from(want), 1e-5);
      // the world light at the bake-frame points (no mapping): another vector
      const wrong = directVector(bakeTable, offsets, [light]);
      expect(Math.max(...Array.from(wrong).map((x, i) => Math.abs(x - want[i])))).toBeGreaterThan(0.01 * Math.max(...want));
    }
    expect(lightInBakeFrame(bakeGrid(bake(null)), lights[0]).position).toEqual(lights[0].position);
  });
});
