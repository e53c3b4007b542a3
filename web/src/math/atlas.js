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

