/**
 * A KTX2 reader for the subset Kiln writes (proto/bundle.md section 4): uncompressed formats, one level,
 * no layers, one face, 2D or 3D, supercompression none or Zstandard (one frame, inflated with fzstd).
 *
 * three's KTX2Loader rejects RGB32F and the integer formats, so the viewer reads every artifact here and
 * builds its textures itself. Anything outside the subset throws a KTX2Error naming the reason; nothing
 * warns and returns undefined.
 */
import { decompress } from 'fzstd';

export class KTX2Error extends Error {}

const IDENTIFIER = [0xab, 0x4b, 0x54, 0x58, 0x20, 0x32, 0x30, 0xbb, 0x0d, 0x0a, 0x1a, 0x0a];

/** vkFormat -> {name, components, typeSize, kind}; kind picks the typed array (proto/bundle.md 4.3). */
export const VK_FORMATS = {
  9: { name: 'R8_UNORM', components: 1, typeSize: 1, kind: 'unorm' },
  13: { name: 'R8_UINT', components: 1, typeSize: 1, kind: 'uint' },
  16: { name: 'R8G8_UNORM', components: 2, typeSize: 1, kind: 'unorm' },
  37: { name: 'R8G8B8A8_UNORM', components: 4, typeSize: 1, kind: 'unorm' },
  43: { name: 'R8G8B8A8_SRGB', components: 4, typeSize: 1, kind: 'unorm' },
  74: { name: 'R16_UINT', components: 1, typeSize: 2, kind: 'uint' },
  76: { name: 'R16_SFLOAT', components: 1, typeSize: 2, kind: 'half' },
  83: { name: 'R16G16_SFLOAT', components: 2, typeSize: 2, kind: 'half' },
  97: { name: 'R16G16B16A16_SFLOAT', components: 4, typeSize: 2, kind: 'half' },
  98: { name: 'R32_UINT', components: 1, typeSize: 4, kind: 'uint' },
  99: { name: 'R32_SINT', components: 1, typeSize: 4, kind: 'sint' },
  100: { name: 'R32_SFLOAT', components: 1, typeSize: 4, kind: 'float' },
  103: { name: 'R32G32_SFLOAT', components: 2, typeSize: 4, kind: 'float' },
  106: { name: 'R32G32B32_SFLOAT', components: 3, typeSize: 4, kind: 'float' },
  109: { name: 'R32G32B32A32_SFLOAT', components: 4, typeSize: 4, kind: 'float' },
  // one 32-bit word per texel: R bits 0-10, G 11-21 (5-bit exponent, 6-bit mantissa), B 22-31 (5 + 5); WebGL2's
  // R11F_G11F_B10F (RGB + UNSIGNED_INT_10F_11F_11F_REV), filterable everywhere
  122: { name: 'B10G11R11_UFLOAT_PACK32', components: 3, typeSize: 4, kind: 'ufloat-packed', texelBytes: 4 },
  // one 32-bit word per texel: 9-bit mantissas R bits 0-8, G 9-17, B 18-26, the shared exponent 27-31 (bias 15);
  // WebGL2's RGB9_E5 (RGB + UNSIGNED_INT_5_9_9_9_REV), filterable everywhere. The light stage's irradiance.
  123: { name: 'E5B9G9R9_UFLOAT_PACK32', components: 3, typeSize: 4, kind: 'ufloat-packed', texelBytes: 4, samples: 6 },
};

function typedView(kind, typeSize, bytes) {
  const { buffer, byteOffset, byteLength } = bytes;
  const aligned = byteOffset % typeSize === 0;
  const src = aligned ? bytes : bytes.slice();  // copy when the level is not aligned in the buffer
  const b = aligned ? buffer : src.buffer;
  const off = aligned ? byteOffset : 0;
  const n = byteLength / typeSize;
  if (kind === 'float') return new Float32Array(b, off, n);
  if (kind === 'half') return new Uint16Array(b, off, n);  // raw IEEE half bits: see halfToFloat
  if (kind === 'sint') return new Int32Array(b, off, n);
  if (kind === 'ufloat-packed') return new Uint32Array(b, off, n);
  if (typeSize === 1) return new Uint8Array(b, off, n);
  if (typeSize === 2) return new Uint16Array(b, off, n);
  return new Uint32Array(b, off, n);
}

