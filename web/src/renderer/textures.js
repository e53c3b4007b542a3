/**
 * Parsed KTX2 artifacts (loader/ktx2.js) -> three.js textures. Float volumes sample with LINEAR filtering
 * where OES_texture_float_linear exists; elsewhere they are converted to half floats, which filter linearly
 * on every WebGL2 device (proto/bundle.md 4.3).
 */
import {
  ClampToEdgeWrapping, Data3DTexture, DataTexture, DataUtils, FloatType, HalfFloatType, LinearFilter,
  NearestFilter, RGBAFormat, RGFormat, RedFormat, UnsignedByteType,
} from 'three';

const FORMATS = { 1: RedFormat, 2: RGFormat, 4: RGBAFormat };

function widen(tex) {
  // RGB (3 components) has no filterable float format in WebGL2 as a render-independent texture: pad to RGBA.
  if (tex.components !== 3) return tex;
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
  const format = FORMATS[t.components];
  let data = t.data;
  let type;
  if (t.kind === 'float') {
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
