/**
 * Parsed KTX2 artifacts (loader/ktx2.js) -> three.js textures. Float volumes sample with LINEAR filtering
 * where OES_texture_float_linear exists; elsewhere they are converted to half floats, which filter linearly
 * on every WebGL2 device (proto/bundle.md 4.3), as do the half-float artifacts (RGBA16F, RG16F) and the packed
 * packed irradiance formats, uploaded as they are: E5B9G9R9_UFLOAT_PACK32 (what the light stage writes) as RGB9_E5
 * (RGBFormat + UnsignedInt5999Type), B10G11R11_UFLOAT_PACK32 as R11F_G11F_B10F (RGBFormat + UnsignedInt101111Type).
 */
import {
  ClampToEdgeWrapping, Data3DTexture, DataTexture, DataUtils, FloatType, HalfFloatType, LinearFilter,
  NearestFilter, RGBAFormat, RGBFormat, RGFormat, RedFormat, UnsignedByteType, UnsignedInt101111Type,
  UnsignedInt5999Type,
} from 'three';
import { texelsAsNumbers } from '../loader/ktx2.js';

const FORMATS = { 1: RedFormat, 2: RGFormat, 4: RGBAFormat };

function widen(tex) {
  // RGB32F has no filterable format in WebGL2 as a render-independent texture: pad to RGBA (the packed
  // B10G11R11 and E5B9G9R9 formats are RGB and filterable as they are).
  if (tex.components !== 3 || tex.kind === 'ufloat-packed') return tex;
  const n = tex.data.length / 3;
  const out = new tex.data.constructor(n * 4);
  for (let i = 0; i < n; i++) { out[i * 4] = tex.data[i * 3]; out[i * 4 + 1] = tex.data[i * 3 + 1]; out[i * 4 + 2] = tex.data[i * 3 + 2]; out[i * 4 + 3] = 1; }
  return { ...tex, components: 4, data: out };
}

/**
 * @param {ReturnType<import('../loader/ktx2.js').parseKTX2>} ktx
 * @param {{filter?: 'linear'|'nearest', floatLinear?: boolean}} options  floatLinear: the device has
 *   OES_texture_float_linear
 */
export function textureFromKTX2(ktx, { filter = 'linear', floatLinear = true } = {}) {
  const t = widen(ktx);
  let format = FORMATS[t.components];
  let data = t.data;
  let type;
  if (t.kind === 'ufloat-packed') {
    format = RGBFormat;
    type = t.vkFormat === 123 ? UnsignedInt5999Type : UnsignedInt101111Type;
  } else if (t.kind === 'float') {
    type = FloatType;
    if (filter === 'linear' && !floatLinear) { data = Uint16Array.from(data, (x) => DataUtils.toHalfFloat(x)); type = HalfFloatType; }
  } else if (t.kind === 'half') {
    type = HalfFloatType;
  } else if (t.kind === 'unorm' && t.typeSize === 1) {
    type = UnsignedByteType;
  } else {
    throw new Error(`no texture path for ${t.format} (integer formats need a usampler; none of our modes uses one yet)`);
  }
  const tex = t.is3D ? new Data3DTexture(data, t.width, t.height, t.depth) : new DataTexture(data, t.width, t.height);
  tex.format = format;
  tex.type = type;
  const f = filter === 'linear' ? LinearFilter : NearestFilter;
  tex.minFilter = f;
  tex.magFilter = f;
  tex.wrapS = tex.wrapT = ClampToEdgeWrapping;
  if (t.is3D) tex.wrapR = ClampToEdgeWrapping;
  tex.generateMipmaps = false;
  tex.flipY = false;
  tex.unpackAlignment = 1;
  tex.needsUpdate = true;
  return tex;
}

/**
 * A DDGI atlas (parsed KTX2, 2D, ny·t high, nz·nx·t wide) re-packed with its tile columns wrapped after `columns`
 * tiles: tile c = k·nx + i goes to column c mod columns of row block c div columns, the blocks (ny tiles high each)
 * stacked downwards, unused tiles 0 — octahedral.glsl octAtlasUVWrapped reads it; workers/render/shading.py
 * wrap_atlas writes the same. The tiles keep their borders, so bilinear filtering reads the same texels.
 */