/**
 * Parse a KTX2 file of the Kiln subset.
 * @param {ArrayBuffer|Uint8Array} input
 * @returns {{vkFormat: number, format: string, components: number, typeSize: number, kind: string,
 *   width: number, height: number, depth: number, is3D: boolean, supercompression: number,
 *   valuesPerTexel: number, kv: Record<string, string>,
 *   data: Float32Array|Uint16Array|Uint8Array|Uint32Array|Int32Array}}
 *   data holds width·height·max(depth,1)·valuesPerTexel values, x fastest, then y, then z (bundle.md 4.6):
 *   valuesPerTexel = components, except 1 (a Uint32Array word) for the packed B10G11R11_UFLOAT_PACK32 and
 *   E5B9G9R9_UFLOAT_PACK32.
 *   Little-endian hosts only (every browser we target).
 */
export function parseKTX2(input) {
  const bytes = input instanceof Uint8Array ? input : new Uint8Array(input);
  if (bytes.byteLength < 104) throw new KTX2Error(`file of ${bytes.byteLength} bytes is shorter than the KTX2 header`);
  for (let i = 0; i < 12; i++) {
    if (bytes[i] !== IDENTIFIER[i]) throw new KTX2Error('not a KTX 2.0 file (wrong identifier)');
  }
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const u32 = (o) => dv.getUint32(o, true);
  const u64 = (o) => {
    const hi = dv.getUint32(o + 4, true);
    if (hi !== 0) throw new KTX2Error(`64-bit offset at byte ${o} is beyond what a browser buffer holds`);
    return dv.getUint32(o, true);
  };
  const vkFormat = u32(12);
  const fmt = VK_FORMATS[vkFormat];
  if (!fmt) throw new KTX2Error(`unsupported vkFormat ${vkFormat} (Kiln's subset: ${Object.keys(VK_FORMATS).join(', ')})`);
  const typeSize = u32(16);
  if (typeSize !== fmt.typeSize) throw new KTX2Error(`typeSize ${typeSize} does not match ${fmt.name}`);
  const width = u32(20), height = u32(24), depth = u32(28);
  const layers = u32(32), faces = u32(36), levels = u32(40), sc = u32(44);
  if (!width || !height) throw new KTX2Error('zero width or height');
  if (layers !== 0) throw new KTX2Error('array textures are not in the subset');
  if (faces !== 1) throw new KTX2Error('cube maps are not in the subset');
  if (levels > 1) throw new KTX2Error(`${levels} mip levels: the subset has one`);
  if (sc !== 0 && sc !== 2) throw new KTX2Error(`supercompression scheme ${sc} is not in the subset (0 none, 2 Zstandard)`);
  const dfdOffset = u32(48), dfdLength = u32(52), kvdOffset = u32(56), kvdLength = u32(60);
  if (u64(64) !== 0 || u64(72) !== 0) throw new KTX2Error('supercompression global data is not in the subset');
  const levelOffset = u64(80), levelLength = u64(88), rawLength = u64(96);
  const texelBytes = fmt.texelBytes || fmt.components * fmt.typeSize;
  const expected = width * height * Math.max(depth, 1) * texelBytes;
  if (rawLength !== expected) {
    throw new KTX2Error(`uncompressedByteLength ${rawLength} != ${width}x${height}x${Math.max(depth, 1)} x ${texelBytes} bytes`);
  }
  if (dfdOffset + dfdLength > bytes.byteLength || kvdOffset + kvdLength > bytes.byteLength) {
    throw new KTX2Error('file is shorter than its data format descriptor or key/value data');
  }
  const nSamples = fmt.samples ?? fmt.components;  // E5B9G9R9: a mantissa and the exponent per channel
  if (dfdLength !== 28 + 16 * nSamples) throw new KTX2Error(`DFD of ${dfdLength} bytes does not fit ${fmt.name}`);
  const samples = (u32(dfdOffset + 8) >>> 16) - 24;
  if (samples !== 16 * nSamples) throw new KTX2Error(`DFD describes ${samples / 16} samples, ${fmt.name} has ${nSamples}`);
  if (levelOffset + levelLength !== bytes.byteLength) {
    throw new KTX2Error(levelOffset + levelLength > bytes.byteLength ? 'file is shorter than its level data' : 'bytes after the level data');
  }
  const kv = {};
  const dec = new TextDecoder();
  for (let o = kvdOffset; o < kvdOffset + kvdLength;) {
    const n = u32(o);
    if (n === 0) break;
    const entry = bytes.subarray(o + 4, o + 4 + n);
    const nul = entry.indexOf(0);
    if (nul < 0) throw new KTX2Error('malformed key/value entry (no NUL after the key)');
    const key = dec.decode(entry.subarray(0, nul));
    let value = entry.subarray(nul + 1);
    if (value.length && value[value.length - 1] === 0) value = value.subarray(0, value.length - 1);
    if (key in kv) throw new KTX2Error(`duplicate key ${key}`);
    kv[key] = dec.decode(value);
    o += 4 + n + ((4 - (n % 4)) % 4);
  }
  let level = bytes.subarray(levelOffset, levelOffset + levelLength);
  if (sc === 2) {
    try {
      level = decompress(level);
    } catch (e) {
      throw new KTX2Error(`corrupt Zstandard level: ${e.message || e}`);
    }
    if (level.byteLength !== rawLength) {
      throw new KTX2Error(`Zstandard level inflates to ${level.byteLength} bytes, expected ${rawLength}`);
    }
  } else if (levelLength !== rawLength) {
    throw new KTX2Error(`level of ${levelLength} bytes, expected ${rawLength}`);
  }
  return {
    vkFormat, format: fmt.name, components: fmt.components, typeSize, kind: fmt.kind,
    valuesPerTexel: fmt.texelBytes ? 1 : fmt.components,
    width, height, depth, is3D: depth > 0, supercompression: sc, kv,
    data: typedView(fmt.kind, typeSize, level),
  };
}

