// The DDGI atlas layout the viewer binds (no three.js here: state/modes.js imports it too).

/**
 * Tiles per row of a DDGI octahedral atlas re-packed to fit `maxWidth` texels (0: it fits as stored). As
 * workers/render/shading.py wrap_atlas: the atlas is nz·nx tiles wide (proto/bundle.md 5.1), too wide for a
 * 16,384-texel device from about 1,640 probes per layer (sealed-box's automatic 53 x 8 x 53 grid: 28,090).
 */
export function atlasColumns(width, tile, maxWidth) {
  if (width <= maxWidth) return 0;
  const columns = Math.floor(maxWidth / tile);
  if (columns < 1) throw new Error(`an atlas tile of ${tile} texels does not fit ${maxWidth}`);
  return columns;
}


/**
 * A DDGI atlas stored without its tile borders (the artifact's `meta.stored_border` 0, proto/bundle.md 5.1) with
 * the borders added back, as proto/atlas.py atlas_add_border: every n × n tile (n = `texels`) becomes n + 2 wide,
 * its 1-texel border the mirrored copies of RTXGI (top row = first row with columns flipped, bottom likewise, left
 * column = first column with rows flipped, right likewise, each corner from the opposite interior corner).
 * `rec` is a parsed KTX2 record (loader/ktx2.js parseKTX2 or kiln-three's): any kind, `valuesPerTexel` (or
 * `components`) values a texel, packed formats one word. Returns a new record (no three.js texture).
 */
export function atlasWithBorder(rec, texels) {
  const n = Number(texels);
  const vpt = rec.valuesPerTexel ?? rec.components;
  if (!(n >= 1) || rec.width % n || rec.height % n) throw new Error(`atlas of ${rec.width} x ${rec.height} is not made of ${n} x ${n} tiles`);
  const cols = rec.width / n;
  const rows = rec.height / n;
  const t = n + 2;
  const width = cols * t;
  const height = rows * t;
  const data = new rec.data.constructor(width * height * vpt);
  const src = rec.data;
  // interior texel (r, c) of tile (R, C) -> bordered texel (r + 1, c + 1); the border per add_border
  const from = (R, C, r, c) => ((R * n + r) * rec.width + C * n + c) * vpt;
  const to = (R, C, y, x) => ((R * t + y) * width + C * t + x) * vpt;
  const copy = (d, s) => { for (let k = 0; k < vpt; k++) data[d + k] = src[s + k]; };
  for (let R = 0; R < rows; R++) {
    for (let C = 0; C < cols; C++) {
      for (let r = 0; r < n; r++) {
        for (let c = 0; c < n; c++) copy(to(R, C, r + 1, c + 1), from(R, C, r, c));
      }
      for (let c = 0; c < n; c++) {
        copy(to(R, C, 0, c + 1), from(R, C, 0, n - 1 - c));
        copy(to(R, C, n + 1, c + 1), from(R, C, n - 1, n - 1 - c));
      }
      for (let r = 0; r < n; r++) {
        copy(to(R, C, r + 1, 0), from(R, C, n - 1 - r, 0));
        copy(to(R, C, r + 1, n + 1), from(R, C, n - 1 - r, n - 1));
      }
      copy(to(R, C, 0, 0), from(R, C, n - 1, n - 1));
      copy(to(R, C, 0, n + 1), from(R, C, n - 1, 0));
      copy(to(R, C, n + 1, 0), from(R, C, 0, n - 1));
      copy(to(R, C, n + 1, n + 1), from(R, C, 0, 0));
    }
  }
  const { texture, ...rest } = rec;  // eslint-disable-line no-unused-vars
  return { ...rest, width, height, data };
}

/** The record of an artifact as the renderers bind it: a border-stripped atlas (`info.meta.stored_border` 0) with
 * its borders added back (atlasWithBorder), anything else as it is. */
export function withStoredBorder(rec, info) {
  const meta = info?.meta;
  return meta && meta.stored_border === 0 ? atlasWithBorder(rec, meta.texels) : rec;
}
