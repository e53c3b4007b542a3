/**
 * Debug images drawn on 2D canvases from decoded artifacts: the octahedral irradiance and depth atlases
 * (bundle.md 5.1 tiling, one tile per probe) and slices of the visibility field θ (MD §3.4) with the
 * "don't care" samples in red. Row 0 of an atlas is drawn at the top.
 */

import { texelsAsNumbers } from '../loader/ktx2.js';

function percentile(values, q) {
  const a = Float32Array.from(values).filter((x) => Number.isFinite(x)).sort();
  return a.length ? a[Math.min(a.length - 1, Math.floor(q * a.length))] : 1;
}

function toCanvas(canvas, width, height, fill) {
  canvas.width = width;
  canvas.height = height;
  const ctx = canvas.getContext('2d');
  const img = ctx.createImageData(width, height);
  fill(img.data);
  ctx.putImageData(img, 0, 0);
  return canvas;
}

const srgb8 = (c) => Math.round(255 * Math.min(1, Math.max(0, c <= 0.0031308 ? c * 12.92 : 1.055 * c ** (1 / 2.4) - 0.055)));

/** Irradiance atlas (RGBA16F, RGBA32F or the packed R11G11B10F): linear RGB scaled so the 99th percentile is 1, then sRGB. */
export function drawIrradianceAtlas(canvas, atlas) {
  const { width: W, height: H, components: C } = atlas;
  const data = texelsAsNumbers(atlas);
  const lum = new Float32Array(W * H);
  for (let i = 0; i < W * H; i++) lum[i] = Math.max(data[i * C], data[i * C + 1], data[i * C + 2]);
  const scale = 1 / Math.max(1e-6, percentile(lum, 0.99));
  return toCanvas(canvas, W, H, (px) => {
    for (let i = 0; i < W * H; i++) {
      for (let c = 0; c < 3; c++) px[i * 4 + c] = srgb8(data[i * C + c] * scale);
      px[i * 4 + 3] = 255;
    }
  });
}

/** Depth-moment atlas (RG16F or RG32F): mean distance, grey from 0 (black) to the 99th percentile (white). */
export function drawDepthAtlas(canvas, atlas) {
  const { width: W, height: H, components: C } = atlas;
  const data = texelsAsNumbers(atlas);
  const d = new Float32Array(W * H);
  for (let i = 0; i < W * H; i++) d[i] = data[i * C];
  const scale = 1 / Math.max(1e-6, percentile(d, 0.99));
  return toCanvas(canvas, W, H, (px) => {
    for (let i = 0; i < W * H; i++) {
      const g = Math.round(255 * Math.min(1, Math.max(0, d[i] * scale)));
      px[i * 4] = px[i * 4 + 1] = px[i * 4 + 2] = g;
      px[i * 4 + 3] = 255;
    }
  });
}

/**
 * Draw one axis slice of a (Z, Y, X, C) volume: 'z' shows an x-y slice (y up), 'y' an x-z slice, 'x' a z-y
 * slice. `pixel(t, out, o)` writes the RGB of voxel t (linear index, x fastest) at out[o..o+2].
 */
export function drawVolumeSlice(canvas, { width: X, height: Y, depth: Z }, axis, index, pixel) {
  const [w, hgt] = { z: [X, Y], y: [X, Z], x: [Z, Y] }[axis];
  const at = (u, v) => {  // u right, v up -> (x, y, z)
    if (axis === 'z') return [u, v, index];
    if (axis === 'y') return [u, index, v];
    return [index, v, u];
  };
  return toCanvas(canvas, w, hgt, (px) => {
    for (let row = 0; row < hgt; row++) for (let u = 0; u < w; u++) {
      const v = hgt - 1 - row;  // up is +v
      const [x, y, z] = at(u, v);
      const o = (row * w + u) * 4;
      pixel((z * Y + y) * X + x, px, o);
      px[o + 3] = 255;
    }
  });
}

/**
 * One slice of θ for one cell corner (0-7), along an axis (drawVolumeSlice). theta0123/theta4567: RGBA8
 * volumes (Z, Y, X, 4); dontCare: R8 volume or null.
 */
export function drawThetaSlice(canvas, { theta0123, theta4567, dontCare }, corner, axis, index) {
  const vol = corner < 4 ? theta0123 : theta4567;
  const ch = corner % 4;
  const { data } = vol;
  return drawVolumeSlice(canvas, vol, axis, index, (t, px, o) => {
    const dc = dontCare && dontCare.data[t];
    const g = data[t * 4 + ch];
    px[o] = dc ? 200 : g;
    px[o + 1] = dc ? 40 : g;
    px[o + 2] = dc ? 40 : g;
  });
}

/**
 * One slice of the dense masks (bundle.md 5.2 `masks_0123` / `masks_4567`, RGBA8 (Z, Y, X, 4), round(255·m_k)):
 * `channel` 0-7 as grey (4-7 from masks4567), or 'rgb' = m_0, m_1, m_2 as red, green, blue.
 */
export function drawMaskSlice(canvas, { masks0123, masks4567 }, channel, axis, index) {
  if (channel === 'rgb') {
    const d = masks0123.data;
    return drawVolumeSlice(canvas, masks0123, axis, index, (t, px, o) => {
      px[o] = d[t * 4]; px[o + 1] = d[t * 4 + 1]; px[o + 2] = d[t * 4 + 2];
    });
  }
  const k = Number(channel);
  const vol = k < 4 ? masks0123 : masks4567;
  const d = vol.data;
  return drawVolumeSlice(canvas, vol, axis, index, (t, px, o) => {
    const g = d[t * 4 + (k % 4)];
    px[o] = g; px[o + 1] = g; px[o + 2] = g;
  });
}