/** IEEE 754 half (as its 16 bits) -> number. */
export function halfToFloat(h) {
  const s = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 0x1f;
  const f = h & 0x3ff;
  if (e === 0) return s * f * 2 ** -24;
  if (e === 31) return f ? NaN : s * Infinity;
  return s * (1 + f / 1024) * 2 ** (e - 15);
}

/** An unsigned small float (5-bit exponent, bias 15, `m` mantissa bits) -> number (as proto/ktx2.py). */
function ufloatToFloat(bits, m) {
  const e = bits >>> m;
  const f = bits & ((1 << m) - 1);
  if (e === 0) return f * 2 ** (-14 - m);
  if (e === 31) return f ? NaN : Infinity;
  return (1 + f / (1 << m)) * 2 ** (e - 15);
}

/** B10G11R11_UFLOAT_PACK32 words -> Float32Array of r, g, b per texel. */
export function unpackB10G11R11(words) {
  const out = new Float32Array(words.length * 3);
  for (let i = 0; i < words.length; i++) {
    const w = words[i];
    out[i * 3] = ufloatToFloat(w & 0x7ff, 6);
    out[i * 3 + 1] = ufloatToFloat((w >>> 11) & 0x7ff, 6);
    out[i * 3 + 2] = ufloatToFloat(w >>> 22, 5);
  }
  return out;
}

/** E5B9G9R9_UFLOAT_PACK32 words -> Float32Array of r, g, b per texel: mantissa · 2^(e − 15 − 9) (as proto/ktx2.py). */
export function unpackE5B9G9R9(words) {
  const out = new Float32Array(words.length * 3);
  for (let i = 0; i < words.length; i++) {
    const w = words[i];
    const scale = 2 ** ((w >>> 27) - 24);
    out[i * 3] = (w & 0x1ff) * scale;
    out[i * 3 + 1] = ((w >>> 9) & 0x1ff) * scale;
    out[i * 3 + 2] = ((w >>> 18) & 0x1ff) * scale;
  }
  return out;
}

/**
 * The texel values of a parsed KTX2 as plain numbers, `components` per texel (halves decoded, the packed
 * formats unpacked to r, g, b, UNORM as the stored integers).
 */
export function texelsAsNumbers(tex) {
  if (tex.kind === 'ufloat-packed') return tex.vkFormat === 123 ? unpackE5B9G9R9(tex.data) : unpackB10G11R11(tex.data);
  return tex.kind === 'half' ? Float32Array.from(tex.data, halfToFloat) : tex.data;
}

/**
 * A table artifact (proto/bundle.md 3: any array as a one-channel 2D KTX2 of its rows, `meta.ktx2.table`) in the
 * form loader/npy.js gives: {dtype, shape, data}, data the level's typed array (Float32Array for R32_SFLOAT,
 * Int32Array for R32_SINT, Uint32Array for R32_UINT, halves decoded), shape the manifest's.
 */
export function tableFromKTX2(tex, shape) {
  const n = tex.width * tex.height * Math.max(tex.depth, 1) * tex.valuesPerTexel;
  const count = (shape || []).reduce((a, b) => a * b, 1);
  if (!shape || count !== n) throw new KTX2Error(`table of ${n} values does not fit shape [${shape}]`);
  const dtype = { float: 'float32', half: 'float32', sint: 'int32', uint: `uint${8 * tex.typeSize}`, unorm: 'uint8' }[tex.kind];
  return { dtype, shape: [...shape], data: tex.kind === 'half' ? texelsAsNumbers(tex) : tex.data };
}
