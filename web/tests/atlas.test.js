// The DDGI atlas re-pack for devices narrower than nz·nx tiles (math/atlas.js, renderer/textures.js wrapAtlas),
// the layout octahedral.glsl octAtlasUVWrapped reads and workers/render/shading.py wrap_atlas writes.
import { describe, expect, it } from 'vitest';
import { atlasColumns } from '../src/math/atlas.js';
import { wrapAtlas } from '../src/renderer/textures.js';

const counts = [3, 2, 2];          // nx, ny, nz: 6 tiles per row block, 2 rows of tiles
const t = 4;                       // tile texels (n + 2)
const comp = 2;

function atlas() {
  const width = counts[0] * counts[2] * t;
  const height = counts[1] * t;
  const data = new Float32Array(width * height * comp);
  for (let y = 0; y < height; y++) for (let x = 0; x < width; x++) {
    data[(y * width + x) * comp] = 1000 * Math.floor(x / t) + 100 * Math.floor(y / t) + 10 * (y % t) + (x % t);
    data[(y * width + x) * comp + 1] = -1;
  }
  return { kind: 'float', components: comp, width, height, depth: 0, is3D: false, data };
}

describe('DDGI atlas re-pack', () => {
  it('keeps an atlas that fits and wraps one that does not', () => {
    expect(atlasColumns(24, t, 16384)).toBe(0);
    expect(atlasColumns(24, t, 8)).toBe(2);
    expect(atlasColumns(28090, 10, 16384)).toBe(1638);        // sealed-box's 53 x 8 x 53 grid, 8-texel maps
    expect(() => atlasColumns(24, t, 3)).toThrow(/does not fit/);
  });

  it('moves tile c = k·nx + i of layer j to column c mod columns, row j + (c div columns)·ny', () => {
    const a = atlas();
    const columns = atlasColumns(a.width, t, 8);
    const w = wrapAtlas(a, counts, columns);
    expect([w.width, w.height]).toEqual([2 * t, 3 * counts[1] * t]);   // 6 tiles in 3 blocks of 2
    for (let c = 0; c < 6; c++) for (let j = 0; j < counts[1]; j++) for (let y = 0; y < t; y++) for (let x = 0; x < t; x++) {
      const col = c % columns;
      const row = j + Math.floor(c / columns) * counts[1];           // octAtlasUVWrapped
      const v = w.data[((row * t + y) * w.width + col * t + x) * comp];
      expect(v).toBe(1000 * c + 100 * j + 10 * y + x);
    }
    expect(wrapAtlas(a, counts, 0)).toBe(a);
  });
});