export function wrapAtlas(ktx, counts, columns) {
  if (!columns) return ktx;
  const [nx, ny, nz] = counts.map(Number);
  const t = ktx.height / ny;
  const C = nx * nz;
  const rows = Math.ceil(C / columns);
  const comp = ktx.valuesPerTexel ?? ktx.components;  // one packed word per texel for B10G11R11, E5B9G9R9
  const width = columns * t;
  const height = rows * ny * t;
  const data = new ktx.data.constructor(width * height * comp);
  const span = t * comp;
  for (let c = 0; c < C; c++) {
    const col = c % columns;
    const block = Math.floor(c / columns);
    for (let j = 0; j < ny; j++) {
      for (let y = 0; y < t; y++) {
        const src = ((j * t + y) * ktx.width + c * t) * comp;
        const dst = (((block * ny + j) * t + y) * width + col * t) * comp;
        data.set(ktx.data.subarray(src, src + span), dst);
      }
    }
  }
  return { ...ktx, data, width, height };
}

/**
 * Probe volumes (parsed KTX2, same size) stacked along z into one 3D texture: gi_grid.glsl giStackedUVW
 * (workers/render/shading.py stack_volumes: the bytes concatenated in slot order). RGBA32F or RGBA16F (all of one
 * kind), LINEAR.
 */
export function stackedVolumeTexture(volumes, options = {}) {
  if (!volumes.length) throw new Error('no volumes to stack');
  let vs = volumes.map(widen);
  if (vs.some((v) => v.kind !== vs[0].kind)) {  // half and float volumes together (one fell back): all float
    vs = vs.map((v) => (v.kind === 'half' ? { ...v, kind: 'float', data: texelsAsNumbers(v) } : v));
  }
  const { width, height, depth, components, kind } = vs[0];
  for (const v of vs) {
    if (!['float', 'half'].includes(v.kind) || v.kind !== kind || v.width !== width || v.height !== height
        || v.depth !== depth || v.components !== components) {
      throw new Error(`stacked volumes must be float or half, all ${kind} ${width}x${height}x${depth}x${components}, got ${v.format} ${v.width}x${v.height}x${v.depth}`);
    }
  }
  const per = vs[0].data.length;
  const data = new vs[0].data.constructor(per * vs.length);
  vs.forEach((v, s) => data.set(v.data, s * per));
  return textureFromKTX2({ ...vs[0], data, depth: Math.max(1, depth) * vs.length, is3D: true }, options);
}

/**
 * The ddgi mode's uProbeData: texel (i, j, k) = relocated position xyz, w = 1 unless the probe is OFF
 * (state 0), RGBA32F NEAREST (shading.py prepare_mode("ddgi")).
 */
export function probeDataTexture(positions, states) {
  const p = widen(positions);
  const n = p.data.length / 4;
  const data = new Float32Array(n * 4);
  for (let i = 0; i < n; i++) {
    data[i * 4] = p.data[i * 4]; data[i * 4 + 1] = p.data[i * 4 + 1]; data[i * 4 + 2] = p.data[i * 4 + 2];
    data[i * 4 + 3] = states && states.data[i * (states.components || 1)] === 0 ? 0 : 1;
  }
  return textureFromKTX2({ ...p, kind: 'float', data, components: 4 }, { filter: 'nearest' });
}

/**
 * probe_grid.glsl's uGridLayers: R32F, NEAREST, no mipmaps, width max(counts) (at least 1), height 3; texel (i, a) =
 * layer i of axis a (bake-frame metres), read with texelFetch where uGridRectilinear is true. From the layers of a
 * rectilinear grid (math/sh.js gridLayers: [xs, ys, zs], checked), the rest of each row 0; a 1 x 3 texture of zeros
 * for a uniform grid (null), so the sampler always has a texture of its type.
 * @param {ArrayLike<number>[]|null} layers  axis a holds counts[a] layers
 * @returns {import('three').DataTexture}
 */
export function gridLayersTexture(layers) {
  const width = Math.max(1, ...(layers ? layers.map((L) => L.length) : []));
  const data = new Float32Array(width * 3);
  if (layers) layers.forEach((L, a) => data.set(L, a * width));
  const tex = new DataTexture(data, width, 3, RedFormat, FloatType);
  tex.minFilter = tex.magFilter = NearestFilter;
  tex.wrapS = tex.wrapT = ClampToEdgeWrapping;
  tex.generateMipmaps = false;
  tex.flipY = false;
  tex.unpackAlignment = 1;
  tex.name = layers ? 'kiln:grid-layers' : 'kiln:grid-layers (uniform grid)';
  tex.needsUpdate = true;
  return tex;
}
