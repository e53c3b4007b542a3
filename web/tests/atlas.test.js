// The DDGI atlas re-pack for devices narrower than nz·nx tiles (math/atlas.js, renderer/textures.js wrapAtlas),
// the layout octahedral.glsl octAtlasUVWrapped reads and workers/render/shading.py wrap_atlas writes.
import { describe, expect, it } from 'vitest';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { atlasColumns, atlasWithBorder, withStoredBorder } from '../src/math/atlas.js';
import { parseKTX2 } from '../src/loader/ktx2.js';
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

describe('atlasWithBorder (a DDGI atlas stored without its tile borders, proto/atlas.py atlas_add_border)', () => {
  const FIX = fileURLToPath(new URL('../../proto/fixtures/', import.meta.url));
  const expected = JSON.parse(readFileSync(FIX + 'expected.json', 'utf8'));

  function strip(rec, n) {
    const tt = n + 2;
    const cols = rec.width / tt;
    const rows = rec.height / tt;
    const vpt = rec.valuesPerTexel ?? rec.components;
    const width = cols * n;
    const data = new rec.data.constructor(width * rows * n * vpt);
    for (let y = 0; y < rows * n; y++) {
      for (let x = 0; x < width; x++) {
        const sy = Math.floor(y / n) * tt + (y % n) + 1;
        const sx = Math.floor(x / n) * tt + (x % n) + 1;
        for (let k = 0; k < vpt; k++) data[(y * width + x) * vpt + k] = rec.data[(sy * rec.width + sx) * vpt + k];
      }
    }
    return { ...rec, width, height: rows * n, data };
  }

  it('gives back the Python-written bordered atlas from its interior texels', () => {
    const a = expected.atlas;
    const rec = parseKTX2(new Uint8Array(readFileSync(FIX + a.file)));
    const back = atlasWithBorder(strip(rec, a.texels), a.texels);
    expect([back.width, back.height]).toEqual([rec.width, rec.height]);
    expect(Array.from(back.data)).toEqual(Array.from(rec.data));
    expect(withStoredBorder(strip(rec, a.texels), { meta: { stored_border: 0, texels: a.texels } }).data).toEqual(back.data);
    expect(withStoredBorder(rec, { meta: { texels: a.texels } })).toBe(rec);      // bordered as stored: untouched
  });

  it('copies whole packed words (one value a texel) and drops a three.js texture', () => {
    const n = 2;
    const words = Uint32Array.from([1, 2, 3, 4, 5, 6, 7, 8]);   // two 2 x 2 tiles side by side
    const rec = { kind: 'ufloat-packed', components: 3, valuesPerTexel: 1, width: 4, height: 2, data: words, texture: {} };
    const b = atlasWithBorder(rec, n);
    expect([b.width, b.height, b.texture, b.data.constructor.name]).toEqual([8, 4, undefined, 'Uint32Array']);
    // tile 0 interior [[1, 2], [5, 6]]: bordered rows as add_border builds them
    const row = (y) => Array.from(b.data.subarray(y * 8, y * 8 + 4));
    expect([row(0), row(1), row(2), row(3)]).toEqual([[6, 2, 1, 5], [5, 1, 2, 6], [1, 5, 6, 2], [2, 6, 5, 1]]);
  });
});
