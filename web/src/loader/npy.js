/**
 * A tiny .npy reader (NumPy format 1.0-3.0) for the bake's npy artifacts (`prt_points`, `prt_sh_transfer`,
 * ...): little-endian (or byte-order-free) float32, float64, int8/16/32/64 and uint8/16/32/64 arrays, C order.
 * Returns {dtype, shape, data} with data a typed array of the file's element type (int64/uint64 as
 * BigInt64Array/BigUint64Array; use toFloat64 for plain numbers). Anything else throws NpyError.
 */
export class NpyError extends Error {}

const MAGIC = [0x93, 0x4e, 0x55, 0x4d, 0x50, 0x59];  // \x93NUMPY
const TYPES = {
  f4: Float32Array, f8: Float64Array, i1: Int8Array, i2: Int16Array, i4: Int32Array, i8: BigInt64Array,
  u1: Uint8Array, u2: Uint16Array, u4: Uint32Array, u8: BigUint64Array, b1: Uint8Array,
};

/** @param {ArrayBuffer|Uint8Array} input */
export function parseNpy(input) {
  const bytes = input instanceof Uint8Array ? input : new Uint8Array(input);
  if (bytes.byteLength < 10 || MAGIC.some((b, i) => bytes[i] !== b)) throw new NpyError('not an .npy file (bad magic)');
  const major = bytes[6];
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let headerLen, start;
  if (major === 1) { headerLen = dv.getUint16(8, true); start = 10; }
  else if (major === 2 || major === 3) { headerLen = dv.getUint32(8, true); start = 12; }
  else throw new NpyError(`unsupported .npy version ${major}`);
  const header = new TextDecoder(major === 3 ? 'utf-8' : 'latin1').decode(bytes.subarray(start, start + headerLen));
  const descr = /'descr'\s*:\s*'([^']*)'/.exec(header);
  const order = /'fortran_order'\s*:\s*(True|False)/.exec(header);
  const shapeM = /'shape'\s*:\s*\(([^)]*)\)/.exec(header);
  if (!descr || !order || !shapeM) throw new NpyError(`bad .npy header: ${header}`);
  if (order[1] === 'True') throw new NpyError('Fortran-order arrays are not supported');
  const d = descr[1];
  const endian = d[0];
  const code = d.slice(1);
  if (endian === '>' && !['i1', 'u1', 'b1'].includes(code)) throw new NpyError(`big-endian dtype ${d} is not supported`);
  if (!['<', '|', '='].includes(endian) && endian !== '>') throw new NpyError(`unsupported dtype ${d}`);
  const Type = TYPES[code];
  if (!Type) throw new NpyError(`unsupported dtype ${d}`);
  const shape = shapeM[1].split(',').map((s) => s.trim()).filter((s) => s.length).map(Number);
  const count = shape.reduce((a, b) => a * b, 1);
  const offset = start + headerLen;
  const need = count * Type.BYTES_PER_ELEMENT;
  if (bytes.byteLength - offset < need) throw new NpyError(`truncated .npy: ${bytes.byteLength - offset} bytes of data, ${need} needed`);
  const abs = bytes.byteOffset + offset;
  const data = abs % Type.BYTES_PER_ELEMENT === 0
    ? new Type(bytes.buffer, abs, count)
    : new Type(bytes.slice(offset, offset + need).buffer, 0, count);
  return { dtype: d, shape, data };
}

/** The array's values as a Float64Array (BigInt arrays converted). */
export function toFloat64(arr) {
  const src = arr.data ?? arr;
  if (src instanceof BigInt64Array || src instanceof BigUint64Array) return Float64Array.from(src, (x) => Number(x));
  return Float64Array.from(src);
}
