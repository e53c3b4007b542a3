/**
 * @kiln/three: load a Kiln bundle (proto/bundle.md) into a plain three.js app. See ../README.md.
 */
export { KilnBundle, BundleError, KTX2LOADER_FORMATS, FORMAT_VERSION, ktx2VkFormat, recordFromTexture } from './bundle.js';
export { KilnGI, EXTENSION_MODES, IRRADIANCE_HOOK, modeGLSL, stackRecords } from './gi.js';
export { probeGridBox, padShL2, resampleShL2, shRotationL2, cellSize, threeTexelCoord, SH_L2_TEXELS, frameMatrix, isIdentityFrame, fitsProbeGrid } from './grid.js';

import { KilnBundle } from './bundle.js';
import { KilnGI } from './gi.js';

/**
 * Everything at once: the manifest, the baked scene (GLTFLoader on the `scene` artifact, its lights included), the
 * LightProbeGrid (added to the scene; on, mode 'grid') and the material extension on every mesh material. A bake
 * whose probe grid is turned (grid.frame, yaw ≠ 0) gets a LightProbeGrid resampled onto world axes (grid.js
 * resampleShL2). Without `sh_l2` (an L1 bake) probeGrid is null and the mode is the extension's 'leaking'.
 * @param {string} base  URL of the bundle folder (or, with options.bake, of the Kiln server)
 * @param {import('three').WebGLRenderer} renderer
 * @returns {Promise<{bundle: KilnBundle, gltf: object, scene: import('three').Group, gi: KilnGI, probeGrid: object|null}>}
 */
export async function loadKilnBundle(base, renderer, { pad = 1, fetch, bake = null, headers } = {}) {
  const bundle = bake ? await KilnBundle.fromServer(base, bake, { renderer, fetch, headers })
    : await KilnBundle.load(base, { renderer, fetch });
  const gi = new KilnGI(bundle, renderer, { pad });
  const gltf = await bundle.loadScene();
  const probeGrid = bundle.has('sh_l2') ? await gi.createProbeGrid() : null;
  if (probeGrid) gltf.scene.add(probeGrid);
  gi.extendScene(gltf.scene);
  const leaking = gi.modes().find((m) => m.id === 'leaking')?.available;
  await gi.setMode(probeGrid ? 'grid' : leaking ? 'leaking' : 'off');
  return { bundle, gltf, scene: gltf.scene, gi, probeGrid };
}
