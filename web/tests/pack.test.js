// Several dropped files as one upload (src/loader/pack.js): a .gltf with its buffers and images, zipped at the
// relative paths the model names them by; the server reads that zip like any other.
import { describe, expect, it } from 'vitest';
import { unzipSync } from 'three/addons/libs/fflate.module.js';
import { PackError, modelJson, packUpload, referencedFiles } from '../src/loader/pack.js';

const gltf = {
  asset: { version: '2.0' },
  buffers: [{ uri: 'data%20dir/box%20bin.bin', byteLength: 4 }, { uri: 'data:application/octet-stream;base64,AAAAAA==' }],
  images: [{ uri: 'tex/wall.png' }, { uri: '../outside.png' }, { uri: 'https://example.com/x.png' }],
};
const file = (bytes, name) => new File([bytes], name);

describe('packUpload', () => {
  it('zips a model and the files it references at their relative paths', async () => {
    const model = file(JSON.stringify(gltf), 'room.gltf');
    const bin = file(new Uint8Array([1, 2, 3, 4]), 'box bin.bin');
    const png = file(new Uint8Array([137, 80, 78, 71]), 'wall.png');
    const extra = file(new Uint8Array([9]), 'notes.txt');
    const out = await packUpload([bin, model, png, extra]);
    expect(out.name).toBe('room.zip');
    const entries = unzipSync(new Uint8Array(await out.arrayBuffer()));
    expect(Object.keys(entries).sort()).toEqual(['data dir/box bin.bin', 'room.gltf', 'tex/wall.png']);
    expect(Array.from(entries['data dir/box bin.bin'])).toEqual([1, 2, 3, 4]);
    expect(JSON.parse(new TextDecoder().decode(entries['room.gltf']))).toEqual(gltf);
  });

  it('passes one file through and says what is missing or ambiguous', async () => {
    const glb = file(new Uint8Array([103, 108, 84, 70]), 'a.glb');
    expect(await packUpload([glb])).toBe(glb);
    const model = file(JSON.stringify(gltf), 'room.gltf');
    await expect(packUpload([model, file(new Uint8Array([1]), 'box bin.bin')])).rejects.toThrow(
      "room.gltf: image 0 'tex/wall.png' is not among the dropped files");
    await expect(packUpload([model, file('{}', 'b.gltf')])).rejects.toBeInstanceOf(PackError);
    await expect(packUpload([file('x', 'a.bin'), file('y', 'b.png')])).rejects.toThrow('none of the dropped files');
  });

  it('reads the references of a .gltf and of a .glb JSON chunk, never outside the folder', () => {
    expect(referencedFiles(gltf)).toEqual([{ rel: 'data dir/box bin.bin', what: 'buffer 0' },
      { rel: 'tex/wall.png', what: 'image 0' }]);
    const json = new TextEncoder().encode(JSON.stringify({ asset: { version: '2.0' }, images: [{ uri: 'a/b.png' }] }));
    const glb = new Uint8Array(20 + json.length);
    const dv = new DataView(glb.buffer);
    dv.setUint32(0, 0x46546c67, true); dv.setUint32(4, 2, true); dv.setUint32(8, glb.length, true);
    dv.setUint32(12, json.length, true); dv.setUint32(16, 0x4e4f534a, true); glb.set(json, 20);
    expect(referencedFiles(modelJson(glb))).toEqual([{ rel: 'a/b.png', what: 'image 0' }]);
    expect(modelJson(new TextEncoder().encode('{nope'))).toBeNull();
  });
});
